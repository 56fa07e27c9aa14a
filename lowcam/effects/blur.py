"""Gaussian blurs: the varying optical blur and the sensor's horizontal blur (Klein & Murray 2010, sec. 4.3, 5.2).

The spatially varying blur is step 3 of sec. 5.2, on a 24x18-cell grid: ``sigma^2 = antialias^2 +
(corner_softness |d_red - d_blue|)^2 + gap^2`` in output pixels, blended from a few uniform blurs. The horizontal
blur of every sensel plane is step 6 (7 taps, sigma 0.7 sensels, sec. 4.3). Its calibration measures edge spread
across slanted edges: the extra horizontal blur is ``sqrt(sigma_h^2 - sigma_v^2)`` px, half that in sensels.

Contents
--------
- :func:`gaussian_taps`: a normalised ``taps``-tap sampled Gaussian of standard deviation ``sigma`` (px)
- :func:`blur_levels`: blur radii (px) whose blend covers any sigma in [lo, hi]: 0, then octaves from 0.5 px
- :func:`level_weights`: piecewise-linear (hat) weights of each blur level for each sigma; they sum to 1
- :func:`blur_level_maps`: the uniform blurs a sigma grid blends, each with its weight map over the image
- :func:`varying_gaussian`: blur an image with a Gaussian whose sigma varies smoothly over a coarse grid
- :func:`gaussian_reach`: how far (px) that blur can spread a pixel
- :class:`SpatialBlur`: spatially varying Gaussian blur on a 24x18-cell grid (sec. 5.2 step 3)
- :class:`HorizontalBlur`: horizontal Gaussian blur of every sensel plane, 7 taps, sigma 0.7 (sec. 4.3, step 6)
- :func:`filter_rows`: convolve every sensel plane's colour and alpha along rows with a kernel
- :func:`edge_sigma`: Gaussian sigma (px) of the edge spread across one slanted edge, and its normal's angle
- :func:`find_edges`: boxes around the sides of every slanted square in a greyscale image
- :func:`fit_edge_blur`: horizontal and vertical edge-spread sigmas, and the extra horizontal blur (sec. 4.3)
- :class:`VerticalBlur`: vertical Gaussian blur of every sensel plane: a candidate the paper's camera did not show,
  before the sharpening (``vertical_blur``) or after it (``vertical_blur_after_sharpening``)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [ISO12233] ISO 12233:2017, "Photography - Electronic still picture imaging - Resolution and spatial frequency
  responses" (the slanted-edge method).
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import grid_points, sample_texture
from ..node_images import gaussian_blur_kernel
from ..window import filter_in_strips, grow_window
from .base import Effect, NodeStage, Param, Search


def gaussian_taps(sigma: float, taps: int = 7, dtype=np.float32) -> np.ndarray:
    """A normalised ``taps``-tap sampled Gaussian of standard deviation ``sigma`` (px)."""
    x = np.arange(taps) - (taps - 1) / 2
    k = np.exp(-0.5 * (x / sigma) ** 2) if sigma > 0 else (x == 0).astype(float)
    return (k / k.sum()).astype(dtype)


def blur_levels(lo: float, hi: float) -> list[float]:
    """Blur radii (px) whose blend covers any sigma in [lo, hi]: 0, then octaves from 0.5 px."""
    levels = [0.0] + [0.5 * 2.0**k for k in range(12)]
    below = max(i for i, s in enumerate(levels) if s <= lo)
    above = next((i for i, s in enumerate(levels) if s >= hi), len(levels) - 1)
    return levels[below:above + 1]


def level_weights(sigma: np.ndarray, levels: list[float]) -> np.ndarray:
    """Piecewise-linear (hat) weights of each blur level for each sigma; they sum to 1."""
    idx = np.clip(np.searchsorted(levels, sigma, side="right") - 1, 0, len(levels) - 2)
    lo = np.asarray(levels)[idx]
    hi = np.asarray(levels)[idx + 1]
    t = np.clip((sigma - lo) / (hi - lo), 0.0, 1.0)
    w = np.zeros((len(levels),) + sigma.shape, np.float32)
    np.put_along_axis(w, idx[None], (1 - t)[None], axis=0)
    np.put_along_axis(w, idx[None] + 1, t[None], axis=0)
    return w


def blur_level_maps(sigma_grid: np.ndarray, shape) -> list[tuple[float, np.ndarray | None]]:
    """The uniform Gaussian blurs (sigma, px) a blur varying as ``sigma_grid`` blends, each with its weight map
    over an image of ``shape`` (rows, cols), bilinear from the grid; the maps sum to 1. A uniform sigma gives one
    level and no map."""
    lo, hi = float(sigma_grid.min()), float(sigma_grid.max())
    if hi - lo < 1e-3:
        return [(lo, None)]
    levels = blur_levels(lo, hi)
    rows, cols = shape
    return [(s, cv2.resize(wg, (cols, rows), interpolation=cv2.INTER_LINEAR))
            for s, wg in zip(levels, level_weights(sigma_grid, levels)) if wg.any()]


def varying_gaussian(image: np.ndarray, sigma_grid: np.ndarray, window=None, in_place: bool = False) -> np.ndarray:
    """Blur ``image`` with a Gaussian whose sigma (px) varies smoothly as given by ``sigma_grid``.

    ``sigma_grid`` holds sigma at the cell centres of a coarse grid over the image (the paper's 24x18 cells, with
    bilinear interpolation between). The result blends a stack of uniform blurs with weights interpolated from
    the grid (:func:`blur_level_maps`), so the cost is a few separable blurs whatever the grid. A ``window``
    (rows, cols) holding every non-zero pixel (:func:`~lowcam.window.nonzero_window`) limits the work to it and
    the widest kernel's reach, with the same result: outside, the blur of zeros is zero. With a window,
    ``in_place`` writes the result into ``image``.
    """
    levels = blur_level_maps(sigma_grid, image.shape[:2])
    if window is None:
        return _blend_levels(image, levels)
    rows, cols = grow_window(window, gaussian_reach(sigma_grid), image.shape)
    out = image if in_place else image.copy()  # zero beyond the grown window, as its blur
    out[rows, cols] = _blend_levels(image[rows, cols], [(s, None if m is None else m[rows, cols]) for s, m in levels])
    return out


def gaussian_reach(sigma_grid: np.ndarray) -> int:
    """How far (px) :func:`varying_gaussian` can spread a pixel: cv2.GaussianBlur's float32 kernel has radius
    round(8 sigma + 1) // 2 <= 4 sigma + 1, for the widest blur level it may blend."""
    lo, hi = float(sigma_grid.min()), float(sigma_grid.max())
    widest = hi if hi - lo < 1e-3 else blur_levels(lo, hi)[-1]
    return int(np.ceil(4 * widest)) + 2


