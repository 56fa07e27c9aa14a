"""Model against measurement: hidden effects are found, fitted and explain the data.

Every test hides something in a synthetic measurement set made from bundled scenes (the data has it, the
diagnosed profile does not, or has it wrong) and checks that `diagnose` ranks the right candidate first and that
adding it brings the error down to the noise floor. Strengths and seeds vary from test to test.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lowcam
from lowcam.measure.diagnose import NAMED_GAIN, diagnose
from lowcam.measure.sets import load_set
from lowcam.measure.synth import synthesise

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def draw(seed, lo, hi):
    return float(np.random.default_rng(seed).uniform(lo, hi))


# candidate -> (effects added to the data, effects switched off in the diagnosed profile, changes in the data)
HIDDEN = {
    "vignetting": ([], ["vignetting"]),
    "chromatic_aberration": ([], ["chromatic_aberration"]),
    "motion_blur": ([], ["motion_blur"]),
    "chroma_subsampling": ([], ["chroma_subsampling"]),
    "radial_distortion": ([("lens_distortion", {"w": 0.93 + draw(1, 0.08, 0.15)})], []),
    "tone_curve": ([("tone_curve", {"gamma": draw(2, 1.6, 2.4)})], []),
    "rolling_shutter": ([("rolling_shutter", {"readout_s": draw(3, 0.02, 0.04)})], []),
    "prnu": ([("prnu", {"strength": draw(4, 0.02, 0.04), "pattern_seed": 4})], []),
    "dsnu": ([("dsnu", {"strength": draw(5, 1.5, 3.0), "pattern_seed": 5})], []),
    "row_noise": ([("row_noise", {"sigma_dn": draw(6, 1.5, 3.0)})], []),
    "hot_pixels": ([("hot_pixels", {"strength": draw(7, 80, 150), "fraction": 0.001, "pattern_seed": 7})], []),
    "vertical_blur": ([("vertical_blur", {"sigma": draw(8, 0.6, 1.0)})], []),
    "vertical_blur_after_sharpening": ([("vertical_blur", {"after": "demosaic", "sigma": draw(13, 0.6, 1.0)})], []),
    "defocus": ([("defocus", {"radius_px": draw(9, 1.5, 3.0)})], []),
    "asymmetric_sharpening": ([("sharpening", {"shift": draw(10, 0.4, 0.8)})], []),
    "jpeg": ([("jpeg", {"quality": int(draw(11, 50, 75))})], []),
    "noise_reduction": ([("noise_reduction", {"luma_strength_dn": draw(14, 15.0, 35.0),
                                              "scale_px": draw(16, 1.5, 3.0)})], []),
    "edge_enhancement": ([("edge_enhancement", {"gain": draw(15, 0.8, 1.8), "radius_px": draw(17, 0.8, 2.0),
                                                "coring_dn": draw(18, 1.0, 4.0)})], []),
    "local_tone_mapping": ([("local_tone_mapping", {"clip_limit": draw(19, 2.0, 4.0),
                                                    "strength": draw(20, 0.5, 0.9)})], []),
    "temporal_noise_reduction": ([("temporal_noise_reduction", {"strength": draw(21, 0.4, 0.8),
                                                                "motion_threshold_dn": draw(22, 8.0, 32.0)})], []),
    "video_codec": ([("video_codec", {"crf": int(draw(23, 26, 34)), "gop_frames": 250})], []),
    "veiling_glare": ([("veiling_glare", {"strength": draw(12, 0.05, 0.1), "radius_px": draw(12, 40, 80)})], []),
    "bilinear_demosaic": ([("demosaic", {"method": "bilinear"})], []),
    "gradient_corrected_demosaic": ([("demosaic", {"method": "gradient_corrected"})], []),
    "edge_aware_demosaic": ([("demosaic", {"method": "edge_aware"})], []),
    "colour_matrix": ([("crosstalk", {"matrix": [[0.85, 0.1, 0.05], [0.12, 0.8, 0.08], [0.05, 0.12, 0.83]]})], []),
    "quantisation_bits": ([("quantisation", {"bits": 5})], []),
    "monochrome": ([("saturation", {"saturation": 0.0})], []),
    "horizontal_blur": ([], []),  # the profile's sigma is wrong: see the parametrisation below
}


ALL_SCENES = ("chart", "photo", "noise-field", "flat-bright", "flat-dark", "pan")
#: candidate -> (scenes of its small focused set, decoys: candidates it could be mistaken for)
FOCUS = {
    "vignetting": (("flat-bright", "flat-dark", "photo"), ("tone_curve", "veiling_glare")),
    "chromatic_aberration": (("chart", "noise-field"), ("radial_distortion", "defocus")),
    "motion_blur": (("pan", "photo"), ("rolling_shutter", "horizontal_blur")),
    "chroma_subsampling": (("photo", "chart"), ("jpeg", "colour_matrix")),
    "radial_distortion": (("chart", "noise-field"), ("chromatic_aberration", "vignetting")),
    "tone_curve": (("flat-bright", "flat-dark", "photo"), ("colour_matrix", "vignetting")),
    "rolling_shutter": (("pan", "photo"), ("motion_blur", "radial_distortion")),
    # per-pixel maps are judged out of sample: with few captures the correction alone passes 1.25
    "prnu": (ALL_SCENES, ("dsnu", "vignetting")),
    "dsnu": (ALL_SCENES, ("prnu", "hot_pixels")),
    "row_noise": (("flat-bright", "photo"), ("dsnu", "quantisation_bits")),
    "hot_pixels": (("flat-dark", "flat-bright", "photo"), ("dsnu", "prnu")),
    "vertical_blur": (("chart", "noise-field"), ("defocus", "horizontal_blur")),
    "vertical_blur_after_sharpening": (("chart", "noise-field"), ("vertical_blur", "defocus")),
    "defocus": (("chart", "noise-field"), ("vertical_blur", "asymmetric_sharpening")),
    "asymmetric_sharpening": (("chart", "noise-field"), ("horizontal_blur", "defocus")),
    "jpeg": (("photo", "noise-field"), ("chroma_subsampling", "defocus")),
    "noise_reduction": (("flat-bright", "photo", "noise-field"), ("dsnu", "defocus")),
    "edge_enhancement": (("chart", "noise-field"), ("asymmetric_sharpening", "defocus")),
    "local_tone_mapping": (("flat-dark", "photo", "chart"), ("tone_curve", "veiling_glare")),
    "temporal_noise_reduction": (("flat-bright", "photo"), ("noise_reduction", "video_codec")),
    "video_codec": (("flat-bright", "photo"), ("jpeg", "temporal_noise_reduction")),
    "veiling_glare": (("chart", "photo"), ("tone_curve", "vignetting")),
    "bilinear_demosaic": (("noise-field", "photo"), ("horizontal_blur", "chroma_subsampling")),
    "gradient_corrected_demosaic": (("noise-field", "photo"), ("bilinear_demosaic", "horizontal_blur")),
    "edge_aware_demosaic": (("noise-field", "photo"), ("bilinear_demosaic", "gradient_corrected_demosaic")),
    "colour_matrix": (("photo", "chart"), ("tone_curve", "chroma_subsampling")),
    "quantisation_bits": (("flat-bright", "photo"), ("tone_curve", "row_noise")),
    "monochrome": (("photo", "chart"), ("colour_matrix", "chroma_subsampling")),
    "horizontal_blur": (("chart", "noise-field"), ("defocus", "vertical_blur")),
}


def assert_verdict_matches_numbers(d):
    """The verdict follows from the numbers printed beside it, and the summary prints them."""
    best = d.best
    if d.error <= 1.1:
        assert d.verdict == "explained", d.summary()
    elif best is not None and best.score <= 1.25 and best.score <= d.error * (1 - NAMED_GAIN):
        assert d.verdict == "missing-effect" and f"{best.score:.3f}" in d.summary(), d.summary()
    else:
        assert d.verdict == "unexplained", d.summary()
    assert best is None or best.full and best.held_out_full, "the best candidate's errors are always the full ones"
    doc = d.as_json()
    ranked = [c["score"] for c in doc["candidates"][len(d.added):]]
    assert ranked == sorted(ranked), "candidates are ranked by their decision error"
    for c in doc["candidates"]:
        # the decision error is the held-out one; without one the candidate takes no credit
        expected = c["error_held_out"] if c["error_held_out"] is not None else max(c["error_after"], d.error)
        assert abs(c["score"] - expected) < 1e-3 and c["held_out"] and "error_is_estimate" in c, c


def run_case(tmp_path, fire_i, add, remove, seed, diagnosed=None, only=None, only_scenes=None, frames=6):
    folder = synthesise(fire_i, tmp_path / "set", add=add, seed=seed, frames=frames, only_scenes=only_scenes)
    profile = diagnosed or (fire_i.without(*remove) if remove else fire_i)
    d = diagnose(load_set(folder, profile), profile, only=only, workdir=tmp_path / "work")
    assert_verdict_matches_numbers(d)
    return d


def hidden_case(fire_i, candidate):
    """(effects added to the data, effects switched off, the diagnosed profile or None) for a candidate."""
    add, remove = HIDDEN[candidate]
    diagnosed = None
    if candidate == "horizontal_blur":  # a wrong parameter: the profile's sigma doubled
        diagnosed = fire_i.with_effect("horizontal_blur", sigma=2 * fire_i.effect("horizontal_blur").sigma)
    return add, remove, diagnosed


def test_every_candidate_has_a_hidden_case_and_a_focused_set():
    from lowcam.measure.diagnose import candidates

    assert set(HIDDEN) == set(FOCUS) == set(candidates())


#: Focused-set cases known to stop short: candidate -> why (strict: a pass fails it).
@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("candidate", HIDDEN)
def test_a_hidden_effect_beats_its_decoys_on_a_small_focused_set(tmp_path, fire_i, candidate):
    """A small focused set: 4 frames of 2-3 scenes that show the effect, the candidate against two it could be
    mistaken for."""
    add, remove, diagnosed = hidden_case(fire_i, candidate)
    scenes, decoys = FOCUS[candidate]
    d = run_case(tmp_path, fire_i, add, remove, seed=100 + len(candidate), diagnosed=diagnosed,
                 only=[candidate, *decoys], only_scenes=scenes, frames=4)
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    assert d.error > 1.1, f"the hidden {candidate} is not visible: error {d.error:.3f}"
    assert d.candidates[0].effect == candidate, ranking
    assert d.candidates[0].error_after <= 1.1, ranking
    assert d.verdict == "missing-effect"


#: Left out of the standard set: with every candidate and forward selection, a coded set's diagnosis runs over 10
#: minutes (once the codec is added, each later candidate's comparison codes every capture twice); the video codec
#: is judged on its focused set and in tests/test_candidate_video_codec.py.
NOT_ON_THE_STANDARD_SET = ("video_codec",)


@pytest.mark.slow
@pytest.mark.parametrize("candidate", [c for c in HIDDEN if c not in NOT_ON_THE_STANDARD_SET])
def test_a_hidden_effect_is_ranked_first_and_adding_it_reaches_the_noise_floor(tmp_path, fire_i, candidate):
    """The slow tier: the standard set (6 frames of every scene) against every candidate."""
    add, remove, diagnosed = hidden_case(fire_i, candidate)
    d = run_case(tmp_path, fire_i, add, remove, seed=100 + len(candidate), diagnosed=diagnosed)
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates[:4]]
    assert d.error > 1.1, f"the hidden {candidate} is not visible: error {d.error:.3f}"
    assert d.candidates[0].effect == candidate, ranking
    assert d.candidates[0].error_after <= 1.1, ranking
    assert d.verdict == "missing-effect"


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_a_set_with_nothing_hidden_is_explained(tmp_path, fire_i):
    d = run_case(tmp_path, fire_i, [], [], seed=31, only=["vignetting", "tone_curve", "dsnu"])
    assert d.verdict == "explained" and d.error <= 1.1


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_two_hidden_effects_both_surface_on_a_focused_set(tmp_path, fire_i):
    """A focused version of the next test: the two among four decoys, on the scenes that show them."""
    d = run_case(tmp_path, fire_i, [("tone_curve", {"gamma": 1.8})], ["vignetting"], seed=32, frames=4,
                 only=["tone_curve", "vignetting", "colour_matrix", "veiling_glare", "dsnu", "defocus"],
                 only_scenes=("flat-bright", "flat-dark", "photo"))
    top = [c.effect for c in d.candidates[:3]]
    assert "tone_curve" in top and "vignetting" in top, top


@pytest.mark.slow
def test_two_hidden_effects_both_surface_in_the_top_three(tmp_path, fire_i):
    d = run_case(tmp_path, fire_i, [("tone_curve", {"gamma": 1.8})], ["vignetting"], seed=32)
    top = [c.effect for c in d.candidates[:3]]
    assert "tone_curve" in top and "vignetting" in top, top


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_diagnose_cli_writes_json_and_adds_the_best_effect(tmp_path):
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "synth", "--add", "tone_curve:gamma=2.0", "-o",
                        str(tmp_path / "set")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "diagnose", str(tmp_path / "set"), "--only",
                        "gamma,vignetting,defocus", "--json", str(tmp_path / "d.json"), "--add-best", "-o",
                        str(tmp_path / "fixed.toml")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["verdict"] == "missing-effect" and doc["noise_floor"] == 1.0 and doc["error"] > 1.1
    assert doc["candidates"][0]["effect"] == "tone_curve" and abs(doc["candidates"][0]["params"]["gamma"] - 2.0) < 0.1
    assert {"channels", "regions", "bands", "intensities"} <= set(doc["where"])
    fixed = lowcam.load_profile(tmp_path / "fixed.toml")
    assert fixed.effect("tone_curve") is not None
    # the error falls step by step in compare's history
    for profile in ("fire-i", str(tmp_path / "fixed.toml")):
        r = subprocess.run([sys.executable, "-m", "lowcam.cli", "compare", str(tmp_path / "set"), "--profile",
                            profile, "--report", str(tmp_path / "report")], capture_output=True, text=True,
                           timeout=600)
        assert r.returncode == 0, r.stderr
    history = json.loads((tmp_path / "set" / ".lowcam" / "history.json").read_text())
    assert len(history) == 2 and history[1]["error"] < 1.1 < history[0]["error"]
    # what the ranking promised is what the next comparison gives: its error in sample within 5 %, and never more
    # than 5 % above its held-out error
    best = doc["candidates"][0]
    numbers = (history[1]["error"], best["error_after"], best["score"])
    assert abs(numbers[0] - numbers[1]) <= 0.05 * numbers[1] and numbers[0] <= 1.05 * numbers[2], numbers
    page = (tmp_path / "report" / "index.html").read_text()
    assert page.count("<img") >= 13 and (tmp_path / "report" / "history.png").is_file()


def test_a_user_plugin_effect_can_be_hidden_and_added(tmp_path, monkeypatch):
    (tmp_path / "lens_tint.py").write_text(
        "from lowcam.effects import Effect, Param\n"
        "class Tint(Effect):\n"
        "    '''A coloured lens: scales red (a user's own effect).'''\n"
        "    name = 'tint'\n"
        "    writes = 'rgb'\n"
        "    params = {'red_gain': Param(1.0, low=0.1, high=3.0)}\n"
        "    def apply(self, state):\n"
        "        state.rgb[..., 0] *= self.red_gain\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "lens_tint")  # the user's consent
    fire_i = lowcam.load_profile("fire-i")
    tinted = fire_i.with_effect("lens_tint:Tint", red_gain=1.15)
    assert tinted.effects[-1].name == "tint"
    saved = tinted.save(tmp_path / "tinted.toml")
    assert 'type = "lens_tint:Tint"' in saved.read_text()
    assert lowcam.load_profile(saved).effect("tint").red_gain == 1.15


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.skipif(not (SHARED / "opencv-chessboard-left").is_dir(), reason="../shared/data is not beside")
def test_compare_on_real_chessboard_frames_writes_a_report(tmp_path):
    from lowcam.calibrate import apply_to_profile, calibrate_lens

    frames = sorted((SHARED / "opencv-chessboard-left").glob("*.jpg"))
    cal = calibrate_lens(frames, "checkerboard:9x6:0.025", ("opencv",))
    profile = apply_to_profile(lowcam.load_profile("fire-i"), [cal], tmp_path / "left.toml")
    profile.save(tmp_path / "left.toml")
    entries = "".join(f'[[capture]]\nname = "{f.stem}"\ntarget = "checkerboard:9x6:0.025"\nframes = ["{f}"]\n\n'
                      for f in frames[:4])
    (tmp_path / "set").mkdir()
    (tmp_path / "set" / "set.toml").write_text(entries)
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "compare", str(tmp_path / "set"), "--profile",
                        str(tmp_path / "left.toml"), "--report", str(tmp_path / "report"), "--json",
                        str(tmp_path / "c.json")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "c.json").read_text())
    # another camera than the Fire-i: far above the noise floor, and mostly at low frequencies (uneven light,
    # the board's margin), as the README reports
    bands = {b["band"]: b["error"] for b in doc["where"]["bands"]}
    assert doc["error"] > 3 and len(doc["where"]["regions"]) == 9
    assert bands["low"] > bands["mid"] > bands["high"], bands
    assert (tmp_path / "report" / "residual_maps.png").stat().st_size > 5000


def test_with_one_frame_per_capture_added_model_noise_cannot_lower_the_error(tmp_path, fire_i):
    """The frames' noise cannot be measured from one frame: candidates are compared against the diagnosed
    profile's noise, so a profile that only adds noise does not look better (it would with its own noise)."""
    from lowcam.measure.compare import compare
    from lowcam.measure.diagnose import Context

    folder = synthesise(fire_i, tmp_path / "set", add=[("tone_curve", {"gamma": 1.3})], frames=1, seed=41,
                        only_scenes=("photo", "flat-dark"))
    mset = load_set(folder, fire_i)
    ctx = Context(mset, fire_i, tmp_path / "w")
    noisier = fire_i.with_effect("row_noise", sigma_dn=4.0).with_effect("quantisation", bits=4)
    assert compare(mset, noisier).error < 0.9 * ctx.base.error  # with its own noise as the yardstick it games
    assert ctx.compare(noisier).error >= ctx.base.error
    assert ctx.base.measured == {"mean": True, "variance": False, "rows": False}


