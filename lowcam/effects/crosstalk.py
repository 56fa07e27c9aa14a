"""Colour crosstalk of the Bayer filters and the camera's saturation control (Klein & Murray 2010, sec. 4.2,
4.4.2, 5.2 step 2)."""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, NodeStage, Param, Search

#: Fire-i filter response to 700/546/438 nm primaries, rows sum to 1 (sec. 4.2).
FIRE_I_CROSSTALK = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]
#: Rows of the saturation control's fixed part A (sec. 4.4.2).
SATURATION_LUMA = (0.2915, 0.5887, 0.1113)


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
    node = NodeStage("Crosstalk", "image", "matrix")
    searches = (Search("colour_matrix", "colours are mixed differently: crosstalk rows {rows}", fit="colour_matrix", requires="crosstalk"),)
    params = {
        "matrix": Param(FIRE_I_CROSSTALK, "matrix", length=3),
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


def saturation_matrix(beta: float, luma=SATURATION_LUMA) -> np.ndarray:
    """The Fire-i saturation control ``S(beta) = A + (beta / 65) (I - A)``, every row of A equal to ``luma``.

    The paper prints ``A + beta B`` with B to four decimals; ``B = (I - A) / 65`` reproduces every printed entry
    (to the last digit but one: -0.0091 against -0.0090) and makes ``beta = 65`` exactly the identity, as the
    paper states (sec. 4.4.2).

    >>> bool(np.allclose(saturation_matrix(65), np.eye(3)))
    True
    """
    a = np.tile(np.asarray(luma, np.float64), (3, 1))
    return a + (beta / 65.0) * (np.eye(3) - a)


class Saturation(Effect):
    """The camera's saturation control applied to the demosaiced premultiplied colour (sec. 4.4.2).

    The matrix is also recorded in the state, so blending can take it into account: the video frame already went
    through it, and with per-channel alpha the camera mixes the channels of the light behind the graphics too.
    """

    name = "saturation"
    section = "4.4.2"
    writes = "rgb"
    order = 240
    node = NodeStage("Saturation", "rgb", "saturation")
    params = {
        "saturation": Param(90.0, low=0.0, high=255.0, doc="camera setting; 65 is the identity, Fire-i default 90"),
        "luma": Param(list(SATURATION_LUMA), "vector", length=3),
    }

    def apply(self, state):
        s = saturation_matrix(self.saturation, self.luma)
        state.rgb = cv2.transform(state.rgb, s.astype(np.float32))
        state.colour_matrix = s if state.colour_matrix is None else s @ state.colour_matrix


def fit_colour_matrix(ideal: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The 3x3 matrix M with ``measured ~ M ideal`` (least squares over patches; both (N, 3), same units)."""
    x, *_ = np.linalg.lstsq(np.asarray(ideal, np.float64), np.asarray(measured, np.float64), rcond=None)
    return x.T


def crosstalk_from_colour_matrix(total: np.ndarray, saturation: float, luma=SATURATION_LUMA) -> np.ndarray:
    """Undo the camera's saturation setting: the sensor's own mixing ``S(beta)^-1 M``, rows renormalised to 1
    (sec. 4.2, 4.4.2). Pass the setting the patches were captured at."""
    m = np.linalg.solve(saturation_matrix(saturation, luma), total)
    return m / m.sum(axis=1, keepdims=True)
