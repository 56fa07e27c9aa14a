"""``lowcam render`` and ``lowcam demo --footage`` with real bpy when things go wrong: a .blend without a camera or
without its plates, an output pattern that names the .blend, Ctrl-C during a render, a damaged footage frame.

Each refusal comes before any frame is rendered; scenes are tiny (a cube, 2 Cycles samples, 400 px wide).
"""
from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import bpy
import cv2
import numpy as np
import pytest

from lowcam.cli import main
from lowcam_blender import submodule

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parent.parent
DATA = next((p / "phone-gyro-video" for p in (ROOT.parent / "shared/data", ROOT.parent.parent / "shared/data")
             if (p / "phone-gyro-video").is_dir()), None)


def tiny_scene(path: Path, camera: bool = True, plates: str | None = None, samples: int = 2) -> Path:
    """A cube before a camera (or none), Cycles with ``samples``, saved as ``path``; ``plates``: a #### pattern."""
    submodule("addon.render")   # the add-on registered: scenes have their Lowcam settings
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", samples, False
    scene.render.resolution_x, scene.render.resolution_y = 400, 300
    bpy.ops.mesh.primitive_cube_add(location=(0.0, 6.0, 0.0))
    if camera:
        bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0), rotation=(math.pi / 2, 0.0, 0.0))
        scene.camera = bpy.context.object
    if plates:
        scene.lowcam.plate_source, scene.lowcam.plate_pattern = "SEQUENCE", plates
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def refused(capfd, argv) -> str:
    capfd.readouterr()
    assert main(argv) == 2
    err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_render_refuses_a_blend_without_camera_or_plates_and_an_output_that_is_the_blend(tmp_path, capfd):
    out = tmp_path / "out"
    line = refused(capfd, ["render", str(tiny_scene(tmp_path / "nocam.blend", camera=False)), "--frames", "1",
                           "-o", str(out)])
    assert line == (f"lowcam render: error: {tmp_path / 'nocam.blend'}: scene 'Scene' has no camera; give it one "
                    "(Scene properties > Camera)")
    blend = tiny_scene(tmp_path / "plated.blend", plates="//plates/####.png")
    (tmp_path / "plates").mkdir()
    cv2.imwrite(str(tmp_path / "plates" / "0001.png"), np.full((480, 640, 3), 90, np.uint8))
    line = refused(capfd, ["render", str(blend), "--frames", "1-2", "-o", str(out)])   # frame 2 has no plate
    assert line == f"lowcam render: error: {blend}: frame 2: {tmp_path / 'plates' / '0002.png'}: no such file"
    (tmp_path / "plates" / "0001.png").unlink()
    line = refused(capfd, ["render", str(blend), "--frames", "1", "-o", str(out)])     # no plate at all
    assert line == f"lowcam render: error: {blend}: frame 1: {tmp_path / 'plates' / '0001.png'}: no such file"
    assert not out.exists()                                                             # nothing was rendered
    # -o whose pattern expands to the .blend itself: refused, not taken for a finished frame
    shot = tiny_scene(tmp_path / "shot0001.blend")
    before = shot.read_bytes()
    line = refused(capfd, ["render", str(shot), "--frames", "1", "-o", str(tmp_path / "shot####.blend")])
    assert "-o would replace" in line and str(shot) in line and shot.read_bytes() == before


@pytest.mark.timeout(300)
def test_ctrl_c_during_a_render_is_one_line_and_status_130(tmp_path):
    blend = tiny_scene(tmp_path / "scene.blend", samples=64)   # most of each frame's time is Cycles'
    out, scratch = tmp_path / "out", tmp_path / "tmp"
    scratch.mkdir()
    frames = 40
    proc = subprocess.Popen([sys.executable, "-m", "lowcam.cli", "render", str(blend), "--frames", f"1-{frames}",
                             "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, "TMPDIR": str(scratch)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120 and proc.poll() is None and not list(out.glob("*.png")):
            time.sleep(0.05)
        time.sleep(0.5)   # into the next frame's render
        if proc.poll() is not None or len(list(out.glob("*.png"))) > frames - 5:
            pytest.skip(f"the render (nearly) ended before it could be interrupted (exit {proc.poll()})")
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == ["lowcam render: interrupted"], err[-2000:]
    assert proc.returncode == 130
    written = sorted(out.glob("*.png"))
    assert 1 <= len(written) < frames
    assert all(cv2.imread(str(p)).shape == (480, 640, 3) for p in written)   # whole composites only
    assert not list(out.glob(".*.part")) and list(scratch.iterdir()) == []   # no temporaries, no scratch renders


def _footage_copy(folder: Path, frames=(99, 100)) -> Path:
    source = next(p for p in [DATA, *DATA.iterdir()] if (p / "framestamp.txt").is_file())
    (folder / "reshape").mkdir(parents=True)
    for name in ("framestamp.txt", "gyro.txt", "gyro_dump.txt"):
        shutil.copy(source / name, folder / name)
    for n in frames:
        shutil.copy(source / "reshape" / f"RE_frame-{n}.jpg", folder / "reshape" / f"RE_frame-{n}.jpg")
    return folder


@pytest.mark.skipif(DATA is None, reason="the phone-gyro-video data set is not beside the repository")
@pytest.mark.parametrize("damage", ["truncated", "smaller"])
def test_demo_footage_refuses_a_damaged_frame_by_name_and_leaves_no_folder(tmp_path, damage):
    clip = _footage_copy(tmp_path / "clip")
    frame = clip / "reshape" / "RE_frame-100.jpg"
    if damage == "truncated":
        frame.write_bytes(frame.read_bytes()[:20000])
    else:
        cv2.imwrite(str(frame), cv2.resize(cv2.imread(str(frame)), (640, 480)))
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "demo", "--footage", str(clip), "--footage-frames", "2",
                        "-o", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert lines[0].startswith(f"lowcam demo: error: {frame}: ")
    assert ("truncated" in lines[0]) if damage == "truncated" else ("640x480" in lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip"]   # no output folder, half-made or not


@pytest.mark.slow   # the plate estimate before the renders takes a minute on a busy 2-core machine
@pytest.mark.timeout(600)
@pytest.mark.skipif(DATA is None, reason="the phone-gyro-video data set is not beside the repository")
def test_ctrl_c_during_the_footage_demo_render_leaves_no_folder(tmp_path):
    clip = _footage_copy(tmp_path / "clip")
    proc = subprocess.Popen([sys.executable, "-m", "lowcam.cli", "demo", "--footage", str(clip), "--footage-frames",
                             "2", "-o", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        for line in proc.stdout:   # into the renders
            if line.startswith("[3/5]"):
                time.sleep(1.0)
                os.killpg(proc.pid, signal.SIGINT)
                break
        _, err = proc.communicate(timeout=120)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert proc.returncode == 130 and "Traceback" not in err and "ReferenceError" not in err, err[-2000:]
    assert [line for line in err.splitlines() if line.strip()][-1] == "lowcam demo: interrupted"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip"]
