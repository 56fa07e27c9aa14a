"""Vignetting: multiplicative fall-off of the rendered light towards the corners (Klein & Murray 2010, sec. 4.1).

Each sensel's colour (not its alpha) is multiplied by a gain texture over the output frame (80x60 in the paper,
Fig. 2; brightest texel = 1) at Bayer sampling (sec. 5.2 step 5). Without a measured texture, a radial model
``1 + k2 rho^2 + k4 rho^4`` (rho = radius / half-diagonal) is used; a lens from the lensfun database uses
lensfun's ``pa`` model ``1 + k1 r^2 + k2 r^4 + k3 r^6`` (``model = "lensfun_pa"``, :func:`lensfun_vignetting`),
evaluated at every sensel. The calibration averages flat fields, blurs
away sensor and target irregularities, subsamples and normalises, as the paper does (sec. 4.1).

Contents
--------
- :func:`radial_vignetting`: gain map ``1 + k2 rho^2 + k4 rho^4`` over a (rows, cols) texture, maximum 1
- :func:`lensfun_vignetting`: lensfun's ``pa`` vignetting gain at output pixels
- :class:`Vignetting`: multiplies each sensel's colour (not its alpha) by a gain texture, brightest = 1 (sec. 4.1)
- :data:`GAINS_KEPT`: how many sets of sensel gains the process keeps
- :func:`fit_vignetting`: the gain texture from flat-field frames (sec. 4.1)
- :func:`vignetting_statistic`: the radial fall-off of a moving shot (the same scene points at different radii)
- :func:`vignetting_from_plate`: k2, k4 of the radial model from a moving shot (a PlateEstimate)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Lensfun] lensfun 0.3.4, ``libs/lensfun/mod-color.cpp`` (``AddColorCallbackVignetting``,
  ``ModifyColor_Vignetting_PA``: ``r`` = normalised radius / sqrt(1 + aspect^2), 1 at the calibration sensor's
  corner), https://github.com/lensfun/lensfun.
- [Goldman2010] D. B. Goldman, "Vignette and Exposure Calibration and Compensation", IEEE TPAMI 32(12),
  2276-2288, 2010 (the same scene points seen at different image positions).
"""
from __future__ import annotations

import threading
from collections import OrderedDict

import cv2
import numpy as np

from ..errors import LowcamError
from ..geometry import sample_texture
from ..io import read_gain_map
from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, NodeStage, Param, Search
from .lens_models import LENSFUN_FRAME_PARAMS, lensfun_frame


def radial_vignetting(width: int, height: int, k2: float, k4: float, shape=(60, 80)) -> np.ndarray:
    """Gain map ``1 + k2 rho^2 + k4 rho^4`` (rho = radius / half-diagonal) at the cell centres of a ``shape``
    (rows, cols) texture over the frame, normalised to a maximum of 1."""
    rows, cols = shape
    u = (np.arange(cols) + 0.5) * width / cols - 0.5
    v = (np.arange(rows) + 0.5) * height / rows - 0.5
    uu, vv = np.meshgrid(u, v)
    rho2 = ((uu - (width - 1) / 2) ** 2 + (vv - (height - 1) / 2) ** 2) / (np.hypot(width, height) / 2) ** 2
    gain = np.clip(1 + k2 * rho2 + k4 * rho2**2, 0.0, None)
    return (gain / gain.max()).astype(np.float32)


def lensfun_vignetting(u, v, width, height, terms, crop_factor=1.0, calibration_crop_factor=1.0,
                       calibration_aspect_ratio=1.5, center=(0.0, 0.0)) -> np.ndarray:
    """Lensfun's ``pa`` vignetting ``1 + k1 r^2 + k2 r^4 + k3 r^6`` (``terms`` = [k1, k2, k3]) at output pixels
    (``u``, ``v``) of a ``width`` x ``height`` frame; ``r`` is lensfun's normalised radius
    (:func:`~lowcam.effects.lens_models.lensfun_frame`) over ``sqrt(1 + calibration_aspect_ratio^2)``: 1 at the corner
    of the calibration sensor. The gain is 1 at the centre, not renormalised (lensfun's own convention)."""
    unit, u0, v0 = lensfun_frame(width, height, crop_factor, calibration_crop_factor, calibration_aspect_ratio,
                                 center)
    scale = unit * np.sqrt(1.0 + calibration_aspect_ratio ** 2)
    r2 = ((np.asarray(u, np.float64) - u0) ** 2 + (np.asarray(v, np.float64) - v0) ** 2) / scale ** 2
    k1, k2, k3 = terms
    return np.clip(1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)), 0.0, None)