@pytest.mark.parametrize("scenes, by_captures", [(("photo", "flat-bright", "flat-dark"), False),
                                                  (("photo", "chart", "flat-bright"), True)])
def test_no_fold_is_fitted_on_captures_that_cannot_determine_the_candidate(tmp_path, fire_i, scenes, by_captures):
    """A candidate whose parameters only textured captures determine (``determined_by``) is held out by capture
    only where every fold is fitted on a textured one; otherwise each capture's frames are split into tiles."""
    from lowcam.measure.diagnose import TILE_PX, Context

    folder = synthesise(fire_i, tmp_path / "set", frames=1, seed=5, width=320, only_scenes=scenes)
    ctx = Context(load_set(folder, fire_i), fire_i, tmp_path / "w")
    assert sorted(ctx.mset.captures[i].name for i in ctx.textured) == sorted(s for s in scenes if "flat" not in s)
    assert ctx.folds("all", True)[1] == "leave-one-out over 3 captures"
    assert ctx.folds("all", False, "textured")[1] == "leave-one-out over 3 captures"  # a fit that takes whole frames
    pairs, how = ctx.folds("all", True, "textured")
    if by_captures:
        assert how == "leave-one-out over 3 captures"
    else:
        assert how == f"2 folds of {TILE_PX}-px image tiles"
        for fitted, measured in pairs:  # each fold fits every capture on half its tiles, measured on the others
            assert len(fitted.mset.captures) == len(measured.mset.captures) == 3
            assert not any((a.mask & b.mask).any() for a, b in zip(fitted.inputs, measured.inputs))


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_removing_an_effect_is_a_candidate(tmp_path, fire_i):
    """The camera lacks the profile's sharpening: ``without_sharpening`` wins against changing it."""
    folder = synthesise(fire_i, tmp_path / "set", remove=["sharpening"], seed=42, frames=4,
                        only_scenes=("chart", "noise-field"))
    d = diagnose(load_set(folder, fire_i), fire_i, workdir=tmp_path / "work",
                 only=["without_sharpening", "asymmetric_sharpening", "defocus", "without_vignetting"])
    assert_verdict_matches_numbers(d)
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    assert d.error > 1.5 and d.candidates[0].effect == "without_sharpening", ranking
    assert d.candidates[0].error_after <= 1.25, ranking


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_a_grey_camera_is_found_monochrome(tmp_path, fire_i):
    """Frames of a monochrome camera, made here by OpenCV's own RGB -> grey (BT.601 luma) of the profile's frames:
    ``monochrome`` beats the colour candidates."""
    import cv2

    from lowcam.measure.sets import write_set
    from lowcam.measure.synth import scenes
    from lowcam.pipeline import simulate

    captures = []
    for name, (ideal, omega) in scenes(fire_i).items():
        if name in ("photo", "chart"):
            frames = [cv2.cvtColor(cv2.cvtColor(simulate(ideal, fire_i, None, omega, None, 43 + len(name), k),
                                                cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB) for k in range(4)]
            captures.append({"name": name, "ideal": ideal, "frames": frames, "angular_velocity": omega})
    folder = write_set(tmp_path / "grey", captures)
    d = diagnose(load_set(folder, fire_i), fire_i, only=["monochrome", "colour_matrix", "chroma_subsampling"],
                 workdir=tmp_path / "w")
    assert_verdict_matches_numbers(d)
    ranking = {c.effect: round(c.error_after, 3) for c in d.candidates}
    # a colour matrix with three equal rows removes all colour: no colour camera's, so not offered
    assert d.error > 2 and ranking["monochrome"] <= 1.25 and ranking["chroma_subsampling"] > 2, ranking
    assert d.candidates[0].effect == "monochrome" and "colour_matrix" not in ranking, ranking
    assert "removes colour" in d.not_fitted["colour_matrix"], d.not_fitted
    luma = d.candidates[[c.effect for c in d.candidates].index("monochrome")].params["luma"]
    assert np.allclose(luma, [0.299, 0.587, 0.114], atol=0.03), luma  # OpenCV's BT.601 weights, found


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_only_names_the_candidates_of_every_step_once_and_none_is_refused(tmp_path):
    """``--only`` holds for ``--until-explained`` too (it screened every candidate and added the tone curve it
    hid), names each candidate once (``gamma`` is ``tone_curve``), and naming none is refused in one line."""
    def lowcam(*args):
        return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True,
                              timeout=600)

    assert lowcam("synth", "--add", "tone_curve:gamma=2.0", "--frames", "2", "--width", "160", "-o",
                  tmp_path / "set").returncode == 0
    r = lowcam("diagnose", tmp_path / "set", "--only", "vignetting,vignetting", "--until-explained", "-o",
               tmp_path / "p.toml", "--json", tmp_path / "u.json")
    assert r.returncode == 0, r.stderr
    steps = json.loads((tmp_path / "u.json").read_text())["steps"]
    assert {c["effect"] for s in steps for c in s["candidates"]} == {"vignetting"}, steps
    assert {s.get("added") for s in steps} <= {"vignetting", None}
    r = lowcam("diagnose", tmp_path / "set", "--only", "gamma,tone_curve", "--json", tmp_path / "d.json")
    assert r.returncode == 0 and [c["effect"] for c in json.loads((tmp_path / "d.json").read_text())[
        "candidates"]] == ["tone_curve"], r.stderr
    r = lowcam("diagnose", tmp_path / "set", "--only=", "--json", tmp_path / "e.json")
    assert r.returncode == 2 and "names no candidate" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "e.json").exists()


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_until_explained_adds_effects_step_by_step_and_draws_the_history(tmp_path):
    """Two hidden effects (a tone curve, and no vignetting): the loop adds both, refits them together and stops
    near the noise floor; each step's profile, the history plot and the JSON are written."""
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "synth", "--add", "tone_curve:gamma=1.8", "--remove",
                        "vignetting", "--frames", "4", "-o", str(tmp_path / "set")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "diagnose", str(tmp_path / "set"), "--until-explained",
                        "-o", str(tmp_path / "fixed.toml"), "--json", str(tmp_path / "d.json")],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "d.json").read_text())
    errors = [s["error"] for s in doc["steps"]]
    added = [s.get("added") for s in doc["steps"][:-1]]
    # the hidden change is no vignetting: removing the profile's, with the tone curve refitted, or a refitted one
    assert "tone_curve" in added and {"vignetting", "without_vignetting"} & set(added), doc["steps"]
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[0] > 10 and errors[-1] <= 1.15, errors  # near the floor (1.13 seen; 1.1 is "explained")
    # each step's promise holds in the next step's comparison: its error in sample within 5 %, and never more than
    # 5 % above its held-out error (the refit of every effect added together may do better than either)
    best = [s["candidates"][0] for s in doc["steps"][:-1]]
    assert [c["effect"] for c in best] == added
    numbers = [(e, c["error_after"], c["score"]) for e, c in zip(errors[1:], best)]
    assert all(abs(e - in_sample) <= 0.05 * in_sample and e <= 1.05 * held_out
               for e, in_sample, held_out in numbers), numbers
    steps = tmp_path / "fixed-steps"
    assert (steps / "history.png").stat().st_size > 10_000
    assert len(list(steps.glob("*.toml"))) == len(added)
    vignetting = lowcam.load_profile(tmp_path / "fixed.toml").effect("vignetting")
    assert vignetting is None or vignetting.implausible() == [], vignetting
