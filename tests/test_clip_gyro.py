"""A clip's own gyro as camera motion (``--gyro CLIP.mp4``): a GoPro-style clip made here after GoPro's published
GPMF format (tests/gpmf_clip.py: a known rotation in GoPro's documented axes, two data layouts), read by
telemetry-parser (Gyroflow's reader, not Lowcam), comes back as the known rotation in Lowcam's camera frame; the
clip's frame rate is its own; ``lowcam motion`` and ``lowcam batch`` take it as they take a ``.gcsv`` log; a clip
with no gyro, a clip cut short and a file that is no video are each one line naming the file, nothing written
(lowcam/gyro_logs.py)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gpmf_clip import GYRO_HZ, LAYOUTS, SCAL, write_gopro_clip
from lowcam.cli import main
from lowcam.gyro_logs import log_kind, read_gyro_log
from lowcam.motion import read_motion_json

ROOT = Path(__file__).resolve().parent.parent
QUANTUM = 0.5 / SCAL            # rad/s: the int16 rounding of the stored rates
FPS = 30


def known_rate(t):
    """Rad/s in Lowcam's camera frame (x right, y down, z forward): three different motions, so that a swapped or
    negated axis, or a shifted clock, shows: x a 1 Hz sine, y a pan rising linearly, z a roll falling linearly."""
    t = np.asarray(t, np.float64)
    return np.stack([0.4 * np.sin(2 * np.pi * t), 0.8 + 0.5 * t, -0.3 - 0.2 * t], -1)


def known_mean(a, b):
    """The exact mean of :func:`known_rate` over [a, b] s."""
    x = 0.4 * (np.cos(2 * np.pi * a) - np.cos(2 * np.pi * b)) / (2 * np.pi * (b - a))
    return np.array([x, 0.8 + 0.25 * (a + b), -0.3 - 0.1 * (a + b)])


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clips")
    out = {name: write_gopro_clip(folder / f"{name.split()[0]}.mp4", known_rate, orin=orin)
           for name, orin in LAYOUTS.items()}
    out["no gyro"] = write_gopro_clip(folder / "plain.mp4", known_rate, gyro=False)
    return out


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_telemetry_parser_reads_the_clip_back_as_the_known_rotation(clips, layout):
    """telemetry-parser finds a GoPro clip; Lowcam's samples are at i / 200 s and equal the known rate within the
    stored rounding (1/(2 SCAL) rad/s) on every axis, whichever layout the camera stored; the frame rate is the
    clip's."""
    import telemetry_parser

    path = clips[layout]
    assert telemetry_parser.Parser(str(path)).camera == "GoPro"
    assert log_kind(path) == "clip"
    log = read_gyro_log(path)
    assert log.kind == "clip" and log.fps == FPS
    t = log.samples[:, 0]
    np.testing.assert_allclose(t, np.arange(2 * int(GYRO_HZ)) / GYRO_HZ, atol=1e-9)
    error = np.abs(log.samples[:, 1:] - known_rate(t))
    assert error.max() <= QUANTUM * 1.001, error.max(0)
    # the axes are told apart: the mapping one sign or swap away is far off
    assert np.abs(log.samples[:, 1:] - known_rate(t)[:, [1, 0, 2]]).max() > 0.5
    assert np.abs(log.samples[:, 1:] + known_rate(t)).max() > 0.5


def test_motion_command_takes_the_clips_rate_and_rotation(clips, tmp_path):
    """``lowcam motion --gyro CLIP`` needs no --fps: frame f is exposed from (f - 1) / 30 s for 0.02 s and gets the
    exact mean of the known rotation over that exposure (within the rounding and the trapezoid's error)."""
    out = tmp_path / "m.json"
    assert main(["motion", "--gyro", str(clips["hero8-style YxZ"]), "--exposure-s", "0.02", "--frames", "1-40",
                 "-o", str(out)]) == 0
    assert json.loads(out.read_text())["fps"] == FPS
    motion = read_motion_json(out)
    assert sorted(motion) == list(range(1, 41))
    for f, m in motion.items():
        a = (f - 1) / FPS
        np.testing.assert_allclose(m.angular_velocity, known_mean(a, a + 0.02), atol=QUANTUM + 2e-4, rtol=0)
        assert m.exposure_s == 0.02
    # --gyro-t0 shifts the clip's clock as it does a log's: frame 1 then starts 0.5 s into the clip
    assert main(["motion", "--gyro", str(clips["hero8-style YxZ"]), "--exposure-s", "0.02", "--frames", "1",
                 "--gyro-t0", "0.5", "-o", str(tmp_path / "t0.json")]) == 0
    np.testing.assert_allclose(read_motion_json(tmp_path / "t0.json")[1].angular_velocity, known_mean(0.5, 0.52),
                               atol=QUANTUM + 2e-4, rtol=0)


