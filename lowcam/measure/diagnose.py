"""Which physical effect does the profile lack? Fit each candidate, re-simulate, rank by how far the error falls.

Every candidate is an effect the profile lacks, or one whose parameters may be wrong. Each is fitted to the
measured frames (most by a bounded search on a noise-free simulation against the measured temporal means; the
fixed-pattern maps in closed form; noise-shaped candidates against the full error), then the full noise-aware
error (:mod:`lowcam.measure.compare`) is computed with it. Candidates are ranked by that error, best first,
after correcting per-pixel maps for what they absorb of the noise (:attr:`Candidate.score`).

Verdict: ``explained`` when the profile's own error is below 1.1; ``missing-effect`` when the best candidate's
score is at most 1.25; ``unexplained`` otherwise (``where`` then still says where the residual lives).

Contents
--------
- :data:`UNEXPLAINED_ABOVE`: the best candidate's score above which the verdict is ``unexplained`` (1.25)
- :data:`RENAMED_CANDIDATES`: candidates renamed after their effect; the old names are still accepted
- :class:`Candidate`: one fitted candidate: its error after, score, params and evidence
- :class:`Context`: the measured set, the profile, cached inputs and the noise-free objective
- :func:`candidates`: candidate name -> (effect class, :class:`~lowcam.effects.Search`) pairs, in chain order
- :func:`candidate_effect`: the profile effect a candidate adds or changes
- :func:`fit_candidate`: fit one candidate on the context's profile: (profile with it, params, evidence), or None
- :func:`fit_pixel_gain`: PRNU: per-pixel least-squares gain of the measured means against the clean model
- :func:`fit_pixel_offset`: DSNU: the per-pixel mean offset of the measured means from the clean model
- :func:`fit_hot_pixels`: pixels far brighter than the model in every capture that can show it
- :func:`fit_row_noise`: row noise from the excess variance of row means over the model's
- :func:`fit_colour_matrix`: a crosstalk matrix from a colour matrix between the clean model and the means
- :data:`CLOSED_FORM`: the closed-form fits a :class:`~lowcam.effects.Search` may name (``fit = ...``)
- :data:`PER_PIXEL_FITS`: the closed-form fits that give a dense per-pixel map
- :func:`per_pixel`: True for a candidate fitted as a dense per-pixel map (it absorbs noise)
- :class:`Diagnosis`: the comparison, the ranked candidates and the verdict
- :func:`rank`: fit every named candidate and rank them by score
- :func:`diagnose`: rank the candidates (all of :func:`candidates`, or ``only``) for a measurement set
- :func:`save_candidate_profile`: write a candidate's profile, its fitted maps (.npy) copied beside it

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008 (fixed-pattern and row noise).
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (PRNU and DSNU).
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .compare import EXPLAINED_BELOW, capture_inputs, compare, row_noise_variance, simulate_capture

UNEXPLAINED_ABOVE = 1.25
#: Candidates renamed after their effect; the old names are still accepted.
RENAMED_CANDIDATES = {"gamma": "tone_curve"}


@dataclass
class Candidate:
    effect: str
    error_after: float
    params: dict
    evidence: str
    profile: object = field(repr=False, default=None)
    per_pixel: bool = False  # fitted as a map with one value per pixel and channel
    captures: int = 1

    @property
    def score(self) -> float:
        """The error expected on new frames, by which candidates are ranked. A per-pixel map fitted to C captures
        absorbs 1/C of the noise of the means it was fitted to, so its in-sample error is inflated by
        ``sqrt((1 + 1/C) / (1 - 1/C))``; effects with a handful of parameters keep their error."""
        if not self.per_pixel:
            return self.error_after
        f = 1.0 / max(self.captures, 2)
        return self.error_after * float(np.sqrt((1 + f) / (1 - f)))

    def as_json(self) -> dict:
        return {"effect": self.effect, "error_after": round(self.error_after, 4), "score": round(self.score, 4),
                "params": {k: (v if not isinstance(v, float) else round(v, 6)) for k, v in self.params.items()},
                "evidence": self.evidence}


class Context:
    """The measured set, the profile, cached inputs and the noise-free objective."""

    def __init__(self, mset, profile, workdir: Path):
        self.mset, self.profile, self.workdir = mset, profile, Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.inputs = [capture_inputs(profile, c) for c in mset.captures]
        self.cache: dict = {}
        self.means = [c.mean for c in mset.captures]
        self.moving = any(np.any(c.angular_velocity) for c in mset.captures)
        # Captures with structure: flat fields say nothing about geometry or blur.
        self.textured = [i for i, (ideal, _) in enumerate(self.inputs) if ideal[..., :3].std() > 0.02]
        self.moving_ones = [i for i, c in enumerate(mset.captures) if np.any(c.angular_velocity)]

    def quiet(self, profile):
        """The profile without its random and step effects, for a smooth, deterministic objective."""
        names = [n for n in ("noise", "row_noise", "quantisation") if profile.effect(n) is not None]
        return profile.without(*names) if names else profile

    def clean(self, profile, subset=None) -> list[np.ndarray]:
        q = self.quiet(profile)
        idx = range(len(self.inputs)) if subset is None else subset
        return [simulate_capture(q, self.mset.captures[i], 1, inputs=self.inputs[i], cache=self.cache,
                                 until="bayer_sampling")[0].astype(np.float64) for i in idx]

    def compare(self, profile):
        return compare(self.mset, profile, cache=self.cache, inputs=self.inputs)

    def sse(self, profile, subset=None) -> float:
        idx = range(len(self.inputs)) if subset is None else subset
        return float(sum(((self.means[i] - s) ** 2).sum() for i, s in zip(idx, self.clean(profile, subset))))


def _search(ctx, build, bounds, x0, evals: int = 30, subset=None):
    """Minimise the noise-free SSE over continuous parameters (bounded Brent in 1-D, Nelder-Mead otherwise)."""
    from scipy.optimize import minimize, minimize_scalar

    def cost(x):
        x = np.clip(np.atleast_1d(x), [b[0] for b in bounds], [b[1] for b in bounds])
        return ctx.sse(build(x), subset)

    if len(bounds) == 1:
        r = minimize_scalar(lambda v: cost([v]), bounds=bounds[0], method="bounded",
                            options={"xatol": 1e-3 * (bounds[0][1] - bounds[0][0]), "maxiter": evals})
        return np.array([r.x])
    r = minimize(cost, x0, method="Nelder-Mead", options={"maxfev": evals, "xatol": 1e-3, "fatol": 1e-6})
    return np.clip(r.x, [b[0] for b in bounds], [b[1] for b in bounds])


def _grid(ctx, build, values, full: bool = False):
    scores = [(ctx.compare(build(v)).error if full else ctx.sse(build(v))) for v in values]
    return values[int(np.argmin(scores))]


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


def candidate_effect(name: str) -> str:
    """The profile effect a candidate adds or changes."""
    return candidates()[name][0][0].name


def fit_candidate(ctx, name: str):
    """Fit candidate ``name`` on ``ctx.profile``: (profile with it, fitted params, evidence), or None when the
    profile or the captures cannot show it."""
    for cls, search in candidates()[name]:
        have = ctx.profile.effect(cls.name)
        if search.requires and ctx.profile.effect(search.requires) is None:
            continue
        if search.when and (have is None or any(getattr(have, k) != v for k, v in search.when.items())):
            continue
        if search.captures == "moving" and not ctx.moving:
            continue
        if search.fixed and have is not None and have.enabled and all(
                getattr(have, k) == v for k, v in search.fixed.items()):
            continue
        fit = CLOSED_FORM[search.fit] if isinstance(search.fit, str) and search.fit else search.fit
        fitted = fit(ctx, cls.name) if fit else _fit_search(ctx, cls, search)
        if fitted is None:
            continue
        profile, params, shown = fitted
        was = {f"was_{k}": v for k, v in (have.values() if have is not None else {}).items()}
        return profile, params, search.evidence.format(**shown, **was)
    return None


def _fit_search(ctx, cls, search):
    """Grid values first (with refinement steps), then a bounded search over the continuous parameters."""
    p, effect = ctx.profile, cls.name
    subset = {"all": None, "textured": ctx.textured, "moving": ctx.moving_ones}[search.captures]
    values = dict(search.fixed)

    def build(extra):
        return p.with_effect(effect, replace=search.replace, after=search.after or None, **values, **extra)

    for key, options in search.grid.items():
        best = _grid(ctx, lambda v: build({key: v}), list(options), search.full_error)
        if key in search.refine:
            low, high = cls.params[key].low, cls.params[key].high
            best = _grid(ctx, lambda v: build({key: v}), sorted({min(high, max(low, best + d))
                                                                 for d in search.refine[key]}), search.full_error)
        values[key] = best
    if search.bounds:
        keys, bounds = list(search.bounds), list(search.bounds.values())
        x0 = [search.start.get(k, 0.5 * (lo + hi)) for k, (lo, hi) in zip(keys, bounds)]
        x = _search(ctx, lambda x: build(dict(zip(keys, map(float, x)))), bounds, x0, search.evals, subset)
        values.update(zip(keys, map(float, x)))
    return build({}), values, values


def _pixel_maps(ctx):
    """The clean model and the measured means of every capture, stacked."""
    return np.stack(ctx.clean(ctx.profile)), np.stack(ctx.means)


def _with_map(ctx, effect: str, values: np.ndarray):
    """The profile with ``effect`` reading the per-pixel map ``values`` (saved as .npy), and its params."""
    path = ctx.workdir / f"{effect}.npy"
    np.save(path, values.astype(np.float32))
    return ctx.profile.with_effect(effect, replace=True, texture=str(path)), {"texture": str(path)}


def fit_pixel_gain(ctx, effect):
    """PRNU: per-pixel least-squares gain of the measured means against the clean model."""
    s, m = _pixel_maps(ctx)
    gain = ((m - s) * s).sum(0) / np.maximum((s * s).sum(0), 1e-6)
    profile, params = _with_map(ctx, effect, gain)
    return profile, dict(params, sigma=float(gain.std())), {"sigma": float(gain.std())}


def fit_pixel_offset(ctx, effect):
    """DSNU: the per-pixel mean offset of the measured means from the clean model."""
    s, m = _pixel_maps(ctx)
    offset = (m - s).mean(0)
    profile, params = _with_map(ctx, effect, offset)
    return profile, dict(params, sigma_dn=float(offset.std())), {"sigma_dn": float(offset.std())}


def fit_hot_pixels(ctx, effect):
    """Pixels far brighter than the model in every capture that can show it (robust threshold)."""
    s, m = _pixel_maps(ctx)
    unclipped = m < 250  # a hot pixel over a bright area clips: its offset shows only where there is headroom
    diff = np.where(unclipped, m - s, np.nan)
    with np.errstate(all="ignore"):
        low = np.nanmin(diff, axis=0)  # bright in every capture that can show it
        offset = np.nanmean(diff, axis=0)
    low, offset = np.nan_to_num(low), np.nan_to_num(offset)
    spread = 1.4826 * np.median(np.abs(low - np.median(low)))
    hot = low > max(8 * spread, 10.0)
    if not hot.any():
        return None
    n = int(hot.any(axis=-1).sum())
    profile, params = _with_map(ctx, effect, np.where(hot, offset, 0.0))
    return profile, dict(params, count=n), {"count": n, "median_dn": float(np.median(offset[hot]))}


def fit_row_noise(ctx, effect):
    """Row noise from the excess variance of row means over the model's, refined on the full error."""
    base = ctx.compare(ctx.profile)
    excess = float(np.mean([row_noise_variance(st.measured) - row_noise_variance(st.simulated)
                           for st in base.captures]))
    if excess <= 0:
        return None
    sigmas = [np.sqrt(excess) * f for f in (0.8, 1.0, 1.25)]
    best = float(_grid(ctx, lambda v: ctx.profile.with_effect(effect, sigma_dn=v), sigmas, full=True))
    return ctx.profile.with_effect(effect, sigma_dn=best), {"sigma_dn": best}, {"sigma_dn": float(np.sqrt(excess))}


