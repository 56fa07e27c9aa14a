"""Model against measurement: the noise-aware error, where it lives, and probes per physical effect.

The error
---------
For a capture with ``n`` measured frames F and ``K`` simulated frames G (the profile with its noise, seeds
1000.., so the model's own randomness is included), three families of statistics are compared:

- ``mean``: the residual of the temporal means ``R = mean(F) - mean(G)`` against the noise that the two means
  carry, ``e_mean^2 = sum R^2 / sum(var_F / n + var_G / K)`` over all pixels and channels (per-pixel temporal
  variances). 1.0 means that the residual is as large as the noise alone would make it.
- ``variance``: the temporal noise variance per channel and brightness bin, measured over model;
  ``e_var = exp(rms |ln ratio|)`` (1.0: the model's noise has the measured strength at every brightness).
- ``rows``: the variance of per-frame row means of the noise (row noise), measured over model, as ``e_var``.

The error is ``sqrt((e_mean^2 + e_var^2 + e_rows^2) / 3)``, over all captures: 1.0 (the noise floor) when the
model explains the frames down to their noise. A capture with one frame has no temporal noise to measure: its
noise families are not compared (:attr:`Comparison.measured`), and the noise of its mean is the model's, or a
fixed ``assumed_noise`` (diagnosis passes the diagnosed profile's, so a candidate cannot win by adding noise). The
verdict is ``explained`` up to 1.1 times the noise floor
(:attr:`Comparison.noise_floor`, 1.0 unless set), ``not explained`` above.

Contents
--------
- :data:`EXPLAINED_BELOW`: the error, in noise floors, up to which the verdict is ``explained`` (1.1)
- :data:`EDGE_SHARE`, :data:`EDGES_HOLD`: the pixels counted as edges, and when the residual is said to be there
- :data:`SIM_SEED`: the first noise seed of the simulated frames
- :data:`SEQUENCE_SEED_STEP`, :data:`NOISE_OF_MEAN_PX`: the second model sequence that measures the noise of the
  mean where frames are not independent (a video encoder), and the squares it is averaged over
- :data:`INTENSITY_BINS`: the brightness bins (DN) of the variance comparison
- :data:`CACHED_FRONTS`: deterministic fronts of the chain a shared cache keeps
- :data:`WORKERS`: captures simulated at a time by a comparison made from the main thread
- :class:`CaptureStats`: one capture's measured and simulated frames and its error sums
- :class:`Comparison`: the error, its families and per-capture statistics; ``where`` and ``verdict``
- :class:`CaptureInputs`: what a capture is simulated from: the ideal render, the plate, the mask of compared pixels
- :func:`capture_inputs`: a capture's :class:`CaptureInputs`, rendering the target's ideal view when needed
- :func:`simulate_capture`: ``count`` noisy frames of a capture through a profile, the deterministic part cached
- :func:`capture_stats`: the error sums of one capture's measured frames F against simulated frames G
- :func:`combine`: the error and its families over all captures
- :data:`BANDS`: the radial spatial-frequency bands of :func:`where` and :func:`noise_texture`
- :func:`temporal_noise`: a static capture's temporal noise on the grey (each frame less the frames' mean)
- :func:`spatial_correlation`: the correlation of that noise with the noise d pixels right and d pixels down
- :func:`noise_texture`: how a capture's temporal noise is correlated in space (neighbours, frequency bands) and time
- :func:`residual_family`: the kind of residual left (edges, levels, space or time), with its numbers
- :func:`where`: where the mean residual lives: per channel, region (3x3), spatial-frequency band, brightness
- :func:`compare`: compare a profile with a measurement set (the error above)
"""
from __future__ import annotations

import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from ..effects.delivered_frame import beyond_spread, row_log_ratios
from ..effects.fixed_pattern import row_noise_variance
from ..effects.temporal_noise_reduction import frame_to_frame_correlation
from ..errors import LowcamError
from ..pipeline import deterministic_prefix, has_temporal, prefix_key, prepare, resume_sequence
from .targets import ideal_from_target

