"""Calibration from measurements (Klein & Murray 2010, sec. 4): captures in, profile parameters and plots out.

Each calibration reads the camera's frames (:mod:`lowcam.captures`), fits the parameters of one effect with that
effect's own fitting code (``lowcam.effects.*``), writes them into a profile (textures beside it), prints a
one-line summary and saves a plot (:mod:`lowcam.reports`). :func:`write_report` gathers the plots and numbers into
an HTML page.

:data:`CALIBRATIONS` is the one table of calibrations: the ``lowcam calibrate`` sub-commands and the manifest's
sections (:func:`run_manifest`) are made from it. Effects name the calibration that measures them
(``Effect.calibration``); :func:`calibration_listing` gathers those declarations.

Contents
--------
- :class:`Texture`: a fitted texture for an effect's path parameter, written beside the profile
- :class:`Calibration`: one calibration's outcome: summary, fitted values, textures, numbers and figures
- :func:`calibrate_lens`: FOV and Brown-Conrady lenses from chessboard or ChArUco views (sec. 4.1)
- :func:`calibrate_vignetting`: the vignetting texture from flat fields (sec. 4.1)
- :func:`calibrate_chromatic_aberration`: the lateral-colour grid from frames of the noise field (sec. 4.1)
- :func:`calibrate_noise`: both noise laws from a stack of frames of a static scene (sec. 4.3)
- :func:`calibrate_demosaic`: which demosaicing, from noise covariances of a static stack (sec. 4.4.1)
- :func:`calibrate_blur`: horizontal and vertical blur from slanted edges (sec. 4.3)
- :func:`calibrate_sharpening`: sharpening from captures at sharpness 0 and at a setting (sec. 4.4.3)
- :func:`calibrate_colour`: crosstalk from patch colours, the saturation setting divided out (sec. 4.2, 4.4.2)
- :func:`calibrate_plate`: a profile from the footage itself, no chart, no ideal (:mod:`lowcam.measure.plate`)
- :func:`apply_to_profile`: a copy of a profile with every calibration's values, textures written beside it
- :func:`write_report`: an HTML page with every calibration's summary, numbers and plots
- :class:`Option`: one input of a calibration: a manifest key and a ``lowcam calibrate`` argument
- :class:`Calibrator`: one calibration, as ``lowcam calibrate <name>`` and a manifest's ``[name]`` section run it
- :data:`CALIBRATIONS`: every calibration by name, in the order a manifest runs them
- :func:`calibrator`: the calibration called ``name`` (or one of its aliases, e.g. ``"ca"``)
- :func:`calibration_listing`: each calibration with the effects that declare it
- :func:`run_manifest`: run every calibration a manifest lists; returns (base profile, calibrations)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Zhang2000] Z. Zhang, "A Flexible New Technique for Camera Calibration", IEEE TPAMI 22(11), 1330-1334, 2000.
- [Devernay2001] F. Devernay and O. Faugeras, "Straight lines have to be straight", Machine Vision and Applications
  13(1), 14-24, 2001.
- [Klein2007] G. Klein and D. Murray, "Parallel Tracking and Mapping for Small AR Workspaces", ISMAR 2007 (PTAM).
- [Brown1966] D. C. Brown, "Decentering Distortion of Lenses", Photogrammetric Engineering 32(3), 444-462, 1966.
- [Lucas1981] B. D. Lucas and T. Kanade, "An Iterative Image Registration Technique with an Application to Stereo
  Vision", IJCAI 1981, 674-679.
- [Irie2008] K. Irie, A. E. McKinnon, K. Unsworth and I. M. Woodhead, "A Model for Measurement of Noise in CCD
  Digital-Video Cameras", Measurement Science and Technology 19(4), 2008.
- [EMVA1288] EMVA Standard 1288, "Standard for Characterization of Image Sensors and Cameras", release 4.0, 2021
  (photon transfer).
"""
from __future__ import annotations

import argparse
import html
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from ..arguments import Number, Reads, Text
from ..captures import (chart_patch_colours, detect_target, expand_paths, load_frames, parse_target,  # noqa: F401
                        read_patches_csv, refuse_saturated, srgb_to_linear)
from ..effects import known_effects
from ..effects.bayer import identify_demosaic
from ..effects.blur import find_edges, fit_edge_blur, gaussian_taps
from ..effects.chromatic_aberration import fit_chromatic_aberration, write_ca_grid
from ..effects.crosstalk import crosstalk_from_colour_matrix, fit_colour_matrix
from ..effects.lens import fit_lens
from ..effects.noise import MIN_LEVELS, brightness_levels, fit_noise
from ..effects.saturation import colour_matrix_problems, saturation_matrix
from ..effects.sharpening import Sharpening, fit_row_filter, fit_sharpening_to_images, frequency_response
from ..effects.vignetting import fit_vignetting
from ..errors import LowcamError
from ..geometry import grid_points
from ..io import make_output_folder, write_png
from ..measure import plate
from ..plate_estimate import format_value
from ..profile import load_profile
from ..reports import figure, image, numbers_block, write_page
from ..schema import read_toml


@dataclass
class Texture:
    """A fitted texture for the effect parameter ``param`` (a path): :func:`apply_to_profile` saves ``data`` as
    ``file`` beside the profile with ``write(path, data, camera)`` and points the parameter at it."""

    param: str
    data: np.ndarray
    file: str
    write: Callable[[Path, np.ndarray, Any], None]


