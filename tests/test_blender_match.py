"""The Match loop inside Blender (real bpy): estimate from the plate, compare, diagnose, add, undo, cancel, errors.

The measurement set hides a tone curve (``lowcam synth --add tone_curve:gamma=2.0``, 2 frames a capture) that the
bundled fire-i profile lacks; Diagnose tries two candidates only, so that a diagnosis takes seconds. Every job runs
the ``lowcam`` command line in a child process, and the panel's numbers are checked against the same command run
here. Blender stores its numbers as 32-bit floats: equal means equal to that precision.

The bpy module runs no event loop, so nothing calls Blender's timers: :func:`_drive` calls the add-on's timer
function (``jobs.tick``) in a loop, as Blender's loop would, and measures the gaps between its calls: how long the
main thread is held.
"""
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np
import pytest

from lowcam_blender import submodule

pytestmark = pytest.mark.blender  # real bpy: the Blender tier

CANDIDATES = "tone_curve,vignetting"
jobs = submodule("addon.jobs")
match = submodule("addon.match")


def _cli(*args, check=True):
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr[-2000:]
    return r


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """A measurement set whose camera has a tone curve (gamma 2) that fire-i lacks."""
    folder = tmp_path_factory.mktemp("match-set") / "set"
    _cli("synth", "--add", "tone_curve:gamma=2.0", "--frames", 2, "--width", 64, "-o", folder)
    return folder


