"""Blending into a raw Bayer frame (Klein & Murray 2010, sec. 7: the IDS uEye pipeline)."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param


class RawBlend(Effect):
    """Blends each sensel plane directly into the camera's own Bayer pixels, then quantises to the raw bit depth.

    The plate is the camera's raw frame (one channel); an RGB plate is sampled through the mosaic. After this
    stage the planes hold the whole raw frame (alpha 1), ready for demosaicing. Sensels that no graphics touch
    keep the plate's values exactly.
    """

    name = "raw_blend"
    section = "7"
    writes = "bayer"
    always_runs = True
    params = {"bits": Param(8, int, low=1, high=16, doc="raw bit depth, scaled to 8-bit DN")}

    def apply(self, state):
        from .bayer import unmosaic

        plate = unmosaic(state.plate_raw, state.geometry)
        step = 256.0 / 2 ** self.bits
        covered = state.bayer_alpha != 0
        blended = plate * (1 - state.bayer_alpha) + state.bayer
        blended = np.clip(np.round(blended / step) * step, 0.0, 255.0)
        state.bayer = np.where(covered, blended, plate).astype(np.float32)
        state.bayer_alpha = np.ones_like(state.bayer_alpha)
        state.raw_touched = covered
