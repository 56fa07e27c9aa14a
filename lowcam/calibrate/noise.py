"""The noise calibration: both noise laws from a stack of frames of a static scene (sec. 4.3).

Contents
--------
- :func:`calibrate_noise`: both noise laws from a stack of frames of a static scene (sec. 4.3)

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

import numpy as np

from ..effects.noise import MIN_LEVELS, brightness_levels, fit_noise
from ..errors import LowcamError
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


def calibrate_noise(patterns, demosaic: str = "block", law: str = "sigma_linear",
                    plot_dir: Path | None = None) -> Calibration:
    frames, names, source = load_checked(patterns, 10, "noise calibration")
    _check_noise_stack(source, frames)
    try:
        fit = fit_noise(np.stack(frames), demosaic)
    except ValueError as e:  # too few pixels in the brightness bins, despite the checks above
        raise LowcamError(f"{source}: {e}") from None
    require_finite(source, "the noise law", sigma_linear_law=fit["sigma_linear"],
                    variance_linear_law=fit["variance_linear"])
    figures = []
    if plot_dir:
        def draw(fig):
            for c, channel in enumerate(("red", "green", "blue")):
                ax = fig.add_subplot(1, 3, c + 1)
                mu, sd = fit["mean"][..., c].ravel(), fit["sigma"][..., c].ravel()
                pick = np.random.default_rng(0).choice(mu.size, min(mu.size, 20000), replace=False)
                ax.plot(mu[pick], sd[pick], ",", color=channel, alpha=0.3)
                x = np.linspace(0, 255, 100)
                k = np.sqrt(2) if channel == "green" and demosaic == "block" else 1.0
                a, b = fit["sigma_linear"][channel]
                ax.plot(x, (a + b * x) / k, "k-", label="sigma linear")
                a, b = fit["variance_linear"][channel]
                ax.plot(x, np.sqrt(a + b * x) / k, "k--", label="variance linear")
                ax.axvline(220, color="grey", lw=0.5)
                ax.set_xlabel("mean (DN)")
                ax.set_ylabel("sigma (DN)")
                ax.set_title(channel)
                ax.legend(fontsize=7)
        figures.append(figure(Path(plot_dir) / "noise.png", draw, (12, 4)))
    chosen = fit[law]
    summary = "noise: " + ", ".join(f"{c} {law} [{a:.3f}, {b:.4f}]" for c, (a, b) in chosen.items())
    return Calibration("noise", summary, {"noise": {"law": law, **chosen}},
                       {"sigma_linear": fit["sigma_linear"], "variance_linear": fit["variance_linear"],
                        "frames": len(frames)}, figures)


#: 4x4 blocks (over all frames) that the 16x16 noise correlations need.