def _small_profile(folder: Path) -> Path:
    """The Fire-i at 160x120 with a 30 ms rolling shutter."""
    shutil.copytree(ROOT / "profiles" / "fire-i", folder / "fire-i", dirs_exist_ok=True)
    text = (ROOT / "profiles" / "fire-i.toml").read_text()
    text = text.replace("\nwidth = 640\n", "\nwidth = 160\n").replace("\nheight = 480\n", "\nheight = 120\n")
    anchor = '[[effect]]\ntype = "chromatic_aberration"'
    text = text.replace(anchor, f'[[effect]]\ntype = "rolling_shutter"\nreadout_s = 0.03\n\n{anchor}')
    (folder / "small.toml").write_text(text)
    return folder / "small.toml"


def test_batch_films_the_clips_rotation(clips, tmp_path):
    """``lowcam batch --gyro CLIP`` (no --fps) films the frames of Lowcam's CSV of the known rotation at 30 frames/s,
    but for the stored rounding (a few pixels a few DN apart); without the motion they differ 60 times as much."""
    from lowcam.outputs import write_exr
    from lowcam.profile import load_profile
    from lowcam.sample import sample_render

    profile = _small_profile(tmp_path)
    render = sample_render(load_profile(profile), 160)
    for f in (1, 2):
        write_exr(tmp_path / "renders" / f"{f:04d}.exr", render)
    t = np.arange(400) / GYRO_HZ
    (tmp_path / "known.csv").write_text("t,wx,wy,wz\n" + "".join(f"{ti!r},{w[0]!r},{w[1]!r},{w[2]!r}\n"
                                                                  for ti, w in zip(t, known_rate(t))))

    def batch(out, *extra):
        assert main(["batch", "--profile", str(profile), "--renders", str(tmp_path / "renders" / "####.exr"),
                     "--frames", "1-2", "-o", str(tmp_path / out / "####.png"), "--quiet", *extra]) == 0
        from lowcam.io import read_image
        return [read_image(tmp_path / out / f"{f:04d}.png").astype(int) for f in (1, 2)]

    from_clip = batch("clip", "--gyro", str(clips["hero5-style ZXY"]), "--exposure-s", "0.02")
    from_csv = batch("csv", "--gyro", str(tmp_path / "known.csv"), "--exposure-s", "0.02", "--fps", str(FPS))
    still = batch("still")
    for a, b, c in zip(from_clip, from_csv, still):
        assert np.abs(a - b).max() <= 3 and np.abs(a - b).mean() < 0.01     # measured: 3 DN at one pixel
        assert np.abs(a - c).mean() > 0.3                                   # measured: 0.58 and 0.61 DN


# --- bad input ---------------------------------------------------------------------------------------------------

