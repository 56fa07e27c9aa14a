"""ColorChecker captures: the chart found, its patches read with their noise, and a camera's colour matrix and tone
curve fitted from them (``lowcam calibrate colour --target colorchecker``, ``target = "colorchecker"`` captures).

The charts are rendered here: the 24 patches of colour-science's reference colours in the chart's layout (black
gaps and frame), warped in perspective, seen by hidden cameras whose colour matrices come from colour-science's
camera spectral sensitivities (integrated against the patches' reflectances under an illuminant, fitted as a
3x3 matrix from the working space, white balanced) and hidden tone curves from colour-science's transfer
functions. The real chart is Infinite-ISP's raw ColorChecker frame (``../shared/data/infinite-isp-raw``).
"""
from __future__ import annotations

import os
from pathlib import Path

import colour
import cv2
import numpy as np
import pytest

from lowcam.colour_checker import (COLUMNS, NEUTRALS, ROWS, find_chart, read_colour_checker, read_patches,
                                   reference_colours)
from lowcam.effects.saturation import colour_matrix_problems, saturation_matrix
from lowcam.errors import LowcamError

DATA = Path(os.environ.get("LOWCAM_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")
SHAPE = colour.SpectralShape(400, 700, 5)
ILLUMINANTS = ("D65", "D50", "A", "FL2", "FL11")


def camera_matrix(rng) -> tuple[np.ndarray, str]:
    """A camera's white-balanced colour matrix (rows sum to 1: linear Rec.709 -> camera RGB) and its description:
    colour-science's camera sensitivities (a random mix of the two cameras it holds, each channel shifted by up
    to 8 nm) integrated against the Ohta ColorChecker reflectances under a random illuminant, then the 3x3
    matrix fitted from the patches' reference colours."""
    names = list(colour.MSDS_CAMERA_SENSITIVITIES)
    mix = rng.uniform(0.0, 0.35)
    shifts = rng.uniform(-8, 8, 3)
    ill = ILLUMINANTS[rng.integers(len(ILLUMINANTS))]
    wl = SHAPE.wavelengths
    sens = np.zeros((len(wl), 3))
    for name, weight in zip(names, (1 - mix, mix)):
        msds = colour.MSDS_CAMERA_SENSITIVITIES[name].copy().align(SHAPE, extrapolator_kwargs={"method": "Constant",
                                                                                                "left": 0, "right": 0})
        for c in range(3):
            sens[:, c] += weight * np.interp(wl - shifts[c], wl, msds.values[:, c], left=0, right=0)
    refl = np.array([sd.copy().align(SHAPE).values for sd in colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()])
    light = colour.SDS_ILLUMINANTS[ill].copy().align(SHAPE).values
    rgb = (refl * light) @ sens
    m = np.linalg.lstsq(reference_colours(), rgb, rcond=None)[0].T
    return m / m.sum(axis=1, keepdims=True), f"{names[0]} + {mix:.2f} {names[1]}, shifts {np.round(shifts, 1)} nm, {ill}"


def render_chart(light: np.ndarray, size=(640, 480), corners=None, background=0.18, frame=0.03,
                 supersample: int = 4) -> np.ndarray:
    """(H, W, 3) float linear light: a ColorChecker (24 patches ``light`` (24, 3) in a 6 x 4 grid, each 0.86 of its
    cell, black gaps and a frame of ``frame``) on a grey ``background``, the grid's outer corners at ``corners``
    (pixels: top-left, top-right, bottom-right, bottom-left), edges anti-aliased."""
    w, h = size
    if corners is None:
        corners = np.array([[0.15 * w, 0.2 * h], [0.85 * w, 0.2 * h], [0.85 * w, 0.2 * h + 0.7 * w * 4 / 6],
                            [0.15 * w, 0.2 * h + 0.7 * w * 4 / 6]])
    cell = 64
    chart = np.full((ROWS * cell + cell // 2, COLUMNS * cell + cell // 2, 3), frame, np.float32)
    pad = cell // 4
    for k in range(24):
        y, x = pad + (k // COLUMNS) * cell, pad + (k % COLUMNS) * cell
        g = int(round(0.07 * cell))
        chart[y + g:y + cell - g, x + g:x + cell - g] = light[k]
    src = np.array([[pad, pad], [pad + COLUMNS * cell, pad], [pad + COLUMNS * cell, pad + ROWS * cell],
                    [pad, pad + ROWS * cell]], np.float32)
    s = supersample
    hom = cv2.getPerspectiveTransform(src - 0.5, (np.asarray(corners, np.float32) + 0.5) * s - 0.5)
    big = cv2.warpPerspective(chart, hom, (w * s, h * s), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=(np.nan, np.nan, np.nan))  # the cyan's red is below 0 in Rec.709
    big = np.where(np.isnan(big), np.float32(background), big)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


def jittered_corners(rng, size=(640, 480), jitter=0.04):
    w, h = size
    base = np.array([[0.15 * w, 0.18 * h], [0.85 * w, 0.18 * h], [0.85 * w, 0.18 * h + 0.7 * w * 4 / 6],
                     [0.15 * w, 0.18 * h + 0.7 * w * 4 / 6]])
    return base + rng.uniform(-jitter, jitter, base.shape) * w


CURVES = {  # colour-science's transfer functions, and the same curve as Lowcam's tone curve writes it
    "BT.709": (colour.models.oetf_BT709, {"gamma": 1 / 0.45, "toe_break": 0.018}),
    "sRGB": (colour.models.eotf_inverse_sRGB, {"gamma": 2.4, "toe_break": 0.0031308}),
    "gamma 2.2": (lambda x: np.clip(x, 0.0, None) ** (1 / 2.2), {"gamma": 2.2, "toe_break": 0.0}),
}


def shoot(rng, total: np.ndarray, curve, frames: int = 1, exposure: float = 0.8, sigma_dn: float = 2.0):
    """8-bit frames of a perspective-warped chart: linear light ``exposure`` x reference, the camera's ``total``
    matrix, the transfer ``curve`` (to 0-1), 255 x, Gaussian noise of ``sigma_dn`` (the processor's, after the
    curve), rounded and clipped; and the chart's true corners."""
    corners = jittered_corners(rng)
    light = render_chart(reference_colours() * exposure, corners=corners) @ total.T
    encoded = 255.0 * curve(np.clip(light, 0.0, None))
    return [np.clip(np.round(encoded + rng.normal(0, sigma_dn, encoded.shape)), 0, 255).astype(np.uint8)
            for _ in range(frames)], corners


def relative_error(fitted, hidden) -> float:
    return float(np.linalg.norm(np.asarray(fitted) - hidden) / np.linalg.norm(hidden))


def test_cameras_are_plausible():
    """The hidden cameras drawn from colour-science's sensitivities are cameras Lowcam accepts (white balanced,
    each channel weighing itself most, colour not folded away)."""
    rng = np.random.default_rng(11)
    for _ in range(6):
        k, about = camera_matrix(rng)
        assert np.allclose(k.sum(axis=1), 1.0) and not colour_matrix_problems(k), about
        assert (np.diag(k) == k.max(axis=1)).all(), about


@pytest.mark.slow  # about 4 s
def test_chart_found_and_patches_read():
    """The chart is found within a pixel of where it was drawn (in perspective), the right way up, and every
    patch's mean is the drawn colour within 4 times the noise the reading gives it."""
    rng = np.random.default_rng(3)
    k, _ = camera_matrix(rng)
    curve = CURVES["gamma 2.2"][0]
    frames, corners = shoot(rng, k, curve)
    found = find_chart(frames[0])
    assert found is not None and np.abs(found - corners).max() < 1.5
    reading = read_patches(frames[0].astype(np.float64), found)
    truth = 255.0 * curve(np.clip(0.8 * reference_colours() @ k.T, 0.0, None))
    assert not reading.clipped.any()
    assert np.abs(reading.mean - truth).max() < 4 * reading.noise.max() + 0.05
    # noise of a mean over ~1000 pixels of sigma 2 DN: about 2 / sqrt(1000)
    assert 0.03 < np.median(reading.noise) < 0.12


@pytest.mark.slow  # the chart found twice: about 4 s
def test_noisy_frames_of_one_view_are_one_view_and_a_moving_one_is_named():
    """Four frames of one view under heavy noise (8 DN) are read as one view: the chart found once, on their mean,
    within a pixel of where it was drawn; the same frames with the third moved by 3 px are refused in one line
    naming that frame."""
    rng = np.random.default_rng(12)
    k, _ = camera_matrix(rng)
    frames, corners = shoot(rng, k, CURVES["sRGB"][0], frames=4, sigma_dn=8.0)
    names = [f"f{i}.png" for i in range(4)]
    reading = read_colour_checker(frames, names)
    assert np.abs(reading.corners - corners).max() < 1.5
    frames[2] = np.roll(frames[2], 3, axis=1)
    with pytest.raises(LowcamError, match=r"^f2\.png: the ColorChecker moved by [0-9.]+ px against f0\.png") as e:
        read_colour_checker(frames, names)
    assert len(str(e.value).splitlines()) == 1


def _calibrate(tmp_path, frames, base, saturation: float, name: str):
    from lowcam.cli import main

    folder = tmp_path / name
    folder.mkdir()
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i}.png"), f[..., ::-1])
    out, report = tmp_path / f"{name}.toml", tmp_path / f"{name}.json"
    args = ["calibrate", "colour", str(folder / "*.png"), "--target", "colorchecker", "--saturation", str(saturation),
            "--profile", str(base), "-o", str(out), "--json", str(report)]
    assert main(args) == 0
    import json

    from lowcam.profile import load_profile

    numbers = json.loads(report.read_text())["calibrations"][0]["numbers"]
    return load_profile(out), numbers


@pytest.mark.slow  # each chart is found in about 2 s
def test_calibrate_recovers_hidden_cameras(tmp_path, capsys):
    """Cameras drawn at random (seeded) from colour-science's sensitivities, under hidden tone curves and
    saturation settings: ``lowcam calibrate colour --target colorchecker`` fits them to the patches' noise (fit
    error <= 1.25), recovers the crosstalk within 2 % (relative Frobenius norm) and the curve's gamma within 2 %."""
    from lowcam.profile import load_profile

    base = tmp_path / "base.toml"
    # these cameras have no fall-off: nor has the profile (the fit takes the profile's as the camera's)
    load_profile("fire-i").with_effect("tone_curve", gamma=2.0).without("vignetting").save(base)
    rng = np.random.default_rng(2026)
    for i in range(4):
        k, about = camera_matrix(rng)
        saturation = float(rng.choice([65.0, 90.0]))
        name = list(CURVES)[i % len(CURVES)]
        curve, truth = CURVES[name]
        frames, _ = shoot(rng, saturation_matrix(saturation) @ k, curve, frames=2, exposure=rng.uniform(0.6, 0.85))
        profile, numbers = _calibrate(tmp_path, frames, base, saturation, f"cam{i}")
        fitted = profile.effect("crosstalk").matrix
        error = relative_error(fitted, k)
        print(f"{about}, {name}, saturation {saturation:g}: fit error {numbers['fit_error']:.3f}, matrix "
              f"{100 * error:.3f} %, gamma {profile.effect('tone_curve').gamma:.3f} (hidden {truth['gamma']:.3f})")
        assert numbers["fit_error"] <= 1.25, about
        assert error <= 0.02, about
        assert profile.effect("tone_curve").gamma == pytest.approx(truth["gamma"], rel=0.02)
        assert profile.effect("saturation").saturation == saturation


def test_linear_camera_without_tone_curve(tmp_path):
    """A profile without a tone curve fits the matrix alone; a linear camera is fitted to its noise."""
    from lowcam.calibrate.colour import calibrate_colour

    rng = np.random.default_rng(8)
    k, about = camera_matrix(rng)
    frames, _ = shoot(rng, k, lambda x: x, frames=1, exposure=0.85)
    reading = read_colour_checker(frames, ["linear.png"])
    cal = calibrate_colour(reference_colours() * 255, reading.mean, 65.0, None, "linear", reading.noise, None,
                           ~reading.clipped)
    assert cal.numbers["fit_error"] <= 1.25 and "tone_curve" not in cal.values
    assert relative_error(cal.values["crosstalk"]["matrix"], k) <= 0.02, about


@pytest.mark.parametrize("spelling", ["colorchecker", "colourchecker"])
def test_no_chart_is_one_line_naming_the_frame(tmp_path, capsys, spelling):
    """A frame without a ColorChecker (here a grey wall with a smooth light) is refused in one line naming it; the
    target is looked for under either spelling the target parser accepts."""
    from lowcam.cli import main

    y, x = np.mgrid[0:240, 0:320]
    wall = np.clip(100 + 0.1 * x + 0.05 * y, 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "wall.png"), np.repeat(wall[..., None], 3, axis=2))
    rc = main(["calibrate", "colour", str(tmp_path / "wall.png"), "--target", spelling,
               "-o", str(tmp_path / "cam.toml")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "wall.png" in err and "no ColorChecker" in err
    assert not (tmp_path / "cam.toml").exists()
    with pytest.raises(LowcamError, match="colours, not points"):
        from lowcam.captures import detect_target, parse_target
        detect_target(wall, parse_target("colorchecker"))


@pytest.mark.slow  # the fire-i chain on four frames, twice
def test_compare_finds_a_missing_colour_matrix(tmp_path):
    """A ``target = "colorchecker"`` capture filmed through the Fire-i with a hidden crosstalk (a camera from
    colour-science's data): the patches' mean residual is far above the noise for the Fire-i's own crosstalk and
    at the noise for the hidden one."""
    from lowcam.measure.compare import compare
    from lowcam.measure.sets import load_set
    from lowcam.outputs import write_png
    from lowcam.pipeline import simulate
    from lowcam.profile import load_profile

    rng = np.random.default_rng(5)
    k, about = camera_matrix(rng)
    base = load_profile("fire-i")
    hidden = base.with_effect("crosstalk", matrix=k.tolist(), extra_mixing=0.0)
    corners = np.array([[400, 330], [880, 330], [880, 650], [400, 650]], float) + rng.uniform(-15, 15, (4, 2))
    ideal = np.ones((960, 1280, 4), np.float32)
    ideal[..., :3] = render_chart(reference_colours() * 0.7, size=(1280, 960), corners=corners)
    (tmp_path / "frames").mkdir()
    for i in range(4):
        write_png(tmp_path / "frames" / f"cc-{i:03d}.png", simulate(ideal, hidden, None, seed=7, frame=i))
    (tmp_path / "set.toml").write_text('[[capture]]\nname = "cc"\ntarget = "colorchecker"\n'
                                       'frames = ["frames/cc-*.png"]\n')
    mset = load_set(tmp_path, base)
    wrong, right = compare(mset, base), compare(mset, hidden)
    print(f"{about}: mean error {wrong.families['mean']:.2f} (Fire-i), {right.families['mean']:.2f} (hidden)")
    assert wrong.families["mean"] > 4.0 and right.families["mean"] < 1.2
    mask = right.captures[0].sums["mask"]
    assert 0.05 < mask.mean() < 0.5  # the patches' inner halves only


@pytest.mark.slow  # a 1920x1080 raw frame
def test_real_colorchecker_raw():
    """Infinite-ISP's raw ColorChecker (12-bit BGGR, light booth, barrel distortion and vignetting), dark frame
    subtracted and demosaiced by 2x2 blocks: the chart is found with all 24 patches unclipped, the fitted matrix
    makes the neutral patches grey within 15 % between channels (8-13 % seen), and the fit's error stays bounded (the booth's
    uneven light and the sensor's spectral mismatch are not noise: about 57 noise units, 16 DN RMS of 250)."""
    from lowcam.calibrate.colour import calibrate_colour

    folder = DATA / "infinite-isp-raw"
    path = folder / "ColorCheckerRAW_1920x1080_12bit_BGGR.raw"
    if not path.is_file():
        pytest.skip("no shared data")
    raw = np.fromfile(path, "<u2").reshape(1080, 1920).astype(np.float64)
    dark = np.fromfile(folder / "BlackImage_1920x1080_12bits_BGGR.raw", "<u2").reshape(1080, 1920).astype(np.float64)

    def planes(x):  # BGGR: red at odd rows and columns, blue at even
        return x[1::2, 1::2], 0.5 * (x[0::2, 1::2] + x[1::2, 0::2]), x[0::2, 0::2]

    rgb = np.dstack([p - np.median(d) for p, d in zip(planes(raw), planes(dark))])
    corners = find_chart(rgb)
    assert corners is not None
    reading = read_patches(rgb, corners, floor=-np.inf, ceiling=4090.0)
    assert len(reading.mean) == 24 and not reading.clipped.any()
    # the reading follows the chart: the neutral row falls from white to black in every channel
    assert (np.diff(reading.mean[list(NEUTRALS)], axis=0) < 0).all()
    scale = 250.0 / reading.mean.max()
    cal = calibrate_colour(reference_colours() * 255, reading.mean * scale, 65.0, None, "raw",
                           reading.noise * scale, None, ~reading.clipped)
    total = np.array(cal.numbers["total_matrix"])
    neutral = np.linalg.solve(total, (reading.mean[list(NEUTRALS)] * scale).T).T
    spread = neutral.max(axis=1) / neutral.min(axis=1)
    print(f"real raw: fit error {cal.numbers['fit_error']:.1f}, RMS {cal.numbers['rms_residual_dn']:.1f} DN, "
          f"neutral channel spread {np.round(100 * (spread - 1), 1)} %")
    assert (spread < 1.15).all()
    assert cal.numbers["fit_error"] < 100 and cal.numbers["rms_residual_dn"] < 25


def colorchecker_set(folder, hidden, rng, captures: int = 2, frames: int = 4):
    """A measurement set of ``target = "colorchecker"`` captures filmed by the profile ``hidden``: the chart in
    perspective at random places, exposures and backgrounds, rendered at twice the output size."""
    from lowcam.outputs import write_png
    from lowcam.pipeline import simulate

    entries = []
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    for c in range(captures):
        corners = np.array([[400, 330], [880, 330], [880, 650], [400, 650]], float) + rng.uniform(-40, 40, (4, 2))
        ideal = np.ones((960, 1280, 4), np.float32)
        ideal[..., :3] = render_chart(reference_colours() * rng.uniform(0.5, 0.8), size=(1280, 960), corners=corners,
                                      background=rng.uniform(0.1, 0.3))
        for i in range(frames):
            write_png(folder / "frames" / f"cc{c}-{i:03d}.png", simulate(ideal, hidden, None, seed=7 + c, frame=i))
        entries.append(f'[[capture]]\nname = "cc{c}"\ntarget = "colorchecker"\nframes = ["frames/cc{c}-*.png"]\n')
    (folder / "set.toml").write_text("\n".join(entries))
    return folder


@pytest.mark.slow  # diagnosis of two candidates on two captures: about a minute
def test_diagnose_finds_a_missing_colour_matrix_on_the_chart(tmp_path):
    """Two ColorChecker captures through the Fire-i with a hidden crosstalk from colour-science's camera data:
    diagnosis ranks ``colour_matrix`` first and its fitted crosstalk is the hidden one within 2 %."""
    from lowcam.measure.diagnose import diagnose
    from lowcam.measure.sets import load_set
    from lowcam.profile import load_profile

    rng = np.random.default_rng(1)
    base = load_profile("fire-i")
    k, about = camera_matrix(rng)
    folder = colorchecker_set(tmp_path / "set", base.with_effect("crosstalk", matrix=k.tolist(), extra_mixing=0.0),
                              rng)
    d = diagnose(load_set(folder, base), base, only=["colour_matrix", "tone_curve"], workdir=tmp_path / "work")
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    print(f"{about}: error {d.error:.2f}, {ranking}")
    assert d.error > 3 and d.candidates[0].effect == "colour_matrix", ranking
    fitted = d.candidates[0].profile.effect("crosstalk").total_matrix()
    assert relative_error(fitted, k) < 0.02, (fitted, k)


def turned_chart_set(folder, hidden, angles=(0.0, 4.0, -3.0), frames: int = 4, light: float = 0.7):
    """A measurement set of ``target = "colorchecker"`` captures filmed by the profile ``hidden`` (its lens, its
    fall-off, its noise): the chart straight on at the middle of a 1280x960 render, turned by each of ``angles``
    (deg) about its centre, ``frames`` frames each (seeded noise); captures ``cc0``, ``cc1``, ..."""
    from lowcam.outputs import write_png
    from lowcam.pipeline import simulate

    (folder / "frames").mkdir(parents=True, exist_ok=True)
    half = np.array([[-240, -160], [240, -160], [240, 160], [-240, 160]], float)
    entries = []
    for c, angle in enumerate(angles):
        a = np.radians(angle)
        corners = half @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + [640, 480]
        ideal = np.ones((960, 1280, 4), np.float32)
        ideal[..., :3] = render_chart(reference_colours() * light, size=(1280, 960), corners=corners, background=0.2)
        for i in range(frames):
            write_png(folder / "frames" / f"cc{c}-{i:03d}.png", simulate(ideal, hidden, None, seed=11 + c, frame=i))
        entries.append(f'[[capture]]\nname = "cc{c}"\ntarget = "colorchecker"\nframes = ["frames/cc{c}-*.png"]\n')
    (folder / "set.toml").write_text("\n".join(entries))
    return folder


@pytest.mark.slow  # per camera: 12 frames filmed, a calibration and a comparison of three captures (minutes)
def test_calibration_through_a_wide_lens_explains_every_capture(tmp_path):
    """Charts filmed through the Fire-i (its 113 deg lens, its fall-off to 0.6 in the corners, its noise) with hidden
    crosstalk matrices drawn at random (seeded, colour-science's camera data): ``lowcam calibrate colour --target
    colorchecker`` takes a capture's four noisy frames of one view (the chart found once, on their mean), fits the
    hidden crosstalk within 0.02 in every element (measured: 0.001-0.002; the fall-off across the chart is the
    profile's) near the patches' noise (fit error at most 4; measured: 2.5-2.9), and ``compare`` of all three
    captures (straight on, turned by 4 and -3 deg) with the calibrated profile is at most 1.5 (measured: 1.04-1.05;
    the Fire-i's own crosstalk: 5.4). Diagnosis's ``colour_matrix`` candidate on the same captures finds the
    calibration's crosstalk within 0.02 in every element (measured: 0.002)."""
    from lowcam.measure.compare import compare
    from lowcam.measure.diagnose import diagnose
    from lowcam.measure.sets import load_set
    from lowcam.profile import load_profile

    base = load_profile("fire-i")
    rng = np.random.default_rng(38)
    for trial in range(2):
        k, about = camera_matrix(rng)
        hidden = base.with_effect("crosstalk", matrix=k.tolist(), extra_mixing=0.0)
        folder = turned_chart_set(tmp_path / f"set{trial}", hidden)
        frames = [cv2.imread(str(p))[..., ::-1] for p in sorted((folder / "frames").glob("cc0-*.png"))]
        profile, numbers = _calibrate(tmp_path, frames, "fire-i", base.effect("saturation").saturation, f"cam{trial}")
        fitted = np.array(profile.effect("crosstalk").matrix)
        mset = load_set(folder, base)
        after = compare(mset, profile)
        print(f"{about}: fit error {numbers['fit_error']:.2f}, crosstalk off by {np.abs(fitted - k).max():.4f}, "
              f"compare {after.error:.2f}")
        assert np.abs(fitted - k).max() <= 0.02, (fitted, k)
        assert numbers["fit_error"] <= 4.0
        assert after.error <= 1.5
        if trial == 0:  # diagnosis's colour_matrix candidate on the same captures finds the same crosstalk
            d = diagnose(mset, base, only=["colour_matrix"], workdir=tmp_path / "work")
            found = d.candidates[0].profile.effect("crosstalk").total_matrix()
            calibrated = profile.effect("crosstalk").total_matrix()
            print(f"diagnosis's crosstalk off the calibration's by {np.abs(found - calibrated).max():.4f}")
            assert np.abs(found - calibrated).max() <= 0.02
