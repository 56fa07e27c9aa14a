"""Spatial noise reduction of a camera's image processor: luma and chroma filtered apart (not in the paper).

Today's phones, action cameras and webcams smooth the frame before they deliver it: white sensor noise becomes
blotchy, low-pass noise, and fine texture of low contrast is wiped while edges stay. The stage filters the
delivered frame's full-range BT.601 luma with ``luma_strength_dn`` and its chroma with ``chroma_strength_dn``
(:mod:`~lowcam.effects.delivered_frame`), with one of two edge-preserving filter families, both OpenCV's:

- ``bilateral`` [Tomasi1998]: ``cv2.bilateralFilter``, range sigma = the strength (DN), spatial sigma =
  ``scale_px``, over a window of ``2 ceil(2 scale_px) + 1`` px;
- ``nl_means`` [Buades2005]: ``cv2.fastNlMeansDenoising``, filter parameter ``h`` = the strength (DN), 7x7
  patches compared over a search window of ``2 round(scale_px) + 1`` px (chroma: both planes as one
  two-channel image).

A strength of 0 leaves that part of the frame as it is. The processed frame replaces the delivered one only where
the graphics reach (the plate already went through the camera's filter).

Contents
--------
- :data:`METHODS`: the filter families
- :func:`denoise_plane`: one plane (or a two-channel stack) filtered by a family at a strength and scale
- :func:`denoise_frame`: an RGB frame's luma and chroma filtered apart
- :func:`fit_noise_reduction`: diagnosis's fit: the family, strengths and scale whose filtered noisy model frames
  best match the measured frames' means and noise (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`NoiseReduction`: the stage
- :func:`neighbour_correlation`, :func:`smoothed_noise_statistic`, :func:`noise_reduction_from_plate`: the plate
  probe: how much a still shot's noise correlates with its neighbours' and how much of it there is, against the
  base profile filming the shot's scene with a noise law scaled and the filter at a strength

It has no compositor node: Blender's compositor has no non-local-means filter, and its Bilateral Blur node
(iterated 3x3 passes with a determinator image) is not OpenCV's bilateral filter, so the node group could not
give the engine's frame; ``lowcam.node_maps.bake`` refuses a profile with it, and the render handler, which runs
the engine, simulates it.

References
----------
- [Tomasi1998] C. Tomasi and R. Manduchi, "Bilateral filtering for gray and color images", Proc. ICCV 1998,
  839-846.
- [Buades2005] A. Buades, B. Coll and J.-M. Morel, "A non-local algorithm for image denoising", Proc. CVPR 2005,
  vol. 2, 60-65 (OpenCV's fastNlMeansDenoising: the same with integral images over the search window).
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 YCbCr).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..plate_estimate import PlateEstimate, PlateProbe, holds_still, inter_frame_coded, register_footage
from .base import Effect, Param, Search
from .delivered_frame import (fit_delivered_stage, processed_by, to_uint8, to_ycc, within_footprint,
                              ycc_change_to_rgb)
from .noise import PLATE_PAIRS, STILL_PX

#: The filter families: OpenCV's bilateral filter and its fast non-local means.
METHODS = ("bilateral", "nl_means")


def _window(method: str, scale_px: float) -> int:
    """The filter's window (px, odd): the bilateral's kernel, the non-local means' search window."""
    if method == "bilateral":
        return 2 * math.ceil(2 * scale_px) + 1
    return 2 * max(int(round(scale_px)), 1) + 1


def denoise_plane(plane: np.ndarray, method: str, strength_dn: float, scale_px: float) -> np.ndarray:
    """``plane`` (H, W) or (H, W, 2) float32 (DN; chroma centred on 0) filtered by ``method`` at ``strength_dn``
    (the bilateral's range sigma, the non-local means' ``h``) and ``scale_px`` (see the module's docstring),
    float32. The non-local means reads 8-bit values: the plane is rounded (chroma offset by 128) and the filter's
    change added to it."""
    plane = np.asarray(plane, np.float32)
    if strength_dn <= 0:
        return plane
    window = _window(method, scale_px)
    if method == "bilateral":
        if plane.ndim == 3:
            return np.dstack([cv2.bilateralFilter(np.ascontiguousarray(plane[..., k]), window, strength_dn,
                                                  scale_px, borderType=cv2.BORDER_REFLECT_101)
                              for k in range(plane.shape[2])])
        return cv2.bilateralFilter(plane, window, strength_dn, scale_px, borderType=cv2.BORDER_REFLECT_101)
    offset = 0.0 if plane.ndim == 2 else 128.0
    q = np.clip(np.rint(plane + offset), 0, 255).astype(np.uint8)
    out = cv2.fastNlMeansDenoising(np.ascontiguousarray(q), None, float(strength_dn), 7, window)
    return plane + (out.astype(np.float32) - q)


