"""Sensor noise with an intensity-dependent standard deviation (Klein & Murray 2010, sec. 4.3, 5.2 step 5).

Gaussian noise per sensel, independent in space and time, in 8-bit DN, under one of two laws per channel:
``sigma = a + b mu`` (the paper's linear fit, sec. 4.3) or ``sigma^2 = a + b mu`` (photon transfer: read noise
plus shot noise, the form Irie et al. and EMVA 1288 predict). Under the Fire-i's 2x2-block demosaicing each
green pixel averages two sensels, so the measured green law is scaled by sqrt 2 (sigma) or 2 (variance) to give
the per-sensel one; red and blue are not scaled. Means above 220 DN are left out of the fits (saturation). A
sensor with a black level has a negative variance intercept (EMVA 1288: ``a = K^2 sigma_d^2 - K mu_dark``), so
``a`` may be negative; the variance is clamped at 0 where the law falls below it. A law is fitted only to a stack
that shows at least :data:`MIN_LEVELS` brightness levels.

Beyond the paper, the noise may carry a grain (``grain_px``): the white noise is correlated in space by a Gaussian
of that sigma over the sensor's mosaic, its variance kept, so that its level per intensity is the law's and its
power per spatial frequency the Gaussian's, ``exp(-(2 pi f sigma)^2)`` (a sensor read out at more pixels than the
frame and scaled down, binning, or a raw-domain denoiser leave such noise). Neighbours ``d`` pixels apart then
correlate by ``exp(-d^2 / (4 sigma^2))`` before demosaicing.

Contents
--------
- :data:`SEED_RANGE`, :data:`FRAME_RANGE`: the seeds and frame numbers accepted
- :func:`frame_rng`: the random generator of one frame: reproducible from (seed, frame), independent between frames
- :class:`Noise`: Gaussian noise per sensel, its sigma a function of the mean (DN), scaled by alpha
- :data:`MAX_GRAIN_PX`: the largest grain (px) a profile may give its noise
- :func:`grain_noise`: white unit noise on the sensel planes correlated by a Gaussian over the mosaic, variance kept
- :data:`MIN_LEVELS`, :data:`LEVEL_STEP_DN`: the brightness levels (bands of DN) a noise stack must show
- :func:`brightness_levels`: how many distinct brightness levels per-pixel temporal means show
- :func:`fit_noise_law`: fit ``[a, b]`` of a noise law to per-pixel temporal means and deviations (sec. 4.3);
  ``a`` may be negative (a black level)
- :func:`fit_noise`: both noise laws per channel from a stack (N, H, W, 3) of frames of a static scene, in DN
- :data:`NLF_BIN_DN`, :data:`SPATIAL_QUANTILE`, :data:`NLF_BLOCK_PX`, :data:`HEADLINE_DN`: the brightness bins (DN)
  of the noise level function measured on footage, the quantile of flat-block variances that gives its spatial
  lower envelope, the blocks (px) it is measured in and the levels (DN) it is read at
- :data:`ROUNDING_FLOOR_DN2`, :data:`REPEATED_SHARE`: below this variance (in a bin, or in this share of its
  blocks) a bin shows pixels a codec repeated or flattened, not noise
- :func:`noise_level_statistic`: the noise level function (sigma against mean per channel or of the luma, DN) of
  footage: from registered frame pairs (a moving camera, moving objects) or single frames' flat blocks
- :data:`BIN_SCATTER`: the scatter about a law allowed to every bin of footage besides its standard error
- :func:`fit_plate_law`: ``[a, b]`` of a law fitted to a noise level function, both at least 0, and how far off it
  may be
- :func:`noise_gain`: how the chain after the noise scales it per channel, as the noise level function sees it
- :data:`PLATE_PAIRS`, :data:`STILL_PX`, :data:`MIN_PAIRS`: the frame pairs the plate's noise estimate
  registers, the motion (px) below which a pair is still, and how many still pairs (or pairs on the coding grid)
  it needs to use them alone
- :data:`CODING_GRID_PX`: JPEG's block, the grid a camera moving by its multiples puts back on the same content
- :data:`CODEC_FLICKER`: how much more luma noise a JPEG-coded pan shows than a still shot, by quality (measured)
- :func:`channel_proportions`: how a law read on the luma is shared between the channels (the base profile's)
- :func:`noise_level_function_from_plate`: the noise law from footage (a :class:`lowcam.plate_estimate.PlateEstimate`)

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

from dataclasses import replace

import cv2
import numpy as np

from ..errors import LowcamError, NotFitted, ProfileError
from ..geometry import CFA_CHANNELS
from ..parallel import thread_map
from ..plate_estimate import PlateEstimate, PlateProbe, pair_starts, register_footage
from ..registration import GRID_WINDOW, RegisteredPairs, register_frames, register_on_grid
from .base import Effect, NodeStage, Param, lead_frames, plugin_failures
from .jpeg import _GRID_T, LUMA_WEIGHTS, bt601_luma, jpeg_blockiness


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


#: The largest grain (Gaussian sigma, px) of a profile's noise: beyond it the noise is blotches, which spatial noise
#: reduction (:mod:`lowcam.effects.noise_reduction`) models with the detail it also takes.
MAX_GRAIN_PX = 4.0


def grain_noise(white: np.ndarray, cfa: dict, sigma_px: float) -> np.ndarray:
    """White unit noise on the four sensel planes (4, rows, cols; R, Gr, Gb, B at ``cfa``'s offsets in the 2x2
    cell) correlated in space: interleaved into the mosaic, filtered by a Gaussian of ``sigma_px`` (px of the
    mosaic; edges mirrored) and divided by the filter's gain on white noise, ``sum(g^2)`` per axis, so that every
    sensel keeps unit variance. Returns new planes; ``sigma_px`` 0 returns ``white``.
    """
    if sigma_px <= 0.0:
        return white
    _, rows, cols = white.shape
    mosaic = np.empty((2 * rows, 2 * cols), np.float32)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = cfa[name]
        mosaic[dy::2, dx::2] = white[k]
    radius = int(np.ceil(4.0 * sigma_px))
    g = cv2.getGaussianKernel(2 * radius + 1, sigma_px, cv2.CV_32F)
    shaped = cv2.sepFilter2D(mosaic, -1, g, g, borderType=cv2.BORDER_REFLECT_101)
    shaped *= np.float32(1.0 / float(np.sum(g.astype(np.float64) ** 2)))
    return np.stack([shaped[dy::2, dx::2] for dy, dx in (cfa[name] for name in CFA_CHANNELS)])


class Noise(Effect):
    """Gaussian noise per sensel, independent in time, its sigma a function of the mean (DN).

    ``law = "sigma_linear"``: ``sigma = a + b mu`` (the paper's fit, sec. 4.3);
    ``law = "variance_linear"``: ``sigma^2 = a + b mu`` (photon transfer: read noise plus shot noise).
    ``red``, ``green``, ``blue`` hold ``[a, b]`` per sensel, in 8-bit DN (green is the per-sensel value, i.e. the
    demosaiced green sigma times sqrt 2 under 2x2-block demosaicing). On partially covered sensels the noise is
    scaled by alpha, so transparent areas stay noise-free and the plate's own noise is not doubled.
    ``grain_px`` (0: white, the paper) correlates the noise in space (:func:`grain_noise`), its level kept.
    """

    name = "noise"
    section = "4.3, 5.2 step 5"
    writes = "bayer"
    order = 130
    calibration = "noise"
    node = NodeStage("Noise", "mosaic", "noise")
    random = True
    removable = False           # the noise every comparison is measured against
    params = {
        "law": Param("sigma_linear", str, choices=("sigma_linear", "variance_linear")),
        "red": Param([1.5, 0.015], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
        "green": Param([1.2, 0.012], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
        "blue": Param([1.8, 0.016], "vector", length=2, low=-255.0, high=255.0, doc="[a, b]; a < 0: black level"),
        "grain_px": Param(0.0, low=0.0, high=MAX_GRAIN_PX, unit="px",
                          doc="sigma of the Gaussian that correlates the noise in space; 0: white"),
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

    def bake_node(self, state, bake) -> None:
        """The law and its coefficients per channel (the node adds noise from them). The node draws each sensel's
        noise apart, so a profile whose noise has a grain is refused in one line."""
        if self.grain_px > 0.0:
            raise self.error(f"grain_px = {self.grain_px:g}: the compositor node group draws white noise (each sensel "
                             f"apart); use the engine (the add-on's render handler), or set grain_px = 0 for the "
                             f"node group")
        bake.values["noise_law"] = self.law
        bake.values["noise"] = {c: list(getattr(self, c)) for c in ("red", "green", "blue")}

    def apply(self, state):
        rng = frame_rng(state.seed, state.frame)
        z = grain_noise(rng.standard_normal(state.bayer.shape, dtype=np.float32), state.geometry.cfa, self.grain_px)
        alpha = state.bayer_alpha
        mean = state.bayer / np.maximum(alpha, 1e-6)

        def add(k: int, channel: str) -> None:  # one sensel plane; the planes side by side
            state.bayer[k] += z[k] * np.clip(alpha[k], 0.0, 1.0) * self.sigma(channel, mean[k]).astype(np.float32)

        thread_map(lambda kc: add(*kc), enumerate(("red", "green", "green", "blue")))


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
#: Variance (DN^2) of rounding to whole DN: a bin whose noise variance measures below it shows pixels a codec
#: repeated or flattened (an inter-frame codec's skipped blocks, a vector quantiser's codebook), not noise.
ROUNDING_FLOOR_DN2 = 1.0 / 12.0
#: A bin where at least this share of the members' variances lies below :data:`ROUNDING_FLOOR_DN2` is left out
#: too: a JPEG at a low quality quantises the noise of many flat blocks away entirely and keeps the others', and a
#: quantile of such a mixture jumps between the two with the noise drawn (on scikit-image's rocket at quality 70,
#: 25-60 % of the blocks of every bin; two still shots' laws 20 % apart).
REPEATED_SHARE = 0.25
#: The scatter allowed to every bin besides its standard error when a law is fitted, as a share of the median
#: sigma: the bins of footage scatter about any law by more than their block counts say (scene, codec).
BIN_SCATTER = 0.1
#: Side (px) of the blocks of registered differences (and of the spatial method's blocks).
NLF_BLOCK_PX = 8
#: The levels (DN) at which a noise level function is read for tables and comparisons.
HEADLINE_DN = (64, 128, 192)
#: Frame pairs the plate's noise estimate registers (spread over the shot).
PLATE_PAIRS = 12
#: A pair whose registration moves no pixel by more than this (px) counts as still (no codec flicker).
STILL_PX = 0.5
#: The still frame pairs (or pairs on the coding grid) the plate's noise estimate needs to use them alone.
MIN_PAIRS = 3
#: JPEG's block (px): the luma's grid, which a camera moving by whole multiples of it puts back on the same content.
CODING_GRID_PX = 8
#: How much a pan's registered luma noise reads above a still shot's of the same scene when the frames are
#: JPEG-coded and no frame pairs lie on the coding grid, by IJG quality: the coding error of a moving scene changes
#: from frame to frame. Measured with :func:`noise_level_statistic` (``luma``, mean over 64, 128 and 192 DN) on
#: scikit-image's astronaut, chelsea, coffee, rocket and immunohistochemistry (rocket's noise not measurable at 70
#: and below), blurred 1.2 px across, noise variance 0.5 + 0.05 DN, Pillow 4:2:0, 8 frames cropped 3 px apart
#: against 8 still ones framing the pan's middle (a sub-pixel pan reads 0.04-0.2 less on average, 0.9-1.4 x the
#: still shot's per scene: its registration's error leaves out textured pixels, where the coder keeps more noise).
CODEC_FLICKER = {95: 1.01, 90: 1.08, 85: 1.14, 80: 1.18, 70: 1.34, 50: 1.53}


def _quantile_se(values: np.ndarray, quantile: float) -> tuple[float, float]:
    """(the ``quantile`` of ``values``, its standard error): half the spread of the order statistics one binomial
    standard deviation either side of it."""
    v = np.sort(values)
    n = len(v)
    spread = np.sqrt(n * quantile * (1 - quantile))
    lo = v[int(np.clip(np.floor(quantile * n - spread), 0, n - 1))]
    hi = v[int(np.clip(np.ceil(quantile * n + spread), 0, n - 1))]
    return float(np.quantile(v, quantile)), float(max(hi - lo, 0.0) / 2)


def _binned_nlf(mean: np.ndarray, var: np.ndarray, dof, quantile: float, saturation_dn: float = 220.0,
                min_count: int = 30, floor_dn: float = 4.0) -> dict:
    """One channel's noise level function: the pixels (or blocks) binned by mean in :data:`NLF_BIN_DN`-wide bins,
    each bin's variance the ``quantile`` of its members' variances (each with ``dof`` degrees of freedom, a number
    or one per member) divided by that quantile of chi-square / dof, so textured or moving members above it do not
    lift it [Liu2008's lower envelope]. Means below ``floor_dn`` (noise clipped at 0) or above ``saturation_dn`` are
    left out. Returns ``{"levels", "sigmas", "counts", "se"}`` (DN, DN, members, the sigma's standard error in DN)
    and ``"repeated"`` (bins left out as below), bins with fewer than ``min_count`` members left out, and bins whose
    variance lies below :data:`ROUNDING_FLOOR_DN2`, or :data:`REPEATED_SHARE` of whose members' do (pixels a codec
    repeated from frame to frame or flattened: the noise is not measurable there, not 0)."""
    from scipy.stats import chi2

    dof = np.broadcast_to(np.asarray(dof, np.float64), np.shape(mean))
    keep = (mean > floor_dn) & (mean < saturation_dn) & np.isfinite(var) & (dof >= 1)
    flat = var[keep] < ROUNDING_FLOOR_DN2
    mean, var, dof = mean[keep], var[keep] / (chi2.ppf(quantile, dof[keep]) / dof[keep]), dof[keep]
    idx = (mean // NLF_BIN_DN).astype(np.int64)
    order = np.argsort(idx, kind="stable")
    _, first, counts = np.unique(idx[order], return_index=True, return_counts=True)
    out = {"levels": [], "sigmas": [], "counts": [], "se": [], "repeated": 0}
    for start, n in zip(first, counts):
        if n >= min_count:
            sel = order[start:start + n]
            v, se = _quantile_se(var[sel], quantile)
            if v < ROUNDING_FLOOR_DN2 or flat[sel].mean() >= REPEATED_SHARE:  # a codec repeated or flattened them
                out["repeated"] += 1
                continue
            sigma = float(np.sqrt(v))
            out["levels"].append(float(mean[sel].mean()))
            out["sigmas"].append(sigma)
            out["counts"].append(int(n))
            out["se"].append(float(se / (2 * sigma)) if sigma > 0 else float("inf"))
    return out


def _blocks(x: np.ndarray, b: int) -> np.ndarray:
    """(N, b*b) blocks of the last two axes of ``x`` (..., H, W) (rows and columns beyond whole blocks dropped)."""
    h, w = x.shape[-2:]
    x = x[..., : h // b * b, : w // b * b]
    x = x.reshape(x.shape[:-2] + (h // b, b, w // b, b))
    return np.swapaxes(x, -3, -2).reshape(-1, b * b)


def _read_at(levels, sigmas, at_dn: float):
    """The noise level function read at ``at_dn`` (DN), or None outside the measured levels (+- half a bin)."""
    if not levels or not levels[0] - NLF_BIN_DN / 2 <= at_dn <= levels[-1] + NLF_BIN_DN / 2:
        return None
    return float(np.interp(at_dn, levels, sigmas))


def noise_level_statistic(frames, method: str | None = None, block: int = NLF_BLOCK_PX, floor_dn: float = 4.0,
                          saturation_dn: float = 220.0, luma: bool = False) -> dict:
    """The noise level function of footage: sigma (DN) against mean (DN) per channel (``luma``: of the frames'
    full-range BT.601 luma alone, JPEG's Y, the one channel ``"luma"``, a stack registered on it; frames or pairs
    of one channel are taken for the luma already).

    ``frames``: a stack (T, H, W, 3) float32 DN, or :class:`lowcam.registration.RegisteredPairs`.
    ``method = "registered"`` (the default for pairs or a stack of 2 frames or more): each frame registered with
    the next, or the one of the next few that nearest-neighbour sampling reads most exactly
    (:func:`lowcam.registration.register_frames`: tracked homography, nearest-neighbour sampling, moving and steep
    pixels left out); in ``block`` x ``block`` blocks of the first frame's grid with at least half their pixels
    compared, the variance of the difference (about its block mean: an exposure step between the frames cancels)
    over 2 is one sample of the noise variance at the block's mean level, with ``n - 1`` degrees of freedom; each
    bin's sigma is the median of its blocks (unbiased for the chi-square spread), so blocks a moving object or
    misregistration lifts do not lift it. A still shot is the case of the identity: its pixels are compared where
    they are. ``"spatial"`` (one frame at a time, the default for one frame): the variance inside blocks about
    their best-fitting plane, whose flattest members (the :data:`SPATIAL_QUANTILE` quantile) give the noise
    [Liu2008, Foi2008]; texture can only lift it and a codec that flattens blocks lowers it. Means outside
    ``floor_dn``-``saturation_dn`` are left out (clipped noise).

    Returns ``{"method", "levels_dn", "sigma_dn", "blocks", "sigma_se_dn": {channel: [per bin]}, "repeated_bins":
    {channel: bins whose pixels a codec repeated or flattened (:data:`REPEATED_SHARE`)}, "sigma_at_dn":
    {"64"|"128"|"192": [r, g, b] or [luma]}}`` (``sigma_at_dn`` interpolated between bins; None where that level
    was not measured: never a value made up outside the measured levels) and, for ``"registered"``, ``pairs`` and
    ``compared`` (the share of pixels compared)."""
    channels = ("luma",) if luma else ("red", "green", "blue")
    if isinstance(frames, RegisteredPairs):
        pairs, method = frames, method or "registered"
        if method != "registered":
            raise ValueError(f"registered pairs are measured by the 'registered' method, not '{method}'")
        if luma and pairs.diff.shape[-1] == 3:  # (one channel: the luma already)
            pairs = RegisteredPairs(bt601_luma(pairs.level)[..., None], bt601_luma(pairs.diff)[..., None],
                                    pairs.registrations, pairs.pairs)
    else:
        x = np.asarray(frames, np.float32)
        if x.ndim == 3:
            x = x[None]
        if luma and x.shape[-1] == 3:
            x = bt601_luma(x)[..., None]
        method = method or ("registered" if len(x) >= 2 else "spatial")
        if method == "registered" and len(x) < 2:
            raise ValueError("a registered noise level function needs at least 2 frames")
        if method == "registered":
            pairs = register_frames(x)
    out = {"method": method, "levels_dn": {}, "sigma_dn": {}, "blocks": {}, "sigma_se_dn": {}, "repeated_bins": {}}
    for c, channel in enumerate(channels):
        if method == "registered":
            d, lv = _blocks(pairs.diff[..., c], block), _blocks(pairs.level[..., c], block)
            n = np.isfinite(d).sum(axis=1)
            ok = n >= block * block // 2
            with np.errstate(invalid="ignore"):
                var = np.nanvar(d[ok], axis=1, ddof=1) / 2
                mean = np.nanmean(lv[ok], axis=1)
            nlf = _binned_nlf(mean, var, n[ok] - 1, 0.5, saturation_dn, min_count=20, floor_dn=floor_dn)
        elif method == "spatial":
            blocks = _blocks(x[..., c], block).astype(np.float64)
            # each block less its best-fitting plane (shading, vignetting), leaving b^2 - 3 degrees of freedom
            yy, xx = np.mgrid[0:block, 0:block]
            design = np.column_stack([np.ones(block * block), xx.ravel() - (block - 1) / 2,
                                      yy.ravel() - (block - 1) / 2])
            resid = blocks - blocks @ np.linalg.pinv(design).T @ design.T
            k = block * block - 3
            nlf = _binned_nlf(blocks.mean(axis=1), (resid ** 2).sum(axis=1) / k, k, SPATIAL_QUANTILE,
                              saturation_dn, min_count=10, floor_dn=floor_dn)
        else:
            raise ValueError(f"unknown noise level method '{method}' (registered or spatial)")
        out["levels_dn"][channel] = nlf["levels"]
        out["sigma_dn"][channel] = nlf["sigmas"]
        out["blocks"][channel] = nlf["counts"]
        out["sigma_se_dn"][channel] = nlf["se"]
        out["repeated_bins"][channel] = nlf["repeated"]
    out["sigma_at_dn"] = {str(m): [_read_at(out["levels_dn"][ch], out["sigma_dn"][ch], m) for ch in channels]
                          for m in HEADLINE_DN}
    if method == "registered":
        out["pairs"] = len(pairs)
        out["compared"] = pairs.compared
    return out


def fit_plate_law(levels, sigmas, se, law: str, floor_dn: float = 0.0) -> tuple[float, float, float]:
    """``(a, b, relative_error)`` of ``law`` fitted to binned (mean, sigma, sigma's standard error) by weighted
    least squares with ``b >= 0`` and the sigma at 0 DN at least ``floor_dn`` (``a >= floor_dn``, or its square
    for the variance law), so the law is above 0 over 0-255 DN: footage shows no black level below its darkest
    bin, and an intercept below the floor would claim dark pixels quieter than their 8-bit rounding. Each bin's
    error is its standard error and :data:`BIN_SCATTER` of the median sigma in quadrature, so that no bin of many
    blocks outweighs the rest; bins more than 25 % off the line (blocks still holding texture or motion) are dropped,
    keeping at least the better half, and the law fitted again (up to four times).

    ``relative_error``: how far the law may be off, relative to the sigma: the root sum of squares of the fit's
    largest standard error over the measured levels and :data:`HEADLINE_DN` (from the bins' standard errors
    alone; a law read beyond the levels measured is extrapolated, and less sure) and of the bins' robust
    deviation from the law (1.4826 times the median absolute relative deviation, over all bins: a law
    that does not describe the bins is no better known than it misses them)."""
    from scipy.optimize import nnls

    m = np.asarray(levels, np.float64)
    s = np.asarray(sigmas, np.float64)
    power = 2 if law == "variance_linear" else 1
    slope = power * s ** (power - 1)  # d(sigma^power) / d(sigma)
    se = np.maximum(np.asarray(se, np.float64), 1e-3 * np.maximum(s, 1e-3)) * slope
    y = s ** power
    ey = np.hypot(se, BIN_SCATTER * power * np.median(y))
    floor = floor_dn ** power
    keep = np.ones(len(m), bool)
    for _ in range(4):
        (a, b), _ = nnls(np.column_stack([np.ones(keep.sum()), m[keep]]) / ey[keep, None],
                         (y[keep] - floor) / ey[keep])
        a += floor
        fit = np.maximum(a + b * m, 1e-9)
        off = np.abs(y - fit) / fit / power
        new = off <= 0.25
        if new.sum() < (len(m) + 1) // 2:  # at least the better half of the bins
            new = off <= np.sort(off)[(len(m) - 1) // 2]
        if (new == keep).all():
            break
        keep = new
    misfit = 1.4826 * float(np.median(np.abs(y - fit) / fit / power))
    try:
        cov = np.linalg.inv((np.column_stack([np.ones(keep.sum()), m[keep]]) / se[keep, None]).T
                            @ (np.column_stack([np.ones(keep.sum()), m[keep]]) / se[keep, None]))
    except np.linalg.LinAlgError:
        return float(a), float(b), float("inf")
    at = np.union1d(m, HEADLINE_DN)  # the measured levels and those a law is read at (extrapolated, if need be)
    grid = np.column_stack([np.ones(len(at)), at])
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", grid, cov, grid), 0.0))
    return float(a), float(b), float(np.hypot((sd / np.maximum(a + b * at, 1e-9) / power).max(), misfit))


def noise_gain(profile, method: str, film, level: float = 0.5, sigma_dn: float = 8.0,
               frames: int = 4, proportions=None) -> list[float]:
    """How the chain after the noise scales it, per channel, as :func:`noise_level_statistic` measures it.

    The profile films a flat grey (``level`` of white) with a constant per-sensel sigma of ``sigma_dn`` and
    without; the statistic's sigma of the difference over ``sigma_dn`` is the gain: the horizontal blur and the
    sharpening (the norm of their kernels), the demosaic's averaging (green's two sensels), colour matrices
    after the noise, chroma subsampling, and (``"spatial"``) the bias of block variances under the noise's
    spatial correlation. Dividing a measured output sigma by it gives the per-sensel law the profile holds.
    ``proportions`` (red, green, blue): the sensels' sigmas are ``sigma_dn`` times these, and the one gain
    returned is the luma's (:func:`noise_level_statistic` with ``luma``): a luma sigma divided by it is the
    sigma that those proportions scale to each channel's.
    A temporal filter (``temporal_noise_reduction``) is in it: the grey is filmed as a sequence, settled first,
    since the filter holds noise from frame to frame and the registered differences of consecutive frames see
    less of it (what it leaves depends on the noise's level: the plate estimate asks again at the footage's). A JPEG at the end of the chain is left out: what it does to noise depends on the scene (it flattens the
    noise of flat blocks and keeps much of a textured block's), which a flat grey cannot tell, so the law read
    through this gain is the noise the frames carried into their coding.
    ``film(profile, make_ideal, seed, frame)``: the profile's frame (float32 DN) of the ideal
    ``make_ideal(width, height)`` (:func:`lowcam.measure.plate.film`; effects do not run the pipeline)."""
    def ideal(width, height):
        out = np.ones((height, width, 4), np.float32)
        out[..., :3] = level
        return out
    scale = (1.0, 1.0, 1.0) if proportions is None else proportions
    law = {"law": "variance_linear", **{ch: [(sigma_dn * k) ** 2, 0.0]
                                        for ch, k in zip(("red", "green", "blue"), scale)}}
    if profile.effect("jpeg") is not None and profile.effect("jpeg").enabled:
        profile = profile.without("jpeg")
    noisy = profile.with_effect("noise", **law)
    clean = film(profile.without("noise") if profile.effect("noise") else profile, ideal)
    h, w = clean.shape[:2]
    crop = (slice(h // 4, 3 * h // 4), slice(w // 4, 3 * w // 4))
    count = frames if method != "spatial" else 1
    following = [e for e in profile.effects if e.enabled and e.follows_previous]
    lead = lead_frames(following)
    shots = np.stack([film(noisy, ideal, seed=1, frame=k) for k in range(count + lead)])
    if following:  # a temporal filter holds noise: the frames in order, settled first
        shots = np.clip(np.rint(shots), 0, 255).astype(np.uint8)
        reach = np.ones(shots.shape[:3], bool)
        for effect in following:
            with plugin_failures(effect):
                shots, reach = effect.finish_frames(shots, reach)
        shots = shots.astype(np.float32)
    diffs = shots[lead:, crop[0], crop[1]] - clean[crop] + 128.0
    stat = noise_level_statistic(diffs, method, luma=proportions is not None)
    gains = [float(np.median(sig)) / sigma_dn if sig else 0.0 for sig in stat["sigma_dn"].values()]
    if min(gains) <= 0:
        raise NotFitted(f"{profile.source}: the chain after the noise leaves none of it (a flat grey filmed with "
                        f"{sigma_dn:g} DN of noise per sensel shows none): no law can be read through it")
    return gains


def channel_proportions(profile) -> list[float]:
    """The sigmas of the profile's noise law at 128 DN, red, green and blue, over green's (1, 1, 1 without a law,
    or where one of them is 0): how a law read on the luma is shared between the channels."""
    noise = profile.effect("noise") if profile is not None else None
    if noise is None:
        return [1.0, 1.0, 1.0]
    sig = [float(noise.sigma(ch, 128.0)) for ch in ("red", "green", "blue")]
    return [1.0, 1.0, 1.0] if min(sig) <= 0 else [v / sig[1] for v in sig]


def _codec_flicker(footage, base, moving: bool) -> tuple[float, str]:
    """(confidence factor, note) for the codec's share of a moving shot's registered noise: 1 for a still shot
    (or frame pairs a whole number of JPEG blocks apart) and for uncoded frames; for JPEG-coded frames (the
    profile's ``jpeg`` effect, which the JPEG probe sets before the noise runs) ``1 - (r - 1) / 0.5`` where ``r``
    is :data:`CODEC_FLICKER` at that quality, clipped to 0..1; 0 where the footage shows an 8x8 grid at a quality
    not measured."""
    if not moving:
        return 1.0, ""
    jpeg = base.effect("jpeg") if base is not None else None
    if jpeg is None or not jpeg.enabled:
        grid = jpeg_blockiness(footage.stack(max_frames=4))
        if min(grid["t_h"], grid["t_v"]) < _GRID_T[0]:
            return 1.0, ""
        return 0.0, ("; the camera moves and the frames show an 8x8 block grid at a quality not measured: a "
                     "block coder's error of a moving scene changes from frame to frame and reads as noise")

    qs = sorted(CODEC_FLICKER)
    ratio = float(np.interp(int(jpeg.quality), qs, [CODEC_FLICKER[q] for q in qs]))
    factor = float(np.clip(1 - (ratio - 1) / 0.5, 0.0, 1.0))
    return factor, (f"; the camera moves, and no two frames within {GRID_WINDOW} of each other lie a whole number "
                    f"of {CODING_GRID_PX} px blocks apart (a camera shifting by whole pixels, neither turning nor "
                    f"zooming): JPEG's coding error (about quality {int(jpeg.quality)}) of a moving scene changes "
                    f"from frame to frame and reads as noise (about {ratio:.2f} x a still shot's)")


class _LumaFrames:
    """A sequence of frames (H, W, 3) read as their BT.601 luma (H, W, 1), one at a time."""

    def __init__(self, frames):
        self.frames = frames

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i) -> np.ndarray:
        return bt601_luma(self.frames[i])[..., None]


def noise_level_function_from_plate(footage, base, film):
    """The noise law per channel from footage, as a :class:`lowcam.plate_estimate.PlateEstimate`.

    Up to :data:`PLATE_PAIRS` frame pairs spread over the shot are registered
    (:func:`lowcam.plate_estimate.register_footage`); where at least :data:`MIN_PAIRS` pairs hold still (no pixel
    moves more than :data:`STILL_PX`) only those are used, since a codec's coding error of a moving scene changes
    from frame to frame. JPEG-coded frames (the profile's ``jpeg`` effect) are registered and measured on their
    luma (:func:`noise_level_statistic` with ``luma``): JPEG codes it at full resolution on its own 8 px grid,
    while it subsamples the chroma and quantises most of the chroma's noise away, so that each channel's own
    noise would read as little more than the luma's, as if the camera had no colour noise (the channels share the
    luma's law in the base profile's proportions, :func:`channel_proportions`, through the luma's gain,
    :func:`noise_gain`). A moving JPEG-coded shot is
    measured on frame pairs a whole number of blocks apart where it has at least :data:`MIN_PAIRS`
    (:func:`lowcam.registration.register_on_grid`, :data:`CODING_GRID_PX`): there the grid falls on the same
    content in both frames and the coding error cancels as in a still shot. :func:`noise_level_statistic`
    measures the registered differences; where they show fewer than :data:`MIN_LEVELS` brightness levels (a shot
    that cannot be registered, or an inter-frame codec that repeats most pixels) the flattest blocks of single
    frames stand in if they show more: a lower envelope that texture lifts, so it is reported, never applied. The
    output-domain noise level function is divided by the base profile's :func:`noise_gain` (what its sharpening,
    blur and demosaic do to per-sensel noise) and fitted with the profile's law, its slope at least 0 and its sigma
    at 0 DN at least the 8-bit rounding's (:data:`ROUNDING_FLOOR_DN2`, the luma's share of it for the luma, through
    the gain; :func:`fit_plate_law`); a law :meth:`Noise.implausible` flags is not applied.

    Confidence, from the measurement's own evidence: ``0.95 (1 - s / 0.25) min(1, levels / 4)``, ``s`` how far
    the fitted sigma may be off (:func:`fit_plate_law`: its standard error from the bins' block counts and
    scatter, and the bins' deviation from the law), times the codec factor of a moving JPEG-coded shot without
    pairs on its grid (:data:`CODEC_FLICKER`). Fewer than :data:`MIN_LEVELS` brightness levels: not measurable.
    ``base``: the profile being refined; ``film``: as :func:`noise_gain` takes it."""
    law = getattr(base.effect("noise"), "law", "sigma_linear")
    jpeg = base.effect("jpeg")
    luma = jpeg is not None and jpeg.enabled
    channels = ("luma",) if luma else ("red", "green", "blue")
    cache: dict = {}
    # JPEG-coded frames are registered and compared on their luma alone: the masks of moving and steep pixels are
    # then the luma's, not a subsampled chroma's (whose coding error a pan changes where the luma's cancels)
    shot = replace(footage, frames=_LumaFrames(footage.frames)) if luma else footage
    pairs = register_footage(shot, PLATE_PAIRS, cache)
    still = [k for k, r in enumerate(pairs.registrations) if r.motion_px < STILL_PX]
    moving = len(still) < MIN_PAIRS
    used = pairs if moving else pairs.select(still)
    on_grid = False
    if luma and moving:
        grid = register_on_grid(shot.frames, pair_starts(len(shot), PLATE_PAIRS), CODING_GRID_PX, cache=cache)
        if len(grid) >= MIN_PAIRS:
            used, on_grid = grid, True
    method = "registered"
    stat = noise_level_statistic(used, method, luma=luma)
    registered_levels = min(len(stat["levels_dn"][ch]) for ch in channels)
    repeated = max(stat["repeated_bins"].values())
    if registered_levels < MIN_LEVELS:  # single frames' flattest blocks instead
        spatial = noise_level_statistic(footage.stack(max_frames=6), "spatial", luma=luma)
        if min(len(spatial["levels_dn"][ch]) for ch in channels) >= MIN_LEVELS:
            method, stat = "spatial", spatial
    measured = {"method": method, "pairs": len(used), "still_pairs": len(still),
                "grid_pairs": len(used) if on_grid else 0, "compared": round(float(used.compared), 3),
                "sigma_at_dn": stat["sigma_at_dn"], "levels_dn": stat["levels_dn"], "sigma_dn": stat["sigma_dn"],
                "blocks": stat["blocks"]}
    levels = min(len(stat["levels_dn"][ch]) for ch in channels)
    if levels < MIN_LEVELS:
        return PlateEstimate.not_measurable(
            "noise_level_function", "noise", measured,
            f"{levels} brightness level{'s' * (levels != 1)} with enough flat blocks (at least {MIN_LEVELS} "
            f"needed to tell the law's intercept from its slope)" + (
                f"; {repeated} more where the codec repeats or flattens pixels" if repeated else ""))
    proportions = channel_proportions(base) if luma else None
    gains = noise_gain(base, method, film, proportions=proportions)
    if any(e.enabled and (e.follows_previous or e.name == "noise_reduction") for e in base.effects):
        # what a temporal filter or an edge-preserving denoiser leaves of the noise depends on its level (the 8-bit
        # rounding, the motion threshold, the range sigma): the gain again at the footage's own per-sensel sigma
        level = float(np.median([np.median(stat["sigma_dn"][ch]) / g for ch, g in zip(channels, gains)]))
        gains = noise_gain(base, method, film, sigma_dn=max(level, 0.5), proportions=proportions)
    params = {"law": law}
    measured["gain"] = gains
    worst = 0.0
    for c, channel in enumerate(channels):
        sig = np.asarray(stat["sigma_dn"][channel]) / gains[c]
        se = np.asarray(stat["sigma_se_dn"][channel]) / gains[c]
        floor = np.sqrt(ROUNDING_FLOOR_DN2 * (np.sum(np.square(LUMA_WEIGHTS)) if luma else 1.0)) / gains[c]
        a, b, rel = fit_plate_law(stat["levels_dn"][channel], sig, se, law, floor)
        worst = max(worst, rel)
        if luma:  # each channel in the base profile's proportions (variance: their squares)
            power = 2 if law == "variance_linear" else 1
            params.update({ch: [a * k ** power, b * k ** power]
                           for ch, k in zip(("red", "green", "blue"), proportions)})
        else:
            params[channel] = [a, b]
    flicker, note = _codec_flicker(footage, base, moving and not on_grid and method == "registered")
    confidence = 0.95 * float(np.clip(1 - worst / 0.25, 0, 1)) * min(1.0, levels / 4) * flicker
    of = "the luma of " if luma else ""
    if method == "spatial":
        confidence = min(confidence, 0.4)
        where = (f"the registered frame pairs ({used.compared:.0%} of their pixels compared) show {registered_levels} "
                 f"brightness level{'s' * (registered_levels != 1)}" + (
                     f" ({repeated} more where the codec repeats or flattens pixels)"
                     if repeated else "") + f": flattest {NLF_BLOCK_PX}x{NLF_BLOCK_PX} blocks of {of}single "
                 "frames instead (texture lifts them: reported only)")
    else:
        if on_grid:
            shifts = sorted({tuple(int(v) for v in r.H[:2, 2]) for r in used.registrations})
            kind = (f"{len(used)} frame pairs a whole number of {CODING_GRID_PX} px blocks apart (moved by "
                    f"{'; '.join(f'{x}, {y}' for x, y in shifts[:3])} px: JPEG's grid falls on the same content "
                    "in both frames, so its coding error cancels as in a still shot)")
        else:
            kind = f"{len(used)} still frame pairs" if not moving else f"{len(used)} registered frame pairs"
        where = f"{of}{kind}, {stat['compared']:.0%} of their pixels compared"
    if repeated and method == "registered":
        where += (f"; {repeated} brightness bin{'s' * (repeated > 1)} left out where the codec repeats pixels "
                  "from frame to frame or flattens them (no noise to measure there)")
    reason = f"{where}, {levels} brightness levels, law within {worst:.0%} of them{note}"
    if luma:
        reason += ("; read on the luma, which JPEG codes at full resolution (it quantises most of the chroma's "
                   "noise away), and shared in the base profile's proportions red : green : blue = "
                   f"{' : '.join(f'{k:.2f}' for k in proportions)}")
    try:
        bad = Noise(True, "plate", None, **params).implausible()
    except ProfileError as e:  # beyond the law's range (the noise of binary frames): no law a camera has
        bad = [str(e)]
    if bad:
        confidence = 0.0
        reason += f"; not applied: {'; '.join(bad)}"
    return PlateEstimate("noise_level_function", "noise", measured, params, round(confidence, 3), reason)


#: Declared after its estimator and statistic, which the module defines below the class.
Noise.plate_probe = PlateProbe(
    "noise_level_function", noise_level_function_from_plate, noise_level_statistic, order=40,
    about="sigma against mean per channel from registered frame pairs (a moving camera, moving objects)",
    compared=("sigma_at_dn",), pairs=True)
