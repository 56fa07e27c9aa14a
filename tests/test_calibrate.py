"""Calibration recovers known parameters from captures the engine makes, and reproduces OpenCV's published
calibration of real frames (paper sec. 4)."""
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import lowcam
from lowcam import LowcamError
from lowcam.calibrate import (apply_to_profile, calibrate_blur, calibrate_chromatic_aberration, calibrate_colour,
                              calibrate_demosaic, calibrate_lens, calibrate_noise, calibrate_sharpening,
                              calibrate_vignetting)
from lowcam.captures import detect_target, parse_target
from lowcam.effects.chromatic_aberration import radial_ca_grid
from lowcam.effects.vignetting import radial_vignetting

from helpers import chessboard_view, flat_render, noise_field, opaque, slanted_squares

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
CHESSBOARD = SHARED / "opencv-chessboard-left"


def save(frames, folder: Path, stem="f"):
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, f in enumerate(frames):
        p = folder / f"{stem}{i:02d}.png"
        cv2.imwrite(str(p), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        paths.append(str(p))
    return paths


def quiet(profile, *more):
    """The profile in the paper's calibration mode: RGB output (no 4:1:1), saturation at identity."""
    p = profile.without("chroma_subsampling", *more)
    p.effect("saturation").saturation = 65.0
    return p


@pytest.mark.skipif(not CHESSBOARD.is_dir(), reason="../shared/data is not beside the checkout")
def test_real_frames_reproduce_opencvs_published_intrinsics(tmp_path):
    cal = calibrate_lens(sorted(CHESSBOARD.glob("*.jpg")), "checkerboard:9x6:0.025", ("opencv", "fov"), tmp_path)
    brown = cal.numbers["opencv"]
    assert brown["fx_px"] == pytest.approx(535.916, rel=0.01)
    assert brown["cx_px"] == pytest.approx(342.283, rel=0.01)
    assert brown["rms_px"] == pytest.approx(0.393, rel=0.10)
    assert cal.numbers["fov"]["rms_px"] < 0.6  # the FOV model fits this lens almost as well
    assert cal.numbers["frames_used"] == 13
    assert (tmp_path / "lens_residuals.png").stat().st_size > 10000


@pytest.mark.parametrize("w", [0.93, 0.55])
def test_lens_fov_recovered_from_synthetic_chessboard_views(fire_i, tmp_path, w):
    profile = fire_i.without("noise", "vignetting", "chromatic_aberration", "motion_blur", "chroma_subsampling")
    profile.effect("lens_distortion").w = w
    rng = np.random.default_rng(int(w * 100))
    frames = []
    for k in range(8):
        rvec = rng.uniform(-0.35, 0.35, 3)
        tvec = [rng.uniform(-0.12, 0.02), rng.uniform(-0.08, 0.0), rng.uniform(0.22, 0.32)]
        frames.append(lowcam.simulate(chessboard_view(profile, rvec, tvec), profile))
    cal = calibrate_lens(save(frames, tmp_path), "checkerboard:9x6:0.025", ("fov",))
    fit = cal.numbers["fov"]
    truth = profile.effect("lens_distortion")
    assert fit["w"] == pytest.approx(w, rel=0.01)
    assert fit["fx"] == pytest.approx(truth.fx, rel=0.01)
    assert fit["rms_px"] < 0.2


@pytest.mark.parametrize("k2, k4", [(-0.30, -0.10), (-0.12, 0.0)])
def test_vignetting_recovered_within_2_percent(fire_i, tmp_path, k2, k4):
    profile = quiet(fire_i)
    v = profile.effect("vignetting")
    profile.effects[profile.effects.index(v)] = type(v)(k2=k2, k4=k4)
    frames = [lowcam.simulate(flat_render(0.75, 800, 600), profile, seed=s) for s in range(8)]
    cal = calibrate_vignetting(save(frames, tmp_path))
    gain = cal.textures["vignetting"].data
    truth = radial_vignetting(640, 480, k2, k4)
    assert np.sqrt(np.mean((gain - truth) ** 2)) < 0.02


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("red, blue", [(1.2, 0.5), (-0.8, 1.5)])
def test_chromatic_aberration_recovered_within_0_1_px(fire_i, tmp_path, red, blue):
    profile = quiet(fire_i, "noise")
    ca = profile.effect("chromatic_aberration")
    profile.effects[profile.effects.index(ca)] = type(ca)(red_corner_px=red, blue_corner_px=blue, cubic=1.0)
    frames = [lowcam.simulate(noise_field(seed=s), profile) for s in range(2)]
    cal = calibrate_chromatic_aberration(save(frames, tmp_path))
    err = cal.textures["chromatic_aberration"].data - radial_ca_grid(640, 480, red, blue, cubic=1.0)
    assert np.sqrt(np.mean(err ** 2)) < 0.1


def gradient_render(width=800, height=600):
    x = np.linspace(0.02, 0.95, width, dtype=np.float32)
    return opaque(np.tile(x, (height, 1)))


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("law, coeffs", [
    ("sigma_linear", {"red": [1.5, 0.015], "green": [1.2, 0.012], "blue": [1.8, 0.016]}),
    ("variance_linear", {"red": [2.0, 0.08], "green": [1.0, 0.05], "blue": [3.0, 0.04]}),
])
def test_noise_law_recovered_within_5_percent(fire_i, tmp_path, law, coeffs):
    profile = quiet(fire_i, "horizontal_blur", "sharpening", "quantisation", "vignetting", "crosstalk")
    noise = profile.effect("noise")
    noise.law = law
    for c, v in coeffs.items():
        setattr(noise, c, v)
    frames = [lowcam.simulate(gradient_render(), profile, seed=1, frame=f) for f in range(60)]
    cal = calibrate_noise(save(frames, tmp_path), "block", law)
    for channel, (a, b) in coeffs.items():
        fa, fb = cal.values["noise"][channel]
        assert fa == pytest.approx(a, rel=0.05) and fb == pytest.approx(b, rel=0.05), (channel, fa, fb)


def _lag_correlation(frames, d):
    """The temporal noise's correlation with the noise d pixels right and d pixels down, on the grey."""
    grey = np.asarray(frames, np.float64).mean(-1)
    noise = grey - grey.mean(0)
    return (np.mean(noise[:, :, d:] * noise[:, :, :-d]) + np.mean(noise[:, d:] * noise[:, :-d])) / (2 * noise.var())


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_noise_calibration_gives_the_grain_and_level_of_gaussian_correlated_noise(fire_i, tmp_path):
    """Frames whose noise is white noise through scipy's Gaussian filter (sigma s drawn at random), added to the
    base camera's noise-free frames: their correlation at d pixels is exp(-d^2 / (4 s^2)), in closed form. The
    calibrated profile's frames correlate as the stack's at 1-3 px and carry its noise level per channel (a grain
    the demosaicing averages less keeps more of green's noise); white noise gives no grain."""
    from scipy import ndimage

    base = quiet(fire_i, "horizontal_blur", "sharpening", "quantisation")
    base.save(tmp_path / "base.toml")
    render = gradient_render()
    clean = lowcam.simulate(render, base.without("noise")).astype(np.float64)
    rng = np.random.default_rng(2026)
    grains = {}
    for s in [0.0] + sorted(rng.uniform(0.6, 2.2, 2).round(2).tolist()):
        white = rng.standard_normal((12, 3) + clean.shape[:2])
        noise = ndimage.gaussian_filter(white, (0, 0, s, s)) * np.sqrt(4 * np.pi) * s if s else white  # unit variance
        frames = np.clip(np.rint(clean + 2.5 * noise.transpose(0, 2, 3, 1)), 0, 255).astype(np.uint8)
        for d in (1, 2):
            assert _lag_correlation(frames, d) == pytest.approx(np.exp(-d * d / (4 * s * s)) if s else 0, abs=0.02)
        out = tmp_path / f"cam{s}.toml"
        r = subprocess.run([sys.executable, "-m", "lowcam.cli", "calibrate", "noise",
                            *save(list(frames), tmp_path / f"stack{s}"), "--profile", str(tmp_path / "base.toml"),
                            "-o", str(out), "--plots", str(tmp_path / f"plots{s}")],
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        calibrated = lowcam.load_profile(out)
        grains[s] = calibrated.effect("noise").grain_px
        assert (tmp_path / f"plots{s}" / "noise.png").stat().st_size > 10000
        if not s:
            assert grains[s] == 0.0
            continue
        model = np.stack([lowcam.simulate(render, calibrated, seed=9, frame=f) for f in range(8)])
        for d in (1, 2, 3):
            assert _lag_correlation(model, d) == pytest.approx(_lag_correlation(frames, d), abs=0.05), (s, d)
        inner = (slice(None), slice(20, -20), slice(40, -200))   # away from the borders and the saturated end
        level = model[inner].astype(np.float64).std(0, ddof=1).mean((0, 1))
        assert level == pytest.approx(frames[inner].astype(np.float64).std(0, ddof=1).mean((0, 1)), rel=0.08), s
    assert list(grains.values()) == sorted(grains.values()) and grains[max(grains)] > grains[min(grains)] + 0.3


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("method", ["block", "bilinear"])
def test_demosaic_method_identified(fire_i, tmp_path, method):
    profile = quiet(fire_i, "vignetting", "chromatic_aberration")
    profile.effect("demosaic").method = method
    for c in ("red", "green", "blue"):
        setattr(profile.effect("noise"), c, [6.0, 0.0])
    frames = [lowcam.simulate(flat_render(0.5, 400, 300), profile, seed=2, frame=f) for f in range(25)]
    cal = calibrate_demosaic(save(frames, tmp_path), profile.geometry)
    assert cal.numbers["best"] == method


@pytest.mark.parametrize("sigma", [0.7, 1.2])
def test_horizontal_blur_recovered_from_slanted_edges(fire_i, tmp_path, sigma):
    profile = quiet(fire_i, "noise", "quantisation", "vignetting", "chromatic_aberration", "lens_distortion")
    profile.effect("horizontal_blur").sigma = sigma
    profile.effect("sharpening").sharpness = 0.0
    cal = calibrate_blur(save([lowcam.simulate(slanted_squares(), profile)], tmp_path))
    assert cal.values["horizontal_blur"]["sigma"] == pytest.approx(sigma, rel=0.05)


@pytest.mark.parametrize("sharpness", [80.0, 40.0])
def test_sharpening_recovered_from_two_settings(fire_i, tmp_path, sharpness):
    soft = quiet(fire_i, "noise", "quantisation", "vignetting", "chromatic_aberration", "motion_blur")
    soft.effect("sharpening").sharpness = 0.0
    sharp = soft.copy()
    sharp.effect("sharpening").sharpness = sharpness
    scene = noise_field(cells=(600, 450), crisp=True)
    cal = calibrate_sharpening(save([lowcam.simulate(scene, soft)], tmp_path / "soft"),
                               save([lowcam.simulate(scene, sharp)], tmp_path / "sharp"), sharpness, tmp_path)
    assert cal.numbers["a"] == pytest.approx(0.025 * sharpness, rel=0.05)
    assert cal.numbers["sigma"] == pytest.approx(0.55, rel=0.05)
    assert (tmp_path / "sharpening.png").is_file()


def test_colour_crosstalk_recovered(fire_i):
    profile = quiet(fire_i, "noise", "vignetting", "chromatic_aberration", "quantisation")
    profile.effect("saturation").saturation = 90.0
    rng = np.random.default_rng(5)
    colours = rng.uniform(0.1, 0.8, (12, 3)).astype(np.float32)
    measured = []
    for c in colours:
        frame = lowcam.simulate(opaque(np.broadcast_to(c, (300, 400, 3)).copy()), profile).astype(float)
        measured.append(frame[200:280, 280:360].reshape(-1, 3).mean(axis=0))
    cal = calibrate_colour(colours * 255, np.array(measured), 90.0)
    truth = profile.effect("crosstalk").total_matrix()
    assert np.abs(np.array(cal.values["crosstalk"]["matrix"]) - truth).max() < 0.01


def test_calibrated_parts_write_a_profile_that_loads_and_runs(fire_i, tmp_path):
    profile = quiet(fire_i)
    frames = [lowcam.simulate(flat_render(0.7, 800, 600), profile, seed=s) for s in range(4)]
    cal = calibrate_vignetting(save(frames, tmp_path / "flat"))
    out = apply_to_profile(fire_i, [cal], tmp_path / "mine.toml").save(tmp_path / "mine.toml")
    mine = lowcam.load_profile(out)
    assert Path(mine.effect("vignetting").texture) == tmp_path / "mine" / "vignetting.png"
    assert lowcam.simulate(flat_render(0.5), mine).shape == (480, 640, 3)


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_calibrate_all_from_a_manifest_with_report(fire_i, tmp_path):
    profile = quiet(fire_i)
    save([lowcam.simulate(flat_render(0.7, 800, 600), profile, seed=s) for s in range(4)], tmp_path / "flat")
    bilinear = profile.with_effect("demosaic", method="bilinear")  # not the base profile's block demosaicing
    save([lowcam.simulate(gradient_render(), bilinear, seed=3, frame=f) for f in range(12)], tmp_path / "static")
    (tmp_path / "manifest.toml").write_text('profile = "fire-i"\n[vignetting]\nframes = ["flat/*.png"]\n'
                                            '[noise]\nframes = ["static/*.png"]\n[demosaic]\nframes = ["static/*.png"]\n')
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "calibrate", "all", str(tmp_path / "manifest.toml"),
                        "-o", str(tmp_path / "cam.toml"), "--report", str(tmp_path / "report")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("vignetting:") and lines[1].startswith("noise:") and lines[2].startswith("demosaic:")
    page = (tmp_path / "report" / "index.html").read_text()
    assert page.count("<img") == 3 and "noise.png" in page and "numbers and fit quality" in page
    assert lowcam.load_profile(tmp_path / "cam.toml").effect("demosaic").method == "bilinear"


@pytest.mark.parametrize("make, args, message", [
    ("flat", ["lens"], "the target (checkerboard:9x6:0.025) was found in 0 frame(s)"),
    ("saturated", ["vignetting"], "of the pixels are saturated"),
    ("few", ["noise"], "3 frame(s) given, at least 10 needed"),
    ("mixed", ["vignetting"], "mixed sizes"),
])
def test_bad_captures_get_a_message_naming_the_frame(tmp_path, make, args, message):
    grey = np.full((480, 640, 3), 120, np.uint8)
    frames = {"flat": [grey] * 3, "saturated": [grey, np.full_like(grey, 255)], "few": [grey] * 3,
              "mixed": [grey, np.full((240, 320, 3), 120, np.uint8)]}[make]
    paths = save(frames, tmp_path / "in")
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "calibrate", *args, *paths, "-o",
                        str(tmp_path / "o.toml")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr
    if make in ("saturated", "mixed"):
        assert "f01.png" in r.stderr  # the offending frame is named


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_chart_has_every_element_and_its_charuco_board_is_detectable(tmp_path):
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "chart", "-o", str(tmp_path / "chart.png"),
                        "--dpi", "120"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    import json

    layout = json.loads((tmp_path / "chart.json").read_text())
    kinds = [e["type"] for e in layout["elements"]]
    assert kinds == ["charuco", "noise_field", "slanted_squares", "grey_steps", "colour_patches"]
    img = cv2.cvtColor(cv2.imread(str(tmp_path / "chart.png")), cv2.COLOR_BGR2RGB)
    found = detect_target(img, parse_target("charuco"))
    assert found is not None and len(found[1]) >= 20
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "chart", "-o", str(tmp_path / "chart.pdf")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and (tmp_path / "chart.pdf").read_bytes()[:4] == b"%PDF"
    with pytest.raises(LowcamError, match="chart size"):
        from lowcam.chart import make_chart

        make_chart("a5")


def test_colour_from_a_photographed_chart_is_found_automatically(fire_i, tmp_path):
    from lowcam.captures import chart_patch_colours, srgb_to_linear
    from lowcam.chart import write_chart

    chart_png, layout = write_chart(tmp_path / "chart.png", dpi=150)
    page = cv2.cvtColor(cv2.imread(str(chart_png)), cv2.COLOR_BGR2RGB)
    linear = srgb_to_linear(page).astype(np.float32)
    profile = quiet(fire_i, "noise", "vignetting", "chromatic_aberration", "quantisation", "lens_distortion")
    profile.effect("saturation").saturation = 90.0
    # the page seen square-on, filling most of a 1600-wide pinhole render
    w, h = 1600, 1200
    scale = 0.85 * w / page.shape[1]
    m = np.array([[scale, 0, (w - scale * page.shape[1]) / 2], [0, scale, (h - scale * page.shape[0]) / 2]])
    view = cv2.warpAffine(linear, m, (w, h), flags=cv2.INTER_AREA, borderValue=(0.5, 0.5, 0.5))
    frames = [lowcam.simulate(opaque(view), profile, seed=s) for s in range(2)]
    paths = save(frames, tmp_path / "frames")
    ideal, measured, notes = chart_patch_colours(paths, layout)
    assert len(ideal) == 24 and not notes
    cal = calibrate_colour(ideal, measured, 90.0, tmp_path)
    truth = profile.effect("crosstalk").total_matrix()
    assert np.abs(np.array(cal.values["crosstalk"]["matrix"]) - truth).max() < 0.03
    assert (tmp_path / "colour.png").is_file()


def _subcommands(parser):
    import argparse

    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_cli_and_manifest_take_exactly_the_table_of_calibrations(tmp_path, capsys):
    from lowcam.calibrate import CALIBRATIONS, calibration_listing, calibrator, run_manifest
    from lowcam.cli import build_parser, main
    from lowcam.effects import known_effects

    parser = build_parser()
    names = set(_subcommands(_subcommands(parser)["calibrate"])) - {"all", "list"}
    assert names == set(CALIBRATIONS) | {"ca"}
    for name in names:  # each sub-command dispatches to its table entry; "ca" is chromatic_aberration's alias
        c = calibrator(name)
        argv = [a for o in c.options if o.required for a in
                (["f.png"] if o.positional else [o.flag, "f.png" if o.kind == "frames" else "1"])]
        args = parser.parse_args(["calibrate", name, *argv, "-o", "x.toml"])
        assert args.calibration == c.name == ("chromatic_aberration" if name == "ca" else name)
    for name, c in CALIBRATIONS.items():  # the manifest knows the same sections, each with its own keys
        (tmp_path / "m.toml").write_text(f"[{name}]\nbogus = 1\n")
        known = ", ".join(c.manifest_keys)
        with pytest.raises(LowcamError, match=rf"\[{name}\]: unknown key 'bogus' \(known: {known}\)"):
            run_manifest(tmp_path / "m.toml")
    (tmp_path / "m.toml").write_text("[ca]\nframes = ['x.png']\n")
    with pytest.raises(LowcamError, match="unknown manifest section 'ca'"):
        run_manifest(tmp_path / "m.toml")
    # the listing names the effects that declare each calibration
    listing = calibration_listing()
    assert list(listing)[:len(CALIBRATIONS)] == list(CALIBRATIONS)
    for name, effects in listing.items():
        assert effects == [e.name for e in known_effects() if e.calibration == name]
    assert listing["lens"] == ["lens_distortion"] and listing["colour"] == ["crosstalk"]
    assert "horizontal_blur" in listing["blur"] and CALIBRATIONS["vignetting"].effects == ["vignetting"]
    assert main(["calibrate", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()[:len(CALIBRATIONS)]
    assert [ln.split()[:2] for ln in lines] == [[n, ", ".join(listing[n]) or "-"] for n in CALIBRATIONS]


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_ca_alias_calibrates_and_writes_the_grid_beside_the_profile(fire_i, tmp_path, capsys):
    from lowcam.cli import main

    profile = quiet(fire_i, "noise")
    ca = profile.effect("chromatic_aberration")
    profile.effects[profile.effects.index(ca)] = type(ca)(red_corner_px=1.0, blue_corner_px=0.5)
    paths = save([lowcam.simulate(noise_field(seed=s), profile) for s in range(2)], tmp_path / "in")
    assert main(["calibrate", "ca", *paths, "-o", str(tmp_path / "cam.toml")]) == 0
    assert capsys.readouterr().out.startswith("chromatic aberration: 2 frames")
    mine = lowcam.load_profile(tmp_path / "cam.toml")
    assert Path(mine.effect("chromatic_aberration").texture) == tmp_path / "cam" / "chromatic_aberration.csv"
