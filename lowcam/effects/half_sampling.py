"""Half-sampling of the distorted image (Klein & Murray 2010, sec. 5.2 step 2).

The paper takes four bilinear taps just outside the 2x2 box (a slightly enlarged box, against aliasing); here the
exact 2x2 box is followed by the 3-tap kernel ``[e, 1 - 2e, e]`` on the half-resolution image.

Contents
--------
- :class:`HalfSampling`: 2x2 box down-sampling of the supersampled working image, slightly enlarged

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, NodeStage, Param


class HalfSampling(Effect):
    """2x2 box down-sampling of the supersampled working image, slightly enlarged to avoid aliasing.

    The paper takes four bilinear taps just outside the 2x2 box (16 source pixels). We use the exact 2x2 box
    followed by the 3-tap kernel ``[e, 1 - 2e, e]`` on the half-resolution image, ``e = box_enlargement``.
    """

    name = "half_sampling"
    section = "5.2 step 2"
    writes = "working"
    order = 30
    node = NodeStage("Half Sampling", "image", "half_sampling")
    always_runs = True
    params = {"box_enlargement": Param(0.05, low=0.0, high=0.33, doc="weight of each neighbouring tap")}

    def apply(self, state):
        h, w = state.geometry.working_shape
        state.working = cv2.resize(state.working, (w, h), interpolation=cv2.INTER_AREA)
        e = self.box_enlargement if self.enabled else 0.0
        if e > 0:
            k = np.array([e, 1 - 2 * e, e], np.float32)
            state.working = cv2.sepFilter2D(state.working, -1, k, k, borderType=cv2.BORDER_CONSTANT)
