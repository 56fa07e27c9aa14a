"""Temporal noise reduction of a camera's image processor: a recursive, motion-adaptive filter over the delivered
frames (not in the paper).

Phones, action cameras, drones and webcams average each pixel with the frame they delivered before, where the
pixel does not move [Brailean1995]: a first-order recursive (IIR) filter, ``out_t = k in_t`` ... more exactly

    ``out_t = (1 - k_t) in_t + k_t out_{t-1}``,  ``k_t = strength * clip(2 - 2 |Y(in_t) - Y(out_{t-1})| / T, 0, 1)``

per pixel, with ``Y`` the full-range BT.601 luma, ``T`` = ``motion_threshold_dn`` and ``strength`` the share of
the last frame kept on a still pixel; the filter keeps its output at full precision (an image processor's is
wider than 8 bits) and delivers it rounded. The weight is the same for R, G and B. On a still scene, at a constant
``k``, the noise's variance falls to ``(1 - k) / (1 + k)`` of the input's (and the rounding's 1/12 DN^2 is added)
and the noise is held from one frame to the next (correlation ``k``). A pixel whose luma changes by less than
``T / 2`` (noise) keeps the full strength; from there the weight falls linearly, and where the luma changes by
``T`` or more (motion, a cut) the pixel takes the new frame alone, so moving edges leave a short trail below that.

The previous output is the frame the camera delivered: where the graphics reach in a frame the stage filters them
with the frame before; elsewhere the plate keeps its bytes (it went through the camera's filter already) and is
what the next frame's graphics are averaged with.

Frames in sequence and single frames
------------------------------------
The filter acts on sequences (``temporal``): the frames of one capture of a measurement set (and the model's
frames that ``compare`` and diagnosis simulate) are filtered as one sequence, after :meth:`lead_frames` frames
of other noise that bring the filter to its steady state, as a real camera is mid-stream when it is recorded.
In a shot (``lowcam batch``) each frame is filtered with the frame the shot delivered before it (its written
8-bit output, :meth:`TemporalNoiseReduction.finish_after`: within half a DN of the filter's own state, and what a
resumed shot reads again), so the shot's frames are made in order; the stage comes after
the spatial stages, before a JPEG or video coder, so that frame is the filter's own output unless a coder
follows. The shot's first frame, and a frame made on its own (``lowcam.simulate`` without ``previous``), have no
frame before them and leave the stage unchanged.

Contents
--------
- :func:`frame_to_frame_correlation`: how much of a still stack's noise is held from one frame to the next
- :func:`filter_sequence`: (T, H, W, 3) uint8 frames through the recursive filter
- :func:`fit_temporal_noise_reduction`: diagnosis's fit: strength and motion threshold whose filtered noisy model
  sequences best match the measured frames' means and noise
  (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`TemporalNoiseReduction`: the stage
- :func:`noisy_pixels`: the pixels of a grey stack whose noise shows (those that change over the frames)
- :func:`held_share`: the share of a still stack's noise held from one frame to the next (its temporal variogram)
- :func:`held_noise_statistic`, :func:`temporal_noise_reduction_from_plate`: the plate probe: the noise held from
  frame to frame in the footage's still frames, and the strength that holds as much

It has no compositor node: a compositor node tree computes one frame from that frame's inputs and holds nothing
from the frame before, so ``lowcam.node_maps.bake`` refuses a profile with it; the render handler, which runs
the engine, simulates it.

References
----------
- [Brailean1995] J. C. Brailean, R. P. Kleihorst, S. Efstratiadis, A. K. Katsaggelos and R. L. Lagendijk, "Noise
  reduction filters for dynamic image sequences: a review", Proceedings of the IEEE 83(9), 1272-1292, 1995
  (recursive temporal filters, motion-adaptive weights, sec. III).
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 luma).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..plate_estimate import PlateEstimate, PlateProbe, holds_still, inter_frame_coded, still_segments
from .base import Effect, Param, Search
from .delivered_frame import BT601_TO_YCC, fit_delivered_stage

#: The largest share of the last frame the stage keeps (a filter that keeps more never settles over a shot).
MAX_STRENGTH = 0.9
#: The weight left on the frame before the lead frames when the sequence's first frame is delivered.
_SETTLED = 0.05
_LUMA = BT601_TO_YCC[0]


def lead_frames(strength: float) -> int:
    """Frames a filter of ``strength`` needs before its output no longer shows where it started: the smallest
    ``L`` with ``strength^L <= 0.05`` (0 for a strength of 0)."""
    if strength <= 0:
        return 0
    return int(math.ceil(math.log(_SETTLED) / math.log(min(strength, MAX_STRENGTH))))


def frame_to_frame_correlation(frames: np.ndarray) -> float | None:
    """The correlation of a still stack's temporal noise from one frame to the next (n >= 3 frames (n, H, W, 3)),
    ``1 - var(F_{t+1} - F_t) / (2 var(N) n / (n - 1))`` on the grey (channel mean), ``N_t = F_t - mean(F)``: 0 for
    noise drawn anew each frame (the mean's bias corrected for such noise), above 0 where a stage holds it (this
    filter, a video encoder's predicted frames), 1.0 for frames that hold no temporal noise at all. None with fewer
    than 3 frames."""
    n = len(frames)
    if n < 3:
        return None
    grey = np.asarray(frames).astype(np.float32).mean(-1)
    var = float(np.mean(np.square(grey - grey.mean(0))))
    if var <= 1e-9:
        return 1.0
    step = float(np.mean(np.square(np.diff(grey, axis=0))))
    return float(1.0 - step / (2.0 * var * n / (n - 1)))


def filter_sequence(frames: np.ndarray, strength: float, motion_threshold_dn: float, footprints=None) -> np.ndarray:
    """``frames`` (T, H, W, 3) uint8 through the recursive filter of the module's docstring, in order: (T, H, W, 3)
    uint8, frame 0 as it is (the filter's state at full precision, each output rounded). ``footprints`` (T, H, W)
    bool: where the filter acts in each frame (all when None); elsewhere a frame keeps its bytes, and those are
    what the next frame is averaged with."""
    frames = np.asarray(frames)
    out = np.empty_like(frames)
    if len(frames) == 0:
        return out
    out[0] = frames[0]
    if strength <= 0:
        out[1:] = frames[1:]
        return out
    luma = _LUMA.reshape(1, 3).astype(np.float32)
    slope = np.float32(2 * strength / motion_threshold_dn)
    previous = frames[0].astype(np.float32)
    for t in range(1, len(frames)):
        current = frames[t].astype(np.float32)
        step = cv2.subtract(previous, current)  # the last output less this frame
        k = np.abs(cv2.transform(step, luma))   # |luma change| ...
        k *= -slope
        k += np.float32(2 * strength)
        np.clip(k, 0.0, strength, out=k)        # ... as the weight of the last output
        if footprints is not None:
            k *= footprints[t]
        previous = cv2.add(current, cv2.multiply(step, cv2.merge((k, k, k))))
        out[t] = cv2.convertScaleAbs(previous)  # rounded (a mean of 0-255 values needs no clipping)
    return out


def fit_temporal_noise_reduction(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): the strength on a coarse grid at a motion threshold of 16 DN,
    then the threshold, then each finer (:func:`~lowcam.effects.delivered_frame.fit_delivered_stage`). The model
    keeps its noise and is simulated once without the stage, as many frames as the captures have and the lead
    frames of the strongest filter searched before them; each trial filters those again (with the lead frames its
    own strength needs) and drops the lead. The
    filter holds noise from frame to frame, so two sequences of independent noise measure the noise of the mean
    (``frozen_noise``)."""
    caps = ctx.mset.captures
    frames = max(3, max(len(caps[i].frames) for i in ctx.quick))
    lead = lead_frames(MAX_STRENGTH)

    def process(values, stack):  # the trial's own lead frames only: fewer for a weaker filter
        own = lead_frames(values["strength"])
        return filter_sequence(stack[lead - own:], values["strength"], values["motion_threshold_dn"])[own:]


    def finer(key, factors, low, high):
        return lambda v: sorted({round(min(max(v[key] * f, low), high), 3) for f in factors})

    coarse = [("strength", (0.2, 0.4, 0.6, 0.75, 0.85))]
    plan = [("motion_threshold_dn", (4.0, 8.0, 16.0, 32.0, 64.0)),
            ("strength", finer("strength", (0.85, 0.93, 1.0, 1.07, 1.15), 0.05, MAX_STRENGTH)),
            ("motion_threshold_dn", finer("motion_threshold_dn", (0.7, 0.85, 1.0, 1.2, 1.4), 1.0, 255.0)),
            ("strength", finer("strength", (0.96, 1.0, 1.04), 0.05, MAX_STRENGTH))]
    start = {"strength": 0.5, "motion_threshold_dn": 16.0}
    return fit_delivered_stage(ctx, effect, process, [(start, plan, coarse)], count=frames, lead=lead,
                               frozen_noise=True)


fit_temporal_noise_reduction.refines = True  # diagnosis calls it again, in full, for a promising candidate


class TemporalNoiseReduction(Effect):
    """Temporal noise reduction of the delivered frames: each pixel averaged with the last delivered frame by a
    share ``strength``, full up to half of ``motion_threshold_dn``'s luma change and 0 from it on (see the module's
    docstring)."""

    name = "temporal_noise_reduction"
    section = "not in the paper"
    writes = "output"
    order = 276  # after the spatial stages, before a coder: the delivered frame is what the next is averaged with
    temporal = True
    searches = (Search("temporal_noise_reduction", "noise held from frame to frame: {strength:.2f} of the last "
                       "frame kept on still pixels, none where the luma changes by {motion_threshold_dn:.0f} DN",
                       fit=fit_temporal_noise_reduction, changes_noise=True, held_noise=True),)
    params = {
        "strength": Param(0.5, low=0.0, high=MAX_STRENGTH,
                          doc="the share of the last delivered frame kept on a still pixel; 0: off"),
        "motion_threshold_dn": Param(16.0, low=1.0, high=255.0, unit="DN",
                                     doc="the luma change from the last delivered frame at which a pixel counts "
                                         "as moving and keeps none of it"),
    }

    follows_previous = True

    def lead_frames(self) -> int:
        return lead_frames(self.strength)

    def finish_after(self, previous, frame, footprint):
        """``frame`` filtered with ``previous``, the frame the shot delivered before it, where the graphics reach
        (:func:`filter_sequence` of the two)."""
        previous = np.asarray(previous)
        if frame.ndim != 3 or previous.shape != frame.shape or previous.dtype != np.uint8:
            raise self.error(f"needs the frame before as {frame.shape} 8-bit RGB, got {previous.dtype} "
                             f"{previous.shape}")
        pair = np.stack([previous, frame])
        return filter_sequence(pair, self.strength, self.motion_threshold_dn, np.stack([footprint, footprint]))[1], \
            footprint

    def apply(self, state):
        """Nothing before the blend: the filter acts on the delivered frames (:meth:`finish_frames`)."""

    def finish(self, state, frame, footprint):
        """A frame on its own has no frame before it: unchanged."""
        if frame.ndim != 3:
            raise self.error("acts on an RGB frame; a raw camera delivers a colour-filter mosaic")
        return frame, footprint

    def finish_frames(self, frames, footprints):
        """The frames (T, H, W, 3) uint8 filtered in order where the graphics reach (``footprints``), the plate's
        own bytes elsewhere (:func:`filter_sequence`)."""
        frames = np.asarray(frames)
        if frames.ndim != 4:
            raise self.error("acts on RGB frames; a raw camera delivers a colour-filter mosaic")
        return filter_sequence(frames, self.strength, self.motion_threshold_dn, footprints), footprints


#: A plate shows held noise on a run of at least this many still frames; at most :data:`PLATE_FRAMES` are read.
PLATE_MIN_FRAMES = 4
PLATE_FRAMES = 16
#: A share held at most this much (and two standard errors) above 0 is no filter.
PLATE_NONE_BELOW = 0.05
#: The motion threshold a plate estimate sets: at least this many times the standard deviation of the luma change
#: the filter sees on still frames (so that the noise keeps the full strength: under half of it).
NOISE_STEPS = 8.0
#: The variance the 8-bit rounding of R, G and B adds to their mean (DN^2): (1/12) / 3.
_GREY_ROUNDING = 1 / 36
_TILES = 4


def noisy_pixels(grey: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of a stack's grey (n, H, W) that change over the frames: not a letterbox's black or
    a highlight held at 255, where no noise shows. (Pixels that touch 0 or 255 now and then stay: leaving them out
    would choose pixels by how their noise ran.)"""
    return grey.max(0) > grey.min(0)


def held_share(frames: np.ndarray) -> float | None:
    """The share ``k`` of a still stack's (n >= 3, (n, H, W, 3)) noise that a first-order recursive filter holds
    from one frame to the next, from the noise's temporal variogram on the grey (channel mean): the mean squared
    change over one frame ``D1 = 2 v (1 - k)`` and over two ``D2 = 2 v (1 - k^2)``, so ``k = D2 / D1 - 1``, each
    less the output rounding's ``2 q`` (``q = 1/36`` DN^2 on the grey). Differences cancel the scene and the
    frames' slow drift, which biases a lag-one correlation over few frames. Only pixels that carry noise count
    (:func:`noisy_pixels`: black bars and clipped highlights would add the rounding's share without its change).
    0 for noise drawn anew each frame; None with fewer than 3 frames or no temporal noise beyond the rounding."""
    if len(frames) < 3:
        return None
    grey = np.asarray(frames).astype(np.float32).mean(-1)
    grey = grey[:, noisy_pixels(grey)]
    if grey.size == 0:
        return None
    d1 = float(np.mean(np.square(grey[1:] - grey[:-1]))) - 2 * _GREY_ROUNDING
    d2 = float(np.mean(np.square(grey[2:] - grey[:-2]))) - 2 * _GREY_ROUNDING
    if d1 <= 2 * _GREY_ROUNDING:  # hardly more than the rounding: the ratio says nothing
        return None
    return float(np.clip(d2 / d1 - 1.0, -1.0, 1.0))


def held_noise_statistic(frames: np.ndarray) -> dict:
    """The plate statistic: the share of a still stack's (T, H, W, 3) noise held from one frame to the next
    (:func:`held_share`), ``{}`` where the stack has fewer than :data:`PLATE_MIN_FRAMES` frames or moves (a moving
    scene's change is no noise)."""
    if len(frames) < PLATE_MIN_FRAMES or not holds_still(frames):
        return {}
    k = held_share(frames)
    return {} if k is None else {"held_share": round(k, 4)}


def temporal_noise_reduction_from_plate(footage, base, film):
    """The temporal filter's strength from footage, as a :class:`lowcam.plate_estimate.PlateEstimate`.

    The longest run of still frames (:func:`lowcam.plate_estimate.still_segments`, at least
    :data:`PLATE_MIN_FRAMES`, its first :data:`PLATE_FRAMES` read) gives the share of the noise held from one
    frame to the next (:func:`held_share`: the strength a still pixel is filtered with), and over a 4x4 grid of
    tiles its standard error. A share within :data:`PLATE_NONE_BELOW` and two standard errors of 0 shows no filter
    (one the base has is turned off). Still frames cannot show the motion threshold: it is set to
    :data:`NOISE_STEPS` times the robust standard deviation of the run's luma change from frame to frame (so the
    noise keeps the full strength), or the base's (16 DN without one), the larger. Confidence
    ``0.9 (1 - se / 0.1) min(1, frames / 8)``; a video whose predicted frames hold noise as well (a codec with P-
    or B-frames) caps it at 0.4: reported, not applied. Without such a run: not measurable. ``film`` is not
    needed: the share is read off the footage alone."""
    runs = [r for r in still_segments(footage) if r[1] - r[0] >= PLATE_MIN_FRAMES]
    name, effect = "held_noise", "temporal_noise_reduction"
    if not runs:
        return PlateEstimate.not_measurable(name, effect, {}, f"no run of {PLATE_MIN_FRAMES} still frames: the "
                                            "noise held from frame to frame shows only where nothing moves")
    start, stop = max(runs, key=lambda r: r[1] - r[0])
    frames = footage.stack(range(start, min(stop, start + PLATE_FRAMES)))
    n = len(frames)
    share = held_share(frames)
    if share is None:
        return PlateEstimate.not_measurable(name, effect, {"frames": n}, f"{n} still frames from frame {start} "
                                            "hold no noise beyond the 8-bit rounding")
    h, w = frames.shape[1:3]
    tiles = [held_share(frames[:, h * r // _TILES:h * (r + 1) // _TILES, w * c // _TILES:w * (c + 1) // _TILES])
             for r in range(_TILES) for c in range(_TILES)]
    tiles = np.array([t for t in tiles if t is not None])
    se = float(tiles.std(ddof=1) / np.sqrt(len(tiles))) if len(tiles) > 1 else 1.0
    have = base.effect(effect)
    threshold = have.motion_threshold_dn if have is not None else TemporalNoiseReduction.params[
        "motion_threshold_dn"].default
    steps = np.diff(frames @ BT601_TO_YCC[0], axis=0)[:, noisy_pixels(frames.astype(np.float32).mean(-1))]
    # the filter compares a frame with its last output, which differ by 1 / (1 - k) times the outputs' steps
    noise_step = float(1.4826 * np.median(np.abs(steps - np.median(steps)))) / max(1.0 - share, 0.1)
    threshold = round(max(threshold, NOISE_STEPS * noise_step), 1)
    measured = {"frames": n, "first_frame": int(start), "held_share": round(share, 4),
                "standard_error": round(se, 4), "luma_step_sigma_dn": round(noise_step, 3)}
    confidence = 0.9 * float(np.clip(1 - se / 0.1, 0, 1)) * min(1.0, n / 8)
    why = f"{n} still frames from frame {start}: {share:.2f} +- {se:.2f} of the noise held from frame to frame"
    if inter_frame_coded(footage):
        video = footage.video
        confidence = min(confidence, 0.4)
        why += (f"; the clip's predicted frames ({video.get('codec', 'a codec')}, {video.get('frame_types', '')}) "
                "hold noise as well: reported, not applied")
    if share <= max(PLATE_NONE_BELOW, 2 * se):
        params = {"enabled": False} if have is not None and have.enabled else {}
        return PlateEstimate(name, effect, measured, params, round(confidence, 3), why + ": no temporal filter")
    strength = float(min(share, MAX_STRENGTH))
    why += (f"; the motion threshold, which still frames cannot show, {threshold:g} DN: {NOISE_STEPS:g} times the "
            f"noise's luma change from the filter's last output ({noise_step:.2f} DN) or the base's, the larger")
    return PlateEstimate(name, effect, measured, {"strength": round(strength, 3), "motion_threshold_dn": threshold},
                         round(confidence, 3), why)


#: Declared after its estimator and statistic, which the module defines below the class.
TemporalNoiseReduction.plate_probe = PlateProbe(
    "held_noise", temporal_noise_reduction_from_plate, held_noise_statistic, order=35,
    about="the noise held from one still frame to the next: a temporal filter (before the noise law, which it "
          "lowers)")
