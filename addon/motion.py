"""Camera motion from a Blender scene: the angular velocity over each frame's shutter interval.

Contents
--------
- :func:`camera_motion`: per-frame motion of a camera (e.g. a solved one) from its ``matrix_world`` at sub-frames
- :func:`write_camera_gyro_csv`: a camera's motion (a solved tracking camera's) as a gyro CSV, for ``calibrate plate``
"""
from __future__ import annotations

import math

import numpy as np

from lowcam.motion import FrameMotion, angular_velocity_between
from lowcam.outputs import atomic_write_bytes


def _rotation_at(scene, camera, time_frames: float) -> np.ndarray:
    whole = math.floor(time_frames)
    scene.frame_set(whole, subframe=time_frames - whole)
    m = np.array(camera.matrix_world.to_3x3().normalized())
    return m


def camera_motion(scene, camera, frames, shutter_frames: float | None = None) -> dict[int, FrameMotion]:
    """Per-frame motion of ``camera`` (e.g. a solved tracking camera) from ``matrix_world`` at sub-frames.

    The shutter interval is centred on each frame and lasts ``shutter_frames`` frames (default: the scene's
    motion-blur shutter), i.e. ``exposure_s = shutter_frames / fps``.
    """
    fps = scene.render.fps / scene.render.fps_base
    shutter = scene.render.motion_blur_shutter if shutter_frames is None else shutter_frames
    exposure = shutter / fps
    current = scene.frame_current, scene.frame_subframe
    out = {}
    try:
        for f in frames:
            ra = _rotation_at(scene, camera, f - shutter / 2)
            rb = _rotation_at(scene, camera, f + shutter / 2)
            out[int(f)] = FrameMotion(angular_velocity_between(ra, rb, exposure), exposure)
    finally:
        scene.frame_set(current[0], subframe=current[1])
    return out


def write_camera_gyro_csv(scene, camera, first_frame: int, frames: int, exposure_s: float, path,
                          steps_per_frame: int = 4):
    """Write ``camera``'s motion over ``frames`` frames from scene frame ``first_frame`` as a gyro CSV
    (:func:`lowcam.motion.read_gyro_csv`'s format: ``t,wx,wy,wz``, s and rad/s in Lowcam's camera frame), so a
    camera solved from the clip's tracking stands in for a gyro log.

    The log's clock starts (``t = 0``) at the first frame's exposure start, ``exposure_s`` centred on the frame as
    the render's shutter is; the rate at each sample time ``t`` is the body rate between the rotations half a step
    before and after it (:func:`lowcam.motion.angular_velocity_between`), ``steps_per_frame`` samples a frame and
    one frame beyond the last."""
    fps = scene.render.fps / scene.render.fps_base
    dt = 1.0 / (fps * steps_per_frame)
    start = first_frame - exposure_s * fps / 2          # scene frame at t = 0
    count = (frames + 1) * steps_per_frame + 1
    current = scene.frame_current, scene.frame_subframe
    try:
        rotations = [_rotation_at(scene, camera, start + (k - 0.5) * dt * fps) for k in range(count + 1)]
    finally:
        scene.frame_set(current[0], subframe=current[1])
    rows = [(k * dt, *angular_velocity_between(a, b, dt)) for k, (a, b) in enumerate(zip(rotations, rotations[1:]))]
    text = "t,wx,wy,wz\n" + "".join(",".join(f"{v:.9g}" for v in row) + "\n" for row in rows)
    return atomic_write_bytes(path, text.encode())
