"""Blending into a raw Bayer frame (Klein & Murray 2010, sec. 7: the IDS uEye pipeline).

For raw-Bayer cameras the chain stops after Bayer sampling (sec. 5.2 step 5): each rendered sensel plane is
blended with the camera's own Bayer pixels, and the frame is then demosaiced bilinearly (sec. 7). Sensels that
no graphics touch keep the plate's values exactly.

Contents
--------
- :class:`RawBlend`: blends each sensel plane into the camera's own Bayer pixels, then quantises to the raw depth

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param
from .bayer import mosaic, unmosaic


class RawBlend(Effect):
    """Blends each sensel plane directly into the camera's own Bayer pixels, then quantises to the raw bit depth.

    The plate is the camera's raw frame (one channel); an RGB plate is sampled through the mosaic. After this
    stage the planes hold the whole raw frame (alpha 1), ready for demosaicing. Sensels that no graphics touch
    keep the plate's values exactly.
    """

    name = "raw_blend"
    section = "7"
    writes = "bayer"
    order = 190
    always_runs = True
    params = {"bits": Param(8, int, low=1, high=16, doc="raw bit depth, scaled to 8-bit DN")}

    def apply(self, state):
        plate = unmosaic(state.plate_raw, state.geometry)
        step = 256.0 / 2 ** self.bits
        covered = state.bayer_alpha != 0
        blended = plate * (1 - state.bayer_alpha) + state.bayer
        blended = np.clip(np.round(blended / step) * step, 0.0, 255.0)
        state.bayer = np.where(covered, blended, plate).astype(np.float32)
        state.bayer_alpha = np.ones_like(state.bayer_alpha)
        state.raw_touched = covered

    def finish(self, state, frame, footprint):
        """The frame is the demosaiced raw frame itself; the footprint is the touched sensels' pixels and their
        demosaicing neighbours."""
        touched = mosaic(state.raw_touched, state.geometry).astype(np.uint8)
        rgb = np.rint(np.clip(state.rgb, 0, 255)).astype(np.uint8)
        return rgb, cv2.dilate(touched, np.ones((3, 3), np.uint8)).astype(bool)
