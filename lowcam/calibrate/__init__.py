"""Calibration from measurements (Klein & Murray 2010, sec. 4): captures in, profile parameters and plots out.

Each calibration reads the camera's frames, fits the parameters of one effect with that effect's own fitting
code (``lowcam.effects.*``), writes them into a profile (textures beside it), prints a one-line summary and saves
a plot. :func:`write_report` gathers the plots and numbers into an HTML page.
"""
from __future__ import annotations

import glob
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..errors import LowcamError

@dataclass
class Calibration:
    """One calibration's outcome: ``summary`` (one line), fitted ``values`` per effect, ``numbers`` for the
    report, ``figures`` (PNG paths)."""

    what: str
    summary: str
    values: dict[str, dict] = field(default_factory=dict)
    numbers: dict = field(default_factory=dict)
    figures: list[Path] = field(default_factory=list)


# --- captures ------------------------------------------------------------------------------------------------------

def expand_paths(patterns) -> list[Path]:
    out = []
    for p in patterns:
        matches = sorted(glob.glob(str(p)))
        out.extend(Path(m) for m in matches) if matches else out.append(Path(p))
    return out


def load_frames(patterns, min_frames: int = 1, what: str = "calibration") -> tuple[list[np.ndarray], list[str]]:
    """Read capture frames (PNG/JPEG, RGB uint8); every problem names the frame."""
    from ..io import read_image

    paths = expand_paths(patterns)
    if len(paths) < min_frames:
        raise LowcamError(f"{what}: {len(paths)} frame(s) given, at least {min_frames} needed")
    frames, names = [], []
    for p in paths:
        img = read_image(p)
        if img.dtype != np.uint8:
            img = np.round(img / 257.0).astype(np.uint8)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        if frames and img.shape != frames[0].shape:
            raise LowcamError(f"{p}: the frame is {img.shape[1]}x{img.shape[0]}, the first frame ({names[0]}) is "
                              f"{frames[0].shape[1]}x{frames[0].shape[0]}: mixed sizes")
        frames.append(img)
        names.append(str(p))
    return frames, names


def refuse_saturated(frames, names, fraction: float = 0.01) -> None:
    """Flat fields and noise stacks must not clip: name the first frame with over ``fraction`` pixels at 255."""
    for f, n in zip(frames, names):
        clipped = float((f >= 255).any(axis=-1).mean())
        if clipped > fraction:
            raise LowcamError(f"{n}: {100 * clipped:.1f} % of the pixels are saturated (255); lower the exposure")


# --- targets -------------------------------------------------------------------------------------------------------

def parse_target(spec: str):
    """``"checkerboard:9x6:0.025"`` (inner corners, square in metres) or ``"charuco"`` (the chart's board)."""
    kind, _, rest = spec.partition(":")
    if kind in ("checkerboard", "chessboard"):
        try:
            size, square = rest.split(":")
            cols, rows = (int(v) for v in size.lower().split("x"))
            return ("checkerboard", (cols, rows), float(square))
        except ValueError:
            raise LowcamError(f"target '{spec}': use checkerboard:COLSxROWS:SQUARE_M, e.g. checkerboard:9x6:0.025")
    if kind == "charuco":
        return ("charuco", None, None)
    raise LowcamError(f"target '{spec}': unknown (use checkerboard:9x6:0.025 or charuco)")


