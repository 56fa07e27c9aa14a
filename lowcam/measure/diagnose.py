"""Which physical effect does the profile lack? Fit each candidate, re-simulate, rank by how far the error falls.

Every candidate is an effect the profile lacks, one whose parameters may be wrong, or one it should not have
(``without_EFFECT``, and ``monochrome``). Each is fitted to the measured temporal means on a noise-free simulation
(:meth:`Context.clean`), in two passes so that a diagnosis takes seconds:

1. **Screening.** Every candidate is fitted coarsely: its grid values (walked from the profile's value towards
   lower error), its closed-form fit, or one Gauss-Newton step of its continuous parameters from finite
   differences (:func:`gauss_newton`).
2. **Fitting.** The :data:`FITTED` best screened candidates are fitted to convergence (more Gauss-Newton steps).

Each candidate's error is then estimated from its noise-free residual and the noise the first comparison measured
(:meth:`Context.estimate`), and the :data:`FULL_ERRORS` best estimates, and every candidate that changes the
noise itself, get the full noise-aware error of :mod:`lowcam.measure.compare`. Ranking is by the error expected on
new frames (:attr:`Candidate.score`): a dense per-pixel map absorbs part of the noise of the means it was fitted
to, so its mean family is corrected out of sample.

Measured and assumed. With one frame per capture the frames' noise cannot be measured; every candidate is then
compared against the noise of the diagnosed profile (``assumed_noise`` in :func:`lowcam.measure.compare.compare`),
so a candidate cannot lower the error by only adding model noise. ``Diagnosis.as_json()["measured"]`` says which
families were measured.

Verdict (:attr:`Diagnosis.verdict`): ``explained`` when the profile's own error is at most 1.1; ``missing-effect``
when the best candidate's expected error is at most :data:`UNEXPLAINED_ABOVE` (it is named, with that error);
``unexplained`` otherwise (``where`` then still says where the residual lives).

Contents
--------
- :data:`UNEXPLAINED_ABOVE`: the best candidate's expected error above which the verdict is ``unexplained`` (1.25)
- :data:`FITTED`: how many screened candidates are fitted to convergence (at most)
- :data:`REFINE_WITHIN`: a screened candidate is fitted to convergence when its estimated error is within this
  factor of the best screened candidate's
- :data:`FULL_ERRORS`: how many runners-up at most get the full noise-aware error besides the best
- :data:`RENAMED_CANDIDATES`: candidates renamed after their effect; the old names are still accepted
- :data:`NOT_REMOVABLE`: effects no ``without_EFFECT`` candidate removes (the chain needs them)
- :class:`Candidate`: one fitted candidate: its error after (in sample and expected), params and evidence
- :class:`Context`: the measured set, the profile, memoised noise-free simulations and the error estimate
- :func:`candidates`: candidate name -> (effect class, :class:`~lowcam.effects.Search`) pairs, in chain order
- :func:`removal_candidates`: the ``without_EFFECT`` candidates of a profile
- :func:`candidate_effect`: the profile effect a candidate adds or changes
- :func:`gauss_newton`: bounded Gauss-Newton (Levenberg-Marquardt) steps on the noise-free residual
- :func:`fit_candidate`: fit one candidate on the context's profile: (profile with it, params, evidence), or None
- :func:`fit_pixel_gain`: PRNU: per-pixel least-squares gain of the measured means against the clean model
- :func:`fit_row_noise`: row noise from the excess variance of row means over the model's
- :func:`fit_monochrome`: a sensor without colour: the saturation control at 0, its luma weights fitted
- :data:`CLOSED_FORM`: the closed-form fits a :class:`~lowcam.effects.Search` may name (``fit = ...``)
- :data:`NOISE_FITS`: the closed-form fits whose candidates change the noise (always fully compared)
- :func:`per_pixel`: True for a candidate fitted as a dense per-pixel map (it absorbs noise)
- :class:`Diagnosis`: the comparison, the ranked candidates, the verdict and the time taken
- :func:`rank`: screen, fit and rank the named candidates
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
"""
from __future__ import annotations

