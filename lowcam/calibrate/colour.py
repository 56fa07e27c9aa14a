"""The colour calibration: crosstalk from patch colours, the saturation setting divided out (sec. 4.2, 4.4.2).

The patches' measured colours are fitted as ``measured = M ideal`` (DN), or, where the profile has a tone curve,
as ``measured = black + (white - black) V(M ideal / 255)`` with the curve's ``gamma`` and ``toe_break`` fitted
along (``black_dn`` and ``white_dn`` stay the profile's: the matrix carries the exposure, and the chart's darkest
patch, 3 % of white, cannot tell a black level from a toe). Where each patch's
noise is known (a chart read from frames, :mod:`lowcam.colour_checker`), the fit weighs each patch by it and its
**fit error** is the RMS of the residuals in units of that noise: 1.0 when the model explains the patches down
to their noise (about 0.9 is expected, the fitted parameters taking up some of it).

Contents
--------
- :func:`fit_patch_colours`: the colour matrix (and tone curve) from patch colours, weighted by their noise
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
from ..effects.tone_curve import tone_response
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


def _tone(x, gamma, toe, black, white):
    return tone_response(np.clip(x / 255.0, 0.0, None), gamma, toe, black, white)


def fit_patch_colours(ideal, measured, noise=None, tone: dict | None = None):
    """The colour matrix ``M`` (3x3) with ``measured ~ M ideal`` (both (N, 3); ideal in render units x 255,
    measured in DN), each patch and channel weighed by ``1 / noise`` (None: alike); with ``tone`` (the profile's
    tone curve: ``gamma``, ``toe_break``, ``black_dn``, ``white_dn``) the model is ``tone(M ideal)`` and the
    curve's gamma and toe break are fitted along (its black and white levels kept: the chart's darkest patch, 3 %
    of white, cannot tell a black level from a toe). Returns (M, the fitted tone
    curve's values or None, the residuals (N, 3) divided by the noise)."""
    ideal, measured = np.asarray(ideal, np.float64), np.asarray(measured, np.float64)
    sigma = np.ones_like(measured) if noise is None else np.maximum(np.asarray(noise, np.float64), 1e-3)
    total = fit_colour_matrix(ideal, measured, sigma)
    if tone is None:
        return total, None, (measured - ideal @ total.T) / sigma
    from scipy.optimize import least_squares

    white, black = float(tone["white_dn"]), float(tone["black_dn"])

    def residual(q):
        m = q[:9].reshape(3, 3)
        return ((_tone(ideal @ m.T, q[9], q[10], black, white) - measured) / sigma).ravel()

    best = None
    for gamma, toe in ((float(tone["gamma"]), float(tone["toe_break"])), (2.2, 0.018), (2.2, 0.0), (1.0, 0.0)):
        # the start: the matrix fitted to the measured colours taken back through this start's curve
        grid = np.linspace(0.0, 1.5, 3001) * 255.0
        values = _tone(grid, gamma, toe, black, white)
        order = np.argsort(values)
        back = np.interp(measured, values[order], grid[order])
        m0 = np.linalg.lstsq(ideal, back, rcond=None)[0].T
        start = np.concatenate([m0.ravel(), [gamma, toe]])
        low = np.concatenate([np.full(9, -np.inf), [0.3, 0.0]])
        high = np.concatenate([np.full(9, np.inf), [5.0, 0.3]])
        r = least_squares(residual, np.clip(start, low + 1e-9, high - 1e-9), bounds=(low, high),
                          x_scale=np.concatenate([np.full(9, 0.05), [0.1, 0.005]]))
        if best is None or r.cost < best.cost:
            best = r
    q = best.x
    values = {"gamma": float(q[9]), "toe_break": float(q[10]), "black_dn": black, "white_dn": white}
    return q[:9].reshape(3, 3), values, best.fun.reshape(-1, 3)


def calibrate_colour(ideal_rgb, measured_rgb, saturation: float, plot_dir: Path | None = None,
                     source: str = "colour calibration", noise=None, tone: dict | None = None,
                     usable=None) -> Calibration:
    """Crosstalk from patch colours: ``ideal_rgb`` (N, 3) the light (render units x 255), ``measured_rgb`` the
    camera's mean patch colours (DN) at saturation setting ``saturation``; ``source`` names them in messages.
    ``noise`` (N, 3): each mean's noise (DN), which weighs the fit and makes its error figure (module docstring);
    ``tone``: the profile's tone curve values, fitted along; ``usable`` (N,) False for patches known clipped."""
    # at 0 the saturation matrix is singular; within a hair of 0 dividing it out amplifies rounding a trillionfold
    if not np.isfinite(saturation) or saturation <= 0 or np.linalg.cond(saturation_matrix(saturation)) > 1e6:
        raise LowcamError(f"--saturation {saturation:g}: the patches' saturation setting must be above 0 (at 0 the "
                          f"camera's output is grey and its crosstalk cannot be recovered)")
    ideal_rgb, measured_rgb = np.asarray(ideal_rgb, np.float64), np.asarray(measured_rgb, np.float64)
    bad = ~np.isfinite(ideal_rgb).all(axis=1) | ~np.isfinite(measured_rgb).all(axis=1)
    if bad.any():
        raise LowcamError(f"{source}: patch {int(np.argmax(bad)) + 1} has a missing or non-numeric colour")
    unclipped = (measured_rgb.min(axis=1) > 3) & (measured_rgb.max(axis=1) < 250)  # clipping breaks linearity
    if usable is not None:
        unclipped &= np.asarray(usable, bool)
    needed = 4 if tone is None else 6  # the tone curve's two parameters need two patches more
    if unclipped.sum() < needed:
        raise LowcamError(f"{source}: only {int(unclipped.sum())} patches are free of clipping, {needed} needed")
    ideal_rgb, measured_rgb = ideal_rgb[unclipped], measured_rgb[unclipped]
    noise = None if noise is None else np.asarray(noise, np.float64)[unclipped]
    _check_patch_colours(source, ideal_rgb)
    total, fitted_tone, residual = fit_patch_colours(ideal_rgb, measured_rgb, noise, tone)
    crosstalk = crosstalk_from_colour_matrix(total, saturation)
    require_finite(source, "the crosstalk", colour_matrix=total, crosstalk=crosstalk)
    problems = colour_matrix_problems(crosstalk, "the crosstalk")
    if problems:  # the patches are fine (checked above): the setting divided out is not the one they were taken at
        raise LowcamError(f"{source}: with --saturation {saturation:g} divided out, {problems[0]}, which no camera "
                          f"has; give the saturation setting the patches were captured at")
    predicted = (ideal_rgb @ total.T if fitted_tone is None
                 else _tone(ideal_rgb @ total.T, *(fitted_tone[k] for k in ("gamma", "toe_break", "black_dn",
                                                                            "white_dn"))))
    rms_dn = float(np.sqrt(np.mean((measured_rgb - predicted) ** 2)))
    numbers = {"total_matrix": total.tolist(), "patches_used": int(unclipped.sum()), "rms_residual_dn": rms_dn}
    summary = "colour: crosstalk rows " + "; ".join(" ".join(f"{v:.3f}" for v in row) for row in crosstalk)
    if noise is not None:
        numbers["fit_error"] = float(np.sqrt(np.mean(residual ** 2)))
        summary += f"; fit error {numbers['fit_error']:.2f} (1.0: the patches' noise)"
    else:
        summary += f"; RMS residual {rms_dn:.2f} DN"
    values = {"crosstalk": {"matrix": crosstalk.tolist(), "extra_mixing": 0.0},
              "saturation": {"saturation": saturation}}
    if fitted_tone is not None:
        values["tone_curve"] = fitted_tone
        numbers["tone_curve"] = fitted_tone
        summary += f"; tone curve gamma {fitted_tone['gamma']:.3f}, toe break {fitted_tone['toe_break']:.4f}"
    figures = []
    if plot_dir:
        def draw(fig):
            ax = fig.add_subplot(1, 2, 1)
            for c, colour in enumerate(("red", "green", "blue")):
                ax.plot(np.asarray(measured_rgb)[:, c], predicted[:, c], "o", color=colour, ms=4)
            ax.plot([0, 255], [0, 255], "k--", lw=0.8)
            ax.set_xlabel("measured (DN)")
            ax.set_ylabel("fitted model of ideal (DN)")
            ax = fig.add_subplot(1, 2, 2)
            ax.imshow(crosstalk, cmap="viridis")
            for i in range(3):
                for j in range(3):
                    ax.text(j, i, f"{crosstalk[i, j]:.3f}", ha="center", va="center", color="w")
            ax.set_xticks(range(3), ["r", "g", "b"])
            ax.set_yticks(range(3), ["r^", "g^", "b^"])
            ax.set_title("crosstalk (saturation divided out)")
        figures.append(figure(Path(plot_dir) / "colour.png", draw, (9, 4)))
    return Calibration("colour", summary, values, numbers, figures)
