"""Which physical effect does the profile lack? Fit each candidate, re-simulate, rank by the error on held-out captures.

Every candidate is an effect the profile lacks, one whose parameters may be wrong, or one it should not have
(``without_EFFECT``, and ``monochrome``). Each is fitted to the measured temporal means on a noise-free simulation
(:meth:`Context.clean`), and judged on captures its fit did not see:

1. **Screening on two folds.** The captures are dealt into two halves (:meth:`Context.folds`); every candidate
   is fitted coarsely on each half (its grid values walked from the profile's value towards lower error, its
   closed-form fit, or one Gauss-Newton step of its continuous parameters, :func:`gauss_newton`) and measured on
   the other half. Each capture is thus measured with a fit that did not see it: the held-out error.
2. **Fitting.** The :data:`FITTED` best by held-out error are fitted to convergence on every capture (the profile
   that would be added), and their folds' fits are finished from it.
3. **Identifiable and plausible.** A fitted number's standard error is half the difference of its two folds' fits
   (:attr:`Candidate.uncertainty`); a searched key on which the folds disagree by more than
   :data:`UNDETERMINED_SPREAD` of its range, or that the captures do not show at all, is not determined by the
   data: it is held at the profile's value and the candidate fitted again (or not offered when nothing is left
   to fit). A fit whose effect no real camera has (:meth:`lowcam.effects.Effect.implausible`) is not offered;
   a number at a bound of its search is flagged. Why a candidate could not be fitted is kept
   (:attr:`Diagnosis.not_fitted`).

Each error is estimated from the noise-free residual and the noise the first comparison measured
(:meth:`Context.estimate`); the best candidate, every candidate that changes the noise, and the runners-up that
could still win, get the full noise-aware errors of :mod:`lowcam.measure.compare`, in sample and held out.
Ranking and verdicts use the held-out error (:attr:`Candidate.score`); a candidate that nothing could be held out
of (one capture shows it, and its fit takes whole frames) takes no credit.

Measured and assumed. With one frame per capture the frames' noise cannot be measured; every candidate is then
compared against the noise of the diagnosed profile (``assumed_noise`` in :func:`lowcam.measure.compare.compare`),
so a candidate cannot lower the error by only adding model noise. ``Diagnosis.as_json()["measured"]`` says which
families were measured.

Verdict (:attr:`Diagnosis.verdict`): ``explained`` when the profile's own error is at most 1.1; ``missing-effect``
when the best candidate's held-out error is at most :data:`UNEXPLAINED_ABOVE` and below the profile's own by
:data:`NAMED_GAIN` (it is named, with that error); ``unexplained`` otherwise, naming the residual's family (edges,
levels, space or time: :func:`lowcam.measure.compare.residual_family`), and ``where`` says where it lives.

Contents
--------
- :data:`UNEXPLAINED_ABOVE`: the best candidate's held-out error above which the verdict is ``unexplained`` (1.25)
- :data:`NAMED_GAIN`: how much lower than the profile's error a candidate's must be for it to be named (3 %)
- :data:`FITTED`: how many screened candidates are fitted to convergence (at most)
- :data:`REFINE_WITHIN`: a screened candidate is fitted to convergence when its held-out error is within this
  factor of the best screened candidate's
- :data:`FULL_ERRORS`: how many runners-up at most get the full noise-aware error besides the best
- :data:`RENAMED_CANDIDATES`: candidates renamed after their effect; the old names are still accepted
- :data:`HELD_NOISE`: how much more held from frame to frame the captures' noise must be than the profile's for
  a temporal candidate to be fitted
- :data:`TILE_PX`, :data:`UNDETERMINED_SPREAD`, :data:`AT_BOUND`: the folds' image tiles, and when a fitted number
  is not determined or at its bound
- :class:`Candidate`: one fitted candidate: its errors in sample and held out, params, uncertainties and evidence
- :class:`Context`: the measured set, the profile, memoised noise-free simulations, the error estimate, folds
- :func:`candidates`: candidate name -> (effect class, :class:`~lowcam.effects.Search`) pairs, in chain order
- :func:`removal_candidates`: the ``without_EFFECT`` candidates of a profile
- :func:`candidate_effect`: the profile effect a candidate adds or changes
- :func:`gauss_newton`: bounded Gauss-Newton (Levenberg-Marquardt) steps on the noise-free residual
- :func:`fit_candidate`: fit one candidate on the context's profile: (profile with it, params, evidence)
- :func:`per_pixel`: True for a candidate fitted as a dense per-pixel map
- :class:`Diagnosis`: the comparison, the ranked candidates, those not fitted and why, the verdict, the time
- :func:`rank`: screen, fit and rank the named candidates by their held-out errors
- :func:`polish`: refit several added effects together (each in turn with the others held)
- :func:`diagnose`: rank the candidates (all, or ``only``) for a measurement set, with forward selection
- :class:`Step`: one step of :func:`explain`: the diagnosis, the effect added and the error after
- :func:`explain`: add the best candidate and refit, step by step, until the error reaches the floor
- :func:`save_candidate_profile`: write a candidate's profile, its fitted maps (.npy) copied beside it

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008 (fixed-pattern and row noise).
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (PRNU and DSNU).
- [Nocedal2006] J. Nocedal and S. J. Wright, "Numerical Optimization", 2nd ed., Springer 2006, ch. 10
  (Gauss-Newton and Levenberg-Marquardt).
- [Hastie2009] T. Hastie, R. Tibshirani and J. Friedman, "The Elements of Statistical Learning", 2nd ed.,
  Springer 2009, sec. 7.10 (cross-validation).
- [Shao1989] J. Shao and C. F. J. Wu, "A General Theory for Jackknife Variance Estimation", Annals of Statistics
  17(3), 1176-1197, 1989 (the delete-d jackknife).
"""
from __future__ import annotations

import functools
import shutil
import tempfile
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..effects import known_effects
from ..errors import NotFitted
from ..pipeline import prefix_key
from .compare import (EXPLAINED_BELOW, SEQUENCE_SEED_STEP, SIM_SEED, Comparison, capture_inputs, capture_stats,
                      combine, compare, residual_family, simulate_capture)
from .sets import MeasurementSet

UNEXPLAINED_ABOVE = 1.25
#: A candidate is named (``missing-effect``) and added by :func:`explain` only when its held-out error is below
#: the profile's own by at least this fraction: one that does not lower the error is never named.
NAMED_GAIN = 0.03
FITTED = 4
REFINE_WITHIN = 1.5
FULL_ERRORS = 3
#: Candidates renamed after their effect; the old names are still accepted.
RENAMED_CANDIDATES = {"gamma": "tone_curve"}
_MEMO_ENTRIES = 64  # noise-free frames kept (one capture each, about 1 MB at 640x480)
#: Candidates fitted at once (threads: OpenCV and numpy release the GIL); the results do not depend on it.
WORKERS = 2
#: Side (px) of the image tiles of the two spatial folds, used when fewer than two captures show a candidate.
TILE_PX = 64
#: Sets of at most this many captures are cross-validated leaving one capture out at a time; larger ones on two
#: halves.
LEAVE_ONE_OUT_UP_TO = 5
#: A fitted parameter whose two folds' estimates differ by more than this share of its searched range is not
#: determined by the data.
UNDETERMINED_SPREAD = 0.5
#: A fitted parameter within this share of its searched range from a bound is flagged as at the bound.
AT_BOUND = 0.01
#: A candidate that holds noise from frame to frame (``Search.held_noise``: a temporal filter, a video encoder) is
#: fitted only when the captures' noise is held by at least this much more than the profile's
#: (:attr:`~lowcam.measure.compare.Comparison.held_noise`, a frame-to-frame correlation; raw frames read within
#: 0.01 of the model's).
HELD_NOISE = 0.1
#: The ideal renders hold colour when their chroma varies by at least this (render units) on opaque pixels
#: (:meth:`Context.scene_has_colour`).
SCENE_CHROMA = 0.01


