"""Shots: serial, Dask (real workers on loopback) and chunked runs give the same bytes; resume; bad frames."""
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from lowcam.batch import Shot, expand_pattern, parse_frames, process_frame, run_shot
from lowcam.errors import LowcamError
from lowcam.motion import FrameMotion, read_motion_json, write_motion_json
from lowcam.outputs import write_exr
from lowcam.sample import sample_plate

from helpers import disk_render

FRAMES = list(range(1, 13))


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory, fire_i):
    d = tmp_path_factory.mktemp("shot")
    plate = sample_plate(fire_i)
    motion = {}
    for f in FRAMES:
        write_exr(d / "renders" / f"{f:04d}.exr", disk_render(fire_i, 0.15, centre=(-0.5 + 0.08 * f, 0.1), width=800))
        cv2.imwrite(str(d / "plates" / f"{f:04d}.png") if (d / "plates").mkdir(exist_ok=True) is None else "",
                    cv2.cvtColor(np.roll(plate, 3 * f, axis=1), cv2.COLOR_RGB2BGR))
        motion[f] = FrameMotion((0.02 * f, 0.5 - 0.05 * f, 0.0), 0.02 + 0.001 * f)
    write_motion_json(d / "motion.json", motion, fps=30)
    return d


def lowcam_batch(d, out, *extra):
    return subprocess.run([sys.executable, "-m", "lowcam.cli", "batch", "--profile", "fire-i",
                           "--renders", str(d / "renders/####.exr"), "--plates", str(d / "plates/####.png"),
                           "--motion", str(d / "motion.json"), "-o", str(out / "####.png"), *extra],
                          capture_output=True, text=True, timeout=600)


def frame_bytes(folder):
    return {p.name: p.read_bytes() for p in sorted(Path(folder).glob("*.png"))}


def test_patterns_and_frame_ranges():
    assert expand_pattern("r/####.exr", 7) == "r/0007.exr" and expand_pattern("r/%03d.png", 7) == "r/007.png"
    assert parse_frames("1-4,9,20-24x2") == [1, 2, 3, 4, 9, 20, 22, 24]


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_serial_dask_and_chunked_runs_give_the_same_bytes(shot_dir, tmp_path):
    shot = Shot("fire-i", str(shot_dir / "renders/####.exr"), str(tmp_path / "serial/####.png"),
                str(shot_dir / "plates/####.png"), read_motion_json(shot_dir / "motion.json"), True)
    results = run_shot(shot, FRAMES, quiet=True)
    assert [r.status for r in results] == ["written"] * 12
    serial = frame_bytes(tmp_path / "serial")
    assert len(serial) == 12 and len(set(serial.values())) == 12

    shot.output = str(tmp_path / "dask/####.png")
    results = run_shot(shot, FRAMES, workers=2, quiet=True)
    assert [r.status for r in results] == ["written"] * 12
    assert frame_bytes(tmp_path / "dask") == serial

    for chunk in ("1-6", "7-12"):
        r = lowcam_batch(shot_dir, tmp_path / "chunks", "--frames", chunk, "--quiet")
        assert r.returncode == 0, r.stderr
    assert frame_bytes(tmp_path / "chunks") == serial


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_two_shots_at_once_on_one_scheduler_each_get_their_own_frames(shot_dir, tmp_path):
    """A farm's shared Dask scheduler: two shots of the same frame numbers submitted at once each run their own
    tasks (the same keys would have handed the second shot the first one's results, its frames never made)."""
    from concurrent.futures import ThreadPoolExecutor

    from dask.distributed import LocalCluster

    def shot(name, seed):
        return Shot("fire-i", str(shot_dir / "renders/####.exr"), str(tmp_path / f"{name}/####.png"),
                    str(shot_dir / "plates/####.png"), read_motion_json(shot_dir / "motion.json"), True, seed=seed)

    run_shot(shot("serial-a", 1), FRAMES, quiet=True)
    run_shot(shot("serial-b", 2), FRAMES, quiet=True)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            ThreadPoolExecutor(2) as pool:
        runs = [pool.submit(run_shot, shot(name, seed), FRAMES, scheduler=cluster.scheduler_address, quiet=True)
                for name, seed in (("a", 1), ("b", 2))]
        assert all([r.status for r in run.result()] == ["written"] * 12 for run in runs)
    assert frame_bytes(tmp_path / "a") == frame_bytes(tmp_path / "serial-a")
    assert frame_bytes(tmp_path / "b") == frame_bytes(tmp_path / "serial-b") != frame_bytes(tmp_path / "a")