@dataclass
class Calibration:
    """One calibration's outcome: ``summary`` (one line), fitted ``values`` per effect, ``textures`` per effect
    (:class:`Texture`), ``numbers`` for the report, ``figures`` (PNG paths), ``provenance`` entries for the
    profile's ``[provenance]`` table (``"effect.param"``: where the number came from), ``notes`` (lines for the
    terminal and the report) and ``table`` (rows of a table in the report, one dict of column: text each)."""

    what: str
    summary: str
    values: dict[str, dict] = field(default_factory=dict)
    numbers: dict = field(default_factory=dict)
    figures: list[Path] = field(default_factory=list)
    textures: dict[str, Texture] = field(default_factory=dict)
    provenance: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    table: list[dict] = field(default_factory=list)


def _write_gain_png(path: Path, gain: np.ndarray, camera) -> None:
    write_png(path, np.round(gain * 65535).astype(np.uint16))


def _write_ca_csv(path: Path, grid: np.ndarray, camera) -> None:
    write_ca_grid(path, grid, camera.width, camera.height)


# --- checks shared by the calibrations -----------------------------------------------------------------------------
# A calibration refuses input that cannot determine what it fits, before it writes anything (plots included).

def _source(patterns) -> str:
    """The input as named on the command line or in the manifest, for messages: a few names, or the first and
    last of many."""
    names = [str(p) for p in patterns]
    if len(names) <= 3:
        return " ".join(names) or "(no frames)"
    return f"{names[0]} ... {names[-1]} ({len(names)} names)"


def _load(patterns, min_frames: int, what: str):
    """(frames, names, source) of a calibration's frames; too few, unreadable or mixed sizes are refused."""
    patterns = list(patterns)
    source = _source(patterns)
    frames, names = load_frames(patterns, min_frames, f"{source}: {what}")
    return frames, names, source


def _contrast(image) -> float:
    """Spread (1st to 99th percentile, DN) of an image lightly smoothed, so that pixel noise alone shows little."""
    smooth = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 1.0)
    lo, hi = np.percentile(smooth, [1, 99])
    return float(hi - lo)


def _identical(frames) -> bool:
    return all(np.array_equal(f, frames[0]) for f in frames[1:])


def _all_finite(value) -> bool:
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    return bool(np.isfinite(np.asarray(value, np.float64)).all())


def _require_finite(source: str, what: str, **fitted) -> None:
    """Refuse a fit whose values came out NaN or infinite: ``what`` names what stays undetermined."""
    for name, value in fitted.items():
        if not _all_finite(value):
            raise LowcamError(f"{source}: the fitted {name.replace('_', ' ')} is not finite, so {what} is "
                              f"undetermined")


#: Below this contrast (DN, :func:`_contrast`) a frame holds no edge or texture to measure.
_MIN_CONTRAST_DN = 10.0


# --- the calibrations ---------------------------------------------------------------------------------------------

def _distinct_views(points, tolerance_px: float = 0.5) -> int:
    """How many of the target's detections differ (by more than ``tolerance_px`` at some corner)."""
    kept: list[np.ndarray] = []
    for p in points:
        if not any(k.shape == p.shape and np.abs(k - p).max() <= tolerance_px for k in kept):
            kept.append(p)
    return len(kept)


def calibrate_lens(patterns, target: str = "checkerboard:9x6:0.025", models=("fov", "opencv"),
                   plot_dir: Path | None = None) -> Calibration:
    frames, names, source = _load(patterns, 3, "lens calibration")
    spec = parse_target(target)
    obj, img, used, missing = [], [], [], []
    for f, n in zip(frames, names):
        found = detect_target(f, spec)
        if found is None:
            missing.append(n)
            continue
        obj.append(found[0])
        img.append(found[1])
        used.append(n)
    notes = [f"{n}: {target} not found, frame skipped" for n in missing]
    if len(used) < 3:
        raise LowcamError(f"{source}: the target ({target}) was found in {len(used)} frame(s), at least 3 are "
                          f"needed" + (f"; not found in {', '.join(Path(m).name for m in missing)}" if missing
                                       else ""))
    views = _distinct_views(img)
    if views < 3:
        raise LowcamError(f"{source}: the target ({target}) shows {views} distinct view(s) in {len(used)} frames, "
                          f"so the lens is undetermined; at least 3 views from different angles are needed")
    h, w = frames[0].shape[:2]
    fits = {}
    for m in models:
        try:
            fits[m] = fit_lens(obj, img, (w, h), m)
        except cv2.error:  # OpenCV's initial calibration failed on these views
            raise LowcamError(f"{source}: OpenCV cannot calibrate from these {len(used)} views of the target "
                              f"({target}); tilt the board more between frames") from None
        _require_finite(source, f"the {m} lens", **{f"{m} lens": fits[m].params, "RMS error": fits[m].rms})
    best = min(fits, key=lambda m: fits[m].rms)
    numbers = {"frames_used": len(used), "skipped": notes}
    for m, fit in fits.items():
        numbers[m] = {"rms_px": fit.rms, "per_frame_rms_px": dict(zip((Path(u).name for u in used),
                                                                       fit.per_frame_rms)), **fit.params}
    figures = []
    if plot_dir:
        def draw(fig):
            for k, (m, fit) in enumerate(fits.items()):
                ax = fig.add_subplot(1, len(fits), k + 1)
                pts = np.concatenate(img)
                res = np.concatenate(fit.residuals)
                ax.quiver(pts[:, 0], pts[:, 1], res[:, 0], -res[:, 1], np.hypot(res[:, 0], res[:, 1]),
                          angles="xy", scale_units="xy", scale=0.01, cmap="viridis")
                ax.set_xlim(0, w)
                ax.set_ylim(h, 0)
                ax.set_aspect("equal")
                ax.set_title(f"{m}: RMS {fit.rms:.3f} px (arrows x100)")
        figures.append(figure(Path(plot_dir) / "lens_residuals.png", draw, (11, 4.5)))
    summary = (f"lens: {len(used)}/{len(frames)} frames, " +
               ", ".join(f"{m} RMS {fits[m].rms:.3f} px" for m in fits) + f"; profile gets {best}")
    return Calibration("lens", summary, {"lens_distortion": {"model": best, **fits[best].params}}, numbers,
                       figures)