_LENSFUN_KEYS = ("lensfun_terms", *LENSFUN_FRAME_PARAMS)

#: Sets of sensel gains kept, shared by every copy of a profile (each frame of a shot and every simulation of a fit
#: asks for the same ones): (geometry, values, texture bytes) -> read-only (4, hb, wb) planes.
GAINS_KEPT = 8
_KEPT_GAINS: OrderedDict = OrderedDict()
_KEPT_LOCK = threading.Lock()


class Vignetting(Effect):
    """Multiplies each sensel's colour (not its alpha) by a gain texture, brightest = 1 (sec. 4.1).

    ``texture``: a greyscale PNG (80x60 in the paper; 16-bit recommended) covering the output frame, gain =
    value / maximum code value, normalised so the brightest texel is 1. Without a texture the radial model of
    :func:`radial_vignetting` with ``k2`` and ``k4`` is used, or with ``model = "lensfun_pa"`` lensfun's model
    (:func:`lensfun_vignetting`) evaluated at every sensel, with ``lensfun_terms`` and the lens's crop factors,
    aspect ratio and centre (the keys of the lens_distortion effect's lensfun models).
    """

    name = "vignetting"
    section = "4.1, 5.2 step 5"
    writes = "bayer"
    order = 120
    calibration = "vignetting"
    node = NodeStage("Vignetting", "mosaic", "gain")
    searches = (Search("vignetting", "radial fall-off k2 = {k2:.3f}, k4 = {k4:.3f}",
                       bounds={"k2": (-1.0, 0.5), "k4": (-1.0, 1.0)}, start={"k2": -0.2, "k4": 0.0}, replace=True,
                       evals=30, reach={"k2": 0.5, "k4": 0.8}),)
    params = {
        "texture": Param("", "path", doc="greyscale PNG gain map; empty: radial model"),
        "k2": Param(0.0, low=-10.0, high=10.0),
        "k4": Param(0.0, low=-10.0, high=10.0),
        "model": Param("radial", str, choices=("radial", "lensfun_pa"), doc="without a texture: the model"),
        "lensfun_terms": Param([0.0, 0.0, 0.0], "vector", length=3, low=-50.0, high=50.0,
                               doc="lensfun pa model: [k1, k2, k3] of 1 + k1 r^2 + k2 r^4 + k3 r^6 (lensfun's "
                                   "fisheyes reach 27)"),
        **LENSFUN_FRAME_PARAMS,
    }

    def values(self):
        drop = ("k2", "k4") if self.model == "lensfun_pa" else _LENSFUN_KEYS
        return {k: v for k, v in super().values().items() if k not in drop}

    def _lensfun_gain(self, u, v, width, height):
        return lensfun_vignetting(u, v, width, height, self.lensfun_terms, self.crop_factor,
                                  self.calibration_crop_factor, self.calibration_aspect_ratio,
                                  tuple(self.lensfun_center))

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._texture = None
        if self.texture:
            try:
                self._texture = read_gain_map(self.texture)
            except LowcamError as e:
                raise self.error(f"texture: {e}") from None

    def implausible(self) -> list[str]:
        """A radial fall-off that rises away from the centre (more than 2 %: a lens does not gather more light
        off-axis), or leaves the corners almost dark (below 5 % of the centre)."""
        if self._texture is not None or self.model != "radial":
            return []
        rho2 = np.linspace(0.0, 1.0, 101) ** 2
        gain = 1 + self.k2 * rho2 + self.k4 * rho2 ** 2
        out = [f"a fall-off that rises {100 * (gain.max() - 1):.0f} % away from the centre"] if gain.max() > 1.02 \
            else []
        if gain.min() < 0.05:
            out.append(f"corners at {max(gain.min(), 0.0):.2f} of the centre's light")
        return out

    def gain_texture(self, width: int, height: int) -> np.ndarray:
        if self._texture is not None:
            return self._texture
        if self.model == "lensfun_pa":  # for display and export; the stage itself evaluates every sensel
            rows, cols = 60, 80
            u = (np.arange(cols) + 0.5) * width / cols - 0.5
            v = (np.arange(rows) + 0.5) * height / rows - 0.5
            uu, vv = np.meshgrid(u, v)
            return self._lensfun_gain(uu, vv, width, height).astype(np.float32)
        return radial_vignetting(width, height, self.k2, self.k4)

    def gain_planes(self, geometry) -> np.ndarray:
        """The gain of every sensel, (4, hb, wb) like the sensel planes (the node group bakes the same); read-only,
        kept for the next call with the same geometry and values (:data:`GAINS_KEPT`)."""
        key = (geometry, repr(self.values()), None if self._texture is None else self._texture.tobytes())
        with _KEPT_LOCK:
            planes = _KEPT_GAINS.get(key)
            if planes is not None:
                _KEPT_GAINS.move_to_end(key)
                return planes
        planes = self._gain_planes(geometry)
        planes.flags.writeable = False
        with _KEPT_LOCK:
            _KEPT_GAINS[key] = planes
            while len(_KEPT_GAINS) > GAINS_KEPT:
                _KEPT_GAINS.popitem(last=False)
        return planes

    def _gain_planes(self, geometry) -> np.ndarray:
        pos = geometry.sensel_positions
        if self._texture is None and self.model == "lensfun_pa":
            return self._lensfun_gain(pos[..., 0], pos[..., 1], geometry.width, geometry.height).astype(np.float32)
        return sample_texture(self.gain_texture(geometry.width, geometry.height), geometry.frame_extent,
                              pos[..., 0], pos[..., 1]).astype(np.float32)

    def apply(self, state):
        state.bayer *= self.gain_planes(state.geometry)


