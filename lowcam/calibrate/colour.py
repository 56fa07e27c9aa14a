"""The colour calibration: crosstalk from patch colours, the saturation setting divided out (sec. 4.2, 4.4.2).

Contents
--------
- :func:`calibrate_colour`: crosstalk from patch colours, the saturation setting divided out (sec. 4.2, 4.4.2)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..effects.crosstalk import crosstalk_from_colour_matrix, fit_colour_matrix
from ..effects.saturation import colour_matrix_problems, saturation_matrix
from ..errors import LowcamError
from ..reports import figure
from .checks import require_finite
from .outcome import Calibration


def _check_patch_colours(source: str, ideal: np.ndarray) -> None:
    """The colour matrix needs patches whose ideal colours span all three dimensions."""
    singular = np.linalg.svd(ideal, compute_uv=False)
    rank = int((singular > 1e-3 * singular[0]).sum()) if singular[0] > 0 else 0
    if rank < 3:
        if np.ptp(ideal, axis=0).max() <= 1e-6 * max(np.abs(ideal).max(), 1.0):
            how = "have identical colours"
        elif rank <= 1:
            how = "differ in brightness only (one hue)"
        else:
            how = "have colours in one plane (two hues)"
        raise LowcamError(f"{source}: the {len(ideal)} unclipped patches {how}, so the colour matrix is "
                          f"undetermined (rank {rank} of 3)")


def calibrate_colour(ideal_rgb, measured_rgb, saturation: float, plot_dir: Path | None = None,
                     source: str = "colour calibration") -> Calibration:
    """Crosstalk from patch colours: ``ideal_rgb`` (N, 3) the light (render units x 255), ``measured_rgb`` the
    camera's mean patch colours (DN) at saturation setting ``saturation``; ``source`` names them in messages."""
    # at 0 the saturation matrix is singular; within a hair of 0 dividing it out amplifies rounding a trillionfold
    if not np.isfinite(saturation) or saturation <= 0 or np.linalg.cond(saturation_matrix(saturation)) > 1e6:
        raise LowcamError(f"--saturation {saturation:g}: the patches' saturation setting must be above 0 (at 0 the "
                          f"camera's output is grey and its crosstalk cannot be recovered)")
    ideal_rgb, measured_rgb = np.asarray(ideal_rgb, np.float64), np.asarray(measured_rgb, np.float64)
    bad = ~np.isfinite(ideal_rgb).all(axis=1) | ~np.isfinite(measured_rgb).all(axis=1)
    if bad.any():
        raise LowcamError(f"{source}: patch {int(np.argmax(bad)) + 1} has a missing or non-numeric colour")
    unclipped = (measured_rgb.min(axis=1) > 3) & (measured_rgb.max(axis=1) < 250)  # clipping breaks linearity
    if unclipped.sum() < 4:
        raise LowcamError(f"{source}: only {int(unclipped.sum())} patches are free of clipping, 4 needed")
    ideal_rgb, measured_rgb = ideal_rgb[unclipped], measured_rgb[unclipped]
    _check_patch_colours(source, ideal_rgb)
    total = fit_colour_matrix(ideal_rgb, measured_rgb)
    crosstalk = crosstalk_from_colour_matrix(total, saturation)
    require_finite(source, "the crosstalk", colour_matrix=total, crosstalk=crosstalk)
    problems = colour_matrix_problems(crosstalk, "the crosstalk")
    if problems:  # the patches are fine (checked above): the setting divided out is not the one they were taken at
        raise LowcamError(f"{source}: with --saturation {saturation:g} divided out, {problems[0]}, which no camera "
                          f"has; give the saturation setting the patches were captured at")
    figures = []
    if plot_dir:
        def draw(fig):
            ax = fig.add_subplot(1, 2, 1)
            predicted = np.asarray(ideal_rgb) @ total.T
            for c, colour in enumerate(("red", "green", "blue")):
                ax.plot(np.asarray(measured_rgb)[:, c], predicted[:, c], "o", color=colour, ms=4)
            ax.plot([0, 255], [0, 255], "k--", lw=0.8)
            ax.set_xlabel("measured (DN)")
            ax.set_ylabel("fitted matrix x ideal (DN)")
            ax = fig.add_subplot(1, 2, 2)
            ax.imshow(crosstalk, cmap="viridis")
            for i in range(3):
                for j in range(3):
                    ax.text(j, i, f"{crosstalk[i, j]:.3f}", ha="center", va="center", color="w")
            ax.set_xticks(range(3), ["r", "g", "b"])
            ax.set_yticks(range(3), ["r^", "g^", "b^"])
            ax.set_title("crosstalk (saturation divided out)")
        figures.append(figure(Path(plot_dir) / "colour.png", draw, (9, 4)))
    return Calibration("colour", "colour: crosstalk rows " + "; ".join(" ".join(f"{v:.3f}" for v in row)
                                                                      for row in crosstalk),
                       {"crosstalk": {"matrix": crosstalk.tolist(), "extra_mixing": 0.0},
                        "saturation": {"saturation": saturation}}, {"total_matrix": total.tolist()}, figures)