def detect_target(image: np.ndarray, target) -> tuple[np.ndarray, np.ndarray] | None:
    """(object points (N, 3) in metres, image points (N, 2) in pixels) of the target in one frame, or None."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    kind, size, square = target
    if kind == "checkerboard":
        ok, corners = cv2.findChessboardCorners(grey, size, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            return None
        corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        obj = np.zeros((size[0] * size[1], 3))
        obj[:, :2] = np.mgrid[0:size[0], 0:size[1]].T.reshape(-1, 2) * square
        return obj, corners.reshape(-1, 2).astype(np.float64)
    from .chart import charuco_board

    board = charuco_board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(grey)
    if ids is None or len(ids) < 8:
        return None
    obj = board.getChessboardCorners()[ids.ravel()]
    return np.asarray(obj, np.float64), corners.reshape(-1, 2).astype(np.float64)


# --- plots ---------------------------------------------------------------------------------------------------------

def _figure(path: Path, draw, size=(7, 4.5)) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=size, dpi=100)
    draw(fig)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


# --- the calibrations ---------------------------------------------------------------------------------------------

def calibrate_lens(patterns, target: str = "checkerboard:9x6:0.025", models=("fov", "opencv"),
                   plot_dir: Path | None = None) -> Calibration:
    from ..effects.lens import fit_lens

    frames, names = load_frames(patterns, 3, "lens calibration")
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
        raise LowcamError(f"lens calibration: the target ({target}) was found in {len(used)} frame(s), at least 3 "
                          f"are needed" + (f"; not found in {', '.join(Path(m).name for m in missing)}" if missing
                                           else ""))
    h, w = frames[0].shape[:2]
    fits = {m: fit_lens(obj, img, (w, h), m) for m in models}
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
        figures.append(_figure(Path(plot_dir) / "lens_residuals.png", draw, (11, 4.5)))
    summary = (f"lens: {len(used)}/{len(frames)} frames, " +
               ", ".join(f"{m} RMS {fits[m].rms:.3f} px" for m in fits) + f"; profile gets {best}")
    return Calibration("lens", summary, {"lens_distortion": {"model": best, **fits[best].params}}, numbers,
                       figures)


def calibrate_vignetting(patterns, plot_dir: Path | None = None) -> Calibration:
    from ..effects.vignetting import fit_vignetting

    frames, names = load_frames(patterns, 1, "vignetting calibration")
    refuse_saturated(frames, names)
    gain = fit_vignetting(frames)
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
        figures.append(_figure(Path(plot_dir) / "vignetting.png", draw, (10, 4)))
    return Calibration("vignetting", f"vignetting: {len(frames)} flat fields, corner gain {corners:.3f}",
                       {"vignetting": {"_texture": gain}}, {"corner_gain": corners, "frames": len(frames)}, figures)


def calibrate_chromatic_aberration(patterns, plot_dir: Path | None = None) -> Calibration:
    from ..effects.chromatic_aberration import fit_chromatic_aberration
    from ..geometry import grid_points

    frames, names = load_frames(patterns, 1, "chromatic-aberration calibration")
    refuse_saturated(frames, names, 0.05)
    grid = fit_chromatic_aberration(frames)
    h, w = frames[0].shape[:2]
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
        figures.append(_figure(Path(plot_dir) / "chromatic_aberration.png", draw))
    return Calibration("chromatic_aberration",
                       f"chromatic aberration: {len(frames)} frames, max red {red.max():.2f} px, blue {blue.max():.2f} px",
                       {"chromatic_aberration": {"_grid": grid}},
                       {"max_red_px": float(red.max()), "max_blue_px": float(blue.max())}, figures)


def calibrate_noise(patterns, demosaic: str = "block", law: str = "sigma_linear",
                    plot_dir: Path | None = None) -> Calibration:
    from ..effects.noise import fit_noise

    frames, names = load_frames(patterns, 10, "noise calibration")
    fit = fit_noise(np.stack(frames), demosaic)
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
        figures.append(_figure(Path(plot_dir) / "noise.png", draw, (12, 4)))
    chosen = fit[law]
    summary = "noise: " + ", ".join(f"{c} {law} [{a:.3f}, {b:.4f}]" for c, (a, b) in chosen.items())
    return Calibration("noise", summary, {"noise": {"law": law, **chosen}},
                       {"sigma_linear": fit["sigma_linear"], "variance_linear": fit["variance_linear"],
                        "frames": len(frames)}, figures)


def calibrate_demosaic(patterns, geometry, plot_dir: Path | None = None) -> Calibration:
    from ..effects.bayer import identify_demosaic

    frames, names = load_frames(patterns, 10, "demosaic identification")
    result = identify_demosaic(np.stack(frames), geometry)
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
        figures.append(_figure(Path(plot_dir) / "demosaic.png", draw, (8, 6)))
    method = "block" if result["best"] == "block" else "bilinear"  # the engine simulates these two
    errors = ", ".join(f"{m} {e:.3f}" for m, e in result["errors"].items())
    return Calibration("demosaic", f"demosaic: best match {result['best']} (errors {errors})",
                       {"demosaic": {"method": method}}, {"best": result["best"], "errors": result["errors"]},
                       figures)


def calibrate_blur(patterns, plot_dir: Path | None = None) -> Calibration:
    from ..effects.blur import fit_edge_blur

    frames, _ = load_frames(patterns, 1, "blur calibration")
    r = fit_edge_blur(frames)
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
        figures.append(_figure(Path(plot_dir) / "blur.png", draw))
    return Calibration("blur", f"blur: edge sigma horizontal {r['sigma_horizontal_px']:.3f} px, vertical "
                               f"{r['sigma_vertical_px']:.3f} px -> horizontal blur {r['extra_horizontal_sensels']:.3f} sensels",
                       {"horizontal_blur": {"sigma": r["extra_horizontal_sensels"]}}, r, figures)


def calibrate_sharpening(soft_patterns, sharp_patterns, sharpness: float, plot_dir: Path | None = None,
                         taps: int = 101) -> Calibration:
    """Sharpening from two captures of one static scene, at sharpness 0 and at ``sharpness`` (sec. 4.4.3).

    The filter is measured on the red channel at sensel resolution (every other pixel), where the paper found the
    camera sharpens: the free 101-tap filter for the plot, and the 7-tap model fitted to the images themselves
    (the free filter is poorly determined at frequencies the scene and the sensor's blur leave empty).
    """
    from ..effects.sharpen import fit_row_filter, fit_sharpening_to_images, frequency_response

    soft, _ = load_frames(soft_patterns, 1, "sharpening calibration (soft)")
    sharp, _ = load_frames(sharp_patterns, 1, "sharpening calibration (sharp)")
    if soft[0].shape != sharp[0].shape:
        raise LowcamError("sharpening calibration: the soft and sharp captures differ in size")
    s0 = np.mean(soft, axis=0)[::2, ::2, 0]
    s1 = np.mean(sharp, axis=0)[::2, ::2, 0]
    h = fit_row_filter(s0, s1, taps)
    a, sigma = fit_sharpening_to_images(s0, s1)
    figures = []
    if plot_dir:
        def draw(fig):
            from ..effects.blur import gaussian_taps

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
        figures.append(_figure(Path(plot_dir) / "sharpening.png", draw, (10, 4)))
    gain = a / sharpness if sharpness > 0 else 0.0
    return Calibration("sharpening", f"sharpening: a = {a:.3f}, sigma = {sigma:.3f} sensels at sharpness "
                                     f"{sharpness:g} (gain per unit {gain:.4f})",
                       {"sharpening": {"sharpness": sharpness, "gain_per_unit": gain, "sigma": sigma}},
                       {"a": a, "sigma": sigma, "filter": h.tolist()}, figures)


def calibrate_colour(ideal_rgb, measured_rgb, saturation: float, plot_dir: Path | None = None) -> Calibration:
    """Crosstalk from patch colours: ``ideal_rgb`` (N, 3) the light (render units x 255), ``measured_rgb`` the
    camera's mean patch colours (DN) at saturation setting ``saturation``."""
    from ..effects.crosstalk import crosstalk_from_colour_matrix, fit_colour_matrix

    ideal_rgb, measured_rgb = np.asarray(ideal_rgb, np.float64), np.asarray(measured_rgb, np.float64)
    unclipped = (measured_rgb.min(axis=1) > 3) & (measured_rgb.max(axis=1) < 250)  # clipping breaks linearity
    if unclipped.sum() < 4:
        raise LowcamError(f"colour calibration: only {int(unclipped.sum())} patches are free of clipping, 4 needed")
    ideal_rgb, measured_rgb = ideal_rgb[unclipped], measured_rgb[unclipped]
    total = fit_colour_matrix(ideal_rgb, measured_rgb)
    crosstalk = crosstalk_from_colour_matrix(total, saturation)
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
        figures.append(_figure(Path(plot_dir) / "colour.png", draw, (9, 4)))
    return Calibration("colour", "colour: crosstalk rows " + "; ".join(" ".join(f"{v:.3f}" for v in row)
                                                                      for row in crosstalk),
                       {"crosstalk": {"matrix": crosstalk.tolist(), "extra_mixing": 0.0},
                        "saturation": {"saturation": saturation}}, {"total_matrix": total.tolist()}, figures)


# --- profiles and reports --------------------------------------------------------------------------------------------

def apply_to_profile(profile, calibrations, out_path: Path):
    """A copy of ``profile`` with every calibration's values, textures written beside ``out_path``."""
    from ..effects.chromatic_aberration import write_ca_grid
    from ..io import write_png

    out_path = Path(out_path).resolve()
    tex_dir = out_path.parent / out_path.stem
    new = profile
    for cal in calibrations:
        for name, values in cal.values.items():
            values = dict(values)
            if "_texture" in values:
                path = tex_dir / "vignetting.png"
                write_png(path, np.round(values.pop("_texture") * 65535).astype(np.uint16))
                values["texture"] = str(path)
            if "_grid" in values:
                path = tex_dir / "chromatic_aberration.csv"
                write_ca_grid(path, values.pop("_grid"), new.camera.width, new.camera.height)
                values["texture"] = str(path)
            new = new.with_effect(name, replace=(name == "lens_distortion"), source=str(out_path),
                                  base_dir=out_path.parent, **values)
    new = new.copy()
    new.path = out_path
    return new


def write_report(calibrations, folder) -> Path:
    """An HTML page with every calibration's summary, numbers and plots."""
    from ..io import atomic_write_bytes

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>Lowcam calibration</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}pre{background:#f4f4f4;padding:8px;"
             "overflow:auto}img{max-width:100%}</style></head><body><h1>Lowcam calibration report</h1>"]
    for cal in calibrations:
        parts.append(f"<h2>{html.escape(cal.what)}</h2><p><b>{html.escape(cal.summary)}</b></p>")
        for fig in cal.figures:
            fig = Path(fig)
            target = folder / fig.name
            if fig.resolve() != target.resolve():
                target.write_bytes(fig.read_bytes())
            parts.append(f"<img src='{html.escape(fig.name)}' alt='{html.escape(cal.what)}'>")
        numbers = json.dumps(cal.numbers, indent=1, default=lambda o: np.asarray(o).tolist())
        parts.append(f"<details><summary>numbers and fit quality</summary><pre>{html.escape(numbers)}</pre></details>")
    parts.append("</body></html>")
    path = folder / "index.html"
    atomic_write_bytes(path, "\n".join(parts).encode())
    return path


