"""The noise calibration: both noise laws from a stack of frames of a static scene (sec. 4.3).

Contents
--------
- :func:`calibrate_noise`: both noise laws from a stack of frames of a static scene (sec. 4.3), and the noise's
  grain through a base profile's chain
- :data:`GRAIN_MARGIN`, :data:`GRAIN_LAGS_PX`: how much more a stack's neighbours must correlate than the base's
  white noise makes them for a grain, and the lags (px) its figure shows
- :func:`neighbour_correlation`: the correlation of a stack's temporal noise with its neighbours d pixels away
- :func:`fit_grain`: the noise's grain (px) that makes the base's frames correlate as the stack's, and the factor
  per channel that keeps the noise's level

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

from pathlib import Path

import cv2
import numpy as np

from ..effects.noise import MAX_GRAIN_PX, MIN_LEVELS, brightness_levels, fit_noise
from ..errors import LowcamError
from ..measure.compare import spatial_correlation, temporal_noise
from ..measure.plate import film
from ..reports import figure
from .checks import identical, load_checked, require_finite
from .outcome import Calibration


_MIN_NOISE_PIXELS = 1000


def _check_noise_stack(source: str, frames, saturation_dn: float = 220.0) -> None:
    """A noise law needs temporal noise and at least :data:`~lowcam.effects.noise.MIN_LEVELS` brightness levels
    in every channel (:func:`lowcam.effects.noise.brightness_levels`: bands of 16 DN, or of five times the noise
    left in the means if wider, so that one flat grey never counts as more than two levels)."""
    if identical(frames):
        raise LowcamError(f"{source}: the {len(frames)} frames are identical, so they hold no noise to measure "
                          f"(were they copied from one capture?)")
    stack = np.asarray(frames)
    mean = stack.mean(axis=0)
    sample = stack[:, ::4, ::4].astype(np.float64)  # enough pixels for the typical noise
    for c, channel in enumerate(("red", "green", "blue")):
        mu = mean[..., c].ravel()
        mu = mu[(mu > 2.0) & (mu < saturation_dn)]
        if mu.size == 0:
            raise LowcamError(f"{source}: no {channel} pixel of the noise stack lies between 2 and "
                              f"{saturation_dn:g} DN (all dark or saturated), so the noise law cannot be fitted")
        if mu.size < _MIN_NOISE_PIXELS:
            raise LowcamError(f"{source}: only {mu.size} {channel} pixels of the noise stack lie between 2 and "
                              f"{saturation_dn:g} DN; the noise law needs at least {_MIN_NOISE_PIXELS}")
        levels, step = brightness_levels(mu, sample[..., c].std(axis=0, ddof=1), len(frames), saturation_dn)
        if levels < MIN_LEVELS:
            count = "one brightness level only" if levels == 1 else f"{levels} brightness levels"
            lo, hi = np.percentile(mu, [1, 99])
            raise LowcamError(f"{source}: the noise stack shows {count} in {channel} ({lo:.0f}-{hi:.0f} DN); the "
                              f"noise law needs at least {MIN_LEVELS} levels {step:.0f} DN apart (a static scene "
                              f"with dark to bright areas)")


#: A stack's noise has a grain only where its neighbours correlate by this much more than the base profile's white
#: noise makes them correlate (the demosaicing and the filters after it correlate white noise too).
GRAIN_MARGIN = 0.03
#: The lags (px) at which the calibration's figure shows the noise's correlation.
GRAIN_LAGS_PX = (1, 2, 3, 4)
_MODEL_FRAMES = 4
_GRAIN_STEPS = 10


def neighbour_correlation(frames, lag_px: int = 1) -> float:
    """The correlation of a static stack's temporal noise with the noise ``lag_px`` pixels right and down, the two
    averaged (:func:`lowcam.measure.compare.spatial_correlation`)."""
    return float(np.mean(spatial_correlation(temporal_noise(frames), lag_px)))


def _model_frames(base, noise_values: dict, grain_px: float, scene: np.ndarray) -> np.ndarray:
    """The base profile with this noise filming ``scene`` (the stack's mean frame, DN, as the ideal image: its
    levels, and so the noise's, as the stack's): :data:`_MODEL_FRAMES` frames, the same draws for every grain (so
    that the correlation found rises smoothly with it)."""
    profile = base.with_effect("noise", **noise_values, grain_px=grain_px)

    def ideal(width, height):
        out = np.ones((height, width, 4), np.float32)
        out[..., :3] = cv2.resize(scene, (width, height), interpolation=cv2.INTER_AREA) / 255.0
        return out
    return np.stack([film(profile, ideal, seed=0, frame=f) for f in range(_MODEL_FRAMES)])


def fit_grain(frames, base, noise_values: dict) -> dict:
    """The grain (``grain_px``, the Gaussian sigma in px) that makes ``base`` with the noise law ``noise_values``
    correlate its noise with the neighbours one pixel away as the stack ``frames`` does, by bisection over
    0-:data:`~lowcam.effects.noise.MAX_GRAIN_PX` (the correlation rises with the grain).

    A stack that correlates by less than :data:`GRAIN_MARGIN` more than the base's white noise has none (0).
    The demosaicing and the filters after the noise average a grain away less than white noise, so each channel's
    noise leaves the chain stronger: ``variance_factor`` per channel is the model's output variance with the grain
    over that without it, by which the law's variance is divided to keep the level measured. Returns ``grain_px``,
    ``variance_factor``, ``measured`` and ``white`` (the base's correlation at grain 0) and ``correlation`` per
    lag (:data:`GRAIN_LAGS_PX`) for the stack, the white model and the grainy one."""
    measured = neighbour_correlation(frames)
    scene = np.clip(np.asarray(frames, np.float32).mean(0), 0.0, 255.0)
    white_frames = _model_frames(base, noise_values, 0.0, scene)
    white = neighbour_correlation(white_frames)
    grain, grainy = 0.0, white_frames
    if measured > white + GRAIN_MARGIN:
        low, high = 0.0, MAX_GRAIN_PX
        for _ in range(_GRAIN_STEPS):
            middle = 0.5 * (low + high)
            if neighbour_correlation(_model_frames(base, noise_values, middle, scene)) < measured:
                low = middle
            else:
                high = middle
        grain = round(0.5 * (low + high), 3)
        grainy = _model_frames(base, noise_values, grain, scene)

    def variance(stack):
        return (stack - stack.mean(0)).reshape(-1, 3).var(0)

    factor = variance(grainy) / np.maximum(variance(white_frames), 1e-9)
    return {"grain_px": grain, "measured": measured, "white": white,
            "variance_factor": {c: float(factor[k]) for k, c in enumerate(("red", "green", "blue"))},
            "correlation": {name: [neighbour_correlation(stack, d) for d in GRAIN_LAGS_PX]
                            for name, stack in (("frames", frames), ("white", white_frames), ("grain", grainy))}}


def _keep_level(law_values: dict, law: str, variance_factor: dict) -> dict:
    """The law's coefficients per channel divided so that its variance falls by ``variance_factor``."""
    k = {c: 1.0 / (f if law == "variance_linear" else np.sqrt(f)) for c, f in variance_factor.items()}
    return {c: [a * k[c], b * k[c]] for c, (a, b) in law_values.items()}


def calibrate_noise(patterns, demosaic: str = "block", law: str = "sigma_linear",
                    plot_dir: Path | None = None, base=None) -> Calibration:
    """Both noise laws per channel from a stack of at least 10 frames of a static scene (sec. 4.3). With a
    ``base`` profile (the chain the frames came through), the noise's grain too (:func:`fit_grain`), and the laws
    corrected for it; without one the noise is white, as the paper's."""
    frames, names, source = load_checked(patterns, 10, "noise calibration")
    _check_noise_stack(source, frames)
    stack = np.stack(frames)
    try:
        fit = fit_noise(stack, demosaic)
    except ValueError as e:  # too few pixels in the brightness bins, despite the checks above
        raise LowcamError(f"{source}: {e}") from None
    require_finite(source, "the noise law", sigma_linear_law=fit["sigma_linear"],
                    variance_linear_law=fit["variance_linear"])
    grain = fit_grain(stack, base, {"law": law, **fit[law]}) if base is not None else None
    if grain is not None and grain["grain_px"] > 0.0:
        for name in ("sigma_linear", "variance_linear"):
            fit[name] = _keep_level(fit[name], name, grain["variance_factor"])
    figures = []
    if plot_dir:
        def draw(fig):
            panels = 4 if grain is not None else 3
            for c, channel in enumerate(("red", "green", "blue")):
                ax = fig.add_subplot(1, panels, c + 1)
                mu, sd = fit["mean"][..., c].ravel(), fit["sigma"][..., c].ravel()
                pick = np.random.default_rng(0).choice(mu.size, min(mu.size, 20000), replace=False)
                ax.plot(mu[pick], sd[pick], ",", color=channel, alpha=0.3)
                x = np.linspace(0, 255, 100)
                k = np.sqrt(2) if channel == "green" and demosaic == "block" else 1.0  # the sensels averaged
                if grain is not None:             # a grain's noise is averaged less
                    k /= np.sqrt(grain["variance_factor"][channel])
                a, b = fit["sigma_linear"][channel]
                ax.plot(x, (a + b * x) / k, "k-", label="sigma linear")
                a, b = fit["variance_linear"][channel]
                ax.plot(x, np.sqrt(a + b * x) / k, "k--", label="variance linear")
                ax.axvline(220, color="grey", lw=0.5)
                ax.set_xlabel("mean (DN)")
                ax.set_ylabel("sigma (DN)")
                ax.set_title(channel)
                ax.legend(fontsize=7)
            if grain is not None:
                ax = fig.add_subplot(1, panels, panels)
                labels = {"frames": "frames", "white": "model, white noise",
                          "grain": f"model, grain {grain['grain_px']:.2f} px"}
                for name, style in (("frames", "ko-"), ("white", "b--"), ("grain", "r-")):
                    ax.plot(GRAIN_LAGS_PX, grain["correlation"][name], style, label=labels[name])
                ax.set_xlabel("lag (px)")
                ax.set_ylabel("noise correlation")
                ax.set_title("grain")
                ax.legend(fontsize=7)
        figures.append(figure(Path(plot_dir) / "noise.png", draw, (16 if grain is not None else 12, 4)))
    chosen = fit[law]
    summary = "noise: " + ", ".join(f"{c} {law} [{a:.3f}, {b:.4f}]" for c, (a, b) in chosen.items())
    values = {"law": law, **chosen}
    numbers = {"sigma_linear": fit["sigma_linear"], "variance_linear": fit["variance_linear"], "frames": len(frames)}
    if grain is not None:
        summary += (f"; grain {grain['grain_px']:.2f} px (neighbours correlate {grain['measured']:.2f}, "
                    f"{grain['white']:.2f} with white noise)")
        values["grain_px"] = grain["grain_px"]
        numbers["grain"] = {k: grain[k] for k in ("grain_px", "measured", "white", "variance_factor")}
    return Calibration("noise", summary, {"noise": values}, numbers, figures)


#: 4x4 blocks (over all frames) that the 16x16 noise correlations need.
