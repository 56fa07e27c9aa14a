"""Defocus: a uniform disc blur of the optical image (paper sec. 2 and 3 set it aside for fixed-focus lenses).

Contents
--------
- :func:`disc_kernel`: a normalised, anti-aliased pillbox of ``radius_px``
- :class:`Defocus`: out-of-focus blur: the working image convolved with a disc of ``radius_px`` output pixels

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param, Search


def disc_kernel(radius_px: float) -> np.ndarray:
    """A normalised, anti-aliased pillbox of ``radius_px``."""
    r = int(np.ceil(radius_px)) + 1
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    k = np.clip(radius_px + 0.5 - np.hypot(x, y), 0.0, 1.0).astype(np.float32)
    return k / k.sum()


class Defocus(Effect):
    """Out-of-focus blur: the working image convolved with a disc of ``radius_px`` output pixels."""

    name = "defocus"
    section = "2-3 (defocus; not simulated in the paper)"
    writes = "working"
    order = 90
    searches = (Search("defocus", "everything is blurred as by a {radius_px:.2f} px defocus disc",
                       bounds={"radius_px": (0.0, 8.0)}, captures="textured"),)
    params = {"radius_px": Param(0.0, low=0.0, high=30.0, unit="px (output)")}

    def apply(self, state):
        if self.radius_px <= 0:
            return
        radius = self.radius_px * min(state.geometry.working_scale)
        state.working = cv2.filter2D(state.working, -1, disc_kernel(radius), borderType=cv2.BORDER_CONSTANT)
