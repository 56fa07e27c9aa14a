"""The camera's tone curve (gamma): not modelled in the paper (sec. 8 names it as missing).

``out = 255 (in / 255)^(1 / gamma)`` on each channel of the demosaiced frame, in straight colour so partial
coverage keeps its alpha; ``gamma`` 1 is the identity, 2.2 a typical display encoding.

Contents
--------
- :class:`ToneCurve`: ``out = 255 (in / 255)^(1 / gamma)`` on each channel of the demosaiced frame

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Search


class ToneCurve(Effect):
    """``out = 255 (in / 255)^(1 / gamma)`` on each channel of the demosaiced frame (straight colour, so partial
    coverage keeps its alpha). ``gamma`` 1 is the identity; 2.2 is a typical display encoding."""

    name = "tone_curve"
    section = "not in the paper (sec. 8: gamma is not modelled)"
    writes = "rgb"
    order = 250
    searches = (Search("tone_curve", "mid-tones follow a gamma of {gamma:.2f}", bounds={"gamma": (0.3, 4.0)}),)
    params = {"gamma": Param(1.0, low=0.2, high=5.0)}

    def apply(self, state):
        a = np.maximum(state.rgb_alpha, 1e-6)
        straight = np.clip(state.rgb / a, 0.0, None)
        curved = 255.0 * (straight / 255.0) ** (1.0 / self.gamma)
        state.rgb = np.where(state.rgb_alpha > 0, curved * state.rgb_alpha, state.rgb).astype(np.float32)
