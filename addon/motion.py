"""Camera motion from a Blender scene: the angular velocity over each frame's shutter interval.

Contents
--------
- :func:`camera_motion`: per-frame motion of a camera (e.g. a solved one) from its ``matrix_world`` at sub-frames
"""
from __future__ import annotations

import math

import numpy as np

from lowcam.motion import FrameMotion, angular_velocity_between


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
