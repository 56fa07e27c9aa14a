"""The demosaicing calibration: which method, from the noise covariances of a static stack (sec. 4.4.1).

Contents
--------
- :func:`calibrate_demosaic`: which demosaicing, from noise covariances of a static stack (sec. 4.4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..effects.bayer import identify_demosaic
from ..errors import LowcamError
from ..reports import figure
from .checks import identical, load_checked, require_finite
from .outcome import Calibration


_MIN_DEMOSAIC_BLOCKS = 500


def calibrate_demosaic(patterns, geometry, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = load_checked(patterns, 10, "demosaic identification")
    if identical(frames):
        raise LowcamError(f"{source}: the {len(frames)} frames are identical, so they hold no noise to identify "
                          f"the demosaicing from (were they copied from one capture?)")
    h, w = frames[0].shape[:2]
    samples = (h // 4) * (w // 4) * len(frames)
    if samples < _MIN_DEMOSAIC_BLOCKS:
        raise LowcamError(f"{source}: the {len(frames)} frames of {w}x{h} hold {samples} 4x4 blocks, at least "
                          f"{_MIN_DEMOSAIC_BLOCKS} are needed to measure the noise correlations")
    result = identify_demosaic(np.stack(frames), geometry)
    require_finite(source, "the demosaicing", **{f"{m} error": e for m, e in result["errors"].items()})
    figures = []
    if plot_dir:
        def draw(fig):
            cols = ["measured"] + list(result["predicted"])
            for c in range(3):
                for k, col in enumerate(cols):
                    ax = fig.add_subplot(3, len(cols), c * len(cols) + k + 1)
                    m = result["measured"][c] if col == "measured" else result["predicted"][col][c]
                    ax.imshow(m, vmin=-1, vmax=1, cmap="RdBu_r")
                    ax.set_xticks([])
                    ax.set_yticks([])
                    if c == 0:
                        ax.set_title(col if col == "measured" else f"{col} ({result['errors'][col]:.3f})", fontsize=8)
        figures.append(figure(Path(plot_dir) / "demosaic.png", draw, (8, 6)))
    method = "block" if result["best"] == "block" else "bilinear"  # the engine simulates these two
    errors = ", ".join(f"{m} {e:.3f}" for m, e in result["errors"].items())
    return Calibration("demosaic", f"demosaic: best match {result['best']} (errors {errors})",
                       {"demosaic": {"method": method}}, {"best": result["best"], "errors": result["errors"]},
                       figures)
