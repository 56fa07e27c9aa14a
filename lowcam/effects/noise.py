"""Sensor noise with an intensity-dependent standard deviation (Klein & Murray 2010, sec. 4.3, 5.2 step 5).

Gaussian noise per sensel, independent in space and time, in 8-bit DN, under one of two laws per channel:
``sigma = a + b mu`` (the paper's linear fit, sec. 4.3) or ``sigma^2 = a + b mu`` (photon transfer: read noise
plus shot noise, the form Irie et al. and EMVA 1288 predict). Under the Fire-i's 2x2-block demosaicing each
green pixel averages two sensels, so the measured green law is scaled by sqrt 2 (sigma) or 2 (variance) to give
the per-sensel one; red and blue are not scaled. Means above 220 DN are left out of the fits (saturation). A
sensor with a black level has a negative variance intercept (EMVA 1288: ``a = K^2 sigma_d^2 - K mu_dark``), so
``a`` may be negative; the variance is clamped at 0 where the law falls below it. A law is fitted only to a stack
that shows at least :data:`MIN_LEVELS` brightness levels.

Contents
--------
- :data:`SEED_RANGE`, :data:`FRAME_RANGE`: the seeds and frame numbers accepted
- :func:`frame_rng`: the random generator of one frame: reproducible from (seed, frame), independent between frames
- :class:`Noise`: Gaussian noise per sensel, its sigma a function of the mean (DN), scaled by alpha
- :data:`MIN_LEVELS`, :data:`LEVEL_STEP_DN`: the brightness levels (bands of DN) a noise stack must show
- :func:`brightness_levels`: how many distinct brightness levels per-pixel temporal means show
- :func:`fit_noise_law`: fit ``[a, b]`` of a noise law to per-pixel temporal means and deviations (sec. 4.3);
  ``a`` may be negative (a black level)
- :func:`fit_noise`: both noise laws per channel from a stack (N, H, W, 3) of frames of a static scene, in DN
- :func:`noise_level_statistic`: the noise level function (sigma against mean per channel, DN) of a stack of frames
- :data:`NLF_BIN_DN`, :data:`SPATIAL_QUANTILE`: the brightness bins (DN) of the noise level function measured on
  footage, and the quantile of flat-block variances that gives its spatial lower envelope
- :func:`noise_gain`: how the chain after the noise scales it per channel, as the noise level function sees it
- :func:`noise_level_function_from_plate`: the noise law from footage (a :class:`lowcam.measure.plate.PlateEstimate`)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008.
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (photon transfer).
- [Liu2008] C. Liu, R. Szeliski, S. B. Kang, C. L. Zitnick and W. T. Freeman, "Automatic Estimation and Removal of
  Noise from a Single Image", IEEE TPAMI 30(2), 299-314, 2008 (the noise level function, its lower envelope).
- [Foi2008] A. Foi, M. Trimeche, V. Katkovnik and K. Egiazarian, "Practical Poissonian-Gaussian Noise Modeling and
  Fitting for Single-Image Raw-Data", IEEE TIP 17(10), 1737-1754, 2008.
"""
from __future__ import annotations

import numpy as np

from ..errors import LowcamError
from .base import Effect, NodeStage, Param


#: Seeds are 0 <= seed < 2**64; frames -2**31 <= frame < 2**31 (Blender's frames are well inside).
SEED_RANGE = (0, 2 ** 64)
FRAME_RANGE = (-2 ** 31, 2 ** 31)


def frame_rng(seed: int, frame: int) -> np.random.Generator:
    """The random generator of one frame: reproducible from (seed, frame) alone, independent between frames.

    Every seed in :data:`SEED_RANGE` and frame in :data:`FRAME_RANGE` gives its own stream (none is reduced to
    fewer bits); seeds below 2**32 keep the streams they always had."""
    seed, frame = int(seed), int(frame)
    if not SEED_RANGE[0] <= seed < SEED_RANGE[1]:
        raise LowcamError(f"seed {seed}: must be an integer in [0, 2^64)")
    if not FRAME_RANGE[0] <= frame < FRAME_RANGE[1]:
        raise LowcamError(f"frame {frame}: must be an integer in [-2^31, 2^31)")
    words = [seed & 0xFFFFFFFF, frame & 0xFFFFFFFF, 0x10CA] + ([seed >> 32] if seed >> 32 else [])
    return np.random.default_rng(np.random.SeedSequence(words))


class Noise(Effect):
    """Gaussian noise per sensel, independent in space and time, its sigma a function of the mean (DN).

    ``law = "sigma_linear"``: ``sigma = a + b mu`` (the paper's fit, sec. 4.3);
    ``law = "variance_linear"``: ``sigma^2 = a + b mu`` (photon transfer: read noise plus shot noise).
    ``red``, ``green``, ``blue`` hold ``[a, b]`` per sensel, in 8-bit DN (green is the per-sensel value, i.e. the
    demosaiced green sigma times sqrt 2 under 2x2-block demosaicing). On partially covered sensels the noise is
    scaled by alpha, so transparent areas stay noise-free and the plate's own noise is not doubled.
    """

    name = "noise"
    section = "4.3, 5.2 step 5"
    writes = "bayer"
    order = 130
    calibration = "noise"
    node = NodeStage("Noise", "mosaic", "noise")
    random = True
    params = {
        "law": Param("sigma_linear", str, choices=("sigma_linear", "variance_linear")),
        "red": Param([1.5, 0.015], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
        "green": Param([1.2, 0.012], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
        "blue": Param([1.8, 0.016], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
    }

    def check(self):
        for key in ("red", "green", "blue"):
            a, b = getattr(self, key)
            if not (-255 <= a <= 255 and 0 <= b <= 255):
                raise self.error(f"'{key}' = {[a, b]}: the intercept a must lie in [-255, 255] (negative under a "
                                 f"black level) and the slope b in [0, 255]")

    def implausible(self) -> list[str]:
        """A channel whose law gives no noise at some level in 0-255 DN: every real sensor has read noise at every
        level it delivers (a negative intercept is a black level the delivered frames sit above, which a
        calibration may measure, but not a value to assume for footage)."""
        out = []
        for key in ("red", "green", "blue"):
            a, b = getattr(self, key)
            if a + 255.0 * b <= 0.0:
                out.append(f"{key} noise is 0 at every level")
            elif a < 0.0:
                out.append(f"{key} noise is 0 below {-a / b:.0f} DN")
        return out

    def sigma(self, channel: str, mean_dn):
        """Noise sigma (DN) of ``channel`` ("red", "green", "blue") at mean signal ``mean_dn``.

        A negative intercept (a black level: EMVA 1288's ``sigma_y^2 = K^2 sigma_d^2 + K (mu_y - mu_y.dark)``
        has ``a = K^2 sigma_d^2 - K mu_y.dark``) gives no noise where the law falls below 0: the variance (or
        sigma) is clamped at 0, the coefficients are kept."""
        a, b = getattr(self, channel)
        mu = np.clip(mean_dn, 0.0, 255.0)
        law = np.maximum(a + b * mu, 0.0)
        return law if self.law == "sigma_linear" else np.sqrt(law)

    def apply(self, state):
        rng = frame_rng(state.seed, state.frame)
        z = rng.standard_normal(state.bayer.shape, dtype=np.float32)
        alpha = state.bayer_alpha
        mean = state.bayer / np.maximum(alpha, 1e-6)
        for k, channel in enumerate(("red", "green", "green", "blue")):
            state.bayer[k] += z[k] * np.clip(alpha[k], 0.0, 1.0) * self.sigma(channel, mean[k]).astype(np.float32)


#: A noise law is fitted only to a stack showing this many distinct brightness levels (:func:`brightness_levels`):
#: with one level the intercept is an extrapolation across the whole range (443 % off on an EMVA 1288 sensor).
MIN_LEVELS = 3
#: The width (DN) of the brightness bands that :func:`brightness_levels` counts.
LEVEL_STEP_DN = 16.0


def brightness_levels(mean_dn: np.ndarray, sigma_dn: np.ndarray | None = None, frames: int | None = None,
                      saturation_dn: float = 220.0) -> tuple[int, float]:
    """How many distinct brightness levels the per-pixel temporal means show, and the band width (DN) counted.

    The usable means (2 DN to ``saturation_dn``, as :func:`fit_noise_law` uses them) are cut into bands
    :data:`LEVEL_STEP_DN` wide, or five times the noise left in the means (``median(sigma) / sqrt(frames)``)
    if wider, so that the scatter of one flat grey never spans more than two bands; a level is a band holding
    at least 1 % of those pixels. One flat grey thus counts 1 or 2, a ramp or a chart of greys many.
    """
    mu = np.asarray(mean_dn, np.float64).ravel()
    mu = mu[(mu > 2.0) & (mu < saturation_dn)]
    step = LEVEL_STEP_DN
    if sigma_dn is not None and frames:
        step = max(step, 5.0 * float(np.median(np.asarray(sigma_dn, np.float64))) / np.sqrt(frames))
    if mu.size == 0:
        return 0, step
    count = np.bincount(((mu - 2.0) // step).astype(np.int64))
    return int((count >= max(0.01 * mu.size, 1)).sum()), step


def fit_noise_law(mean_dn: np.ndarray, sigma_dn: np.ndarray, law: str, saturation_dn: float = 220.0,
                  bins: int = 40, frames: int | None = None) -> tuple[float, float]:
    """Fit ``[a, b]`` of a noise law to per-pixel temporal means and standard deviations (sec. 4.3).

    Means above ``saturation_dn`` are ignored (clipped pixels lose their noise), as are the darkest 2 DN. The
    pixels are binned by mean; each bin's variance is the average of its pixels' variances (robust to the many
    pixels of one brightness), less the 1/12 DN^2 that rounding to 8 bits adds (the simulator rounds its output
    too), and the law is fitted to the bins by weighted least squares. The intercept ``a`` may be negative: a
    sensor with a black level ``mu_dark`` (DN) has ``sigma^2 = K^2 sigma_d^2 + K (mu - mu_dark)`` [EMVA1288],
    an intercept ``K^2 sigma_d^2 - K mu_dark`` below 0 when the offset exceeds the read noise's share; the
    slope ``b`` is at least 0. Means of fewer than :data:`MIN_LEVELS` brightness levels are refused
    (:func:`brightness_levels`; ``frames``: how many frames the means average).
    """
    mu = np.asarray(mean_dn, np.float64).ravel()
    sd = np.asarray(sigma_dn, np.float64).ravel()
    var = sd ** 2
    keep = (mu < saturation_dn) & (mu > 2.0)
    mu, var = mu[keep], var[keep]
    if mu.size < 10:
        raise ValueError("too few unsaturated pixels to fit a noise law")
    levels, step = brightness_levels(mu, sd[keep], frames, saturation_dn)
    if levels < MIN_LEVELS:
        raise ValueError(f"the means show {levels} brightness level{'s' * (levels != 1)} ({mu.min():.0f}-"
                         f"{mu.max():.0f} DN); a noise law needs at least {MIN_LEVELS} levels {step:.0f} DN apart "
                         f"(a static scene with dark to bright areas)")
    edges = np.linspace(mu.min(), mu.max(), bins + 1)
    idx = np.clip(np.digitize(mu, edges) - 1, 0, bins - 1)
    count = np.bincount(idx, minlength=bins)
    ok = count >= 20
    if ok.sum() < 2:
        raise ValueError("the captures span too narrow a range of brightness to fit a noise law")
    bm = (np.bincount(idx, mu, bins) / np.maximum(count, 1))[ok]
    bv = np.maximum((np.bincount(idx, var, bins) / np.maximum(count, 1))[ok] - 1 / 12, 0.0)
    w = np.sqrt(count[ok])
    if law == "variance_linear":
        a, b = np.linalg.lstsq(np.column_stack([np.ones_like(bm), bm]) * w[:, None], bv * w, rcond=None)[0]
    else:
        a, b = np.linalg.lstsq(np.column_stack([np.ones_like(bm), bm]) * w[:, None], np.sqrt(bv) * w,
                               rcond=None)[0]
    return float(a), float(max(b, 0.0))


def fit_noise(stack, demosaic: str = "block", saturation_dn: float = 220.0) -> dict:
    """Both noise laws per channel from a stack (N, H, W, 3) of frames of a static scene, in DN.

    Under 2x2-block demosaicing each green pixel averages two sensels, so green's per-sensel law is the measured
    one scaled by sqrt 2 (sigma) or 2 (variance), as the paper corrects it (sec. 4.3); red and blue come from one
    sensel each. Returns ``{law: {channel: [a, b]}}`` plus the per-pixel ``mean`` and ``sigma`` (H, W, 3).
    """
    x = np.asarray(stack, np.float64)
    if x.ndim != 4 or x.shape[0] < 2:
        raise ValueError("the noise calibration needs a stack of at least 2 frames of a static scene")
    mean = x.mean(axis=0)
    sigma = x.std(axis=0, ddof=1)
    out = {"mean": mean, "sigma": sigma}
    for law in ("sigma_linear", "variance_linear"):
        out[law] = {}
        for c, channel in enumerate(("red", "green", "blue")):
            a, b = fit_noise_law(mean[..., c], sigma[..., c], law, saturation_dn, frames=x.shape[0])
            if channel == "green" and demosaic == "block":
                k = np.sqrt(2.0) if law == "sigma_linear" else 2.0
                a, b = a * k, b * k
            out[law][channel] = [a, b]
    return out


#: Brightness bins (DN) of the noise level function measured on footage.
NLF_BIN_DN = 12.0
#: The quantile of block variances that the spatial noise level function takes in each bin (its lower envelope).
SPATIAL_QUANTILE = 0.05


def _binned_nlf(mean: np.ndarray, var: np.ndarray, dof: int, quantile: float, saturation_dn: float = 220.0,
                min_count: int = 30, floor_dn: float = 4.0) -> tuple[list[float], list[float]]:
    """(levels, sigmas) of one channel: the pixels (or blocks) binned by mean in :data:`NLF_BIN_DN`-wide bins,
    each bin's variance the ``quantile`` of its members' variances (each with ``dof`` degrees of freedom) divided
    by that quantile of chi-square / dof, so textured or moving members above it do not lift it [Liu2008's lower
    envelope]. Means below ``floor_dn`` (noise clipped at 0) or above ``saturation_dn`` are left out."""
    from scipy.stats import chi2

    bias = chi2.ppf(quantile, dof) / dof
    keep = (mean > floor_dn) & (mean < saturation_dn) & np.isfinite(var)
    mean, var = mean[keep], var[keep]
    idx = (mean // NLF_BIN_DN).astype(np.int64)
    levels, sigmas = [], []
    for b in np.unique(idx):
        sel = idx == b
        if sel.sum() >= min_count:
            levels.append(float(mean[sel].mean()))
            sigmas.append(float(np.sqrt(max(np.quantile(var[sel], quantile) / bias, 0.0))))
    return levels, sigmas


def noise_level_statistic(frames, method: str | None = None, block: int = 8, floor_dn: float = 4.0,
                          saturation_dn: float = 220.0) -> dict:
    """The noise level function of a stack (T, H, W, 3) float32 DN: sigma (DN) against mean (DN) per channel.

    ``method = "temporal"`` (a still shot): each pixel's mean and variance over the frames; ``"spatial"`` (one
    frame at a time): the variance inside ``block`` x ``block`` blocks about their best-fitting plane, whose flattest
    members give the noise [Liu2008, Foi2008]. Each brightness bin's sigma is its members' median variance
    (temporal) or :data:`SPATIAL_QUANTILE` quantile (spatial), unbiased for the chi-square spread of that quantile
    (the spatial one stays biased by the noise's own spatial correlation, which
    :func:`noise_level_function_from_plate` calibrates on the model). ``None``: temporal for 3 frames or more. Means
    outside ``floor_dn``-``saturation_dn`` are left out (clipped noise). Returns ``{"method", "levels_dn": {channel:
    [...]}, "sigma_dn": {channel: [...]}, "sigma_at_dn": {"64"|"128"|"192": [r, g, b]}}`` (the last interpolated
    from the bins, for comparisons)."""
    x = np.asarray(frames, np.float32)
    if x.ndim == 3:
        x = x[None]
    method = method or ("temporal" if len(x) >= 3 else "spatial")
    out = {"method": method, "levels_dn": {}, "sigma_dn": {}}
    for c, channel in enumerate(("red", "green", "blue")):
        if method == "temporal":
            if len(x) < 2:
                raise ValueError("a temporal noise level function needs at least 2 frames")
            k = len(x) - 1
            mean = x[..., c].mean(axis=0).ravel()
            var = x[..., c].var(axis=0, ddof=1).ravel()
            levels, sigmas = _binned_nlf(mean, var, k, 0.5, saturation_dn, floor_dn=floor_dn)
        else:
            t, h, w = x.shape[:3]
            b = block
            blocks = x[:, : h // b * b, : w // b * b, c].reshape(t, h // b, b, w // b, b).transpose(0, 1, 3, 2, 4)
            blocks = blocks.reshape(-1, b * b).astype(np.float64)
            # each block less its best-fitting plane (shading, vignetting), leaving b^2 - 3 degrees of freedom
            yy, xx = np.mgrid[0:b, 0:b]
            design = np.column_stack([np.ones(b * b), xx.ravel() - (b - 1) / 2, yy.ravel() - (b - 1) / 2])
            resid = blocks - blocks @ np.linalg.pinv(design).T @ design.T
            k = b * b - 3
            levels, sigmas = _binned_nlf(blocks.mean(axis=1), (resid ** 2).sum(axis=1) / k, k, SPATIAL_QUANTILE,
                                         saturation_dn, min_count=10, floor_dn=floor_dn)
        out["levels_dn"][channel] = levels
        out["sigma_dn"][channel] = sigmas
    out["sigma_at_dn"] = {str(m): [float(np.interp(m, out["levels_dn"][ch], out["sigma_dn"][ch]))
                                   if out["levels_dn"][ch] else float("nan") for ch in ("red", "green", "blue")]
                          for m in (64, 128, 192)}
    return out


def _fit_bins(levels, sigmas, law: str) -> tuple[float, float]:
    """``[a, b]`` of ``law`` fitted to binned (mean, sigma) by least squares (variance or sigma, as the law),
    twice dropping the bins more than 25 % off the line (a bin whose flattest blocks still hold texture)."""
    m = np.asarray(levels, np.float64)
    y = np.asarray(sigmas, np.float64) ** (2 if law == "variance_linear" else 1)
    keep = np.ones(len(m), bool)
    for _ in range(3):
        a, b = np.linalg.lstsq(np.column_stack([np.ones(keep.sum()), m[keep]]), y[keep], rcond=None)[0]
        fit = np.maximum(a + b * m, 1e-6)
        new = np.abs(y - fit) <= 0.25 * fit * (2 if law == "variance_linear" else 1)
        if new.sum() < 2 or (new == keep).all():
            break
        keep = new
    return float(a), float(max(b, 0.0))


def noise_gain(profile, method: str, film, level: float = 0.5, sigma_dn: float = 8.0,
               frames: int = 4) -> list[float]:
    """How the chain after the noise scales it, per channel, as :func:`noise_level_statistic` measures it.

    The profile films a flat grey (``level`` of white) with a constant per-sensel sigma of ``sigma_dn`` and
    without; the statistic's sigma of the difference over ``sigma_dn`` is the gain: the horizontal blur and the
    sharpening (the norm of their kernels), the demosaic's averaging (green's two sensels), colour matrices
    after the noise, chroma subsampling, and (``"spatial"``) the bias of block variances under the noise's
    spatial correlation. Dividing a measured output sigma by it gives the per-sensel law the profile holds.
    ``film(profile, make_ideal, seed, frame)``: the profile's frame (float32 DN) of the ideal
    ``make_ideal(width, height)`` (:func:`lowcam.measure.plate.film`; effects do not run the pipeline)."""
    def ideal(width, height):
        out = np.ones((height, width, 4), np.float32)
        out[..., :3] = level
        return out
    law = {"law": "variance_linear", "red": [sigma_dn ** 2, 0.0], "green": [sigma_dn ** 2, 0.0],
           "blue": [sigma_dn ** 2, 0.0]}
    noisy = profile.with_effect("noise", **law)
    clean = film(profile.without("noise") if profile.effect("noise") else profile, ideal)
    h, w = clean.shape[:2]
    crop = (slice(h // 4, 3 * h // 4), slice(w // 4, 3 * w // 4))
    diffs = np.stack([film(noisy, ideal, seed=1, frame=k)[crop] - clean[crop] + 128.0
                      for k in range(frames if method == "temporal" else 1)])
    stat = noise_level_statistic(diffs, method)
    return [float(stat["sigma_at_dn"]["128"][c]) / sigma_dn for c in range(3)]


def noise_level_function_from_plate(footage, base, film):
    """The noise law per channel from footage, as a :class:`lowcam.measure.plate.PlateEstimate`.

    Where the camera holds still for 3 frames or more (:func:`lowcam.measure.plate.still_segments`) each pixel's
    temporal variance is used; otherwise the flattest blocks of single frames (Liu2008's lower envelope). The
    output-domain noise level function is divided by the base profile's :func:`noise_gain` (what its sharpening,
    blur and demosaic do to per-sensel noise) and fitted with the profile's law. Confidence: temporal 0.9 with
    8 frames or more, spatial 0.6 (texture can lift the envelope), both scaled down below 4 brightness levels.
    ``base``: the profile being refined; ``film``: as :func:`noise_gain` takes it."""
    from ..measure.plate import PlateEstimate, still_segments
    law = getattr(base.effect("noise"), "law", "sigma_linear")
    runs = still_segments(footage)
    if runs:
        start, stop = max(runs, key=lambda r: r[1] - r[0])
        stop = min(stop, start + 30)
        frames = footage.stack(range(start, stop))
        method, n = "temporal", stop - start
    else:
        frames = footage.stack(max_frames=6)
        method, n = "spatial", len(frames)
    stat = noise_level_statistic(frames, method)
    measured = {"method": method, "frames": n, "sigma_at_dn": stat["sigma_at_dn"], "levels_dn": stat["levels_dn"],
                "sigma_dn": stat["sigma_dn"]}
    levels = min(len(stat["levels_dn"][ch]) for ch in ("red", "green", "blue"))
    if levels < 2:
        return PlateEstimate("noise_level_function", "noise", measured, {}, 0.0,
                             f"{levels} brightness level(s) with enough pixels: no noise law can be fitted")
    gains = noise_gain(base, method, film)
    params = {"law": law}
    measured["gain"] = gains
    for c, channel in enumerate(("red", "green", "blue")):
        sig = np.asarray(stat["sigma_dn"][channel]) / gains[c]
        params[channel] = list(_fit_bins(stat["levels_dn"][channel], sig, law))
    confidence = (min(0.9, 0.5 + 0.05 * n) if method == "temporal" else 0.6) * min(1.0, levels / 4)
    where = (f"{n} still frames, temporal variance" if method == "temporal" else
             f"no still segment: flattest {8}x{8} blocks of {n} frames")
    return PlateEstimate("noise_level_function", "noise", measured, params, round(confidence, 3),
                         f"{where}, {levels} brightness levels")
