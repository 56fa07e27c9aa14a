"""Real footage with a gyro log as the plate: the engine side of ``lowcam demo --footage``.

A phone clip (JPEG frames, frame stamps, a gyro log and per-frame exposures; the ``phone-gyro-video`` layout of
gyro-video-stabilization) drives the camera: each frame's angular velocity (rad/s, camera frame) is the gyro's
time average over the middle row's exposure (:func:`lowcam.motion.average_rate`), the camera's orientation per
frame is the integrated gyro (:func:`lowcam.motion.integrate_rotation`), motion blur integrates over the logged
exposure, and rolling shutter reads the rows out over ``readout_s``. The lens is the clip's pinhole K.

Contents
--------
- :data:`PHONE_K`, :data:`PHONE_READOUT_S`: the phone-gyro-video camera's intrinsics (800x600 px) and row read-out (s)
- :class:`FootageClip`: frames, frame start times (s), exposures (s), camera-frame gyro samples, K and read-out
- :func:`find_footage`: the data set's folder holding ``framestamp.txt`` (the set's root or that folder)
- :func:`read_footage_clip`: ``count`` frames of a phone-gyro-video folder from ``first`` on
- :func:`frame_motion`: a frame's mean angular velocity (rad/s) over its middle row's exposure, and the exposure (s)
- :func:`camera_rotations`: each frame's camera-to-world rotation (the first frame's camera = world)
- :func:`footage_profile`: a base profile set to the clip: frame size, pinhole lens from K, rolling-shutter read-out
- :func:`plate_profile`: :func:`footage_profile`, then ``lowcam calibrate plate``'s estimates from the clip's frames
- :func:`write_gif`: frames as an animated GIF (Pillow), atomically

References
----------
- Li Haipeng, gyro-video-stabilization (MIT): the phone-gyro-video data and its K and read-out time.
- R. Hartley and A. Zisserman, Multiple View Geometry, 2nd ed., 2004, sec. 8.4.2 (rotation homography K R K^-1).
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import LowcamError
from .io import read_plate
from .measure.plate import Footage, estimate_profile
from .motion import (PHONE_GYRO_TIME_OFFSET_S, PHONE_GYRO_TO_CAMERA, average_rate, integrate_rotation,
                     read_exposure_log, read_framestamps, read_phone_gyro_log)
from .outputs import atomic_write_bytes

#: Intrinsics of the phone-gyro-video camera for its 800x600 frames (px), from the data set's source.
PHONE_K = np.array([[573.8534, -0.6974, 406.0101], [0.0, 575.0448, 309.0112], [0.0, 0.0, 1.0]])
#: Its rolling-shutter read-out time, first row to last (s).
PHONE_READOUT_S = 0.033312


@dataclass
class FootageClip:
    """``frames``: JPEG paths; ``numbers``: their frame numbers (1-based lines of framestamp.txt); ``starts``: each
    frame's first-row time on the gyro clock (s, offset applied); ``exposures``: s; ``gyro``: (N, 4) ``t, wx, wy,
    wz`` in the camera frame (rad/s); ``K``: 3x3 intrinsics (px); ``readout_s``: first row to last (s)."""

    folder: Path
    frames: list[Path]
    numbers: list[int]
    starts: np.ndarray
    exposures: np.ndarray
    gyro: np.ndarray
    K: np.ndarray = field(default_factory=PHONE_K.copy)
    readout_s: float = PHONE_READOUT_S
    width: int = 800
    height: int = 600


def find_footage(path) -> Path:
    """The folder holding ``framestamp.txt``: ``path`` itself or its one sub-folder that has it."""
    path = Path(path)
    if not path.is_dir():
        raise LowcamError(f"{path}: no such footage folder (the phone-gyro-video data set)")
    if (path / "framestamp.txt").is_file():
        return path
    found = sorted(p.parent for p in path.glob("*/framestamp.txt"))
    if not found:
        raise LowcamError(f"{path}: no framestamp.txt in it or its sub-folders: not a phone-gyro-video folder")
    return found[0]


def read_footage_clip(path, first: int = 99, count: int = 24, axes=PHONE_GYRO_TO_CAMERA,
                      time_offset_s: float = PHONE_GYRO_TIME_OFFSET_S) -> FootageClip:
    """``count`` frames of a phone-gyro-video folder from frame ``first`` on (``reshape/RE_frame-N.jpg`` is frame
    N, line N of framestamp.txt), with its gyro mapped to the camera frame by ``axes``. A frame that is missing,
    damaged or not 800x600 is a one-line error naming it."""
    folder = find_footage(path)
    stamps = read_framestamps(folder / "framestamp.txt")
    exposure = read_exposure_log(folder / "gyro_dump.txt")
    gyro = read_phone_gyro_log(folder / "gyro.txt", axes)
    numbers = list(range(first, first + count))
    frames = [folder / "reshape" / f"RE_frame-{n}.jpg" for n in numbers]
    for n, f in zip(numbers, frames):
        if not f.is_file():
            raise LowcamError(f"{f}: no such frame (the clip asks for frames {first}-{first + count - 1})")
        if n > len(stamps) or n not in exposure:
            raise LowcamError(f"{folder}: frame {n} has no frame stamp or exposure")
    for f in frames:   # every frame decodes whole, at the clip's size, before any work
        read_plate(f, FootageClip.width, FootageClip.height)
    starts = np.array([stamps[n - 1] for n in numbers]) + time_offset_s
    return FootageClip(folder, frames, numbers, starts, np.array([exposure[n] for n in numbers]), gyro)


def _middle_time(clip: FootageClip, i: int) -> float:
    """Middle of frame i's middle-row exposure (s, gyro clock)."""
    return float(clip.starts[i] + 0.5 * clip.readout_s)