def fit_colour_matrix(ctx, effect):
    """A crosstalk matrix from a least-squares colour matrix between the clean model and the means."""
    from ..effects.crosstalk import fit_colour_matrix as fit_matrix
    from ..effects.saturation import saturation_matrix

    p = ctx.profile
    s = np.concatenate([c.reshape(-1, 3) for c in ctx.clean(p)])
    m = np.concatenate([c.reshape(-1, 3) for c in ctx.means])
    ok = (s.max(1) < 250) & (m.max(1) < 250) & (s.min(1) > 3)
    t = fit_matrix(s[ok], m[ok])
    sat = p.effect("saturation")
    sat = saturation_matrix(sat.saturation) if sat is not None and sat.enabled else np.eye(3)
    old = p.effect(effect)
    old = old.total_matrix() if old.enabled else np.eye(3)
    new = np.linalg.solve(sat, t @ sat @ old)
    new = new / new.sum(axis=1, keepdims=True)
    rows = "; ".join(" ".join(f"{v:.3f}" for v in r) for r in new)
    return p.with_effect(effect, matrix=new.tolist(), extra_mixing=0.0), {"matrix": new.round(4).tolist()}, \
        {"rows": rows}


#: The closed-form fits a :class:`~lowcam.effects.Search` may name (``fit = ...``).
CLOSED_FORM = {"pixel_gain": fit_pixel_gain, "pixel_offset": fit_pixel_offset, "hot_pixels": fit_hot_pixels,
               "row_noise": fit_row_noise, "colour_matrix": fit_colour_matrix}
