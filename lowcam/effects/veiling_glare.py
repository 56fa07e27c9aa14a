"""Veiling glare: light scattered inside the lens spreads a faint haze around bright areas (sec. 3: flare).

The haze is ``strength`` times a wide Gaussian blur (``radius_px`` output pixels) of the light, added to the light.
It reaches beyond the graphics' edges: colour without alpha, so it adds to the plate there.

Contents
--------
- :class:`VeilingGlare`: adds ``strength`` times a wide Gaussian blur (``radius_px``) of the light to the light

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param, Search


class VeilingGlare(Effect):
    """Adds ``strength`` times a wide Gaussian blur (``radius_px`` output pixels) of the light to the light; the
    haze reaches beyond the graphics' edges (colour without alpha: it adds to the plate there)."""

    name = "veiling_glare"
    section = "3 (flare)"
    writes = "working"
    order = 100
    searches = (Search("veiling_glare", "a haze of {strength:.3f} of the light, spread over {radius_px:.0f} px",
                       bounds={"strength": (0.0, 0.5), "radius_px": (5.0, 300.0)},
                       start={"strength": 0.05, "radius_px": 40.0}, captures="textured", evals=30),)
    params = {"strength": Param(0.0, low=0.0, high=1.0), "radius_px": Param(40.0, low=1.0, high=500.0)}

    def apply(self, state):
        if self.strength <= 0:
            return
        sigma = self.radius_px * min(state.geometry.working_scale)
        small = cv2.resize(state.working[..., :3], None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
        haze = cv2.GaussianBlur(small, (0, 0), sigma / 4)
        haze = cv2.resize(haze, state.working.shape[1::-1], interpolation=cv2.INTER_LINEAR)
        state.working[..., :3] += np.float32(self.strength) * haze
