"""The lateral-colour calibration: a grid of red and blue offsets from frames of the noise field (sec. 4.1).

Contents
--------
- :func:`calibrate_chromatic_aberration`: the lateral-colour grid from frames of the noise field (sec. 4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Lucas1981] B. D. Lucas and T. Kanade, "An Iterative Image Registration Technique with an Application to Stereo
  Vision", IJCAI 1981, 674-679.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..captures import refuse_saturated
from ..effects.chromatic_aberration import fit_chromatic_aberration
from ..errors import LowcamError
from ..geometry import grid_points
from ..reports import figure
from .checks import MIN_CONTRAST_DN, contrast_dn, load_checked, require_finite
from .outcome import Calibration, Texture, _write_ca_csv


_CA_PATCH = 30


def calibrate_chromatic_aberration(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = load_checked(patterns, 1, "chromatic-aberration calibration")
    refuse_saturated(frames, names, 0.05)
    h, w = frames[0].shape[:2]
    if min(h, w) < 2 * _CA_PATCH + 4:  # each patch, with its margin, must fit in the frame
        raise LowcamError(f"{source}: the frames are {w}x{h}; aligning {_CA_PATCH}-px patches needs frames of at "
                          f"least {2 * _CA_PATCH + 4}x{2 * _CA_PATCH + 4} px")
    texture = max(contrast_dn(f[..., 1]) for f in frames)
    if texture < MIN_CONTRAST_DN:
        raise LowcamError(f"{source}: the frames hold no texture (contrast {texture:.1f} DN in green), so the "
                          f"colour channels cannot be aligned; use the chart's noise field")
    try:
        grid = fit_chromatic_aberration(frames, patch=_CA_PATCH)
    except ValueError as e:  # some cell of the grid had too little texture in every frame
        raise LowcamError(f"{source}: {e}") from None
    require_finite(source, "the chromatic aberration", offset_grid=grid)
    red, blue = np.hypot(grid[..., 0], grid[..., 1]), np.hypot(grid[..., 2], grid[..., 3])
    figures = []
    if plot_dir:
        def draw(fig):
            ax = fig.add_subplot(1, 1, 1)
            u, v = grid_points((-0.5, -0.5, w - 0.5, h - 0.5), grid.shape[1::-1])
            ax.quiver(u, v, grid[..., 0], -grid[..., 1], color="red", angles="xy", scale_units="xy", scale=0.05)
            ax.quiver(u, v, grid[..., 2], -grid[..., 3], color="blue", angles="xy", scale_units="xy", scale=0.05)
            ax.set_xlim(0, w)
            ax.set_ylim(h, 0)
            ax.set_aspect("equal")
            ax.set_title("red and blue sampling offsets relative to green (x20)")
        figures.append(figure(Path(plot_dir) / "chromatic_aberration.png", draw))
    return Calibration("chromatic_aberration",
                       f"chromatic aberration: {len(frames)} frames, max red {red.max():.2f} px, "
                       f"blue {blue.max():.2f} px",
                       {"chromatic_aberration": {}},
                       {"max_red_px": float(red.max()), "max_blue_px": float(blue.max())}, figures,
                       {"chromatic_aberration": Texture("texture", grid, "chromatic_aberration.csv", _write_ca_csv)})


#: Unsaturated pixels per channel that the noise law's brightness bins need (40 bins of at least 20 pixels).