@dataclass
class Candidate:
    """One fitted candidate.

    ``error_after`` is its error in sample: with the fit that saw the captures it is measured on (the full
    noise-aware error when ``full``, else estimated from the noise-free fit: :meth:`Context.estimate`).
    ``held_out`` is its error on captures held out of the fit (two folds: each half of the captures fitted, the
    other half measured; ``validation`` says how, or why it could not be), with its ``held_out_families``;
    ranking and verdicts use it (:attr:`score`). ``uncertainty``: each fitted number's standard error from the
    spread of the folds' fits; ``flags``: fitted numbers at a bound of their search, or effects outside what a
    real camera has (:meth:`lowcam.effects.Effect.implausible`)."""

    effect: str
    error_after: float
    params: dict
    evidence: str
    profile: object = field(repr=False, default=None)
    per_pixel: bool = False  # fitted as a map with one value per pixel and channel
    captures: int = 1
    families: dict = field(default_factory=dict)
    full: bool = False
    seconds: float = 0.0
    comparison: object = field(default=None, repr=False)  # the full comparison, when ``full``
    held_out: float | None = None
    held_out_families: dict = field(default_factory=dict)
    held_out_full: bool = False
    validation: str = ""
    base_error: float = float("inf")
    uncertainty: dict = field(default_factory=dict)
    flags: list = field(default_factory=list)

    @property
    def score(self) -> float:
        """The decision error, by which candidates are ranked and verdicts given: the held-out error. Without
        one (nothing could be held out of its fit) the candidate takes no credit: the profile's own error."""
        if self.held_out is None:
            return max(self.error_after, self.base_error)
        return self.held_out

    @property
    def optimistic(self) -> float:
        """The lowest decision error the candidate could have: with its noise families at the floor."""
        fam = self.held_out_families if self.held_out is not None else self.families
        if not fam:
            return self.score
        error = _at_floor(fam)
        return error if self.held_out is not None else max(error, self.base_error)

    def as_json(self) -> dict:
        def number(v):
            return round(v, 6) if isinstance(v, float) else v

        held = None if self.held_out is None else round(self.held_out, 4)
        return {"effect": self.effect, "error_after": round(self.error_after, 4),
                "error_in_sample": round(self.error_after, 4), "error_held_out": held,
                "held_out": self.validation, "error_out_of_sample": round(self.score, 4),
                "score": round(self.score, 4), "error_is_estimate": not self.full,
                "held_out_is_estimate": not self.held_out_full, "seconds": round(self.seconds, 3),
                "families": {k: round(v, 4) for k, v in self.families.items()},
                "held_out_families": {k: round(v, 4) for k, v in self.held_out_families.items()},
                "params": {k: number(v) for k, v in self.params.items()},
                "uncertainty": {k: round(v, 6) for k, v in self.uncertainty.items()},
                "flags": list(self.flags), "evidence": self.evidence}


