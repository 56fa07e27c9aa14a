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
writes it from a Blender scene's camera.

Gyro CSV: a header naming the columns ``t`` (s), ``wx``, ``wy``, ``wz`` (rad/s, camera frame) in any order,
commas or whitespace between values. Frame ``f`` is exposed from ``t0 + (f - first_frame) / fps`` for
``exposure_s``; its angular velocity is the time average of the gyro over that interval (trapezoidal rule on the
samples, linearly interpolated at the ends).

Contents
--------
- :class:`FrameMotion`: one frame's angular velocity (rad/s) and exposure (s)
- :func:`write_motion_json`: write ``{frame: FrameMotion}`` as motion.json (atomically)
- :func:`read_motion_json`: a motion.json as ``{frame: FrameMotion}``
- :func:`read_gyro_csv`: gyro samples as an (N, 4) array of ``t, wx, wy, wz``, sorted by time
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

from .errors import LowcamError


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
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise LowcamError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise LowcamError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != "lowcam-motion":
        raise LowcamError(f"{path}: not a lowcam motion file (expected \"format\": \"lowcam-motion\")")
    out = {}
    for i, entry in enumerate(doc.get("frames", [])):
        try:
            f = int(entry["frame"])
            w = tuple(float(v) for v in entry["angular_velocity"])
            e = entry.get("exposure_s")
            e = None if e is None else float(e)
        except (KeyError, TypeError, ValueError):
            raise LowcamError(f"{path}: frames[{i}] needs 'frame' and 'angular_velocity' [wx, wy, wz]") from None
        if len(w) != 3 or not np.all(np.isfinite(w)) or (e is not None and not 0 <= e <= 10):
            raise LowcamError(f"{path}: frames[{i}] (frame {f}) has a bad angular_velocity or exposure_s")
        out[f] = FrameMotion(w, e)
    return out


def read_gyro_csv(path) -> np.ndarray:
    """Samples as an (N, 4) array of ``t, wx, wy, wz``, sorted by time."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    except FileNotFoundError:
        raise LowcamError(f"{path}: no such file") from None
    split = (lambda s: s.split(",")) if "," in lines[0] else str.split
    header = [h.strip().lower() for h in split(lines[0])]
    if sorted(header) != ["t", "wx", "wy", "wz"]:
        raise LowcamError(f"{path}: the gyro CSV needs a header naming t, wx, wy, wz; got {lines[0]!r}")
    try:
        data = np.array([[float(v) for v in split(ln)] for ln in lines[1:]])
    except ValueError:
        raise LowcamError(f"{path}: the gyro CSV holds a value that is not a number") from None
    if data.ndim != 2 or data.shape[1] != 4 or len(data) < 2:
        raise LowcamError(f"{path}: the gyro CSV needs at least two rows of four values")
    data = data[:, [header.index(c) for c in ("t", "wx", "wy", "wz")]]
    return data[np.argsort(data[:, 0])]


def average_rate(samples: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Time average of the angular velocity over [t0, t1] from gyro samples (t, wx, wy, wz)."""
    t = samples[:, 0]
    if t0 < t[0] or t1 > t[-1]:
        raise ValueError(f"the exposure {t0:.4f}-{t1:.4f} s lies outside the gyro log ({t[0]:.4f}-{t[-1]:.4f} s)")
    inside = (t > t0) & (t < t1)
    ts = np.concatenate([[t0], t[inside], [t1]])
    ws = np.stack([np.interp(ts, t, samples[:, k]) for k in (1, 2, 3)], -1)
    return np.trapz(ws, ts, axis=0) / (t1 - t0)


def gyro_to_motion(samples: np.ndarray, frames, fps: float, exposure_s: float, t0: float = 0.0,
                   first_frame: int | None = None, source: str = "gyro") -> dict[int, FrameMotion]:
    """Per-frame motion from gyro samples: frame f starts at ``t0 + (f - first_frame) / fps``."""
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
