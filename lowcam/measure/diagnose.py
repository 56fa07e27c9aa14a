"""Which physical effect does the profile lack? Fit each candidate, re-simulate, rank by how far the error falls.

Every candidate is an effect the profile lacks, or one whose parameters may be wrong. Each is fitted to the
measured frames (most by a bounded search on a noise-free simulation against the measured temporal means; the
fixed-pattern maps in closed form; noise-shaped candidates against the full error), then the full noise-aware
error (:mod:`lowcam.measure.compare`) is computed with it. Candidates are ranked by that error, best first,
after correcting per-pixel maps for what they absorb of the noise (:attr:`Candidate.score`).

Verdict: ``explained`` when the profile's own error is below 1.1; ``missing-effect`` when the best candidate's
score is at most 1.25; ``unexplained`` otherwise (``where`` then still says where the residual lives).
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .compare import EXPLAINED_BELOW, capture_inputs, compare, simulate_capture

UNEXPLAINED_ABOVE = 1.25


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


def _fit_one(ctx, effect: str, key: str, bounds, subset=None, evals: int = 20):
    """Fit one parameter of one effect: (profile with it, {key: value}, value)."""
    p = ctx.profile
    x = float(_search(ctx, lambda v: p.with_effect(effect, **{key: v[0]}), [bounds], None, evals, subset)[0])
    return p.with_effect(effect, **{key: x}), {key: x}, x


def _grid(ctx, build, values, full: bool = False):
    scores = [(ctx.compare(build(v)).error if full else ctx.sse(build(v))) for v in values]
    return values[int(np.argmin(scores))]


# --- the candidates ------------------------------------------------------------------------------------------------
# Each returns (profile with the candidate, fitted params, evidence) or None when the set cannot show it.

def c_vignetting(ctx):
    p = ctx.profile
    x = _search(ctx, lambda x: p.with_effect("vignetting", replace=True, k2=x[0], k4=x[1]),
                [(-1.0, 0.5), (-1.0, 1.0)], [-0.2, 0.0])
    corner = 1 + x[0] + x[1]
    return p.with_effect("vignetting", replace=True, k2=x[0], k4=x[1]), {"k2": x[0], "k4": x[1]}, \
        f"brightness falls to {corner / max(1.0, 1 + min(0, x[0])):.2f} of the centre's at the corners"


def c_chromatic_aberration(ctx):
    p = ctx.profile

    def build(x):
        return p.with_effect("chromatic_aberration", replace=True, red_corner_px=x[0], blue_corner_px=x[1],
                             cubic=x[2])
    x = _search(ctx, build, [(-5, 5), (-5, 5), (0, 5)], [0.5, 0.3, 1.0], evals=45, subset=ctx.textured)
    return build(x), {"red_corner_px": x[0], "blue_corner_px": x[1], "cubic": x[2]}, \
        f"red and blue sample {x[0]:+.2f} and {x[1]:+.2f} px outward of green at the corners"


def c_radial_distortion(ctx):
    lens = ctx.profile.effect("lens_distortion")
    key, bounds = ("w", (0.0, 1.6)) if lens.model == "fov" else ("k1", (-1.0, 1.0))
    p, params, x = _fit_one(ctx, "lens_distortion", key, bounds, ctx.textured)
    return p, params, f"lens {key} = {x:.4f} (was {getattr(lens, key):.4f})"


def c_motion_blur(ctx):
    if not ctx.moving:
        return None
    p, params, x = _fit_one(ctx, "motion_blur", "exposure_s", (0.0005, 0.1), ctx.moving_ones)
    return p, params, f"moving captures are smeared as by a {1e3 * x:.1f} ms exposure"


def c_rolling_shutter(ctx):
    if not ctx.moving:
        return None
    p, params, x = _fit_one(ctx, "rolling_shutter", "readout_s", (0.0, 0.1), ctx.moving_ones)
    return p, params, f"moving captures skew as with a {1e3 * x:.1f} ms row read-out"


def c_gamma(ctx):
    p, params, x = _fit_one(ctx, "tone_curve", "gamma", (0.3, 4.0))
    return p, params, f"mid-tones follow a gamma of {x:.2f}"


def _pixel_maps(ctx):
    """Per-pixel least-squares gain and offset of the measured means against the clean model."""
    s = np.stack(ctx.clean(ctx.profile))
    m = np.stack(ctx.means)
    return s, m


def _with_map(ctx, effect: str, values: np.ndarray, **params):
    """The profile with ``effect`` reading the per-pixel map ``values`` (saved as .npy), and its params."""
    path = ctx.workdir / f"{effect}.npy"
    np.save(path, values.astype(np.float32))
    return ctx.profile.with_effect(effect, replace=True, texture=str(path)), {"texture": str(path), **params}


def c_prnu(ctx):
    s, m = _pixel_maps(ctx)
    gain = ((m - s) * s).sum(0) / np.maximum((s * s).sum(0), 1e-6)
    return (*_with_map(ctx, "prnu", gain, sigma=float(gain.std())),
            f"a fixed per-pixel gain pattern, sigma {100 * gain.std():.2f} %, proportional to brightness")


def c_dsnu(ctx):
    s, m = _pixel_maps(ctx)
    offset = (m - s).mean(0)
    return (*_with_map(ctx, "dsnu", offset, sigma_dn=float(offset.std())),
            f"a fixed per-pixel offset pattern, sigma {offset.std():.2f} DN, the same at every brightness")


def c_hot_pixels(ctx):
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
    return (*_with_map(ctx, "hot_pixels", np.where(hot, offset, 0.0), count=n),
            f"{n} pixels stay bright by {np.median(offset[hot]):.0f} DN or more in every capture")


def c_row_noise(ctx):
    base = ctx.compare(ctx.profile)
    extra = []
    for st in base.captures:
        def rowvar(x):
            x = x.astype(np.float64)
            return (x - x.mean(0, keepdims=True)).mean(axis=2).var(axis=(0, 1))
        extra.append(rowvar(st.measured) - rowvar(st.simulated))
    excess = float(np.mean(extra))
    if excess <= 0:
        return None
    sigmas = [np.sqrt(excess) * f for f in (0.8, 1.0, 1.25)]
    best = _grid(ctx, lambda v: ctx.profile.with_effect("row_noise", sigma_dn=v), sigmas, full=True)
    return ctx.profile.with_effect("row_noise", sigma_dn=best), {"sigma_dn": best}, \
        f"row means of the noise vary {np.sqrt(excess):.2f} DN more than pixel noise explains"


def c_vertical_blur(ctx):
    p, params, x = _fit_one(ctx, "vertical_blur", "sigma", (0.0, 3.0), ctx.textured)
    return p, params, f"edges are soft vertically as by a {x:.2f}-sensel Gaussian"


def c_horizontal_blur(ctx):
    if ctx.profile.effect("horizontal_blur") is None:
        return None
    p, params, x = _fit_one(ctx, "horizontal_blur", "sigma", (0.0, 4.0), ctx.textured)
    return p, params, f"horizontal blur sigma {x:.3f} sensels (profile: {ctx.profile.effect('horizontal_blur').sigma:.3f})"


def c_defocus(ctx):
    p, params, x = _fit_one(ctx, "defocus", "radius_px", (0.0, 8.0), ctx.textured)
    return p, params, f"everything is blurred as by a {x:.2f} px defocus disc"


def c_asymmetric_sharpening(ctx):
    if ctx.profile.effect("sharpening") is None:
        return None
    p, params, x = _fit_one(ctx, "sharpening", "shift", (-2.0, 2.0), ctx.textured)
    return p, params, f"sharpening halos are lopsided: its low-pass sits {x:+.2f} sensels off centre"


def c_jpeg(ctx):
    p = ctx.profile
    q = _grid(ctx, lambda v: p.with_effect("jpeg", quality=v), [30, 50, 70, 80, 90, 95])
    q = _grid(ctx, lambda v: p.with_effect("jpeg", quality=v), sorted({max(1, min(100, q + d))
                                                                        for d in (-8, -4, 0, 4, 8)}))
    return p.with_effect("jpeg", quality=q), {"quality": q}, f"8x8 block artefacts as from JPEG quality {q}"


def c_veiling_glare(ctx):
    p = ctx.profile

    def build(x):
        return p.with_effect("veiling_glare", strength=x[0], radius_px=x[1])
    x = _search(ctx, build, [(0.0, 0.5), (5.0, 300.0)], [0.05, 40.0], 30, ctx.textured)
    return build(x), {"strength": x[0], "radius_px": x[1]}, \
        f"a haze of {100 * x[0]:.1f} % of the light, spread over {x[1]:.0f} px"


def c_bilinear_demosaic(ctx):
    p = ctx.profile
    if p.effect("demosaic").method == "bilinear":
        return None
    return p.with_effect("demosaic", method="bilinear"), {"method": "bilinear"}, \
        "fine detail and noise correlations follow bilinear demosaicing"


def c_colour_matrix(ctx):
    from ..effects.crosstalk import fit_colour_matrix, saturation_matrix

    p = ctx.profile
    s = np.concatenate([c.reshape(-1, 3) for c in ctx.clean(p)])
    m = np.concatenate([c.reshape(-1, 3) for c in ctx.means])
    ok = (s.max(1) < 250) & (m.max(1) < 250) & (s.min(1) > 3)
    t = fit_colour_matrix(s[ok], m[ok])
    sat = saturation_matrix(p.effect("saturation").saturation) if p.effect("saturation") is not None and \
        p.effect("saturation").enabled else np.eye(3)
    old = p.effect("crosstalk").total_matrix() if p.effect("crosstalk") is not None and \
        p.effect("crosstalk").enabled else np.eye(3)
    new = np.linalg.solve(sat, t @ sat @ old)
    new = new / new.sum(axis=1, keepdims=True)
    return p.with_effect("crosstalk", matrix=new.tolist(), extra_mixing=0.0), {"matrix": new.round(4).tolist()}, \
        "colours are mixed differently: crosstalk rows " + "; ".join(" ".join(f"{v:.3f}" for v in r) for r in new)


def c_quantisation_bits(ctx):
    p = ctx.profile
    bits = _grid(ctx, lambda v: p.with_effect("quantisation", bits=v), [4, 5, 6, 7, 8], full=True)
    return p.with_effect("quantisation", bits=bits), {"bits": bits}, f"levels are {256 // 2 ** bits} DN apart " \
                                                                      f"({bits} bits)"


def c_chroma_subsampling(ctx):
    p = ctx.profile
    if p.effect("yuv_blend") is None:
        return None
    group = _grid(ctx, lambda v: p.with_effect("chroma_subsampling", group=v), [2, 4, 8])
    return p.with_effect("chroma_subsampling", group=group), {"group": group}, \
        f"colour is shared by groups of {group} pixels horizontally"


CANDIDATES = {
    "vignetting": c_vignetting, "chromatic_aberration": c_chromatic_aberration,
    "radial_distortion": c_radial_distortion, "motion_blur": c_motion_blur, "gamma": c_gamma,
    "rolling_shutter": c_rolling_shutter, "prnu": c_prnu, "dsnu": c_dsnu, "row_noise": c_row_noise,
    "hot_pixels": c_hot_pixels, "vertical_blur": c_vertical_blur, "horizontal_blur": c_horizontal_blur,
    "defocus": c_defocus, "asymmetric_sharpening": c_asymmetric_sharpening, "jpeg": c_jpeg,
    "veiling_glare": c_veiling_glare, "bilinear_demosaic": c_bilinear_demosaic, "colour_matrix": c_colour_matrix,
    "quantisation_bits": c_quantisation_bits, "chroma_subsampling": c_chroma_subsampling,
}


@dataclass
class Diagnosis:
    comparison: object
    candidates: list

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
        return {"error": round(self.error, 4), "noise_floor": 1.0, "verdict": self.verdict,
                "families": {k: round(v, 4) for k, v in self.comparison.families.items()},
                "candidates": [c.as_json() for c in self.candidates], "where": self.comparison.where}


def rank(ctx, base_error: float, names, progress=None) -> list[Candidate]:
    """Fit every named candidate on ``ctx.profile`` and rank them by score."""
    out = []
    for i, name in enumerate(names):
        if progress:
            progress(i, len(names), name)
        fitted = CANDIDATES[name](ctx)
        if fitted is None:
            continue
        cand_profile, params, evidence = fitted
        after = ctx.compare(cand_profile).error
        out.append(Candidate(name, after, {k: (float(v) if isinstance(v, (np.floating, float)) else v)
                                           for k, v in params.items()},
                             f"{evidence}; error {base_error:.2f} -> {after:.2f}", cand_profile,
                             name in ("prnu", "dsnu"), len(ctx.mset.captures)))
    out.sort(key=lambda c: c.score)
    return out


def diagnose(mset, profile, only=None, workdir=None, progress=None, rounds: int = 2) -> Diagnosis:
    """Rank the candidates (all of :data:`CANDIDATES`, or ``only``) for a measurement set.

    Forward selection: when the best candidate alone leaves the error above 1.1, the others are fitted again
    with it added (up to ``rounds`` rounds), so effects that hide together surface one after the other; each
    later candidate's ``error_after`` then includes the ones before it.
    """
    workdir = Path(workdir or tempfile.mkdtemp(prefix="lowcam-diagnose-"))
    ctx = Context(mset, profile, workdir)
    base = ctx.compare(profile)
    names = list(only or CANDIDATES)
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
    return Diagnosis(base, chosen + ranked)


def save_candidate_profile(candidate: Candidate, path) -> Path:
    """Write the candidate's profile; fitted maps (.npy) are copied into a folder beside it."""
    import shutil

    path = Path(path).resolve()
    profile = candidate.profile
    effect = profile.effect(CANDIDATE_EFFECT.get(candidate.effect, candidate.effect))
    if effect is not None and getattr(effect, "texture", None) and Path(effect.texture).suffix == ".npy":
        target = path.parent / path.stem / Path(effect.texture).name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(effect.texture, target)
        profile = profile.with_effect(effect.name, texture=str(target), source=str(path), base_dir=path.parent)
    return profile.save(path)


#: The profile effect each candidate adds or changes.
CANDIDATE_EFFECT = {"radial_distortion": "lens_distortion", "gamma": "tone_curve",
                    "asymmetric_sharpening": "sharpening", "bilinear_demosaic": "demosaic",
                    "colour_matrix": "crosstalk", "quantisation_bits": "quantisation"}
