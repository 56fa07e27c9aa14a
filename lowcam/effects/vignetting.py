"""Vignetting: multiplicative fall-off of the rendered light towards the corners (Klein & Murray 2010, sec. 4.1).

Each sensel's colour (not its alpha) is multiplied by a gain texture over the output frame (80x60 in the paper,
Fig. 2; brightest texel = 1) at Bayer sampling (sec. 5.2 step 5). Without a measured texture, a radial model
``1 + k2 rho^2 + k4 rho^4`` (rho = radius / half-diagonal) is used. The calibration averages flat fields, blurs
away sensor and target irregularities, subsamples and normalises, as the paper does (sec. 4.1).

Contents
--------
- :func:`radial_vignetting`: gain map ``1 + k2 rho^2 + k4 rho^4`` over a (rows, cols) texture, maximum 1
- :class:`Vignetting`: multiplies each sensel's colour (not its alpha) by a gain texture, brightest = 1 (sec. 4.1)
- :func:`fit_vignetting`: the gain texture from flat-field frames (sec. 4.1)
- :func:`vignetting_statistic`: the radial fall-off of a moving shot (the same scene points at different radii)
- :func:`vignetting_from_plate`: k2, k4 of the radial model from a moving shot (a PlateEstimate)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import numpy as np

from ..geometry import sample_texture
from .base import Effect, NodeStage, Param, Search


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


class Vignetting(Effect):
    """Multiplies each sensel's colour (not its alpha) by a gain texture, brightest = 1 (sec. 4.1).

    ``texture``: a greyscale PNG (80x60 in the paper; 16-bit recommended) covering the output frame, gain =
    value / maximum code value, normalised so the brightest texel is 1. Without a texture the radial model of
    :func:`radial_vignetting` with ``k2`` and ``k4`` is used.
    """

    name = "vignetting"
    section = "4.1, 5.2 step 5"
    writes = "bayer"
    order = 120
    calibration = "vignetting"
    node = NodeStage("Vignetting", "mosaic", "gain")
    searches = (Search("vignetting", "radial fall-off k2 = {k2:.3f}, k4 = {k4:.3f}",
                       bounds={"k2": (-1.0, 0.5), "k4": (-1.0, 1.0)}, start={"k2": -0.2, "k4": 0.0}, replace=True,
                       evals=30),)
    params = {
        "texture": Param("", "path", doc="greyscale PNG gain map; empty: radial model"),
        "k2": Param(0.0, low=-10.0, high=10.0),
        "k4": Param(0.0, low=-10.0, high=10.0),
    }

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._texture = None
        if self.texture:
            from ..errors import LowcamError
            from ..io import read_gain_map

            try:
                self._texture = read_gain_map(self.texture)
            except LowcamError as e:
                raise self.error(f"texture: {e}") from None

    def gain_texture(self, width: int, height: int) -> np.ndarray:
        if self._texture is not None:
            return self._texture
        return radial_vignetting(width, height, self.k2, self.k4)

    def gain_planes(self, geometry) -> np.ndarray:
        """The gain of every sensel, (4, hb, wb) like the sensel planes (the node group bakes the same)."""
        pos = geometry.sensel_positions
        return sample_texture(self.gain_texture(geometry.width, geometry.height), geometry.frame_extent,
                              pos[..., 0], pos[..., 1]).astype(np.float32)

    def apply(self, state):
        state.bayer *= self.gain_planes(state.geometry)


def fit_vignetting(frames, shape=(60, 80), blur_fraction: float = 1 / 40) -> np.ndarray:
    """The gain texture from flat-field frames (sec. 4.1): average them, blur away sensor and target
    irregularities (Gaussian, sigma = ``blur_fraction`` of the frame width), subsample to ``shape`` (rows, cols)
    and normalise the brightest texel to 1. Colour frames are averaged over their channels."""
    import cv2

    mean = np.mean([np.asarray(f, np.float32) for f in frames], axis=0)
    if mean.ndim == 3:
        mean = mean.mean(axis=2)
    blurred = cv2.GaussianBlur(mean, (0, 0), blur_fraction * mean.shape[1])
    small = cv2.resize(blurred, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return (small / small.max()).astype(np.float32)


def vignetting_statistic(frames) -> dict:
    """The radial fall-off (k2, k4) of a moving shot (T, H, W, 3) float32 DN."""
    raise NotImplementedError


def vignetting_from_plate(footage, base=None):
    """k2, k4 of the radial vignetting model from a moving shot, as a PlateEstimate."""
    raise NotImplementedError