def denoise_frame(frame: np.ndarray, method: str, luma_strength_dn: float, chroma_strength_dn: float,
                  scale_px: float) -> np.ndarray:
    """An (H, W, 3) uint8 RGB frame with its luma filtered at ``luma_strength_dn`` and its chroma (Cb, Cr) at
    ``chroma_strength_dn`` (:func:`denoise_plane`), the changes taken back to RGB, rounded (uint8)."""
    ycc = to_ycc(frame)
    change = np.zeros_like(ycc)
    if luma_strength_dn > 0:
        change[..., 0] = denoise_plane(ycc[..., 0], method, luma_strength_dn, scale_px) - ycc[..., 0]
    if chroma_strength_dn > 0:
        change[..., 1:] = denoise_plane(ycc[..., 1:], method, chroma_strength_dn, scale_px) - ycc[..., 1:]
    return to_uint8(frame.astype(np.float32) + ycc_change_to_rgb(change))


def fit_noise_reduction(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): for each family, the luma strength on a coarse grid at the
    family's usual scale, no chroma; for the family that fits best, the luma strength finer, the scale, the chroma
    strength and each finer again (:func:`~lowcam.effects.delivered_frame.fit_delivered_stage`). While diagnosis
    screens: the bilateral family's coarse grid only (it shows whether smoothing helps; the non-local means costs
    5-10 times as much)."""
    finer = lambda key, f: (lambda v: [min(max(v[key] * k, 0.0), 60.0) for k in f])  # noqa: E731
    searches = []
    for method in METHODS:
        scales = (1.0, 1.5, 2.0, 3.0) if method == "bilateral" else (3.0, 5.0, 10.0)
        coarse = [("luma_strength_dn", (3.0, 8.0, 20.0, 45.0))]
        plan = [("luma_strength_dn", finer("luma_strength_dn", (0.6, 0.78, 1.0, 1.28, 1.65))),
                ("scale_px", scales),
                ("luma_strength_dn", finer("luma_strength_dn", (0.85, 0.93, 1.0, 1.08, 1.17))),
                ("chroma_strength_dn", (0.0, 5.0, 12.0, 30.0)),
                ("chroma_strength_dn", finer("chroma_strength_dn", (0.7, 1.0, 1.4))),
                ("scale_px", lambda v: [min(max(v["scale_px"] * k, 0.5), 12.0) for k in (0.85, 1.0, 1.18)]),
                ("luma_strength_dn", finer("luma_strength_dn", (0.95, 1.0, 1.05)))]
        usual = 2.0 if method == "bilateral" else 5.0
        start = {"method": method, "luma_strength_dn": 8.0, "chroma_strength_dn": 0.0, "scale_px": usual}
        searches.append((start, plan, coarse))
    return fit_delivered_stage(ctx, effect, processed_by(NoiseReduction), searches)


class NoiseReduction(Effect):
    """Spatial noise reduction of the delivered frame: its luma filtered at ``luma_strength_dn`` and its chroma at
    ``chroma_strength_dn`` by an edge-preserving filter of the family ``method`` and spatial ``scale_px``
    (OpenCV's ``bilateralFilter`` or ``fastNlMeansDenoising``; see the module's docstring)."""

    name = "noise_reduction"
    section = "not in the paper"
    writes = "output"
    order = 272
    searches = (Search("noise_reduction", "noise smoothed and fine texture wiped: {method} filter, luma strength "
                       "{luma_strength_dn:.1f} DN, chroma {chroma_strength_dn:.1f} DN, scale {scale_px:.1f} px",
                       fit=fit_noise_reduction, changes_noise=True),)
    params = {
        "method": Param("bilateral", str, choices=METHODS, doc="the filter family: bilateral or non-local means"),
        "luma_strength_dn": Param(8.0, low=0.0, high=60.0, unit="DN",
                                  doc="the luma filter's strength: the bilateral's range sigma, the non-local "
                                      "means' h; 0: luma untouched"),
        "chroma_strength_dn": Param(0.0, low=0.0, high=60.0, unit="DN",
                                    doc="the chroma filter's strength (Cb, Cr), as luma_strength_dn"),
        "scale_px": Param(2.0, low=0.5, high=12.0, unit="px",
                          doc="the bilateral's spatial sigma; the non-local means' search radius"),
    }

    def process_frame(self, frame: np.ndarray) -> np.ndarray:
        """The whole (H, W, 3) uint8 frame filtered (:func:`denoise_frame`)."""
        return denoise_frame(frame, self.method, self.luma_strength_dn, self.chroma_strength_dn, self.scale_px)

    def apply(self, state):
        """Nothing before the blend: the filter acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        if frame.ndim != 3:
            raise self.error("acts on an RGB frame; a raw camera delivers a colour-filter mosaic")
        reach = _window(self.method, self.scale_px) // 2 + 3
        return within_footprint(frame, footprint, self.process_frame, reach), footprint


