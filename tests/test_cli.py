"""The command line, run as a user runs it: a real process, real files, exit codes and messages."""
import subprocess
import sys

import cv2
import numpy as np
import OpenEXR
import pytest

from lowcam.outputs import write_exr
from lowcam.sample import sample_plate, sample_render


def lowcam(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    write_exr(d / "render.exr", sample_render("fire-i", 1000))
    cv2.imwrite(str(d / "plate.png"), cv2.cvtColor(sample_plate("fire-i"), cv2.COLOR_RGB2BGR))
    return d


def test_apply_writes_the_camera_frame(inputs, tmp_path):
    out = tmp_path / "out.png"
    r = lowcam("apply", "--profile", "fire-i", "--render", inputs / "render.exr", "--plate", inputs / "plate.png",
               "--angular-velocity", "0,0.5,0", "--seed", "3", "-o", out)
    assert r.returncode == 0, r.stderr
    frame = cv2.imread(str(out))
    plate = cv2.imread(str(inputs / "plate.png"))
    assert frame.shape == (480, 640, 3)
    changed = np.any(frame != plate, axis=2)
    assert 0.05 < changed.mean() < 0.6  # the objects, not the whole frame
    again = tmp_path / "again.png"
    lowcam("apply", "--render", inputs / "render.exr", "--plate", inputs / "plate.png", "--angular-velocity",
           "0,0.5,0", "--seed", "3", "-o", again)
    assert out.read_bytes() == again.read_bytes()


@pytest.mark.parametrize("args, message", [
    (["--profile", "nope"], "unknown profile 'nope'"),
    (["--plate", "missing.png"], "missing.png: no such file"),
])
def test_bad_input_is_one_line_on_stderr_with_exit_2(inputs, tmp_path, args, message):
    r = lowcam("apply", "--render", inputs / "render.exr", *args, "-o", tmp_path / "o.png", cwd=tmp_path)
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o.png").exists()


def test_nan_render_is_reported_by_name(tmp_path):
    bad = np.full((300, 400, 4), 0.5, np.float32)
    bad[10, 20, 1] = np.nan
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGBA": bad}).write(str(tmp_path / "bad.exr"))
    r = lowcam("apply", "--render", tmp_path / "bad.exr", "-o", tmp_path / "o.png")
    assert r.returncode == 2 and "bad.exr: 1 pixels hold NaN or Inf (first at x=20, y=10)" in r.stderr


def test_bad_angular_velocity_is_refused():
    r = lowcam("apply", "--render", "x.exr", "--angular-velocity", "1,2", "-o", "o.png")
    assert r.returncode == 2 and "wx,wy,wz" in r.stderr


def test_stages_writes_one_image_per_stage(tmp_path):
    r = lowcam("stages", "--profile", "fire-i", "--angular-velocity", "0,0.5,0", "-o", tmp_path / "stages")
    assert r.returncode == 0, r.stderr
    files = sorted(p.name for p in (tmp_path / "stages").glob("*.png"))
    assert len(files) == 16 and files[0] == "00-lens_distortion.png" and files[-1] == "15-chroma_subsampling.png"
    mosaic = cv2.imread(str(tmp_path / "stages" / "06-bayer_sampling.png"))
    assert mosaic.shape == (480, 640, 3)
    # a Bayer mosaic: each pixel carries one colour only
    assert np.all((mosaic > 0).sum(axis=2) <= 1)


def test_profiles_lists_the_bundled_profiles():
    r = lowcam("profiles")
    assert r.returncode == 0 and "fire-i" in r.stdout and "ueye" in r.stdout


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_demo_writes_the_composite_next_to_the_plain_composite(tmp_path):
    r = lowcam("demo", "-o", tmp_path / "demo", "--render-width", "1000")
    assert r.returncode == 0, r.stderr
    assert "[3/3]" in r.stdout
    side = cv2.imread(str(tmp_path / "demo" / "side_by_side.png"))
    assert side.shape == (480 + 28, 2 * 640 + 8, 3)
    ours = cv2.imread(str(tmp_path / "demo" / "lowcam.png")).astype(int)
    plain = cv2.imread(str(tmp_path / "demo" / "plain.png")).astype(int)
    plate = cv2.imread(str(tmp_path / "demo" / "plate" / "0001.png")).astype(int)
    objects = (plain != plate).any(axis=2)
    assert 0.02 < objects.mean() < 0.5                            # the sample scene's objects were rendered
    assert np.abs(ours - plain)[objects].mean() > 2.0             # and degraded


def test_synthetic_demo_runs_the_engine_without_blender(tmp_path):
    r = lowcam("demo", "--synthetic", "-o", tmp_path, "--render-width", "1000")
    assert r.returncode == 0, r.stderr
    ours = cv2.imread(str(tmp_path / "lowcam.png")).astype(int)
    plain = cv2.imread(str(tmp_path / "plain.png")).astype(int)
    assert ours.shape == (480, 640, 3) and np.abs(ours - plain).mean() > 1.0
    assert not (tmp_path / "sample_scene.blend").exists()


def test_a_listing_read_only_in_part_ends_quietly_and_a_full_disk_does_not():
    """``lowcam profile search Canon | head -1``: the reader leaves early; that is no error. Writing to a full
    device is one."""
    reader = subprocess.Popen([sys.executable, "-m", "lowcam.cli", "profile", "search", "Canon"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = reader.stdout.readline()
    reader.stdout.close()  # as head -1 does
    stderr = reader.stderr.read().decode()
    assert reader.wait(timeout=120) == 0 and first.startswith(b"Canon") and stderr == "", stderr
    with open("/dev/full", "wb") as full:
        r = subprocess.run([sys.executable, "-m", "lowcam.cli", "profile", "search", "Canon"], stdout=full,
                           stderr=subprocess.PIPE, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip() == "lowcam profile search: error: No space left on device", r.stderr
