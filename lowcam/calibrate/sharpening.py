"""The sharpening calibration: from captures at sharpness 0 and at a setting (sec. 4.4.3).

Contents
--------
- :func:`calibrate_sharpening`: sharpening from captures at sharpness 0 and at a setting (sec. 4.4.3)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..effects.blur import gaussian_taps
from ..effects.sharpening import Sharpening, fit_row_filter, fit_sharpening_to_images, frequency_response
from ..errors import LowcamError
from ..reports import figure
from .checks import MIN_CONTRAST_DN, contrast_dn, load_checked, require_finite
from .outcome import Calibration


def calibrate_sharpening(soft_patterns, sharp_patterns, sharpness: float, plot_dir: Path | None = None,
                         taps: int = 101) -> Calibration:
    """Sharpening from two captures of one static scene, at sharpness 0 and at ``sharpness`` (sec. 4.4.3).

    The filter is measured on the red channel at sensel resolution (every other pixel), where the paper found the
    camera sharpens: the free 101-tap filter for the plot, and the 7-tap model fitted to the images themselves
    (the free filter is poorly determined at frequencies the scene and the sensor's blur leave empty).
    """
    if not np.isfinite(sharpness) or sharpness <= 0:
        raise LowcamError(f"--sharpness {sharpness:g}: the sharp captures' setting must be above 0 (the soft "
                          f"captures are at 0), else there is no sharpening to measure")
    soft, soft_names, soft_source = load_checked(soft_patterns, 1, "sharpening calibration (soft)")
    sharp, sharp_names, sharp_source = load_checked(sharp_patterns, 1, "sharpening calibration (sharp)")
    if soft[0].shape != sharp[0].shape:
        raise LowcamError(f"{sharp_names[0]}: the sharp capture is {sharp[0].shape[1]}x{sharp[0].shape[0]}, the "
                          f"soft one ({soft_names[0]}) is {soft[0].shape[1]}x{soft[0].shape[0]}: mixed sizes")
    height, width = soft[0].shape[:2]
    if (width + 1) // 2 < taps:  # a row at sensel resolution must hold the whole filter
        raise LowcamError(f"{soft_source}: the frames are {width}x{height}; the {taps}-tap sharpening filter needs "
                          f"frames at least {2 * taps} px wide")
    s0 = np.mean(soft, axis=0)[::2, ::2, 0]
    s1 = np.mean(sharp, axis=0)[::2, ::2, 0]
    contrast = contrast_dn(s0)
    if contrast < MIN_CONTRAST_DN:
        raise LowcamError(f"{soft_source}: the frames hold no edge (contrast {contrast:.1f} DN in red), so the "
                          f"sharpening filter cannot be measured; use the chart's noise field")
    if np.array_equal(s0, s1):
        raise LowcamError(f"{sharp_source}: the sharp captures equal the soft ones ({soft_source}), so they show "
                          f"no sharpening; capture them at sharpness {sharpness:g}")
    try:
        h = fit_row_filter(s0, s1, taps)
    except np.linalg.LinAlgError:  # the rows hold too little detail for every tap
        raise LowcamError(f"{soft_source}: the rows hold too little detail to determine the {taps}-tap filter "
                          f"(singular system); use the chart's noise field") from None
    a, sigma = fit_sharpening_to_images(s0, s1)
    require_finite(soft_source, "the sharpening", filter=h, strength=a, sigma=sigma)
    figures = []
    if plot_dir:
        def draw(fig):
            model = (1 + a) * gaussian_taps(0, 7, np.float64) - a * gaussian_taps(sigma, 7, np.float64)
            ax = fig.add_subplot(1, 2, 1)
            ax.plot(np.arange(taps) - taps // 2, h, ".-", label=f"measured ({taps} taps)")
            ax.plot(np.arange(7) - 3, model, "o-", label=f"F = I + {a:.2f}(I - L), sigma {sigma:.2f}")
            ax.set_xlim(-15, 15)
            ax.legend(fontsize=7)
            ax.set_title("impulse response (sensels)")
            ax = fig.add_subplot(1, 2, 2)
            ax.plot(*frequency_response(h), label="measured")
            ax.plot(*frequency_response(model), label="7-tap model")
            ax.set_xlabel("cycles / sensel")
            ax.set_title("frequency response")
            ax.legend(fontsize=7)
        figures.append(figure(Path(plot_dir) / "sharpening.png", draw, (10, 4)))
    gain = a / sharpness
    most = Sharpening.params["gain_per_unit"].high
    if gain > most:  # the captures are fine: the setting they are said to be at is not
        raise LowcamError(f"--sharpness {sharpness:g}: the sharp captures ({sharp_source}) sharpen by a = {a:.3f}, "
                          f"{gain:.3g} per unit of setting, beyond the {most:g} of a camera; give the setting they "
                          f"were captured at")
    return Calibration("sharpening", f"sharpening: a = {a:.3f}, sigma = {sigma:.3f} sensels at sharpness "
                                     f"{sharpness:g} (gain per unit {gain:.4f})",
                       {"sharpening": {"sharpness": sharpness, "gain_per_unit": gain, "sigma": sigma}},
                       {"a": a, "sigma": sigma, "filter": h.tolist()}, figures)