def _blend_levels(image: np.ndarray, levels) -> np.ndarray:
    """Blend the uniform blurs of ``image`` with their weight maps (:func:`blur_level_maps`), one strip of rows
    per thread (:func:`~lowcam.window.filter_in_strips`: ``cv2.GaussianBlur`` runs on one core), same result."""
    widest = max(s for s, _ in levels)
    halo = _kernel_radius(widest) + 1 if widest > 0 else 0

    def blend(piece, *piece_maps):  # the weight maps cut alongside, in the order of the levels that have one
        cut = iter(piece_maps)
        return _blend_strip(piece, [(s, None if m is None else next(cut)) for s, m in levels])

    return filter_in_strips(blend, image, halo, *(m for _, m in levels if m is not None))


def _kernel_radius(sigma: float) -> int:
    """The radius (px) of ``cv2.GaussianBlur``'s float32 kernel for ``sigma``: size round(8 sigma + 1) | 1."""
    return (int(np.floor(8 * sigma + 1 + 0.5)) | 1) // 2


def _blend_strip(image: np.ndarray, levels) -> np.ndarray:
    """:func:`_blend_levels` of one piece of the image, in the calling thread."""
    out = out_weight = None
    for s, wmap in levels:
        level = cv2.GaussianBlur(image, (0, 0), s) if s > 0 else image
        if out is None:
            out, out_weight = level, wmap
        else:  # (w_acc acc + w level) / (w_acc + w): the weights sum to 1, so this is the running sum
            out = cv2.blendLinear(out, level, out_weight, wmap)
            out_weight = out_weight + wmap
    return out


