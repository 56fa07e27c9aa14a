"""Sensor noise with an intensity-dependent standard deviation (Klein & Murray 2010, sec. 4.3, 5.2 step 5)."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param


def frame_rng(seed: int, frame: int) -> np.random.Generator:
    """The random generator of one frame: reproducible from (seed, frame) alone, independent between frames."""
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(frame) & 0xFFFFFFFF, 0x10CA]))


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
    params = {
        "law": Param("sigma_linear", str, choices=("sigma_linear", "variance_linear")),
        "red": Param([1.5, 0.015], "vector", length=2),
        "green": Param([1.2, 0.012], "vector", length=2),
        "blue": Param([1.8, 0.016], "vector", length=2),
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