EXPLAINED_BELOW = 1.1
#: The share of each frame's pixels that :func:`where` counts as edges (the steepest of the simulated mean).
EDGE_SHARE = 0.1
#: The residual is at edges (:func:`residual_family`) when they hold this many times their share of it.
EDGES_HOLD = 3.0
SIM_SEED = 1000
#: The second model sequence of a profile whose frames are not independent starts at ``SIM_SEED`` plus this
#: (:func:`capture_stats`'s ``again``).
SEQUENCE_SEED_STEP = 500
#: Side (px) of the squares over which the noise of the mean measured from two model sequences is averaged.
NOISE_OF_MEAN_PX = 9
INTENSITY_BINS = np.linspace(0, 256, 17)
#: Deterministic fronts of the chain a shared ``cache`` keeps (:func:`simulate_capture`), least recently used out
#: first.
CACHED_FRONTS = 32
#: Captures simulated at a time by a comparison made from the main thread (NumPy and OpenCV release the GIL); a
#: comparison made inside diagnosis's candidate threads runs its captures in turn.
WORKERS = 2


@dataclass
class CaptureStats:
    name: str
    measured: np.ndarray  # (n, H, W, 3) uint8
    simulated: np.ndarray  # (K, H, W, 3) uint8
    sums: dict = field(default_factory=dict)  # per family: (numerator, denominator) or list of log ratios

    @property
    def residual(self) -> np.ndarray:
        return self.measured.astype(np.float64).mean(0) - self.simulated.astype(np.float64).mean(0)


@dataclass
class Comparison:
    error: float
    families: dict
    captures: list
    noise_floor: float = 1.0

    @property
    def measured(self) -> dict:
        """Family -> True when the frames measure it, False when it is assumed (1.0: one frame per capture has no
        temporal noise to compare, and the mean's noise is then the diagnosed profile's)."""
        several = any(len(s.measured) > 1 for s in self.captures)
        return {"mean": True, "variance": several, "rows": several}

    @property
    def error_unmasked(self) -> float:
        """The error with the masks' pixels compared too (:attr:`error` leaves them out): shown beside it."""
        return combine(self.captures, masked=False)[0]

    @property
    def noise_texture(self) -> dict | None:
        """The noise's correlation in space and time (:func:`noise_texture`), the frames' against the model's,
        each the mean over the captures with at least 3 frames; None without one."""
        pairs = [(noise_texture(s.measured), noise_texture(s.simulated)) for s in self.captures]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        if not pairs:
            return None

        def mean(which):
            keys = ("lag1_x", "lag1_y", "lag1_t")
            out = {k: float(np.mean([p[which][k] for p in pairs])) for k in keys}
            out["bands"] = {b: float(np.mean([p[which]["bands"][b] for p in pairs])) for _, _, b in BANDS}
            return out
        return {"measured": mean(0), "model": mean(1), "captures": len(pairs)}

    @property
    def held_noise(self) -> float | None:
        """How much more the frames' noise is held from one frame to the next than the model's: the mean over the
        captures of at least 3 frames of their :func:`frame_to_frame_correlation` less the model frames'; about 0
        for a camera that draws its noise anew each frame as the model does, up to 1 where a stage holds it (a
        temporal filter, a video encoder). None without such a capture."""
        pairs = [(frame_to_frame_correlation(s.measured), frame_to_frame_correlation(s.simulated))
                 for s in self.captures]
        held = [a - b for a, b in pairs if a is not None and b is not None]
        return float(np.mean(held)) if held else None

    @property
    def where(self) -> dict:
        if not hasattr(self, "_where"):
            self._where = where(self.captures)
        return self._where

    @property
    def verdict(self) -> str:
        return "explained" if self.error <= EXPLAINED_BELOW * self.noise_floor else "not explained"


class CaptureInputs(NamedTuple):
    """What a capture is simulated from and compared on: ``ideal`` (h, w, 4) premultiplied RGBA, ``plate`` (H, W, 3)
    uint8 or None, ``mask`` (H, W) bool or None: the output pixels compared (False: left out as a nuisance, an
    occluder or the board's border, and shown as masked in the report; None: every pixel)."""

    ideal: np.ndarray
    plate: np.ndarray | None
    mask: np.ndarray | None = None


