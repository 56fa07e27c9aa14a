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
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import schema
from .errors import LowcamError

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
    from .io import atomic_write_bytes

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


def average_rate(samples: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Time average of the angular velocity over [t0, t1] from gyro samples (t, wx, wy, wz)."""
    t = samples[:, 0]
    if t0 < t[0] or t1 > t[-1]:
        raise ValueError(f"the exposure {t0:.4f}-{t1:.4f} s lies outside the gyro log ({t[0]:.4f}-{t[-1]:.4f} s)")
    inside = (t > t0) & (t < t1)
    ts = np.concatenate([[t0], t[inside], [t1]])
    ws = np.stack([np.interp(ts, t, samples[:, k]) for k in (1, 2, 3)], -1)
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
        except ValueError as e:
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
    import cv2

    rel = axes @ (np.asarray(rot_a).T @ np.asarray(rot_b)) @ axes.T
    rotvec = cv2.Rodrigues(rel)[0].ravel()
    return tuple(float(v) for v in rotvec / dt)