import tempfile
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import NotFitted
from .compare import EXPLAINED_BELOW, capture_inputs, combine, compare, prefix_key, row_noise_variance, \
    simulate_capture

UNEXPLAINED_ABOVE = 1.25
FITTED = 4
REFINE_WITHIN = 1.5
FULL_ERRORS = 3
#: Candidates renamed after their effect; the old names are still accepted.
RENAMED_CANDIDATES = {"gamma": "tone_curve"}
#: Effects no ``without_EFFECT`` candidate removes: the chain cannot run without them, or they are its noise.
NOT_REMOVABLE = ("bayer_sampling", "demosaic", "yuv_blend", "noise", "raw_blend")
_MEMO_ENTRIES = 160  # noise-free frames kept (one capture each, about 4 MB at 640x480)
#: Candidates fitted at once (threads: OpenCV and numpy release the GIL); the results do not depend on it.
WORKERS = 2


@dataclass
class Candidate:
    """One fitted candidate. ``error_after`` is the error with it, in sample (the full noise-aware error when
    ``full``, else estimated from the noise-free fit: :meth:`Context.estimate`); ``families`` its families."""

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

    @property
    def score(self) -> float:
        """The error expected on new frames, by which candidates are ranked. A per-pixel map fitted to the means
        of C captures absorbs 1/C of their noise, so its mean family is inflated by ``sqrt((1 + 1/C) / (1 - 1/C))``
        (in sample the residual variance is (1 - 1/C) of the noise, on new frames (1 + 1/C)); effects with a
        handful of parameters keep their error."""
        if not self.per_pixel or not self.families:
            return self.error_after
        f = 1.0 / max(self.captures, 2)
        families = dict(self.families, mean=self.families["mean"] * float(np.sqrt((1 + f) / (1 - f))))
        return float(np.sqrt(sum(v * v for v in families.values()) / len(families)))

    @property
    def optimistic(self) -> float:
        """The lowest error the candidate could have: its expected error with its noise families at the floor."""
        if not self.families:
            return self.score
        families = {k: 1.0 if k in ("variance", "rows") else v for k, v in self.families.items()}
        error = float(np.sqrt(sum(v * v for v in families.values()) / len(families)))
        return Candidate(self.effect, error, {}, "", per_pixel=self.per_pixel, captures=self.captures,
                         families=families).score

    def as_json(self) -> dict:
        return {"effect": self.effect, "error_after": round(self.error_after, 4),
                "error_out_of_sample": round(self.score, 4), "score": round(self.score, 4),
                "error_is_estimate": not self.full, "seconds": round(self.seconds, 3),
                "families": {k: round(v, 4) for k, v in self.families.items()},
                "params": {k: (v if not isinstance(v, float) else round(v, 6)) for k, v in self.params.items()},
                "evidence": self.evidence}