PER_PIXEL_FITS = ("pixel_gain", "pixel_offset")


def per_pixel(name: str) -> bool:
    """True for a candidate fitted as a dense per-pixel map (it absorbs noise: :attr:`Candidate.score`)."""
    return any(search.fit in PER_PIXEL_FITS for _, search in candidates()[name])


@dataclass
class Diagnosis:
    comparison: object
    candidates: list
    scratch: object = None  # the temporary folder of fitted maps; removed with the Diagnosis

    @property
    def error(self) -> float:
        return self.comparison.error

    @property
    def verdict(self) -> str:
        if self.error <= EXPLAINED_BELOW:
            return "explained"
        if self.candidates and self.candidates[0].score <= UNEXPLAINED_ABOVE:
            return "missing-effect"
        return "unexplained"

    def as_json(self) -> dict:
        return {"error": round(self.error, 4), "noise_floor": self.comparison.noise_floor,
                "verdict": self.verdict,
                "families": {k: round(v, 4) for k, v in self.comparison.families.items()},
                "candidates": [c.as_json() for c in self.candidates], "where": self.comparison.where}


def rank(ctx, base_error: float, names, progress=None) -> list[Candidate]:
    """Fit every named candidate on ``ctx.profile`` and rank them by score."""
    out = []
    for i, name in enumerate(names):
        if progress:
            progress(i, len(names), name)
        fitted = fit_candidate(ctx, name)
        if fitted is None:
            continue
        cand_profile, params, evidence = fitted
        after = ctx.compare(cand_profile).error
        out.append(Candidate(name, after, {k: (float(v) if isinstance(v, (np.floating, float)) else v)
                                           for k, v in params.items()},
                             f"{evidence}; error {base_error:.2f} -> {after:.2f}", cand_profile,
                             per_pixel(name), len(ctx.mset.captures)))
    out.sort(key=lambda c: c.score)
    return out


