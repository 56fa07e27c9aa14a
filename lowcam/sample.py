"""A sample scene made without Blender: an ideal pinhole render of a few objects and a real photograph as plate.

Used by ``lowcam demo``, the tests and the benchmarks. The objects are placed in camera-plane coordinates, so the
same scene comes out at any render size. Edges are anti-aliased analytically (exact area coverage).

A plate is what the camera filmed, so the sample plate is the photograph *filmed through the camera*: the
photograph is taken as the opaque ideal image of the scene behind the graphics (:func:`photograph_render`) and
run through the profile's whole chain with the shot's camera motion (:func:`film`), with noise from a seed
independent of the graphics' (:func:`plate_seed`). Plate and graphics then share the camera's blur, motion blur
and noise level, so a plain composite shows sharp graphics floating on the footage and Lowcam's shows them in it.

Contents
--------
- :func:`photograph`: a bundled photograph (scikit-image's ``coffee`` or ``astronaut``), uint8 RGB
- :func:`sample_render`: premultiplied linear RGBA of a shaded sphere, a checkerboard card and white text
- :func:`sample_photograph`: a real photograph (:func:`photograph` ``"coffee"``) cropped and scaled to the frame, uint8 RGB
- :data:`PLATE_SEED_OFFSET`: added to the graphics' seed (mod 2^64) for the plate's noise
- :func:`plate_seed`: the noise seed of a plate filmed for graphics simulated with ``seed``
- :func:`photograph_render`: a photograph as the opaque ideal render of the scene (premultiplied linear RGBA)
- :func:`film`: a photograph filmed through the camera: the profile's chain on it, with the shot's motion
- :func:`sample_plate`: the sample photograph filmed through the camera (the plate of the sample scene), uint8 RGB
- :func:`side_by_side`: two frames next to each other with a caption bar above each
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import LowcamError
from .pipeline import render_field_of_view, simulate
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


def _crop_to_aspect(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """The centre of ``img`` with the aspect ratio ``w`` : ``h``."""
    ih, iw = img.shape[:2]
    if iw / ih > w / h:
        cw = int(round(ih * w / h))
        return img[:, (iw - cw) // 2:(iw - cw) // 2 + cw]
    ch = int(round(iw * h / w))
    return img[(ih - ch) // 2:(ih - ch) // 2 + ch]


def photograph(name: str) -> np.ndarray:
    """A bundled photograph, uint8 RGB: ``"coffee"`` (600x400, CC0) or ``"astronaut"`` (512x512, public domain),
    scikit-image's ``data.coffee()`` and ``data.astronaut()`` byte for byte (``lowcam/data/README.md``)."""
    return cv2.cvtColor(cv2.imread(str(Path(__file__).resolve().parent / "data" / f"{name}.png")), cv2.COLOR_BGR2RGB)


def sample_photograph(profile="fire-i") -> np.ndarray:
    """A real photograph (:func:`photograph` ``"coffee"``) cropped and scaled to the camera's frame, uint8 RGB: the
    sharp scene, before any camera filmed it."""
    profile = load_profile(profile)
    w, h = profile.camera.width, profile.camera.height
    photo = photograph("coffee")
    return cv2.resize(_crop_to_aspect(photo, w, h), (w, h), interpolation=cv2.INTER_AREA)


#: Added to the graphics' seed (mod 2^64) for the noise of the plate filmed for them: the plate's noise and the
#: graphics' are then independent, as two exposures' are (the golden-ratio constant of SplitMix64, any odd
#: 64-bit number far from small offsets would do).
PLATE_SEED_OFFSET = 0x9E3779B97F4A7C15


def plate_seed(seed: int) -> int:
    """The noise seed of a plate filmed for graphics simulated with ``seed``: ``(seed + PLATE_SEED_OFFSET) mod
    2^64``, never equal to ``seed``."""
    return (int(seed) + PLATE_SEED_OFFSET) % 2**64


def photograph_render(photo: np.ndarray, profile="fire-i", width: int = 1200) -> np.ndarray:
    """A uint8 RGB photograph as the opaque ideal render of the scene: premultiplied linear RGBA (alpha 1) of
    ``width`` columns at the render's aspect (:func:`lowcam.pipeline.render_camera`), the photograph's centre
    scaled to cover it. Code value / 255 is used linearly, as renders are (the paper models no gamma)."""
    profile = load_profile(profile)
    photo = np.asarray(photo)
    if photo.dtype != np.uint8 or photo.ndim != 3 or photo.shape[2] != 3:
        raise LowcamError(f"photograph: a (H, W, 3) uint8 image is needed, got {photo.dtype} {photo.shape}")
    height = int(round(width * profile.camera.height / profile.camera.width))
    img = cv2.resize(_crop_to_aspect(photo, width, height), (width, height), interpolation=cv2.INTER_CUBIC
                     if photo.shape[1] < width else cv2.INTER_AREA)
    out = np.ones((height, width, 4), np.float32)
    out[..., :3] = np.clip(img.astype(np.float32) / 255.0, 0.0, 1.0)
    return out


def film(photo: np.ndarray, profile="fire-i", angular_velocity=(0.0, 0.0, 0.0), exposure_s: float | None = None,
         seed: int = 0, frame: int = 0, render_width: int = 1200) -> np.ndarray:
    """``photo`` (uint8 RGB) filmed through the camera: the profile's whole chain run on it as the opaque ideal
    image of the scene (:func:`photograph_render`), turning at ``angular_velocity`` (rad/s, camera frame) over
    ``exposure_s`` (None: the profile's), with the noise of ``(seed, frame)``. Returns the (h, w, 3) uint8 frame.

    Effects that need render passes (object motion, defocus from depth) are left out: a photograph has none.
    """
    profile = load_profile(profile)
    passless = [e.name for e in profile.effects if e.enabled and e.needs_pass]
    if passless:
        profile = profile.without(*passless)
    render = photograph_render(photo, profile, render_width)
    return simulate(render, profile, None, angular_velocity, exposure_s, seed, frame)


def sample_plate(profile="fire-i", angular_velocity=(0.0, 0.0, 0.0), exposure_s: float | None = None,
                 seed: int = 0, frame: int = 0) -> np.ndarray:
    """The sample scene's plate: :func:`sample_photograph` filmed through ``profile``'s camera (:func:`film`)
    turning at ``angular_velocity`` over ``exposure_s``, for graphics simulated with noise ``seed`` (the plate's
    noise uses :func:`plate_seed` of it, so the two are independent) at ``frame``. uint8 RGB at the camera's size.
    """
    profile = load_profile(profile)
    return film(sample_photograph(profile), profile, angular_velocity, exposure_s, plate_seed(seed), frame)


def side_by_side(left: np.ndarray, right: np.ndarray, left_label: str, right_label: str) -> np.ndarray:
    """Two frames next to each other with a caption bar above each."""
    h, w = left.shape[:2]
    bar = 28
    canvas = np.full((h + bar, 2 * w + 8, 3), 255, np.uint8)
    canvas[bar:, :w] = left
    canvas[bar:, w + 8:] = right
    for x, label in ((6, left_label), (w + 14, right_label)):
        cv2.putText(canvas, label, (x, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas
