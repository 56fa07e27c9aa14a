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
- :data:`OUTLIER_SIGMAS`, :data:`SPARSE_PIXELS`, :data:`SPARSE_ENERGY`: when an offset map is sparse (hot pixels)
- :func:`offset_evidence`: where a fixed offset's energy sits: a few outliers (hot pixels) or a dense map (DSNU)
- :func:`fit_dense_offset`: DSNU's diagnosis fit: the mean offset map, refused when its energy is in a few pixels
- :func:`fit_hot_pixels`: hot pixels' diagnosis fit: the outliers of the offset map, refused when the map is dense
- :func:`wiener_shrink`: a per-pixel map shrunk by its Wiener factor (signal variance over signal plus noise)
- :func:`mean_noise_var`: per capture and pixel, the noise variance left in the frames' mean (DN^2)
- :func:`row_noise_variance`: per channel, the variance of the per-frame row means of the noise of a stack
- :func:`fit_pixel_gain`: PRNU's diagnosis fit: the per-pixel gain of the measured means against the clean model
- :func:`fit_row_noise`: row noise's diagnosis fit: the excess variance of row means over the model's
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

import os
import tempfile

import cv2
import numpy as np

from ..errors import NotFitted
from ..geometry import BAYER_BORDER
from .base import Effect, Param, Search
from .noise import frame_rng


# --- diagnosis: hot pixels (a few outliers) against DSNU (a dense map), told apart by where the offset sits -------

#: Offsets further than this many robust sigmas (1.4826 MAD) from the map's median are outliers.
OUTLIER_SIGMAS = 6.0
#: The offset is "sparse" (hot pixels, not DSNU) when outliers are at most this share of the pixels...
SPARSE_PIXELS = 0.01
#: ... and hold at least this share of its fixed energy (:func:`offset_evidence`).
SPARSE_ENERGY = 0.5


def offset_evidence(offsets: np.ndarray, noise_var: float = 0.0) -> dict:
    """Where the energy of a fixed per-pixel offset sits, from its maps in C captures (C, H, W, 3), DN.

    Outliers are values of the mean map further than :data:`OUTLIER_SIGMAS` robust sigmas (1.4826 MAD) from
    its median. The *fixed* energy of each value is what repeats from capture to capture: the mean product of
    its deviations in two different captures, so the temporal noise and the model's mismatch in each scene
    (which differ between captures) add nothing; with one capture, the squared deviation less ``noise_var``.
    Returns the median, robust sigma, outlier mask, the outliers' share of the pixels (any channel) and of the
    fixed energy, and whether that makes the offset sparse (hot pixels: :data:`SPARSE_PIXELS`,
    :data:`SPARSE_ENERGY`) rather than dense (DSNU) [EMVA1288, sec. 8]."""
    offsets = np.asarray(offsets, np.float64)
    mean = offsets.mean(0)
    med = float(np.median(mean))
    dev = offsets - np.median(offsets, axis=(1, 2, 3), keepdims=True)
    spread = max(1.4826 * float(np.median(np.abs(mean - med))), 1e-3)
    out = np.abs(mean - med) > OUTLIER_SIGMAS * spread
    c = len(offsets)
    if c > 1:
        total = dev.sum(0)
        fixed = (total ** 2 - (dev ** 2).sum(0)) / (c * (c - 1))
    else:
        fixed = dev[0] ** 2 - noise_var
    energy = float(np.maximum(fixed, 0.0).sum())
    share = min(max(float(fixed[out].sum()), 0.0) / energy, 1.0) if energy > 0 else 0.0
    pixels = float(out.any(axis=-1).mean())
    return {"median": med, "spread": spread, "outliers": out, "pixels": pixels, "share": share,
            "sparse": bool(out.any()) and pixels <= SPARSE_PIXELS and share >= SPARSE_ENERGY}


