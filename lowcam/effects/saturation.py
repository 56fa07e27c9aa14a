"""The camera's colour processing after demosaicing: colour correction and the saturation control (Klein & Murray
2010, sec. 4.4.2).

``S(beta) = A + (beta / 65) (I - A)``, every row of A equal to ``[0.2915 0.5887 0.1113]``: the paper's
``A + beta B`` with ``B = (I - A) / 65``, so ``beta = 65`` is the identity (the Fire-i's default is 90).
Before it, the image processor's colour-correction matrix ``C`` (identity for the Fire-i): the frame becomes
``S(beta) C rgb``. Real cameras' C map the sensor's white-balanced RGB to the output primaries and have negative
off-diagonal entries, rows summing to 1 so white stays white (e.g. Adobe DNG specification 1.6, "Camera to XYZ
(D50) transformation"); being digital, it mixes the sensor noise too, unlike the optical crosstalk.

Contents
--------
- :data:`SATURATION_LUMA`: the rows of the control's fixed part A (sec. 4.4.2)
- :data:`LUMA_SUM_TOLERANCE`: how far from 1 luma weights may sum
- :func:`saturation_matrix`: the Fire-i saturation control ``S(beta)``
- :func:`colour_matrix_problems`: what in a colour matrix no real camera has (:data:`MIN_OWN_WEIGHT`,
  :data:`MAX_NEGATIVE`, :data:`MIN_DETERMINANT`); the crosstalk's total matrix is judged so too
- :func:`fit_monochrome`: diagnosis's fit of a camera without colour: no colour filters, or grey output
- :class:`Saturation`: colour correction and the saturation control on the demosaiced premultiplied colour

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import NotFitted
from .base import Effect, NodeStage, Param, Search

#: Rows of the saturation control's fixed part A (sec. 4.4.2).
SATURATION_LUMA = (0.2915, 0.5887, 0.1113)
#: Luma weights sum to 1 within this (the paper's sum to 0.9915).
LUMA_SUM_TOLERANCE = 0.05


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


#: What a real camera's colour matrix keeps within (:func:`colour_matrix_problems`): each channel's weight on
#: itself at least :data:`MIN_OWN_WEIGHT`, no other weight below -:data:`MAX_NEGATIVE`, a determinant at least
#: :data:`MIN_DETERMINANT` (a matrix that folds the colours together is a grey camera: ``monochrome``).
MIN_OWN_WEIGHT = 0.2
MAX_NEGATIVE = 1.0
MIN_DETERMINANT = 0.05


def colour_matrix_problems(matrix, what: str = "the colour matrix") -> list[str]:
    """What in a 3x3 colour matrix (rows: output channels) no real camera has: a channel weighing itself below
    :data:`MIN_OWN_WEIGHT` (a negative green weight on green), a weight below -:data:`MAX_NEGATIVE`, or a
    determinant below :data:`MIN_DETERMINANT` (three equal rows remove every colour).

    >>> colour_matrix_problems([[0.91, -0.73, 0.81]] * 3)[0]
    'the colour matrix weighs green at -0.73 on itself'
    """
    m = np.asarray(matrix, np.float64)
    names = ("red", "green", "blue")
    out = [f"{what} weighs {names[k]} at {m[k, k]:.2f} on itself" for k in range(3) if m[k, k] < MIN_OWN_WEIGHT]
    if m.min() < -MAX_NEGATIVE:
        out.append(f"{what} has a weight of {m.min():.2f}")
    det = float(np.linalg.det(m))
    if det < MIN_DETERMINANT:
        out.append(f"{what} removes colour (determinant {det:.3f}): a grey camera is 'monochrome'")
    return out


def fit_monochrome(ctx, effect: str):
    """A camera without colour, in whichever of two forms fits the measured means better (noise-free SSE):

    - *no colour filters*: every sensel sees the same mix of the light (``bayer_sampling.colour_filters`` off,
      its ``grey_weights``), each output pixel is its own sensel (``demosaic.method = "monochrome"``), and the
      crosstalk and lateral colour of colour filters are gone;
    - *grey output*: a colour camera whose processor delivers the luma of the demosaiced colour (the saturation
      control at 0).

    The weights (>= 0, summing to 1 within :data:`~lowcam.effects.saturation.LUMA_SUM_TOLERANCE`) are fitted by
    non-negative least squares to the measured grey only where the ideal renders hold colour
    (:meth:`Context.scene_has_colour`); a grey scene shows every such set of weights alike, so they are then the
    profile's. NotFitted when the measured frames carry colour, or the model delivers grey already."""
    p = ctx.profile
    sat = p.effect(effect)
    s, m = ctx.pixels(p, ctx.quick)
    grey = m.mean(axis=1)
    if np.abs(m - grey[:, None]).mean() > 0.1 * max(m.std(), 1e-6):
        raise NotFitted("the frames carry colour")
    control = saturation_matrix(sat.saturation, sat.luma)
    if abs(np.linalg.det(control)) < 1e-9 or not p.effect("bayer_sampling").colour_filters:
        raise NotFitted("the profile delivers grey already")
    if ctx.scene_has_colour():
        from scipy.optimize import nnls

        ok = (s.max(1) < 250) & (grey < 250) & (s.min(1) > 3)
        luma = nnls(np.linalg.solve(control, s[ok].T).T, grey[ok])[0]  # from the colour before the control
        total = float(luma.sum())
        luma *= np.clip(total, 1 - LUMA_SUM_TOLERANCE, 1 + LUMA_SUM_TOLERANCE) / max(total, 1e-12)
        how = "fitted"
    else:
        luma = np.asarray(sat.luma, np.float64)
        how = "the profile's: a grey scene does not determine them"
    forms = [("grey output of a colour sensor", p.with_effect(effect, saturation=0.0, luma=luma.tolist()))]
    unfiltered = p.without(*(n for n in ("crosstalk", "chromatic_aberration") if p.effect(n) is not None))
    forms.append(("a sensor without colour filters",
                  unfiltered.with_effect("bayer_sampling", colour_filters=False, grey_weights=luma.tolist())
                  .with_effect("demosaic", method="monochrome")))
    form, profile = min(forms, key=lambda f: ctx.sse(f[1], ctx.quick))
    weights = " ".join(f"{w:.3f}" for w in luma)
    return profile, {"form": form, "luma": luma.round(4).tolist(), "luma_weights": how}, \
        {"form": form, "weights": weights, "how": how}


