"""Half-sampling of the distorted image (Klein & Murray 2010, sec. 5.2 step 2).

The paper takes four bilinear taps just outside the 2x2 box (a slightly enlarged box, against aliasing); here the
exact 2x2 box (taken by the lens warp) is followed by the 3-tap kernel ``[e, 1 - 2e, e]`` on the half-resolution
image.

Contents
--------
- :class:`HalfSampling`: 2x2 box down-sampling of the supersampled working image, slightly enlarged (the box is
  taken by the lens warp)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..node_images import stmap
from ..window import grow_window
from .base import Effect, NodeStage, Param


class HalfSampling(Effect):
    """2x2 box down-sampling of the supersampled working image, slightly enlarged to avoid aliasing.

    The paper takes four bilinear taps just outside the 2x2 box (16 source pixels). We use the exact 2x2 box
    followed by the 3-tap kernel ``[e, 1 - 2e, e]`` on the half-resolution image, ``e = box_enlargement``. The
    box itself is taken as the lens warp samples the supersampled grid (:class:`~lowcam.effects.lens.
    LensDistortion`), so this stage applies the kernel.
    """

    name = "half_sampling"
    section = "5.2 step 2"
    writes = "working"
    order = 30
    node = NodeStage("Half Sampling", "image", "half_sampling")
    always_runs = True
    params = {"box_enlargement": Param(0.05, low=0.0, high=0.33, doc="weight of each neighbouring tap")}

    def bake_node(self, state, bake) -> None:
        """Bilinear reads at the corner each 2x2 box shares (exact box means, ``half_uv``), then the 3x3 kernel
        ``[e, 1 - 2e, e]`` outer itself (``half_kernel``)."""
        hw, ww = bake.geometry.working_shape
        yy, xx = np.mgrid[0:hw, 0:ww].astype(np.float32)
        bake.images["half_uv"] = stmap(2 * xx + 0.5, 2 * yy + 0.5, 2 * ww, 2 * hw)
        e = self.box_enlargement if self.enabled else 0.0
        k = np.array([e, 1 - 2 * e, e], np.float32)
        bake.images["half_kernel"] = np.outer(k, k).astype(np.float32)

    def apply(self, state):
        e = self.box_enlargement if self.enabled else 0.0
        window = state.window("working")
        if e <= 0 or window is None:
            return
        k = np.array([e, 1 - 2 * e, e], np.float32)
        rows, cols = grow_window(window, 1, state.working.shape)  # the kernel of zeros is zero
        state.working[rows, cols] = cv2.sepFilter2D(state.working[rows, cols], -1, k, k,
                                                    borderType=cv2.BORDER_CONSTANT)
        state.keep_window("working", (rows, cols), self)
