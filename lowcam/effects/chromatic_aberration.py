"""Lateral chromatic aberration: per-channel sampling offsets (Klein & Murray 2010, sec. 4.1, 5.2 step 5).

Red and blue sensels sample the image through their own offset grids; green is the reference. A grid is (rows,
cols, 4) ``[red_du, red_dv, blue_du, blue_dv]`` in output pixels at the cell centres of the output frame (24x18
cells in the paper), stored as a CSV (:data:`CSV_COLUMNS`). Without a measured grid, a radial model displaces
red and blue outward by ``s (rho + cubic rho^3) / (1 + cubic)``, ``rho`` = radius / half-diagonal, ``s`` the
displacement at the corner. A lens from the lensfun database uses lensfun's own transverse-chromatic-aberration
model instead (``model = "lensfun"``, :func:`lensfun_tca_grid`): the red (blue) image is the green one scaled
radially by ``Rd = Ru (b Ru^2 + c Ru + v)`` in lensfun's normalised coordinates (lensfun 0.3.4
``ModifyCoord_TCA_Poly3``; its ``linear`` model is ``v = k``, ``b = c = 0``). The calibration measures the
offsets by Lucas-Kanade alignment of red and blue to green over patches of a noise target, as the paper does
(sec. 4.1).

Contents
--------
- :data:`CSV_COLUMNS`: the header of a grid CSV: ``u,v,red_du,red_dv,blue_du,blue_dv``
- :data:`MAX_OFFSET_PX`: the largest offset a grid may hold (output px)
- :func:`read_ca_grid`: read a chromatic-aberration grid CSV as (rows, cols, 4)
- :func:`write_ca_grid`: write a grid for an output frame of ``width`` x ``height`` in the same format
- :func:`radial_ca_grid`: a lateral-colour grid from the radial model
- :func:`lensfun_tca_offsets`: where red and blue sample relative to green under lensfun's TCA model (px)
- :func:`lensfun_tca_grid`: a dense lateral-colour grid from lensfun's TCA model
- :class:`ChromaticAberration`: red and blue sample through their own offset grids; green is the reference
- :func:`lk_shift`: Lucas-Kanade sub-pixel translation of one patch (Gauss-Newton) [Lucas1981]
- :func:`channel_shifts`: where red and blue sample relative to green around given points, by Lucas-Kanade
- :func:`fit_chromatic_aberration`: the lateral-colour grid from frames of a grey white-noise field (sec. 4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Lensfun] lensfun 0.3.4, ``libs/lensfun/mod-subpix.cpp`` (``ModifyCoord_TCA_Poly3``, ``ModifyCoord_UnTCA_Poly3``,
  ``ModifyCoord_TCA_Linear``) and ``libs/lensfun/modifier.cpp`` (normalisation), https://github.com/lensfun/lensfun.
- [Lucas1981] B. D. Lucas and T. Kanade, "An Iterative Image Registration Technique with an Application to Stereo
  Vision", IJCAI 1981, 674-679.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .. import schema
from ..errors import LowcamError
from ..geometry import grid_points
from ..outputs import atomic_write_bytes
from .base import Effect, NodeStage, Param, Search
from .lens_models import LENSFUN_FRAME_PARAMS, lensfun_frame

CSV_COLUMNS = ["u", "v", "red_du", "red_dv", "blue_du", "blue_dv"]

#: Largest red or blue offset a grid may hold (output px): the radial model's bound at the corner.
MAX_OFFSET_PX = 50.0


def read_ca_grid(path: Path) -> np.ndarray:
    """Read a chromatic-aberration grid CSV.

    Format: a header ``u,v,red_du,red_dv,blue_du,blue_dv`` and one row per grid point. ``u, v`` are the point's
    output-pixel coordinates: the cell centres of a regular partition of the output frame (24x18 cells in the
    paper), rows in scan order. ``red_du, red_dv`` say where the red sensels sample the image relative to green,
    in output pixels (positive ``du``: to the right); likewise blue. Returns an array (rows, cols, 4).

    Every value must be finite, ``u, v`` within a 16384-px frame and each offset within
    :data:`MAX_OFFSET_PX`; the points must form a full grid, each point once.
    """
    offset = (-MAX_OFFSET_PX, MAX_OFFSET_PX)
    data, lines = schema.read_number_csv(
        path, CSV_COLUMNS, "chromatic-aberration grid", min_rows=4,
        low={"u": -1.0, "v": -1.0, **{c: offset[0] for c in CSV_COLUMNS[2:]}},
        high={"u": 16384.0, "v": 16384.0, **{c: offset[1] for c in CSV_COLUMNS[2:]}})
    _, first = np.unique(data[:, :2], axis=0, return_index=True)
    if len(first) != len(data):
        twice = np.setdiff1d(np.arange(len(data)), first)[0]
        raise LowcamError(f"{path}: line {lines[twice]}: the point u={data[twice, 0]:g}, v={data[twice, 1]:g} is "
                          "listed twice")
    nu, nv = len(np.unique(data[:, 0])), len(np.unique(data[:, 1]))
    if len(data) != nu * nv or nu < 2 or nv < 2:
        raise LowcamError(f"{path}: the chromatic-aberration grid's {len(data)} points do not form a full grid "
                          f"of at least 2x2 (they have {nu} u and {nv} v values)")
    order = np.lexsort((data[:, 0], data[:, 1]))
    return data[order, 2:].reshape(nv, nu, 4)


def write_ca_grid(path: Path, grid: np.ndarray, width: int, height: int) -> None:
    """Write ``grid`` (rows, cols, 4) for an output frame of ``width`` x ``height`` in :func:`read_ca_grid`'s format."""
    rows, cols = grid.shape[:2]
    u, v = grid_points((-0.5, -0.5, width - 0.5, height - 0.5), (cols, rows))
    lines = [",".join(CSV_COLUMNS)]
    for i in range(rows):
        for j in range(cols):
            lines.append(",".join(f"{x:.6g}" for x in (u[i, j], v[i, j], *grid[i, j])))
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())


