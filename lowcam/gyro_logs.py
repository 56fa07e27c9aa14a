"""Gyroflow's gyro logs as camera motion: ``.gcsv`` logs, ``.gyroflow`` projects and the gyro a camera records
inside its own video file, read into the gyro samples (``t, wx, wy, wz``: s, rad/s in Lowcam's camera frame) that
:func:`lowcam.motion.gyro_to_motion` turns into each frame's angular velocity, for ``lowcam batch --gyro`` and
``lowcam motion --gyro``.

Gyroflow (https://gyroflow.xyz) stabilises video with a gyro log; the same log drives Lowcam's motion blur and
rolling shutter (both take the frame's angular velocity).

GCSV (Gyroflow's text log, ``docs.gyroflow.xyz``, "GCSV format"; read as telemetry-parser's
``src/gyroflow/gcsv.rs`` reads it): a first line ``GYROFLOW IMU LOG`` or ``CAMERA IMU LOG``; ``key,value`` lines
(``version``, ``id``, ``orientation``, ``tscale``, ``gscale``, ``ascale``, ``frame_readout_time``, ...); a column
header ``t,gx,gy,gz[,ax,ay,az[,mx,my,mz]]`` (``time`` for ``t``); then one sample a line. ``t * tscale`` is the
time in s (``tscale`` 0.001 when absent), ``g * gscale`` the rate in rad/s (``gscale`` 1 when absent). Columns
after ``gz`` are not used.

Axes. ``orientation`` (``xzY`` when absent, telemetry-parser's default) says where the file's axes go: letter i
names the file axis that becomes Gyroflow's axis i, upper case as it is, lower case negated (Gyroflow's
``IMUTransforms::orient``: ``YxZ`` gives ``(y, -x, z)``). Gyroflow's own IMU frame is x up, y left, z backward
(out of the lens toward the operator), right-handed: so its docs ("the z vector pointed backwards, the x vector
pointed upwards, and the y vector pointed to the left") and its code (its integrator turns ``g`` into
``(-g_y, g_x, g_z)`` and its frame transform conjugates the result by ``diag(1, -1, -1)`` before the OpenCV camera
matrix) agree. Lowcam's camera frame is x right, y down, z forward, so :data:`GYROFLOW_TO_CAMERA` takes
``w_camera = (-g_y, -g_x, -g_z)``, a proper rotation (the same matrix as
:data:`lowcam.motion.PHONE_GYRO_TO_CAMERA`, found from the phone clip's frames).

Time. A ``.gcsv`` log's time is the video's as it stands (``--gyro-t0`` shifts it). A ``.gyroflow`` project's
``offsets`` (``{"gyro time in us": offset in ms}``, Gyroflow's synchronisation) map gyro time to video time as
Gyroflow does: ``t_video = t_gyro + offset(t_gyro)``, the offset interpolated linearly between the synced points
and extended along the first and last segments (one point: a constant). Video time 0 is the first row of the
video's first frame (Gyroflow stamps frame k at ``k / fps``); with ``--gyro-t0 0`` and ``--gyro-first-frame 1``,
shot frame 1 is the video's first frame. Where the offset drifts, the rates are divided by ``d t_video / d
t_gyro``, so that a frame turns by what the gyro turned between its start and end on the gyro's clock, as
Gyroflow's orientation at a video time is the gyro's at the mapped time.

A clip's own gyro. Action cameras, many drones and some phones record their gyro inside the video file (GoPro's
GPMF track, Sony's, Insta360's, DJI's, ...). Gyroflow reads them with its own library, telemetry-parser
(``Parser(path).normalized_imu()``: ``timestamp_ms`` and ``gyro`` in deg/s, turned by the orientation the file
states, or the one telemetry-parser knows for that camera, into Gyroflow's IMU axes); Lowcam takes those samples
as a ``.gcsv`` log's, through the same :data:`GYROFLOW_TO_CAMERA`. GoPro's documented axes (gpmf-parser's README,
"IMU Orientation"): X toward the camera's left, Y backward (out of the screen), Z up; its cameras write ``ORIO``
``ZXY``, which is Gyroflow's x up, y left, z backward. Time: telemetry-parser's, the first sample at video time 0
(a GoPro's samples spread evenly over its metadata track); a delay between the gyro and the picture is what
Gyroflow's synchronisation finds (``--gyro-t0``, or give its ``.gyroflow`` project). The frame rate is the clip's
first video stream's average rate as FFmpeg reads it (PyAV), when ``--fps`` is not given.

``.gyroflow`` project (JSON, ``"title": "Gyroflow data file"``): ``gyro_source`` gives the samples, either
embedded (``raw_imu``, a list of ``{"timestamp_ms", "gyro": [x, y, z] deg/s}``, or ``file_metadata.raw_imu``)
or from the ``.gcsv`` log ``filepath`` names (absolute, relative to the project, or of that name beside it); its
``imu_orientation`` (else the log's), ``gyro_bias`` (deg/s, added in the file's axes before orienting) and
``rotation`` (``[pitch, roll, yaw]`` deg, applied after orienting as Gyroflow's ``set_imu_rotation`` does) are
applied; ``video_info.fps`` (times its ``fps_scale``, when set) is the frame rate when ``--fps`` is not given. Gyroflow's compressed data (a string)
cannot be read: the log it came from, beside the project, can. Gyroflow's smoothing filters (``lpf``, ``mf``) are
stabilisation choices, not motion, and are not applied.

Contents
--------
- :data:`GYROFLOW_TO_CAMERA`: Gyroflow's IMU axes (x up, y left, z backward) to Lowcam's camera axes
- :data:`DEFAULT_ORIENTATION`: the orientation of a ``.gcsv`` log that names none (``xzY``)
- :class:`GyroLog`: samples ``t, wx, wy, wz`` (s on the video's clock, rad/s in the camera frame), fps, read-out
- :func:`orientation_matrix`: an orientation string as the 3x3 matrix taking the file's axes to Gyroflow's
- :func:`imu_rotation`: Gyroflow's ``rotation`` ``[pitch, roll, yaw]`` (deg) as a 3x3 matrix
- :func:`offset_ms`: Gyroflow's synced offset (ms) at gyro times (ms), as Gyroflow interpolates it
- :func:`offset_slope`: the slope of that offset (ms per ms) at gyro times (ms)
- :func:`log_kind`: ``"gcsv"``, ``"gyroflow"``, ``"clip"`` (binary) or ``"csv"``, from a file's first bytes
- :func:`read_gcsv`: a ``.gcsv`` log as a :class:`GyroLog`
- :func:`read_gyroflow_project`: a ``.gyroflow`` project's gyro data, axes and offsets as a :class:`GyroLog`
- :func:`clip_frame_rate`: a video clip's frame rate as FFmpeg reads it (PyAV), or why it cannot
- :func:`cut_short`: where an MP4/MOV file ends inside one of its boxes (a clip cut short), or None
- :func:`read_clip_gyro`: the gyro a camera recorded inside its video file (telemetry-parser) as a :class:`GyroLog`
- :func:`read_gyro_log`: any of the four (a ``.gcsv``, a ``.gyroflow``, a clip, Lowcam's CSV), told by content
- :func:`gyro_log_motion`: per-frame motion from a gyro log file, and the frame rate used (``batch``/``motion --gyro``)

References
----------
- [Gyroflow] A. Eddy, E. Chen et al., Gyroflow (``src/core/gyro_source/imu_transforms.rs``,
  ``src/core/imu_integration/mod.rs``, ``src/core/stabilization/frame_transform.rs``, ``src/core/lib.rs``),
  https://github.com/gyroflow/gyroflow; telemetry-parser (``src/gyroflow/gcsv.rs``),
  https://github.com/AdrianEddy/telemetry-parser; the GCSV format, https://docs.gyroflow.xyz.
- [GPMF] GoPro, GPMF introduction and "IMU Orientation Uses These Axis Labels" (``README.md``,
  ``GPMF_common.h``: ``ORIN``, ``ORIO``), https://github.com/gopro/gpmf-parser.
"""
from __future__ import annotations

