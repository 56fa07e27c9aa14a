"""Quantisation of the sensel values to the camera's bit depth (Klein & Murray 2010, sec. 4.3, 5.2 step 7).

The Fire-i's output shows 6-bit levels (steps of 4 DN) although its ADC has 10 bits. As on the paper's GPU
(divide by 4, add 128, store in 8 bits), values keep their sign, so sharpening undershoot survives until
blending.

Contents
--------
- :class:`Quantisation`: rounds each sensel's premultiplied value to ``bits`` of 8-bit range (sec. 4.3, 5.2 step 7)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import numpy as np

from .base import Effect, NodeStage, Param, Search


class Quantisation(Effect):
    """Rounds each sensel's premultiplied value to ``bits`` of 8-bit range (sec. 4.3, 5.2 step 7).

    The Fire-i's 6 bits means steps of 4 DN. As on the paper's GPU (divide by 4, add 128, store in 8 bits),
    values keep their sign, so sharpening undershoot survives until blending; they are clipped to
    ``[-255, 510]`` DN.
    """

    name = "quantisation"
    stepped = True
    section = "4.3, 5.2 step 7"
    writes = "bayer"
    order = 180
    node = NodeStage("Quantisation", "mosaic", "quantisation")
    searches = (Search("quantisation_bits", "levels come in {bits} bits", grid={"bits": (4, 5, 6, 7, 8)},
                       full_error=True, requires="quantisation"),)
    params = {"bits": Param(6, int, low=1, high=16)}

    def bake_node(self, state, bake) -> None:
        bake.values["quantisation_step_dn"] = self.step_dn()

    def step_dn(self) -> float:
        return 256.0 / 2 ** self.bits

    def apply(self, state):
        step = self.step_dn()
        state.bayer = (np.round(np.clip(state.bayer, -255.0, 510.0) / step) * step).astype(np.float32)


# --- calibration (sec. 4.4.3, Figs. 6-8) -------------------------------------------------------------------------