class SpatialBlur(Effect):
    """Spatially varying Gaussian blur on a 24x18-cell grid (sec. 5.2 step 3).

    ``sigma^2 = antialias^2 + (corner_softness * |d_red - d_blue|)^2 + gap^2`` in output pixels, where
    ``|d_red - d_blue|`` is the calibrated red-blue separation and ``gap = 0.5 * max(0, s - 1)`` fills the
    spaces between motion-blur taps that are ``s`` working pixels apart.
    """

    name = "spatial_blur"
    section = "5.2 step 3"
    writes = "working"
    order = 80
    node = NodeStage("Spatial Blur", "image", "spatial_blur")
    params = {
        "antialias_sigma_px": Param(0.3, low=0.0, high=20.0, unit="px (output)"),
        "corner_softness": Param(0.5, low=0.0, high=20.0, doc="sigma per px of red-blue separation"),
        "grid": Param([24.0, 18.0], "vector", length=2, low=1, high=256, whole=True,
                       doc="cells (columns, rows)"),
    }

    def bake_node(self, state, bake) -> None:
        """One Gaussian kernel per blur level (``blur_kernel_I``, ``values["blur_levels"]``) and the weight of each
        level after the first as cv2.blendLinear mixes them in turn (``blur_mix_I``: acc = acc + t (level - acc),
        t = its weight over the running sum)."""
        g = bake.geometry
        hw, ww = g.working_shape
        sigma_grid = self.sigma_grid(state) * min(g.working_scale)
        total = np.zeros((hw, ww), np.float32)
        bake.values["blur_levels"] = []
        for i, (s, wmap) in enumerate(blur_level_maps(sigma_grid, (hw, ww))):
            total += 1.0 if wmap is None else wmap
            bake.values["blur_levels"].append(float(s))
            bake.images[f"blur_kernel_{i}"] = gaussian_blur_kernel(s) if s > 0 else np.ones((1, 1), np.float32)
            if i:
                bake.images[f"blur_mix_{i}"] = np.divide(wmap, total, out=np.zeros_like(wmap), where=total > 0)

    def sigma_grid(self, state) -> np.ndarray:
        """Blur sigma in output pixels at the grid's cell centres over the working extent."""
        g = state.geometry
        cells = tuple(int(c) for c in self.grid)
        u, v = grid_points(g.working_extent, cells)
        var = np.full(u.shape, self.antialias_sigma_px ** 2)
        if state.ca_grid is not None:
            ca = sample_texture(state.ca_grid, g.frame_extent, u, v)
            separation = np.hypot(ca[..., 0] - ca[..., 2], ca[..., 1] - ca[..., 3])
            var += (self.corner_softness * separation) ** 2
        if state.motion_tap_spacing is not None:
            spacing = sample_texture(state.motion_tap_spacing, g.working_extent, u, v)
            scale = min(g.working_scale)
            var += (0.5 * np.maximum(0.0, spacing * scale - 1.0) / scale) ** 2
        return np.sqrt(var).astype(np.float32)

    def apply(self, state):
        window = state.window("working")
        if window is not None:  # the blur of zeros is zeros
            sigma = self.sigma_grid(state) * min(state.geometry.working_scale)
            state.working = varying_gaussian(state.working, sigma, window, in_place=True)
            state.keep_window("working", grow_window(window, gaussian_reach(sigma), state.working.shape), self)


class HorizontalBlur(Effect):
    """Horizontal Gaussian blur of every sensel plane, 7 taps, sigma 0.7 sensels (sec. 4.3, 5.2 step 6).

    Applied to colour and alpha alike (it is linear), so premultiplied blending stays exact.
    """

    name = "horizontal_blur"
    section = "4.3, 5.2 step 6"
    writes = "bayer"
    order = 150
    calibration = "blur"
    node = NodeStage("Horizontal Blur", "mosaic", "kernel")
    searches = (Search("horizontal_blur", "horizontal blur sigma {sigma:.3f} sensels (profile: {was_sigma:.3f})",
                       bounds={"sigma": (0.0, 4.0)}, captures="textured", requires="horizontal_blur"),)
    params = {
        "sigma": Param(0.7, low=0.0, high=10.0, unit="sensels"),
        "taps": Param(7, int, low=1, high=31),
    }

    def check(self):
        if self.taps % 2 == 0:
            raise self.error("'taps' must be odd")

    def kernel(self) -> np.ndarray:
        return gaussian_taps(self.sigma, self.taps)

    def apply(self, state):
        filter_rows(state, self.kernel())


