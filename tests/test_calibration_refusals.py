"""Calibrations that cannot learn from their input refuse it: one line naming the input, nothing written.

Each case builds featureless or degenerate input (a flat grey or black frame, identical frames, identical
patches, a one-level noise stack, a broken manifest) and runs ``lowcam calibrate`` on it.
"""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from lowcam.calibrate import CALIBRATIONS
from lowcam.cli import main
from lowcam.outputs import write_png

GREY = 120


def frames(folder: Path, images, stem="f") -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    return [str(write_png(folder / f"{stem}{i:02d}.png", img)) for i, img in enumerate(images)]


def flat(value=GREY, width=320, height=240) -> np.ndarray:
    return np.full((height, width, 3), value, np.uint8)


def textured(seed=0, width=640, height=480) -> np.ndarray:
    """Crisp grey noise cells (4 px), like the chart's noise field."""
    cells = np.random.default_rng(seed).integers(20, 235, (height // 4, width // 4), dtype=np.uint8)
    return np.repeat(np.repeat(cells, 4, axis=0), 4, axis=1)[..., None].repeat(3, axis=2)


def chessboard(cols=10, rows=7, square=40, margin=60) -> np.ndarray:
    """A crisp checkerboard with (cols - 1) x (rows - 1) inner corners on a white page."""
    board = (np.indices((rows, cols)).sum(axis=0) % 2).astype(np.uint8) * 255
    board = np.repeat(np.repeat(board, square, axis=0), square, axis=1)
    page = np.full((rows * square + 2 * margin, cols * square + 2 * margin), 255, np.uint8)
    page[margin:-margin, margin:-margin] = board
    return page[..., None].repeat(3, axis=2)


def patches_csv(path: Path, ideal, measured) -> str:
    rows = ["ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b"]
    rows += [",".join(f"{v:g}" for v in (*i, *m)) for i, m in zip(ideal, measured)]
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def noisy(value, n, sigma=3.0, width=320, height=240, seed=0):
    rng = np.random.default_rng(seed)
    base = np.broadcast_to(np.asarray(value, np.float64), (height, width))[..., None]
    return [np.clip(np.round(base + rng.normal(0, sigma, (height, width, 3))), 0, 255).astype(np.uint8)
            for _ in range(n)]


# each case: (tmp_path) -> (argv after "calibrate", a fragment the message must name)
def lens_flat(t):
    paths = frames(t / "flat", [flat()] * 3)
    return ["lens", *paths], "f00.png"


def lens_one_view(t):
    paths = frames(t / "board", [chessboard()] * 3)
    return ["lens", *paths], "f00.png"


def vignetting_black(t):
    paths = frames(t / "black", [flat(0)] * 3)
    return ["vignetting", *paths], "f00.png"


def ca_flat(t):
    paths = frames(t / "flat", [flat()] * 2)
    return ["chromatic_aberration", *paths], "f00.png"


def ca_alias_flat(t):
    paths = frames(t / "flat", [flat()] * 2)
    return ["ca", *paths], "f00.png"


def noise_one_level(t):
    paths = frames(t / "stack", noisy(GREY, 10))
    return ["noise", *paths], "f00.png"


def noise_identical(t):
    ramp = np.tile(np.linspace(10, 210, 320).astype(np.uint8), (240, 1))[..., None].repeat(3, axis=2)
    paths = frames(t / "stack", [ramp] * 10)
    return ["noise", *paths], "f00.png"


def noise_all_saturated(t):
    paths = frames(t / "stack", noisy(240, 10))
    return ["noise", *paths], "f00.png"


def noise_too_small(t):
    ramp = np.tile(np.linspace(10, 210, 16), (12, 1))
    paths = frames(t / "stack", noisy(ramp, 10, width=16, height=12))
    return ["noise", *paths], "f00.png"


def demosaic_too_small(t):
    paths = frames(t / "stack", noisy(GREY, 10, width=16, height=12))
    return ["demosaic", *paths], "f00.png"


def ca_too_small(t):
    paths = frames(t / "tex", [textured(width=40, height=32)])
    return ["chromatic_aberration", *paths], "f00.png"


def demosaic_identical(t):
    paths = frames(t / "stack", [flat()] * 10)
    return ["demosaic", *paths], "f00.png"


def blur_flat(t):
    paths = frames(t / "flat", [flat()])
    return ["blur", *paths], "f00.png"


def blur_noise_only(t):
    paths = frames(t / "tex", [textured()])
    return ["blur", *paths], "f00.png"


def sharpening_flat(t):
    soft = frames(t / "soft", [flat(width=640, height=480)])
    sharp = frames(t / "sharp", [flat(width=640, height=480)])
    return ["sharpening", "--soft", *soft, "--sharp", *sharp, "--sharpness", "80"], "soft"


def sharpening_identical(t):
    soft = frames(t / "soft", [textured()])
    sharp = frames(t / "sharp", [textured()])
    return ["sharpening", "--soft", *soft, "--sharp", *sharp, "--sharpness", "80"], "sharp"


def sharpening_setting_zero(t):
    soft = frames(t / "soft", [textured(0)])
    sharp = frames(t / "sharp", [textured(1)])
    return ["sharpening", "--soft", *soft, "--sharp", *sharp, "--sharpness", "0"], "--sharpness"


def sharpening_sizes(t):
    soft = frames(t / "soft", [textured()])
    sharp = frames(t / "sharp", [textured(width=320, height=240)])
    return ["sharpening", "--soft", *soft, "--sharp", *sharp, "--sharpness", "80"], "sharp"


def sharpening_too_small(t):
    soft = frames(t / "soft", [textured(0, 160, 120)])
    sharp = frames(t / "sharp", [textured(1, 160, 120)])
    return ["sharpening", "--soft", *soft, "--sharp", *sharp, "--sharpness", "80"], "soft"


def colour_identical(t):
    csv = patches_csv(t / "patches.csv", [(0.5, 0.3, 0.2)] * 8, [(120, 80, 60)] * 8)
    return ["colour", "--patches", csv], "patches.csv"


def colour_greys(t):
    levels = np.linspace(0.2, 0.8, 8)
    csv = patches_csv(t / "patches.csv", [(v, v, v) for v in levels], [(200 * v,) * 3 for v in levels])
    return ["colour", "--patches", csv], "patches.csv"


def colour_saturation_zero(t):
    rng = np.random.default_rng(3)
    ideal = rng.uniform(0.2, 0.8, (8, 3))
    csv = patches_csv(t / "patches.csv", ideal, ideal * 200)
    return ["colour", "--patches", csv, "--saturation", "0"], "--saturation"


def colour_nan_saturation(t):
    rng = np.random.default_rng(3)
    ideal = rng.uniform(0.2, 0.8, (8, 3))
    csv = patches_csv(t / "patches.csv", ideal, ideal * 200)
    return ["colour", "--patches", csv, "--saturation", "nan"], "--saturation"


def colour_missing_layout(t):
    paths = frames(t / "chart", [flat()])
    return ["colour", *paths, "--chart", str(t / "chart.json")], "chart.json"


def colour_chart_not_found(t):
    paths = frames(t / "chart", [flat()])
    (t / "chart.json").write_text(json.dumps({"format": "lowcam-chart", "elements": [
        {"type": "charuco", "rect_mm": [10, 10, 210, 150], "square_mm": 30},
        {"type": "colour_patches", "patches": [{"rect_mm": [230, 10, 20, 20], "srgb": [200, 40, 40]}]}]}))
    return ["colour", *paths, "--chart", str(t / "chart.json")], "f00.png"


def manifest(t, text, *, files=()):
    for f in files:
        (t / f).parent.mkdir(parents=True, exist_ok=True)
        write_png(t / f, flat())
    (t / "m.toml").write_text(text)
    return ["all", str(t / "m.toml")], "m.toml"


def manifest_unknown_section(t):
    return manifest(t, '[vignette]\nframes = ["flat/*.png"]\n')


def manifest_not_a_table(t):
    return manifest(t, 'vignetting = "flat/*.png"\n')


def manifest_number_as_frames(t):
    return manifest(t, "[vignetting]\nframes = 3\n")


def manifest_numbers_in_frames(t):
    return manifest(t, "[vignetting]\nframes = [1, 2]\n")


def manifest_number_as_path(t):
    return manifest(t, "[colour]\npatches = 5\n")


def manifest_missing_frames(t):
    return manifest(t, '[vignetting]\nframes = ["flat/*.png"]\n')


def manifest_missing_later_section(t):
    # the vignetting would run (and plot) first: the missing patch table must stop it before
    return manifest(t, '[vignetting]\nframes = ["flat/f00.png"]\n[colour]\npatches = "gone.csv"\n',
                    files=["flat/f00.png"])


def manifest_profile_not_a_string(t):
    return manifest(t, 'profile = 3\n[vignetting]\nframes = ["flat/f00.png"]\n', files=["flat/f00.png"])


def plate_flat(t):
    # a still, flat, noise-free shot: no noise levels, no edges, no motion, no gyro: nothing to write
    paths = frames(t / "shot", [flat()] * 4)
    return ["plate", *paths], "shot/f00.png"


def manifest_later_refusal(t):
    # vignetting succeeds and would plot; the demosaic stack of identical frames refuses: no plots either
    frames(t / "stack", [flat()] * 10)
    argv, _ = manifest(t, '[vignetting]\nframes = ["flat/f00.png"]\n[demosaic]\nframes = ["stack/*.png"]\n',
                       files=["flat/f00.png"])
    return argv, "stack/*.png"


CASES = [lens_flat, lens_one_view, vignetting_black, ca_flat, ca_alias_flat, noise_one_level, noise_identical,
         noise_all_saturated, noise_too_small, demosaic_identical, demosaic_too_small, ca_too_small, blur_flat, blur_noise_only, sharpening_flat, sharpening_identical,
         sharpening_setting_zero, sharpening_sizes, sharpening_too_small, colour_identical, colour_greys,
         colour_saturation_zero, colour_nan_saturation, colour_missing_layout,
         colour_chart_not_found, plate_flat,
         manifest_unknown_section, manifest_not_a_table, manifest_number_as_frames, manifest_numbers_in_frames,
         manifest_number_as_path, manifest_missing_frames, manifest_missing_later_section,
         manifest_profile_not_a_string, manifest_later_refusal]


def _case_id(case):
    return case.__name__


def test_every_calibration_has_a_refusal_case():
    covered = {fn.__name__.split("_")[0] for fn in (c.values[0] if hasattr(c, "values") else c for c in CASES)}
    covered = {"chromatic_aberration" if n == "ca" else n for n in covered}
    assert set(CALIBRATIONS) <= covered


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_featureless_input_is_refused_in_one_line(tmp_path, capsys, case):
    argv, names = case(tmp_path)
    out = tmp_path / "out.toml"
    code = main(["calibrate", *argv, "-o", str(out)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert names in lines[0], lines[0]
    assert not re.search(r"\bnan\b", lines[0].replace("--saturation nan", "").replace("got nan", ""), re.I), lines[0]
    assert not out.exists()
    assert not (tmp_path / "out-plots").exists() and not (tmp_path / "out").exists()