fit_noise_reduction.refines = True  # diagnosis calls it again, in full, for a promising candidate


#: The grid the plate's statistics are read against: the base's noise sigma scaled by these, and the bilateral
#: filter's luma strength (DN) at :data:`PLATE_SCALE_PX`.
PLATE_NOISE_SCALES = (0.5, 0.8, 1.25, 2.0)
PLATE_STRENGTHS = (0.0, 5.0, 10.0, 20.0, 40.0)
PLATE_SCALE_PX = 2.0
#: A fitted strength under this (DN) is no noise reduction.
PLATE_NONE_BELOW = 2.5
#: A strength whose model correlation is within this of the strongest filter's is a lower bound.
SATURATED_WITHIN = 0.015


def neighbour_correlation(differences: np.ndarray) -> tuple[float, float] | None:
    """(correlation of the noise with its neighbour's, averaged right and down; the noise's variance in one frame,
    DN^2) from differences of still frame pairs (P, H, W, C; NaN where not compared), on their grey (channel
    mean): a difference holds two frames' noise and no scene. White noise correlates about 0 with its neighbours;
    a spatial denoiser (or a blur, a demosaic) raises it. None without noise."""
    d = np.asarray(differences, np.float32).mean(-1)
    right = d[:, :, 1:] * d[:, :, :-1]
    down = d[:, 1:] * d[:, :-1]
    var = float(np.nanmean(np.square(d))) if np.isfinite(d).any() else 0.0
    if var <= 1e-9 or not (np.isfinite(right).any() and np.isfinite(down).any()):
        return None
    return 0.5 * (float(np.nanmean(right)) + float(np.nanmean(down))) / var, var / 2


def smoothed_noise_statistic(frames: np.ndarray) -> dict:
    """The plate statistic: the neighbour correlation of the noise in a still stack's (T >= 2, H, W, 3)
    consecutive differences (:func:`neighbour_correlation`); ``{}`` for one frame or a stack that moves."""
    frames = np.asarray(frames, np.float32)
    if len(frames) < 2 or not holds_still(frames):
        return {}
    got = neighbour_correlation(np.diff(frames, axis=0))
    return {} if got is None else {"neighbour_correlation": round(got[0], 4)}


def _scaled_noise(profile, k: float):
    noise = profile.effect("noise")
    power = 1 if noise.law == "sigma_linear" else 2
    return profile.with_effect("noise", **{ch: [v * k ** power for v in getattr(noise, ch)]
                                          for ch in ("red", "green", "blue")})