def frame_motion(clip: FootageClip, i: int) -> tuple[tuple[float, float, float], float]:
    """Frame i's mean angular velocity (rad/s, camera frame) over its middle row's exposure, and that exposure (s).
    Lowcam's motion blur integrates this rate over the exposure; its rolling shutter spreads it over the rows."""
    t = _middle_time(clip, i)
    e = float(clip.exposures[i])
    try:
        w = average_rate(clip.gyro, t - e / 2, t + e / 2)
    except LowcamError as err:
        raise LowcamError(f"{clip.folder}: frame {clip.numbers[i]}: {err}") from None
    return tuple(float(v) for v in w), e


def camera_rotations(clip: FootageClip) -> np.ndarray:
    """(n, 3, 3) camera-to-world rotations at each frame's middle row (Lowcam camera axes; frame 0 = identity)."""
    out = [np.eye(3)]
    for i in range(1, len(clip.frames)):
        out.append(out[-1] @ integrate_rotation(clip.gyro, _middle_time(clip, i - 1), _middle_time(clip, i)))
    return np.stack(out)


def footage_profile(base, clip: FootageClip):
    """``base`` (a profile) set to the clip's camera: frame size, a pinhole ``opencv`` lens from K (no distortion,
    the skew dropped: 0.7 px over 574), motion blur over the frame's exposure and rolling shutter over
    ``readout_s``; with a ``[provenance]`` entry for each."""
    p = base.copy()
    p.camera.width, p.camera.height = clip.width, clip.height
    p.camera.exposure_s = float(np.median(clip.exposures))
    p.__dict__.pop("geometry", None)
    K = clip.K
    p = p.with_effect("lens_distortion", replace=True, model="opencv", fx_px=float(K[0, 0]), fy_px=float(K[1, 1]),
                      cx_px=float(K[0, 2]), cy_px=float(K[1, 2]))
    p = p.with_effect("motion_blur", exposure_s=0.0)
    p = p.with_effect("rolling_shutter", readout_s=float(clip.readout_s))
    note = f"the footage {clip.folder} (its K, read-out and gyro log)"
    for key in ("camera", "lens_distortion", "rolling_shutter.readout_s", "motion_blur"):
        p.provenance[key] = note
    p.__dict__.pop("geometry", None)
    return p


def plate_profile(base, clip: FootageClip, frames: int | None = None):
    """(profile, estimates): :func:`footage_profile` of ``base``, then the confident estimates of
    :func:`lowcam.measure.plate.estimate_profile` from ``frames`` of the clip's frames, evenly spread (all: None)."""
    n = len(clip.frames) if frames is None else min(len(clip.frames), frames)
    pick = np.unique(np.linspace(0, len(clip.frames) - 1, n).round().astype(int))
    stack = np.stack([read_plate(clip.frames[i], clip.width, clip.height) for i in pick])
    return estimate_profile(Footage(stack, 30.0, str(clip.folder)), footage_profile(base, clip))


def write_gif(path, frames, fps: float = 10.0) -> Path:
    """``frames`` (uint8 RGB arrays) as a looping animated GIF (Pillow), written atomically."""
    from PIL import Image


    images = [Image.fromarray(np.ascontiguousarray(f)) for f in frames]
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:], duration=int(round(1000 / fps)),
                   loop=0)
    return atomic_write_bytes(path, buf.getvalue())