class Context:
    """The measured set, the profile, memoised noise-free simulations and the error estimate.

    ``assumed_noise`` (per capture, or None) is the noise that one-frame captures are compared against; by
    default the diagnosed profile's own, from its first comparison (:attr:`base`). :meth:`view` is the same
    context over some of the captures (and pixels), sharing the simulations: the folds candidates are fitted on
    and measured on (:meth:`folds`)."""

    def __init__(self, mset, profile, workdir: Path, assumed_noise=None, parent=None, base=None):
        self.mset, self.profile, self.workdir = mset, profile, Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()  # candidates are fitted in threads
        if parent is not None:  # the same set: share its inputs, means, capture choices and simulations
            for name in ("inputs", "cache", "memo", "_lock", "means", "texture", "chroma"):
                setattr(self, name, getattr(parent, name))
            assumed_noise = assumed_noise or parent.assumed_noise
        else:
            self._lock = threading.Lock()
            self.inputs = [capture_inputs(profile, c) for c in mset.captures]
            self.cache, self.memo = {}, OrderedDict()
            self.means = [c.mean.astype(np.float32) for c in mset.captures]
            self.texture = [float(inp.ideal[..., :3].std()) for inp in self.inputs]
            self.chroma = [_chroma(inp.ideal) for inp in self.inputs]
        self._choose_captures()
        first = base or compare(mset, profile, cache=self.cache, inputs=self.inputs, assumed_noise=assumed_noise)
        self.assumed_noise = assumed_noise or [s.sums["variance_map"] if len(s.measured) == 1 else None
                                               for s in first.captures]
        self._calibrate(first)

    def _choose_captures(self) -> None:
        captures = self.mset.captures
        self.moving = any(np.any(c.angular_velocity) for c in captures)
        # Captures with structure: flat fields say nothing about geometry or blur.
        self.textured = [i for i, t in enumerate(self.texture) if t > 0.02]
        self.moving_ones = [i for i, c in enumerate(captures) if np.any(c.angular_velocity)]
        # a few captures for screening and quick full errors: the two flattest and the most textured
        by_texture = [int(i) for i in np.argsort(self.texture)]
        self.quick = list(dict.fromkeys((*by_texture[:2], by_texture[-1])))
        self.screen_textured = sorted(self.textured, key=lambda i: -self.texture[i])[:2]
        self._folds = {}

    def _calibrate(self, first) -> None:
        """Per capture: the noise the mean family divides by, the model's noise in the simulated frames' mean,
        and the offset of noisy from noise-free frames (clipping, rounding), measured once and kept."""
        self.base = first
        self._noise = np.array([s.sums["mean"][1] for s in first.captures])
        self._model_noise = np.array([s.sums["model_noise"] for s in first.captures])
        self._offset = np.array([s.sums["mean"][0] for s in first.captures]) - \
            self._sse_per_capture(self.profile) - self._model_noise

    @functools.cached_property
    def held_noise(self) -> float | None:
        """The base comparison's :attr:`~lowcam.measure.compare.Comparison.held_noise`, measured once."""
        return self.base.held_noise

    @property
    def holds_noise(self) -> bool:
        """Whether the captures' noise is held from frame to frame more than the profile's (by :data:`HELD_NOISE`):
        the evidence a temporal candidate needs."""
        held = self.held_noise
        return held is not None and held >= HELD_NOISE

    @property
    def holds_noise_reason(self) -> str:
        held = self.held_noise
        if held is None:
            return "no capture has 3 frames to show noise held from frame to frame"
        return (f"the captures' noise is held from frame to frame no more than the profile's (correlation "
                f"{held:+.2f} beyond it, under {HELD_NOISE})")

    def view(self, indices, masks=None) -> "Context":
        """This context over the captures ``indices`` only, and within them the pixels ``masks`` (one (H, W)
        bool per index, or None) keep; simulations are shared."""
        out = object.__new__(Context)
        out.mset = MeasurementSet(self.mset.path, [self.mset.captures[i] for i in indices])
        out.profile, out.workdir, out._local = self.profile, self.workdir, threading.local()
        for name in ("cache", "memo", "_lock"):
            setattr(out, name, getattr(self, name))
        masks = masks or [None] * len(indices)
        out.inputs = [self.inputs[i] if m is None else
                      self.inputs[i]._replace(mask=m if self.inputs[i].mask is None else m & self.inputs[i].mask)
                      for i, m in zip(indices, masks)]
        out.means = [self.means[i] for i in indices]
        out.texture = [self.texture[i] for i in indices]
        out.chroma = [self.chroma[i] for i in indices]
        out.assumed_noise = [self.assumed_noise[i] for i in indices]
        out._choose_captures()
        stats = [self.base.captures[i] if m is None else
                 capture_stats(self.base.captures[i].measured, self.base.captures[i].simulated,
                               self.base.captures[i].name, out.assumed_noise[k], out.inputs[k].mask)
                 for k, (i, m) in enumerate(zip(indices, masks))]
        error, families = combine(stats)
        out._calibrate(Comparison(error, families, stats, self.base.noise_floor))
        return out

    def folds(self, captures: str, tiles: bool, determined_by: str = ""):
        """The folds a candidate searching ``captures`` ("all", "textured", "moving") is fitted and measured on:
        (``[(fitted on, measured on), ...]`` views, each capture measured once, and how they were made).

        Up to :data:`LEAVE_ONE_OUT_UP_TO` captures, each is left out in turn; more are dealt alternately into two
        halves by kind (moving first, then the most colourful, then the most textured), so each half holds moving,
        colourful, textured and flat captures alike. When a fold would be fitted on none of the captures the
        candidate is fitted on, or on none of the captures that determine its parameters (``determined_by``, as
        ``captures``: a video encoder's strength shows on textured captures, while a flat one only shows that noise
        is held), the frames are split into two chequerboards of :data:`TILE_PX` tiles instead (``tiles``: the fit
        honours masks; without it, ``determined_by`` is not asked), else the result is a string saying why nothing
        can be held out."""
        n = len(self.inputs)
        relevant = set(range(n) if captures == "all" else self.subset(captures))
        determining = relevant & set(range(n) if determined_by in ("", "all") or not tiles else
                                     self.subset(determined_by))
        if n <= LEAVE_ONE_OUT_UP_TO:  # the first fold, which screens, leaves out the least telling capture
            held = [[i] for i in sorted(range(n), key=lambda i: (i in self.moving_ones, self.texture[i], i))]
        else:
            order = sorted(range(n), key=lambda i: (i not in self.moving_ones, -self.chroma[i], -self.texture[i], i))
            held = [order[0::2], order[1::2]]
        if len(held) > 1 and all(determining - set(h) for h in held) and len(relevant) > 1:
            key = "captures"
            if key not in self._folds:
                pairs = [(self.view(sorted(set(range(n)) - set(h))), self.view(sorted(h))) for h in held]
                how = (f"leave-one-out over {n} captures" if n <= LEAVE_ONE_OUT_UP_TO else
                       "2 folds of captures")
                self._folds[key] = (pairs, how)
            return self._folds[key]
        if not relevant:
            return "no capture shows it"
        if not tiles:
            return (f"only {len(relevant)} capture{'s' * (len(relevant) != 1)} show{'s' * (len(relevant) == 1)} "
                    "it and its fit takes whole frames: nothing can be held out")
        key = ("tiles", tuple(sorted(relevant)))  # only the captures that show it: the others it leaves alone
        if key not in self._folds:
            h, w = self.means[0].shape[:2]
            yy, xx = np.mgrid[0:h, 0:w]
            chequer = ((yy // TILE_PX + xx // TILE_PX) % 2 == 0)
            shown = sorted(relevant)
            a = self.view(shown, [chequer] * len(shown))
            b = self.view(shown, [~chequer] * len(shown))
            self._folds[key] = ([(a, b), (b, a)], f"2 folds of {TILE_PX}-px image tiles")
        return self._folds[key]

    @property
    def screening(self) -> bool:
        """True while this thread screens a candidate: a fit with ``refines`` may be coarse."""
        return getattr(self._local, "screening", False)

    @screening.setter
    def screening(self, value: bool):
        self._local.screening = value

    def clean(self, profile, subset=None) -> list[np.ndarray]:
        """Noise-free frames (float32) of the captures (all, or ``subset``) through ``profile``, memoised."""
        q = profile.quiet()
        key = prefix_key(q, len(q.effects))
        out = []
        for i in range(len(self.inputs)) if subset is None else subset:
            capture = self.mset.captures[i]
            with self._lock:
                frame = self.memo.get((key, id(capture)))
                if frame is not None:
                    self.memo.move_to_end((key, id(capture)))
            if frame is None:
                frame = simulate_capture(q, capture, 1, inputs=self.inputs[i], cache=self.cache,
                                         until="bayer_sampling")[0]     # kept as 8-bit: a quarter of float32
                with self._lock:
                    self.memo[(key, id(capture))] = frame
                    if len(self.memo) > _MEMO_ENTRIES:
                        self.memo.popitem(last=False)
            out.append(frame.astype(np.float32))
        return out

    def simulate(self, profile, i: int, count: int, second: bool = False) -> np.ndarray:
        """``count`` noisy frames (uint8, noise frames 0..count-1 of :data:`~lowcam.measure.compare.SIM_SEED`) of
        capture ``i`` through ``profile`` (:func:`~lowcam.measure.compare.simulate_capture`), the chain's
        deterministic front kept in the shared cache: how a fit in an effect's module, which does not run the
        pipeline itself, asks for the model's frames. ``second``: the second model sequence, of other noise, that
        ``compare`` makes for a profile whose frames are not independent (a temporal effect)."""
        seed = SIM_SEED + SEQUENCE_SEED_STEP if second else SIM_SEED
        return simulate_capture(profile, self.mset.captures[i], count, seed, inputs=self.inputs[i], cache=self.cache)

    def _difference(self, i, frame):
        d = self.means[i] - frame
        mask = self.inputs[i].mask
        return d if mask is None else d * mask[..., None]

    def pixels(self, profile, subset=None) -> tuple[np.ndarray, np.ndarray]:
        """(noise-free model, measured mean), each (N, 3) float64: every compared pixel of the captures (all, or
        ``subset``), for the fits made in closed form."""
        idx = range(len(self.inputs)) if subset is None else subset
        model, measured = [], []
        for i, s in zip(idx, self.clean(profile, subset)):
            mask = self.inputs[i].mask
            model.append(s.reshape(-1, 3) if mask is None else s[mask])
            measured.append(self.means[i].reshape(-1, 3) if mask is None else self.means[i][mask])
        return np.concatenate(model).astype(np.float64), np.concatenate(measured).astype(np.float64)

    def residual(self, profile, subset=None) -> np.ndarray:
        """The measured means less the noise-free frames, flattened over the captures (all, or ``subset``); masked
        pixels (:class:`~lowcam.measure.compare.CaptureInputs`) read 0."""
        idx = range(len(self.inputs)) if subset is None else subset
        return np.concatenate([self._difference(i, s).ravel() for i, s in zip(idx, self.clean(profile, subset))])

    def _sse_per_capture(self, profile, subset=None) -> np.ndarray:
        idx = range(len(self.inputs)) if subset is None else subset
        return np.array([np.square(self._difference(i, s)).sum(dtype=np.float64)
                         for i, s in zip(idx, self.clean(profile, subset))])

    def sse(self, profile, subset=None) -> float:
        """The noise-free SSE of ``profile`` against the measured means (all captures, or ``subset``)."""
        return float(self._sse_per_capture(profile, subset).sum())

    def compare(self, profile, subset=None, sim_frames=None):
        """The full noise-aware comparison (:func:`~lowcam.measure.compare.compare`) against the assumed noise."""
        return compare(self.mset, profile, sim_frames, self.cache, self.inputs, self.assumed_noise, subset)

    def mean_sums(self, profile, subset=None) -> tuple[np.ndarray, np.ndarray]:
        """Per capture (all, or ``subset``): the mean family's numerator and denominator expected of ``profile``
        from its noise-free residual (:meth:`estimate`)."""
        idx = list(range(len(self.inputs))) if subset is None else list(subset)
        num = self._sse_per_capture(profile, subset) + self._model_noise[idx] + self._offset[idx]
        return np.maximum(num, 0.0), self._noise[idx]

    def estimate(self, profile, subset=None) -> tuple[float, dict]:
        """(error, families) expected of ``profile`` (over all captures, or ``subset``) from its noise-free
        residual: the mean family's residual is the noise-free one plus the model's noise in the mean of the
        simulated frames and the first comparison's offset of noisy from noise-free frames; the noise families are
        the first comparison's."""
        num, den = self.mean_sums(profile, subset)
        return self.families_with_mean(float(num.sum()), float(den.sum()))

    def families_with_mean(self, num: float, den: float) -> tuple[float, dict]:
        """(error, families): the first comparison's noise families with the mean family ``sqrt(num / den)``."""
        families = dict(self.base.families, mean=float(np.sqrt(max(num, 0.0) / den)))
        return float(np.sqrt(sum(v * v for v in families.values()) / len(families))), families

    def reach(self) -> float:
        """How far from the centre the captures' compared, rendered pixels reach, as a share of the half-diagonal
        (the 99.5th percentile of the farthest capture's; 1: the corners)."""
        if getattr(self, "_reach", None) is None:
            h, w = self.means[0].shape[:2]
            yy, xx = np.mgrid[0:h, 0:w]
            rho = np.hypot(xx - (w - 1) / 2, yy - (h - 1) / 2) / np.hypot(w / 2, h / 2)
            reach = 0.0
            for inp in self.inputs:
                shown = _opaque_output(inp.ideal, (h, w))
                if inp.mask is not None:
                    shown &= inp.mask
                if shown.any():
                    reach = max(reach, float(np.percentile(rho[shown], 99.5)))
            self._reach = min(reach, 1.0)
        return self._reach

    def scene_has_colour(self) -> bool:
        """True when some capture's ideal render holds colour (its chroma, each opaque pixel's channels about their
        mean, varies by at least :data:`SCENE_CHROMA`): a sensor's colour weights are determined by the data only
        then (a grey chart shows every set of weights summing to 1 alike)."""
        return max(self.chroma, default=0.0) >= SCENE_CHROMA

    def subset(self, captures: str):
        """The captures (indices, or None for all) a search with ``captures`` fits on."""
        return {"all": None, "textured": self.textured, "moving": self.moving_ones}[captures]

    def screening_subset(self, captures: str):
        """Fewer captures for screening: the two most textured, or :attr:`quick`."""
        return {"all": self.quick, "textured": self.screen_textured, "moving": self.moving_ones}[captures]


def _chroma(ideal: np.ndarray) -> float:
    """How much colour an ideal render (H, W, 4) holds: the spread of its opaque pixels' channels about their
    mean (0 for a grey scene)."""
    rgb = ideal[..., :3][ideal[..., 3] > 0.5]
    return float((rgb - rgb.mean(axis=1, keepdims=True)).std()) if rgb.size else 0.0


def _opaque_output(ideal: np.ndarray, shape) -> np.ndarray:
    """Where the ideal render is opaque, at the output's ``shape`` (rows, cols): the pixels whose content the
    render gives (a target's paper, not the plate around it). The render is scaled to the frame (its field of
    view a little wider than the frame's: close enough for how far content reaches)."""
    alpha = cv2.resize(np.ascontiguousarray(ideal[..., 3]), (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return alpha > 0.5


# --- the candidates: each effect's declared searches (lowcam.effects.Search) ---------------------------------------

def candidates() -> dict:
    """Candidate name -> list of (effect class, :class:`~lowcam.effects.Search`), from every known effect's
    ``searches`` (bundled and plug-in), in chain order."""
    out: dict = {}
    for cls in known_effects():
        for search in cls.searches:
            out.setdefault(search.candidate, []).append((cls, search))
    return out


def removal_candidates(profile) -> list[str]:
    """The ``without_EFFECT`` candidates of ``profile``: each enabled effect the chain can run without."""
    return [f"without_{e.name}" for e in profile.effects
            if e.enabled and not e.always_runs and e.removable]


def candidate_effect(name: str) -> str:
    """The profile effect a candidate adds or changes."""
    if name.startswith("without_"):
        return name[len("without_"):]
    return candidates()[name][0][0].name


def gauss_newton(ctx, build, x0, bounds, subset=None, steps: int = 4):
    """Bounded Gauss-Newton steps minimising the noise-free SSE of ``build(x)`` ([Nocedal2006] ch. 10).

    Parameters are scaled to their bounds; the Jacobian comes from forward differences of 5 % of each range
    (towards the inside; 25 % where that changes nothing); each step is clipped to the bounds and halved until the
    SSE falls (backtracking), which
    copes with effects that hardly act near their start (a blur of sigma 0). Returns (x, SSE, blind): ``blind``
    the indices of the parameters that change nothing the captures show (their Jacobian column is 0)."""
    lo, hi = np.array([b[0] for b in bounds], float), np.array([b[1] for b in bounds], float)
    span = np.maximum(hi - lo, 1e-12)
    x = np.clip(np.asarray(x0, float), lo, hi)
    r = ctx.residual(build(x), subset)
    sse = float(np.dot(r, r))
    blind: set = set()
    for _ in range(steps):
        jac = np.zeros((r.size, len(x)), np.float32)
        blind = set()
        for k in range(len(x)):
            for size in (0.05, 0.25):  # a wider difference where the effect hardly acts
                h = size * span[k] if x[k] + size * span[k] <= hi[k] else -size * span[k]
                xk = x.copy()
                xk[k] += h
                jac[:, k] = (r - ctx.residual(build(xk), subset)) / (h / span[k])  # d(model)/d(scaled x)
                if np.abs(jac[:, k]).max() > 1e-3:
                    break
            else:
                blind.add(k)
        jtj = (jac.T @ jac).astype(np.float64)
        ridge = 1e-3 * np.diag(np.diag(jtj)) + 1e-9 * np.trace(jtj) * np.eye(len(x))
        target = np.clip(x + np.linalg.lstsq(jtj + ridge, (jac.T @ r).astype(np.float64), rcond=None)[0] * span,
                         lo, hi)
        moved = False
        for t in (1.0, 0.5, 0.25, 0.125, 0.0625):
            x_new = x + t * (target - x)
            if np.all(np.abs(x_new - x) < 1e-4 * span):
                break
            r_new = ctx.residual(build(x_new), subset)
            sse_new = float(np.dot(r_new, r_new))
            if sse_new < sse:
                moved = np.all(np.abs(x_new - x) >= 2e-3 * span) or t == 1.0
                x, r, sse = x_new, r_new, sse_new
                break
        if not moved:
            break
    return x, sse, blind


class _Fit:
    """One candidate's fit in progress on one context: :meth:`screen` (coarse), then :meth:`finish` (to
    convergence). ``hold``: searched keys kept at the profile's value (the data do not determine them)."""

    def __init__(self, ctx, name, cls, search, hold=()):
        self.ctx, self.name, self.cls, self.search = ctx, name, cls, search
        self.values = dict(search.fixed)
        self.keys = [k for k in search.bounds if k not in hold]
        self.bounds = [search.bounds[k] for k in self.keys]
        self.subset = ctx.screening_subset(search.captures)  # fitted on a few captures; polish uses all
        have = ctx.profile.effect(cls.name)
        current = have.values() if have is not None and have.enabled and not search.replace else {}
        start = lambda k: current.get(k, search.start.get(k, cls.params[k].default))  # noqa: E731
        self.values.update({k: start(k) for k in hold})
        self.x = np.array([start(k) for k in self.keys], float)
        self.result = None  # (profile, params, shown) once fitted in closed form
        self.screened = self.done = False
        self.seconds = 0.0
        self.blind: set = set()  # keys the captures do not show

    @property
    def fits_anything(self) -> bool:
        """False for a candidate that only sets fixed values (a demosaicing method): nothing is learnt."""
        return bool(self.keys or self.search.grid or self.search.fit)

    def build(self, x=None, extra=None):
        values = dict(self.values, **(extra or {}))
        if self.keys:
            values.update(zip(self.keys, map(float, self.x if x is None else x)))
        return self.ctx.profile.with_effect(self.cls.name, replace=self.search.replace,
                                            after=self.search.after or None, **values)

    def _grid(self, key, options):
        """The option of least error (the full error of a few captures when the noise shows it), walked from the
        profile's current value (else the middle option) towards lower error: over ordered options the error is
        taken to have one minimum, so the walk stops where both neighbours are worse."""
        scores: dict = {}

        def score(i):
            if i not in scores:
                profile = self.build(extra={key: options[i]})
                scores[i] = (self.ctx.compare(profile, self.ctx.quick[:2], 4).error if self.search.full_error
                             else self.ctx.sse(profile, self.subset))
            return scores[i]

        have = self.ctx.profile.effect(self.cls.name)
        start = getattr(have, key, None) if have is not None else None
        i = options.index(start) if start in options else len(options) // 2
        while True:
            better = [j for j in (i - 1, i + 1) if 0 <= j < len(options) and score(j) < score(i)]
            if not better:
                break
            i = min(better, key=score)
        self.values[key] = options[i]

    def _gauss_newton(self, steps):
        self.x, _, blind = gauss_newton(self.ctx, self.build, self.x, self.bounds, self.subset, steps=steps)
        self.blind = {self.keys[k] for k in blind}

    def screen(self):
        started = time.perf_counter()
        self.screened = True
        fit = self.search.fit
        if fit:
            self.ctx.screening = True  # a fit that ``refines`` does a coarse version now, the full one in finish
            try:
                self.result = fit(self.ctx, self.cls.name)
            finally:
                self.ctx.screening = False
            self.done = self.result is None or not getattr(fit, "refines", False)
        else:
            for key, options in self.search.grid.items():
                self._grid(key, list(options))
            if self.keys:
                self._gauss_newton(1)
            self.done = not self.keys
        self.seconds += time.perf_counter() - started

    def finish(self):
        started = time.perf_counter()
        if self.search.fit:  # a fit that refines: its full version
            self.result, self.done = self.search.fit(self.ctx, self.cls.name), True
            self.seconds += time.perf_counter() - started
            return
        if self.keys:
            self._gauss_newton(max(1, self.search.evals // 10))
        self.done = True
        self.seconds += time.perf_counter() - started

    def fitted(self):
        """(profile with it, fitted params, values shown in the evidence)."""
        if self.search.fit:
            return self.result
        values = dict(self.values, **dict(zip(self.keys, map(float, self.x))))
        return self.build(), values, values

    def numbers(self) -> dict:
        """The fitted numbers by name (searched keys, and the scalars and vectors of a closed-form fit), for
        their spread between folds."""
        if not self.search.fit:
            return dict(zip(self.keys, map(float, self.x)))
        out = {}
        for key, value in (self.result[1] if self.result else {}).items():
            arr = np.asarray(value) if isinstance(value, (int, float, list, tuple)) and not isinstance(value, bool) \
                else None
            if arr is not None and arr.dtype.kind in "fi" and 0 < arr.size <= 16:
                out[key] = arr.astype(float)
        return out


def _fits(ctx, name, hold=()):
    """The :class:`_Fit` of candidate ``name`` on ``ctx.profile``; :class:`~lowcam.errors.NotFitted` with the
    reason when the profile or the captures cannot show it."""
    reasons = []
    for cls, search in candidates()[name]:
        have = ctx.profile.effect(cls.name)
        if search.when and (have is None or any(getattr(have, k) != v for k, v in search.when.items())):
            continue  # a search for another form of the effect (a lens model)
        if search.requires and ctx.profile.effect(search.requires) is None:
            reasons.append(f"the profile has no {search.requires}")
        elif search.captures == "moving" and not ctx.moving:
            reasons.append("no capture moves")
        elif search.captures == "textured" and not ctx.textured:
            reasons.append("no capture has texture")
        elif search.held_noise and not ctx.holds_noise and not (have is not None and have.enabled):
            reasons.append(ctx.holds_noise_reason)  # (a profile's own temporal effect is refitted regardless)
        elif search.per_pixel and any(len(c.frames) < 2 for c in ctx.mset.captures):
            # a dense map fitted to one frame cannot tell the sensor's pattern from that frame's noise
            reasons.append("a per-pixel map needs several frames per capture")
        elif search.fixed and have is not None and have.enabled and all(
                getattr(have, k) == v for k, v in search.fixed.items()):
            reasons.append("the profile has it already")
        else:
            return _Fit(ctx, name, cls, search, hold)
    raise NotFitted(reasons[0] if reasons else "no search applies to the profile's form of the effect")


def fit_candidate(ctx, name: str):
    """Fit candidate ``name`` on ``ctx.profile`` to convergence: (profile with it, fitted params, evidence);
    :class:`~lowcam.errors.NotFitted` when the profile or the captures cannot show it."""
    if name.startswith("without_"):
        return _removal(ctx, name)
    f = _fits(ctx, name)
    f.screen()
    if not f.done:
        f.finish()
    return _evidence(ctx, f)


def _evidence(ctx, f):
    fitted = f.fitted()
    if fitted is None:
        raise NotFitted("the fit found nothing")
    profile, params, shown = fitted
    have = ctx.profile.effect(f.cls.name)
    was = {f"was_{k}": v for k, v in (have.values() if have is not None else {}).items()}
    return profile, params, f.search.evidence.format(**shown, **was)


def _removal(ctx, name):
    effect = candidate_effect(name)
    if ctx.profile.effect(effect) is None:
        raise NotFitted(f"the profile has no {effect}")
    return ctx.profile.without(effect), {}, f"the frames look as if the camera had no {effect}"


def per_pixel(name: str) -> bool:
    """True for a candidate fitted as a dense per-pixel map."""
    return not name.startswith("without_") and any(search.per_pixel for _, search in candidates()[name])


def _changes_noise(name: str) -> bool:
    return not name.startswith("without_") and any(search.changes_noise or search.full_error
                                                   for _, search in candidates()[name])


def _floor_error(ctx, c: Candidate) -> float:
    """The lowest error a candidate could reach once fully compared: :attr:`Candidate.optimistic` (its noise families
    at the floor), and for a stage that changes the noise its mean family without the model's noise in the mean
    too (its estimate counts the profile's, which such a stage may lower); a stage that holds noise from frame to
    frame, whose mean family is measured otherwise, 0."""
    if not _changes_noise(c.effect):
        return c.optimistic
    if any(search.held_noise for _, search in candidates()[c.effect]):
        return 0.0
    fam = c.held_out_families if c.held_out is not None else c.families
    if "mean" not in fam:
        return 0.0
    return _at_floor(fam, float(np.sum(ctx._model_noise)) / max(float(np.sum(ctx._noise)), 1e-12))


def _at_floor(families: dict, mean_less: float = 0.0) -> float:
    """The error of ``families`` with the noise families (variance, rows) at the floor, 1, and ``mean_less`` taken
    off the mean family's square (not below 0)."""
    fam = {k: 1.0 if k in ("variance", "rows") else v for k, v in families.items()}
    if mean_less:
        fam["mean"] = float(np.sqrt(max(fam["mean"] ** 2 - mean_less, 0.0)))
    return float(np.sqrt(sum(v * v for v in fam.values()) / len(fam)))


@dataclass
class Diagnosis:
    comparison: object
    candidates: list
    scratch: object = None  # the temporary folder of fitted maps; removed with the Diagnosis
    seconds: float = 0.0
    added: list = field(default_factory=list)  # forward selection: the candidates added before the last round
    not_fitted: dict = field(default_factory=dict)  # candidate -> why it could not be fitted

    @property
    def error(self) -> float:
        return self.comparison.error

    @property
    def best(self):
        """The best candidate (the polished combination after forward selection), or None."""
        return self.candidates[0] if self.candidates else None

    @property
    def lowers(self) -> bool:
        """True when the best candidate's held-out error is below the profile's by :data:`NAMED_GAIN` at least."""
        return self.best is not None and self.best.score <= self.error * (1 - NAMED_GAIN)

    @property
    def verdict(self) -> str:
        if self.error <= EXPLAINED_BELOW * self.comparison.noise_floor:
            return "explained"
        if self.lowers and self.best.score <= UNEXPLAINED_ABOVE:
            return "missing-effect"
        return "unexplained"

    def summary(self) -> str:
        """One line: the error, the verdict and the numbers it rests on (held-out errors); when unexplained, the
        residual's family (:func:`lowcam.measure.compare.residual_family`)."""
        v, b = self.verdict, self.best
        if v == "explained":
            return f"error {self.error:.3f}, verdict {v}: at the noise floor (explained up to {EXPLAINED_BELOW})"
        if v == "missing-effect":
            return (f"error {self.error:.3f}, verdict {v}: {b.effect} brings it to {b.score:.3f} held out (at most "
                    f"{UNEXPLAINED_ABOVE})")
        if b is not None and not self.lowers:
            why = f"no candidate lowers it (the best, {b.effect}, leaves {b.score:.3f} held out)"
        elif b is not None:
            why = f"the best candidate, {b.effect}, leaves {b.score:.3f} held out (above {UNEXPLAINED_ABOVE})"
        else:
            why = "no candidate could be fitted" + (
                ": " + "; ".join(f"{k}: {r}" for k, r in list(self.not_fitted.items())[:3]) if self.not_fitted
                else "")
        family, numbers = residual_family(self.comparison)
        return f"error {self.error:.3f}, verdict {v}: {why}; the residual is one of {family}: {numbers}"

    def as_json(self) -> dict:
        return {"error": round(self.error, 4), "error_unmasked": round(self.comparison.error_unmasked, 4),
                "noise_floor": self.comparison.noise_floor,
                "verdict": self.verdict, "summary": self.summary(), "seconds": round(self.seconds, 2),
                "residual_family": residual_family(self.comparison)[0],
                "families": {k: round(v, 4) for k, v in self.comparison.families.items()},
                "measured": self.comparison.measured, "added": [c.effect for c in self.added],
                "candidates": [c.as_json() for c in self.candidates],
                "not_fitted": [{"effect": k, "reason": r} for k, r in self.not_fitted.items()],
                "where": self.comparison.where}


class _Trial:
    """One candidate's fits: on the first fold's fitting half (every candidate), on the second fold's too (the
    finalists, so that every capture is measured with a fit that did not see it), and on every capture (the
    best: the profile that would be added)."""

    def __init__(self, name: str):
        self.name = name
        self.folds: list = []  # [(fitted on, measured on, _Fit or None)]
        self.how = ""  # how it is held out, or why it cannot be
        self.main = None  # _Fit on every capture
        self.fixed = None  # (profile, params, evidence) of a candidate that fits nothing (a removal, a method)
        self.reason = ""  # why it cannot be fitted at all
        self.every = False  # every fold fitted, not the first only
        self.unreached = ""  # why keys are held: the captures do not reach where they act
        self.joint: dict = {}  # fold (None: every capture) -> the profile with the earlier additions refitted

    def used(self) -> list:
        """The folds fitted: every one, or the first alone (screening a set of two halves)."""
        return self.folds if self.every else self.folds[:1]

    def profile_for(self, k):
        """The profile fold ``k`` (None: every capture) measures: its fit's, with the earlier additions refitted
        where that was done; None when the fold has no fit."""
        if k in self.joint:
            return self.joint[k]
        f = self.main if k is None else self.folds[k][2]
        return None if f is None or f.fitted() is None else f.fitted()[0]

    def fits(self) -> list:
        return [f for _, _, f in self.used() if f is not None] + ([self.main] if self.main is not None else [])

    def shown(self):
        """The fit whose profile and numbers the candidate shows: on every capture, else the first fold's."""
        return self.main or (self.folds[0][2] if self.folds else None)

    def validation(self) -> str:
        if not self.folds:
            return self.how
        fitted_on, measured_on, _ = self.folds[0]
        if self.every:
            return self.how
        if self.how.startswith("2 folds of captures"):
            return f"fitted on {len(fitted_on.inputs)} captures, measured on the other {len(measured_on.inputs)}"
        return f"fitted on one of {self.how}, measured on the other"


def _attempt(work, trial, fold=None):
    """Run ``work()`` (a fit step); a :class:`~lowcam.errors.NotFitted` drops the fold's fit (or the trial's)."""
    try:
        work()
    except NotFitted as e:
        if fold is None:
            trial.reason, trial.main = str(e), None
        else:
            trial.folds[fold] = trial.folds[fold][:2] + (None,)
            trial.reason = trial.reason or str(e)


def _base_sums(view):
    return np.array([s.sums["mean"][0] for s in view.base.captures]), view._noise


def _measured_sums(view, profile, captures: str):
    """The mean family's sums of ``profile`` on the captures of ``view``: simulated on those of the kind
    ``captures`` (the captures that can show the candidate), the profile's own on the others (a flat field, a
    still capture)."""
    num, den = _base_sums(view)
    idx = view.subset(captures)
    idx = list(range(len(view.inputs))) if idx is None else idx
    if idx:
        num = num.copy()
        num[idx] = view.mean_sums(profile, idx)[0]
    return num, den


def _held_out(ctx, trial) -> tuple[float, dict] | None:
    """(error, families) of the whole set with every measured capture judged by a fit that did not see it: every
    fold pooled, or, with only the first fold fitted, its measured half's improvement over the profile carried
    to the whole set (its mean family scaled by the half's ratio). None when no fold has a fit."""
    used = [(held, f, trial.profile_for(k)) for k, (_, held, f) in enumerate(trial.used())]
    if all(p is None for _, _, p in used):
        return None
    num = base = 0.0
    for held, f, p in used:
        kind = f.search.captures if f is not None and not trial.joint else "all"
        num += float((_measured_sums(held, p, kind) if p is not None else _base_sums(held))[0].sum())
        base += float(_base_sums(held)[0].sum())
    if trial.every:  # every fold measured; captures outside the folds (they cannot show it) keep the profile's
        num += _outside(ctx, trial)
    else:  # one half measured: its ratio to the profile's, over the whole set
        num = _carried(ctx, num, base)
    return ctx.families_with_mean(num, float(ctx._noise.sum()))


def _in_sample(ctx, trial) -> tuple[float, dict]:
    """(error, families) in sample: each fit measured on the captures it was fitted to, carried to the whole set."""
    num = base = 0.0
    for k, g in [(k, x[2]) for k, x in enumerate(trial.used())] + [(None, trial.main)]:
        p = trial.profile_for(k)
        if g is not None and p is not None:
            idx = list(range(len(g.ctx.inputs))) if g.subset is None else g.subset
            num += float(g.ctx.mean_sums(p, idx)[0].sum())
            base += float(_base_sums(g.ctx)[0][idx].sum())
    return ctx.families_with_mean(_carried(ctx, num, base) if base else float(_base_sums(ctx)[0].sum()),
                                  float(ctx._noise.sum()))


def _half_estimate(ctx, profile) -> tuple[float, dict]:
    """:meth:`Context.estimate` of a profile nothing was fitted for, on the half of the captures every candidate
    is screened on (carried to the whole set, as :func:`_held_out`), or on every capture of a small set."""
    folds = ctx.folds("all", tiles=False)
    if isinstance(folds, str) or len(folds[0]) > 2:
        return ctx.estimate(profile)
    held = folds[0][0][1]
    num, base = float(held.mean_sums(profile)[0].sum()), float(_base_sums(held)[0].sum())
    return ctx.families_with_mean(_carried(ctx, num, base), float(ctx._noise.sum()))


def _outside(ctx, trial) -> float:
    """The profile's own mean-family numerator over the captures no fold of ``trial`` measures."""
    covered = {id(c) for _, held, _ in trial.folds for c in held.mset.captures}
    return float(sum(s.sums["mean"][0] for c, s in zip(ctx.mset.captures, ctx.base.captures)
                     if id(c) not in covered))


def _carried(ctx, num: float, base: float) -> float:
    """The whole set's mean-family numerator when some captures' numerator ``num`` stands against the profile's
    own ``base`` on the same captures: the profile's whole numerator times that ratio."""
    return num / max(base, 1e-12) * float(sum(s.sums["mean"][0] for s in ctx.base.captures))


def _spread(trial) -> tuple[dict, set]:
    """Each fitted number's standard error from its two folds' fits (half their difference: the delete-half
    jackknife [Shao1989]), and the searched keys the data do not determine (the folds disagree by more than
    :data:`UNDETERMINED_SPREAD` of the range, or the captures do not show the key at all)."""
    se, loose = {}, set()
    for f in trial.fits():
        loose |= f.blind
    fits = [f for _, _, f in trial.used() if f is not None and f.fitted() is not None]
    if len(fits) < 2:
        return se, loose
    k, numbers = len(fits), [f.numbers() for f in fits]
    search = fits[0].search
    for key in set.intersection(*(set(n) for n in numbers)):
        values = np.stack([np.asarray(n[key], float) for n in numbers])
        # delete-d jackknife with d = n / k left out per fold: var = (k - 1) / k sum (theta_j - mean)^2
        se[key] = float(np.sqrt((k - 1) / k * ((values - values.mean(0)) ** 2).sum(0)).max())
        if key in search.bounds:
            lo, hi = search.bounds[key]
            if np.ptp(values, axis=0).max() > UNDETERMINED_SPREAD * (hi - lo):
                loose.add(key)
    return se, loose


def _flags(ctx, f, profile) -> list[str]:
    """Fitted numbers at a bound of their search, and effects that no real camera has."""
    out = []
    if f is not None and not f.search.fit:
        for key, value, (lo, hi) in zip(f.keys, f.x, f.bounds):
            out += [f"{key} at its bound {bound:g}" for bound in (lo, hi) if abs(value - bound) <= AT_BOUND * (hi - lo)]
    for effect in profile.effects:
        before = ctx.profile.effect(effect.name)
        if effect.enabled and (before is None or before.values() != effect.values()):
            out += [f"implausible: {p}" for p in effect.implausible()]
    return out


def _warm(trial, source, folds) -> None:
    """Start the Gauss-Newton fits of ``folds`` from ``source``'s fitted keys (converged fits need fewer steps)."""
    if source is None or not source.keys:
        return
    for _, _, f in folds:
        if f is not None and not f.screened and f.keys == source.keys:
            f.x = np.clip(source.x, [b[0] for b in f.bounds], [b[1] for b in f.bounds])


def _setup(ctx, name, hold=(), refit=()) -> _Trial:
    """A candidate's trial: its folds' fits (or why it has none), not yet run. With ``refit`` (effects added
    earlier), a removal gets folds too: the earlier additions are refitted with it on each."""
    trial = _Trial(name)
    try:
        if name.startswith("without_"):
            trial.fixed = _removal(ctx, name)
            folds = ctx.folds("all", tiles=False) if refit else "nothing added before"
            if not isinstance(folds, str):
                pairs, trial.how = folds
                trial.folds, trial.every = [(a, b, None) for a, b in pairs], True
            return trial
        probe = _fits(ctx, name, hold)
        unreached = [k for k, r in probe.search.reach.items() if k in probe.keys and ctx.reach() < r]
        if unreached:
            trial.unreached = f"the captures reach {100 * ctx.reach():.0f} % of the way to the corners"
            if set(unreached) >= set(probe.keys) and not (probe.search.grid or probe.search.fit):
                raise NotFitted(f"{', '.join(unreached)} not determined: {trial.unreached}")
            hold = tuple(hold) + tuple(unreached)
            probe = _fits(ctx, name, hold)
        if not probe.fits_anything:
            trial.fixed = _evidence(ctx, probe)
            return trial
        search = probe.search
        folds = ctx.folds(search.captures, not search.fit or getattr(search.fit, "honours_masks", False),
                          search.determined_by)
        if isinstance(folds, str):
            trial.how, trial.main = folds, probe
            return trial
        pairs, trial.how = folds
        for fitted_on, measured_on in pairs:
            try:
                f = _fits(fitted_on, name, hold)
            except NotFitted:
                f = None
            trial.folds.append((fitted_on, measured_on, f))
    except NotFitted as e:
        trial.reason = str(e)
    return trial


def _candidate(ctx, trial, base_error) -> Candidate | None:
    """The trial's :class:`Candidate` with its estimated errors (in sample on the captures its fits saw, held
    out on those they did not: :func:`_held_out`); None (with ``trial.reason``) when nothing could be fitted or
    the fit is not a real camera's."""
    started = time.perf_counter()
    n = len(ctx.mset.captures)
    if trial.fixed is not None:
        profile, params, evidence = trial.fixed
        profile = trial.joint.get(None, profile)
        error, families = _half_estimate(ctx, profile)
        c = Candidate(trial.name, error, params, evidence, profile, False, n, families, held_out=error,
                      held_out_families=families, validation="nothing fitted", base_error=base_error)
        if trial.joint:
            c.validation = f"the earlier additions refitted with it on {trial.how}"
            c.held_out, c.held_out_families = _held_out(ctx, trial)
        c.seconds = time.perf_counter() - started
        return c
    f = trial.shown()
    try:
        if f is None:
            raise NotFitted(trial.reason or "the fit found nothing")
        profile, params, evidence = _evidence(f.ctx, f)
    except NotFitted as e:
        trial.reason = str(e)
        return None
    profile = trial.profile_for(None if trial.main is not None else 0) or profile
    flags = _flags(ctx, f, profile)
    implausible = [x[len("implausible: "):] for x in flags if x.startswith("implausible: ")]
    if implausible:
        trial.reason = "the fit is not a real camera's: " + "; ".join(implausible)
        return None
    error, families = _in_sample(ctx, trial)
    c = Candidate(trial.name, error, {k: (float(v) if isinstance(v, (np.floating, float)) else v)
                                      for k, v in params.items()}, evidence, profile, f.search.per_pixel, n,
                  families, validation=trial.validation(), base_error=base_error, flags=flags)
    held = _held_out(ctx, trial)
    if held is not None:
        c.held_out, c.held_out_families = held
    c.uncertainty, loose = _spread(trial)
    c.flags += [f"{k} not determined by the data" for k in sorted(loose)]
    held = [k for k in f.search.bounds if k not in f.keys]
    if held:
        c.flags.append(f"{', '.join(held)} held at the profile's value" +
                       (f": {trial.unreached}" if trial.unreached else ""))
    c.seconds = sum(g.seconds for g in trial.fits()) + time.perf_counter() - started
    return c


def _full(ctx, c: Candidate, trial, in_sample: bool = True, sim_frames: int | None = None) -> None:
    """The full noise-aware errors: in sample (``c.profile`` on every capture) and held out (each fold's fit on
    the captures it did not see, carried to the whole set as in :func:`_held_out`), with ``sim_frames``
    simulated frames per capture (default: as many as measured, at least 4)."""
    started = time.perf_counter()
    fixed = c.validation == "nothing fitted" and not (trial is not None and trial.joint)
    if in_sample or fixed:  # nothing fitted: its error in sample is its error held out
        c.comparison = ctx.compare(c.profile)
        c.error_after, c.families, c.full = c.comparison.error, dict(c.comparison.families), True
    if fixed:
        c.held_out, c.held_out_families, c.held_out_full = c.error_after, dict(c.families), True
    elif trial is not None and trial.folds:
        stats, base = [], []
        for k, (_, held, _f) in enumerate(trial.used()):
            p = trial.profile_for(k)
            stats += held.compare(p, sim_frames=sim_frames).captures if p is not None else held.base.captures
            base += held.base.captures
        if trial.every:  # captures outside the folds keep the profile's own
            covered = {id(c) for _, held, _ in trial.folds for c in held.mset.captures}
            stats += [s for c, s in zip(ctx.mset.captures, ctx.base.captures) if id(c) not in covered]
        _, families = combine(stats)
        if not trial.every:  # one half measured: its mean family's ratio to the profile's, over the whole set
            families["mean"] *= ctx.base.families["mean"] / max(combine(base)[1]["mean"], 1e-12)
        c.held_out_families = families
        c.held_out = float(np.sqrt(sum(v * v for v in families.values()) / len(families)))
        c.held_out_full = True
    c.seconds += time.perf_counter() - started


def rank(ctx, base_error: float, names, progress=None, refit=()) -> tuple[list[Candidate], dict]:
    """Cross-validated ranking of the named candidates on ``ctx.profile``. Returns (candidates ranked by their
    held-out error, {candidate: why it could not be fitted}). ``refit``: the :class:`Candidate` s added before
    (``ctx.profile`` holds them); they may have made up for what a candidate changes, so the finalists and the
    removals are measured with them refitted (:func:`polish`, on the same folds).

    1. Every candidate is screened on the first fold (:meth:`Context.folds`): fitted coarsely on one half of the
       captures and measured on the other.
    2. The :data:`FITTED` best by held-out error (within :data:`REFINE_WITHIN` of the best), and every fit that
       screens coarsely on purpose (``refines``) whose error in sample is within that (and, where the best is at
       most :data:`~lowcam.measure.compare.EXPLAINED_BELOW`, at least :data:`NAMED_GAIN` below the profile's),
       are fitted on every fold to convergence, so that every capture is measured with a fit that did not see it (leaving one capture
       out, every fold is screened already); none when the profile's error is explained already (at most
       :data:`~lowcam.measure.compare.EXPLAINED_BELOW`), where no candidate will be named.
    3. Every candidate's errors are estimated, in sample and held out; the finalists' fitted numbers get their
       spread between the folds, and keys the data do not determine are held at the profile's value and the
       candidate refitted.
    4. The best is fitted on every capture (the profile that would be added); it, every candidate that changes
       the noise and could still beat the best other estimate at its floor (:func:`_floor_error`), and every
       runner-up that could still win at its floor (at most :data:`FULL_ERRORS`) get the full noise-aware errors."""
    def in_turn(work, items, label):  # ``work`` on each item, WORKERS at a time, results in order
        done = iter(range(len(items)))

        def one(item):
            if progress:
                progress(next(done), len(items), label(item))
            return work(item)

        with ThreadPoolExecutor(WORKERS) as pool:
            return list(pool.map(one, items))

    def run(trials, step, label, folds=(0,), main=False):
        jobs = [(t, k) for t in trials for k in folds if k < len(t.folds) and t.folds[k][2] is not None]
        jobs += [(t, None) for t in trials if main and t.main is not None]

        def one(job):
            t, k = job
            f = t.main if k is None else t.folds[k][2]
            if f.done if step == "finish" else f.screened:
                return
            _attempt(getattr(f, step), t, k)

        in_turn(one, jobs, lambda job: f"{job[0].name} ({label})")

    def screened(trials):
        for t in trials:  # leaving one capture out, every fold is screened (a few small captures)
            t.every = len(t.folds) > 2
        every = tuple(range(max([len(t.folds) for t in trials] + [1])))
        run(trials, "screen", "screening", folds=(0,), main=True)
        run([t for t in trials if t.every], "screen", "screening", folds=every[1:])
        held = {t.name: _held_out(ctx, t) for t in trials if t.folds}
        errors = sorted((h[0], t.name) for t in trials if (h := held.get(t.name)) is not None)
        top = errors[0][0] if errors else np.inf
        if base_error <= EXPLAINED_BELOW:   # explained already: nothing will be named, nothing fitted further
            return
        finalists = [by_name[n] for e, n in errors if e <= REFINE_WITHIN * top][:FITTED]

        def could_win(t):  # a fit whose screening is coarse on purpose (``refines``), by its error in sample
            error = _in_sample(ctx, t)[0]
            # where the best already brings the whole error (the profile's noise families kept) to the floor, only
            # a fit whose own screening lowers the profile's error by NAMED_GAIN
            return error <= REFINE_WITHIN * top and (top > EXPLAINED_BELOW or error <= (1 - NAMED_GAIN) * base_error)

        finalists += [t for t in trials if t.folds and t not in finalists and t.folds[0][2] is not None
                      and getattr(t.folds[0][2].search.fit, "refines", False) and t.folds[0][2].fitted() is not None
                      and could_win(t)]
        run([t for t in finalists if not t.every], "finish", "fitting")
        for t in finalists:
            t.every = True
            _warm(t, t.folds[0][2], t.folds[1:])
        run(finalists, "screen", "fitting the other folds", folds=every[1:])
        run(finalists, "finish", "fitting", folds=every)
        if refit:
            join(finalists)

    def join(trials):  # the earlier additions refitted with each candidate, on each fold and on every capture
        def one(job):
            t, k = job
            start = t.fixed[0] if t.fixed is not None else t.profile_for(k)
            if start is not None:
                t.joint[k] = polish(ctx if k is None else t.folds[k][0], list(refit), start, sweeps=1)

        jobs = [(t, k) for t in trials for k in range(len(t.used()))] + \
            [(t, None) for t in trials if t.main is not None or t.fixed is not None]
        in_turn(one, jobs, lambda job: f"{job[0].name} (refitting the effects added before)")

    trials = [_setup(ctx, n, refit=refit) for n in names]
    by_name = {t.name: t for t in trials}
    screened(trials)
    join([t for t in trials if t.fixed is not None and t.folds])
    out = [c for c in in_turn(lambda t: _candidate(ctx, t, base_error), trials,
                              lambda t: f"{t.name} (estimating)") if c is not None]
    # keys the data do not determine: held at the profile's value, the candidate fitted again
    for c in list(out):
        loose = [x[:-len(" not determined by the data")] for x in c.flags if x.endswith("not determined by the data")]
        f = by_name[c.effect].shown()
        if not loose or f is None or f.search.fit:
            continue
        out.remove(c)
        if set(loose) >= set(f.search.bounds):
            by_name[c.effect].reason = f"not determined by the data: {', '.join(loose)}"
            continue
        again = by_name[c.effect] = _setup(ctx, c.effect, hold=loose)
        screened([again])
        again.unreached = again.unreached or "not determined by the data"
        redone = _candidate(ctx, again, base_error)
        if redone is not None:
            redone.evidence += f" ({', '.join(loose)} held at the profile's value)"
            out.append(redone)
    # a stage that changes the noise: its estimate cannot see what it does, so it is compared in full, unless even
    # at its floor it cannot beat the best other estimate (the hopeful runners-up below catch it should that rise)
    rivals = [c.score for c in out if not _changes_noise(c.effect)]
    for floor, c in sorted(((_floor_error(ctx, c), c) for c in out if _changes_noise(c.effect)),
                           key=lambda pair: pair[0]):
        if rivals and floor >= min(rivals):
            continue
        if progress:
            progress(0, 1, f"{c.effect} (full error)")
        _full(ctx, c, by_name[c.effect], in_sample=False, sim_frames=4)
        quick = ctx.compare(c.profile, ctx.quick, 4)
        c.error_after, c.families = quick.error, dict(quick.families)
        rivals.append(c.score)

    def settle():  # the best: fitted on every capture (the profile to add), its errors the full ones
        out.sort(key=lambda c: c.score)
        while out and not (out[0].full and (out[0].held_out_full or out[0].held_out is None)):
            c, t = out[0], by_name.get(out[0].effect)
            f = next((x for _, _, x in t.folds if x is not None), None) if t is not None else None
            if f is not None and t.main is None:
                t.main = _fits(ctx, t.name, tuple(k for k in f.search.bounds if k not in f.keys))
                if f.keys == t.main.keys:  # from the folds' mean
                    fits = [x for _, _, x in t.used() if x is not None]
                    t.main.x = np.clip(np.mean([x.x for x in fits], axis=0), [b[0] for b in f.bounds],
                                       [b[1] for b in f.bounds])
                if progress:
                    progress(0, 1, f"{t.name} (fitting on every capture)")
                _attempt(t.main.screen, t)
                if t.main is not None and not t.main.done:
                    _attempt(t.main.finish, t)
                if t.main is not None and t.main.fitted() is None:  # its folds' fits did, this one finds nothing
                    t.reason, t.main = "fitted on every capture, the fit found nothing", None
                    out.pop(0)
                    continue
                if t.main is not None:
                    c.profile, params, c.evidence = _evidence(ctx, t.main)
                    c.params = dict(params)
                    if refit:
                        c.profile = t.joint[None] = polish(ctx, list(refit), c.profile, sweeps=1)
            if progress:
                progress(0, 1, f"{c.effect} (full error)")
            _full(ctx, c, t)
            out.sort(key=lambda c: c.score)

    settle()
    # an estimate keeps the first comparison's noise families; a runner-up that could still win with noise
    # families at the floor is fully compared too (the best first, at most FULL_ERRORS of them)
    floors = [(_floor_error(ctx, c), c) for c in out if not c.held_out_full]
    hopeful = sorted(((floor, c) for floor, c in floors if floor < out[0].score), key=lambda pair: pair[0])
    for floor, c in hopeful[:FULL_ERRORS]:
        if floor < out[0].score:
            if progress:
                progress(0, 1, f"{c.effect} (full error)")
            _full(ctx, c, by_name.get(c.effect), in_sample=False)
            out.sort(key=lambda c: c.score)
    settle()
    for c in out:
        held = "" if c.held_out is None else f", {c.held_out:.2f} held out"
        c.evidence += f"; error {base_error:.2f} -> {c.error_after:.2f} in sample{held}" + \
            ("" if c.full else " (estimated)")
    failed = {t.name: t.reason for t in by_name.values() if t.reason and not any(c.effect == t.name for c in out)}
    return out, failed


def polish(ctx, chosen: list[Candidate], profile, sweeps: int = 2):
    """Refit the ``chosen`` candidates together on ``profile`` (which holds them all): each is fitted again with
    the others held, in turn, ``sweeps`` times (backfitting, a block coordinate descent); a refit is kept when it
    lowers the noise-free SSE. Unlike screening, the refits use every capture. Per-pixel maps and removals keep
    their fit. Returns the polished profile."""
    for _ in range(sweeps):
        for c in chosen:
            if c.per_pixel or c.effect.startswith("without_"):
                continue
            here = Context(ctx.mset, profile, ctx.workdir / "polish", parent=ctx, base=ctx.base)
            here.quick, here.screen_textured = list(range(len(ctx.mset.captures))), list(here.textured)
            try:
                fitted = fit_candidate(here, c.effect)
            except NotFitted:
                continue
            if here.sse(fitted[0]) < here.sse(profile):
                profile = fitted[0]
    return profile


def diagnose(mset, profile, only=None, workdir=None, progress=None, rounds: int = 2, assumed_noise=None,
             refit=()) -> Diagnosis:
    """Rank the candidates (all of :func:`candidates` and :func:`removal_candidates`, or ``only``) for a
    measurement set.

    Forward selection: when the best candidate alone leaves the error above 1.1 (held out, and in sample: a
    round after one that explains its captures could name nothing), the others are fitted again
    with it added (up to ``rounds`` rounds), so effects that hide together surface one after the other; each
    later candidate's ``error_after`` then includes the ones before it, and the best of the last round has every
    added effect refitted together (:func:`polish`) before its full error is computed. ``refit``: candidates
    added to ``profile`` before (:func:`explain`), refitted with the finalists and removals (:func:`rank`).
    """
    started = time.perf_counter()
    scratch = None if workdir else tempfile.TemporaryDirectory(prefix="lowcam-diagnose-")
    workdir = Path(workdir or scratch.name)
    ctx = Context(mset, profile, workdir, assumed_noise)
    base = ctx.base
    names = list(only or [*candidates(), *removal_candidates(profile)])
    ranked, failed = rank(ctx, base.error, names, progress, refit)
    chosen: list[Candidate] = []
    for _ in range(rounds - 1):
        if not ranked or min(ranked[0].score, ranked[0].error_after) <= EXPLAINED_BELOW or \
                ranked[0].score >= base.error:
            break
        best = ranked[0]
        chosen.append(best)
        ctx = Context(mset, best.profile, workdir / f"after-{best.effect}", parent=ctx, base=best.comparison)
        remaining = [n for n in names if n not in {c.effect for c in chosen}]
        again, more = rank(ctx, best.error_after, remaining, progress, [*refit, *chosen])
        failed.update(more)
        for c in again:
            c.evidence += f" (with {', '.join(x.effect for x in chosen)} added)"
        ranked = again
    if chosen and ranked and ranked[0].score > EXPLAINED_BELOW:
        top = ranked[0]
        top.profile = polish(ctx, chosen + [top], top.profile)
        _full(ctx, top, None)
        top.evidence += f"; all {len(chosen) + 1} refitted together: error {top.error_after:.2f}"
    return Diagnosis(base, chosen + ranked, scratch, time.perf_counter() - started, chosen, failed)


@dataclass
class Step:
    """One step of :func:`explain`: the diagnosis of the profile so far, the candidate added (None at the end)
    and the profile after it."""

    diagnosis: Diagnosis
    added: Candidate | None
    profile: object


def explain(mset, profile, workdir, max_steps: int = 6, progress=None, min_gain: float = NAMED_GAIN,
            only=None) -> list[Step]:
    """``diagnose --until-explained``: diagnose, add the best candidate, refit every continuous parameter added so
    far together (:func:`polish`), and repeat until the error is explained, no candidate lowers it by at least
    ``min_gain`` (relative), or ``max_steps`` effects were added. The last step's ``added`` is None. ``only``: the
    candidates to try (all when None), as :func:`diagnose` takes them."""
    workdir = Path(workdir)
    steps: list[Step] = []
    added: list[Candidate] = []
    assumed = None
    for k in range(max_steps + 1):
        d = diagnose(mset, profile, only, workdir=workdir / f"step-{k}", progress=progress, rounds=1,
                     assumed_noise=assumed, refit=added)
        assumed = assumed or [s.sums["variance_map"] if len(s.measured) == 1 else None
                              for s in d.comparison.captures]
        best = d.best
        if d.verdict == "explained" or best is None or best.score > d.error * (1 - min_gain) or \
                k == max_steps:
            steps.append(Step(d, None, profile))
            return steps
        added.append(best)
        profile = best.profile
        if len(added) > 1:
            profile = polish(Context(mset, profile, workdir / f"polish-{k}", assumed, base=best.comparison), added,
                             profile)
        steps.append(Step(d, best, profile))
    return steps


def save_candidate_profile(candidate: Candidate, path, profile=None) -> Path:
    """Write the candidate's profile (or ``profile``); fitted maps (.npy) are copied into a folder beside it."""
    path = Path(path).resolve()
    profile = profile or candidate.profile
    for effect in profile.effects:
        texture = getattr(effect, "texture", None)
        if texture and Path(texture).suffix == ".npy" and not Path(texture).is_relative_to(path.parent / path.stem):
            target = path.parent / path.stem / Path(texture).name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(texture, target)
            profile = profile.with_effect(effect.name, texture=str(target), source=str(path), base_dir=path.parent)
    return profile.save(path)
