"""Per-frame camera motion for shots: the ``motion.json`` format and gyro CSV integration.

``motion.json``::

    {
      "format": "lowcam-motion", "version": 1,
      "fps": 24.0,
      "frames": [
        {"frame": 1, "angular_velocity": [0.0, 0.8, 0.0], "exposure_s": 0.02},
        ...
      ]
    }

``angular_velocity`` is in rad/s in the camera frame (x right, y down, z forward), averaged over that frame's
exposure; ``exposure_s`` is the exposure time in seconds (optional; the profile's when absent). ``lowcam motion``
writes it from a Blender scene's camera. Each frame is listed once; every value must be finite.

Gyro CSV: a header naming the columns ``t`` (s), ``wx``, ``wy``, ``wz`` (rad/s, camera frame) in any order,
commas or whitespace between values, times strictly increasing. Frame ``f`` is exposed from
``t0 + (f - first_frame) / fps`` for ``exposure_s``; its angular velocity is the time average of the gyro over
that interval (trapezoidal rule on the samples, linearly interpolated at the ends).

Phone gyro logs (the ``phone-gyro-video`` set of gyro-video-stabilization, Li Haipeng): ``gyro.txt`` rows
``wx, wy, wz, t`` (rad/s, s), ``framestamp.txt`` (the time each frame's first row starts, s; line n is frame n,
1-based) and ``gyro_dump.txt`` (per-frame exposure). The gyro's axes are the phone's, not the camera's:
:data:`PHONE_GYRO_TO_CAMERA` maps them (``w_camera = M @ w_gyro``). Checked against the frames (tests/
test_footage_demo.py): over the 102 frame pairs, the image motion the integrated gyro predicts through K agrees
with OpenCV's Lucas-Kanade tracks with correlations 0.91 (horizontal shift), 0.995 (vertical) and 0.81 (roll), a
median track error of 1.34 px against 3.04 px with no rotation; the source code's unsigned mapping (gyro x to
camera y, y to x, z to z) gives -0.91, -0.995, -0.81 and 5.3 px. Of the 48 signed axis permutations, this one fits
best (the same with z flipped: 1.43 px; its roll correlation is -0.81).

Contents
--------
- :data:`MOTION_KEYS`, :data:`FRAME_KEYS`: the keys of a motion.json and of each of its frames
- :data:`MAX_RATE`, :data:`MAX_FRAME`: the largest angular velocity (rad/s) and frame number read
- :class:`FrameMotion`: one frame's angular velocity (rad/s) and exposure (s)
- :func:`write_motion_json`: write ``{frame: FrameMotion}`` as motion.json (atomically)
- :func:`read_motion_json`: a motion.json as ``{frame: FrameMotion}``
- :func:`read_gyro_csv`: gyro samples as an (N, 4) array of ``t, wx, wy, wz``, times strictly increasing
- :func:`average_rate`: time average of the angular velocity over [t0, t1] from gyro samples
- :func:`gyro_to_motion`: per-frame motion from gyro samples: frame f starts at ``t0 + (f - first_frame) / fps``
- :data:`BLENDER_TO_CAMERA`: Blender's camera axes (x right, y up, looking down -z) to Lowcam's
- :func:`angular_velocity_between`: mean body rate (rad/s, camera frame) between two camera-to-world rotations
- :data:`PHONE_GYRO_TO_CAMERA`: the phone gyro log's axes to Lowcam's camera axes (checked against the frames)
- :data:`PHONE_GYRO_TIME_OFFSET_S`: the gyro clock's offset from the frame stamps, fitted to the frames (s)
- :func:`read_phone_gyro_log`: a phone gyro log of rows ``wx wy wz t`` as ``t, wx, wy, wz`` in the camera frame
- :func:`read_framestamps`: frame start times (s), one per line
- :func:`read_exposure_log`: per-frame exposure times (s) from a phone's raw log (``SOF ... frameNum :N exp time E``)
- :func:`integrate_rotation`: the rotation (camera frame at ``t0``) the gyro integrates to over [t0, t1]
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from . import schema
from .errors import LowcamError
from .outputs import atomic_write_bytes

# numpy 2.0 renamed trapz to trapezoid and 2.4 removed trapz (Blender 5.1+ and Debian's 4.3 run numpy 2.x)
_trapezoid = getattr(np, "trapezoid", None) or np.trapz

#: The keys of a motion.json, and of each of its frames.
MOTION_KEYS = {"format", "version", "fps", "frames"}
FRAME_KEYS = {"frame", "angular_velocity", "exposure_s"}
#: Largest angular velocity read (rad/s; gyros saturate near 35) and frame number (Blender's limit).
MAX_RATE = 1000.0
MAX_FRAME = 1048574


@dataclass(frozen=True)
class FrameMotion:
    angular_velocity: tuple[float, float, float]
    exposure_s: float | None = None


def write_motion_json(path, motion: dict[int, FrameMotion], fps: float | None = None) -> Path:
    """Write ``{frame: FrameMotion}`` as motion.json (atomically)."""
    frames = []
    for f in sorted(motion):
        m = motion[f]
        entry = {"frame": int(f), "angular_velocity": [float(v) for v in m.angular_velocity]}
        if m.exposure_s is not None:
            entry["exposure_s"] = float(m.exposure_s)
        frames.append(entry)
    doc = {"format": "lowcam-motion", "version": 1, "frames": frames}
    if fps:
        doc["fps"] = float(fps)
    atomic_write_bytes(path, (json.dumps(doc, indent=1) + "\n").encode())
    return Path(path)


def read_motion_json(path) -> dict[int, FrameMotion]:
    """A motion.json as ``{frame: FrameMotion}``; every value is checked (a bad one names the file and the key)."""
    path = Path(path)
    doc = schema.read_json(path, "motion file")
    if not isinstance(doc, dict) or doc.get("format") != "lowcam-motion":
        raise LowcamError(f"{path}: not a lowcam motion file (expected \"format\": \"lowcam-motion\")")
    schema.table(doc, str(path), known=MOTION_KEYS, required=("frames",))
    schema.integer(doc.get("version", 1), str(path), "version", 1, 1)
    if "fps" in doc:
        schema.number(doc["fps"], str(path), "fps", 1e-3, 1e4, "frames/s")
    out, where_listed = {}, {}
    for i, entry in enumerate(schema.array_of(doc["frames"], str(path), "frames")):
        where = f"{path}: frames[{i}]"
        schema.table(entry, where, known=FRAME_KEYS, required=("frame", "angular_velocity"))
        f = schema.integer(entry["frame"], where, "frame", -MAX_FRAME, MAX_FRAME)
        if f in where_listed:
            raise LowcamError(f"{where}: frame {f} is listed twice (also frames[{where_listed[f]}])")
        w = schema.numbers(entry["angular_velocity"], where, "angular_velocity", 3, -MAX_RATE, MAX_RATE, "rad/s")
        e = entry.get("exposure_s")
        e = None if e is None else schema.number(e, where, "exposure_s", 0.0, 10.0, "s")
        out[f], where_listed[f] = FrameMotion(tuple(w), e), i
    return out


def read_gyro_csv(path) -> np.ndarray:
    """Samples as an (N, 4) array of ``t, wx, wy, wz``: at least two, finite, times strictly increasing."""
    path = Path(path)
    data, lines = schema.read_number_csv(path, ("t", "wx", "wy", "wz"), "gyro CSV", min_rows=2,
                                         low={"wx": -MAX_RATE, "wy": -MAX_RATE, "wz": -MAX_RATE},
                                         high={"wx": MAX_RATE, "wy": MAX_RATE, "wz": MAX_RATE})
    back = np.flatnonzero(np.diff(data[:, 0]) <= 0)
    if len(back):
        k = back[0] + 1
        raise LowcamError(f"{path}: line {lines[k]}: 't' = {data[k, 0]:g} s does not follow the previous sample's "
                          f"{data[k - 1, 0]:g} s (times must increase)")
    return data


def _rates_within(samples: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """Times (t0, the samples inside, t1) and the angular velocities linearly interpolated at them; an interval
    outside the log is a :class:`LowcamError`."""
    t = samples[:, 0]
    if t0 < t[0] or t1 > t[-1]:
        raise LowcamError(f"the interval {t0:.4f}-{t1:.4f} s lies outside the gyro log ({t[0]:.4f}-{t[-1]:.4f} s)")
    ts = np.concatenate([[t0], t[(t > t0) & (t < t1)], [t1]])
    return ts, np.stack([np.interp(ts, t, samples[:, k]) for k in (1, 2, 3)], -1)


def average_rate(samples: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Time average of the angular velocity over [t0, t1] from gyro samples (t, wx, wy, wz)."""
    ts, ws = _rates_within(samples, t0, t1)
    return _trapezoid(ws, ts, axis=0) / (t1 - t0)