def fit_vignetting(frames, shape=(60, 80), blur_fraction: float = 1 / 40) -> np.ndarray:
    """The gain texture from flat-field frames (sec. 4.1): average them, blur away sensor and target
    irregularities (Gaussian, sigma = ``blur_fraction`` of the frame width), subsample to ``shape`` (rows, cols)
    and normalise the brightest texel to 1. Colour frames are averaged over their channels."""
    mean = np.mean([np.asarray(f, np.float32) for f in frames], axis=0)
    if mean.ndim == 3:
        mean = mean.mean(axis=2)
    blurred = cv2.GaussianBlur(mean, (0, 0), blur_fraction * mean.shape[1])
    small = cv2.resize(blurred, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return (small / small.max()).astype(np.float32)


def _rho2(x, y, width: int, height: int):
    """Squared radius over the squared half-diagonal, as :func:`radial_vignetting` measures it."""
    return ((x - (width - 1) / 2) ** 2 + (y - (height - 1) / 2) ** 2) / (np.hypot(width, height) / 2) ** 2


def vignetting_statistic(frames, max_pairs: int = 30, min_shift_px: float = 1.5) -> dict:
    """The radial fall-off of a moving shot (T, H, W, 3) float32 DN, from the same scene points seen at
    different radii [Goldman2010].

    Each pair of consecutive frames is registered by a global translation (OpenCV's phase correlation); pairs
    moving at least ``min_shift_px`` give, at smooth, unclipped points on a 4-px grid, ``log I_b(x + d) - log
    I_a(x) = log V(x + d) - log V(x) + e`` (``e``: the pair's exposure change). With ``log V = c2 rho^2 + c4
    rho^4`` (rho = radius / half-diagonal) this is linear in ``c2``, ``c4`` and the ``e``s: solved by least
    squares, twice dropping points beyond 3 robust deviations (parallax, moving objects). Returns ``{}`` when no
    pair moves; else the pairs used, the total shift (px), ``c2``, ``c4``, ``k2``, ``k4`` of the radial model
    ``1 + k2 rho^2 + k4 rho^4`` closest to ``exp(c2 rho^2 + c4 rho^4)``, the gain at rho = 0.5, 0.8 and 1 and the
    corner gain's standard error."""
    x = np.asarray(frames, np.float32)
    grey = [cv2.GaussianBlur(f.mean(axis=2) if f.ndim == 3 else f, (0, 0), 1.5) for f in x]
    h, w = grey[0].shape
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    rows, cols, values, total, pairs = [], [], [], 0.0, 0
    step = 4
    for i in range(min(len(grey) - 1, max_pairs)):
        a, b = grey[i], grey[i + 1]
        (dx, dy), response = cv2.phaseCorrelate(a.copy(), b.copy(), window)  # it may window its inputs in place
        if np.hypot(dx, dy) < min_shift_px or response < 0.05:
            continue
        m = int(np.ceil(max(abs(dx), abs(dy)))) + 4
        yy, xx = np.mgrid[m:h - m:step, m:w - m:step].astype(np.float32)
        va = a[yy.astype(int), xx.astype(int)]
        vb = cv2.remap(b, xx + np.float32(dx), yy + np.float32(dy), cv2.INTER_LINEAR)
        gy, gx = np.gradient(a)
        grad = np.hypot(gx, gy)[yy.astype(int), xx.astype(int)]
        ok = (va > 15) & (va < 235) & (vb > 15) & (vb < 235) & (grad < 0.01 * va + 0.5)
        if ok.sum() < 50:
            continue
        r0 = _rho2(xx[ok], yy[ok], w, h)
        r1 = _rho2(xx[ok] + dx, yy[ok] + dy, w, h)
        rows.append(np.column_stack([r1 - r0, r1 ** 2 - r0 ** 2]))
        cols.append(np.full(ok.sum(), pairs))
        values.append(np.log(vb[ok]) - np.log(va[ok]))
        total += float(np.hypot(dx, dy))
        pairs += 1
    if pairs == 0:
        return {}
    radial = np.concatenate(rows)
    pair = np.concatenate(cols)
    y = np.concatenate(values)
    design = np.column_stack([radial, np.eye(pairs)[pair]])
    keep = np.ones(len(y), bool)
    for _ in range(3):
        sol, *_ = np.linalg.lstsq(design[keep], y[keep], rcond=None)
        res = y - design @ sol
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res) <= 3 * max(mad, 1e-4)
    c2, c4 = float(sol[0]), float(sol[1])
    # standard error of log V(1) = c2 + c4 from the least-squares covariance
    dk = design[keep]
    s2 = float(np.sum((y[keep] - dk @ sol) ** 2) / max(keep.sum() - dk.shape[1], 1))
    try:
        cov = s2 * np.linalg.inv(dk.T @ dk)[:2, :2]
        se = float(np.sqrt(max(cov[0, 0] + cov[1, 1] + 2 * cov[0, 1], 0.0)))
    except np.linalg.LinAlgError:
        se = float("inf")
    r2 = np.linspace(0.0, 1.0, 50)
    k2, k4 = np.linalg.lstsq(np.column_stack([r2, r2 ** 2]), np.exp(c2 * r2 + c4 * r2 ** 2) - 1, rcond=None)[0]
    gain = {str(r): float(np.exp(c2 * r ** 2 + c4 * r ** 4)) for r in (0.5, 0.8, 1.0)}
    return {"pairs": pairs, "shift_px_total": total, "points": int(keep.sum()), "c2": c2, "c4": c4,
            "k2": float(k2), "k4": float(k4), "gain_at_rho": gain, "corner_gain_se": float(np.exp(c2 + c4) * se)}


