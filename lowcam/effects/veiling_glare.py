"""Veiling glare: light scattered inside the lens spreads a faint haze around bright areas (sec. 3: flare).

The haze is ``strength`` times a wide Gaussian blur (``radius_px`` output pixels) of the light, added to the light.
It reaches beyond the graphics' edges: colour without alpha, so it adds to the plate there.

Its signature in a comparison is dark areas lifted above the model near bright ones, more in brighter captures.
The candidate's fit (:func:`fit_veiling_glare`) measures that first, then fits the haze: the model's response to a
small haze is linear in ``strength`` (the blur acts on the light, the chain after it is nearly linear), so for each
radius on a grid the best strength is a projection of the residual, and the radius with the smallest error wins.

Contents
--------
- :data:`RADII_PX`: the haze radii the fit tries
- :func:`dark_pixels`: a capture's dark areas, away from the edges
- :func:`dark_lift`: per capture, how far the dark areas' measured mean sits above the model (DN), and the
  capture's brightness
- :func:`fit_veiling_glare`: diagnosis's fit: strength and radius, with what was seen on the dark areas
- :class:`VeilingGlare`: adds ``strength`` times a wide Gaussian blur (``radius_px``) of the light to the light

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- ISO 9358:1994, "Optics and optical instruments - Veiling glare of image forming systems - Definitions and
  methods of measurement" (the veiling glare index: the light a black patch receives, as a share of the field's).
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param, Search

#: The haze radii (output pixels) the fit tries; screening tries every other one.
RADII_PX = (10.0, 25.0, 60.0, 150.0, 300.0)
_TRIAL_STRENGTH = 0.05


def dark_pixels(model: np.ndarray, mask=None, dark_share: float = 0.25) -> np.ndarray:
    """(H, W) bool: a capture's dark areas, the pixels whose model (H, W, 3, DN; channel mean) is below
    ``dark_share`` of its 99th percentile, 3 px or more from anything brighter (the edges' blur is not a haze),
    inside ``mask`` (the compared pixels) when given."""
    grey = model.mean(axis=2)
    dark = grey < dark_share * max(float(np.percentile(grey, 99)), 1e-6)
    dark = cv2.erode(dark.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    return dark if mask is None else dark & mask


def dark_lift(measured: np.ndarray, model: np.ndarray, mask=None):
    """(lift DN, brightness DN, dark pixels) of one capture: the mean of measured less model (H, W, 3, DN) over its
    :func:`dark_pixels`, and the model's mean brightness. The lift is NaN with fewer than 200 dark pixels."""
    dark = dark_pixels(model, mask)
    count = int(dark.sum())
    lift = float((measured - model).mean(axis=2)[dark].mean()) if count >= 200 else float("nan")
    return lift, float(model.mean()), count


def fit_veiling_glare(ctx, effect: str):
    """The candidate's fit on the captures with texture (``ctx``: a diagnosis context). What was seen: the dark
    areas' lift above the profile's noise-free frames per capture (:func:`dark_lift`), pooled over captures and in
    the brightest and dimmest. The fit: for each radius of :data:`RADII_PX`, the frames with a trial haze give the
    model's response per unit strength ``J``; the strength is ``<J, R> / <J, J>`` (``R``: the residual, masked
    pixels left out), kept within the search bounds; the radius whose linear prediction leaves the least is
    chosen, refined between its neighbours on the grid by a parabola in log radius. None when no capture has dark
    areas (a haze cannot be seen) or no haze lowers the error."""
    have = ctx.profile.effect(effect)
    base = ctx.profile.without(effect) if have is not None and have.enabled else ctx.profile
    subset = ctx.screening_subset("textured") if ctx.screening else ctx.subset("textured")
    idx = list(range(len(ctx.means))) if subset is None else list(subset)
    masks = [ctx.inputs[i].mask for i in idx]
    means = [ctx.means[i] for i in idx]
    clean = ctx.clean(base, idx)
    seen = [dark_lift(m, c, k) for m, c, k in zip(means, clean, masks)]
    with_dark = [k for k, (lift, _, _) in enumerate(seen) if np.isfinite(lift)]
    if not with_dark:
        return None
    resid = [(m - c) * (1.0 if k is None else k[..., None]) for m, c, k in zip(means, clean, masks)]
    lo, hi = VeilingGlare.searches[0].bounds["strength"]

    def trial(radius):
        """(drop in squared error the linear model predicts, strength, radius, response per unit strength)."""
        frames = ctx.clean(base.with_effect(effect, strength=_TRIAL_STRENGTH, radius_px=radius), idx)
        jac = [(t - c) / _TRIAL_STRENGTH * (1.0 if k is None else k[..., None])
               for t, c, k in zip(frames, clean, masks)]
        jj = sum(float((j.astype(np.float64) ** 2).sum()) for j in jac)
        jr = sum(float((j.astype(np.float64) * r).sum()) for j, r in zip(jac, resid))
        strength = float(np.clip(jr / max(jj, 1e-12), lo, hi))
        return 2 * strength * jr - strength ** 2 * jj, strength, radius, jac

    radii = RADII_PX[::2] if ctx.screening else RADII_PX
    tried = [trial(r) for r in radii]
    k = int(np.argmax([t[0] for t in tried]))
    best = tried[k]
    if 0 < k < len(tried) - 1 and not ctx.screening:  # the radius between the grid's: a parabola in log radius
        x = np.log(radii[k - 1:k + 2])
        y = np.array([t[0] for t in tried[k - 1:k + 2]])
        curve = np.polyfit(x, y, 2)
        if curve[0] < 0:
            refined = trial(float(np.exp(np.clip(-curve[1] / (2 * curve[0]), x[0], x[2]))))
            best = refined if refined[0] > best[0] else best
    gain, strength, radius, jac = best
    if strength <= 0 or gain <= 0:
        return None
    haze = [float(strength * jac[k].mean(axis=2)[dark_pixels(clean[k], masks[k])].mean()) for k in with_dark]
    lifts = np.array([seen[k][0] for k in with_dark])
    counts = np.array([seen[k][2] for k in with_dark], np.float64)
    order = np.argsort([seen[k][1] for k in with_dark])
    values = {"strength": strength, "radius_px": radius}
    shown = dict(values, dark_lift_dn=float((lifts * counts).sum() / counts.sum()),
                 bright_lift_dn=float(lifts[order[-1]]), dim_lift_dn=float(lifts[order[0]]),
                 haze_lift_dn=float((np.array(haze) * counts).sum() / counts.sum()), captures=len(with_dark))
    return ctx.profile.with_effect(effect, **values), values, shown


fit_veiling_glare.refines = True  # screening: two captures and every other radius; the full fit all of them


class VeilingGlare(Effect):
    """Adds ``strength`` times a wide Gaussian blur (``radius_px`` output pixels) of the light to the light; the
    haze reaches beyond the graphics' edges (colour without alpha: it adds to the plate there)."""

    name = "veiling_glare"
    section = "3 (flare)"
    writes = "working"
    order = 100
    searches = (Search("veiling_glare", "dark areas sit {dark_lift_dn:+.1f} DN from the model over {captures} "
                       "captures ({bright_lift_dn:+.1f} in the brightest, {dim_lift_dn:+.1f} in the dimmest); a "
                       "haze of {strength:.3f} of the light spread over {radius_px:.0f} px lifts them "
                       "{haze_lift_dn:.1f} DN",
                       bounds={"strength": (0.0, 0.5), "radius_px": (5.0, 300.0)}, fit=fit_veiling_glare),)
    params = {"strength": Param(0.0, low=0.0, high=1.0), "radius_px": Param(40.0, low=1.0, high=500.0)}

    def apply(self, state):
        if self.strength <= 0:
            return
        sigma = self.radius_px * min(state.geometry.working_scale)
        small = cv2.resize(state.working[..., :3], None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
        haze = cv2.GaussianBlur(small, (0, 0), sigma / 4)
        haze = cv2.resize(haze, state.working.shape[1::-1], interpolation=cv2.INTER_LINEAR)
        state.working[..., :3] += np.float32(self.strength) * haze
