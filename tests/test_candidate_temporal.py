"""Temporal noise reduction, and the evidence a temporal candidate needs, against code no one here wrote.

- The filter's physics: a still pixel's noise variance and frame-to-frame correlation against the analytic values
  of a first-order recursive filter, and the whole sequence against OpenCV's running average
  (``cv2.accumulateWeighted``).
- Hidden behind the Fire-i by OpenCV: its running average where the luma (OpenCV's YCrCb) changes by less than a
  threshold, the frame itself where it changes more (``cv2.accumulateWeighted`` with a mask, ``cv2.copyTo``), at
  seeded random strengths and thresholds, each capture's frames filtered in order after 30 frames that settle the
  filter. Diagnosis must name ``temporal_noise_reduction`` first, at a held-out error of at most 1.25, before the
  spatial noise reduction and the video codec, which also lower the noise.
- A set whose frames draw their noise anew each frame gets no temporal candidate fitted, and says why.
"""
import subprocess
import sys
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import lowcam
from helpers import drawn, quiet_fire_i
from lowcam.effects.temporal_noise_reduction import filter_sequence, frame_to_frame_correlation, lead_frames
from lowcam.errors import LowcamError, ProfileError
from lowcam.measure.compare import simulate_capture
from lowcam.measure.diagnose import HELD_NOISE, diagnose
from lowcam.measure.sets import load_set, write_set
from lowcam.measure.synth import scenes
from lowcam.pipeline import simulate

SETTLE = 30  # frames each hidden filter runs before a capture's first


def still(frames=40, sigma=2.0, level=120.0, shape=(64, 80), seed=0):
    rng = np.random.default_rng(seed)
    return np.clip(np.rint(level + sigma * rng.standard_normal((frames,) + shape + (3,))), 0, 255).astype(np.uint8)


def opencv_running_average(frames, alpha, threshold=None):
    """OpenCV's running average, ``acc = (1 - alpha) acc + alpha frame`` (``cv2.accumulateWeighted``), where the
    luma of OpenCV's YCrCb changed by less than ``threshold`` from the average (everywhere when None); elsewhere the
    average restarts at the frame (``cv2.copyTo``). Each output is the average rounded."""
    acc = frames[0].astype(np.float32)
    out = [frames[0]]
    for f in frames[1:]:
        if threshold is None:
            cv2.accumulateWeighted(f, acc, alpha)
        else:
            luma = cv2.cvtColor(f, cv2.COLOR_RGB2YCrCb)[..., 0]
            average = cv2.cvtColor(np.clip(np.rint(acc), 0, 255).astype(np.uint8), cv2.COLOR_RGB2YCrCb)[..., 0]
            still_px = (cv2.absdiff(luma, average) < threshold).astype(np.uint8)
            cv2.accumulateWeighted(f, acc, alpha, mask=still_px)
            cv2.copyTo(f.astype(np.float32), 1 - still_px, acc)
        out.append(np.clip(np.rint(acc), 0, 255).astype(np.uint8))
    return np.stack(out)


# --- the physics --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("strength", [0.3, 0.6, 0.85])
def test_a_still_pixel_keeps_the_analytic_share_of_its_noise(strength):
    """``y_t = (1 - k) in_t + k y_{t-1}`` on white noise of variance s^2 (rounded: q = 1/12 more), delivered rounded
    (q again): variance ``(s^2 + q) (1 - k) / (1 + k) + q`` and correlation ``k`` from one frame to the next of its
    held part, once settled (a threshold far above the noise keeps ``k``)."""
    sigma = 6.0  # well above the 1 DN steps (a filter that moves less than half a step holds its value)
    frames = still(frames=200, sigma=sigma)
    out = filter_sequence(frames, strength, 255.0)[lead_frames(strength) + 5:].astype(np.float64)
    noise = out - 120.0  # the scene's level (the frames' mean would take part of a slow filter's noise)
    k = strength  # the luma changes by far less than half the threshold: the full strength
    q = 1 / 12
    held = (sigma ** 2 + q) * (1 - k) / (1 + k)
    expected = held + q
    assert abs(noise.var() / expected - 1) < 0.1, (noise.var(), expected)
    lag = float((noise[1:] * noise[:-1]).mean() / noise.var())
    assert abs(lag - k * held / expected) < 0.06, (lag, k * held / expected)
    assert frame_to_frame_correlation(out) > strength - 0.25
    assert abs(frame_to_frame_correlation(frames.astype(np.float64))) < 0.02


