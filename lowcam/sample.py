"""A sample scene made without Blender: an ideal pinhole render of a few objects and a real photograph as plate.

Used by ``lowcam demo``, the tests and the benchmarks. The objects are placed in camera-plane coordinates, so the
same scene comes out at any render size. Edges are anti-aliased analytically (exact area coverage).

Contents
--------
- :func:`sample_render`: premultiplied linear RGBA of a shaded sphere, a checkerboard card and white text
- :func:`sample_plate`: a real photograph (scikit-image's ``coffee``) cropped and scaled to the frame, uint8 RGB
- :func:`side_by_side`: two frames next to each other with a caption bar above each
"""
from __future__ import annotations

import cv2
import numpy as np

from .pipeline import render_field_of_view
from .profile import load_profile


def _coverage_1d(lo, hi, centres, half_px):
    """Fraction of each pixel [c - h, c + h] inside [lo, hi]."""
    return np.clip((np.minimum(hi, centres + half_px) - np.maximum(lo, centres - half_px)) / (2 * half_px), 0, 1)


def sample_render(profile="fire-i", width: int = 1600, height: int | None = None) -> np.ndarray:
    """Premultiplied linear RGBA (height, width, 4) float32: a shaded sphere, a checkerboard card and white
    text, on a transparent background, framed for ``profile``'s camera."""
    profile = load_profile(profile)
    half_x, _ = render_field_of_view(profile)
    height = height or int(round(width * profile.camera.height / profile.camera.width))
    focal = width / (2 * half_x)
    px = 1.0 / focal  # one render pixel in camera-plane units
    x = (np.arange(width) - width / 2 + 0.5) * px
    y = (np.arange(height) - height / 2 + 0.5) * px
    xx, yy = np.meshgrid(x.astype(np.float32), y.astype(np.float32))
    out = np.zeros((height, width, 4), np.float32)

    def over(rgb, alpha):
        a = alpha[..., None]
        out[..., :3] = rgb * a + out[..., :3] * (1 - a)
        out[..., 3:] = a + out[..., 3:] * (1 - a)

    # Checkerboard card, 8x6 squares, right of centre.
    x0, x1, y0, y1 = 0.12, 0.62, -0.30, 0.075
    sq = (x1 - x0) / 8
    cov = _coverage_1d(x0, x1, xx, px / 2) * _coverage_1d(y0, y1, yy, px / 2)
    ix = np.floor((xx - x0) / sq).astype(int)
    iy = np.floor((yy - y0) / sq).astype(int)
    # Anti-aliased squares: the white fraction of each pixel, from the 1-D fractions along x and y.
    fx = np.clip(((xx - x0) / sq - ix) * sq / px + 0.5, 0, 1)
    fy = np.clip(((yy - y0) / sq - iy) * sq / px + 0.5, 0, 1)
    fx = np.where((ix % 2) == 0, fx, 1 - fx)
    fy = np.where((iy % 2) == 0, fy, 1 - fy)
    white = fx * fy + (1 - fx) * (1 - fy)
    grey = 0.05 + 0.85 * white
    over(np.repeat(grey[..., None], 3, -1), cov)

    # A shaded orange sphere, left of centre, overlapping the frame's middle.
    cx, cy, r = -0.28, 0.08, 0.26
    d = np.hypot(xx - cx, yy - cy)
    cov = np.clip((r - d) / px + 0.5, 0, 1)
    nz = np.sqrt(np.clip(1 - (d / r) ** 2, 0, 1))
    nx, ny = (xx - cx) / r, (yy - cy) / r
    light = np.array([-0.5, -0.6, 0.62])
    light /= np.linalg.norm(light)
    lambert = np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0, 1)
    spec = lambert ** 60
    base = np.array([0.95, 0.45, 0.12], np.float32)
    shade = (0.08 + 0.85 * lambert)[..., None] * base + 0.6 * spec[..., None]
    over(np.clip(shade, 0, 1).astype(np.float32), cov)

    # White text near the top: a crisp overlay that the camera must soften.
    text = np.zeros((height, width), np.uint8)
    scale = width / 640
    org = (int(width * 0.30), int(height * 0.27))
    cv2.putText(text, "LOWCAM", org, cv2.FONT_HERSHEY_SIMPLEX, 1.6 * scale, 255, max(1, int(3 * scale)),
                cv2.LINE_AA)
    over(np.ones(3, np.float32), text.astype(np.float32) / 255)
    return out


def sample_plate(profile="fire-i") -> np.ndarray:
    """A real photograph (scikit-image's ``coffee``) cropped and scaled to the camera's frame, uint8 RGB."""
    from skimage import data

    profile = load_profile(profile)
    w, h = profile.camera.width, profile.camera.height
    img = data.coffee()
    ih, iw = img.shape[:2]
    if iw / ih > w / h:
        cw = int(round(ih * w / h))
        img = img[:, (iw - cw) // 2:(iw - cw) // 2 + cw]
    else:
        ch = int(round(iw * h / w))
        img = img[(ih - ch) // 2:(ih - ch) // 2 + ch]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def side_by_side(left: np.ndarray, right: np.ndarray, left_label: str, right_label: str) -> np.ndarray:
    """Two frames next to each other with a caption bar above each."""
    import cv2

    h, w = left.shape[:2]
    bar = 28
    canvas = np.full((h + bar, 2 * w + 8, 3), 255, np.uint8)
    canvas[bar:, :w] = left
    canvas[bar:, w + 8:] = right
    for x, label in ((6, left_label), (w + 14, right_label)):
        cv2.putText(canvas, label, (x, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas
