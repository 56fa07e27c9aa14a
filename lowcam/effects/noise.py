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
- :func:`noise_level_function_from_plate`: the noise law from footage (a :class:`lowcam.measure.plate.PlateEstimate`)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008.
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (photon transfer).
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


def noise_level_statistic(frames) -> dict:
    """The noise level function of a stack (T, H, W, 3) float32 DN: binned mean levels and sigma per channel."""
    raise NotImplementedError


def noise_level_function_from_plate(footage, base=None):
    """The noise law per channel from footage, as a :class:`lowcam.measure.plate.PlateEstimate`."""
    raise NotImplementedError
