"""Verdicts that real footage earns: fitted numbers the data determine, fits a real camera can have, decisions on
captures held out of the fit, and a reason for every candidate that cannot be fitted.

The data: the real chessboard views of another camera (``../shared/data/opencv-chessboard-left``: a monochrome
stereo-rig camera delivering JPEG), and hidden effects written in this file (a polynomial fall-off, colour casts
that differ from capture to capture) on the profile's frames.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lowcam
from helpers import diagnose_set, make_set, quiet_fire_i
from lowcam.measure.diagnose import diagnose
from lowcam.measure.sets import load_set

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
CHESSBOARD = SHARED / "opencv-chessboard-left"


def to_uint8(x):
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def radius2(profile):
    """rho^2 of every output pixel: the distance from the frame centre over the half-diagonal, squared."""
    h, w = profile.camera.height, profile.camera.width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)


@pytest.fixture(scope="module")
def chessboard_set(tmp_path_factory):
    """Four real views as ``target`` captures, and the Fire-i profile with the lens calibrated from all 13."""
    from lowcam.calibrate import apply_to_profile, calibrate_lens

    if not CHESSBOARD.is_dir():
        pytest.skip("../shared/data is not beside the repository")
    tmp = tmp_path_factory.mktemp("left")
    frames = sorted(CHESSBOARD.glob("*.jpg"))
    cal = calibrate_lens(frames, "checkerboard:9x6:0.025", ("opencv",))
    profile = apply_to_profile(lowcam.load_profile("fire-i"), [cal], tmp / "left.toml")
    profile.save(tmp / "left.toml")
    (tmp / "set").mkdir()
    (tmp / "set" / "set.toml").write_text("".join(
        f'[[capture]]\nname = "{f.stem}"\ntarget = "checkerboard:9x6:0.025"\nframes = ["{f}"]\n\n'
        for f in frames[:4]))
    return tmp, lowcam.load_profile(tmp / "left.toml")


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_a_grey_target_determines_no_colour_matrix_and_the_grey_camera_is_monochrome(chessboard_set):
    """On a black-and-white board every set of colour weights summing to 1 gives the same ideal: the colour matrix
    is not offered (it was, with a negative green weight), and ``monochrome`` keeps the profile's weights."""
    tmp, profile = chessboard_set
    mset = load_set(tmp / "set", profile)
    d = diagnose(mset, profile, only=["monochrome", "colour_matrix"], workdir=tmp / "work", rounds=1)
    assert "no colour" in d.not_fitted.get("colour_matrix", ""), d.not_fitted
    assert [c.effect for c in d.candidates] == ["monochrome"], d.candidates
    best = d.best
    assert best.held_out is not None and best.held_out < d.error, (best.held_out, d.error)
    assert best.validation == "leave-one-out over 4 captures"
    assert best.params["luma"] == pytest.approx(profile.effect("saturation").luma, abs=1e-4)
    assert "grey scene does not determine" in best.params["luma_weights"]


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_vignetting_of_views_that_never_reach_the_corners_holds_its_outer_term(tmp_path):
    """A fall-off 1 - 0.25 rho^2 - 0.1 rho^4 written on the frames, compared only within 70 % of the half-diagonal
    (the captures' masks): k4 acts mostly beyond, so it is held at the profile's value and said so; over the
    whole frame both terms are fitted."""
    profile = quiet_fire_i()
    rho2 = radius2(profile)
    gain = (1 - 0.25 * rho2 - 0.1 * rho2 ** 2)[..., None]
    scenes = ("flat-dark", "flat-bright", "photo")
    inner = diagnose_set(tmp_path / "inner", profile, ["vignetting"], rounds=1, scenes=scenes,
                         post=lambda f: to_uint8(f * gain), mask=rho2 < 0.49)
    whole = diagnose_set(tmp_path / "whole", profile, ["vignetting"], rounds=1, scenes=scenes,
                         post=lambda f: to_uint8(f * gain))
    held, free = inner.best, whole.best
    assert held.effect == free.effect == "vignetting"
    assert held.params["k4"] == 0.0 and held.params["k2"] < -0.2, held.params
    assert any("k4 held at the profile's value: the captures reach 70 % of the way" in f for f in held.flags)
    assert free.params["k4"] != 0.0 and not any("held" in f for f in free.flags), free.flags
    assert held.held_out <= 1.25, held.held_out


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_a_fit_that_does_not_carry_over_to_other_captures_gets_no_credit(tmp_path):
    """Each capture tinted its own way (red, green, blue gains of 1.12 on one channel: a per-shot white balance,
    written here on the delivered frames) is not a colour matrix of the camera: one matrix fitted to all of them
    lowers the error in sample, but not on the captures held out of its fit, and the loop would not add it."""
    profile = quiet_fire_i()
    scenes = ("photo", "chart", "noise-field", "flat-bright")
    tints = [(1.12, 1.0, 1.0), (1.0, 1.12, 1.0), (1.0, 1.0, 1.12), (1.06, 1.06, 1.0)]
    delivered = []

    def post(frame):  # make_set delivers each capture's 4 frames in a row
        tint = tints[len(delivered) // 4]
        delivered.append(frame)
        return to_uint8(frame * np.asarray(tint))

    folder = make_set(profile, tmp_path / "set", scenes=scenes, post=post)
    mset = load_set(folder, profile)
    d = diagnose(mset, profile, only=["colour_matrix"], workdir=tmp_path / "work", rounds=1)
    c = d.best
    assert c is not None and c.effect == "colour_matrix"
    assert c.error_after < 0.97 * d.error, (c.error_after, d.error)  # it gains in sample ...
    assert c.held_out > c.error_after * 1.03 and c.held_out > 0.97 * d.error, (c.held_out, d.error)  # ... not beyond
    assert c.score > 0.97 * d.error  # the loop adds an effect only where it lowers the decision error by 3 %


def test_one_capture_holds_nothing_out_and_its_closed_form_fit_takes_no_credit(tmp_path):
    """A tone curve (gamma 1.6, written on the frames) in one capture: the closed-form fit takes whole frames, so
    nothing can be held out; the candidate says so and ranks at the profile's own error, while a blur (a
    Gauss-Newton fit) is held out on image tiles."""
    profile = quiet_fire_i()
    folder = make_set(profile, tmp_path / "set", scenes=("photo",), frames=4,
                      post=lambda f: to_uint8(255 * (f / 255.0) ** (1 / 1.6)))
    mset = load_set(folder, profile)
    d = diagnose(mset, profile, only=["tone_curve", "horizontal_blur"], workdir=tmp_path / "work", rounds=1)
    by = {c.effect: c for c in d.candidates}
    tone = by["tone_curve"]
    assert tone.error_after < 0.5 * d.error, tone.error_after  # the fit itself works ...
    assert tone.held_out is None and "nothing can be held out" in tone.validation, tone.validation
    assert tone.score == pytest.approx(d.error)  # ... but earns no credit
    assert by["horizontal_blur"].validation.startswith("fitted on one of 2 folds of 64-px image tiles") or \
        by["horizontal_blur"].validation == "2 folds of 64-px image tiles", by["horizontal_blur"].validation
    assert d.verdict == "unexplained"


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_every_candidate_that_cannot_be_fitted_says_why(tmp_path):
    """``--only`` names candidates the set cannot show: the line, the JSON and the report give each one's
    reason (it printed only "no candidate could be fitted")."""
    profile = quiet_fire_i()
    make_set(profile, tmp_path / "set", scenes=("flat-bright", "flat-dark"), frames=2)
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "diagnose", str(tmp_path / "set"), "--only",
                        "motion_blur,rolling_shutter", "--json", str(tmp_path / "d.json"), "--report",
                        str(tmp_path / "report")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "motion_blur                  not fitted: no capture moves" in r.stdout, r.stdout
    assert "no candidate could be fitted: motion_blur: no capture moves" in r.stdout, r.stdout
    doc = json.loads((tmp_path / "d.json").read_text())
    assert {x["effect"]: x["reason"] for x in doc["not_fitted"]} == {"motion_blur": "no capture moves",
                                                                     "rolling_shutter": "no capture moves"}
    page = (tmp_path / "report" / "index.html").read_text()
    assert "<b>rolling_shutter</b>: no capture moves" in page


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_the_report_shows_held_out_errors_and_uncertainties(tmp_path):
    """The diagnosis report draws each candidate's error in sample beside its held-out error and lists its fitted
    numbers with their standard errors."""
    profile = quiet_fire_i()
    rho2 = radius2(profile)
    gain = (1 - 0.3 * rho2)[..., None]
    make_set(profile, tmp_path / "set", scenes=("flat-bright", "photo", "flat-dark"), frames=2,
             post=lambda f: to_uint8(f * gain))
    profile.save(tmp_path / "quiet.toml")
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "diagnose", str(tmp_path / "set"), "--profile",
                        str(tmp_path / "quiet.toml"), "--only", "vignetting,tone_curve", "--json",
                        str(tmp_path / "d.json"), "--report", str(tmp_path / "report")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "d.json").read_text())
    vig = next(c for c in doc["candidates"] if c["effect"] == "vignetting")
    assert vig["error_held_out"] is not None and vig["held_out"] == "leave-one-out over 3 captures"
    assert set(vig["uncertainty"]) == {"k2", "k4"} and all(v >= 0 for v in vig["uncertainty"].values())
    page = (tmp_path / "report" / "index.html").read_text()
    assert "<th>held out</th>" in page and f"k2 {vig['params']['k2']:.4g} &plusmn;" in page, page[:2000]
    assert (tmp_path / "report" / "candidates.png").stat().st_size > 5000


def test_fall_offs_and_colour_matrices_no_camera_has_are_named():
    from lowcam.effects import Crosstalk, Noise, Saturation, Vignetting

    assert Vignetting(k2=0.5).implausible() == ["a fall-off that rises 50 % away from the centre"]
    assert Vignetting(k2=-0.3, k4=-0.1).implausible() == []
    assert "corners at 0.00" in Vignetting(k2=-1.0, k4=-0.5).implausible()[0]
    assert Crosstalk(matrix=[[0.91, -0.73, 0.81]] * 3, extra_mixing=0.0).implausible()[0] == \
        "the crosstalk weighs green at -0.73 on itself"
    assert Crosstalk().implausible() == []
    assert Saturation(luma=[0.3, 0.3, 0.3]).implausible() == ["luma weights summing to 0.900"]
    assert Noise(green=[-0.757, 0.029]).implausible() == ["green noise is 0 below 26 DN"]