def radial_ca_grid(width, height, red_px, blue_px, cells=(24, 18), cubic=0.0) -> np.ndarray:
    """A lateral-colour grid from a radial model: displacement ``s (rho + cubic rho^3) / (1 + cubic)`` outward,
    ``rho`` = radius / half-diagonal, ``s`` = ``red_px`` or ``blue_px`` (the displacement at the corner)."""
    u, v = grid_points((-0.5, -0.5, width - 0.5, height - 0.5), cells)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    half_diag = np.hypot(width, height) / 2
    du, dv = (u - cx) / half_diag, (v - cy) / half_diag
    rho = np.hypot(du, dv)
    gain = (1 + cubic * rho**2) / (1 + cubic)
    return np.stack([red_px * du * gain, red_px * dv * gain, blue_px * du * gain, blue_px * dv * gain], -1)


def lensfun_tca_offsets(u, v, width, height, red, blue, crop_factor=1.0, calibration_crop_factor=1.0,
                        calibration_aspect_ratio=1.5, center=(0.0, 0.0)) -> np.ndarray:
    """Where red and blue sample relative to green at output pixels (``u``, ``v``) under lensfun's TCA model:
    ``(..., 4)`` ``[red_du, red_dv, blue_du, blue_dv]`` px.

    ``red`` and ``blue`` are lensfun's ``[v, c, b]`` of ``Rd = Ru (b Ru^2 + c Ru + v)``: the colour's image is
    green's scaled radially about the distortion centre, radii in lensfun's normalised unit
    (:func:`~lowcam.effects.lens_models.lensfun_frame`). A sensel at radius ``Rd`` therefore sees what green sees at
    ``Ru`` (solved by Newton's method, as lensfun's ``ModifyCoord_UnTCA_Poly3`` does when it simulates the lens).
    """
    unit, u0, v0 = lensfun_frame(width, height, crop_factor, calibration_crop_factor, calibration_aspect_ratio,
                                 center)
    x = (np.asarray(u, np.float64) - u0) / unit
    y = (np.asarray(v, np.float64) - v0) / unit
    rd = np.hypot(x, y)
    out = []
    for vv, cc, bb in (red, blue):
        ru = rd / vv
        for _ in range(30):
            step = (ru * (vv + ru * (cc + ru * bb)) - rd) / (vv + ru * (2 * cc + 3 * bb * ru))
            ru = ru - step
            if np.abs(step).max(initial=0.0) < 1e-14:
                break
        ratio = np.where(rd > 0, ru / np.where(rd > 0, rd, 1.0), 1.0 / vv) - 1.0
        out += [unit * x * ratio, unit * y * ratio]
    return np.stack(out, -1)