def vignetting_from_plate(footage, base=None, film=None):
    """k2, k4 of the radial vignetting model from a moving shot, as a :class:`lowcam.plate_estimate.PlateEstimate`
    (:func:`vignetting_statistic`; a measured ``texture`` in the base is replaced by the radial model).

    Confidence: 0.9, scaled by how far the camera moved (a tenth of the frame diagonal in all: full) and halved
    when the corner gain's standard error exceeds 0.02; a shot in which the camera hardly moves gives none, and
    neither do corners found brighter than the centre (beyond 2 %: a lens does not brighten its corners; exposure
    changes or moving scene content do)."""
    frames = footage.stack(max_frames=31)
    stat = vignetting_statistic(frames)
    if not stat:
        return PlateEstimate.not_measurable("radial_falloff", "vignetting", {},
                                            "the camera hardly moves: vignetting needs a moving shot")
    h, w = footage.shape
    coverage = min(1.0, stat["shift_px_total"] / (0.1 * np.hypot(w, h)))
    confidence = 0.9 * coverage * (1.0 if stat["corner_gain_se"] < 0.02 else 0.5)
    params = {"k2": stat["k2"], "k4": stat["k4"], "texture": ""}
    if stat["gain_at_rho"]["1.0"] > 1.02:
        return PlateEstimate("radial_falloff", "vignetting", stat, {}, 0.0,
                             f"corners {stat['gain_at_rho']['1.0']:.3f} x as bright as the centre: not a lens "
                             f"fall-off (exposure changes or moving scene content)")
    return PlateEstimate("radial_falloff", "vignetting", stat, params, round(confidence, 3),
                         f"{stat['pairs']} moving frame pairs, {stat['shift_px_total']:.0f} px of motion, corner "
                         f"gain {stat['gain_at_rho']['1.0']:.3f} +- {stat['corner_gain_se']:.3f}")


#: Declared after its estimator and statistic, which the module defines below the class.
Vignetting.plate_probe = PlateProbe("radial_falloff", vignetting_from_plate, vignetting_statistic, order=50,
                                      about="brightness of the same scene points at different radii over a moving "
                                            "shot")