import csv
import math
import os
import stat
import sys
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np

from . import schema
from .errors import LowcamError
from .motion import MAX_RATE, FrameMotion, gyro_to_motion, read_gyro_csv

#: Gyroflow's IMU axes (x up, y left, z backward) to Lowcam's camera axes (x right, y down, z forward):
#: ``w_camera = M @ w_gyroflow``, i.e. camera x = -y, camera y = -x, camera z = -z (det +1).
GYROFLOW_TO_CAMERA = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: The orientation of a ``.gcsv`` log that names none (telemetry-parser's default).
DEFAULT_ORIENTATION = "xzY"
_HEADERS = ("GYROFLOW IMU LOG", "CAMERA IMU LOG")
#: Largest |offset| (ms) and gyro time (s) read from a project.
_MAX_OFFSET_MS = 1e7
_MAX_TIME_S = 1e9


@dataclass(frozen=True)
class GyroLog:
    """A gyro log read: ``samples`` (N, 4) ``t, wx, wy, wz`` (s on the video's clock, rad/s in Lowcam's camera
    frame, times strictly increasing); ``fps`` (the project's frame rate, None when the file gives none);
    ``readout_s`` (the rolling shutter read-out the file states, s, None when none); ``orientation`` (the
    string applied, "" for Lowcam's CSV and for a clip, whose orientation telemetry-parser applies); ``kind``
    (``"gcsv"``, ``"gyroflow"``, ``"clip"`` or ``"csv"``)."""

    samples: np.ndarray
    fps: float | None = None
    readout_s: float | None = None
    orientation: str = ""
    kind: str = "csv"


def orientation_matrix(text, where: str, key: str = "orientation") -> np.ndarray:
    """The orientation string ``text`` (three letters, each of x, y, z once; upper case as is, lower case negated)
    as the 3x3 matrix ``M`` with ``w_gyroflow = M @ w_file`` (Gyroflow's ``orient``: letter i picks the file axis
    that becomes axis i)."""
    if not isinstance(text, str) or len(text) != 3 or sorted(text.lower()) != ["x", "y", "z"]:
        raise LowcamError(f"{where}: '{key}' must be three letters naming x, y and z once each (upper case "
                          f"as is, lower case negated, e.g. YxZ), got {schema.shown(text)}")
    m = np.zeros((3, 3))
    for i, letter in enumerate(text):
        m[i, "xyz".index(letter.lower())] = 1.0 if letter.isupper() else -1.0
    return m


def imu_rotation(pitch_deg: float, roll_deg: float, yaw_deg: float) -> np.ndarray:
    """Gyroflow's ``rotation`` ``[pitch, roll, yaw]`` (deg) as the matrix it applies after orienting: nalgebra's
    ``Rotation3::from_euler_angles(yaw, pitch, roll)``, i.e. ``Rz(roll) Ry(pitch) Rx(yaw)``."""
    def axis(k, deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        i, j = [a for a in range(3) if a != k]
        r = np.eye(3)
        r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
        if k == 1:  # Ry: [[c, 0, s], [0, 1, 0], [-s, 0, c]]
            r[i, j], r[j, i] = s, -s
        return r

    return axis(2, roll_deg) @ axis(1, pitch_deg) @ axis(0, yaw_deg)


def offset_ms(offsets: dict[int, float], t_ms: np.ndarray) -> np.ndarray:
    """Gyroflow's synced offset (ms) at gyro times ``t_ms`` (ms): ``offsets`` maps gyro time (us) to the offset
    (ms); linear between points, along the end segments beyond them, constant for one point, 0 for none."""
    t_ms = np.asarray(t_ms, np.float64)
    if not offsets:
        return np.zeros_like(t_ms)
    keys = np.array(sorted(offsets), np.float64) / 1000.0
    values = np.array([offsets[k] for k in sorted(offsets)], np.float64)
    if len(keys) == 1:
        return np.full_like(t_ms, values[0])
    k = np.clip(np.searchsorted(keys, t_ms, side="right") - 1, 0, len(keys) - 2)
    return values[k] + (values[k + 1] - values[k]) * (t_ms - keys[k]) / (keys[k + 1] - keys[k])


def offset_slope(offsets: dict[int, float], t_ms: np.ndarray) -> np.ndarray:
    """The slope of :func:`offset_ms` (ms of offset per ms of gyro time) at gyro times ``t_ms`` (ms)."""
    t_ms = np.asarray(t_ms, np.float64)
    if len(offsets) < 2:
        return np.zeros_like(t_ms)
    keys = np.array(sorted(offsets), np.float64) / 1000.0
    values = np.array([offsets[k] for k in sorted(offsets)], np.float64)
    k = np.clip(np.searchsorted(keys, t_ms, side="right") - 1, 0, len(keys) - 2)
    return (values[k + 1] - values[k]) / (keys[k + 1] - keys[k])


def log_kind(path) -> str:
    """``"gcsv"`` (first line ``GYROFLOW IMU LOG`` or ``CAMERA IMU LOG``), ``"gyroflow"`` (a JSON object),
    ``"clip"`` (binary: a NUL byte in the first 256, as every MP4/MOV box header has) or ``"csv"`` (anything else,
    Lowcam's CSV), from the file's first bytes; a pipe or device is ``"csv"``."""
    path = Path(path)
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return "csv"
        with open(path, "rb") as f:
            head = f.read(256)
    except (OSError, ValueError):
        return "csv"  # the CSV reader says what is wrong with it
    if b"\0" in head:
        return "clip"
    text = head.decode("utf-8", "replace").lstrip("\ufeff")
    if any(text.startswith(h) for h in _HEADERS):
        return "gcsv"
    return "gyroflow" if text.lstrip().startswith("{") else "csv"


def _scale(header: dict, key: str, default: float, where: str) -> float:
    if key not in header:
        return default
    try:
        x = float(header[key][0])
    except ValueError:
        x = math.nan
    if not (math.isfinite(x) and 0 < x < 1e9):
        raise LowcamError(f"{where}: line {header[key][1]}: '{key}' must be a positive number, "
                          f"got {schema.shown(header[key][0])}")
    return x


def _check_times(t: np.ndarray, where: str, lines=None) -> None:
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        k = back[0] + 1
        at = f"line {lines[k]}: " if lines is not None else f"sample {k}: "
        raise LowcamError(f"{where}: {at}time {t[k]:.6f} s does not follow the previous sample's {t[k - 1]:.6f} s "
                          f"(times must increase)")


def _gcsv_rows(path: Path, text: str):
    """A GCSV's header keys ``{key: (value, line)}``, its column names, and its rows ``[(line, cells)]``."""
    lines = text.splitlines()
    if not lines or lines[0].strip() not in _HEADERS:
        raise LowcamError(f"{path}: not a Gyroflow .gcsv log (its first line must be 'GYROFLOW IMU LOG' or "
                          f"'CAMERA IMU LOG')")
    header, columns, rows = {}, None, []
    for n, cells in enumerate(csv.reader(lines[1:]), 2):
        cells = [c.strip() for c in cells]
        if not any(cells):
            continue
        if columns is None:
            if cells[0].lower() in ("t", "time"):
                columns = [c.lower() for c in cells]
            elif len(cells) >= 2:   # key,value (a note may hold commas); a line of one word is passed over
                header[cells[0]] = (",".join(cells[1:]), n)
            continue
        rows.append((n, cells))
    if columns is None:
        raise LowcamError(f"{path}: no column header 't,gx,gy,gz' (a .gcsv log lists its samples under one)")
    missing = [c for c in ("gx", "gy", "gz") if c not in columns]
    if missing:
        raise LowcamError(f"{path}: the column header {schema.shown(','.join(columns))} has no '{missing[0]}' "
                          f"(a .gcsv log needs t,gx,gy,gz)")
    return header, columns, rows


def _gcsv_samples(path: Path):
    """A GCSV's samples in its own axes: times (s), rates (N, 3) rad/s, its ``orientation`` (None when it names
    none) with where it stands, and its read-out (s, None when none)."""
    header, columns, rows = _gcsv_rows(path, schema.read_text(path, "gyro log"))
    tscale, gscale = _scale(header, "tscale", 0.001, str(path)), _scale(header, "gscale", 1.0, str(path))
    if len(rows) < 2:
        raise LowcamError(f"{path}: the gyro log has {len(rows)} sample(s), at least 2 needed")
    take = [0] + [columns.index(c) for c in ("gx", "gy", "gz")]
    data = np.empty((len(rows), 4))
    for r, (n, cells) in enumerate(rows):
        if len(cells) != len(columns):
            raise LowcamError(f"{path}: line {n}: {len(cells)} values, the column header names {len(columns)}")
        for c, k in enumerate(take):
            try:
                x = float(cells[k])
            except ValueError:
                x = math.nan
            if not math.isfinite(x):
                raise LowcamError(f"{path}: line {n}: '{columns[k]}' must be a finite number, "
                                  f"got {schema.shown(cells[k])}")
            data[r, c] = x
    t = data[:, 0] * tscale
    _check_times(t, str(path), [n for n, _ in rows])
    rates = data[:, 1:] * gscale
    big = np.flatnonzero(np.abs(rates).max(1) > MAX_RATE)
    if len(big):
        raise LowcamError(f"{path}: line {rows[big[0]][0]}: a rate of {np.abs(rates[big[0]]).max():g} rad/s "
                          f"(gscale {gscale:g}) is beyond {MAX_RATE:g} rad/s")
    orientation, where = None, str(path)
    if "orientation" in header:
        orientation, where = header["orientation"][0], f"{path}: line {header['orientation'][1]}"
        orientation_matrix(orientation, where)
    return t, rates, orientation, _readout(header, path)


def read_gcsv(path, orientation: str | None = None) -> GyroLog:
    """A ``.gcsv`` log as a :class:`GyroLog`: times ``t * tscale`` (s), rates ``gscale * g`` (rad/s) oriented by
    the file's ``orientation`` (:data:`DEFAULT_ORIENTATION` when it names none; ``orientation``, when given,
    overrides it, as a project's does) and taken to Lowcam's camera frame. Every value is checked: a bad one is
    one line naming the file and the line."""
    path = Path(path)
    t, rates, own, readout = _gcsv_samples(path)
    orientation = orientation or own or DEFAULT_ORIENTATION
    to_camera = GYROFLOW_TO_CAMERA @ orientation_matrix(orientation, str(path))
    return GyroLog(np.column_stack([t, rates @ to_camera.T]), None, readout, orientation, "gcsv")


def _readout(header: dict, path: Path) -> float | None:
    """The GCSV's ``frame_readout_time`` (ms) in s; None when absent or not a number."""
    try:
        ms = float(header["frame_readout_time"][0])
    except (KeyError, ValueError):
        return None
    return abs(ms) / 1000.0 if math.isfinite(ms) and abs(ms) < 1e4 else None


def _embedded_imu(source: dict, where: str):
    """The project's embedded samples as (N, 4) ``t (ms), gx, gy, gz (deg/s)``, or None when none are embedded
    (a compressed string is refused unless the log file is at hand, see the caller)."""
    raw = source.get("raw_imu")
    if raw is None and isinstance(source.get("file_metadata"), dict):
        raw = source["file_metadata"].get("raw_imu")
        where = f"{where}: 'file_metadata'"
    if raw is None or isinstance(raw, str) or raw == []:
        return None
    entries = schema.array_of(raw, where, "raw_imu")
    out = []
    for i, e in enumerate(entries):
        at = f"{where}: raw_imu[{i}]"
        schema.table(e, at, required=("timestamp_ms",))
        if e.get("gyro") is None:
            continue
        t = schema.number(e["timestamp_ms"], at, "timestamp_ms", -_MAX_TIME_S * 1e3, _MAX_TIME_S * 1e3, "ms")
        g = schema.numbers(e["gyro"], at, "gyro", 3, -MAX_RATE * 180 / math.pi, MAX_RATE * 180 / math.pi, "deg/s")
        out.append([t, *g])
    if len(out) < 2:
        raise LowcamError(f"{where}: 'raw_imu' holds {len(out)} gyro sample(s), at least 2 needed")
    return np.array(out, np.float64)


def _linked_log(source: dict, path: Path) -> Path | None:
    """The log file the project's ``filepath`` names (a path or a ``file://`` URL, relative to the project's
    folder; else the file of that name beside the project), when it exists."""
    name = source.get("filepath")
    if not isinstance(name, str) or not name.strip():
        return None
    if name.startswith("file://"):
        name = unquote(urlparse(name).path)
    elif "://" in name:
        return None
    candidates = [Path(name) if Path(name).is_absolute() else path.parent / name, path.parent / Path(name).name]
    return next((p for p in candidates if p.is_file()), None)


def _offsets(doc: dict, where: str) -> dict[int, float]:
    raw = doc.get("offsets", {})
    schema.table(raw, where, "offsets")
    out = {}
    for key, value in raw.items():
        try:
            us = int(key)
        except ValueError:
            raise LowcamError(f"{where}: 'offsets' key {schema.shown(key)} must be a gyro time in us (a whole "
                              f"number)") from None
        if abs(us) > _MAX_TIME_S * 1e6:
            raise LowcamError(f"{where}: 'offsets' key {key} is out of range (|t| <= {_MAX_TIME_S:g} s)")
        out[us] = schema.number(value, where, f"offsets[{key}]", -_MAX_OFFSET_MS, _MAX_OFFSET_MS, "ms")
    return out


def read_gyroflow_project(path) -> GyroLog:
    """A ``.gyroflow`` project's gyro data as a :class:`GyroLog`: the embedded samples (or those of the ``.gcsv``
    its ``filepath`` names), oriented by its ``imu_orientation``, with its ``gyro_bias`` and ``rotation``, on the
    video's clock through its ``offsets``; ``fps`` from ``video_info``."""
    path = Path(path)
    doc = schema.read_json(path, "Gyroflow project")
    where = str(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("gyro_source"), dict):
        raise LowcamError(f"{path}: not a Gyroflow project (a JSON object with a 'gyro_source' table)")
    source = doc["gyro_source"]
    at = f"{where}: 'gyro_source'"
    orientation = source.get("imu_orientation")
    if orientation is not None:
        orientation_matrix(orientation, at, "imu_orientation")
    bias = source.get("gyro_bias")
    bias = np.zeros(3) if bias is None else np.array(schema.numbers(bias, at, "gyro_bias", 3, -1e4, 1e4, "deg/s"))
    rotation = source.get("rotation")
    turn = np.eye(3) if rotation is None else imu_rotation(*schema.numbers(rotation, at, "rotation", 3, -360, 360,
                                                                             "deg"))
    offsets = _offsets(doc, where)
    fps, info = None, doc.get("video_info")
    if isinstance(info, dict) and info.get("fps") is not None:   # Gyroflow's frame k is at k / (fps * fps_scale)
        fps = schema.number(info["fps"], f"{where}: 'video_info'", "fps", 1e-3, 1e4, "frames/s")
        if info.get("fps_scale") is not None:
            fps *= schema.number(info["fps_scale"], f"{where}: 'video_info'", "fps_scale", 1e-3, 1e3)
    readout = None
    if isinstance(doc.get("stabilization"), dict) and doc["stabilization"].get("frame_readout_time") is not None:
        ms = schema.number(doc["stabilization"]["frame_readout_time"], f"{where}: 'stabilization'",
                           "frame_readout_time", -1e4, 1e4, "ms")
        readout = abs(ms) / 1000.0 or None

    imu = _embedded_imu(source, at)
    if imu is not None:   # Gyroflow's raw IMU: ms, deg/s in the file's axes
        orientation = orientation or "XYZ"
        t_ms, file_rates = imu[:, 0], np.radians(imu[:, 1:] + bias)
        _check_times(t_ms / 1000.0, f"{at}: raw_imu")
    else:
        log = _linked_log(source, path)
        if log is None:
            packed = isinstance(source.get("raw_imu"), str) or isinstance(source.get("file_metadata"), str)
            raise LowcamError(f"{at}: the gyro data is {'compressed (Gyroflow encoding)' if packed else 'absent'} "
                              f"and the log its 'filepath' names ({schema.shown(source.get('filepath'))}) is not "
                              f"at hand: keep the .gcsv beside the project, or give the .gcsv itself")
        if log_kind(log) != "gcsv":
            raise LowcamError(f"{at}: 'filepath' names {log}, which is not a .gcsv log (Lowcam reads the gyro "
                              f"data of a project from its .gcsv log or from the project itself)")
        t_s, file_rates, own, own_readout = _gcsv_samples(log)
        orientation = orientation or own or DEFAULT_ORIENTATION
        t_ms, file_rates = t_s * 1000.0, file_rates + np.radians(bias)
        readout = readout or own_readout
    rates = file_rates @ (GYROFLOW_TO_CAMERA @ turn @ orientation_matrix(orientation, at)).T
    t_video = (t_ms + offset_ms(offsets, t_ms)) / 1000.0
    _check_times(t_video, f"{where}: 'offsets' (gyro time + offset)")
    rates = rates / (1.0 + offset_slope(offsets, t_ms))[:, None]   # rad per second of video time
    return GyroLog(np.column_stack([t_video, rates]), fps, readout, orientation, "gyroflow")


def _first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:200]


def clip_frame_rate(path) -> tuple[float | None, str | None]:
    """``(fps, None)``: the average frame rate (frames/s) of the clip's first video stream as FFmpeg reads it
    (PyAV's ``average_rate``, else its ``guessed_rate``; None when it states neither); or ``(None, why)`` when
    FFmpeg cannot open the file as a video, or reads a still image (``why``: one line)."""
    try:
        import av
    except ImportError:
        return None, "PyAV (av) is not installed"
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None, "no video stream"
            if container.format.name.endswith("_pipe") or container.format.name == "image2":
                return None, f"a still image ({container.format.name})"
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate
    except Exception as e:   # FFmpeg's errors (av.FFmpegError), OSError, ValueError: one line for the caller
        return None, getattr(e, "strerror", None) or _first_line(e)
    fps = float(rate) if rate else None
    return (fps if fps and math.isfinite(fps) and 1e-3 <= fps <= 1e4 else None), None


#: Top-level box types an MP4/MOV file (ISO base media file format, ISO/IEC 14496-12 sec. 4.2) starts with.
_MP4_FIRST_BOXES = {b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"pnot", b"uuid"}


def cut_short(path) -> str | None:
    """Where an MP4/MOV file ends inside one of its top-level boxes (``"its 'mdat' box ends at byte B, the file at
    byte N"``), None when its boxes fit or it is no MP4/MOV. A box is a 32-bit big-endian size (1: a 64-bit size
    follows the type; 0: to the end of the file) and a four-character type (ISO/IEC 14496-12 sec. 4.2)."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(8)
        if len(head) < 8 or head[4:8] not in _MP4_FIRST_BOXES:
            return None
        at = 0
        while at + 8 <= size:
            f.seek(at)
            header = f.read(16)
            length, kind = int.from_bytes(header[:4], "big"), header[4:8]
            if length == 1 and len(header) == 16:
                length = int.from_bytes(header[8:16], "big")
            elif length == 0:
                return None
            if length < 8:
                return f"a box of {length} bytes at byte {at}"
            if at + length > size:
                return f"its '{kind.decode('latin-1')}' box ends at byte {at + length}, the file at byte {size}"
            at += length
    return None


def read_clip_gyro(path) -> GyroLog:
    """The gyro a camera recorded inside its video file (GoPro GPMF, Sony, Insta360, DJI and the other formats
    telemetry-parser reads) as a :class:`GyroLog` of kind ``"clip"``: telemetry-parser's ``normalized_imu()``
    (ms; deg/s in Gyroflow's IMU axes, the file's orientation applied) taken to s and rad/s in Lowcam's camera
    frame by :data:`GYROFLOW_TO_CAMERA`; ``fps`` the clip's (:func:`clip_frame_rate`). A file with no gyro, one
    that is cut short or no video at all is one line naming the file."""
    path = Path(path)
    short = cut_short(path)
    if short:
        raise LowcamError(f"{path}: the clip is cut short ({short}): copy it whole from the camera")
    fps, not_video = clip_frame_rate(path)
    try:
        import telemetry_parser
    except ImportError:
        raise LowcamError(f"{path}: reading a clip's own gyro needs telemetry-parser, which this Python "
                          f"{sys.version_info[0]}.{sys.version_info[1]} lacks (it is built for Python 3.8 to 3.12): "
                          f"export the gyro from Gyroflow as a .gcsv log instead") from None
    imu, why = None, ""
    try:
        imu = telemetry_parser.Parser(str(path)).normalized_imu()
    except BaseException as e:   # its Rust side raises OSError, ValueError ("No metadata") or a PanicException
        if isinstance(e, (KeyboardInterrupt, SystemExit, MemoryError)):
            raise
        why = _first_line(e)
    gyro = [s for s in imu or () if isinstance(s, dict) and s.get("gyro") is not None]
    if len(gyro) < 2:
        if not_video is None:
            raise LowcamError(f"{path}: the clip holds no gyro data that telemetry-parser reads (GoPro GPMF, Sony, "
                              f"Insta360, DJI, ...{f'; it says: {why}' if why else ''}): give a gyro log instead "
                              f"(.gcsv, .gyroflow or a CSV)")
        raise LowcamError(f"{path}: not a video clip ({not_video}), and telemetry-parser finds no gyro in it"
                          f"{f' ({why})' if why else ''}: give the camera's clip or a gyro log")
    try:
        data = np.array([[s["timestamp_ms"], *s["gyro"]] for s in gyro], np.float64)
    except (TypeError, ValueError, KeyError):
        raise LowcamError(f"{path}: telemetry-parser's gyro samples are not numbers (t, gx, gy, gz)") from None
    if data.ndim != 2 or data.shape[1] != 4:
        raise LowcamError(f"{path}: telemetry-parser's gyro samples are not three axes each")
    bad = np.flatnonzero(~np.isfinite(data).all(1))
    if len(bad):
        raise LowcamError(f"{path}: the clip's gyro sample {bad[0]} is not finite")
    t = data[:, 0] / 1000.0
    _check_times(t, f"{path}: the clip's gyro")
    rates = np.radians(data[:, 1:])
    big = np.flatnonzero(np.abs(rates).max(1) > MAX_RATE)
    if len(big):
        raise LowcamError(f"{path}: the clip's gyro sample {big[0]} reads {np.abs(rates[big[0]]).max():g} rad/s, "
                          f"beyond {MAX_RATE:g} rad/s")
    return GyroLog(np.column_stack([t, rates @ GYROFLOW_TO_CAMERA.T]), fps, None, "", "clip")


def read_gyro_log(path) -> GyroLog:
    """A gyro log of any kind Lowcam reads, told by its content (not its name): a Gyroflow ``.gcsv`` log, a
    ``.gyroflow`` project, a video clip with its own gyro (a binary file: :func:`read_clip_gyro`) or Lowcam's
    CSV (``t, wx, wy, wz``). A file named ``.gcsv``, ``.gyroflow`` or ``.csv`` that is not one is refused as
    such."""
    path = Path(path)
    kind = log_kind(path)
    suffix = path.suffix.lower()
    if kind == "gcsv":
        return read_gcsv(path)
    if kind == "gyroflow":
        return read_gyroflow_project(path)
    if suffix == ".gcsv":
        schema.read_text(path, "gyro log")  # a missing, unreadable or binary file says so first
        raise LowcamError(f"{path}: not a Gyroflow .gcsv log (its first line must be 'GYROFLOW IMU LOG' or "
                          f"'CAMERA IMU LOG')")
    if suffix == ".gyroflow":
        return read_gyroflow_project(path)
    if kind == "clip" and suffix != ".csv":
        return read_clip_gyro(path)
    return GyroLog(read_gyro_csv(path))


def gyro_log_motion(path, frames, fps: float | None, exposure_s: float, t0: float = 0.0,
                    first_frame: int | None = None) -> tuple[dict[int, FrameMotion], float]:
    """Per-frame motion from the gyro log ``path`` (:func:`read_gyro_log`), and the frame rate used: frame f is
    exposed from ``t0 + (f - first_frame) / fps`` (video clock) for ``exposure_s``; ``fps`` None takes the
    project's or the clip's."""
    log = read_gyro_log(path)
    fps = fps or log.fps
    if not fps:
        raise LowcamError(f"{path}: give the frame rate (--fps): the gyro {'file' if log.kind == 'clip' else 'log'} "
                          f"states none")
    return gyro_to_motion(log.samples, frames, fps, exposure_s, t0, first_frame, source=str(path)), fps