class Context:
    """The measured set, the profile, memoised noise-free simulations and the error estimate.

    ``assumed_noise`` (per capture, or None) is the noise that one-frame captures are compared against; by
    default the diagnosed profile's own, from its first comparison (:attr:`base`)."""

    def __init__(self, mset, profile, workdir: Path, assumed_noise=None, parent=None, base=None):
        self.mset, self.profile, self.workdir = mset, profile, Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._local, self._lock = threading.local(), threading.Lock()  # candidates are fitted in threads
        if parent is not None:  # the same set: share its inputs, means, capture choices and simulations
            for name in ("inputs", "cache", "memo", "_lock", "means", "moving", "textured", "moving_ones", "quick",
                         "screen_textured"):
                setattr(self, name, getattr(parent, name))
            assumed_noise = assumed_noise or parent.assumed_noise
        else:
            self.inputs = [capture_inputs(profile, c) for c in mset.captures]
            self.cache, self.memo = {}, OrderedDict()
            self.means = [c.mean.astype(np.float32) for c in mset.captures]
            self.moving = any(np.any(c.angular_velocity) for c in mset.captures)
            texture = [inp.ideal[..., :3].std() for inp in self.inputs]
            # Captures with structure: flat fields say nothing about geometry or blur.
            self.textured = [i for i, t in enumerate(texture) if t > 0.02]
            self.moving_ones = [i for i, c in enumerate(mset.captures) if np.any(c.angular_velocity)]
            # a few captures for screening and quick full errors: the two flattest and the most textured
            by_texture = [int(i) for i in np.argsort(texture)]
            self.quick = list(dict.fromkeys((*by_texture[:2], by_texture[-1])))
            self.screen_textured = sorted(self.textured, key=lambda i: -texture[i])[:2]
        first = base or compare(mset, profile, cache=self.cache, inputs=self.inputs, assumed_noise=assumed_noise)
        self.assumed_noise = assumed_noise or [s.sums["variance_map"] if len(s.measured) == 1 else None
                                               for s in first.captures]
        self.base = first
        # per capture: the noise the mean family divides by, the model's noise in the simulated frames' mean, and
        # the offset of noisy from noise-free frames (clipping, rounding), measured once and kept
        self._noise = np.array([s.sums["mean"][1] for s in first.captures])
        self._model_noise = np.array([s.sums["model_noise"] for s in first.captures])
        self._offset = np.array([s.sums["mean"][0] for s in first.captures]) - self._sse_per_capture(profile) - \
            self._model_noise

    @property
    def screening(self) -> bool:
        """True while this thread screens a candidate: a fit with ``refines`` may be coarse."""
        return getattr(self._local, "screening", False)

    @screening.setter
    def screening(self, value: bool):
        self._local.screening = value

    def quiet(self, profile):
        """The profile without its random and step effects, for a smooth, deterministic objective."""
        names = [n for n in ("noise", "row_noise", "quantisation") if profile.effect(n) is not None]
        return profile.without(*names) if names else profile

    def clean(self, profile, subset=None) -> list[np.ndarray]:
        """Noise-free frames (float32) of the captures (all, or ``subset``) through ``profile``, memoised."""
        q = self.quiet(profile)
        key = prefix_key(q, len(q.effects))
        out = []
        for i in range(len(self.inputs)) if subset is None else subset:
            with self._lock:
                frame = self.memo.get((key, i))
                if frame is not None:
                    self.memo.move_to_end((key, i))
            if frame is None:
                frame = simulate_capture(q, self.mset.captures[i], 1, inputs=self.inputs[i], cache=self.cache,
                                         until="bayer_sampling")[0].astype(np.float32)
                with self._lock:
                    self.memo[(key, i)] = frame
                    if len(self.memo) > _MEMO_ENTRIES:
                        self.memo.popitem(last=False)
            out.append(frame)
        return out

    def _difference(self, i, frame):
        d = self.means[i] - frame
        mask = self.inputs[i].mask
        return d if mask is None else d * mask[..., None]

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

    def estimate(self, profile, subset=None) -> tuple[float, dict]:
        """(error, families) expected of ``profile`` (over all captures, or ``subset``) from its noise-free
        residual: the mean family's residual is the noise-free one plus the model's noise in the mean of the
        simulated frames and the first comparison's offset of noisy from noise-free frames; the noise families are
        the first comparison's."""
        idx = list(range(len(self.inputs))) if subset is None else list(subset)
        num = max(float((self._sse_per_capture(profile, subset) + self._model_noise[idx] + self._offset[idx]).sum()),
                  0.0)
        families = dict(self.base.families, mean=float(np.sqrt(num / self._noise[idx].sum())))
        return float(np.sqrt(sum(v * v for v in families.values()) / len(families))), families

    def subset(self, captures: str):
        """The captures (indices, or None for all) a search with ``captures`` fits on."""
        return {"all": None, "textured": self.textured, "moving": self.moving_ones}[captures]

    def screening_subset(self, captures: str):
        """Fewer captures for screening: the two most textured, or :attr:`quick`."""
        return {"all": self.quick, "textured": self.screen_textured, "moving": self.moving_ones}[captures]


