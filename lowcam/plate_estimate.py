"""What a plate estimator returns, and the frame pairs it reads: below the effects, whose estimators make them.

A plate probe (:class:`PlateProbe`, declared by its effect as ``Effect.plate_probe``) measures one no-reference
statistic on footage; its estimator, a plain function in the effect's own module, turns the statistic into that
effect's parameters with a confidence, as a :class:`PlateEstimate`. Temporal statistics (the noise) compare frame pairs registered by a
homography from tracked corners (:func:`register_footage`). Estimators that need the model's frame of a scene
receive ``film`` (:func:`lowcam.measure.plate.film`) from the caller: the effects do not run the pipeline.

Contents
--------
- :class:`PlateProbe`: one no-reference statistic: its estimator and the statistic itself for model vs footage
- :class:`PlateEstimate`: one statistic measured on the footage, the effect parameters it implies, its confidence
  (or that the footage cannot show it: not measurable)
- :func:`format_value`: an estimate's value as a line or a table shows it
- :func:`pair_starts`: the first frames of pairs of consecutive frames spread over a shot
- :func:`register_footage`: those pairs registered (:mod:`lowcam.registration`) for temporal statistics, each
  start with the best of the next few frames
- :func:`still_segments`: runs of consecutive frames in which the camera and scene hold still
- :data:`STILL_DN`, :func:`holds_still`: whether a stack's consecutive frames differ by little more than noise
- :func:`inter_frame_coded`: whether footage is a video of predicted frames (which hold and smooth noise)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from .registration import register_frames


@dataclass(frozen=True)
class PlateProbe:
    """One no-reference statistic of footage, declared by the effect it estimates (``Effect.plate_probe``).

    ``estimate(footage, base, film)`` returns a :class:`PlateEstimate` (or None where the footage cannot show it
    at all); ``base`` is the profile being refined, for the parameters an estimate depends on; ``film`` is
    :func:`lowcam.measure.plate.film`, for estimators that ask the model what it makes of a scene.
    ``statistic(frames)`` measures the statistic alone on a stack (T, H, W, 3) float32 DN, the same way for the
    footage and for the model's simulation, returning a dict of numbers (``{}`` where it cannot be measured).
    ``order``: where it runs among the probes (lower first: a later probe sees the earlier estimates).
    ``compared``: the keys of that dict that ``compare --plate-only`` compares, footage against model (empty: all;
    the noise's per-bin lists are left out: their bins lie at different levels in the two);
    ``pairs``: the statistic also takes :class:`lowcam.registration.RegisteredPairs`, which the comparison
    makes once per stack (:func:`register_footage`) before cutting it into tiles. ``effect``: the effect's name,
    filled in from the effect that declares the probe."""

    name: str
    estimate: Callable
    statistic: Callable[[np.ndarray], dict]
    order: float
    about: str = ""
    compared: tuple = ()
    pairs: bool = False
    effect: str = ""


@dataclass
class PlateEstimate:
    """One statistic measured on the footage and what it implies for the profile.

    ``statistic``: its name; ``effect``: the profile effect it sets; ``measured``: the statistic's values on the
    footage (for the report); ``params``: the effect parameters it implies (``{}``: it only reports), each a
    parameter of ``effect`` or ``"other_effect.param"`` (``"other_effect.enabled": False`` turns that effect
    off); ``base_params``: the base profile's values of the same parameters (None where it lacks them), filled by
    :func:`lowcam.measure.plate.estimate_profile`; ``confidence`` (0..1, earned from the measurement's own
    evidence) with a one-line ``reason``; ``measurable``: False where the footage cannot show the statistic at all
    (too flat, too still): nothing is estimated, and lines and reports say "not measurable" rather than a value;
    ``model``: the same statistic measured on the profile's simulation of similar content
    (:func:`lowcam.measure.plate.model_statistics`), ``None`` until filled; ``applied``: whether
    :func:`lowcam.measure.plate.estimate_profile` wrote ``params`` into the profile."""

    statistic: str
    effect: str
    measured: dict
    params: dict
    confidence: float
    reason: str
    model: dict | None = None
    applied: bool = False
    base_params: dict = field(default_factory=dict)
    measurable: bool = True

    @classmethod
    def not_measurable(cls, statistic: str, effect: str, measured: dict, reason: str) -> "PlateEstimate":
        """An estimate the footage cannot make: no params, confidence 0, ``measurable`` False."""
        return cls(statistic, effect, measured, {}, 0.0, reason, measurable=False)

    def line(self) -> str:
        """One line for the terminal: what was found, how sure, whether it went into the profile."""
        if not self.measurable:
            return f"{self.statistic} ({self.effect}): not measurable ({self.reason}); not applied"
        what = ", ".join(f"{k} = {format_value(v)}" for k, v in self.params.items()) or "reported only"
        state = "applied" if self.applied else "not applied"
        return f"{self.statistic} ({self.effect}): {what}; confidence {self.confidence:.2f} ({self.reason}); {state}"


def format_value(v) -> str:
    """An estimate's value as a line shows it: floats to 4 significant digits, None as "not measurable"."""
    if v is None:
        return "not measurable"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    return str(v)


def pair_starts(frames: int, count: int) -> list[int]:
    """The first frames of up to ``count`` pairs of consecutive frames ``(i, i + 1)``, spread evenly over a shot
    of ``frames`` frames."""
    if frames < 2:
        return []
    return sorted(set(int(round(v)) for v in np.linspace(0, frames - 2, min(count, frames - 1))))


def register_footage(footage, count: int = 12, cache: dict | None = None):
    """:class:`lowcam.registration.RegisteredPairs` of up to ``count`` frame pairs spread over the shot
    ``footage`` (anything with ``frames``, e.g. :class:`lowcam.measure.plate.Footage`; :func:`pair_starts`), each
    frame registered, by a homography from tracked corners, with the one of the next
    :data:`lowcam.registration.PAIR_GAP` frames that nearest-neighbour sampling reads most exactly
    (:func:`lowcam.registration.register_frames`; ``cache``: its consecutive registrations, to share)."""
    return register_frames(footage.frames, pair_starts(len(footage), count), cache=cache)


#: Two frames hold still where their grey difference, blurred (sigma 2 px), averages less than this (DN).
STILL_DN = 2.0


def holds_still(frames) -> bool:
    """Whether consecutive frames of a stack (T, H, W, 3) differ by little more than noise: each pair's grey
    difference, Gaussian-blurred (sigma 2 px: noise averages out, a scene that moved does not), averages less than
    :data:`STILL_DN` in absolute value (the second test of :func:`still_segments`, without its first, which
    spatially correlated noise, a denoiser's, fails)."""
    grey = np.asarray(frames, np.float32).mean(-1)
    return all(float(np.abs(cv2.GaussianBlur(b - a, (0, 0), 2.0)).mean()) < STILL_DN
               for a, b in zip(grey[:-1], grey[1:]))


def still_segments(footage, min_length: int = 3, max_frames: int = 200) -> list[tuple[int, int]]:
    """Runs ``[start, stop)`` of at least ``min_length`` consecutive frames of ``footage`` (anything with
    ``frame(i)`` and a length, e.g. :class:`lowcam.measure.plate.Footage`) in which nothing moves.

    Two frames of a still scene differ by noise alone, which a Gaussian blur (sigma 2 px) removes almost
    entirely (white noise keeps about 1/(2 sqrt(pi) 2) = 14 % of its standard deviation, noise correlated over a
    few pixels by demosaicing about twice that); a scene that moved leaves structure that the blur keeps. A pair is
    still when the blurred difference keeps less than 40 % of the difference's standard deviation and its mean
    absolute value is below :data:`STILL_DN`."""
    n = min(len(footage), max_frames)
    if n < 2:
        return []
    still = []
    prev = footage.frame(0).mean(axis=2)
    for i in range(1, n):
        cur = footage.frame(i).mean(axis=2)
        d = cur - prev
        sd = float(d.std())
        blurred = cv2.GaussianBlur(d, (0, 0), 2.0)
        still.append(sd > 0 and float(blurred.std()) < 0.4 * sd and float(np.abs(blurred).mean()) < STILL_DN)
        prev = cur
    runs, start = [], None
    for i, s_ in enumerate(still + [False]):
        if s_ and start is None:
            start = i
        elif not s_ and start is not None:
            if i + 1 - start >= min_length:
                runs.append((start, i + 1))
            start = None
    return runs


def inter_frame_coded(footage) -> bool:
    """Whether ``footage`` is a video whose frames are predicted from others (a GOP longer than one frame, P- or
    B-frames: :func:`lowcam.video.stream_facts` in ``footage.video``): its coding holds and smooths noise too."""
    video = getattr(footage, "video", None) or {}
    return video.get("gop_length", 1) > 1 or any(t in video.get("frame_types", "") for t in ("P", "B"))
