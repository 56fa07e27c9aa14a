"""Fixed-pattern sensor defects (PRNU, DSNU, hot pixels) and row noise (Klein & Murray 2010, sec. 4.3).

Irie et al., cited in the paper's sec. 4.3, found the Fire-i's noise dominated by shot noise, readout noise and
photo-response non-uniformity (PRNU); the paper found PRNU imperceptible on the Fire-i indoors. These effects are
candidates for other cameras. The fixed maps act on the demosaiced frame, per pixel and channel, from a ``.npy``
texture (H, W, 3) or drawn from ``pattern_seed``; row noise acts on the sensel planes, seeded per frame.

Contents
--------
- :class:`PRNU`: photo-response non-uniformity: each pixel's gain is ``1 + map`` (``strength``: the gain's sigma)
- :class:`DSNU`: dark-signal non-uniformity: a fixed offset per pixel (DN; ``strength``: its sigma)
- :class:`HotPixels`: a ``fraction`` of pixels with a large fixed offset (``strength`` DN, all channels)
- :class:`RowNoise`: temporal row noise: each sensor row gets a random offset per frame (sigma ``sigma_dn``)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008.
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (the definitions of DSNU and PRNU).
"""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Search


class _PixelMap(Effect):
    """A per-pixel, per-channel map over the output frame: from ``texture`` (a .npy array (H, W, 3)) or drawn
    from ``pattern_seed`` with ``strength``."""

    writes = "rgb"
    params = {
        "texture": Param("", "path", doc=".npy array (H, W, 3)"),
        "strength": Param(0.0, low=0.0, high=255.0),
        "pattern_seed": Param(1, int, low=0, high=2**31 - 1),
    }

    def check(self):
        self._map = None
        if not self.texture:
            return
        try:
            m = np.load(self.texture, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:
            raise self.error(f"texture {self.texture} is not a readable .npy array ({e})") from None
        if not isinstance(m, np.ndarray) or m.dtype.kind not in "fiu" or m.ndim != 3 or m.shape[2] != 3:
            raise self.error(f"texture {self.texture} must be a numeric (H, W, 3) array, got "
                             f"{getattr(m, 'dtype', type(m).__name__)} {getattr(m, 'shape', '')}")
        if not np.isfinite(m).all() or np.abs(m).max() > 255:
            raise self.error(f"texture {self.texture} holds NaN, Inf or values beyond +-255")
        self._map = m.astype(np.float32)

    def pattern(self, shape) -> np.ndarray:
        if self.texture:
            m = self._map
            if m.shape != shape:
                raise self.error(f"texture {self.texture} is {m.shape}, the frame needs {shape}")
            return m
        return self.draw(np.random.default_rng(self.pattern_seed), shape)

    def draw(self, rng, shape) -> np.ndarray:
        return (self.strength * rng.standard_normal(shape)).astype(np.float32)


class PRNU(_PixelMap):
    """Photo-response non-uniformity: each pixel's gain is ``1 + map`` (``strength``: the gain's sigma)."""

    name = "prnu"
    section = "4.3 (PRNU, after Irie et al.)"
    order = 210
    searches = (Search("prnu", "a fixed per-pixel gain pattern, sigma {sigma:.4f}, proportional to brightness",
                       fit="pixel_gain"),)
    params = dict(_PixelMap.params, strength=Param(0.0, low=0.0, high=1.0))

    def apply(self, state):
        state.rgb *= 1.0 + self.pattern(state.rgb.shape)


class DSNU(_PixelMap):
    """Dark-signal non-uniformity: each pixel adds a fixed offset (DN; ``strength``: its sigma), where the
    graphics cover it."""

    name = "dsnu"
    section = "4.3 (fixed-pattern offsets)"
    order = 220
    searches = (Search("dsnu",
                       "a fixed per-pixel offset pattern, sigma {sigma_dn:.2f} DN, the same at every brightness",
                       fit="pixel_offset"),)

    def apply(self, state):
        state.rgb += self.pattern(state.rgb.shape) * state.rgb_alpha


class HotPixels(_PixelMap):
    """A ``fraction`` of pixels with a large fixed offset (``strength`` DN, all channels)."""

    name = "hot_pixels"
    section = "4.3 (defective pixels)"
    order = 230
    searches = (Search("hot_pixels", "{count} pixels stay bright by {median_dn:.0f} DN or more in every capture",
                       fit="hot_pixels"),)
    params = dict(_PixelMap.params, strength=Param(0.0, low=0.0, high=255.0),
                  fraction=Param(0.0005, low=0.0, high=0.1))

    def draw(self, rng, shape):
        hot = rng.random(shape[:2]) < self.fraction
        return (self.strength * hot[..., None] * np.ones(shape, np.float32)).astype(np.float32)

    def apply(self, state):
        state.rgb += self.pattern(state.rgb.shape) * state.rgb_alpha


class RowNoise(Effect):
    """Temporal row noise: each sensor row gets a random offset per frame (sigma ``sigma_dn``, all sensels of the
    row), seeded per frame like the pixel noise."""

    name = "row_noise"
    section = "4.3 (read-out noise)"
    writes = "bayer"
    order = 140
    searches = (Search("row_noise", "row means of the noise vary {sigma_dn:.2f} DN more than pixel noise explains",
                       fit="row_noise"),)
    random = True
    params = {"sigma_dn": Param(0.0, low=0.0, high=50.0, unit="DN")}

    def apply(self, state):
        from ..geometry import BAYER_BORDER
        from .noise import frame_rng

        g = state.geometry
        rows = frame_rng(state.seed, state.frame ^ 0x5A5A).standard_normal(g.height + 4).astype(np.float32)
        by = BAYER_BORDER[0]
        hb = g.bayer_shape[0]
        for k, name in enumerate(("R", "Gr", "Gb", "B")):
            dy = g.cfa[name][0]
            r = np.clip(2 * (np.arange(hb) - by) + dy + 2, 0, g.height + 3)
            state.bayer[k] += self.sigma_dn * rows[r][:, None] * np.clip(state.bayer_alpha[k], 0, 1)