#: Flat fields darker than this (DN, 99th percentile) cannot show the fall-off.
_MIN_FLAT_DN = 10.0


def calibrate_vignetting(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = _load(patterns, 1, "vignetting calibration")
    refuse_saturated(frames, names)
    level = float(np.percentile(np.mean(frames, axis=(0, 3)), 99))
    if level < _MIN_FLAT_DN:
        raise LowcamError(f"{source}: the flat fields are dark ({level:.1f} DN at the 99th percentile, "
                          f"{_MIN_FLAT_DN:g} needed), so the vignetting cannot be measured; raise the exposure")
    gain = fit_vignetting(frames)
    _require_finite(source, "the vignetting", gain_texture=gain)
    corners = float(np.mean([gain[0, 0], gain[0, -1], gain[-1, 0], gain[-1, -1]]))
    figures = []
    if plot_dir:
        def draw(fig):
            ax = fig.add_subplot(1, 2, 1)
            im = ax.imshow(gain, cmap="gray", vmin=0, vmax=1)
            fig.colorbar(im, ax=ax)
            ax.set_title("gain texture (80x60)")
            ax = fig.add_subplot(1, 2, 2)
            yy, xx = np.mgrid[0:gain.shape[0], 0:gain.shape[1]]
            r = np.hypot((xx + 0.5) / gain.shape[1] - 0.5, ((yy + 0.5) / gain.shape[0] - 0.5) * 0.75)
            ax.plot(r.ravel() / r.max(), gain.ravel(), ".", ms=2)
            ax.set_xlabel("radius / corner radius")
            ax.set_ylabel("gain")
            ax.set_title("radial fall-off")
        figures.append(figure(Path(plot_dir) / "vignetting.png", draw, (10, 4)))
    return Calibration("vignetting", f"vignetting: {len(frames)} flat fields, corner gain {corners:.3f}",
                       {"vignetting": {}}, {"corner_gain": corners, "frames": len(frames)}, figures,
                       {"vignetting": Texture("texture", gain, "vignetting.png", _write_gain_png)})


#: The Lucas-Kanade patch (px) that aligns red and blue to green.
_CA_PATCH = 30


def calibrate_chromatic_aberration(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = _load(patterns, 1, "chromatic-aberration calibration")
    refuse_saturated(frames, names, 0.05)
    h, w = frames[0].shape[:2]
    if min(h, w) < 2 * _CA_PATCH + 4:  # each patch, with its margin, must fit in the frame
        raise LowcamError(f"{source}: the frames are {w}x{h}; aligning {_CA_PATCH}-px patches needs frames of at "
                          f"least {2 * _CA_PATCH + 4}x{2 * _CA_PATCH + 4} px")
    texture = max(_contrast(f[..., 1]) for f in frames)
    if texture < _MIN_CONTRAST_DN:
        raise LowcamError(f"{source}: the frames hold no texture (contrast {texture:.1f} DN in green), so the "
                          f"colour channels cannot be aligned; use the chart's noise field")
    try:
        grid = fit_chromatic_aberration(frames, patch=_CA_PATCH)
    except ValueError as e:  # some cell of the grid had too little texture in every frame
        raise LowcamError(f"{source}: {e}") from None
    _require_finite(source, "the chromatic aberration", offset_grid=grid)
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
_MIN_NOISE_PIXELS = 1000


def _check_noise_stack(source: str, frames, saturation_dn: float = 220.0) -> None:
    """A noise law needs temporal noise and at least :data:`~lowcam.effects.noise.MIN_LEVELS` brightness levels
    in every channel (:func:`lowcam.effects.noise.brightness_levels`: bands of 16 DN, or of five times the noise
    left in the means if wider, so that one flat grey never counts as more than two levels)."""
    if _identical(frames):
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
    frames, names, source = _load(patterns, 10, "noise calibration")
    _check_noise_stack(source, frames)
    try:
        fit = fit_noise(np.stack(frames), demosaic)
    except ValueError as e:  # too few pixels in the brightness bins, despite the checks above
        raise LowcamError(f"{source}: {e}") from None
    _require_finite(source, "the noise law", sigma_linear_law=fit["sigma_linear"],
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
_MIN_DEMOSAIC_BLOCKS = 500


def calibrate_demosaic(patterns, geometry, plot_dir: Path | None = None) -> Calibration:
    frames, names, source = _load(patterns, 10, "demosaic identification")
    if _identical(frames):
        raise LowcamError(f"{source}: the {len(frames)} frames are identical, so they hold no noise to identify "
                          f"the demosaicing from (were they copied from one capture?)")
    h, w = frames[0].shape[:2]
    samples = (h // 4) * (w // 4) * len(frames)
    if samples < _MIN_DEMOSAIC_BLOCKS:
        raise LowcamError(f"{source}: the {len(frames)} frames of {w}x{h} hold {samples} 4x4 blocks, at least "
                          f"{_MIN_DEMOSAIC_BLOCKS} are needed to measure the noise correlations")
    result = identify_demosaic(np.stack(frames), geometry)
    _require_finite(source, "the demosaicing", **{f"{m} error": e for m, e in result["errors"].items()})
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


def calibrate_blur(patterns, plot_dir: Path | None = None) -> Calibration:
    frames, _, source = _load(patterns, 1, "blur calibration")
    grey = np.mean([f.mean(axis=2) for f in frames], axis=0)
    contrast = _contrast(grey)
    if contrast < _MIN_CONTRAST_DN:
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
    _require_finite(source, "the blur", horizontal_edge_sigma=r["sigma_horizontal_px"],
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
    soft, soft_names, soft_source = _load(soft_patterns, 1, "sharpening calibration (soft)")
    sharp, sharp_names, sharp_source = _load(sharp_patterns, 1, "sharpening calibration (sharp)")
    if soft[0].shape != sharp[0].shape:
        raise LowcamError(f"{sharp_names[0]}: the sharp capture is {sharp[0].shape[1]}x{sharp[0].shape[0]}, the "
                          f"soft one ({soft_names[0]}) is {soft[0].shape[1]}x{soft[0].shape[0]}: mixed sizes")
    height, width = soft[0].shape[:2]
    if (width + 1) // 2 < taps:  # a row at sensel resolution must hold the whole filter
        raise LowcamError(f"{soft_source}: the frames are {width}x{height}; the {taps}-tap sharpening filter needs "
                          f"frames at least {2 * taps} px wide")
    s0 = np.mean(soft, axis=0)[::2, ::2, 0]
    s1 = np.mean(sharp, axis=0)[::2, ::2, 0]
    contrast = _contrast(s0)
    if contrast < _MIN_CONTRAST_DN:
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
    _require_finite(soft_source, "the sharpening", filter=h, strength=a, sigma=sigma)
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
    _require_finite(source, "the crosstalk", colour_matrix=total, crosstalk=crosstalk)
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


# --- a profile from the plate itself --------------------------------------------------------------

def _plate_figures(estimates, plot_dir: Path, base) -> list[Path]:
    """One plot per estimate that has something to draw: the noise level function, the edge profiles, the radial
    fall-off and the gyro's angular velocity, each beside the base profile's model where it was measured."""
    figures = []
    channels = ("red", "green", "blue")
    colours = ("tab:red", "tab:green", "tab:blue")
    for est in estimates:
        m, model = est.measured, est.model or {}
        if est.statistic == "noise_level_function" and m.get("levels_dn"):
            def draw(fig, m=m, model=model, est=est):
                ax = fig.add_subplot(1, 1, 1)
                for ch, col in zip(channels + ("luma",), colours + ("black",)):  # JPEG-coded footage: its luma
                    if ch not in m["levels_dn"]:
                        continue
                    ax.plot(m["levels_dn"][ch], m["sigma_dn"][ch], "o", color=col, ms=4, label=f"footage {ch}")
                    if model.get("levels_dn", {}).get(ch):
                        ax.plot(model["levels_dn"][ch], model["sigma_dn"][ch], "-", color=col, alpha=0.6,
                                label=f"base profile {ch}")
                ax.set_xlabel("mean (DN)")
                ax.set_ylabel("noise sigma (DN, as delivered)")
                ax.set_title(f"noise level function ({m['method']}), confidence {est.confidence:.2f}")
                ax.legend(fontsize=7)
            figures.append(figure(plot_dir / "plate-noise.png", draw))
        elif est.statistic == "edge_profile" and m.get("across_x", {}).get("profile"):
            def draw(fig, m=m, model=model, est=est):
                for k, (key, what) in enumerate((("across_x", "across near-vertical edges (rows)"),
                                                 ("across_y", "across near-horizontal edges (columns)"))):
                    ax = fig.add_subplot(1, 2, k + 1)
                    if m[key].get("profile"):
                        ax.plot(m[key]["offsets_px"], m[key]["profile"], label=f"footage ({m[key]['edges']} edges)")
                    if model.get(key, {}).get("profile"):
                        ax.plot(model[key]["offsets_px"], model[key]["profile"], "--", label="base profile")
                    ax.set_xlabel("px from the edge")
                    ax.set_title(what, fontsize=9)
                    ax.legend(fontsize=7)
            figures.append(figure(plot_dir / "plate-edges.png", draw, (10, 4)))
        elif est.statistic == "radial_falloff" and "c2" in m:
            def draw(fig, m=m, est=est):
                ax = fig.add_subplot(1, 1, 1)
                r = np.linspace(0, 1, 50)
                ax.plot(r, np.exp(m["c2"] * r ** 2 + m["c4"] * r ** 4), label="footage")
                vig = base.effect("vignetting")
                if vig is not None:  # the base's gain texture (or radial model) against radius
                    w, h = base.camera.width, base.camera.height
                    gain = vig.gain_texture(w, h)
                    rows, cols = gain.shape
                    yy, xx = np.mgrid[0:rows, 0:cols]
                    rho = np.hypot((xx + 0.5) * w / cols - w / 2, (yy + 0.5) * h / rows - h / 2) / (np.hypot(w, h) / 2)
                    ax.plot(rho.ravel(), gain.ravel(), ".", ms=1, alpha=0.4, label="base profile")
                ax.set_xlabel("radius / half-diagonal")
                ax.set_ylabel("gain")
                ax.set_title(f"vignetting, confidence {est.confidence:.2f}")
                ax.legend()
            figures.append(figure(plot_dir / "plate-vignetting.png", draw))
        elif est.statistic == "gyro_motion" and m.get("angular_velocity_rad_s"):
            def draw(fig, m=m):
                ax = fig.add_subplot(1, 1, 1)
                w = np.array([v if v is not None else [np.nan] * 3 for v in m["angular_velocity_rad_s"]])
                for k, (axis, col) in enumerate(zip("xyz", colours)):
                    ax.plot(w[:, k], color=col, label=f"w{axis}")
                ax.set_xlabel("frame")
                ax.set_ylabel("rad/s (gyro axes)")
                ax.legend()
            figures.append(figure(plot_dir / "plate-gyro.png", draw))
    return figures


def calibrate_plate(footage, base, gyro: str | None = None, fps: float | None = None,
                    min_confidence: float | None = None, plot_dir: Path | None = None,
                    progress: bool | None = None) -> Calibration:
    """A profile from the footage itself: :func:`lowcam.measure.plate.estimate_profile` on
    ``footage`` (a video file, a folder of frames, or frame names or patterns), starting from ``base``. Confident
    estimates become the calibration's values, each with a ``[provenance]`` entry; the others are listed, not
    written; footage from which nothing can be estimated is refused (one line with every estimate's reason). With
    ``plot_dir`` the base profile films similar content (:func:`lowcam.measure.plate.model_statistics`) and each
    statistic is plotted beside the model's. ``progress`` (stderr; default: when stderr is a terminal)."""
    progress = sys.stderr.isatty() if progress is None else progress

    names = [str(f) for f in ([footage] if isinstance(footage, (str, Path)) else footage)]
    if len(names) == 1 and not any(c in names[0] for c in "*?["):
        shot = plate.read_footage(names[0], fps=fps, gyro=gyro)
    else:
        frames, names_read, source = _load(names, plate.MIN_FRAMES, "plate estimation")
        shot = plate.Footage(np.stack(frames), fps or 30.0, source, names=names_read)
        if gyro:
            shot.gyro, shot.frame_times = plate.read_phone_gyro(gyro)
    threshold = plate.MIN_CONFIDENCE if min_confidence is None else float(min_confidence)
    profile, estimates = plate.estimate_profile(shot, base, progress=progress, min_confidence=threshold)
    if not any(e.applied for e in estimates):
        raise LowcamError(f"{shot.path}: nothing could be estimated from the plate: "
                          + "; ".join(f"{e.statistic}: {'' if e.measurable else 'not measurable, '}{e.reason}"
                                      for e in estimates))
    values: dict[str, dict] = {}
    for est in estimates:
        if est.applied:
            for key, value in est.params.items():
                effect, param = plate._target(est, key)
                values.setdefault(effect, {})[param] = value
    values["camera"] = {"name": profile.camera.name}
    provenance = {k: v for k, v in profile.provenance.items() if base.provenance.get(k) != v}
    figures = []
    if plot_dir:
        if progress:
            print("the base profile filming similar content", file=sys.stderr, flush=True)
        plate.model_statistics(shot, base, estimates)
        figures = _plate_figures(estimates, Path(plot_dir), base)
    numbers = {est.statistic: {"effect": est.effect, "measurable": est.measurable,
                               "confidence": est.confidence if est.measurable else None, "reason": est.reason,
                               "applied": est.applied, "params": est.params, "base_params": est.base_params,
                               "footage": plate.headline(est.measured),
                               "model": None if est.model is None else plate.headline(est.model)}
               for est in estimates}
    applied = [e.statistic for e in estimates if e.applied]
    summary = (f"plate {shot.path}: {len(shot)} frames {shot.shape[1]}x{shot.shape[0]}; applied "
               f"{', '.join(applied) or 'nothing'}; {len(estimates) - len(applied)} reported only")
    def flat(d, prefix=""):
        out = []
        for k, v in (d or {}).items():
            if isinstance(v, dict):
                out += flat(v, f"{prefix}{k}.")
            else:
                out.append(f"{prefix}{k} = {format_value(v)}")
        return "; ".join(out) if not prefix else out

    table = [{"statistic": e.statistic, "effect": e.effect,
              "confidence": f"{e.confidence:.2f}" if e.measurable else "not measurable", "why": e.reason,
              "footage": flat(plate.headline(e.measured)) or "-",
              "base profile on similar content": "-" if e.model is None else (flat(plate.headline(e.model)) or "-"),
              "estimated": flat(e.params) or "-", "base profile's values": flat(e.base_params) or "-",
              "written": "yes" if e.applied else "no"} for e in estimates]
    return Calibration("plate", summary, values, numbers, figures, provenance=provenance,
                       notes=[e.line() for e in estimates], table=table)


# --- profiles and reports --------------------------------------------------------------------------------------------

def apply_to_profile(profile, calibrations, out_path: Path):
    """A copy of ``profile`` with every calibration's values, textures written beside ``out_path``."""
    out_path = Path(out_path).resolve()
    tex_dir = out_path.parent / out_path.stem
    new = profile
    for cal in calibrations:
        for name in list(cal.values) + [n for n in cal.textures if n not in cal.values]:
            values = dict(cal.values.get(name, {}))
            if name == "camera":  # the camera's own settings (a plate profile's name)
                new = new.copy()
                for key, value in values.items():
                    setattr(new.camera, key, value)
                continue
            if values.get("enabled", True) is False:  # an effect the calibration turns off
                new = new.without(name) if new.effect(name) is not None else new
                continue
            texture = cal.textures.get(name)
            if texture is not None:
                path = tex_dir / texture.file
                texture.write(path, texture.data, new.camera)
                values[texture.param] = str(path)
            new = new.with_effect(name, replace=(name == "lens_distortion"), source=str(out_path),
                                  base_dir=out_path.parent, **values)
        new.provenance.update(cal.provenance)
    new = new.copy()
    new.path = out_path
    return new


def write_report(calibrations, folder) -> Path:
    """An HTML page with every calibration's summary, numbers and plots."""
    sections = []
    for cal in calibrations:
        sections.append(f"<h2>{html.escape(cal.what)}</h2><p><b>{html.escape(cal.summary)}</b></p>")
        if cal.notes:
            sections.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in cal.notes) + "</ul>")
        if cal.table:
            head = "".join(f"<th>{html.escape(k)}</th>" for k in cal.table[0])
            rows = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row.values()) + "</tr>"
                           for row in cal.table)
            sections.append(f"<table border='1' cellpadding='4' style='border-collapse:collapse;font-size:90%'>"
                            f"<tr>{head}</tr>{rows}</table>")
        sections.extend(image(folder, fig, cal.what) for fig in cal.figures)
        sections.append(numbers_block(cal.numbers, "numbers and fit quality"))
    return write_page(folder, "Lowcam calibration", "Lowcam calibration report", sections)


# --- the table of calibrations ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Option:
    """One input of a calibration: a key of its manifest section and an argument of its ``lowcam calibrate``
    sub-command (``--key``, or a positional argument).

    ``kind``: ``"frames"`` (file names or glob patterns; at least one if ``required``), ``"path"`` (one file),
    ``str``, or a declared number (:class:`lowcam.arguments.Number`: its range holds on the command line and in a
    manifest alike). In a manifest, frames and paths are relative to the manifest and a key left
    out takes ``default`` (an error if it has none and is ``required``); on the command line a ``required`` option
    must be given.
    """

    key: str
    kind: Any = str
    default: Any = None
    required: bool = False
    positional: bool = False
    choices: tuple[str, ...] | None = None
    help: str | None = None

    def add_argument(self, parser) -> None:
        if self.kind == "frames":
            nargs = "+" if self.required else "*"
            if self.positional:
                parser.add_argument(self.key, nargs=nargs, type=Reads("files"), help=self.help)
            else:
                parser.add_argument(self.flag, dest=self.key, nargs=nargs, type=Reads("files"),
                                    required=self.required, help=self.help)
            return
        kw = {"help": self.help, "choices": self.choices}
        if self.kind == "path":
            kw["type"] = Reads("file")
        elif self.kind is str:
            kw["type"] = Text(self.choices, what=self.key)
        else:
            kw["type"] = self.kind
        if self.positional:
            parser.add_argument(self.key, **kw)
            return
        if self.required:
            kw["required"] = True
        elif self.default is not None:
            kw["default"] = self.default
        parser.add_argument(self.flag, dest=self.key, **kw)

    @property
    def flag(self) -> str:
        return "--" + self.key.replace("_", "-")

    def from_manifest(self, section: dict, where: str, folder: Path):
        """This option's value from a manifest section: types checked, and every frame pattern and path must
        name existing files (relative to ``folder``); each problem is one line naming ``where`` and the key."""
        value = section.get(self.key)
        if self.kind == "frames":
            if value is None or value == "" or value == []:
                if self.required:
                    raise LowcamError(f"{where} needs '{self.key}'")
                return []
            names = [value] if isinstance(value, str) else value
            if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
                raise LowcamError(f"{where}: '{self.key}' must be a file name or pattern, or a list of them, got "
                                  f"{value!r}")
            for name in names:
                if not any(p.is_file() for p in expand_paths([folder / name])):
                    raise LowcamError(f"{where}: '{self.key}' entry {name!r} matches no file in {folder}")
            return [str(folder / n) for n in names]
        if value is None:
            if self.default is None and self.required:
                raise LowcamError(f"{where} needs '{self.key}'")
            return self.default
        if self.kind in ("path", str) and not isinstance(value, str):
            raise LowcamError(f"{where}: '{self.key}' must be a string, got {value!r}")
        if self.kind == "path":
            if not (folder / value).is_file():
                raise LowcamError(f"{where}: '{self.key}' = {value!r}: no such file in {folder}")
            return str(folder / value)
        if self.choices and value not in self.choices:
            raise LowcamError(f"{where}: '{self.key}' must be one of {', '.join(self.choices)}, got {value!r}")
        if isinstance(value, (bool, list, dict)):  # float(True) would pass silently
            raise LowcamError(f"{where}: '{self.key}' must be a {self.kind.__name__}, got {value!r}")
        try:
            return self.kind(value)
        except (TypeError, ValueError):
            raise LowcamError(f"{where}: '{self.key}' must be a {self.kind.__name__}, got {value!r}") from None
        except argparse.ArgumentTypeError as e:  # a declared number out of its range
            raise LowcamError(f"{where}: '{self.key}': {e}") from None


@dataclass(frozen=True)
class Calibrator:
    """One calibration, as ``lowcam calibrate <name>`` and a manifest's ``[name]`` section run it.

    ``function`` fits the parameters; ``help`` is its line in ``lowcam calibrate -h``; ``options`` its inputs
    (:class:`Option`: the sub-command's arguments beside the common ones and the manifest keys it accepts); ``run(
    options, base, plot_dir)`` calls ``function`` with the options' values (a dict), the starting profile and the
    plot folder. ``aliases`` are further sub-command names. The effects it fits are those that declare
    ``calibration = name`` (:attr:`effects`, :func:`calibration_listing`).
    """

    name: str
    function: Callable[..., Calibration]
    help: str
    options: tuple[Option, ...]
    run: Callable[[dict, Any, Path | None], Calibration]
    aliases: tuple[str, ...] = ()

    @property
    def manifest_keys(self) -> tuple[str, ...]:
        return tuple(o.key for o in self.options)

    @property
    def effects(self) -> list[str]:
        """The known effects that declare this calibration (:func:`calibration_listing`)."""
        return calibration_listing().get(self.name, [])

    def add_arguments(self, parser) -> None:
        """This calibration's arguments on its ``lowcam calibrate`` sub-parser."""
        for option in self.options:
            option.add_argument(parser)

    def from_args(self, args, base, plot_dir: Path | None = None) -> Calibration:
        """Run it with parsed command-line ``args`` (from :meth:`add_arguments`)."""
        return self.run({o.key: getattr(args, o.key) for o in self.options}, base, plot_dir)

    def check_section(self, section, where: str) -> None:
        if not isinstance(section, dict):
            raise LowcamError(f"{where} must be a table of keys ({', '.join(self.manifest_keys)})")
        unknown = sorted(set(section) - set(self.manifest_keys))
        if unknown:
            raise LowcamError(f"{where}: unknown key '{unknown[0]}' (known: {', '.join(self.manifest_keys)})")

    def from_manifest(self, section: dict, where: str, folder: Path, base,
                      plot_dir: Path | None = None) -> Calibration:
        """Run it with a manifest's section (``where`` names it in messages; paths relative to ``folder``)."""
        return self.run(self.options_from_manifest(section, where, folder), base, plot_dir)

    def options_from_manifest(self, section: dict, where: str, folder: Path) -> dict:
        """The options' values from a manifest's section, checked (:meth:`Option.from_manifest`), without running."""
        self.check_section(section, where)
        return {o.key: o.from_manifest(section, where, Path(folder)) for o in self.options}


def _lens_models(model: str) -> tuple[str, ...]:
    return ("fov", "opencv") if model == "both" else (model,)


def _run_colour(o: dict, base, plot_dir: Path | None) -> Calibration:
    notes = None
    if o["patches"]:
        source = str(o["patches"])
        ideal, measured = read_patches_csv(o["patches"])
    elif o["frames"] and o["chart"]:
        source = _source(o["frames"])
        ideal, measured, notes = chart_patch_colours(o["frames"], o["chart"])
    else:
        raise LowcamError("colour calibration needs --patches CSV, or frames of the chart with --chart chart.json "
                          "(in a manifest: patches, or frames and chart)")
    cal = calibrate_colour(ideal, measured, o["saturation"], plot_dir, source)
    if notes is not None:
        cal.numbers["skipped"] = notes
    return cal


_FRAMES = Option("frames", "frames", required=True, positional=True)
#: A camera setting (sharpness, saturation: 0-255 on the cameras modelled; 0 is no setting to measure from).
_SETTING = Number(0, 255, low_open=True, what="a camera setting")

#: Every calibration by name, in the order a manifest runs them.
CALIBRATIONS: dict[str, Calibrator] = {c.name: c for c in (
    Calibrator("lens", calibrate_lens, "FOV and Brown-Conrady from checkerboard or ChArUco frames",
               (_FRAMES, Option("target", str, "checkerboard:9x6:0.025",
                                help="checkerboard:COLSxROWS:SQUARE_M or charuco"),
                Option("model", str, "both", choices=("fov", "opencv", "both"))),
               lambda o, base, plots: calibrate_lens(o["frames"], o["target"], _lens_models(o["model"]), plots)),
    Calibrator("vignetting", calibrate_vignetting, "from flat-field frames", (_FRAMES,),
               lambda o, base, plots: calibrate_vignetting(o["frames"], plots)),
    Calibrator("chromatic_aberration", calibrate_chromatic_aberration,
               "chromatic aberration from frames of the noise field", (_FRAMES,),
               lambda o, base, plots: calibrate_chromatic_aberration(o["frames"], plots), aliases=("ca",)),
    Calibrator("noise", calibrate_noise, "both noise laws from a stack of frames of a static scene",
               (_FRAMES, Option("law", str, "sigma_linear", choices=("sigma_linear", "variance_linear"),
                                help="the law written into the profile (both are fitted and reported)"),
                Option("demosaic", str, "block", choices=("block", "bilinear"))),
               lambda o, base, plots: calibrate_noise(o["frames"], o["demosaic"], o["law"], plots)),
    Calibrator("demosaic", calibrate_demosaic, "identify the demosaicing from a static stack", (_FRAMES,),
               lambda o, base, plots: calibrate_demosaic(o["frames"], base.geometry, plots)),
    Calibrator("blur", calibrate_blur, "horizontal/vertical blur from slanted edges", (_FRAMES,),
               lambda o, base, plots: calibrate_blur(o["frames"], plots)),
    Calibrator("sharpening", calibrate_sharpening, "sharpening filter from captures at sharpness 0 and at a setting",
               (Option("soft", "frames", required=True), Option("sharp", "frames", required=True),
                Option("sharpness", _SETTING, 80.0, required=True, help="the camera setting of the --sharp captures")),
               lambda o, base, plots: calibrate_sharpening(o["soft"], o["sharp"], o["sharpness"], plots)),
    Calibrator("colour", calibrate_colour, "crosstalk from the chart's colour patches (or a table of patch colours)",
               (Option("frames", "frames", positional=True, help="frames showing the whole chart"),
                Option("chart", "path", help="the chart's layout JSON (written by lowcam chart)"),
                Option("patches", "path",
                       help="instead: CSV ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b"),
                Option("saturation", _SETTING, 65.0, help="the camera's saturation setting")),
               _run_colour),
    Calibrator("plate", calibrate_plate, "a profile from the footage itself (no chart, no ideal): noise, edges, "
               "vignetting, gyro motion",
               (Option("footage", "frames", required=True, positional=True,
                       help="a video file, a folder of frames, or frame names or patterns"),
                Option("gyro", "path", help="gyro log: rows 'wx wy wz t' (framestamp.txt beside it) or a gyro CSV"),
                Option("fps", Number(0, 1000, low_open=True, what="frames per second"),
                       help="frames/s, 0 to 1000 (default: the video's, else 30)"),
                Option("min_confidence", Number(0, 1, what="a confidence"), 0.5,
                       help="estimates below this confidence (0 to 1) are reported, not applied")),
               lambda o, base, plots: calibrate_plate(o["footage"], base, o["gyro"], o["fps"], o["min_confidence"],
                                                      plots)),
)}


def calibrator(name: str) -> Calibrator:
    """The calibration called ``name`` (or one of its aliases, e.g. ``"ca"``)."""
    for c in CALIBRATIONS.values():
        if name == c.name or name in c.aliases:
            return c
    raise LowcamError(f"unknown calibration '{name}' (known: {', '.join(CALIBRATIONS)})")


def calibration_listing() -> dict[str, list[str]]:
    """Which effects each calibration fits: every name of :data:`CALIBRATIONS` (in order) with the effects that
    declare it as their ``calibration`` (:func:`lowcam.effects.known_effects`, plug-ins loaded so far included).
    A name that effects declare but no calibration has comes after them.

    >>> calibration_listing()["lens"]
    ['lens_distortion']
    """
    listing: dict[str, list[str]] = {name: [] for name in CALIBRATIONS}
    for cls in known_effects():
        if cls.calibration:
            listing.setdefault(cls.calibration, []).append(cls.name)
    return listing


def run_manifest(path, plot_dir: Path | None = None):
    """Run every calibration that the manifest lists; returns (base profile, calibrations).

    Manifest (TOML; frame patterns relative to the manifest; sections and their keys from :data:`CALIBRATIONS`)::

        profile = "fire-i"                      # the profile the results are written into
        [lens]                 frames = ["chessboard/*.png"], target = "checkerboard:9x6:0.025", model = "both"
        [vignetting]           frames = ["flat/*.png"]
        [chromatic_aberration] frames = ["noise/*.png"]
        [noise]                frames = ["static/*.png"], law = "sigma_linear", demosaic = "block"
        [demosaic]             frames = ["static/*.png"]
        [blur]                 frames = ["edges/*.png"]
        [sharpening]           soft = ["soft/*.png"], sharp = ["sharp/*.png"], sharpness = 80
        [colour]               patches = "patches.csv", saturation = 90   # or frames = [...], chart = "chart.json"
    """
    path = Path(path)
    doc = read_toml(path, "manifest")
    known = {"profile", *CALIBRATIONS}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise LowcamError(f"{path}: unknown manifest section '{unknown[0]}' (known: {', '.join(sorted(known))})")
    profile = doc.get("profile", "fire-i")
    if not isinstance(profile, str) or not profile:
        raise LowcamError(f"{path}: 'profile' must be a profile name or file, got {profile!r}")
    base = load_profile(profile)
    listed = [c for name, c in CALIBRATIONS.items() if name in doc]
    if not listed:
        raise LowcamError(f"{path}: the manifest lists no calibration")
    for c in listed:  # every section's keys before the first (slow) calibration runs
        c.check_section(doc[c.name], f"{path}: [{c.name}]")
    options = [c.options_from_manifest(doc[c.name], f"{path}: [{c.name}]", path.parent) for c in listed]
    if plot_dir is None:
        return base, [c.run(o, base, None) for c, o in zip(listed, options)]

    # plots go to a staging folder until every calibration has succeeded: a refusal leaves no plots behind
    with tempfile.TemporaryDirectory(prefix="lowcam-plots-") as staging:
        results = [c.run(o, base, Path(staging)) for c, o in zip(listed, options)]
        for cal in results:
            if cal.figures:
                make_output_folder(plot_dir)
            cal.figures = [Path(shutil.move(str(f), str(Path(plot_dir) / Path(f).name))) for f in cal.figures]
    return base, results