def test_a_still_sequence_matches_opencvs_running_average():
    frames = still(frames=20, sigma=3.0, seed=1)
    ours = filter_sequence(frames, 0.7, 255.0).astype(int)
    theirs = opencv_running_average(frames, 0.3).astype(int)
    # the same recursion (the luma changes by far less than half the threshold), rounded alike but for ties
    assert np.abs(ours - theirs).max() <= 1 and np.mean(ours != theirs) < 0.01


def test_motion_beyond_the_threshold_takes_the_new_frame_and_below_it_leaves_a_trail():
    frames = np.full((3, 8, 8, 3), 100, np.uint8)
    frames[1:, :, 4:] = 160     # the right half brightens by 60 DN in frame 1
    frames[1:, :, :2] = 110     # the left quarter by 10 DN
    frames[1:, :, 2] = 130      # a column by 30 DN
    out = filter_sequence(frames, 0.8, 40.0).astype(float)
    assert np.all(out[1, :, 4:] == 160)                          # moving: the frame itself
    assert np.all(out[1, :, :2] == np.rint(110 + 0.8 * (100 - 110)))  # under half the threshold: full strength
    k = 0.8 * (2 - 2 * 30 / 40)
    assert np.all(out[1, :, 2] == np.rint(130 + k * (100 - 130)))       # between: a weaker trail
    assert np.all(out[:, :, 3] == 100)                           # still: unchanged


def test_only_the_graphics_are_filtered_and_the_plate_is_what_they_are_averaged_with():
    frames = still(frames=6, sigma=4.0, seed=2)
    footprints = np.zeros(frames.shape[:3], bool)
    footprints[:, :, 40:] = True
    out = filter_sequence(frames, 0.8, 255.0, footprints)
    assert np.array_equal(out[:, :, :40], frames[:, :, :40])
    assert out[1:, :, 40:].astype(float).var(axis=0).mean() < 0.5 * frames[1:, :, 40:].astype(float).var(axis=0).mean()
    # where the graphics arrive in a frame, the frame before is the plate's bytes
    late = footprints.copy()
    late[:3] = False
    got = filter_sequence(frames, 0.8, 255.0, late)[3].astype(float)
    previous, current = frames[2].astype(float), frames[3].astype(float)
    change = np.abs((current - previous) @ np.array([0.299, 0.587, 0.114]))
    k = (0.8 * np.clip(2 - 2 * change / 255, 0, 1))[..., None]
    assert np.abs(got - np.rint(current + k * (previous - current)))[:, 40:].max() <= 1


def test_a_capture_is_filtered_from_the_steady_state_and_a_frame_alone_is_not(fire_i):
    profile = quiet_fire_i().with_effect("temporal_noise_reduction", strength=0.8, motion_threshold_dn=64.0)
    ideal, omega = scenes(profile, 640)["flat-bright"]
    capture = SimpleNamespace(ideal=ideal, plate=None, mask=None, angular_velocity=omega, exposure_s=None)
    filtered = simulate_capture(profile, capture, 6, seed=5).astype(np.float64)
    raw = simulate_capture(quiet_fire_i(), capture, 40, seed=6).astype(np.float64)  # other noise
    clean = raw.mean(axis=0)
    first, last = (np.square(filtered[k] - clean).mean() for k in (0, -1))
    assert first < 0.3 * np.square(raw[0] - clean).mean()      # frame 0 is mid-stream, not a raw frame
    assert abs(first / last - 1) < 0.1, (first, last)
    alone = simulate(ideal, profile, None, omega, None, 5, 0)
    assert alone.tobytes() == simulate(ideal, quiet_fire_i(), None, omega, None, 5, 0).tobytes()