def gyro_to_motion(samples: np.ndarray, frames, fps: float, exposure_s: float, t0: float = 0.0,
                   first_frame: int | None = None, source: str = "gyro") -> dict[int, FrameMotion]:
    """Per-frame motion from gyro samples: frame f starts at ``t0 + (f - first_frame) / fps``."""
    fps = schema.number(fps, source, "fps", 1e-3, 1e4, "frames/s")
    exposure_s = schema.number(exposure_s, source, "exposure_s", 1e-6, 10.0, "s")
    t0 = schema.number(t0, source, "t0", unit="s")
    frames = list(frames)
    first = frames[0] if first_frame is None else first_frame
    out = {}
    for f in frames:
        start = t0 + (f - first) / fps
        try:
            w = average_rate(samples, start, start + exposure_s)
        except LowcamError as e:
            raise LowcamError(f"{source}: frame {f}: {e}") from None
        out[f] = FrameMotion(tuple(float(v) for v in w), exposure_s)
    return out


#: Blender's camera axes (x right, y up, looking down -z) to Lowcam's (x right, y down, z forward).
BLENDER_TO_CAMERA = np.diag([1.0, -1.0, -1.0])


def angular_velocity_between(rot_a: np.ndarray, rot_b: np.ndarray, dt: float,
                             axes: np.ndarray = BLENDER_TO_CAMERA) -> tuple[float, float, float]:
    """Mean body rate (rad/s, Lowcam camera frame) of a camera whose camera-to-world rotation goes from ``rot_a``
    to ``rot_b`` in ``dt`` seconds. ``axes`` maps the rotations' camera axes to Lowcam's (Blender's by default).

    The relative rotation ``rot_a^T rot_b`` is expressed in the camera frame at the start; its axis-angle vector
    over ``dt`` is the constant body rate that produces it.
    """
    rel = axes @ (np.asarray(rot_a).T @ np.asarray(rot_b)) @ axes.T
    rotvec = cv2.Rodrigues(rel)[0].ravel()
    return tuple(float(v) for v in rotvec / dt)