class Saturation(Effect):
    """Colour correction and the saturation control on the demosaiced premultiplied colour: ``S(beta) C rgb``
    (sec. 4.4.2; ``colour_correction`` C is the image processor's matrix, identity by default).

    The matrix is also recorded in the state, so blending can take it into account: the video frame already went
    through it, and with per-channel alpha the camera mixes the channels of the light behind the graphics too.
    """

    name = "saturation"
    section = "4.4.2"
    writes = "rgb"
    order = 240
    node = NodeStage("Saturation", "rgb", "saturation")
    searches = (Search("monochrome", "the frames carry no colour: {form} (luma weights {weights}, {how})",
                       fit=fit_monochrome, requires="saturation", full_error=True),)
    params = {
        "saturation": Param(90.0, low=0.0, high=255.0, doc="camera setting; 65 is the identity, Fire-i default 90"),
        "luma": Param(list(SATURATION_LUMA), "vector", length=3, low=0.0, high=1.0),
        "colour_correction": Param(np.eye(3).tolist(), "matrix", length=3, low=-10.0, high=10.0,
                                   doc="the image processor's colour-correction matrix C, applied before S"),
    }

    def check(self):
        if any(len(row) != 3 for row in self.colour_correction):
            raise self.error("'colour_correction' must be 3x3")

    def implausible(self) -> list[str]:
        """Luma weights below 0 or not summing to 1 within :data:`LUMA_SUM_TOLERANCE`, and a colour correction no
        camera has (:func:`colour_matrix_problems`)."""
        out = [f"a negative luma weight ({min(self.luma):.3f})"] if min(self.luma) < 0 else []
        if abs(sum(self.luma) - 1.0) > LUMA_SUM_TOLERANCE:
            out.append(f"luma weights summing to {sum(self.luma):.3f}")
        return out + colour_matrix_problems(self.colour_correction, "the colour correction")

    def bake_node(self, state, bake) -> None:
        """The stage's matrix and its pseudo-inverse (the YUV blend undoes it on the plate behind)."""
        s = self.total_matrix()
        bake.values["saturation_matrix"] = s.ravel().tolist()
        bake.values["saturation_inverse"] = np.linalg.pinv(s).ravel().tolist()

    def total_matrix(self) -> np.ndarray:
        """``S(beta) C``: what the stage does to the colour."""
        s = saturation_matrix(self.saturation, self.luma)
        return s @ np.asarray(self.colour_correction, np.float64)

    def apply(self, state):
        s = self.total_matrix()
        state.rgb = cv2.transform(state.rgb, s.astype(np.float32))
        state.colour_matrix = s if state.colour_matrix is None else s @ state.colour_matrix
