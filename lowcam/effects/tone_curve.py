"""The camera's tone curve (transfer function, OETF): not modelled in the paper (sec. 8 names gamma as missing).

The form is the one of the broadcast and display encodings (ITU-R BT.709 eq. 1.2, IEC 61966-2-1 sRGB,
SMPTE 240M): on the normalised straight colour ``x = in / 255`` a straight toe of slope ``k`` below ``toe_break``
``b``, then a power law with offset, continuous in value and slope at ``b``::

    V(x) = k x                          for x <  b
    V(x) = (1 + a) x^(1 / gamma) - a    for x >= b,   a = c / (1 - c),  c = b^(1 / gamma) (1 - 1 / gamma),
                                                      k = (1 + a) (1 / gamma) b^(1 / gamma - 1)
    out  = black_dn + (white_dn - black_dn) V(x)

BT.709 is ``gamma = 1/0.45, b = 0.018`` (a = 0.099, k = 4.5), SMPTE 240M ``b = 0.0228`` (a = 0.1115, k = 4),
sRGB ``gamma = 2.4, b = 0.0031308`` (a = 0.055, k = 12.92); studio (legal) range puts black and white at 16 and
235 DN. ``b = 0``, black 0 and white 255 is the plain power law ``255 x^(1 / gamma)`` (a profile with only
``gamma`` gives the same frames as before the toe was added). The curve acts on each channel of the demosaiced
frame alike, in straight colour, so partial coverage keeps its alpha.

Contents
--------
- :class:`ToneCurve`: the transfer curve (linear toe, power law with offset, black and white levels) per channel
- :func:`transfer_curve`: ``V(x)``, the normalised curve, for an array of normalised inputs
- :func:`tone_response`: ``out``, the curve between the black and white levels (DN)
- :func:`fit_tone_curve`: the candidate's fit: least squares of the curve on (clean model, measured mean) pairs

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [BT709] Recommendation ITU-R BT.709-6, "Parameter values for the HDTV standards for production and
  international programme exchange", 2015, part 1, item 1.2 (opto-electronic transfer characteristics).
- [sRGB] IEC 61966-2-1:1999, "Default RGB colour space - sRGB".
"""
from __future__ import annotations

import numpy as np

from ..errors import NotFitted
from .base import Effect, Param, Search


def _toe(gamma: float, toe_break: float):
    """(a, k): the power segment's offset and the toe's slope that make the curve continuous with a continuous
    slope at ``toe_break``."""
    p = 1.0 / gamma
    if toe_break <= 0:
        return 0.0, 0.0
    c = toe_break ** p * (1.0 - p)
    a = c / (1.0 - c)
    return a, (1.0 + a) * p * toe_break ** (p - 1.0)


def transfer_curve(x, gamma: float, toe_break: float = 0.0):
    """``V(x)``: ``k x`` below ``toe_break``, ``(1 + a) x^(1 / gamma) - a`` above (module docstring; x >= 0)."""
    if toe_break <= 0:
        return x ** (1.0 / gamma)
    a, k = _toe(gamma, toe_break)
    return np.where(x < toe_break, k * x, (1.0 + a) * x ** (1.0 / gamma) - a)


def tone_response(x, gamma: float, toe_break: float, black_dn: float, white_dn: float):
    """``out = black_dn + (white_dn - black_dn) V(x)`` (DN) of normalised inputs ``x >= 0`` (module docstring)."""
    return black_dn + (white_dn - black_dn) * transfer_curve(x, gamma, toe_break)