DYING = '''
import os
from lowcam.effects import Effect, Param


class Dying(Effect):
    """Ends the worker process that runs it, as the kernel's out-of-memory killer would."""

    name = "dying"
    writes = "bayer"
    order = 125
    params = {"code": Param(3.0, low=0.0, high=255.0)}

    def apply(self, state):
        os._exit(int(self.code))
'''


RAISING = '''
import numpy as np
from lowcam.effects import Effect


class Raising(Effect):
    """A user's effect with a bug in its last stage."""

    name = "raising"
    writes = "output"
    order = 300

    def apply(self, state):
        pass

    def finish(self, state, frame, footprint):
        return np.broadcast_to(frame, (2,) + frame.shape)[5], footprint
'''


def test_a_plug_in_effect_that_raises_fails_each_frame_in_one_line(shot_dir, tmp_path, monkeypatch, fire_i):
    """A plug-in's exception in a serial shot is that frame's one-line failure naming the effect and its line, and
    the shot goes on to the next frame (it was a traceback that ended the shot)."""
    (tmp_path / "user_raising.py").write_text(RAISING)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "user_raising")
    try:
        profile = fire_i.with_effect("user_raising:Raising").save(tmp_path / "raising.toml")
    finally:
        sys.modules.pop("user_raising", None)
    r = lowcam_batch(shot_dir, tmp_path / "out", "--profile", str(profile), "--frames", "1-2")
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    line = (f"plug-in effect 'raising' (user_raising:Raising) failed at {tmp_path / 'user_raising.py'}:17: "
            "IndexError: index 5 is out of bounds for axis 0 with size 2")
    assert f"frame 1: {line}" in r.stderr and f"frame 2: {line}" in r.stderr, r.stderr
    assert not list((tmp_path / "out").glob("*.png"))


@pytest.mark.parametrize("statement", ["sys.exit(3)", "raise ValueError('bad\\nstate')"])
def test_a_plug_in_that_exits_or_raises_is_one_line_and_is_not_imported_again(tmp_path, monkeypatch, capsys,
                                                                            fire_i, statement):
    """From Python too (``lowcam.run``): ``sys.exit`` in a plug-in ends no shot, and the line is found without
    importing the plug-in's module again (it may be gone from ``sys.modules``: its code would run twice)."""
    import lowcam
    from lowcam.effects import PLUGINS

    (tmp_path / "user_exiting.py").write_text(f"""
import sys
from lowcam.effects import Effect
print("IMPORTED")


class Exiting(Effect):
    name = "exiting"
    writes = "bayer"
    order = 125

    def apply(self, state):
        {statement}
""")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "user_exiting")
    try:
        profile = fire_i.with_effect("user_exiting:Exiting")
        sys.modules.pop("user_exiting")
        with pytest.raises(LowcamError) as e:
            lowcam.run(disk_render(fire_i, 0.2), profile)
        assert "user_exiting" not in sys.modules and capsys.readouterr().out.count("IMPORTED") == 1
    finally:
        sys.modules.pop("user_exiting", None)
        PLUGINS.pop("user_exiting:Exiting", None)
    kind = "SystemExit: 3" if "exit" in statement else "ValueError: bad state"
    assert str(e.value) == (f"plug-in effect 'exiting' (user_exiting:Exiting) failed at "
                            f"{tmp_path / 'user_exiting.py'}:13: {kind}")


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_a_frame_whose_dask_worker_dies_fails_in_one_line(shot_dir, tmp_path, monkeypatch, fire_i):
    """A worker killed under a frame (here: a plug-in effect ends its process) is that frame's failure, in one
    line, not a traceback that ends the shot."""
    import dask
    from dask.distributed import LocalCluster

    (tmp_path / "user_dying.py").write_text(DYING)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "user_dying")
    profile = fire_i.with_effect("user_dying:Dying").save(tmp_path / "dying.toml")
    shot = Shot(str(profile), str(shot_dir / "renders/####.exr"), str(tmp_path / "out/####.png"),
                str(shot_dir / "plates/####.png"), read_motion_json(shot_dir / "motion.json"), True,
                plugins=("user_dying",))
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
                LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            results = run_shot(shot, [1, 2], scheduler=cluster.scheduler_address, quiet=True)
    finally:
        sys.modules.pop("user_dying", None)
    assert [r.status for r in results] == ["failed", "failed"]
    assert all("its Dask worker failed (KilledWorker" in r.message and "\n" not in r.message for r in results)
    assert not list((tmp_path / "out").glob("*.png"))