def noise_reduction_from_plate(footage, base, film):
    """The spatial noise reduction's luma strength from footage, as a :class:`lowcam.plate_estimate.PlateEstimate`.

    Frame pairs spread over the shot are registered (:func:`lowcam.plate_estimate.register_footage`) and those
    that hold still (no pixel moves half a pixel) give the noise's neighbour correlation and variance
    (:func:`neighbour_correlation`). The base profile without the stage films the shot's scene (the middle frame
    of those pairs) twice with its noise scaled by each of :data:`PLATE_NOISE_SCALES` and a bilateral filter of
    each luma strength of :data:`PLATE_STRENGTHS` (scale :data:`PLATE_SCALE_PX`): a denoiser correlates the noise
    and lowers it, a louder sensor only raises it, so the two statistics together place the footage on that grid
    (interpolated: ``(ln variance / 0.05)^2 + (correlation / 0.02)^2`` the smallest). A strength under
    :data:`PLATE_NONE_BELOW` is none (a base's stage is turned off); one whose model correlation is within
    :data:`SATURATED_WITHIN` of the strongest filter's is said to be a lower bound (a range sigma that takes in
    all the noise smooths it as a blur does). The noise law's probe, after it, reads the law
    through the stage. Confidence ``0.9 min(1, pairs / 3)``, halved where the best point lies on the grid's edge
    (the largest strength or an outer noise scale); a video whose inter-frame coding smooths and holds noise caps
    it at 0.4. Without a still pair, or a base without a noise law: not measurable."""
    name, effect = "smoothed_noise", "noise_reduction"
    if base.effect("noise") is None:
        return PlateEstimate.not_measurable(name, effect, {}, "the base profile has no noise law to filter")
    pairs = register_footage(footage, PLATE_PAIRS)
    still = [k for k, r in enumerate(pairs.registrations) if r.motion_px < STILL_PX]
    if not still:
        return PlateEstimate.not_measurable(name, effect, {}, "no still frame pair: the noise's texture shows only "
                                            "where nothing moves")
    got = neighbour_correlation(pairs.select(still).diff)
    if got is None:
        return PlateEstimate.not_measurable(name, effect, {}, "the still frame pairs hold no noise")
    corr, var = got
    scene = footage.frame(pairs.pairs[still[len(still) // 2]][0]) if pairs.pairs else footage.frame(0)

    def ideal(width, height):
        out = np.ones((height, width, 4), np.float32)
        out[..., :3] = np.clip(cv2.resize(scene, (width, height), interpolation=cv2.INTER_AREA) / 255.0, 0, 1)
        return out

    have = base.effect(effect)
    plain = base.without(effect) if have is not None else base
    grid_c = np.zeros((len(PLATE_NOISE_SCALES), len(PLATE_STRENGTHS)))
    grid_v = np.zeros_like(grid_c)
    for i, k in enumerate(PLATE_NOISE_SCALES):
        noisy = _scaled_noise(plain, k)
        for j, strength in enumerate(PLATE_STRENGTHS):
            model = noisy if strength == 0 else noisy.with_effect(effect, method="bilateral", luma_strength_dn=strength,
                                                                 chroma_strength_dn=0.0, scale_px=PLATE_SCALE_PX)
            a, b = (film(model, ideal, seed=0, frame=f) for f in (0, 1))
            grid_c[i, j], grid_v[i, j] = neighbour_correlation((a - b)[None])
    fine_k = np.linspace(np.log(PLATE_NOISE_SCALES[0]), np.log(PLATE_NOISE_SCALES[-1]), 61)
    fine_s = np.linspace(PLATE_STRENGTHS[0], PLATE_STRENGTHS[-1], 161)

    def lattice(grid):  # the grid interpolated on a fine lattice of (log noise scale, strength)
        along_s = np.array([np.interp(fine_s, PLATE_STRENGTHS, row) for row in grid])
        return np.array([np.interp(fine_k, np.log(PLATE_NOISE_SCALES), col) for col in along_s.T]).T

    fine_c = lattice(grid_c)
    cost = np.square((np.log(lattice(grid_v)) - np.log(var)) / 0.05) + np.square((fine_c - corr) / 0.02)
    bi, bj = np.unravel_index(int(np.argmin(cost)), cost.shape)
    strength, scale = float(fine_s[bj]), float(np.exp(fine_k[bi]))
    # a filter whose range takes in all of this noise smooths it as a blur does, whatever its strength
    saturated = strength >= PLATE_NONE_BELOW and fine_c[bi, -1] - fine_c[bi, bj] < SATURATED_WITHIN
    measured = {"pairs": len(still), "neighbour_correlation": round(corr, 4), "variance_dn2": round(var, 3),
                "model_without": round(float(np.interp(0.0, np.log(PLATE_NOISE_SCALES), grid_c[:, 0])), 4),
                "noise_scale": round(scale, 3)}
    edge = bj == len(fine_s) - 1 or bi in (0, len(fine_k) - 1)
    confidence = 0.9 * min(1.0, len(still) / 3) * (0.5 if edge else 1.0)
    why = (f"{len(still)} still frame pairs: noise correlated {corr:.2f} with its neighbours, variance {var:.2f} "
           f"DN^2; the base filming their scene matches them with its noise x{scale:.2f} and a bilateral luma "
           f"filter of {strength:.1f} DN")
    if edge:
        why += " (at the edge of the grid searched)"
    if saturated:
        measured["strength_at_least"] = True
        why += (f"; at least that: stronger filters smooth noise this faint alike (correlation within "
                f"{SATURATED_WITHIN} of the strongest's), and the noise law read through it is the same")
    if inter_frame_coded(footage):
        confidence = min(confidence, 0.4)
        why += "; the clip's inter-frame coding smooths and holds noise as well: reported, not applied"
    if strength < PLATE_NONE_BELOW:
        params = {"enabled": False} if have is not None and have.enabled else {}
        return PlateEstimate(name, effect, measured, params, round(confidence, 3), why + ": no noise reduction")
    params = {"method": "bilateral", "luma_strength_dn": round(strength, 2), "chroma_strength_dn": 0.0,
              "scale_px": PLATE_SCALE_PX}
    return PlateEstimate(name, effect, measured, params, round(confidence, 3), why)


#: Declared after its estimator and statistic, which the module defines below the class.
NoiseReduction.plate_probe = PlateProbe(
    "smoothed_noise", noise_reduction_from_plate, smoothed_noise_statistic, order=36,
    about="the noise's correlation with its neighbours in still frames: a spatial denoiser (before the noise law, "
          "which it lowers)")