def _cut(clips, tmp_path):
    data = clips["hero8-style YxZ"].read_bytes()
    return data[:len(data) * 2 // 3]


BAD = {
    "no-gyro.mp4": (lambda clips, tmp_path: clips["no gyro"].read_bytes(), "holds no gyro"),
    "cut-short.mp4": (_cut, "cut short"),
    "picture.mp4": (lambda clips, tmp_path: (ROOT / "lowcam" / "data" / "coffee.png").read_bytes(),
                    "not a video clip"),
    "noise.mov": (lambda clips, tmp_path: np.random.default_rng(7).integers(0, 256, 4096, np.uint8).tobytes(),
                  "not a video clip"),
}


@pytest.mark.parametrize("name", sorted(BAD))
@pytest.mark.parametrize("command", ["motion", "batch"])
def test_bad_clip_is_one_line_naming_it_and_nothing_is_written(name, command, clips, tmp_path, capfd):
    make, says = BAD[name]
    path = tmp_path / name
    path.write_bytes(make(clips, tmp_path))
    out = tmp_path / "out"
    args = ["--gyro", str(path), "--exposure-s", "0.02", "--frames", "1"]
    if command == "motion":
        args += ["-o", str(out / "m.json")]
    else:
        (tmp_path / "renders").mkdir()
        shutil.copyfile(ROOT / "lowcam" / "data" / "coffee.png", tmp_path / "renders" / "0001.png")
        args += ["--renders", str(tmp_path / "renders" / "####.png"), "-o", str(out / "####.png"), "--quiet"]
    capfd.readouterr()
    rc = main([command, *args])
    err = capfd.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and says in lines[0] and "Traceback" not in err, err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.blender
def test_addons_motion_source_reads_the_clips_gyro(clips, tmp_path):
    """The add-on's motion source "File" given the clip: frame f of a 30 frames/s scene starting at frame 1 gets
    the known rotation's mean over its exposure, as ``lowcam motion`` does."""
    from lowcam_blender import submodule

    blend = submodule("addon.sample").build_sample_scene(tmp_path / "scene", render_width=160, samples=1)
    scene = submodule("addon.render").open_scene(blend)
    scene.render.fps, scene.render.fps_base, scene.frame_start = FPS, 1.0, 1
    scene.lowcam.motion_source = "FILE"
    scene.lowcam.motion_file = str(clips["hero8-style YxZ"])
    frames = submodule("addon.frames")
    for f in (1, 7, 31):
        a = (f - 1) / FPS
        np.testing.assert_allclose(frames.motion(scene, f, 0.02).angular_velocity, known_mean(a, a + 0.02),
                                   atol=QUANTUM + 2e-4, rtol=0)


@pytest.mark.blender
def test_addons_plate_clip_gyro_is_timed_by_the_clips_frames(clips, tmp_path):
    """Motion "Plate Clip's Gyro": the plate Movie Clip's own gyro, scene frame f showing the clip's frame
    f - frame_start + frame_offset at the clip's 30 frames/s (not the scene's 24); refused in one line where the
    plate is no Movie Clip."""
    import bpy
    from lowcam.errors import LowcamError
    from lowcam_blender import submodule

    blend = submodule("addon.sample").build_sample_scene(tmp_path / "scene", render_width=160, samples=1)
    scene = submodule("addon.render").open_scene(blend)
    scene.render.fps, scene.render.fps_base = 24, 1.0
    clip = bpy.data.movieclips.load(str(clips["hero5-style ZXY"]))
    clip.frame_start, clip.frame_offset = 5, 3          # scene frame 5 shows the clip's frame index 3
    s = scene.lowcam
    s.plate_source, s.plate_clip, s.motion_source = "CLIP", clip, "PLATE_GYRO"
    frames = submodule("addon.frames")
    for f in (5, 9, 40):
        a = (f - 5 + 3) / FPS
        np.testing.assert_allclose(frames.motion(scene, f, 0.02).angular_velocity, known_mean(a, a + 0.02),
                                   atol=QUANTUM + 2e-4, rtol=0)
    s.plate_source = "NONE"
    with pytest.raises(LowcamError, match="Movie Clip"):
        frames.motion(scene, 5, 0.02)


def test_a_python_without_telemetry_parser_says_so_in_one_line(clips, tmp_path):
    """Where telemetry-parser cannot be installed (Blender 5.1's Python 3.13: no build of it), a clip is refused in
    one line naming the file and the way round; a .gcsv log still reads. Run in a child Python in which the
    package is blocked from importing (``sys.modules[name] = None``)."""
    import subprocess
    import sys

    code = ("import sys; sys.modules['telemetry_parser'] = None\n"
            "from lowcam.cli import main\n"
            f"sys.exit(main(['motion', '--gyro', {str(clips['hero8-style YxZ'])!r}, '--exposure-s', '0.02', "
            f"'--frames', '1', '-o', {str(tmp_path / 'm.json')!r}]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert str(clips["hero8-style YxZ"]) in lines[0] and "telemetry-parser" in lines[0] and ".gcsv" in lines[0]
    assert not (tmp_path / "m.json").exists()