#: The phone gyro log's axes to Lowcam's camera axes (x right, y down, z forward): ``w_camera = M @ w_gyro``, i.e.
#: camera x = -gyro y, camera y = -gyro x, camera z = -gyro z (a proper rotation, det +1). Chosen among all 48 signed
#: permutations by the image motion of the phone-gyro-video frames (see the module docstring).
PHONE_GYRO_TO_CAMERA = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Row v of a frame is exposed around ``framestamp + PHONE_GYRO_TIME_OFFSET_S + (v / H) readout_s`` on the gyro's
#: clock: fitted to the same frames (1 ms steps; the gyro samples every 2.4 ms).
PHONE_GYRO_TIME_OFFSET_S = -0.003


def _read_rows(path, what: str, columns: int) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise LowcamError(f"{path}: no such {what}")
    try:
        text = path.read_text().replace(",", " ")
        data = np.array([[float(x) for x in line.split()] for line in text.splitlines() if line.strip()])
    except (ValueError, UnicodeDecodeError, OSError) as e:
        raise LowcamError(f"{path}: not a {what} ({str(e).splitlines()[0]})") from None
    if data.ndim != 2 or data.shape[1] != columns or len(data) < 2:
        raise LowcamError(f"{path}: a {what} needs at least 2 rows of {columns} numbers")
    if not np.all(np.isfinite(data)):
        raise LowcamError(f"{path}: line {int(np.flatnonzero(~np.isfinite(data).all(1))[0]) + 1}: not finite")
    return data


