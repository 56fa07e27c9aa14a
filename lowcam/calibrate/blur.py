"""The blur calibration: horizontal and vertical blur from slanted edges (sec. 4.3).

Contents
--------
- :func:`calibrate_blur`: horizontal and vertical blur from slanted edges (sec. 4.3)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..effects.blur import find_edges, fit_edge_blur
from ..errors import LowcamError
from ..reports import figure
from .checks import MIN_CONTRAST_DN, contrast_dn, load_checked, require_finite
from .outcome import Calibration


def calibrate_blur(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, _, source = load_checked(patterns, 1, "blur calibration")
    grey = np.mean([f.mean(axis=2) for f in frames], axis=0)
    contrast = contrast_dn(grey)
    if contrast < MIN_CONTRAST_DN:
        raise LowcamError(f"{source}: the frames hold no edge (contrast {contrast:.1f} DN), so the blur cannot "
                          f"be measured; use the chart's slanted squares")
    boxes = [b[4] for b in find_edges(grey)]
    found = {k: boxes.count(k) for k in ("vertical", "horizontal")}
    if not all(found.values()):
        raise LowcamError(f"{source}: {found['vertical']} vertical and {found['horizontal']} horizontal slanted "
                          f"edge(s) found, both are needed to measure the blur; use the chart's slanted squares")
    try:
        r = fit_edge_blur(frames)
    except ValueError as e:  # every edge of one orientation failed its fit
        raise LowcamError(f"{source}: {e}") from None
    require_finite(source, "the blur", horizontal_edge_sigma=r["sigma_horizontal_px"],
                    vertical_edge_sigma=r["sigma_vertical_px"], extra_blur=r["extra_horizontal_sensels"])
    figures = []
    if plot_dir:
        def draw(fig):
            from scipy.special import ndtr

            ax = fig.add_subplot(1, 1, 1)
            x = np.linspace(-4, 4, 200)
            for key, label in (("sigma_horizontal_px", "across vertical edges (horizontal)"),
                               ("sigma_vertical_px", "across horizontal edges (vertical)")):
                ax.plot(x, ndtr(x / r[key]), label=f"{label}: sigma {r[key]:.3f} px")
            ax.set_xlabel("distance from the edge (px)")
            ax.set_ylabel("edge spread (fitted)")
            ax.set_title(f"extra horizontal blur {r['extra_horizontal_sensels']:.3f} sensels "
                         f"({r['edges']['vertical']} + {r['edges']['horizontal']} edges)")
            ax.legend(fontsize=8)
        figures.append(figure(Path(plot_dir) / "blur.png", draw))
    return Calibration("blur", f"blur: edge sigma horizontal {r['sigma_horizontal_px']:.3f} px, vertical "
                               f"{r['sigma_vertical_px']:.3f} px -> horizontal blur "
                               f"{r['extra_horizontal_sensels']:.3f} sensels",
                       {"horizontal_blur": {"sigma": r["extra_horizontal_sensels"]}}, r, figures)
