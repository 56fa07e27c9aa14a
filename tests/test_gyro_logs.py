"""Gyroflow's gyro logs (``.gcsv``, ``.gyroflow``) as camera motion: read back to a known rotation, driving
``lowcam batch``'s motion blur and rolling shutter as Lowcam's own CSV of that rotation does, and refused in one
line when hostile (lowcam/gyro_logs.py)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lowcam.cli import main
from lowcam.gyro_logs import (GYROFLOW_TO_CAMERA, imu_rotation, log_kind, orientation_matrix, read_gcsv,
                              read_gyro_log, read_gyroflow_project)
from lowcam.motion import read_motion_json

ROOT = Path(__file__).resolve().parent.parent
GSCALE = 0.00053263221          # rad/s per unit: a +-1000 deg/s gyro on 16 bits (Gyroflow's docs)
TSCALE = 1e-6                   # timestamps in us
T_START = 12.5                  # s: the log starts 12.5 s into its clock
ORIENTATION = "zXy"             # Gyroflow's x = file z, y = file x, z = -file y


def known_rate(t):
    """The known motion (rad/s, Lowcam's camera frame: x right, y down, z forward): a pan of 0.8 rad/s about the
    camera's y with a roll about z rising from 0.3 rad/s at the log's start by 0.5 rad/s each second."""
    t = np.asarray(t, np.float64)
    return np.stack([np.zeros_like(t), np.full_like(t, 0.8), 0.3 + 0.5 * (t - T_START)], -1)


def sample_times(n=400, rate_hz=200.0):
    return T_START + np.arange(n) / rate_hz


def file_axes(w_camera, orientation=ORIENTATION):
    """A camera-frame rate in the file's axes: ``w_camera = C O w_file``, so ``w_file = (C O)^T w_camera``."""
    return w_camera @ (GYROFLOW_TO_CAMERA @ orientation_matrix(orientation, "test"))


def write_gcsv(path: Path, t, w_camera, orientation=ORIENTATION, header_extra="", first="GYROFLOW IMU LOG"):
    raw = file_axes(w_camera, orientation) / GSCALE
    lines = [first, "version,1.3", "id,lowcam_test_logger", f"orientation,{orientation}", "note,known rotation",
             "frame_readout_time,15.0", f"tscale,{TSCALE!r}", f"gscale,{GSCALE!r}", "ascale,0.00048828125"]
    lines += [header_extra] if header_extra else []
    lines.append("t,gx,gy,gz,ax,ay,az")
    lines += [f"{round(ti / TSCALE)},{g[0]!r},{g[1]!r},{g[2]!r},0,-2048,0" for ti, g in zip(t, raw)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_lowcam_csv(path: Path, t, w_camera):
    path.write_text("t,wx,wy,wz\n" + "".join(f"{ti!r},{w[0]!r},{w[1]!r},{w[2]!r}\n" for ti, w in zip(t, w_camera)))
    return path


# --- reading ---------------------------------------------------------------------------------------------------------

def test_gcsv_reads_back_the_known_rotation(tmp_path):
    t = sample_times()
    log = read_gcsv(write_gcsv(tmp_path / "clip.gcsv", t, known_rate(t)))
    assert log.kind == "gcsv" and log.orientation == ORIENTATION
    np.testing.assert_allclose(log.samples[:, 0], t, atol=1e-9)
    np.testing.assert_allclose(log.samples[:, 1:], known_rate(t), atol=1e-6)
    assert log.readout_s == pytest.approx(0.015)


def test_plate_calibration_reads_a_gcsv_in_the_camera_frame(tmp_path):
    """``calibrate plate --gyro`` (and the footage reader under it) takes a Gyroflow log as it takes Lowcam's CSV."""
    from lowcam.measure.plate import read_phone_gyro

    t = sample_times()
    samples, frame_times = read_phone_gyro(write_gcsv(tmp_path / "clip.gcsv", t, known_rate(t)))
    assert frame_times is None
    np.testing.assert_allclose(samples[:, 1:], known_rate(t), atol=1e-6)


def test_gyroflow_axes_are_up_left_back():
    """Gyroflow's IMU frame (its docs: z backward, x up, y left) in Lowcam's camera frame (x right, y down, z
    forward): a turn about Gyroflow's +x (up) is a turn about the camera's -y; about +y (left), -x; about +z
    (backward), -z. A proper rotation, as a gyro's axes are."""
    np.testing.assert_array_equal(GYROFLOW_TO_CAMERA @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_array_equal(GYROFLOW_TO_CAMERA @ [0, 1, 0], [-1, 0, 0])
    np.testing.assert_array_equal(GYROFLOW_TO_CAMERA @ [0, 0, 1], [0, 0, -1])
    assert np.linalg.det(GYROFLOW_TO_CAMERA) == pytest.approx(1.0)


def test_orientation_string_as_gyroflow_orients():
    """Gyroflow's ``orient``: letter i names the file axis that becomes axis i, lower case negated: ``YxZ`` turns
    (1, 2, 3) into (2, -1, 3)."""
    np.testing.assert_array_equal(orientation_matrix("YxZ", "f") @ [1, 2, 3], [2, -1, 3])
    np.testing.assert_array_equal(orientation_matrix("zXy", "f") @ [1, 2, 3], [-3, 1, -2])
    np.testing.assert_array_equal(orientation_matrix("XYZ", "f"), np.eye(3))


def test_imu_rotation_is_gyroflows_euler_order():
    """``rotation`` [pitch, roll, yaw] (deg) is nalgebra's from_euler_angles(yaw, pitch, roll) = Rz(roll) Ry(pitch)
    Rx(yaw): a roll of 90 deg alone takes x to y; a yaw of 90 alone takes y to z; a pitch of 90 alone z to x."""
    np.testing.assert_allclose(imu_rotation(0, 90, 0) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(imu_rotation(0, 0, 90) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(imu_rotation(90, 0, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    r = imu_rotation(10, 20, 30)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def _project(path: Path, gyro_source: dict, offsets=None, fps=30.0, fps_scale=None) -> Path:
    doc = {"title": "Gyroflow data file", "version": 3, "videofile": "clip.mp4",
           "video_info": {"width": 1920, "height": 1080, "fps": fps, "num_frames": 60, "fps_scale": fps_scale},
           "stabilization": {"frame_readout_time": 15.0}, "gyro_source": gyro_source, "offsets": offsets or {}}
    path.write_text(json.dumps(doc))
    return path


def test_project_with_embedded_imu_and_offsets(tmp_path):
    """Embedded raw IMU (ms, deg/s in the file's axes) with the project's orientation, and its synced offsets
    (gyro time in us -> ms) taking gyro time to video time: t_video = t_gyro + offset(t_gyro), linear between the
    points and along the end segments beyond them; the rates per second of video time."""
    t = sample_times()
    raw = np.degrees(file_axes(known_rate(t), "YxZ"))
    imu = [{"timestamp_ms": ti * 1000.0, "gyro": list(g), "accl": [0.0, 1.0, 0.0]} for ti, g in zip(t, raw)]
    offsets = {str(round(13.0e6)): -40.0, str(round(14.0e6)): -38.0}  # 2 ms per s of drift
    log = read_gyroflow_project(_project(tmp_path / "clip.gyroflow", {"raw_imu": imu, "imu_orientation": "YxZ"},
                                         offsets))
    shift_ms = -40.0 + 2.0 * (t - 13.0)
    np.testing.assert_allclose(log.samples[:, 0], t + shift_ms / 1000.0, atol=1e-9)
    # the video's clock runs 1.002 times the gyro's: per second of video, the camera turns 1/1.002 as far
    np.testing.assert_allclose(log.samples[:, 1:], known_rate(t) / 1.002, atol=1e-6)
    assert log.fps == 30.0 and log.kind == "gyroflow" and log.readout_s == pytest.approx(0.015)


def test_project_bias_and_rotation_applied_where_gyroflow_applies_them(tmp_path):
    """``gyro_bias`` (deg/s) is added in the file's axes before orienting, ``rotation`` applied after."""
    t = sample_times(50)
    w = known_rate(t)
    bias, rot = np.array([0.5, -1.0, 2.0]), imu_rotation(5.0, -10.0, 20.0)
    # the file holds R^-1 applied, minus the bias: reading must undo both
    gyroflow_axes = (GYROFLOW_TO_CAMERA.T @ w.T).T @ rot          # R^T w_gyroflow, rows
    file_deg = np.degrees(gyroflow_axes @ orientation_matrix("XYZ", "t")) - bias
    imu = [{"timestamp_ms": ti * 1000.0, "gyro": list(g)} for ti, g in zip(t, file_deg)]
    log = read_gyroflow_project(_project(tmp_path / "p.gyroflow", {"raw_imu": imu, "gyro_bias": list(bias),
                                                                   "rotation": [5.0, -10.0, 20.0]}))
    np.testing.assert_allclose(log.samples[:, 1:], w, atol=1e-6)


def test_project_reads_its_gcsv_when_the_data_is_compressed(tmp_path):
    """Gyroflow's compressed data cannot be read: the .gcsv the project names (beside it) is, with the project's
    orientation overriding the log's and the project's offset."""
    t = sample_times()
    write_gcsv(tmp_path / "clip.gcsv", t, known_rate(t), orientation="YxZ")
    text = (tmp_path / "clip.gcsv").read_text().replace("orientation,YxZ", "orientation,XYZ")
    (tmp_path / "clip.gcsv").write_text(text)
    source = {"filepath": "file:///somewhere/else/clip.gcsv", "imu_orientation": "YxZ", "file_metadata": "Qk#z%a"}
    log = read_gyroflow_project(_project(tmp_path / "clip.gyroflow", source, {"13000000": 25.0}))
    np.testing.assert_allclose(log.samples[:, 0], t + 0.025, atol=1e-9)
    np.testing.assert_allclose(log.samples[:, 1:], known_rate(t), atol=1e-6)


def test_kind_is_told_by_content_not_name(tmp_path):
    t = sample_times(20)
    gcsv = write_gcsv(tmp_path / "log.txt", t, known_rate(t))
    csv = write_lowcam_csv(tmp_path / "log.gcsv.bak", t, known_rate(t))
    assert log_kind(gcsv) == "gcsv" and log_kind(csv) == "csv"
    np.testing.assert_allclose(read_gyro_log(gcsv).samples, read_gyro_log(csv).samples, atol=1e-6)
    camera_log = write_gcsv(tmp_path / "cam.log", t, known_rate(t), first="CAMERA IMU LOG")
    assert read_gyro_log(camera_log).kind == "gcsv"


# --- batch and motion ----------------------------------------------------------------------------------------------

def _small_profile(folder: Path, readout_s: float) -> Path:
    """The Fire-i at 160x120 with a rolling shutter of ``readout_s`` (s) beside its motion blur."""
    shutil.copytree(ROOT / "profiles" / "fire-i", folder / "fire-i", dirs_exist_ok=True)
    text = (ROOT / "profiles" / "fire-i.toml").read_text()
    text = text.replace("\nwidth = 640\n", "\nwidth = 160\n").replace("\nheight = 480\n", "\nheight = 120\n")
    anchor = '[[effect]]\ntype = "chromatic_aberration"'
    assert text.count(anchor) == 1
    text = text.replace(anchor, f'[[effect]]\ntype = "rolling_shutter"\nreadout_s = {readout_s}\n\n{anchor}')
    path = folder / f"small-rs{readout_s}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    from lowcam.outputs import write_exr
    from lowcam.profile import load_profile
    from lowcam.sample import sample_render

    folder = tmp_path_factory.mktemp("gyro-shot")
    profile = _small_profile(folder, 0.03)
    render = sample_render(load_profile(profile), 160)
    for f in (1, 2):
        write_exr(folder / "renders" / f"{f:04d}.exr", render)
    t = sample_times()
    write_gcsv(folder / "clip.gcsv", t, known_rate(t))
    write_lowcam_csv(folder / "known.csv", t, known_rate(t))
    return folder


def _batch(shot: Path, out: str, *extra, profile=None) -> list[bytes]:
    rc = main(["batch", "--profile", str(profile or shot / "small-rs0.03.toml"), "--renders",
               str(shot / "renders" / "####.exr"), "--frames", "1-2", "-o", str(shot / out / "####.png"), "--quiet",
               *extra])
    assert rc == 0
    return [(shot / out / f"{f:04d}.png").read_bytes() for f in (1, 2)]


def test_batch_with_a_gcsv_films_the_known_rotation(shot, capsys):
    """The .gcsv log gives batch the motion blur and rolling shutter of the known rotation: the same frames as
    Lowcam's CSV of that rotation; and the motion matters (without it, or without the rolling shutter, they
    differ)."""
    timing = ["--fps", "30", "--exposure-s", "0.02", "--gyro-t0", str(T_START)]
    from_gcsv = _batch(shot, "gcsv", "--gyro", str(shot / "clip.gcsv"), *timing)
    from_csv = _batch(shot, "csv", "--gyro", str(shot / "known.csv"), *timing)
    assert from_gcsv == from_csv
    still = _batch(shot, "still")
    assert all(a != b for a, b in zip(from_gcsv, still))
    no_rs = _batch(shot, "no-rs", "--gyro", str(shot / "clip.gcsv"), *timing, profile=_small_profile(shot, 0.0))
    assert all(a != b for a, b in zip(from_gcsv, no_rs))


def test_motion_command_writes_the_known_rotation(shot, capsys):
    """``lowcam motion --gyro`` (no Blender) writes each frame's mean rate over its exposure: the pan, and the
    roll at the exposure's middle (it is linear in time); equal within 1e-9 to the motion of Lowcam's CSV."""
    timing = ["--fps", "30", "--exposure-s", "0.02", "--gyro-t0", str(T_START), "--frames", "1-3"]
    assert main(["motion", "--gyro", str(shot / "clip.gcsv"), *timing, "-o", str(shot / "gcsv.json")]) == 0
    assert main(["motion", "--gyro", str(shot / "known.csv"), *timing, "-o", str(shot / "csv.json")]) == 0
    a, b = read_motion_json(shot / "gcsv.json"), read_motion_json(shot / "csv.json")
    assert sorted(a) == [1, 2, 3]
    for f in a:
        np.testing.assert_allclose(a[f].angular_velocity, b[f].angular_velocity, atol=1e-9, rtol=0)
        mid = T_START + (f - 1) / 30 + 0.01
        np.testing.assert_allclose(a[f].angular_velocity, known_rate([mid])[0], atol=1e-6)
        assert a[f].exposure_s == 0.02


def test_batch_takes_a_projects_fps_and_offset(shot, tmp_path):
    """A .gyroflow project's frame rate and offset: no --fps, no --gyro-t0."""
    shutil.copyfile(shot / "clip.gcsv", tmp_path / "clip.gcsv")
    # gyro time + 12.5 s... the offset (ms) puts the log's start at video time 0
    project = _project(tmp_path / "clip.gyroflow", {"filepath": "clip.gcsv"}, {"12500000": -12500.0}, fps=15.0,
                       fps_scale=2.0)   # a 30 fps clip conformed to 15 fps: Gyroflow times frames at 30
    assert main(["motion", "--gyro", str(project), "--exposure-s", "0.02", "--frames", "1-2", "-o",
                 str(tmp_path / "m.json")]) == 0
    m = read_motion_json(tmp_path / "m.json")
    assert json.loads((tmp_path / "m.json").read_text())["fps"] == 30.0
    np.testing.assert_allclose(m[2].angular_velocity, known_rate([T_START + 1 / 30 + 0.01])[0], atol=1e-6)


# --- hostile input -------------------------------------------------------------------------------------------------

def _good(tmp_path) -> str:
    t = sample_times(40)
    return write_gcsv(tmp_path / "good.gcsv", t, known_rate(t)).read_text()


def _with_cell(text: str, line: int, column: int, value: str) -> str:
    """``text`` with the cell ``column`` of line ``line`` (0-based) set to ``value``."""
    lines = text.splitlines()
    cells = lines[line].split(",")
    cells[column] = value
    lines[line] = ",".join(cells)
    return "\n".join(lines) + "\n"


HOSTILE = {
    "not-a-gcsv.gcsv": lambda good: "hello, world\n1,2,3\n",
    "missing-column.gcsv": lambda good: good.replace("t,gx,gy,gz,ax,ay,az", "t,gx,gy,ax,ay,az"),
    "nan.gcsv": lambda good: _with_cell(good, 14, 2, "nan"),
    "inf.gcsv": lambda good: _with_cell(good, 20, 0, "inf"),
    "word.gcsv": lambda good: _with_cell(good, 16, 3, "fast"),
    "bad-orientation.gcsv": lambda good: good.replace(f"orientation,{ORIENTATION}", "orientation,XXZ"),
    "letters-orientation.gcsv": lambda good: good.replace(f"orientation,{ORIENTATION}", "orientation,abc"),
    "no-samples.gcsv": lambda good: "\n".join(good.splitlines()[:11]) + "\n",
    "no-header.gcsv": lambda good: "\n".join(ln for ln in good.splitlines() if not ln.startswith("t,")) + "\n",
    "backwards.gcsv": lambda good: good.replace("\n12500000,", "\n99999999999,", 1),
    "zero-gscale.gcsv": lambda good: good.replace(f"gscale,{GSCALE!r}", "gscale,0"),
    "ragged.gcsv": lambda good: good.replace(",0,-2048,0\n", ",0\n", 1),
    "binary.gcsv": lambda good: bytes(range(256)) * 4,
    "not-json.gyroflow": lambda good: "{ this is not json",
    "no-gyro-source.gyroflow": lambda good: json.dumps({"title": "Gyroflow data file", "version": 3}),
    "compressed-no-log.gyroflow": lambda good: json.dumps({"gyro_source": {"filepath": "gone.gcsv",
                                                                          "file_metadata": "Qk#z%a"}}),
    "bad-offsets.gyroflow": lambda good: json.dumps({"gyro_source": {"raw_imu": [
        {"timestamp_ms": 0, "gyro": [0, 0, 0]}, {"timestamp_ms": 5, "gyro": [0, 0, 0]}]}, "offsets": {"abc": 1}}),
    "bad-project-orientation.gyroflow": lambda good: json.dumps({"gyro_source": {"imu_orientation": "XY", "raw_imu": [
        {"timestamp_ms": 0, "gyro": [0, 0, 0]}, {"timestamp_ms": 5, "gyro": [0, 0, 0]}]}}),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_log_is_one_line_naming_the_file(name, tmp_path, capfd):
    content = HOSTILE[name](_good(tmp_path))
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    out = tmp_path / "motion.json"
    capfd.readouterr()
    rc = main(["motion", "--gyro", str(path), "--fps", "30", "--exposure-s", "0.02", "--frames", "1", "-o", str(out)])
    err = capfd.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "Traceback" not in err, err
    assert not out.exists()


def test_nan_sample_names_its_line(tmp_path, capfd):
    (tmp_path / "nan.gcsv").write_text(_with_cell(_good(tmp_path), 14, 2, "nan"))
    rc = main(["motion", "--gyro", str(tmp_path / "nan.gcsv"), "--fps", "30", "--exposure-s", "0.02", "--frames",
               "1", "-o", str(tmp_path / "m.json")])
    err = capfd.readouterr().err
    assert rc == 2 and "line 15" in err and "'gy'" in err, err


def test_motion_needs_a_blend_or_a_gyro_log(tmp_path, capfd):
    rc = main(["motion", "--frames", "1", "-o", str(tmp_path / "m.json")])
    err = capfd.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "--gyro" in err, err


def test_a_hand_written_gcsv(tmp_path):
    """Written by hand, no helper: ``YxZ`` makes file x Gyroflow's -y (right), i.e. the camera's +x; ``gscale``
    0.01 and ``tscale`` 0.001 (ms); no orientation line: ``xzY``, file x to Gyroflow's -x (down), the camera's +y."""
    body = "tscale,0.001\ngscale,0.01\nt,gx,gy,gz\n1000,100,0,0\n1010,100,0,0\n"
    (tmp_path / "a.gcsv").write_text("GYROFLOW IMU LOG\nversion,1.3\norientation,YxZ\n" + body)
    log = read_gcsv(tmp_path / "a.gcsv")
    np.testing.assert_allclose(log.samples, [[1.0, 1.0, 0.0, 0.0], [1.01, 1.0, 0.0, 0.0]], atol=1e-12)
    (tmp_path / "b.gcsv").write_text("CAMERA IMU LOG\n" + body)
    np.testing.assert_allclose(read_gcsv(tmp_path / "b.gcsv").samples[:, 1:], [[0, 1, 0], [0, 1, 0]], atol=1e-12)
