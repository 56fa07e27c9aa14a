"""Edge enhancement of a camera's image processor: an unsharp mask with coring and clamped halos (not in the paper).

A phone's or webcam's processor boosts edges after noise reduction and leaves flat areas alone [Ramanath2005]:

    d = Y - G_r * Y                     (the detail: the frame less its Gaussian blur of sigma ``radius_px``)
    c = d where |d| >= t, else 0        (``coring = "hard"``, t = ``coring_dn``), or
    c = sign(d) max(|d| - t, 0)         (``coring = "soft"``: small details shrink smoothly)
    b = clip(gain c, -undershoot_dn, overshoot_dn)
    out = frame + b

on the full-range BT.601 luma Y (``channels = "luma"``, the boost added to R, G and B alike) or on each of R, G, B
(``channels = "rgb"``). The clamps limit the halos; unequal ones give the lopsided overshoot of phone sharpening
(bright halos clipped harder than dark ones, or the reverse).

Beside the paper's sharpening, not instead of it: :mod:`~lowcam.effects.sharpening` is the sensor-side horizontal
filter on each colour plane before quantisation (the Fire-i's, sec. 4.4.3); this stage is the image processor's
two-dimensional one on the delivered frame. A camera may have both, and a profile keeps either.

Contents
--------
- :data:`CORING`, :data:`CHANNELS`: the coring shapes and the planes it acts on
- :func:`enhance_edges`: an RGB frame with its edges enhanced
- :func:`fit_edge_enhancement`: diagnosis's fit: gain, radius, coring and clamps whose enhanced noisy model frames
  best match the measured frames (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`EdgeEnhancement`: the stage
- :func:`edge_halo_statistic`, :func:`edge_enhancement_from_plate`: the plate probe: the profile across natural
  near-horizontal edges (which the Fire-i's row filters do not shape) against the base profile filming ideal steps

It has no compositor node yet: the node group refuses a profile with it (``lowcam.node_maps.bake``), and the
render handler, which runs the engine, simulates it.

References
----------
- [Ramanath2005] R. Ramanath, W. E. Snyder, Y. Yoo and M. S. Drew, "Color image processing pipeline", IEEE Signal
  Processing Magazine 22(1), 34-43, 2005.
- [Gonzalez2018] R. C. Gonzalez and R. E. Woods, "Digital Image Processing", 4th ed., Pearson 2018, sec. 3.6
  (unsharp masking and high-boost filtering).
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 luma).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, Param, Search
from .delivered_frame import BT601_TO_YCC, fit_delivered_stage, processed_by, to_uint8, within_footprint
from .sharpening import EDGE_FRAMES, MIN_EDGES, SOFT_SCENE, edge_profile_statistic, model_edge_profiles

#: Coring shapes: details under the threshold dropped ("hard") or every detail shrunk by it ("soft").
CORING = ("hard", "soft")
#: The planes enhanced: the luma (the boost added to R, G and B alike) or each of R, G, B.
CHANNELS = ("luma", "rgb")


def enhance_edges(frame: np.ndarray, gain: float, radius_px: float, coring_dn: float = 0.0, coring: str = "soft",
                  overshoot_dn: float = 255.0, undershoot_dn: float = 255.0, channels: str = "luma") -> np.ndarray:
    """An (H, W, 3) uint8 RGB frame with its edges enhanced (the module's formulas), rounded (uint8)."""
    f = np.asarray(frame, np.float32)
    planes = (f @ BT601_TO_YCC[0])[..., None] if channels == "luma" else f
    blurred = cv2.GaussianBlur(planes, (0, 0), radius_px, borderType=cv2.BORDER_REFLECT_101)
    d = planes - (blurred[..., None] if blurred.ndim == 2 else blurred)
    if coring_dn > 0:
        d = np.where(np.abs(d) >= coring_dn, d, 0.0) if coring == "hard" else \
            np.sign(d) * np.maximum(np.abs(d) - coring_dn, 0.0)
    boost = gain * d
    return to_uint8(f + np.minimum(np.maximum(boost, -undershoot_dn, out=boost), overshoot_dn, out=boost))


def fit_edge_enhancement(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): on the luma and on R, G, B, the gain and radius on coarse
    grids (soft coring, no clamps); for the better, gain and radius together on a finer grid (they trade against
    each other), the coring threshold and shape together with the gain (a harder coring drops detail that more
    gain restores), gain and radius finer, the coring and gain and radius
    again, the coring finer, the clamps of each side, then gain, radius and clamps finer
    (:func:`~lowcam.effects.delivered_frame.fit_delivered_stage`). While diagnosis screens: the luma's coarse
    grids only."""
    def finer(key, steps, lo, hi):
        return lambda v: [min(max(v[key] * k, lo), hi) for k in steps]

    def clamped(key):  # a clamp found finer, unless there is none (255)
        return lambda v: [255.0] if v[key] >= 255.0 else finer(key, (0.8, 1.0, 1.25), 0.0, 255.0)(v)

    clamps = (255.0, 60.0, 30.0, 15.0, 8.0, 4.0)
    coarse = [("gain", (0.5, 1.0, 2.0, 3.0)), ("radius_px", (0.6, 1.2, 2.5))]
    def together(steps):  # gain and radius searched together: a wider blur with less gain looks alike
        return lambda v: [(min(v["gain"] * a, 8.0), min(max(v["radius_px"] * b, 0.3), 6.0)) for a in steps
                          for b in steps]

    def cored(v):  # the coring's shape and threshold with the gain: a harder coring drops detail the gain restores
        return [(c, t, min(v["gain"] * k, 8.0)) for c in CORING for t in (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 11.0)
                for k in (0.85, 1.0, 1.18)]

    plan = [(("gain", "radius_px"), together((0.7, 0.85, 1.0, 1.18, 1.4))),
            (("coring", "coring_dn", "gain"), cored),
            (("gain", "radius_px"), together((0.86, 0.93, 1.0, 1.08, 1.16))),
            (("coring", "coring_dn"), [(c, t) for c in CORING for t in (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 11.0)]),
            (("gain", "radius_px"), together((0.9, 0.95, 1.0, 1.05, 1.1))),
            (("coring", "coring_dn"), lambda v: [(c, max(v["coring_dn"] + k, 0.0)) for c in CORING
                                                 for k in (-1.0, -0.5, 0.0, 0.5, 1.0)]),
            ("overshoot_dn", clamps),
            ("undershoot_dn", clamps),
            (("gain", "radius_px"), together((0.96, 1.0, 1.04))),
            ("overshoot_dn", clamped("overshoot_dn")),
            ("undershoot_dn", clamped("undershoot_dn"))]
    searches = [({"gain": 1.0, "radius_px": 1.2, "coring_dn": 0.0, "coring": "soft", "overshoot_dn": 255.0,
                  "undershoot_dn": 255.0, "channels": channels}, plan, coarse) for channels in CHANNELS]
    # cheap trials: a wider crop
    return fit_delivered_stage(ctx, effect, processed_by(EdgeEnhancement), searches, crop=(320, 448))

class EdgeEnhancement(Effect):
    """Edge enhancement of the delivered frame: ``gain`` times its cored detail (the frame less its Gaussian blur
    of ``radius_px``, details under ``coring_dn`` dropped or shrunk), the boost clamped to ``overshoot_dn`` above
    and ``undershoot_dn`` below (see the module's docstring)."""

    name = "edge_enhancement"
    section = "not in the paper"
    writes = "output"
    order = 274
    searches = (Search("edge_enhancement", "edges boosted {gain:.2f}x at radius {radius_px:.2f} px on the "
                       "{channels}, details under {coring_dn:.1f} DN cored ({coring}), halos clamped at "
                       "+{overshoot_dn:.0f}/-{undershoot_dn:.0f} DN", fit=fit_edge_enhancement, changes_noise=True,
                       captures="textured"),)
    params = {
        "gain": Param(1.0, low=0.0, high=8.0, doc="the detail's gain: 1 doubles an edge's step at its own scale"),
        "radius_px": Param(1.2, low=0.3, high=6.0, unit="px", doc="sigma of the Gaussian blur the detail is taken "
                                                                   "from"),
        "coring_dn": Param(0.0, low=0.0, high=64.0, unit="DN", doc="details under this are dropped or shrunk"),
        "coring": Param("soft", str, choices=CORING, doc="hard: small details dropped; soft: all shrunk by "
                                                        "coring_dn"),
        "overshoot_dn": Param(255.0, low=0.0, high=255.0, unit="DN", doc="the largest brightening (bright halo)"),
        "undershoot_dn": Param(255.0, low=0.0, high=255.0, unit="DN", doc="the largest darkening (dark halo)"),
        "channels": Param("luma", str, choices=CHANNELS, doc="luma: one boost for R, G and B; rgb: each its own"),
    }

    def process_frame(self, frame: np.ndarray) -> np.ndarray:
        """The whole (H, W, 3) uint8 frame enhanced (:func:`enhance_edges`)."""
        return enhance_edges(frame, self.gain, self.radius_px, self.coring_dn, self.coring, self.overshoot_dn,
                             self.undershoot_dn, self.channels)

    def apply(self, state):
        """Nothing before the blend: the enhancement acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        if frame.ndim != 3:
            raise self.error("acts on an RGB frame; a raw camera delivers a colour-filter mosaic")
        return within_footprint(frame, footprint, self.process_frame, math.ceil(4 * self.radius_px) + 1), footprint


fit_edge_enhancement.refines = True  # diagnosis calls it again, in full, for a promising candidate


#: Near-horizontal edges of the footage narrower than this share of the base's step, or with this much more
#: overshoot (a fraction of the step) than it, show an enhancement ...
NARROWER = 0.95
MORE_OVERSHOOT = 0.02
#: ... and an estimate is applied only with those halos or edges narrower than this share of the step (noise and a
#: base blurrier than the camera narrow the edges too, without halos).
MUCH_NARROWER = 0.8
#: Footage up to this share larger or smaller than the base profile's frame is scaled to it; beyond, not measurable.
SAME_SIZE = 0.05
#: The most confidence "no enhancement" gets: edges as sharp as a step without halos may be a soft scene enhanced.
NONE_CONFIDENCE = 0.45
_HALO_KEYS = ("edges", "width_10_90_px", "overshoot")
_DOWN = ("across_y",)  # the profiles down the frame, across near-horizontal edges


def edge_halo_statistic(frames) -> dict:
    """The edges, 10-90 % width (px) and overshoot (fraction of the step) of the mean profile across the strong,
    straight, near-horizontal edges of a stack (T, H, W, 3) float32 DN
    (:func:`lowcam.effects.sharpening.edge_profile_statistic`'s ``across_y``); ``{}`` without such edges."""
    stat = edge_profile_statistic(frames, across=_DOWN)["across_y"]
    return {k: stat[k] for k in _HALO_KEYS if k in stat}


def edge_enhancement_from_plate(footage, base, film):
    """The edge enhancement's gain and radius from footage's natural edges, as a
    :class:`lowcam.plate_estimate.PlateEstimate`.

    The mean profile across near-horizontal edges (:func:`edge_halo_statistic`, the footage scaled to the profile's
    frame, to which it must be within :data:`SAME_SIZE`), which the Fire-i's row filters do not shape, is set
    against the base profile without the stage filming ideal steps (rotated so that they fall at every phase of the
    pixel grid). Natural edges are never sharper than the camera makes a step; footage edges narrower than
    :data:`NARROWER` times the step, or with :data:`MORE_OVERSHOOT` more overshoot, were enhanced, and the gain and
    radius are fitted by least squares to the profile (the base's other settings of the stage kept). All of it is
    relative to the base's blur down the frame: a base blurrier than the camera makes natural edges look enhanced. A
    natural edge softer than a step reads the gain low (on a sharp scene the gain and radius trade: gain up to 1.5
    times the truth's at a smaller radius). Confidence ``0.9 min(1, edges / 100)``, halved where the fit misses the
    profile by 0.03 of the step or more (root mean square), and at most :data:`NONE_CONFIDENCE` (reported, not
    applied) without those halos unless the edges are narrower than :data:`MUCH_NARROWER` times the step (noise
    narrows the edges found a little, too). Edges as sharp as a step without halos say "no enhancement" with at most
    :data:`NONE_CONFIDENCE` and no params (a soft scene enhanced looks alike; a base's own stage is kept); edges
    over :data:`lowcam.effects.sharpening.SOFT_SCENE` times as wide as a step without halos, or fewer than
    :data:`lowcam.effects.sharpening.MIN_EDGES` edges, are not measurable. A scene drawn on the render's pixel grid
    (steps on pixel boundaries, which no pixel straddles) comes out sharper than natural edges and reads as
    enhanced."""
    from scipy.optimize import least_squares

    name, effect = "edge_halos", "edge_enhancement"
    frames = footage.stack(max_frames=EDGE_FRAMES)
    w, h = base.camera.width, base.camera.height
    fh, fw = frames.shape[1:3]
    if max(abs(fw / w - 1), abs(fh / h - 1)) > SAME_SIZE:
        return PlateEstimate.not_measurable(name, effect, {}, f"the footage's {fw}x{fh} frames differ in size from "
                                            f"the base profile's {w}x{h}, and scaling them changes every edge's "
                                            "width: a base profile of the footage's size is needed")
    if (fh, fw) != (h, w):
        frames = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames])
    stat = edge_profile_statistic(frames, max_frames=len(frames), across=_DOWN)["across_y"]
    measured = {k: stat[k] for k in _HALO_KEYS if k in stat}
    n = measured.get("edges", 0)
    if n < MIN_EDGES:
        return PlateEstimate.not_measurable(name, effect, measured, f"too little texture to estimate edge "
                                            f"enhancement: {n} near-horizontal strong straight edges (at least "
                                            f"{MIN_EDGES} needed)")
    have = base.effect(effect)
    plain = base.without(effect) if have is not None else base
    at: dict = {}
    step = model_edge_profiles(plain, {}, film, None, at, across=_DOWN)["across_y"]
    if not step.get("edges"):
        return PlateEstimate.not_measurable(name, effect, measured, "the base profile films no straight edges of "
                                            "its steps to compare with")
    width, over = stat["width_10_90_px"], stat["overshoot"]
    measured.update(step_width_10_90_px=step["width_10_90_px"], step_overshoot=step["overshoot"])
    against = (f"{n} near-horizontal edges {width:.2f} px wide (10-90 %), overshoot {over:.3f} of the step; the "
               f"base makes a step {step['width_10_90_px']:.2f} px wide, overshoot {step['overshoot']:.3f}")
    if width >= NARROWER * step["width_10_90_px"] and over <= step["overshoot"] + MORE_OVERSHOOT:
        if width > SOFT_SCENE * step["width_10_90_px"]:
            return PlateEstimate.not_measurable(name, effect, measured, against + ": a scene softer than steps, "
                                                "without halos, shows no enhancement and could hide one")
        confidence = min(NONE_CONFIDENCE, 0.9 * min(1.0, n / 100))
        return PlateEstimate(name, effect, measured, {}, round(confidence, 3),
                             against + ": no edge enhancement, or one that a softer scene hides" +
                             ("; the base's own enhancement is kept" if have is not None and have.enabled else ""))
    target = np.asarray(stat["profile"])
    keys = (f"{effect}.gain", f"{effect}.radius_px")

    def residual(p):
        m = model_edge_profiles(base, dict(zip(keys, p)), film, at, across=_DOWN)["across_y"]
        return np.asarray(m["profile"]) - target if m.get("edges") else np.ones_like(target)

    hi = (EdgeEnhancement.params["gain"].high, EdgeEnhancement.params["radius_px"].high)
    lo = (EdgeEnhancement.params["gain"].low, EdgeEnhancement.params["radius_px"].low)
    start = (have.gain, have.radius_px) if have is not None else (1.0, 1.2)
    sol = least_squares(residual, np.clip(start, lo, hi), bounds=(lo, hi), diff_step=0.05, max_nfev=16)
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    gain, radius = (round(float(v), 3) for v in sol.x)
    measured["fit_rms"] = round(rms, 4)
    confidence = 0.9 * min(1.0, n / 100) * (1.0 if rms < 0.03 else 0.5)
    why = (against + f": enhanced, gain {gain:.2f} at radius {radius:.2f} px (profile fit rms {rms:.3f}; a scene "
           "softer than steps reads the gain low)")
    if over <= step["overshoot"] + MORE_OVERSHOOT and width >= MUCH_NARROWER * step["width_10_90_px"]:
        confidence = min(confidence, NONE_CONFIDENCE)
        why += ("; narrower edges without halos: noise, or a base blurrier down the frame than the camera, narrow "
                "them too, so it is reported, not applied")
    return PlateEstimate(name, effect, measured, {"gain": gain, "radius_px": radius}, round(confidence, 3), why)


#: Declared after its estimator and statistic, which the module defines below the class.
EdgeEnhancement.plate_probe = PlateProbe(
    "edge_halos", edge_enhancement_from_plate, edge_halo_statistic, order=8,
    about="width and halos across natural near-horizontal edges, against the base filming steps (before the "
          "horizontal sharpening, which fits the edges across the rows through it)")