@pytest.fixture
def scene(measured, tmp_path):
    """A saved scene (shot.blend) with fire-i, the set as its Match measurement set, its noise-field frames as
    the plate; no job is left running after the test."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    sc = bpy.context.scene
    sc.render.resolution_x, sc.render.resolution_y = 160, 120
    sc.lowcam.profile = "fire-i"
    sc.lowcam.plate_source = "SEQUENCE"
    sc.lowcam.plate_pattern = str(measured / "frames" / "noise-field-###.png")
    sc.lowcam_match.measurement_set = str(measured)
    sc.lowcam_match.only = CANDIDATES
    yield sc
    jobs.cancel()


def _drive(timeout_s=600.0, until=None):
    """Run the add-on's timer function as Blender's event loop would (again after the interval it returns) until
    the job ends (or ``until()`` holds); returns the longest gap between the starts of two calls, the last call's
    own time included (s), and the number of calls."""
    starts = []
    while True:
        starts.append(time.perf_counter())
        again = jobs.tick()
        if again is None or (until is not None and until()):
            starts.append(time.perf_counter())
            return max(b - a for a, b in zip(starts, starts[1:])), len(starts) - 1
        assert starts[-1] - starts[0] < timeout_s, "the job did not end"
        time.sleep(again)


def _finished(op, **kw):
    assert op(wait=False, **kw) == {"FINISHED"}
    job = jobs.current()
    assert job is not None
    return job


def test_compare_diagnose_add_undo_give_the_command_lines_numbers(scene, measured, tmp_path):
    m = scene.lowcam_match
    # Compare: fire-i against the set
    job = _finished(bpy.ops.lowcam.match_compare)
    _drive()
    assert job.state == "finished", job.error
    cli = tmp_path / "cli-compare.json"
    _cli("compare", measured, "--profile", "fire-i", "--json", cli)
    first = json.loads(cli.read_text())
    assert m.error > 1.25 and m.error == pytest.approx(first["error"], rel=1e-6)
    assert m.verdict == first["verdict"]
    where = m.where.split("; ")
    assert [w.split()[0] for w in where] == ["channel", "region", "band", "level"]
    assert where[2].startswith(f"band {max(first['where']['bands'], key=lambda e: e['error'])['band']} ")
    maps = bpy.data.images["Lowcam Residual Map"]
    assert Path(m.report).is_file() and maps.size[0] > 0
    assert tuple(maps.preview.image_size) == tuple(maps.size)   # the panel shows it at its own size, not 256 px
    assert 0.7 < maps.size[0] / maps.size[1] < 1.4              # near square, as the panel's box
    assert [(v.label, round(v.error, 3)) for v in m.versions] == [("fire-i", round(first["error"], 3))]

    # Diagnose: the hidden tone curve first; the main thread is never held for 0.5 s meanwhile
    job = _finished(bpy.ops.lowcam.match_diagnose)
    longest, calls = _drive()
    assert job.state == "finished", job.error
    print(f"\ndiagnosis: {time.monotonic() - job.started:.1f} s, {calls} timer calls, longest gap {longest:.3f} s")
    assert longest < 0.5 and calls > 20
    assert [c.effect for c in m.candidates][0] == "tone_curve"
    assert m.candidates[0].error_after <= 1.25 and m.candidates[0].held_out <= 1.25
    assert "power 1/2.0" in m.candidates[0].evidence
    report = Path(m.report)                      # the diagnosis's own HTML report, not Compare's
    assert report.name == "index.html" and report.parent.name.startswith("diagnose-") and "tone_curve" in \
        report.read_text()

    # Add the best: fire-i-v2.toml beside the .blend, selected, and its error falls
    job = _finished(bpy.ops.lowcam.match_add, index=-1)
    _drive()
    assert job.state == "finished", job.error
    v2 = tmp_path / "fire-i-v2.toml"
    assert v2.is_file() and Path(bpy.path.abspath(scene.lowcam.profile_file)) == v2
    assert submodule("addon.frames").scene_profile(scene).effect("tone_curve") is not None  # the handler's too
    _cli("compare", measured, "--profile", v2, "--json", cli)
    added = json.loads(cli.read_text())
    assert m.error <= 1.25 and m.error == pytest.approx(added["error"], rel=1e-6)
    assert [v.label for v in m.versions] == ["fire-i", "+ tone_curve"]
    assert m.versions[1].error == pytest.approx(added["error"], rel=1e-6)
    history = bpy.data.images["Lowcam Error History"]
    assert tuple(history.preview.image_size) == tuple(history.size) and history.size[0] >= 500
    assert not m.candidates                      # they were ranked for fire-i

    # Undo to the first version: fire-i again, with its error; comparing again gives that error
    assert bpy.ops.lowcam.match_undo(index=0) == {"FINISHED"}
    assert scene.lowcam.profile_file == "" and scene.lowcam.profile == "fire-i"
    assert m.error == pytest.approx(first["error"], rel=1e-6) and len(m.versions) == 1
    _finished(bpy.ops.lowcam.match_compare)
    _drive()
    assert m.error == pytest.approx(first["error"], rel=1e-6)
    assert v2.is_file()                          # undone versions' files stay


def _gone(pid: int) -> bool:
    """No process of the group runs (an orphaned grandchild that ended may wait a moment for init to reap it)."""
    return not jobs.group_running(pid)


def test_a_cancelled_diagnosis_leaves_no_profile_and_no_process(scene, tmp_path):
    m = scene.lowcam_match
    job = _finished(bpy.ops.lowcam.match_until_explained)
    _drive(timeout_s=120, until=lambda: any(ln.startswith("[") for ln in job.stderr))   # it is fitting
    pid = job.process.pid
    assert not _gone(pid)
    assert bpy.ops.lowcam.match_cancel() == {"FINISHED"}
    assert job.state == "cancelled" and m.job_error == "cancelled" and jobs.current() is None
    assert _gone(pid)                            # the child and its whole process group
    left = sorted(p.name for p in tmp_path.rglob("*") if p.suffix in (".toml", ".json", ".part")
                  or p.name.endswith("-steps"))
    assert left == [], left                      # no fire-i-v2.toml, no steps, no JSON, no temporaries
    assert m.versions[0].error < 0 and len(m.versions) == 1


def test_a_failed_job_is_one_line_in_the_panel(scene, tmp_path):
    m = scene.lowcam_match
    broken = tmp_path / "broken-set"
    broken.mkdir()
    (broken / "set.toml").write_text("[[capture]]\nname = 1\n")
    m.measurement_set = str(broken)
    job = _finished(bpy.ops.lowcam.match_compare)
    _drive()
    assert job.state == "failed"
    assert m.job_error.startswith("lowcam compare: error: ") and "\n" not in m.job_error
    assert m.error < 0 and not (tmp_path / "shot-match" / "compare-fire-i.json").exists()
    m.measurement_set = ""                       # Diagnose needs a set: refused before any process starts
    with pytest.raises(RuntimeError, match="needs a measurement set"):
        bpy.ops.lowcam.match_diagnose()
    assert "needs a measurement set" in m.job_error and jobs.current() is None


def test_estimate_from_the_plate_writes_beside_the_blend_and_selects_it(scene, tmp_path):
    """In background mode the operator waits for its job, as a ``blender -b`` script needs."""
    m = scene.lowcam_match
    assert bpy.ops.lowcam.match_estimate() == {"FINISHED"} and jobs.current() is None
    estimate = tmp_path / "shot-plate.toml"
    assert Path(bpy.path.abspath(scene.lowcam.profile_file)) == estimate
    assert "estimated from the plate" in estimate.read_text()
    assert [v.label for v in m.versions] == ["plate estimate"] and "applied" in m.summary
    assert bpy.path.abspath(scene.lowcam.profile_file) != ""
    assert submodule("addon.frames").scene_profile(scene).path.resolve() == estimate.resolve()


def test_without_a_measurement_set_compare_looks_at_the_plate_alone(scene, measured, tmp_path):
    m = scene.lowcam_match
    m.measurement_set = ""
    assert bpy.ops.lowcam.match_compare() == {"FINISHED"}
    cli = tmp_path / "cli-plate.json"
    _cli("compare", "--plate-only", measured / "frames" / "noise-field-[0-9][0-9][0-9].png", "--json", cli)
    doc = json.loads(cli.read_text())
    assert m.error == pytest.approx(doc["error"], rel=1e-6) and m.verdict == doc["verdict"]
    assert m.where.startswith(f"probe {doc['where']['worst']['probe']} ")
    assert bpy.data.images["Lowcam Residual Map"].filepath.endswith("plate_probes.png")


HEADLESS_SCRIPT = r'''
import json, sys, bpy
from lowcam_blender import submodule
submodule("addon.match")                      # registers the add-on, as Blender does when it is enabled
bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
m = bpy.context.scene.lowcam_match
bpy.ops.lowcam.match_compare()                # background: waits for its job
print(json.dumps({"error": m.error, "verdict": m.verdict, "where": m.where, "profile": m.versions[0].profile}))
'''


def test_a_headless_script_runs_the_operators_like_the_command_line(scene, measured, tmp_path):
    """A separate process, as ``blender -b shot.blend --python loop.py`` would be: the set named relative to the
    .blend (``//``), the operator waits for its job, and the panel's numbers are the command line's."""
    (tmp_path / "set").symlink_to(measured, target_is_directory=True)
    scene.lowcam_match.measurement_set = "//set"
    bpy.ops.wm.save_mainfile()
    r = subprocess.run([sys.executable, "-c", HEADLESS_SCRIPT, str(tmp_path / "shot.blend")], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    panel = json.loads(r.stdout.strip().splitlines()[-1])
    cli = json.loads((tmp_path / "shot-match" / "compare-fire-i.json").read_text())
    _cli("compare", measured, "--profile", "fire-i", "--json", tmp_path / "cli.json")
    assert json.loads((tmp_path / "cli.json").read_text())["error"] == cli["error"]
    assert panel["error"] == pytest.approx(cli["error"], rel=1e-6) and panel["verdict"] == cli["verdict"]
    assert panel["where"] and panel["profile"] == "fire-i"


def test_an_unsaved_file_writes_its_profiles_to_a_temporary_folder():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    folder = match.profile_folder()
    assert folder.is_dir() and folder.is_relative_to(tempfile.gettempdir())
    assert match.work_folder().parent == folder


def test_profile_files_drive_the_handler_the_node_and_save_as(scene, tmp_path):
    from lowcam.profile import load_profile

    s = scene.lowcam
    mine = tmp_path / "elsewhere" / "my-camera.toml"
    mine.parent.mkdir()
    load_profile("fire-i").with_controls(saturation=70.0).save(mine)
    s.profile_file = str(mine)
    frames = submodule("addon.frames")
    assert frames.scene_profile(scene).path.resolve() == mine.resolve()
    assert s.saturation == pytest.approx(70.0)                  # the file's own settings are shown
    assert bpy.ops.lowcam.add_camera_node() == {"FINISHED"}
    tree = submodule("blender_compat").compositor_tree(scene)
    node = next(n for n in tree.nodes if n.bl_idname == "LowcamCameraNode")
    assert node.use_scene_profile and Path(node.node_tree["lowcam_profile"]).resolve() == mine.resolve()
    # Save Profile As: the profile with the scene's saturation, selected; the node follows
    s.saturation = 77.0
    saved = tmp_path / "saved" / "graded"
    saved.parent.mkdir()
    assert bpy.ops.lowcam.save_profile_as(filepath=str(saved)) == {"FINISHED"}
    assert Path(bpy.path.abspath(s.profile_file)) == saved.with_suffix(".toml")
    assert load_profile(saved.with_suffix(".toml")).controls()["saturation"] == pytest.approx(77.0)
    assert Path(node.node_tree["lowcam_profile"]).resolve() == saved.with_suffix(".toml").resolve()
    s.profile = "fire-i"                          # a name from the menu replaces the file
    assert s.profile_file == "" and frames.scene_profile(scene).name == "fire-i"


def test_estimate_takes_the_tracked_cameras_motion_as_its_gyro(scene, tmp_path):
    """With the motion taken from the scene camera (a camera solved from the clip's tracks drives it the same
    way), Estimate hands ``calibrate plate`` that camera's motion as a gyro log: a camera panning about the world's
    vertical at 0.5 rad/s, looking along the horizon, gives each plate frame an angular velocity of 0.5 rad/s about
    the camera's vertical (Lowcam's y points down, so a turn to the left is -y) and none about the others."""
    import math

    rate, fps = 0.5, 25
    scene.render.fps, scene.render.fps_base = fps, 1.0
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.rotation_euler = (math.pi / 2, 0.0, 0.0)
    for frame in (-5, 20):
        camera.rotation_euler[2] = rate * frame / fps
        camera.keyframe_insert("rotation_euler", index=2, frame=frame)
    for curve in submodule("blender_compat").action_fcurves(camera):
        for key in curve.keyframe_points:
            key.interpolation = "LINEAR"
    scene.lowcam.motion_source = "CAMERA"
    assert match.plate_frames(scene) == (0, 2)                    # noise-field-000.png and -001.png
    assert bpy.ops.lowcam.match_estimate() == {"FINISHED"} and jobs.current() is None, scene.lowcam_match.job_error
    log = np.loadtxt(Path(match.work_folder()) / "camera-gyro.csv", delimiter=",", skiprows=1)
    assert log[0, 0] == 0.0 and log[-1, 0] >= 2 / fps                  # both frames and their exposures
    assert np.allclose(log[:, 1:], [0.0, -rate, 0.0], atol=1e-4), log[:3]
    doc = json.loads((Path(match.work_folder()) / "estimate.json").read_text())
    gyro = doc["calibrations"][0]["numbers"]["gyro_motion"]["footage"]
    assert abs(gyro["median_speed_rad_s"] - rate) < 1e-3 and abs(gyro["max_speed_rad_s"] - rate) < 1e-3, gyro


def test_a_running_jobs_progress_redraws_the_panels_at_most_every_redraw_s(monkeypatch):
    """Each redraw costs a software-drawn window tenths of a second: a job's changing progress line is shown at
    most every ``REDRAW_S``, while a job's start and its end are shown at once."""
    clock = [100.0]
    monkeypatch.setattr(jobs.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(jobs, "_shown", [None, 0.0])
    shown = []
    for step_s, line in ((0.0, "diagnosing: 0 s"), (0.1, "diagnosing: 1 s"), (jobs.REDRAW_S, "diagnosing: 2 s"),
                         (0.01, None), (0.01, "comparing: 0 s")):
        clock[0] += step_s
        jobs._redraw(line)
        shown.append(jobs._shown[0])
    assert shown == ["diagnosing: 0 s", "diagnosing: 0 s", "diagnosing: 2 s", None, "comparing: 0 s"]
