"""Colour crosstalk of the Bayer filters, and its calibration from a colour chart (Klein & Murray 2010, sec. 4.2).

The rendered colour is mixed as ``rgb' = N (M rgb)`` (sec. 5.2 step 2): ``M`` the filter crosstalk matrix (the
Fire-i's from its sensor's spectral chart, rows summing to 1), ``N`` the paper's further 5 % of every channel
added to every other, rows renormalised so white stays white. The calibration fits the camera's total colour
matrix to chart patches and divides the saturation setting out: ``S(beta)^-1 M``, rows renormalised to 1.

Diagnosis fits the colour mixing the profile lacks as one 3x3 matrix between its noise-free frames and the
measured means, and places it where the noise says it acts: in the sensor (this crosstalk, before the noise) or
in the image processor after demosaicing (the saturation stage's colour correction, which mixes the noise too).
Entries may be negative (real colour-correction matrices have negative off-diagonals); rows sum to 1, so white
stays white.

Contents
--------
- :data:`FIRE_I_CROSSTALK`: the Fire-i filter response to 700/546/438 nm primaries (sec. 4.2)
- :class:`Crosstalk`: mixes the rendered colour channels as the Bayer filters do: ``rgb' = N (M rgb)``
- :func:`fit_colour_matrix`: the 3x3 matrix M with ``measured ~ M ideal`` (least squares over patches)
- :func:`crosstalk_from_colour_matrix`: the sensor's own mixing, the saturation setting undone (sec. 4.2, 4.4.2)
- :func:`fit_colour_mixing`: the ``colour_matrix`` candidate's fit: a matrix placed in the sensor or after demosaicing

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
from .saturation import SATURATION_LUMA, colour_matrix_problems, saturation_matrix

#: Fire-i filter response to 700/546/438 nm primaries, rows sum to 1 (sec. 4.2).
FIRE_I_CROSSTALK = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]


def _rows_to_one(m: np.ndarray) -> np.ndarray:
    return m / m.sum(axis=1, keepdims=True)


def fit_colour_mixing(ctx, effect: str):
    """The ``colour_matrix`` candidate's fit (``fit(ctx, effect)``, see :class:`~lowcam.effects.Search`).

    ``T`` with ``measured ~ T clean`` by least squares over pixels unclipped in both (the chain between the
    mixing and the output is linear). With ``P`` the processor's matrix ``S(beta) C`` and ``K`` the crosstalk,
    the same change is the crosstalk ``P^-1 T P K`` (before the noise) or the colour correction ``S^-1 T S C``
    (after the noise); each is renormalised to rows summing to 1 and the one with the lower full error (on a few
    captures) is kept.
    """
    p = ctx.profile
    if not ctx.scene_has_colour():
        raise NotFitted("the ideal renders hold no colour (a grey target): no colour matrix can be told")
    s, m = ctx.pixels(p)
    ok = (s.max(1) < 250) & (m.max(1) < 250) & (s.min(1) > 3) & (m.min(1) > 3)
    if ok.sum() < 100:
        raise NotFitted("fewer than 100 pixels are unclipped in both the model and the frames")
    t = fit_colour_matrix(s[ok], m[ok])
    old = p.effect(effect)
    k = old.total_matrix() if old.enabled else np.eye(3)
    sat = p.effect("saturation")
    options = []
    if sat is not None and sat.enabled and abs(np.linalg.det(saturation_matrix(sat.saturation, sat.luma))) < 1e-9:
        raise NotFitted("the profile delivers grey: no colour mixing can be told")
    if sat is not None and sat.enabled:
        S = saturation_matrix(sat.saturation, sat.luma)
        c = np.asarray(sat.colour_correction, np.float64)
        pm = S @ c
        new_c = _rows_to_one(np.linalg.solve(S, t @ pm))
        options.append(("after demosaicing (colour correction)", "saturation",
                        p.with_effect("saturation", colour_correction=new_c.tolist()), new_c))
    else:
        pm = np.eye(3)
    new_k = _rows_to_one(np.linalg.solve(pm, t @ pm @ k))
    options.append(("in the sensor (crosstalk)", effect,
                    p.with_effect(effect, matrix=new_k.tolist(), extra_mixing=0.0), new_k))
    if len(options) > 1 and not getattr(ctx, "screening", False):
        options.sort(key=lambda o: ctx.compare(o[2], ctx.quick, 4).error)  # the noise tells them apart
    where, stage, profile, new = options[0]
    rows = "; ".join(" ".join(f"{v:.3f}" for v in r) for r in new)
    return profile, {"matrix": new.round(4).tolist(), "stage": stage}, {"rows": rows, "where": where}


fit_colour_mixing.refines = True  # screening keeps the first placement; the full fit compares both


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
    searches = (Search("colour_matrix", "colours are mixed differently {where}: rows {rows}",
                       fit=fit_colour_mixing, requires="crosstalk"),)
    params = {
        "matrix": Param(FIRE_I_CROSSTALK, "matrix", length=3, low=-10.0, high=10.0),
        "extra_mixing": Param(0.05, low=0.0, high=1.0),
    }

    def check(self):
        if any(len(row) != 3 for row in self.matrix):
            raise self.error("'matrix' must be 3x3")

    def implausible(self) -> list[str]:
        return colour_matrix_problems(self.total_matrix(), "the crosstalk")

    def total_matrix(self) -> np.ndarray:
        m = np.asarray(self.matrix, np.float64)
        e = self.extra_mixing
        mix = (np.eye(3) + e * (np.ones((3, 3)) - np.eye(3))) / (1 + 2 * e)
        return mix @ m

    def apply(self, state):
        t = np.eye(4, dtype=np.float64)
        t[:3, :3] = self.total_matrix()
        window = state.window("working")  # a matrix keeps zeros zero
        state.working = cv2.transform(state.working, t.astype(np.float32))
        state.keep_window("working", window, self)


def fit_colour_matrix(ideal: np.ndarray, measured: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """The 3x3 matrix M with ``measured ~ M ideal`` (least squares over patches; both (N, 3), same units); with
    ``sigma`` (N, 3), each patch and channel weighed by ``1 / sigma`` (one output channel at a time)."""
    ideal, measured = np.asarray(ideal, np.float64), np.asarray(measured, np.float64)
    if sigma is None:
        x, *_ = np.linalg.lstsq(ideal, measured, rcond=None)
        return x.T
    w = 1.0 / np.asarray(sigma, np.float64)
    return np.array([np.linalg.lstsq(ideal * w[:, c, None], measured[:, c] * w[:, c], rcond=None)[0]
                     for c in range(3)])


def crosstalk_from_colour_matrix(total: np.ndarray, saturation: float, luma=SATURATION_LUMA) -> np.ndarray:
    """Undo the camera's saturation setting: the sensor's own mixing ``S(beta)^-1 M``, rows renormalised to 1
    (sec. 4.2, 4.4.2). Pass the setting the patches were captured at."""
    m = np.linalg.solve(saturation_matrix(saturation, luma), total)
    return m / m.sum(axis=1, keepdims=True)

