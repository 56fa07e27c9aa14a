"""The camera's saturation control after demosaicing (Klein & Murray 2010, sec. 4.4.2).

``S(beta) = A + (beta / 65) (I - A)``, every row of A equal to ``[0.2915 0.5887 0.1113]``: the paper's
``A + beta B`` with ``B = (I - A) / 65``, so ``beta = 65`` is the identity (the Fire-i's default is 90).

Contents
--------
- :data:`SATURATION_LUMA`: the rows of the control's fixed part A (sec. 4.4.2)
- :func:`saturation_matrix`: the Fire-i saturation control ``S(beta)``
- :class:`Saturation`: the saturation control applied to the demosaiced premultiplied colour (sec. 4.4.2)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, NodeStage, Param

#: Rows of the saturation control's fixed part A (sec. 4.4.2).
SATURATION_LUMA = (0.2915, 0.5887, 0.1113)


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
        "luma": Param(list(SATURATION_LUMA), "vector", length=3, low=0.0, high=1.0),
    }

    def apply(self, state):
        s = saturation_matrix(self.saturation, self.luma)
        state.rgb = cv2.transform(state.rgb, s.astype(np.float32))
        state.colour_matrix = s if state.colour_matrix is None else s @ state.colour_matrix