def fit_tone_curve(ctx, effect: str):
    """The candidate's fit: the curve's four parameters by least squares on the (clean model, measured mean) pairs
    of every unclipped pixel and channel, binned by the model's value (the curve acts late in the chain, per
    pixel; what follows it is nearly linear). Any tone curve the profile has is taken out of the model first."""
    from scipy.optimize import least_squares

    have = ctx.profile.effect(effect)
    base = ctx.profile.without(effect) if have is not None and have.enabled else ctx.profile
    s, m = (x.ravel() for x in ctx.pixels(base))
    ok = (m > 0.5) & (m < 254.5) & (s > 0.0)
    s, m = s[ok], m[ok]
    if s.size < 100:
        raise NotFitted("fewer than 100 pixels are unclipped")
    bins = np.clip(np.floor(s).astype(np.int64), 0, 511)
    count = np.bincount(bins, minlength=512)
    keep = count > 0
    n = count[keep].astype(np.float64)
    xs = np.bincount(bins, s, 512)[keep] / n / 255.0
    ms = np.bincount(bins, m, 512)[keep] / n
    w = np.sqrt(n)
    # Below the darkest input the data say nothing: a weak pull (0.02 DN of error over every pixel per DN of
    # black level or per 0.01 of toe) keeps the black level at 0 and the toe short unless the data ask otherwise.
    prior = 0.02 * np.sqrt(n.sum()) * np.array([0.0, 100.0, 1.0, 0.0])

    def residual(q):
        gamma, toe, black, white = q
        fit = w * (tone_response(xs, gamma, toe, black, white) - ms)
        return np.concatenate([fit, prior * q])

    low, high = [0.3, 0.0, -64.0, 128.0], [4.0, 0.3, 96.0, 400.0]
    best = None
    for start in ([1.0, 0.0, 0.0, 255.0], [2.2, 0.02, 0.0, 255.0], [2.2, 0.0, 0.0, 255.0]):
        r = least_squares(residual, start, bounds=(low, high), x_scale=[0.5, 0.01, 5.0, 20.0])
        if best is None or r.cost < best.cost:
            best = r
    gamma, toe, black, white = map(float, best.x)
    values = {"gamma": gamma, "toe_break": toe, "black_dn": black, "white_dn": white}
    return ctx.profile.with_effect(effect, **values), values, values


class ToneCurve(Effect):
    """The camera's transfer curve on each channel of the demosaiced frame (straight colour, so partial coverage
    keeps its alpha): a straight toe below ``toe_break``, then ``(1 + a) x^(1 / gamma) - a``, continuous with a
    continuous slope, scaled to ``black_dn``..``white_dn`` (the BT.709 / sRGB form; module docstring). ``gamma``
    1 with no toe is the identity; 2.2 a typical display encoding."""

    name = "tone_curve"
    section = "not in the paper (sec. 8: gamma is not modelled)"
    writes = "rgb"
    order = 250
    searches = (Search("tone_curve", "mid-tones follow a power 1/{gamma:.2f} with a straight toe below "
                       "{toe_break:.4f} of white, black {black_dn:.1f} DN, white {white_dn:.1f} DN",
                       fit=fit_tone_curve),)
    params = {
        "gamma": Param(1.0, low=0.2, high=5.0, doc="the power segment is x^(1 / gamma) (BT.709: 1 / 0.45)"),
        "toe_break": Param(0.0, low=0.0, high=0.5, doc="normalised input below which the curve is straight "
                                                      "(BT.709: 0.018, sRGB: 0.0031308; 0: a pure power law)"),
        "black_dn": Param(0.0, low=-128.0, high=128.0, unit="DN", doc="output for a black input (legal: 16)"),
        "white_dn": Param(255.0, low=1.0, high=512.0, unit="DN", doc="output for a white input (legal: 235)"),
    }

    def check(self):
        if self.white_dn <= self.black_dn:
            raise self.error(f"'white_dn' ({self.white_dn}) must be above 'black_dn' ({self.black_dn})")

    def apply(self, state):
        a = np.maximum(state.rgb_alpha, 1e-6)
        straight = np.clip(state.rgb / a, 0.0, None)
        curved = tone_response(straight / 255.0, self.gamma, self.toe_break, self.black_dn, self.white_dn)
        state.rgb = np.where(state.rgb_alpha > 0, curved * state.rgb_alpha, state.rgb).astype(np.float32)