def read_phone_gyro_log(path, axes: np.ndarray = PHONE_GYRO_TO_CAMERA) -> np.ndarray:
    """A phone gyro log of rows ``wx, wy, wz, t`` (rad/s in the phone's axes, s; commas or spaces) as an (N, 4)
    array ``t, wx, wy, wz`` with the rates in Lowcam's camera frame (``axes @ w``); times strictly increasing."""
    data = _read_rows(path, "gyro log of rows 'wx wy wz t'", 4)
    if np.abs(data[:, :3]).max() > MAX_RATE:
        raise LowcamError(f"{path}: a rate beyond {MAX_RATE:g} rad/s: not a gyro log of rows 'wx wy wz t'")
    back = np.flatnonzero(np.diff(data[:, 3]) <= 0)
    if len(back):
        raise LowcamError(f"{path}: line {back[0] + 2}: time {data[back[0] + 1, 3]:.6f} s does not follow the "
                          f"previous row's (times must increase)")
    return np.column_stack([data[:, 3], data[:, :3] @ np.asarray(axes, np.float64).T])


def read_framestamps(path) -> np.ndarray:
    """Frame start times (s), one per line (line n is frame n, 1-based), strictly increasing."""
    t = _read_rows(path, "frame-stamp file (one time in s per line)", 1)[:, 0]
    if np.any(np.diff(t) <= 0):
        raise LowcamError(f"{path}: line {int(np.flatnonzero(np.diff(t) <= 0)[0]) + 2}: times must increase")
    return t


def read_exposure_log(path) -> dict[int, float]:
    """Per-frame exposure times (s) from a phone's raw log: ``{frame: exposure_s}`` from its lines
    ``SOF <stamp>, frameNum :N exp time E`` (frames 1-based, as in ``framestamp.txt``)."""
    path = Path(path)
    if not path.is_file():
        raise LowcamError(f"{path}: no such exposure log")
    pattern = re.compile(r"frameNum\s*:\s*(\d+)\s+exp time\s+([0-9.eE+-]+)")
    out = {}
    for m in pattern.finditer(path.read_text(errors="replace")):
        e = float(m.group(2))
        if not 0 < e < 10:
            raise LowcamError(f"{path}: frame {m.group(1)}: exposure {e:g} s is not in (0, 10) s")
        out[int(m.group(1))] = e
    if not out:
        raise LowcamError(f"{path}: no 'frameNum :N exp time E' lines: not a phone exposure log")
    return out


def integrate_rotation(samples: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """The rotation ``R`` (3x3) the body rate integrates to over [t0, t1]: the camera-to-world rotation at ``t1``
    expressed in the camera frame at ``t0`` (``R = prod exp([w_k]x dt_k)``, midpoint rule on the linearly
    interpolated samples). A direction ``d`` seen at ``t0`` is seen at ``R.T @ d`` at ``t1``, so a static point
    moves in the image by the homography ``K R^T K^-1`` (Hartley & Zisserman 2004, sec. 8.4.2)."""
    ts, ws = _rates_within(samples, t0, t1)
    rot = np.eye(3)
    for k in range(len(ts) - 1):
        rot = rot @ cv2.Rodrigues(0.5 * (ws[k] + ws[k + 1]) * (ts[k + 1] - ts[k]))[0]
    return rot
