"""Colour crosstalk of the Bayer filters, and its calibration from a colour chart (Klein & Murray 2010, sec. 4.2).

The rendered colour is mixed as ``rgb' = N (M rgb)`` (sec. 5.2 step 2): ``M`` the filter crosstalk matrix (the
Fire-i's from its sensor's spectral chart, rows summing to 1), ``N`` the paper's further 5 % of every channel
added to every other, rows renormalised so white stays white. The calibration fits the camera's total colour
matrix to chart patches and divides the saturation setting out: ``S(beta)^-1 M``, rows renormalised to 1.

Contents
--------
- :data:`FIRE_I_CROSSTALK`: the Fire-i filter response to 700/546/438 nm primaries (sec. 4.2)
- :class:`Crosstalk`: mixes the rendered colour channels as the Bayer filters do: ``rgb' = N (M rgb)``
- :func:`fit_colour_matrix`: the 3x3 matrix M with ``measured ~ M ideal`` (least squares over patches)
- :func:`crosstalk_from_colour_matrix`: the sensor's own mixing, the saturation setting undone (sec. 4.2, 4.4.2)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, NodeStage, Param, Search
from .saturation import SATURATION_LUMA, saturation_matrix

#: Fire-i filter response to 700/546/438 nm primaries, rows sum to 1 (sec. 4.2).
FIRE_I_CROSSTALK = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]


class Crosstalk(Effect):
    """Mixes the rendered colour channels as the Bayer filters do: ``rgb' = N (M rgb)``.

    ``M`` is the filter crosstalk matrix (``matrix``); ``N`` adds ``extra_mixing`` of every channel to every
    other (the paper's "further 5 %", step 2) and renormalises each row so white stays white. Acts on
    premultiplied colour; alpha is untouched.
    """

    name = "crosstalk"
    section = "4.2, 5.2 step 2"
    writes = "working"
    order = 40
    calibration = "colour"
    node = NodeStage("Crosstalk", "image", "matrix")
    searches = (Search("colour_matrix", "colours are mixed differently: crosstalk rows {rows}", fit="colour_matrix",
                       requires="crosstalk"),)
    params = {
        "matrix": Param(FIRE_I_CROSSTALK, "matrix", length=3, low=-10.0, high=10.0),
        "extra_mixing": Param(0.05, low=0.0, high=1.0),
    }

    def check(self):
        if any(len(row) != 3 for row in self.matrix):
            raise self.error("'matrix' must be 3x3")

    def total_matrix(self) -> np.ndarray:
        m = np.asarray(self.matrix, np.float64)
        e = self.extra_mixing
        mix = (np.eye(3) + e * (np.ones((3, 3)) - np.eye(3))) / (1 + 2 * e)
        return mix @ m

    def apply(self, state):
        t = np.eye(4, dtype=np.float64)
        t[:3, :3] = self.total_matrix()
        state.working = cv2.transform(state.working, t.astype(np.float32))


def fit_colour_matrix(ideal: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The 3x3 matrix M with ``measured ~ M ideal`` (least squares over patches; both (N, 3), same units)."""
    x, *_ = np.linalg.lstsq(np.asarray(ideal, np.float64), np.asarray(measured, np.float64), rcond=None)
    return x.T


def crosstalk_from_colour_matrix(total: np.ndarray, saturation: float, luma=SATURATION_LUMA) -> np.ndarray:
    """Undo the camera's saturation setting: the sensor's own mixing ``S(beta)^-1 M``, rows renormalised to 1
    (sec. 4.2, 4.4.2). Pass the setting the patches were captured at."""
    m = np.linalg.solve(saturation_matrix(saturation, luma), total)
    return m / m.sum(axis=1, keepdims=True)