@pytest.mark.parametrize("workers", [[], pytest.param(["--workers", "2"], marks=pytest.mark.slow)],
                         ids=["serial", "dask"])
def test_a_killed_run_resumes_without_redoing_finished_frames(shot_dir, tmp_path, workers):
    out = tmp_path / "resume"
    cmd = [sys.executable, "-m", "lowcam.cli", "batch", "--renders", str(shot_dir / "renders/####.exr"),
           "--plates", str(shot_dir / "plates/####.png"), "--motion", str(shot_dir / "motion.json"),
           "--frames", "1-12", "-o", str(out / "####.png"), "--quiet", *workers]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    while len(list(out.glob("*.png"))) < 3 and time.time() < deadline:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)  # the job and its Dask workers, as a farm kills a task
    proc.wait()
    time.sleep(0.5)
    done = {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")}
    assert 3 <= len(done) < 12
    for p in out.glob("*.png"):  # every frame that exists is complete
        assert cv2.imread(str(p)).shape == (480, 640, 3)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"{12 - len(done)} written, {len(done)} already done, 0 failed" in r.stdout
    assert all((out / name).stat().st_mtime_ns == t for name, t in done.items())
    assert len(list(out.glob("*.png"))) == 12 and not list(out.glob(".*"))


def test_a_corrupt_frame_is_reported_by_name_and_the_others_are_written(shot_dir, tmp_path):
    bad = tmp_path / "renders"
    bad.mkdir()
    for f in FRAMES:
        os.symlink(shot_dir / "renders" / f"{f:04d}.exr", bad / f"{f:04d}.exr")
    (bad / "0006.exr").unlink()
    (bad / "0006.exr").write_bytes((shot_dir / "renders" / "0006.exr").read_bytes()[:300])
    (bad / "0009.exr").unlink()  # a missing frame too
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "batch", "--renders", str(bad / "####.exr"),
                        "--frames", "1-12", "-o", str(tmp_path / "out/####.png"), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1
    assert "10 written, 0 already done, 2 failed" in r.stderr
    assert f"frame 6: {bad / '0006.exr'}: not a readable OpenEXR file" in r.stderr
    assert f"frame 9: {bad / '0009.exr'}: no such file" in r.stderr
    written = sorted(p.name for p in (tmp_path / "out").glob("*.png"))
    assert written == [f"{f:04d}.png" for f in FRAMES if f not in (6, 9)]


def test_a_serial_shot_reads_ahead_and_writes_behind_with_the_bytes_of_one_frame_at_a_time(shot_dir, tmp_path):
    """The overlapped serial run (reading, simulating and writing on three threads) against process_frame called
    frame after frame: the same bytes, the same failures and skips, in frame order, each frame's time split."""
    renders = tmp_path / "renders"
    renders.mkdir()
    for f in FRAMES[:6]:
        os.symlink(shot_dir / "renders" / f"{f:04d}.exr", renders / f"{f:04d}.exr")
    (renders / "0004.exr").unlink()
    (renders / "0004.exr").write_bytes((shot_dir / "renders" / "0004.exr").read_bytes()[:300])
    motion = read_motion_json(shot_dir / "motion.json")
    del motion[5]   # no motion for frame 5: failed before its render is read

    def shot(out):
        return Shot("fire-i", str(renders / "####.exr"), str(tmp_path / out / "####.png"),
                    str(shot_dir / "plates/####.png"), motion, True)

    one_at_a_time = [process_frame(shot("single"), f) for f in FRAMES[:6]]
    (tmp_path / "overlapped").mkdir()
    (tmp_path / "overlapped" / "0002.png").write_bytes((tmp_path / "single" / "0002.png").read_bytes())  # done
    overlapped = run_shot(shot("overlapped"), FRAMES[:6], quiet=True)
    assert [r.status for r in one_at_a_time] == ["written", "written", "written", "failed", "failed", "written"]
    assert [r.status for r in overlapped] == ["written", "skipped", "written", "failed", "failed", "written"]
    assert [r.message for r in overlapped] == [r.message for r in one_at_a_time]
    assert "not a readable OpenEXR file" in overlapped[3].message and "no entry" in overlapped[4].message
    single, both = frame_bytes(tmp_path / "single"), frame_bytes(tmp_path / "overlapped")
    assert both == single and len(both) == 4
    for r in overlapped:
        assert (r.read_s > 0 and r.simulate_s > 0 and r.write_s > 0) == (r.status == "written")


def test_a_shot_checks_each_render_once_where_it_reads_it(shot_dir, tmp_path, monkeypatch):
    """The reading thread checks the render (lowcam.io.read_checked_render) and the simulation takes its window
    without scanning the render again; the frames are those of lowcam.simulate on the plain array, which checks.
    A CheckedRender that is not what the check returns is refused."""
    import threading

    import lowcam
    from lowcam import io, pipeline
    from lowcam.errors import LowcamError
    from lowcam.io import CheckedRender, read_plate, read_render

    motion = read_motion_json(shot_dir / "motion.json")
    expected = {}
    for f in (2, 7):
        plate = read_plate(shot_dir / "plates" / f"{f:04d}.png", 640, 480)
        m = motion[f]
        expected[f] = lowcam.simulate(read_render(shot_dir / "renders" / f"{f:04d}.exr"), "fire-i", plate,
                                      m.angular_velocity, m.exposure_s, 0, f)
    checks, reads = [], []
    real_check = pipeline.check_render_window
    monkeypatch.setattr(pipeline, "check_render_window", lambda *a, **k: checks.append(1) or real_check(*a, **k))
    monkeypatch.setattr(io, "check_render_window",
                        lambda *a, **k: reads.append(threading.current_thread().name) or real_check(*a, **k))
    shot = Shot("fire-i", str(shot_dir / "renders/####.exr"), str(tmp_path / "####.png"),
                str(shot_dir / "plates/####.png"), motion, True)
    assert [r.status for r in run_shot(shot, [2, 7], quiet=True)] == ["written", "written"]
    assert checks == [] and len(reads) == 2 and all(name.startswith("lowcam-read") for name in reads)
    for f, frame in expected.items():
        assert np.array_equal(cv2.cvtColor(cv2.imread(str(tmp_path / f"{f:04d}.png")), cv2.COLOR_BGR2RGB), frame)
    render = read_render(shot_dir / "renders/0002.exr")
    lowcam.simulate(render, "fire-i")
    assert checks == [1]   # an array handed in is checked
    for wrong in (CheckedRender(render.astype(np.float64), None),
                  CheckedRender(render, (slice(0, render.shape[0] + 1), slice(0, 10)))):
        with pytest.raises(LowcamError, match="CheckedRender must be what"):
            lowcam.simulate(wrong, "fire-i")


def test_a_serial_shot_shows_its_progress_on_a_terminal(shot_dir, tmp_path):
    """The bar is drawn while a reader thread keeps the codecs' messages off descriptor 2."""
    import fcntl
    import pty
    import struct
    import termios

    parent, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a terminal 100 columns wide
    proc = subprocess.Popen([sys.executable, "-m", "lowcam.cli", "batch", "--renders",
                             str(shot_dir / "renders/####.exr"), "--frames", "1-6", "-o", str(tmp_path / "####.png")],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=child)
    os.close(child)
    said = b""
    while True:
        try:
            chunk = os.read(parent, 4096)
        except OSError:   # the child closed the terminal
            break
        if not chunk:
            break
        said += chunk
    os.close(parent)
    assert proc.wait(timeout=300) == 0
    text = said.decode(errors="replace")
    assert "6/6 frames" in text and any(f" {k}/6 frames" in text for k in range(1, 6)), text


def test_plates_from_one_video_file(shot_dir, tmp_path, fire_i):
    video = tmp_path / "plate.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, (640, 480))
    for f in FRAMES:
        writer.write(cv2.imread(str(shot_dir / "plates" / f"{f:04d}.png")))
    writer.release()
    shot = Shot("fire-i", str(shot_dir / "renders/####.exr"), str(tmp_path / "v/####.png"), str(video))
    results = run_shot(shot, [3, 4], quiet=True)
    assert [r.status for r in results] == ["written", "written"]
    out = cv2.imread(str(tmp_path / "v" / "0004.png")).astype(int)
    plate4 = cv2.imread(str(shot_dir / "plates" / "0004.png")).astype(int)
    plate3 = cv2.imread(str(shot_dir / "plates" / "0003.png")).astype(int)
    corner = (slice(0, 60), slice(0, 60))  # far from the object: the (JPEG-coded) plate of the same frame
    assert np.abs(out[corner] - plate4[corner]).mean() < 3 < np.abs(out[corner] - plate3[corner]).mean()
    (tmp_path / "r").mkdir()
    os.symlink(shot_dir / "renders" / "0001.exr", tmp_path / "r" / "0040.exr")
    bad = run_shot(Shot("fire-i", str(tmp_path / "r/####.exr"), str(tmp_path / "w/####.png"), str(video)), [40],
                   quiet=True)
    assert bad[0].status == "failed" and "the video has 12 frames" in bad[0].message


def test_motion_json_from_a_keyframed_blender_camera_round_trips(tmp_path):
    import bpy

    from addon.motion import camera_motion

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 24, 1.0
    scene.render.motion_blur_shutter = 0.5
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    cam.rotation_mode = "XYZ"
    yaw_rate = 0.6  # rad/s about world z; the camera looks level along +y
    for f in (1, 49):
        cam.rotation_euler = (np.pi / 2, 0.0, yaw_rate * (f - 1) / 24)
        cam.keyframe_insert("rotation_euler", frame=f)
    action = cam.animation_data.action
    for fc in action.layers[0].strips[0].channelbag(cam.animation_data.action_slot).fcurves:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    motion = camera_motion(scene, cam, range(5, 41, 5))
    for m in motion.values():
        # turning left about the camera's up axis: Lowcam's y points down, so w_y = -0.6 rad/s
        assert np.allclose(m.angular_velocity, (0.0, -yaw_rate, 0.0), atol=1e-5)
        assert m.exposure_s == pytest.approx(0.5 / 24)
    path = write_motion_json(tmp_path / "motion.json", motion, fps=24)
    assert read_motion_json(path) == motion
    assert json.loads(path.read_text())["frames"][0]["frame"] == 5


@pytest.mark.slow
def test_the_farm_recipe_with_concurrent_one_frame_tasks_never_fails(shot_dir, tmp_path):
    """The README's farm recipe, one frame per task, two tasks at a time into one folder (xargs -P 2), twice:
    a task's start-up must not remove another live task's temporary, so no task fails."""
    serial = tmp_path / "serial"
    assert lowcam_batch(shot_dir, serial, "--frames", "1-8", "--quiet").returncode == 0
    out = tmp_path / "farm"
    task = (f"{sys.executable} -m lowcam.cli batch --profile fire-i --renders '{shot_dir}/renders/####.exr' "
            f"--plates '{shot_dir}/plates/####.png' --motion '{shot_dir}/motion.json' --frames {{}} "
            f"-o '{out}/####.png' --quiet --force")
    for _ in range(2):
        r = subprocess.run(["xargs", "-P", "2", "-I", "{}", "sh", "-c", task], input="\n".join(map(str, range(1, 9))),
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        assert "failed" not in r.stderr and "Traceback" not in r.stderr
        assert frame_bytes(out) == frame_bytes(serial)
        assert not list(out.glob(".lowcam-*"))


def _read_rgb(path):
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


@pytest.mark.parametrize("workers", [0, pytest.param(2, marks=pytest.mark.slow)], ids=["serial", "dask"])
def test_a_temporal_filter_follows_the_frame_before_and_resumes_to_the_same_bytes(shot_dir, tmp_path, fire_i,
                                                                                   workers):
    """Each frame's graphics averaged with the shot's frame before, as written: ``out_k = round(x_k + w (out_{k-1}
    - x_k))``, ``w = 0.7 clip(2 - 2 |luma change| / 255, 0, 1)``, ``x_k`` the frame without the filter; the first
    frame has none before it. A resumed run, and Dask's workers, make the same bytes; JPEG and EXR frames are
    refused."""
    frames = [1, 2, 3, 4]
    profile = fire_i.with_effect("temporal_noise_reduction", strength=0.7, motion_threshold_dn=255.0)
    motion = read_motion_json(shot_dir / "motion.json")
    args = (str(shot_dir / "renders/####.exr"),)
    plates = str(shot_dir / "plates/####.png")
    plain = Shot("fire-i", *args, str(tmp_path / "plain/####.png"), plates, motion, True)
    shot = Shot(str(profile.save(tmp_path / "tnr.toml")), *args, str(tmp_path / "tnr/####.png"), plates, motion, True)
    run_shot(plain, frames, quiet=True)
    assert [r.status for r in run_shot(shot, frames, workers=workers, quiet=True)] == ["written"] * 4
    got = {f: _read_rgb(shot.output_path(f)).astype(float) for f in frames}
    x = {f: _read_rgb(plain.output_path(f)).astype(float) for f in frames}
    assert np.array_equal(got[1], x[1])
    for f in frames[1:]:
        plate = _read_rgb(shot_dir / f"plates/{f:04d}.png").astype(float)
        graphics = np.any(x[f] != plate, axis=2)
        assert 0.02 < graphics.mean() < 0.5
        w = 0.7 * np.clip(2 - 2 * np.abs((got[f - 1] - x[f]) @ np.array([0.299, 0.587, 0.114])) / 255, 0, 1)
        expected = np.rint(x[f] + w[..., None] * (got[f - 1] - x[f]))
        assert np.abs(got[f] - expected)[graphics].max() <= 1
        # the footprint reaches past the pixels that changed: the blur's faint edge, the 4:1:1 groups
        near = cv2.dilate(graphics.astype(np.uint8), np.ones((41, 41), np.uint8)).astype(bool)
        assert np.array_equal(got[f][~near], plate[~near])
        assert np.abs(got[f] - x[f])[graphics].mean() > 1.0
    made = frame_bytes(tmp_path / "tnr")
    for f in (3, 4):
        shot.output_path(f).unlink()
    run_shot(shot, frames, workers=workers, quiet=True)
    assert frame_bytes(tmp_path / "tnr") == made
    # a chunk that starts before the frame it follows is written (chunks at once, every other frame) fails those
    # frames in one line each and writes nothing; made in order afterwards, the same bytes
    shot.output = str(tmp_path / "chunks/####.png")
    early = run_shot(shot, [3, 4], workers=workers, quiet=True)
    assert [r.status for r in early] == ["failed"] * 2 and "follows frame 2, which is not written" in early[0].message
    assert "\n" not in early[0].message and not list((tmp_path / "chunks").glob("*.png"))
    assert [r.status for r in run_shot(shot, frames, workers=workers, quiet=True)] == ["written"] * 4
    assert frame_bytes(tmp_path / "chunks") == made
    # JPEG or EXR frames would change what the next frame reads: refused in one line before any frame
    for suffix in ("jpg", "exr"):
        shot.output = str(tmp_path / f"lossy/####.{suffix}")
        with pytest.raises(LowcamError, match="write PNG frames") as e:
            run_shot(shot, frames, quiet=True)
        assert "\n" not in str(e.value) and not (tmp_path / "lossy").exists()


def test_a_serial_shot_reads_uncompressed_renders_into_a_few_reused_arrays(shot_dir, tmp_path, monkeypatch):
    """Renders in the add-on's uncompressed format, read strip by strip and checked as they are read: the overlapped
    serial shot gives the bytes of process_frame frame after frame and reads its eight renders into at most four
    arrays (two read ahead, one simulated, one being read), reused as each frame is done with."""
    import OpenEXR

    from lowcam import io
    from lowcam.io import read_render

    renders = tmp_path / "renders"
    renders.mkdir()
    for f in FRAMES[:8]:
        rgba = read_render(shot_dir / "renders" / f"{f:04d}.exr")
        OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {c: rgba[..., i].copy() for i, c in enumerate("RGBA")}).write(str(renders / f"{f:04d}.exr"))
    motion = read_motion_json(shot_dir / "motion.json")

    def shot(out):
        return Shot("fire-i", str(renders / "####.exr"), str(tmp_path / out / "####.png"),
                    str(shot_dir / "plates/####.png"), motion, True)

    one_at_a_time = [process_frame(shot("single"), f) for f in FRAMES[:8]]
    addresses, take = [], io._render_buffers.take

    def noted(*args):
        array = take(*args)
        addresses.append(array.__array_interface__["data"][0])
        return array

    monkeypatch.setattr(io._render_buffers, "take", noted)
    overlapped = run_shot(shot("overlapped"), FRAMES[:8], quiet=True)
    assert [r.status for r in overlapped] == [r.status for r in one_at_a_time] == ["written"] * 8
    assert frame_bytes(tmp_path / "overlapped") == frame_bytes(tmp_path / "single")
    assert len(addresses) == 8 and len(set(addresses)) <= 4


@pytest.mark.slow  # a Dask cluster
def test_a_shot_on_dask_ends_when_another_client_of_the_process_closes_first(shot_dir, tmp_path, monkeypatch):
    """Dask's as_completed follows the process's newest client unless told which: a shot whose client was made
    before another shot's, which then closed first, waited for ever (seen once as a hung CI run). Here a second
    client is made just after the shot's and closed while the shot runs: the shot still ends, every frame made."""
    import threading

    from dask.distributed import Client, LocalCluster

    from lowcam import batch

    made = batch._dask_client
    others = []

    @contextlib.contextmanager
    def with_a_newer_client(workers, scheduler):
        with made(workers, scheduler) as client:
            others.append(Client(scheduler, timeout="10s"))       # the process's newest client now
            threading.Timer(1.0, others[-1].close).start()        # closed while the shot runs
            yield client

    monkeypatch.setattr(batch, "_dask_client", with_a_newer_client)
    shot = Shot("fire-i", str(shot_dir / "renders/####.exr"), str(tmp_path / "out/####.png"),
                str(shot_dir / "plates/####.png"), read_motion_json(shot_dir / "motion.json"), True)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        finished = []
        run = threading.Thread(target=lambda: finished.append(
            run_shot(shot, FRAMES, scheduler=cluster.scheduler_address, quiet=True)), daemon=True)
        run.start()
        run.join(timeout=120)
        assert finished and [r.status for r in finished[0]] == ["written"] * len(FRAMES)
    assert len(others) == 1 and others[0].status == "closed"