def capture_inputs(profile, capture) -> CaptureInputs:
    """A capture's :class:`CaptureInputs`, rendering the target's ideal view when needed; the mask is the
    capture's own (``mask`` in set.toml) and the target fit's, both."""
    if capture.ideal is not None:
        return CaptureInputs(capture.ideal, capture.plate, capture.mask)

    ideal, plate, mask = ideal_from_target(profile, capture)
    if capture.mask is not None:
        mask = capture.mask if mask is None else mask & capture.mask
    return CaptureInputs(ideal, plate, mask)


#: Each capture's plates (float and 8-bit), held once for all its kept fronts (by the capture's id and the kind;
#: weakly, so they go with the fronts).
_SHARED_PLATES: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def _shared_plate(key, plate: np.ndarray) -> np.ndarray:
    """The plate held under ``key`` when it equals ``plate`` (the chain only reads plates), else ``plate``."""
    kept = _SHARED_PLATES.setdefault(key, plate)
    same = kept is plate or kept.shape == plate.shape and kept.dtype == plate.dtype and np.array_equal(kept, plate)
    return kept if same else plate


def simulate_capture(profile, capture, count: int, seed: int = SIM_SEED, inputs=None, cache=None,
                     until: str | None = None) -> np.ndarray:
    """``count`` frames of the capture through ``profile`` (noise frames 0..count-1 of ``seed``), in order as one
    sequence (a temporal effect, a video encoder, codes them together: frame 0 an I-frame,
    :func:`lowcam.pipeline.resume_sequence`); the deterministic part of the chain runs once, and not at all when
    ``cache`` (a dict) already holds it."""
    ideal, plate, _ = inputs or capture_inputs(profile, capture)
    key = (id(capture), prefix_key(profile, deterministic_prefix(profile, until)))
    token = cache.pop(key, None) if cache is not None else None
    if token is None:
        token = prepare(ideal, profile, plate, capture.angular_velocity, capture.exposure_s, until)
    if cache is not None:  # least recently used out first: the diagnosed profile's fronts stay
        state, start, plate_u8 = token
        state.plate = _shared_plate((id(capture), "float"), state.plate)
        token = state, start, _shared_plate((id(capture), "8-bit"), plate_u8)
        cache[key] = token
        while len(cache) > CACHED_FRONTS:
            try:
                cache.pop(next(iter(cache)))
            except (KeyError, StopIteration, RuntimeError):  # another thread changed it meanwhile
                break
    return resume_sequence(token, seed, count, profile)


def _variance_log_ratios(vF, vG, level, min_pixels: int = 400, mask=None, vA=None) -> list[float]:
    """Log ratios of the measured over the model's temporal variance per channel and brightness bin; ``vA``: the
    variance of a second model sequence (:func:`~lowcam.effects.delivered_frame.beyond_spread`)."""
    out = []
    nb = len(INTENSITY_BINS) - 1
    keep = slice(None) if mask is None else mask.ravel()
    for c in range(3):
        idx = np.clip(np.digitize(level[..., c].ravel()[keep], INTENSITY_BINS) - 1, 0, nb - 1)
        count = np.bincount(idx, minlength=nb)
        sf = np.bincount(idx, vF[..., c].ravel()[keep], nb)
        sg = np.bincount(idx, vG[..., c].ravel()[keep], nb)
        for b in np.nonzero(count >= min_pixels)[0]:
            mf, mg = sf[b] / count[b], sg[b] / count[b]
            if mf > 0.05 and mg > 0.05:  # skip clipped bins, which carry no noise
                if vA is None:
                    out.append(float(np.log(mf / mg)))
                else:
                    ma = np.bincount(idx, vA[..., c].ravel()[keep], nb)[b] / count[b]
                    out.append(beyond_spread(np.log(mf / mg), np.log(max(ma, 0.05) / mg)))
    return out


def _row_log_ratios(F, G, A=None, mask=None) -> list[float]:
    return row_log_ratios(row_noise_variance(F, mask), row_noise_variance(G, mask),
                          None if A is None else row_noise_variance(A, mask))


def _mean_and_squares(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The float32 mean of ``frames`` (N, ...; uint8 or float32) and the sum of their squared deviations from it,
    one frame at a time: the sums of ``mean(0)`` and ``((frames - mean) ** 2).sum(0)`` of their float32 copy, in the
    same order (so the same bits), without that copy."""
    total = frames[0].astype(np.float32)
    for frame in frames[1:]:
        total += frame
    mean = total / np.float32(len(frames))
    squares = np.square(frames[0] - mean)
    for frame in frames[1:]:
        squares += np.square(frame - mean)
    return mean, squares


def capture_stats(F: np.ndarray, G: np.ndarray, name: str = "", assumed_noise: np.ndarray | None = None,
                  mask: np.ndarray | None = None, again: np.ndarray | None = None) -> CaptureStats:
    """The error sums of one capture's measured frames F against simulated frames G (see the module docstring),
    over the pixels ``mask`` (H, W) keeps (all when None).

    With one measured frame its noise cannot be measured: the per-pixel variance ``assumed_noise`` (the diagnosed
    profile's, fixed while candidates are compared) stands for both, or the model's own when None. Then a model
    cannot lower its error by adding noise.

    ``again``: a second model sequence of the capture (other noise seeds), for a profile whose frames are not
    independent (a video encoder's predicted frames hold the noise of the frame before): the temporal variance
    then understates the noise of the mean, which is measured instead as ``(mean(G) - mean(again))^2`` (twice the
    model mean's variance, standing for the measured mean's and the model's), averaged over
    :data:`NOISE_OF_MEAN_PX` squares, and at least the independent frames' ``var_F / n + var_G / K``; the noise
    families count only what lies beyond the two model sequences' own difference (:func:`~lowcam.effects.delivered_frame.beyond_spread`)."""
    n, k = len(F), len(G)
    mF, squares_F = _mean_and_squares(F)
    mG, squares_G = _mean_and_squares(G)
    vG = np.maximum(squares_G / (k - 1), 1 / 12)
    if n > 1:
        vF = np.maximum(squares_F / (n - 1), 1 / 12)
        noise = vF / n + vG / k
    else:  # one frame: its noise is assumed
        vF = vG if assumed_noise is None else assumed_noise
        noise = vF * (1 / n + 1 / k)
    vA = None
    if again is not None:
        mA, squares_A = _mean_and_squares(again)
        vA = np.maximum(squares_A / (len(again) - 1), 1 / 12)
        d2 = np.square(mG - mA)
        noise = np.maximum(noise, cv2.blur(d2, (NOISE_OF_MEAN_PX, NOISE_OF_MEAN_PX)))
    r = mF - mG
    every = None
    if mask is not None:  # left-out pixels carry no residual and no noise (summed once over all, for beside)
        every = (float((r.astype(np.float64) ** 2).sum()), float(noise.sum(dtype=np.float64)))
        r = r * mask[..., None]
        noise = noise * mask[..., None]
    mean = (float((r.astype(np.float64) ** 2).sum()), float(noise.sum(dtype=np.float64)))
    sums = {"mean": mean, "mean_unmasked": every or mean,
            "model_noise": float((vG if mask is None else vG * mask[..., None]).sum(dtype=np.float64)) / k,
            "noise_map": noise, "variance_map": vF, "mask": mask,
            "variance": _variance_log_ratios(vF, vG, mG, mask=mask, vA=vA) if n > 1 else [],
            "variance_unmasked": _variance_log_ratios(vF, vG, mG, vA=vA) if n > 1 and mask is not None else None,
            "rows": _row_log_ratios(F, G, again, mask) if n > 1 else [],
            "rows_unmasked": _row_log_ratios(F, G, again) if n > 1 and mask is not None else None}
    return CaptureStats(name, F, G, sums)


def combine(stats: list[CaptureStats], masked: bool = True) -> tuple[float, dict]:
    """The error and its families over all captures; ``masked=False``: over every pixel, the captures' masks
    ignored."""
    mean = "mean" if masked else "mean_unmasked"
    num = sum(s.sums[mean][0] for s in stats)
    den = sum(s.sums[mean][1] for s in stats)
    e_mean = float(np.sqrt(num / den))

    def family(s, name):  # a noise family's log ratios, read through the masks or (where there are some) not
        unmasked = s.sums[f"{name}_unmasked"]
        return s.sums[name] if masked or unmasked is None else unmasked

    logs = [v for s in stats for v in family(s, "variance")]
    e_var = float(np.exp(np.sqrt(np.mean(np.square(logs))))) if logs else 1.0
    rows = [v for s in stats for v in family(s, "rows")]
    e_rows = float(np.exp(np.sqrt(np.mean(np.square(rows))))) if rows else 1.0
    error = float(np.sqrt((e_mean ** 2 + e_var ** 2 + e_rows ** 2) / 3))
    return error, {"mean": e_mean, "variance": e_var, "rows": e_rows}


def where(stats: list[CaptureStats]) -> dict:
    """Where the mean residual lives: per channel, per region (3x3), per spatial-frequency band, per brightness,
    and at edges (the steepest :data:`EDGE_SHARE` of pixels: their share of the residual, and the error there and
    elsewhere). Each error is the noise-normalised error of that subset (1.0 = noise)."""
    def ratio(sel_r2, sel_noise):
        return float(np.sqrt(sel_r2 / max(sel_noise, 1e-12)))

    r2 = [s.residual ** 2 if s.sums.get("mask") is None else s.residual ** 2 * s.sums["mask"][..., None]
          for s in stats]
    noise = [s.sums["noise_map"] for s in stats]
    out = {"channels": [], "regions": [], "bands": [], "intensities": []}
    for c, name in enumerate(("red", "green", "blue")):
        out["channels"].append({"channel": name, "error": ratio(sum(x[..., c].sum() for x in r2),
                                                                sum(x[..., c].sum() for x in noise))})
    h, w = r2[0].shape[:2]
    for i in range(3):
        for j in range(3):
            sl = (slice(i * h // 3, (i + 1) * h // 3), slice(j * w // 3, (j + 1) * w // 3))
            out["regions"].append({"region": ["top", "middle", "bottom"][i] + "-" + ["left", "centre", "right"][j],
                                   "error": ratio(sum(x[sl].sum() for x in r2), sum(x[sl].sum() for x in noise))})
    # bands: residual power by radial spatial frequency, against white noise of the same total noise power
    bands = BANDS
    power = np.zeros(3)
    expected = np.zeros(3)
    for s, nz in zip(stats, noise):
        res = s.residual if s.sums.get("mask") is None else s.residual * s.sums["mask"][..., None]
        spec = np.abs(np.fft.fft2(res, axes=(0, 1))) ** 2 / (h * w)
        fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
        f = np.hypot(fx, fy)
        for k, (lo, hi, _) in enumerate(bands):
            sel = (f >= lo) & (f < hi)
            power[k] += spec[sel].sum()
            expected[k] += nz.mean() * sel.sum() * 3
    for k, (_, _, name) in enumerate(bands):
        out["bands"].append({"band": name, "error": ratio(power[k], expected[k])})
    for b in range(0, 16, 2):
        lo, hi = INTENSITY_BINS[b], INTENSITY_BINS[b + 2]
        num = den = 0.0
        for s, x, nz in zip(stats, r2, noise):
            level = s.simulated.mean(0)
            sel = (level >= lo) & (level < hi)
            num += x[sel].sum()
            den += nz[sel].sum()
        if den > 0:
            out["intensities"].append({"range_dn": [float(lo), float(hi)], "error": ratio(num, den)})
    # edges: the steepest EDGE_SHARE of each capture's simulated mean (grey gradient magnitude)
    px = res_edges = res_all = noise_edges = noise_all = 0.0
    for s, x, nz in zip(stats, r2, noise):
        grey = s.simulated.mean(0, dtype=np.float64).mean(-1)
        gy, gx = np.gradient(grey)
        steep = np.hypot(gx, gy)
        edge = steep > max(np.quantile(steep, 1 - EDGE_SHARE), 1e-9)
        px += edge.mean() / len(stats)
        res_edges, res_all = res_edges + x[edge].sum(), res_all + x.sum()
        noise_edges, noise_all = noise_edges + nz[edge].sum(), noise_all + nz.sum()
    out["edges"] = {"share_px": float(px), "share_residual": float(res_edges / max(res_all, 1e-12)),
                    "error": ratio(res_edges, noise_edges),
                    "error_elsewhere": ratio(res_all - res_edges, noise_all - noise_edges)}
    return out


#: The radial spatial-frequency bands (cycles per pixel) of :func:`where` and :func:`noise_texture`.
BANDS = ((0.0, 0.05, "low"), (0.05, 0.2, "mid"), (0.2, 0.71, "high"))


def temporal_noise(frames: np.ndarray) -> np.ndarray:
    """A static capture's temporal noise on the grey: each frame (n, H, W, 3) less the frames' mean, the channels
    averaged (n, H, W; the scene cancels)."""
    grey = np.asarray(frames).astype(np.float32).mean(-1)
    return grey - grey.mean(0)


def spatial_correlation(noise: np.ndarray, lag_px: int = 1) -> tuple[float, float]:
    """The correlation of noise (n, H, W; :func:`temporal_noise`) with the noise ``lag_px`` pixels to the right and
    ``lag_px`` pixels down: 0 for white noise, ``exp(-d^2 / (4 sigma^2))`` for white noise through a Gaussian of
    ``sigma``; 0 where there is no noise."""
    var = float(np.mean(noise ** 2))
    if var <= 1e-9:
        return 0.0, 0.0
    d = int(lag_px)
    return (float(np.mean(noise[:, :, d:] * noise[:, :, :-d]) / var),
            float(np.mean(noise[:, d:, :] * noise[:, :-d, :]) / var))


def noise_texture(frames: np.ndarray) -> dict | None:
    """How the temporal noise of a static capture's frames (n, H, W, 3; n >= 3) is correlated, in space and time:
    what tells a denoised camera from a raw one of the same noise variance.

    The noise is each frame less the frames' mean, ``N_t = F_t - mean(F)`` (the scene cancels), on the grey
    (channel mean). ``lag1_x``, ``lag1_y``: its correlation with its neighbour one pixel right and one down
    (0 for white noise; a spatial denoiser, a blur or a demosaic raise it). ``bands``: the share of its power in
    each radial frequency band of :data:`BANDS` (white noise puts most in ``high``, where most frequencies are;
    blotchy, low-pass noise moves it to ``low`` and ``mid``). ``lag1_t``: the correlation of the noise from one
    frame to the next (:func:`frame_to_frame_correlation`): 0 for noise drawn anew each frame; a temporal filter
    that carries a share ``a`` of the last frame raises it, to below ``a`` over few frames, since their mean takes
    part of a slow drift (0.43 for ``a = 0.6`` over 8 frames). The frames and the model are read alike. None with
    fewer than 3 frames.
    """
    if len(frames) < 3:
        return None
    noise = temporal_noise(frames)
    if float(np.mean(noise ** 2)) <= 1e-9:
        return None
    lag_x, lag_y = spatial_correlation(noise)
    lag_t = frame_to_frame_correlation(frames)
    h, w = noise.shape[1:]
    spec = (np.abs(np.fft.rfft2(noise)) ** 2).sum(0)
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.rfftfreq(w), indexing="ij")
    f = np.hypot(fx, fy)
    power = np.array([spec[(f >= lo) & (f < hi)].sum() for lo, hi, _ in BANDS])
    return {"lag1_x": lag_x, "lag1_y": lag_y, "lag1_t": float(lag_t),
            "bands": {name: float(p) for (_, _, name), p in zip(BANDS, power / max(power.sum(), 1e-12))}}


def residual_family(cmp: "Comparison") -> tuple[str, str]:
    """The kind of residual a comparison leaves, and the numbers that say so (one line):

    - ``time``: the noise between frames (``variance`` or ``rows`` family) is further off than the mean;
    - ``edges``: the pixels at edges (:data:`EDGE_SHARE` of them) hold at least :data:`EDGES_HOLD` times their
      share of the mean's residual (blur, sharpening, coding or registration);
    - ``levels``: the residual varies more with brightness than across the frame (tone, black level, clipping);
    - ``space``: it varies more across the frame's regions (vignetting, a field-dependent effect).
    """
    fam, w = cmp.families, cmp.where
    if cmp.measured["variance"] and max(fam["variance"], fam["rows"]) > fam["mean"]:
        return "time", (f"the noise between frames: variance {fam['variance']:.2f}, rows {fam['rows']:.2f}, "
                        f"against the mean's {fam['mean']:.2f}")
    edges = w["edges"]
    if edges["share_residual"] >= EDGES_HOLD * edges["share_px"]:
        return "edges", (f"{edges['share_residual']:.0%} of the residual on the {edges['share_px']:.0%} of pixels "
                         f"at edges (error {edges['error']:.2f} there, {edges['error_elsewhere']:.2f} elsewhere)")
    levels = sorted(w["intensities"], key=lambda e: e["error"])
    regions = sorted(w["regions"], key=lambda e: e["error"])
    level_spread = levels[-1]["error"] / max(levels[0]["error"], 1e-9) if len(levels) > 1 else 1.0
    region_spread = regions[-1]["error"] / max(regions[0]["error"], 1e-9)
    if level_spread >= region_spread:
        lo, hi = levels[-1]["range_dn"]
        return "levels", (f"worst at {lo:.0f}-{hi:.0f} DN ({levels[-1]['error']:.2f}), best at "
                          f"{levels[0]['range_dn'][0]:.0f}-{levels[0]['range_dn'][1]:.0f} DN ({levels[0]['error']:.2f})")
    return "space", (f"worst in the {regions[-1]['region']} ({regions[-1]['error']:.2f}), best in the "
                     f"{regions[0]['region']} ({regions[0]['error']:.2f})")


def compare(mset, profile, sim_frames: int | None = None, cache=None, inputs=None, assumed_noise=None,
            subset=None) -> Comparison:
    """Compare a profile with a measurement set (see the module docstring for the error). ``cache`` (a dict)
    keeps the deterministic front of the chain between calls that share it; ``assumed_noise`` (per capture, from
    :attr:`CaptureStats.sums` ``["variance_map"]`` of an earlier comparison) fixes the noise of one-frame
    captures; ``subset`` compares only those captures (by index)."""
    chosen = [i for i in range(len(mset.captures)) if subset is None or i in subset]
    for i in chosen:
        cap = mset.captures[i]
        if cap.frames.shape[1:3] != (profile.camera.height, profile.camera.width):
            raise LowcamError(f"{cap.where}: frames are {cap.frames.shape[2]}x{cap.frames.shape[1]}, the "
                              f"profile delivers {profile.camera.width}x{profile.camera.height}")

    def one(i):
        cap = mset.captures[i]
        here = CaptureInputs(*inputs[i]) if inputs else capture_inputs(profile, cap)
        count = sim_frames or max(len(cap.frames), 4)
        temporal = has_temporal(profile)
        if temporal:  # each frame's place in the sequence (its GOP, its filter's state) shapes it: every frame made
            count = max(count, len(cap.frames))
        sim = simulate_capture(profile, cap, count, inputs=here, cache=cache,
                               until="bayer_sampling")  # the front diagnosis's noise-free frames share
        again = None
        if temporal:  # frames not independent: a second sequence measures the noise of the mean
            again = simulate_capture(profile, cap, count, SIM_SEED + SEQUENCE_SEED_STEP, inputs=here, cache=cache,
                                     until="bayer_sampling")
        return capture_stats(cap.frames, sim, cap.name, assumed_noise[i] if assumed_noise else None, here.mask,
                             again)

    if WORKERS > 1 and len(chosen) > 1 and threading.current_thread() is threading.main_thread():
        with ThreadPoolExecutor(WORKERS) as pool:
            stats = list(pool.map(one, chosen))
    else:
        stats = [one(i) for i in chosen]
    error, families = combine(stats)
    return Comparison(error, families, stats)