def test_the_node_group_refuses_it_in_one_line():
    from lowcam.node_maps import bake

    with pytest.raises(LowcamError, match="no node for temporal_noise_reduction"):
        bake(lowcam.load_profile("fire-i").with_effect("temporal_noise_reduction"), (120, 160))


@pytest.mark.parametrize("key,value", [("strength", 0.95), ("strength", -0.1), ("motion_threshold_dn", 0.0)])
def test_out_of_range_parameters_are_refused_naming_the_key(key, value):
    with pytest.raises(ProfileError, match=key) as e:
        lowcam.load_profile("fire-i").with_effect("temporal_noise_reduction", **{key: value})
    assert "\n" not in str(e.value)


def test_the_command_line_refuses_it_out_of_range_in_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "set"
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "synth", "--add", "temporal_noise_reduction:strength=2",
                        "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "strength" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not out.exists()


# --- evidence and diagnosis ---------------------------------------------------------------------------------------

def filtered_set(folder, profile, post, names, frames=6, lead=SETTLE, seed=61):
    """A measurement set of bundled scenes through ``profile``, each capture's ``lead + frames`` delivered frames
    through ``post`` in order and the first ``lead`` dropped."""
    every = scenes(profile, 640)
    captures = []
    for i, name in enumerate(names):
        ideal, omega = every[name]
        shots = np.stack([simulate(ideal, profile, None, omega, None, seed + 1000 * i, k)
                          for k in range(lead + frames)])
        captures.append({"name": name, "ideal": ideal, "frames": list(post(shots)[lead:]),
                         "angular_velocity": omega})
    return write_set(folder, captures)


def test_frames_with_fresh_noise_get_no_temporal_candidate_and_say_why(tmp_path):
    profile = quiet_fire_i()
    folder = filtered_set(tmp_path / "set", profile, lambda s: s, ("flat-bright", "photo"), frames=4, lead=0)
    d = diagnose(load_set(folder, profile), profile, only=["temporal_noise_reduction", "video_codec"],
                 workdir=tmp_path / "work", rounds=1)
    assert abs(d.comparison.held_noise) < HELD_NOISE / 2, d.comparison.held_noise
    assert not d.candidates
    for name in ("temporal_noise_reduction", "video_codec"):
        assert "held from frame to frame" in d.not_fitted[name], d.not_fitted


#: Decoys that lower a set's noise too: spatial noise reduction (and a fixed pattern).
DECOYS = ["noise_reduction", "dsnu"]


@pytest.mark.slow  # a diagnosis takes about a minute
@pytest.mark.parametrize("seed,decoys", [(72, DECOYS), (75, DECOYS + ["video_codec"])])
def test_opencvs_motion_adaptive_running_average_is_named_temporal_noise_reduction(tmp_path, seed, decoys):
    p = drawn(seed, strength=(0.4, 0.85), threshold=[6, 10, 16, 24])
    profile = quiet_fire_i()
    folder = filtered_set(tmp_path / "set", profile,
                          lambda s: opencv_running_average(s, 1 - p["strength"], p["threshold"]),
                          ("flat-dark", "flat-bright", "photo", "noise-field"))
    d = diagnose(load_set(folder, profile), profile, only=["temporal_noise_reduction", *decoys],
                 workdir=tmp_path / "work", rounds=1)
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    print(f"{p}: error {d.error:.2f}, held noise {d.comparison.held_noise:+.2f}; {ranking}; "
          f"{d.candidates[0].params if d.candidates else ''}")
    assert d.comparison.held_noise >= HELD_NOISE
    best = d.candidates[0]
    assert d.error > 1.5 and best.effect == "temporal_noise_reduction", ranking
    assert best.score <= 1.25, ranking
    assert d.verdict == "missing-effect" and d.best.effect == "temporal_noise_reduction", d.summary()
    assert abs(best.params["strength"] - p["strength"]) < 0.2, best.params