# --- the candidates: each effect's declared searches (lowcam.effects.Search) ---------------------------------------

def candidates() -> dict:
    """Candidate name -> list of (effect class, :class:`~lowcam.effects.Search`), from every known effect's
    ``searches`` (bundled and plug-in), in chain order."""
    from ..effects import known_effects

    out: dict = {}
    for cls in known_effects():
        for search in cls.searches:
            out.setdefault(search.candidate, []).append((cls, search))
    return out


def removal_candidates(profile) -> list[str]:
    """The ``without_EFFECT`` candidates of ``profile``: each enabled effect the chain can run without."""
    return [f"without_{e.name}" for e in profile.effects
            if e.enabled and not e.always_runs and e.name not in NOT_REMOVABLE]


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
    copes with effects that hardly act near their start (a blur of sigma 0). Returns (x, SSE)."""
    lo, hi = np.array([b[0] for b in bounds], float), np.array([b[1] for b in bounds], float)
    span = np.maximum(hi - lo, 1e-12)
    x = np.clip(np.asarray(x0, float), lo, hi)
    r = ctx.residual(build(x), subset)
    sse = float(np.dot(r, r))
    for _ in range(steps):
        jac = np.zeros((r.size, len(x)), np.float32)
        for k in range(len(x)):
            for size in (0.05, 0.25):  # a wider difference where the effect hardly acts
                h = size * span[k] if x[k] + size * span[k] <= hi[k] else -size * span[k]
                xk = x.copy()
                xk[k] += h
                jac[:, k] = (r - ctx.residual(build(xk), subset)) / (h / span[k])  # d(model)/d(scaled x)
                if np.abs(jac[:, k]).max() > 1e-3:
                    break
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
    return x, sse


class _Fit:
    """One candidate's fit in progress: :meth:`screen` (coarse), then :meth:`finish` (to convergence)."""

    def __init__(self, ctx, name, cls, search):
        self.ctx, self.name, self.cls, self.search = ctx, name, cls, search
        self.values = dict(search.fixed)
        self.keys = list(search.bounds)
        self.bounds = list(search.bounds.values())
        self.subset = ctx.screening_subset(search.captures)  # fitted on a few captures; polish uses all
        have = ctx.profile.effect(cls.name)
        current = have.values() if have is not None and have.enabled and not search.replace else {}
        self.x = np.array([current.get(k, search.start.get(k, cls.params[k].default)) for k in self.keys], float)
        self.result = None  # (profile, params, shown) once fitted in closed form
        self.reason = None  # why a fit could not be made (NotFitted)
        self.done = False
        self.seconds = 0.0

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

    def _fit(self):
        return CLOSED_FORM[self.search.fit] if isinstance(self.search.fit, str) and self.search.fit else self.search.fit

    def screen(self):
        started = time.perf_counter()
        fit = self._fit()
        if fit:
            self.ctx.screening = True  # a fit that ``refines`` does a coarse version now, the full one in finish
            try:
                self.result = fit(self.ctx, self.cls.name)
            except NotFitted as e:
                self.result, self.reason = None, str(e)
            finally:
                self.ctx.screening = False
            self.done = self.result is None or not getattr(fit, "refines", False)
        else:
            for key, options in self.search.grid.items():
                self._grid(key, list(options))
            if self.keys:
                self.x, _ = gauss_newton(self.ctx, self.build, self.x, self.bounds, self.subset, steps=1)
            self.done = not self.keys
        self.seconds += time.perf_counter() - started

    def finish(self):
        started = time.perf_counter()
        if self.search.fit:  # a fit that refines: its full version
            try:
                self.result = self._fit()(self.ctx, self.cls.name)
            except NotFitted as e:
                self.result, self.reason = None, str(e)
            self.done = True
            self.seconds += time.perf_counter() - started
            return
        if self.keys:
            self.x, _ = gauss_newton(self.ctx, self.build, self.x, self.bounds, self.subset,
                                     steps=max(1, self.search.evals // 10))
        self.done = True
        self.seconds += time.perf_counter() - started

    def fitted(self):
        """(profile with it, fitted params, values shown in the evidence), or None."""
        if self.result is not None or self.search.fit:
            return self.result
        values = dict(self.values, **dict(zip(self.keys, map(float, self.x))))
        return self.build(), values, values


def _fits(ctx, name):
    """The :class:`_Fit` of candidate ``name`` on ``ctx.profile``, or None when the profile or the captures cannot
    show it."""
    for cls, search in candidates()[name]:
        have = ctx.profile.effect(cls.name)
        if search.requires and ctx.profile.effect(search.requires) is None:
            continue
        if search.when and (have is None or any(getattr(have, k) != v for k, v in search.when.items())):
            continue
        if search.captures == "moving" and not ctx.moving:
            continue
        if search.per_pixel and any(len(c.frames) < 2 for c in ctx.mset.captures):
            continue  # a dense map's out-of-sample correction assumes a residual of noise: measure the noise first
        if search.fixed and have is not None and have.enabled and all(
                getattr(have, k) == v for k, v in search.fixed.items()):
            continue
        return _Fit(ctx, name, cls, search)
    return None


def fit_candidate(ctx, name: str):
    """Fit candidate ``name`` on ``ctx.profile`` to convergence: (profile with it, fitted params, evidence), or
    None when the profile or the captures cannot show it."""
    if name.startswith("without_"):
        return _removal(ctx, name)
    f = _fits(ctx, name)
    if f is None:
        return None
    f.screen()
    if not f.done:
        f.finish()
    return _evidence(ctx, f)


def _evidence(ctx, f):
    fitted = f.fitted()
    if fitted is None:
        return None
    profile, params, shown = fitted
    have = ctx.profile.effect(f.cls.name)
    was = {f"was_{k}": v for k, v in (have.values() if have is not None else {}).items()}
    return profile, params, f.search.evidence.format(**shown, **was)


def _removal(ctx, name):
    effect = candidate_effect(name)
    if ctx.profile.effect(effect) is None:
        return None
    return ctx.profile.without(effect), {}, f"the frames look as if the camera had no {effect}"


def _pixel_maps(ctx):
    """The clean model and the measured means of every capture, stacked."""
    return np.stack(ctx.clean(ctx.profile)).astype(np.float64), np.stack(ctx.means).astype(np.float64)


def fit_pixel_gain(ctx, effect):
    """PRNU: per-pixel least-squares gain of the measured means against the clean model."""
    from ..effects.fixed_pattern import _with_map

    s, m = _pixel_maps(ctx)
    gain = ((m - s) * s).sum(0) / np.maximum((s * s).sum(0), 1e-6)
    profile, params = _with_map(ctx, effect, gain)
    return profile, dict(params, sigma=float(gain.std())), {"sigma": float(gain.std())}


def fit_row_noise(ctx, effect):
    """Row noise from the excess variance of row means over the model's (:func:`row_noise_variance`)."""
    excess = float(np.mean([row_noise_variance(st.measured) - row_noise_variance(st.simulated)
                            for st in ctx.base.captures if len(st.measured) > 1] or [0.0]))
    if excess <= 0:
        return None
    sigma = float(np.sqrt(excess))
    return ctx.profile.with_effect(effect, sigma_dn=sigma), {"sigma_dn": sigma}, {"sigma_dn": sigma}


def fit_monochrome(ctx, effect):
    """A sensor without colour: the saturation control at 0 (every channel the luma), the luma's weights fitted
    by least squares to the measured grey (the means' channel average) from the model's colour before the
    saturation control. Lateral colour stays: through a grey sensor it is a slight blur, and no fringe. None when
    the measured frames are not grey."""
    from ..effects.saturation import saturation_matrix

    p = ctx.profile
    sat = p.effect(effect)
    s = np.concatenate([c.reshape(-1, 3) for c in ctx.clean(p, ctx.quick)]).astype(np.float64)
    m = np.concatenate([ctx.means[i].reshape(-1, 3) for i in ctx.quick]).astype(np.float64)
    grey = m.mean(axis=1)
    if np.abs(m - grey[:, None]).mean() > 0.1 * max(m.std(), 1e-6):
        return None  # the frames carry colour
    control = saturation_matrix(sat.saturation, sat.luma)
    if abs(np.linalg.det(control)) < 1e-9:
        return None  # the model is monochrome already
    ok = (s.max(1) < 250) & (grey < 250) & (s.min(1) > 3)
    before = np.linalg.solve(control, s[ok].T).T  # the colour before the control
    luma = np.clip(np.linalg.lstsq(before, grey[ok], rcond=None)[0], 0.0, 1.0)
    p = p.with_effect(effect, saturation=0.0, luma=luma.tolist())
    weights = " ".join(f"{w:.3f}" for w in luma)
    return p, {"saturation": 0.0, "luma": luma.round(4).tolist()}, {"weights": weights}


#: The closed-form fits a :class:`~lowcam.effects.Search` may name (``fit = ...``).
CLOSED_FORM = {"pixel_gain": fit_pixel_gain, "row_noise": fit_row_noise, "monochrome": fit_monochrome}
NOISE_FITS = ("row_noise",)


def per_pixel(name: str) -> bool:
    """True for a candidate fitted as a dense per-pixel map (it absorbs noise: :attr:`Candidate.score`)."""
    return not name.startswith("without_") and any(search.per_pixel for _, search in candidates()[name])


def _changes_noise(name: str) -> bool:
    return not name.startswith("without_") and any(search.fit in NOISE_FITS or search.full_error
                                                   for _, search in candidates()[name])


@dataclass
class Diagnosis:
    comparison: object
    candidates: list
    scratch: object = None  # the temporary folder of fitted maps; removed with the Diagnosis
    seconds: float = 0.0
    added: list = field(default_factory=list)  # forward selection: the candidates added before the last round

    @property
    def error(self) -> float:
        return self.comparison.error

    @property
    def best(self):
        """The best candidate (the polished combination after forward selection), or None."""
        return self.candidates[0] if self.candidates else None

    @property
    def verdict(self) -> str:
        if self.error <= EXPLAINED_BELOW * self.comparison.noise_floor:
            return "explained"
        if self.best is not None and self.best.score <= UNEXPLAINED_ABOVE:
            return "missing-effect"
        return "unexplained"

    def summary(self) -> str:
        """One line: the error, the verdict and the numbers it rests on."""
        v, b = self.verdict, self.best
        if v == "explained":
            why = f"at the noise floor (explained up to {EXPLAINED_BELOW})"
        elif v == "missing-effect":
            why = f"{b.effect} brings it to {b.score:.3f} (at most {UNEXPLAINED_ABOVE})"
        else:
            why = (f"the best candidate, {b.effect}, leaves {b.score:.3f} (above {UNEXPLAINED_ABOVE})" if b else
                   "no candidate could be fitted")
        return f"error {self.error:.3f}, verdict {v}: {why}"

    def as_json(self) -> dict:
        return {"error": round(self.error, 4), "noise_floor": self.comparison.noise_floor,
                "verdict": self.verdict, "summary": self.summary(), "seconds": round(self.seconds, 2),
                "families": {k: round(v, 4) for k, v in self.comparison.families.items()},
                "measured": self.comparison.measured, "added": [c.effect for c in self.added],
                "candidates": [c.as_json() for c in self.candidates], "where": self.comparison.where}


def _screened_error(ctx, f) -> float:
    if f.search.fit:
        return ctx.estimate(f.result[0], ctx.quick)[0] if f.result is not None else np.inf
    return ctx.estimate(f.build(), f.subset)[0]


def _candidate(ctx, name, fitted, seconds, subset) -> Candidate:
    """A fitted candidate with its estimated error on ``subset`` (the captures it was fitted on, so no more
    simulations are needed); a candidate that changes the noise gets the full error on :attr:`Context.quick`.
    ``seconds`` (the fit's) grows by this error's."""
    started = time.perf_counter()
    profile, params, evidence = fitted
    if _changes_noise(name):
        cmp = ctx.compare(profile, ctx.quick, 4)
        error, families = cmp.error, cmp.families
    else:
        error, families = ctx.estimate(profile, subset)
    clean = {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in params.items()}
    return Candidate(name, error, clean, evidence, profile, per_pixel(name), len(ctx.mset.captures), dict(families),
                     False, seconds + time.perf_counter() - started)


def _full(ctx, c: Candidate) -> None:
    started = time.perf_counter()
    c.comparison = ctx.compare(c.profile)
    c.error_after, c.families, c.full = c.comparison.error, dict(c.comparison.families), True
    c.seconds += time.perf_counter() - started


def rank(ctx, base_error: float, names, progress=None) -> list[Candidate]:
    """Screen every named candidate on ``ctx.profile``, fit the :data:`FITTED` most promising to convergence,
    estimate each one's error and compute the full error of the :data:`FULL_ERRORS` best (and of every
    candidate that changes the noise); ranked by :attr:`Candidate.score`."""
    def in_turn(work, items, label):  # ``work`` on each item, WORKERS at a time, results in order
        done = iter(range(len(items)))

        def one(item):
            if progress:
                progress(next(done), len(items), label(item))
            return work(item)

        with ThreadPoolExecutor(WORKERS) as pool:
            return list(pool.map(one, items))

    def screened(name):
        started = time.perf_counter()
        if name.startswith("without_"):
            fitted = _removal(ctx, name)
            return None if fitted is None else _candidate(ctx, name, fitted, time.perf_counter() - started, ctx.quick)
        f = _fits(ctx, name)
        if f is not None:
            f.screen()
        return f

    found = in_turn(screened, names, str)
    out = [x for x in found if isinstance(x, Candidate)]
    fits = [x for x in found if isinstance(x, _Fit)]
    # refine the most promising: by the error estimated on the captures each was screened on (no new simulations
    # for searched ones), against the best of every candidate screened
    screened_errors = sorted((_screened_error(ctx, f), k) for k, f in enumerate(fits))
    best = screened_errors[0][0] if screened_errors else 0.0
    pending = [fits[k] for e, k in screened_errors if not fits[k].done and e <= REFINE_WITHIN * best][:FITTED]
    in_turn(_Fit.finish, pending, lambda f: f"{f.name} (refining)")

    def estimated(f):
        started = time.perf_counter()
        fitted = _evidence(ctx, f)
        return None if fitted is None else _candidate(ctx, f.name, fitted, f.seconds + time.perf_counter() - started,
                                                      ctx.quick if f.search.fit else f.subset)

    out += [c for c in in_turn(estimated, fits, lambda f: f"{f.name} (estimating)") if c is not None]
    out.sort(key=lambda c: c.score)
    while out and not out[0].full:  # the best is always fully compared
        if progress:
            progress(0, 1, f"{out[0].effect} (full error)")
        _full(ctx, out[0])
        out.sort(key=lambda c: c.score)
    # an estimate keeps the first comparison's noise families; a runner-up that could still win with noise
    # families at the floor is fully compared too (the best first, at most FULL_ERRORS of them)
    hopeful = sorted((c for c in out if not c.full and c.optimistic < out[0].score), key=lambda c: c.optimistic)
    for c in hopeful[:FULL_ERRORS]:
        if c.optimistic < out[0].score:
            if progress:
                progress(0, 1, f"{c.effect} (full error)")
            _full(ctx, c)
            out.sort(key=lambda c: c.score)
    for c in out:
        c.evidence += f"; error {base_error:.2f} -> {c.error_after:.2f}" + ("" if c.full else " (estimated)")
    return out


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
            fitted = fit_candidate(here, c.effect)
            if fitted is not None and here.sse(fitted[0]) < here.sse(profile):
                profile = fitted[0]
    return profile


def diagnose(mset, profile, only=None, workdir=None, progress=None, rounds: int = 2, assumed_noise=None,
             ) -> Diagnosis:
    """Rank the candidates (all of :func:`candidates` and :func:`removal_candidates`, or ``only``) for a
    measurement set.

    Forward selection: when the best candidate alone leaves the error above 1.1, the others are fitted again
    with it added (up to ``rounds`` rounds), so effects that hide together surface one after the other; each
    later candidate's ``error_after`` then includes the ones before it, and the best of the last round has every
    added effect refitted together (:func:`polish`) before its full error is computed.
    """
    started = time.perf_counter()
    scratch = None if workdir else tempfile.TemporaryDirectory(prefix="lowcam-diagnose-")
    workdir = Path(workdir or scratch.name)
    ctx = Context(mset, profile, workdir, assumed_noise)
    base = ctx.base
    names = list(only or [*candidates(), *removal_candidates(profile)])
    ranked = rank(ctx, base.error, names, progress)
    chosen: list[Candidate] = []
    for _ in range(rounds - 1):
        if not ranked or ranked[0].error_after <= EXPLAINED_BELOW:
            break
        best = ranked[0]
        chosen.append(best)
        ctx = Context(mset, best.profile, workdir / f"after-{best.effect}", parent=ctx, base=best.comparison)
        remaining = [n for n in names if n not in {c.effect for c in chosen}]
        again = rank(ctx, best.error_after, remaining, progress)
        for c in again:
            c.evidence += f" (with {', '.join(x.effect for x in chosen)} added)"
        ranked = again
    if chosen and ranked and ranked[0].error_after > EXPLAINED_BELOW:
        top = ranked[0]
        top.profile = polish(ctx, chosen + [top], top.profile)
        _full(ctx, top)
        top.evidence += f"; all {len(chosen) + 1} refitted together: error {top.error_after:.2f}"
    return Diagnosis(base, chosen + ranked, scratch, time.perf_counter() - started, chosen)


@dataclass
class Step:
    """One step of :func:`explain`: the diagnosis of the profile so far, the candidate added (None at the end)
    and the profile after it."""

    diagnosis: Diagnosis
    added: Candidate | None
    profile: object


def explain(mset, profile, workdir, max_steps: int = 6, progress=None, min_gain: float = 0.03) -> list[Step]:
    """``diagnose --until-explained``: diagnose, add the best candidate, refit every continuous parameter added so
    far together (:func:`polish`), and repeat until the error is explained, no candidate lowers it by at least
    ``min_gain`` (relative), or ``max_steps`` effects were added. The last step's ``added`` is None."""
    workdir = Path(workdir)
    steps: list[Step] = []
    added: list[Candidate] = []
    assumed = None
    for k in range(max_steps + 1):
        d = diagnose(mset, profile, workdir=workdir / f"step-{k}", progress=progress, rounds=1,
                     assumed_noise=assumed)
        assumed = assumed or [s.sums["variance_map"] if len(s.measured) == 1 else None
                              for s in d.comparison.captures]
        best = d.best
        if d.verdict == "explained" or best is None or best.error_after > d.error * (1 - min_gain) or \
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
    import shutil

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