def wiener_shrink(estimate: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
    """A fixed per-pixel map estimated with noise, shrunk towards its mean pixel by pixel:
    ``mean + P / (P + N) (estimate - mean)``, ``N`` each value's noise variance (``noise_var``, same shape) and
    ``P = var(estimate) - mean(N)`` the pattern's variance (the Wiener filter; an empirical Bayes estimate,
    James and Stein 1961). A value measured with more noise than the pattern has is trusted less, so the map's
    expected error on other captures is least. NaN values stay NaN.

    >>> rng = np.random.default_rng(0); pattern = rng.normal(0, 1, 10000)
    >>> noisy = pattern + rng.normal(0, 1, 10000)
    >>> shrunk = wiener_shrink(noisy, np.ones(10000))
    >>> round(float(np.mean((noisy - pattern) ** 2)), 1), round(float(np.mean((shrunk - pattern) ** 2)), 1)
    (1.0, 0.5)
    """
    ok = np.isfinite(estimate) & np.isfinite(noise_var)
    if ok.sum() < 2:
        return estimate
    mean = float(estimate[ok].mean())
    pattern_var = max(float(estimate[ok].var()) - float(noise_var[ok].mean()), 0.0)
    return mean + pattern_var / np.maximum(pattern_var + noise_var, 1e-30) * (estimate - mean)


def mean_noise_var(ctx) -> np.ndarray:
    """Per capture and pixel, the variance the frames' noise leaves in their mean, (C, H, W, 3): the frames'
    unbiased variance over their count (every capture of a per-pixel fit has two frames or more)."""
    return np.stack([c.frames.astype(np.float32).var(axis=0, ddof=1) / len(c.frames) for c in ctx.mset.captures])


def _offsets(ctx):
    """Per-pixel offsets of the measured means from the clean model, one per capture (C, H, W, 3), DN, as
    measured and with NaN where the measurement clips (a bright pixel over a bright area shows its offset only
    where there is headroom); and the variance the temporal noise leaves in one capture's mean (0 where a
    capture has one frame)."""
    s, m = np.stack(ctx.clean(ctx.profile)), np.stack(ctx.means)
    var = [float(c.frames.astype(np.float32).var(axis=0, ddof=1).mean()) / len(c.frames)
           for c in ctx.mset.captures if len(c.frames) > 1]
    noise_var = sum(var) / len(var) if len(var) == len(ctx.mset.captures) else 0.0
    return np.where(m < 250, m - s, np.nan), m - s, noise_var


def _with_map(ctx, effect: str, values: np.ndarray):
    """The profile with ``effect`` reading the per-pixel map ``values`` (saved as .npy in the workdir, a file of
    its own per fit: a candidate is fitted on several folds at once)."""
    handle, path = tempfile.mkstemp(prefix=f"{effect}-", suffix=".npy", dir=ctx.workdir)
    os.close(handle)
    np.save(path, values.astype(np.float32))
    return ctx.profile.with_effect(effect, replace=True, texture=str(path)), {"texture": str(path)}


def fit_dense_offset(ctx, effect: str):
    """DSNU's fit: the per-pixel mean offset of the measured means from the clean model (closed form), shrunk
    towards its mean by :func:`wiener_shrink`; NotFitted when its energy sits in a few outliers
    (:func:`offset_evidence`: hot pixels, not a dense map)."""
    _, diff, noise_var = _offsets(ctx)
    offset = diff.mean(0)
    ev = offset_evidence(diff, noise_var)
    if ev["sparse"]:
        raise NotFitted(f"the offsets sit in {100 * ev['pixels']:.2f} % of the pixels: hot pixels, not a dense map")
    offset = wiener_shrink(offset, mean_noise_var(ctx).sum(0) / len(diff) ** 2)
    profile, params = _with_map(ctx, effect, offset)
    shown = {"sigma_dn": float(offset.std()), "tail_percent": 100 * ev["pixels"], "share": 100 * ev["share"]}
    return profile, dict(params, sigma_dn=shown["sigma_dn"]), shown


def fit_hot_pixels(ctx, effect: str):
    """Hot pixels' fit: the pixels far brighter than the model (outliers of the offset map, :func:`offset_evidence`)
    in every capture that can show them; their mean offset per channel. NotFitted when there are none, or when
    the map is dense (the outliers are many, or hold little of the offset energy: DSNU)."""
    clipped, diff, noise_var = _offsets(ctx)
    # pixels clipped in every capture (NaN in each) read 0; computed without NumPy's all-NaN warnings, whose filter
    # (``warnings.catch_warnings``) is not thread-safe and fits run in threads
    shown = (~np.isnan(clipped)).sum(axis=0)
    offset = np.where(shown > 0, np.nansum(clipped, axis=0) / np.maximum(shown, 1), 0.0).astype(clipped.dtype)
    low = np.nan_to_num(np.fmin.reduce(clipped, axis=0))  # bright in every capture that can show it
    ev = offset_evidence(diff, noise_var)
    cut = OUTLIER_SIGMAS * ev["spread"]
    hot = (offset - ev["median"] > cut) & (low - ev["median"] > 0.5 * cut)
    if not hot.any():
        raise NotFitted("no pixel stays bright in every capture")
    if not ev["sparse"]:
        raise NotFitted("the fixed offsets are spread over the frame: a dense map, not hot pixels")
    n = int(hot.any(axis=-1).sum())
    profile, params = _with_map(ctx, effect, np.where(hot, offset, 0.0))
    shown = {"count": n, "percent": 100 * n / hot[..., 0].size, "median_dn": float(np.median(offset[hot])),
             "share": 100 * ev["share"]}
    return profile, dict(params, count=n), shown


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


def row_noise_variance(frames: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Per channel: the variance of the per-frame row means of the noise of a (frames, H, W, 3) stack, over rows
    and frames (row noise shows here; pixel noise averages out over a row). With ``mask`` (H, W) bool, each row's
    mean is over the pixels it keeps, and rows it keeps none of are left out."""
    # the row means of the noise are those of the frames less their temporal mean; cv2.reduce sums rows exactly
    if mask is None:
        sums = np.stack([cv2.reduce(np.ascontiguousarray(f), 1, cv2.REDUCE_SUM, dtype=cv2.CV_64F)[:, 0]
                         for f in frames])
        rows = sums / frames.shape[2]
    else:
        kept = mask.sum(axis=1)
        rows = np.stack([np.einsum("hwc,hw->hc", f.astype(np.float64), mask) for f in frames])[:, kept > 0]
        rows /= kept[kept > 0][None, :, None]
    if rows.shape[1] == 0:
        return np.zeros(frames.shape[-1])
    return (rows - rows.mean(axis=0)).var(axis=(0, 1))


def _pixel_maps(ctx):
    """The clean model and the measured means of every capture, stacked."""
    return np.stack(ctx.clean(ctx.profile)).astype(np.float64), np.stack(ctx.means).astype(np.float64)


def fit_pixel_gain(ctx, effect: str):
    """PRNU: per-pixel least-squares gain of the measured means against the clean model, ``g = sum((m - s) s) /
    sum(s^2)`` over the captures, shrunk towards its mean by :func:`~lowcam.effects.fixed_pattern.wiener_shrink`
    with each gain's noise variance ``sum(s^2 v) / sum(s^2)^2`` (``v``: the means' noise variance)."""
    s, m = _pixel_maps(ctx)
    weight = np.maximum((s * s).sum(0), 1e-6)
    gain = wiener_shrink(((m - s) * s).sum(0) / weight, (s * s * mean_noise_var(ctx)).sum(0) / weight ** 2)
    profile, params = _with_map(ctx, effect, gain)
    return profile, dict(params, sigma=float(gain.std())), {"sigma": float(gain.std())}


def fit_row_noise(ctx, effect: str):
    """Row noise from the excess variance of row means over the model's (:func:`row_noise_variance`)."""
    excess = float(np.mean([row_noise_variance(st.measured) - row_noise_variance(st.simulated)
                            for st in ctx.base.captures if len(st.measured) > 1] or [0.0]))
    if excess <= 0:
        raise NotFitted("row means of the noise vary no more than pixel noise explains")
    sigma = float(np.sqrt(excess))
    return ctx.profile.with_effect(effect, sigma_dn=sigma), {"sigma_dn": sigma}, {"sigma_dn": sigma}


class PRNU(_PixelMap):
    """Photo-response non-uniformity: each pixel's gain is ``1 + map`` (``strength``: the gain's sigma)."""

    name = "prnu"
    section = "4.3 (PRNU, after Irie et al.)"
    order = 210
    searches = (Search("prnu", "a fixed per-pixel gain pattern, sigma {sigma:.4f}, proportional to brightness",
                       fit=fit_pixel_gain, per_pixel=True),)
    params = dict(_PixelMap.params, strength=Param(0.0, low=0.0, high=1.0))

    def apply(self, state):
        state.rgb *= 1.0 + self.pattern(state.rgb.shape)


class DSNU(_PixelMap):
    """Dark-signal non-uniformity: each pixel adds a fixed offset (DN; ``strength``: its sigma), where the
    graphics cover it."""

    name = "dsnu"
    section = "4.3 (fixed-pattern offsets)"
    order = 220
    searches = (Search("dsnu", "a dense per-pixel offset map, sigma {sigma_dn:.2f} DN, the same at every "
                               "brightness ({tail_percent:.2f} % of pixels are outliers holding {share:.0f} % of "
                               "its fixed energy)", fit=fit_dense_offset, per_pixel=True),)

    def apply(self, state):
        state.rgb += self.pattern(state.rgb.shape) * state.rgb_alpha


class HotPixels(_PixelMap):
    """A ``fraction`` of pixels with a large fixed offset (``strength`` DN, all channels)."""

    name = "hot_pixels"
    section = "4.3 (defective pixels)"
    order = 230
    searches = (Search("hot_pixels", "{count} pixels ({percent:.3f} % of the frame) stay bright by {median_dn:.0f} "
                                     "DN in every capture and hold {share:.0f} % of the fixed offset energy: "
                                     "sparse outliers, not a dense map", fit=fit_hot_pixels),)
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
                       fit=fit_row_noise, changes_noise=True),)
    random = True
    params = {"sigma_dn": Param(0.0, low=0.0, high=50.0, unit="DN")}

    def apply(self, state):
        g = state.geometry
        rows = frame_rng(state.seed, state.frame ^ 0x5A5A).standard_normal(g.height + 4).astype(np.float32)
        by = BAYER_BORDER[0]
        hb = g.bayer_shape[0]
        for k, name in enumerate(("R", "Gr", "Gb", "B")):
            dy = g.cfa[name][0]
            r = np.clip(2 * (np.arange(hb) - by) + dy + 2, 0, g.height + 3)
            state.bayer[k] += self.sigma_dn * rows[r][:, None] * np.clip(state.bayer_alpha[k], 0, 1)