# --- from the plate alone -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def still_shots():
    """The Fire-i filming the bundled photograph with a still camera: 40 frames, each its own noise."""
    profile = lowcam.load_profile("fire-i")
    ideal, _ = scenes(profile, 640)["photo"]
    return profile, np.stack([simulate(ideal, profile, None, (0, 0, 0), None, 3, k) for k in range(SETTLE + 10)])


def plate_probe(name):
    from lowcam.measure import plate

    return next(p for p in plate.plate_probes() if p.name == name)


@pytest.mark.parametrize("seed", [81, pytest.param(82, marks=pytest.mark.slow)])
def test_the_plate_gives_the_strength_and_the_noise_law_beneath_it(still_shots, seed):
    """Footage of a still scene through OpenCV's running average at a random strength: the held-noise probe reads
    the strength, and the noise law read through it is the unfiltered footage's (read without it, far lower)."""
    from lowcam.measure.plate import MIN_CONFIDENCE, Footage, film

    profile, shots = still_shots
    strength = drawn(seed, strength=(0.3, 0.8))["strength"]
    footage = Footage(opencv_running_average(shots, 1 - strength, 32)[SETTLE:], path="filtered")
    est = plate_probe("held_noise").estimate(footage, profile, film)
    assert est.confidence >= MIN_CONFIDENCE and abs(est.params["strength"] - strength) < 0.05, est.line()
    noise = plate_probe("noise_level_function")

    def sigma(shot, base):
        law = profile.with_effect("noise", **noise.estimate(shot, base, film).params).effect("noise")
        return law.sigma("green", 128.0)

    raw = sigma(Footage(shots[SETTLE:]), profile)
    beneath = sigma(footage, profile.with_effect("temporal_noise_reduction", **est.params))
    without = sigma(footage, profile)
    print(f"strength {strength:.3f}: read {est.params['strength']:.3f}; noise law at 128 DN through it "
          f"{beneath / raw:.3f} of the unfiltered footage's, without it {without / raw:.3f}")
    assert abs(beneath / raw - 1) < 0.15, (beneath, raw)
    assert without < 0.7 * raw


def test_a_plate_without_a_filter_moving_or_coded_is_not_taken_for_one(still_shots):
    from lowcam.measure.plate import MIN_CONFIDENCE, Footage, film

    profile, shots = still_shots
    probe = plate_probe("held_noise")
    raw = probe.estimate(Footage(shots[SETTLE:]), profile, film)
    assert raw.params == {} and "no temporal filter" in raw.reason, raw.line()
    off = probe.estimate(Footage(shots[SETTLE:]), profile.with_effect("temporal_noise_reduction"), film)
    assert off.params == {"enabled": False}
    pan = np.stack([np.roll(f, 4 * k, axis=1) for k, f in enumerate(shots[SETTLE:])])
    assert not probe.estimate(Footage(pan), profile, film).measurable
    filtered = opencv_running_average(shots, 0.4)[SETTLE:]
    coded = probe.estimate(Footage(filtered, video={"codec": "h264", "gop_length": 30, "frame_types": "I 1, P 9"}),
                           profile, film)
    assert coded.params["strength"] > 0.4 and coded.confidence < MIN_CONFIDENCE and "predicted" in coded.reason


