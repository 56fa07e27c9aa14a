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
    assert "the output is the input" in line and str(shot) in line and shot.read_bytes() == before


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