def lensfun_tca_grid(width, height, red, blue, crop_factor=1.0, calibration_crop_factor=1.0,
                     calibration_aspect_ratio=1.5, center=(0.0, 0.0), max_cells: int = 1024) -> np.ndarray:
    """:func:`lensfun_tca_offsets` on a dense grid over the frame (a texel per pixel, or per few pixels on frames
    wider than ``max_cells``), so the bilinear lookup at Bayer sampling reproduces the model to well under
    0.01 px."""
    step = max(1, -(-max(width, height) // max_cells))
    u, v = grid_points((-0.5, -0.5, width - 0.5, height - 0.5), (-(-width // step), -(-height // step)))
    return lensfun_tca_offsets(u, v, width, height, red, blue, crop_factor, calibration_crop_factor,
                               calibration_aspect_ratio, center)


_LENSFUN_KEYS = ("lensfun_red", "lensfun_blue", *LENSFUN_FRAME_PARAMS)
_RADIAL_KEYS = ("red_corner_px", "blue_corner_px", "cubic")


class ChromaticAberration(Effect):
    """Red and blue sensels sample the image through their own offset grids; green is the reference.

    Either ``texture`` (a CSV grid, see :func:`read_ca_grid`), or ``model = "radial"``: :func:`radial_ca_grid`
    with ``red_corner_px``, ``blue_corner_px`` and ``cubic``, or ``model = "lensfun"``: lensfun's TCA model
    (:func:`lensfun_tca_offsets`) with ``lensfun_red``, ``lensfun_blue`` and the lens's crop factors, aspect
    ratio and centre (the same keys as the lens_distortion effect's lensfun models).
    """

    name = "chromatic_aberration"
    section = "4.1, 5.2 step 5"
    writes = "sampling"
    order = 70
    calibration = "chromatic_aberration"
    node = NodeStage("Chromatic Aberration", "image", baked_into="bayer_sampling")
    searches = (Search("chromatic_aberration",
                       "red and blue sample {red_corner_px:+.2f} and {blue_corner_px:+.2f} px outward of green at "
                       "the corners",
                       bounds={"red_corner_px": (-5.0, 5.0), "blue_corner_px": (-5.0, 5.0), "cubic": (0.0, 5.0)},
                       start={"red_corner_px": 0.5, "blue_corner_px": 0.3, "cubic": 1.0}, captures="textured",
                       replace=True, evals=45),)
    params = {
        "texture": Param("", "path", doc="CSV grid; empty: use the radial model"),
        "red_corner_px": Param(0.0, low=-MAX_OFFSET_PX, high=MAX_OFFSET_PX, unit="px",
                               doc="outward shift of red at the corner"),
        "blue_corner_px": Param(0.0, low=-MAX_OFFSET_PX, high=MAX_OFFSET_PX, unit="px",
                                doc="outward shift of blue at the corner"),
        "cubic": Param(0.0, low=0.0, high=100.0, doc="weight of the rho^3 term of the radial model"),
        "model": Param("radial", str, choices=("radial", "lensfun"), doc="without a texture: the model"),
        "lensfun_red": Param([1.0, 0.0, 0.0], "vector", length=3, low=-10.0, high=10.0,
                             doc="lensfun TCA of red: [v, c, b] of Rd = Ru (b Ru^2 + c Ru + v)"),
        "lensfun_blue": Param([1.0, 0.0, 0.0], "vector", length=3, low=-10.0, high=10.0,
                              doc="lensfun TCA of blue: [v, c, b]"),
        **LENSFUN_FRAME_PARAMS,
    }

    def values(self):
        drop = _RADIAL_KEYS if self.model == "lensfun" else _LENSFUN_KEYS
        return {k: v for k, v in super().values().items() if k not in drop}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        try:
            self._grid = read_ca_grid(self.texture) if self.texture else None
        except LowcamError as e:  # name the profile and the key too
            raise self.error(f"'texture': {e}") from None

    def check(self):
        if self.model == "lensfun" and not self.texture:
            for colour in ("red", "blue"):
                v = getattr(self, f"lensfun_{colour}")[0]
                if not 0.5 <= v <= 2.0:
                    raise self.error(f"lensfun_{colour}: the scale v = {v:g} must lie in 0.5..2 (lensfun TCA "
                                     "terms are [v, c, b] with v close to 1)")

    def grid(self, width: int, height: int) -> np.ndarray:
        """(rows, cols, 4) offsets [red_du, red_dv, blue_du, blue_dv] over the output frame."""
        if self._grid is not None:
            return self._grid
        if self.model == "lensfun":
            key = (width, height, repr(self.values()))
            if getattr(self, "_dense", (None,))[0] != key:
                self._dense = (key, lensfun_tca_grid(
                    width, height, self.lensfun_red, self.lensfun_blue, self.crop_factor,
                    self.calibration_crop_factor, self.calibration_aspect_ratio, tuple(self.lensfun_center)))
            return self._dense[1]
        return radial_ca_grid(width, height, self.red_corner_px, self.blue_corner_px, cubic=self.cubic)

    def apply(self, state):
        g = state.geometry
        state.ca_grid = self.grid(g.width, g.height).astype(np.float32)


def lk_shift(ref: np.ndarray, grad_x: np.ndarray, grad_y: np.ndarray, moving: np.ndarray, centre, size: int,
             iterations: int = 30) -> tuple[float, float]:
    """Lucas-Kanade translation ``d`` such that ``moving(p) ~ ref(p + d)`` over a ``size`` x ``size`` patch at
    ``centre`` (Gauss-Newton on bilinearly resampled ``ref``, sub-pixel)."""
    cx, cy = centre
    half = (size - 1) / 2
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32)
    xs += np.float32(cx - half)
    ys += np.float32(cy - half)
    target = cv2.remap(moving, xs, ys, cv2.INTER_LINEAR)
    d = np.zeros(2)
    for _ in range(iterations):
        mx, my = xs + np.float32(d[0]), ys + np.float32(d[1])
        r = cv2.remap(ref, mx, my, cv2.INTER_LINEAR) - target
        gx = cv2.remap(grad_x, mx, my, cv2.INTER_LINEAR)
        gy = cv2.remap(grad_y, mx, my, cv2.INTER_LINEAR)
        a = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]], np.float64)
        if np.linalg.cond(a) > 1e8:
            return float("nan"), float("nan")
        step = -np.linalg.solve(a, [np.sum(gx * r), np.sum(gy * r)])
        d += step
        if np.hypot(*step) < 1e-4:
            break
    return float(d[0]), float(d[1])


def channel_shifts(frame: np.ndarray, u: np.ndarray, v: np.ndarray, patch: int = 30) -> np.ndarray:
    """Where red and blue sample relative to green around each point (``u``, ``v``) of an (H, W, 3) ``frame``:
    ``(..., 4)`` ``[red_du, red_dv, blue_du, blue_dv]`` in pixels by Lucas-Kanade over ``patch`` x ``patch``
    patches (NaN where the patch has too little texture)."""
    frame = np.asarray(frame, np.float32)
    green = np.ascontiguousarray(frame[..., 1])
    gx = cv2.Sobel(green, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
    gy = cv2.Sobel(green, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
    out = np.zeros(np.shape(u) + (4,))
    for c, col in ((0, 0), (2, 2)):
        moving = np.ascontiguousarray(frame[..., c])
        for index in np.ndindex(np.shape(u)):
            out[index + (slice(col, col + 2),)] = lk_shift(green, gx, gy, moving, (u[index], v[index]), patch)
    return out


def fit_chromatic_aberration(frames, cells=(24, 18), patch: int = 30, smooth_cells: float = 0.7) -> np.ndarray:
    """The lateral-colour grid from frames of a grey white-noise field (sec. 4.1).

    In every cell of a ``cells`` grid, a ``patch`` x ``patch`` patch of red and of blue is aligned to green by
    Lucas-Kanade; the shifts are averaged over frames, smoothed with a Gaussian of ``smooth_cells`` cells, and
    returned as (rows, cols, 4) ``[red_du, red_dv, blue_du, blue_dv]`` in :func:`read_ca_grid`'s convention
    (where red/blue sample relative to green). Frames are (H, W, 3) RGB.
    """
    frames = [np.asarray(f, np.float32) for f in frames]
    h, w = frames[0].shape[:2]
    u, v = grid_points((-0.5, -0.5, w - 0.5, h - 0.5), cells)
    margin = patch / 2 + 2
    uc, vc = np.clip(u, margin, w - 1 - margin), np.clip(v, margin, h - 1 - margin)
    grid = np.nanmean([channel_shifts(frame, uc, vc, patch) for frame in frames], axis=0)
    if np.isnan(grid).any():
        raise ValueError("the frames have too little texture to align the colour channels (use the noise field)")
    if smooth_cells > 0:
        grid = cv2.GaussianBlur(grid.astype(np.float32), (0, 0), smooth_cells, borderType=cv2.BORDER_REPLICATE)
    return grid.astype(np.float32)