@pytest.mark.parametrize("strength", [0.3, 0.6])
def test_black_bars_and_clipped_highlights_do_not_raise_the_plates_strength(fire_i, strength):
    """A letterboxed shot (black bars: no noise) with clipped highlights, filtered by OpenCV's running average: the
    share held is read off the pixels that carry noise (it read 0.89 for 0.6 with 60 % of the frame black). A
    frame too small for the tiles gives a finite confidence."""
    from lowcam.measure.plate import Footage, film

    shots = still(frames=40, shape=(96, 128), seed=3)
    shots[:, 56:72] = np.clip(shots[:, 56:72].astype(int) + 130, 0, 255)   # a highlight band clipped at 255
    frames = opencv_running_average(shots, 1 - strength)[SETTLE // 3:]
    frames[:, :40] = 0
    est = plate_probe("held_noise").estimate(Footage(frames), fire_i, film)
    assert abs(est.params["strength"] - strength) < 0.04, est.line()
    tiny = plate_probe("held_noise").estimate(Footage(frames[:, 60:63, 60:63]), fire_i, film)
    assert np.isfinite(tiny.confidence) and np.isfinite(tiny.measured["standard_error"])


def test_blenders_render_handler_follows_the_frame_before(tmp_path, fire_i):
    """What the add-on's handler calls per rendered frame (``lowcam.scene.degrade_frame`` with the composite path
    of the frame before): frame 2 follows frame 1's camera frame as made in this process, and the same bytes
    when frame 1's file is all there is (a render resumed in a new Blender). Frame 1, with none before it, is the
    frame without the filter."""
    from helpers import disk_render
    from lowcam.io import read_image
    from lowcam.outputs import write_exr
    from lowcam.sample import sample_plate
    from lowcam.scene import _CAMERA_FRAMES, degrade_frame

    profile = fire_i.with_effect("temporal_noise_reduction", strength=0.7, motion_threshold_dn=64.0)
    plate = sample_plate(fire_i)
    renders = [write_exr(tmp_path / f"{f:04d}.exr", disk_render(fire_i, 0.2, centre=(0.03 * f, 0.0), width=800))
               for f in (1, 2)]
    out = [tmp_path / "out" / f"{f:04d}.png" for f in (1, 2)]
    first = degrade_frame(renders[0], out[0], profile, plate, frame=1, previous_path=tmp_path / "out/0000.png")
    second = read_image(degrade_frame(renders[1], out[1], profile, plate, frame=2, previous_path=out[0]))
    alone = read_image(degrade_frame(renders[1], tmp_path / "alone.png", fire_i, plate, frame=2))
    assert np.array_equal(read_image(first), read_image(degrade_frame(renders[0], tmp_path / "p1.png", fire_i, plate,
                                                                      frame=1)))
    moved = np.any(second != alone, axis=2)
    assert 0.01 < moved.mean() < 0.3            # the graphics, averaged with frame 1's
    _CAMERA_FRAMES.clear()
    again = read_image(degrade_frame(renders[1], tmp_path / "again.png", profile, plate, frame=2,
                                     previous_path=out[0]))
    assert np.array_equal(again, second)
    with pytest.raises(LowcamError, match="write PNG frames") as e:
        degrade_frame(renders[1], tmp_path / "out.jpg", profile, plate, frame=2, previous_path=out[0])
    assert "\n" not in str(e.value) and not (tmp_path / "out.jpg").exists()
    _CAMERA_FRAMES.clear()


def test_a_coder_after_the_filter_codes_the_capture_from_its_own_first_frame(fire_i):
    """The lead frames settle the filter and are dropped before the video coder: the capture's sequence is the
    filter's output of the lead and capture frames, less the lead, coded from its own frame 0."""
    from lowcam.effects.video_codec import code_sequence
    from lowcam.pipeline import prepare, resume

    filtered = quiet_fire_i().with_effect("temporal_noise_reduction", strength=0.6)
    coded = filtered.with_effect("video_codec", crf=30, gop_frames=250)
    ideal, omega = scenes(fire_i, 640)["photo"]
    token = prepare(ideal, quiet_fire_i(), None, omega)
    lead = lead_frames(0.6)
    plain = np.stack([resume(token, 5, k) for k in (*range(4, 4 + lead), *range(4))])
    expected = code_sequence(filter_sequence(plain, 0.6, 16.0)[lead:], "h264", 30, 250)
    capture = SimpleNamespace(ideal=ideal, plate=None, mask=None, angular_velocity=omega, exposure_s=None)
    assert simulate_capture(coded, capture, 4, seed=5).tobytes() == expected.tobytes()
    assert simulate_capture(filtered, capture, 4, seed=5).tobytes() == filter_sequence(plain, 0.6, 16.0)[
        lead:].tobytes()