def filter_rows(state, kernel: np.ndarray) -> None:
    """Convolve every sensel plane's colour and alpha along rows with ``kernel``."""
    k = kernel.reshape(1, -1).astype(np.float32)
    for planes in (state.bayer, state.bayer_alpha):
        for i in range(planes.shape[0]):
            planes[i] = cv2.filter2D(planes[i], -1, k, borderType=cv2.BORDER_REPLICATE)


# --- calibration from slanted edges (sec. 4.3) ---------------------------------------------------------------------

def edge_sigma(image: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> tuple[float, float]:
    """Gaussian sigma (px) of the edge spread across the one straight edge inside the box [x0:x1, y0:y1], and
    the edge normal's angle (rad, 0 = the normal points along +x).

    Slanted-edge method: the pixels are projected on the edge normal (the dominant gradient direction, through
    the gradient-weighted centre), giving a finely sampled edge-spread function, to which
    ``A + B Phi((s - s0) / sigma)`` is fitted.
    """
    from scipy.optimize import curve_fit
    from scipy.special import ndtr

    roi = np.asarray(image, np.float64)[y0:y1, x0:x1]
    gy, gx = np.gradient(roi)
    angle = np.arctan2(np.sum(gy * np.abs(gy)), np.sum(gx * np.abs(gx)))
    # the edge normal: dominant gradient direction (sign-insensitive), refined by a line fit to the midpoints
    ys, xs = np.mgrid[0:roi.shape[0], 0:roi.shape[1]]
    g = np.hypot(gx, gy)
    strong = g > 0.3 * g.max()
    cx, cy = np.average(xs[strong], weights=g[strong]), np.average(ys[strong], weights=g[strong])
    c, s = np.cos(angle), np.sin(angle)
    dist = (xs - cx) * c + (ys - cy) * s
    order = np.argsort(dist.ravel())
    d, v = dist.ravel()[order], roi.ravel()[order]
    p0 = [v.min(), v.max() - v.min(), 0.0, 1.0]
    if v[: len(v) // 4].mean() > v[-len(v) // 4:].mean():
        p0[1] = -p0[1]

    def esf(x, a, b, s0, sigma):
        return a + b * ndtr((x - s0) / sigma)

    (a, b, s0, sigma), _ = curve_fit(esf, d, v, p0=p0, maxfev=5000)
    return float(abs(sigma)), float(angle)


def find_edges(image: np.ndarray, half_length: int = 12, half_width: int = 8):
    """Boxes around the sides of every dark or bright slanted square in a greyscale image: returns a list of
    ``(x0, y0, x1, y1, orientation)`` with orientation ``"vertical"`` or ``"horizontal"`` (the edge's)."""
    img = np.asarray(image, np.float32)
    lo, hi = np.percentile(img, 2), np.percentile(img, 98)
    binary = ((img - lo) / max(hi - lo, 1e-6) < 0.5).astype(np.uint8)
    boxes = []
    for mask in (binary, 1 - binary):
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        for cnt in contours:
            if cv2.contourArea(cnt) < (4 * half_length) ** 2:
                continue
            (cx, cy), (w, h), ang = cv2.minAreaRect(cnt)
            if min(w, h) < 4 * half_length or abs(w - h) > 0.2 * max(w, h):
                continue
            t = np.radians(ang)
            for k in range(4):
                a = t + k * np.pi / 2
                nx, ny = np.cos(a), np.sin(a)
                r = (w if k % 2 == 0 else h) / 2
                px, py = cx + nx * r, cy + ny * r
                vertical = abs(nx) > abs(ny)
                hx, hy = (half_width, half_length) if vertical else (half_length, half_width)
                x0, y0, x1, y1 = int(px - hx), int(py - hy), int(px + hx), int(py + hy)
                if x0 >= 0 and y0 >= 0 and x1 <= img.shape[1] and y1 <= img.shape[0]:
                    boxes.append((x0, y0, x1, y1, "vertical" if vertical else "horizontal"))
    return boxes


def fit_edge_blur(frames) -> dict:
    """Horizontal and vertical edge-spread sigmas (px) from frames of slanted squares, and the extra horizontal
    blur that makes them differ (sec. 4.3): ``sqrt(sigma_h^2 - sigma_v^2)``, also in sensels (half of it, since
    each Bayer channel has half the frame's resolution)."""
    grey = np.mean([np.asarray(f, np.float64).mean(axis=2) if np.ndim(f) == 3 else np.asarray(f, np.float64)
                    for f in frames], axis=0)
    per = {"vertical": [], "horizontal": []}
    for x0, y0, x1, y1, orient in find_edges(grey):
        try:
            per[orient].append(edge_sigma(grey, x0, y0, x1, y1)[0])
        except (RuntimeError, ValueError, ZeroDivisionError):  # no usable edge in that box
            continue
    if not per["vertical"] or not per["horizontal"]:
        raise ValueError("no slanted edges found in both orientations (use the chart's slanted squares)")
    sigma_h, sigma_v = float(np.median(per["vertical"])), float(np.median(per["horizontal"]))
    extra = float(np.sqrt(max(sigma_h ** 2 - sigma_v ** 2, 0.0)))
    return {"sigma_horizontal_px": sigma_h, "sigma_vertical_px": sigma_v, "extra_horizontal_px": extra,
            "extra_horizontal_sensels": extra / 2, "edges": {k: len(v) for k, v in per.items()}}


class VerticalBlur(Effect):
    """Vertical Gaussian blur of every sensel plane (sigma in sensels): blur the paper's camera did not show, as
    a candidate for others (sec. 4.3 measured only a horizontal one). It stands at its ``order`` (before the
    sharpening) or, as a second one, after the sharpening (``Profile.with_effect(..., after="demosaic")``):
    placed after the demosaic, it blurs the demosaiced frame's columns with the same Gaussian in output pixels
    (2 px per sensel, ``2 taps + 1`` taps), as a scaler or codec blurs the delivered frame."""

    name = "vertical_blur"
    section = "4.3"
    writes = "bayer"
    order = 160
    searches = (Search("vertical_blur", "edges are soft vertically as by a {sigma:.2f}-sensel Gaussian",
                       bounds={"sigma": (0.0, 3.0)}, captures="textured"),
                # the same blur acting after the sharpening, on the demosaiced frame (a scaler or codec softening
                # the delivered frame): sharpening's overshoots and the 2x2 demosaic blocks come out blurred too,
                # which a blur of the sensel planes before the sharpening cannot give
                Search("vertical_blur_after_sharpening", "edges are soft vertically as by a {sigma:.2f}-sensel "
                       "Gaussian acting on the frame after the sharpening and demosaic (a scaler or codec blur)",
                       bounds={"sigma": (0.0, 3.0)}, captures="textured", requires="sharpening",
                       after="demosaic"))
    params = {"sigma": Param(0.0, low=0.0, high=10.0, unit="sensels"), "taps": Param(7, int, low=1, high=31)}

    def apply(self, state):
        if self.sigma <= 0:
            return
        if state.rgb is not None:  # placed after the demosaic: the frame's columns, 2 px per sensel
            k = gaussian_taps(2 * self.sigma, 2 * self.taps + 1).reshape(-1, 1)
            state.rgb = cv2.filter2D(state.rgb, -1, k, borderType=cv2.BORDER_REPLICATE)
            state.rgb_alpha = cv2.filter2D(state.rgb_alpha, -1, k, borderType=cv2.BORDER_REPLICATE)
            return
        k = gaussian_taps(self.sigma, self.taps).reshape(-1, 1)
        for planes in (state.bayer, state.bayer_alpha):
            for i in range(planes.shape[0]):
                planes[i] = cv2.filter2D(planes[i], -1, k, borderType=cv2.BORDER_REPLICATE)