def read_patches_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Patch colours: header ``ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b`` (ideal in render units
    0-1, measured in DN 0-255), one row per patch."""
    path = Path(path)
    try:
        data = np.genfromtxt(path, delimiter=",", names=True)
    except (OSError, ValueError) as e:
        raise LowcamError(f"{path}: cannot read the patch table ({e})") from None
    cols = ["ideal_r", "ideal_g", "ideal_b", "measured_r", "measured_g", "measured_b"]
    if data.dtype.names is None or any(c not in data.dtype.names for c in cols) or data.size < 4:
        raise LowcamError(f"{path}: the patch table needs the columns {','.join(cols)} and at least 4 patches")
    table = np.column_stack([np.atleast_1d(data[c]) for c in cols])
    return table[:, :3] * 255.0, table[:, 3:]


def run_manifest(path, plot_dir: Path | None = None):
    """Run every calibration that the manifest lists; returns (base profile name, calibrations).

    Manifest (TOML; frame patterns relative to the manifest)::

        profile = "fire-i"                      # the profile the results are written into
        [lens]                 frames = ["chessboard/*.png"], target = "checkerboard:9x6:0.025", model = "both"
        [vignetting]           frames = ["flat/*.png"]
        [chromatic_aberration] frames = ["noise/*.png"]
        [noise]                frames = ["static/*.png"], law = "sigma_linear", demosaic = "block"
        [demosaic]             frames = ["static/*.png"]
        [blur]                 frames = ["edges/*.png"]
        [sharpening]           soft = ["soft/*.png"], sharp = ["sharp/*.png"], sharpness = 80
        [colour]               patches = "patches.csv", saturation = 90
    """
    from ..io import read_toml
    from ..profile import load_profile

    path = Path(path)
    doc = read_toml(path, "manifest")
    known = {"profile", "lens", "vignetting", "chromatic_aberration", "noise", "demosaic", "blur", "sharpening",
             "colour"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise LowcamError(f"{path}: unknown manifest section '{unknown[0]}' (known: {', '.join(sorted(known))})")
    base = load_profile(doc.get("profile", "fire-i"))

    def frames(section, key="frames"):
        items = doc[section].get(key)
        if not items:
            raise LowcamError(f"{path}: [{section}] needs '{key}'")
        return [str(path.parent / p) for p in ([items] if isinstance(items, str) else items)]

    cals = []
    if "lens" in doc:
        model = doc["lens"].get("model", "both")
        cals.append(calibrate_lens(frames("lens"), doc["lens"].get("target", "checkerboard:9x6:0.025"),
                                   ("fov", "opencv") if model == "both" else (model,), plot_dir))
    if "vignetting" in doc:
        cals.append(calibrate_vignetting(frames("vignetting"), plot_dir))
    if "chromatic_aberration" in doc:
        cals.append(calibrate_chromatic_aberration(frames("chromatic_aberration"), plot_dir))
    if "noise" in doc:
        cals.append(calibrate_noise(frames("noise"), doc["noise"].get("demosaic", "block"),
                                    doc["noise"].get("law", "sigma_linear"), plot_dir))
    if "demosaic" in doc:
        cals.append(calibrate_demosaic(frames("demosaic"), base.geometry, plot_dir))
    if "blur" in doc:
        cals.append(calibrate_blur(frames("blur"), plot_dir))
    if "sharpening" in doc:
        cals.append(calibrate_sharpening(frames("sharpening", "soft"), frames("sharpening", "sharp"),
                                         float(doc["sharpening"].get("sharpness", 80)), plot_dir))
    if "colour" in doc:
        ideal, measured = read_patches_csv(path.parent / doc["colour"]["patches"])
        cals.append(calibrate_colour(ideal, measured, float(doc["colour"].get("saturation", 65)), plot_dir))
    if not cals:
        raise LowcamError(f"{path}: the manifest lists no calibration")
    return base, cals


def srgb_to_linear(v):
    v = np.asarray(v, np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def chart_patch_colours(patterns, layout_path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Find the chart (its ChArUco board) in each frame and read the mean colour of every colour patch and grey
    step. Returns (ideal linear colours x 255 from the printed sRGB, measured DN averaged over frames, notes)."""
    from .chart import charuco_board

    layout = json.loads(Path(layout_path).read_text())
    if layout.get("format") != "lowcam-chart":
        raise LowcamError(f"{layout_path}: not a lowcam chart layout")
    board = next(e for e in layout["elements"] if e["type"] == "charuco")
    patches = [(p["rect_mm"], p["srgb"]) for e in layout["elements"] if e["type"] == "colour_patches"
               for p in e["patches"]]
    patches += [(p["rect_mm"], [p["value"]] * 3) for e in layout["elements"] if e["type"] == "grey_steps"
                for p in e["patches"]]
    frames, names = load_frames(patterns, 1, "colour calibration")
    spec = parse_target("charuco")
    sums, count, notes = np.zeros((len(patches), 3)), 0, []
    for f, n in zip(frames, names):
        found = detect_target(f, spec)
        if found is None:
            notes.append(f"{n}: the chart's ChArUco board not found, frame skipped")
            continue
        obj, img = found
        # board metres (origin at the board's outer top-left corner, y down) -> page millimetres
        x0, y0 = board["rect_mm"][:2]
        scale = board["square_mm"] / (1000.0 * charuco_board().getSquareLength())
        mm = obj[:, :2] * 1000.0 * scale + [x0, y0]
        h, _ = cv2.findHomography(mm.astype(np.float32), img.astype(np.float32))
        for k, (rect, _) in enumerate(patches):
            x, y, w, hh = rect
            inner = np.array([[x + 0.3 * w, y + 0.3 * hh], [x + 0.7 * w, y + 0.3 * hh], [x + 0.7 * w, y + 0.7 * hh],
                              [x + 0.3 * w, y + 0.7 * hh]], np.float32)
            poly = cv2.perspectiveTransform(inner[None], h)[0]
            mask = np.zeros(f.shape[:2], np.uint8)
            cv2.fillConvexPoly(mask, np.round(poly).astype(np.int32), 1)
            if mask.sum() < 4:
                raise LowcamError(f"{n}: the chart's patches are too small in the frame (move closer)")
            sums[k] += f[mask > 0].reshape(-1, 3).mean(axis=0)
        count += 1
    if count == 0:
        raise LowcamError("colour calibration: the chart was found in none of the frames")
    ideal = srgb_to_linear([c for _, c in patches]) * 255.0
    return ideal, sums / count, notes
