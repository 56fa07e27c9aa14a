"""In-camera sharpening and quantisation (Klein & Murray 2010, sec. 4.4.3, 5.2 step 7)."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param
from .blur import filter_rows, gaussian_taps


class Sharpening(Effect):
    """Horizontal unsharp masking ``F = I + a (I - L)`` on each sensel plane, ``L`` a ``taps``-tap Gaussian.

    The paper sets ``a`` from the camera's sharpness control; the constant that relates them was lost in the
    text extraction. We use ``a = gain_per_unit * sharpness`` with ``gain_per_unit = 0.025``, so the Fire-i's
    default 80 gives ``a = 2`` (about 2x gain at the sensel Nyquist frequency with sigma 0.55) and PTAM's
    recommended 25 gives ``a = 0.6``. Both numbers are profile parameters.
    """

    name = "sharpening"
    section = "4.4.3, 5.2 step 7"
    writes = "bayer"
    params = {
        "sharpness": Param(80.0, low=0.0, high=255.0, doc="the camera's sharpness setting"),
        "gain_per_unit": Param(0.025, low=0.0, high=1.0),
        "sigma": Param(0.55, low=0.01, high=10.0, unit="sensels"),
        "taps": Param(7, int, low=3, high=31),
    }

    def check(self):
        if self.taps % 2 == 0:
            raise self.error("'taps' must be odd")

    def kernel(self) -> np.ndarray:
        a = self.gain_per_unit * self.sharpness
        identity = gaussian_taps(0.0, self.taps)
        return ((1 + a) * identity - a * gaussian_taps(self.sigma, self.taps)).astype(np.float32)

    def apply(self, state):
        filter_rows(state, self.kernel())


class Quantisation(Effect):
    """Rounds each sensel's premultiplied value to ``bits`` of 8-bit range (sec. 4.3, 5.2 step 7).

    The Fire-i's 6 bits means steps of 4 DN. As on the paper's GPU (divide by 4, add 128, store in 8 bits),
    values keep their sign, so sharpening undershoot survives until blending; they are clipped to
    ``[-255, 510]`` DN.
    """

    name = "quantisation"
    section = "4.3, 5.2 step 7"
    writes = "bayer"
    params = {"bits": Param(6, int, low=1, high=16)}

    def step_dn(self) -> float:
        return 256.0 / 2 ** self.bits

    def apply(self, state):
        step = self.step_dn()
        state.bayer = (np.round(np.clip(state.bayer, -255.0, 510.0) / step) * step).astype(np.float32)
