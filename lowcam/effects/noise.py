"""Sensor noise with an intensity-dependent standard deviation (Klein & Murray 2010, sec. 4.3, 5.2 step 5).

Gaussian noise per sensel, independent in space and time, in 8-bit DN, under one of two laws per channel:
``sigma = a + b mu`` (the paper's linear fit, sec. 4.3) or ``sigma^2 = a + b mu`` (photon transfer: read noise
plus shot noise, the form Irie et al. and EMVA 1288 predict). Under the Fire-i's 2x2-block demosaicing each
green pixel averages two sensels, so the measured green law is scaled by sqrt 2 (sigma) or 2 (variance) to give
the per-sensel one; red and blue are not scaled. Means above 220 DN are left out of the fits (saturation).

Contents
--------
- :data:`SEED_RANGE`, :data:`FRAME_RANGE`: the seeds and frame numbers accepted
- :func:`frame_rng`: the random generator of one frame: reproducible from (seed, frame), independent between frames
- :class:`Noise`: Gaussian noise per sensel, its sigma a function of the mean (DN), scaled by alpha
- :func:`fit_noise_law`: fit ``[a, b]`` of a noise law to per-pixel temporal means and deviations (sec. 4.3)
- :func:`fit_noise`: both noise laws per channel from a stack (N, H, W, 3) of frames of a static scene, in DN

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
        "red": Param([1.5, 0.015], "vector", length=2, low=0.0, high=255.0),
        "green": Param([1.2, 0.012], "vector", length=2, low=0.0, high=255.0),
        "blue": Param([1.8, 0.016], "vector", length=2, low=0.0, high=255.0),
    }

    def check(self):
        for key in ("red", "green", "blue"):
            a, b = getattr(self, key)
            if a < 0 or b < 0 or a > 255 or b > 255:
                raise self.error(f"'{key}' = {[a, b]}: both coefficients must lie in [0, 255]")

    def sigma(self, channel: str, mean_dn):
        """Noise sigma (DN) of ``channel`` ("red", "green", "blue") at mean signal ``mean_dn``."""
        a, b = getattr(self, channel)
        mu = np.clip(mean_dn, 0.0, 255.0)
        return a + b * mu if self.law == "sigma_linear" else np.sqrt(a + b * mu)

    def apply(self, state):
        rng = frame_rng(state.seed, state.frame)
        z = rng.standard_normal(state.bayer.shape, dtype=np.float32)
        alpha = state.bayer_alpha
        mean = state.bayer / np.maximum(alpha, 1e-6)
        for k, channel in enumerate(("red", "green", "green", "blue")):
            state.bayer[k] += z[k] * np.clip(alpha[k], 0.0, 1.0) * self.sigma(channel, mean[k]).astype(np.float32)


def fit_noise_law(mean_dn: np.ndarray, sigma_dn: np.ndarray, law: str, saturation_dn: float = 220.0,
                  bins: int = 40) -> tuple[float, float]:
    """Fit ``[a, b]`` of a noise law to per-pixel temporal means and standard deviations (sec. 4.3).

    Means above ``saturation_dn`` are ignored (clipped pixels lose their noise), as are the darkest 2 DN. The
    pixels are binned by mean; each bin's variance is the average of its pixels' variances (robust to the many
    pixels of one brightness), less the 1/12 DN^2 that rounding to 8 bits adds (the simulator rounds its output
    too), and the law is fitted to the bins by weighted least squares.
    """
    mu = np.asarray(mean_dn, np.float64).ravel()
    var = np.asarray(sigma_dn, np.float64).ravel() ** 2
    keep = (mu < saturation_dn) & (mu > 2.0)
    mu, var = mu[keep], var[keep]
    if mu.size < 10:
        raise ValueError("too few unsaturated pixels to fit a noise law")
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
    return float(max(a, 0.0)), float(max(b, 0.0))


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
            a, b = fit_noise_law(mean[..., c], sigma[..., c], law, saturation_dn)
            if channel == "green" and demosaic == "block":
                k = np.sqrt(2.0) if law == "sigma_linear" else 2.0
                a, b = a * k, b * k
            out[law][channel] = [a, b]
    return out