def diagnose(mset, profile, only=None, workdir=None, progress=None, rounds: int = 2) -> Diagnosis:
    """Rank the candidates (all of :func:`candidates`, or ``only``) for a measurement set.

    Forward selection: when the best candidate alone leaves the error above 1.1, the others are fitted again
    with it added (up to ``rounds`` rounds), so effects that hide together surface one after the other; each
    later candidate's ``error_after`` then includes the ones before it.
    """
    scratch = None if workdir else tempfile.TemporaryDirectory(prefix="lowcam-diagnose-")
    workdir = Path(workdir or scratch.name)
    ctx = Context(mset, profile, workdir)
    base = ctx.compare(profile)
    names = list(only or candidates())
    ranked = rank(ctx, base.error, names, progress)
    chosen: list[Candidate] = []
    for _ in range(rounds - 1):
        if not ranked or ranked[0].error_after <= EXPLAINED_BELOW:
            break
        best = ranked[0]
        chosen.append(best)
        ctx = Context(mset, best.profile, workdir / f"after-{best.effect}")
        remaining = [n for n in names if n not in {c.effect for c in chosen}]
        again = rank(ctx, best.error_after, remaining, progress)
        for c in again:
            c.evidence += f" (with {', '.join(x.effect for x in chosen)} added)"
        ranked = again
    return Diagnosis(base, chosen + ranked, scratch)


def save_candidate_profile(candidate: Candidate, path) -> Path:
    """Write the candidate's profile; fitted maps (.npy) are copied into a folder beside it."""
    import shutil

    path = Path(path).resolve()
    profile = candidate.profile
    effect = profile.effect(candidate_effect(candidate.effect))
    if effect is not None and getattr(effect, "texture", None) and Path(effect.texture).suffix == ".npy":
        target = path.parent / path.stem / Path(effect.texture).name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(effect.texture, target)
        profile = profile.with_effect(effect.name, texture=str(target), source=str(path), base_dir=path.parent)
    return profile.save(path)

