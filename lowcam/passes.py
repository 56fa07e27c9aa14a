"""Render passes beyond the colour: image velocity and depth, for object motion blur and defocus from depth.

Both are render-sized arrays in the render's pixel grid (top row first), like the render itself:

``velocity_px_s``
    (H, W, 2) float32: how fast the surface seen at each pixel moves across the image at mid-exposure, in render
    pixels per second, x right and y down. It holds everything that moves: the camera's rotation and
    translation and the objects' own motion (:class:`lowcam.effects.ObjectMotion` takes the rotation out).
``depth_m``
    (H, W) float32: distance of the seen surface from the camera along its viewing axis (m); ``inf`` or very
    large where nothing was rendered.

Blender writes them as the Vector and Depth passes (:func:`from_blender`).

Contents
--------
- :data:`PASS_FIELDS`: each kind of pass ("velocity", "depth") -> its :class:`RenderPasses` field
- :data:`BLENDER_PASS`: each kind of pass -> the Blender pass that holds it
- :class:`RenderPasses`: a render's image velocity (px/s) and depth (m), validated
- :func:`check_passes`: validate passes against a render of ``render_shape``; returns them as float32
- :func:`from_blender`: passes from Blender's Vector and Depth passes, at ``fps`` and ``metres_per_unit``
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import LowcamError


#: Each kind of pass: its :class:`RenderPasses` field and the Blender pass that holds it.
PASS_FIELDS = {"velocity": "velocity_px_s", "depth": "depth_m"}
BLENDER_PASS = {"velocity": "Vector", "depth": "Depth"}


@dataclass(frozen=True)
class RenderPasses:
    velocity_px_s: np.ndarray | None = None
    depth_m: np.ndarray | None = None

    def get(self, kind: str, effect) -> np.ndarray:
        """The pass of ``kind`` ("velocity", "depth") that ``effect`` needs; a clear error when it is missing."""
        value = getattr(self, PASS_FIELDS[kind])
        if value is None:
            raise effect.error(f"needs a {kind} pass (Blender's {BLENDER_PASS[kind]} pass: turn it on, or run the "
                               "add-on's Set Up Scene); or disable the effect")
        return value


def check_passes(passes: RenderPasses | None, render_shape, name: str = "render") -> RenderPasses | None:
    """Validate ``passes`` against a render of ``render_shape`` (rows, cols, ...); returns them as float32."""
    if passes is None:
        return None
    rows, cols = render_shape[:2]
    velocity, depth = passes.velocity_px_s, passes.depth_m
    if velocity is not None:
        velocity = np.ascontiguousarray(velocity, np.float32)
        if velocity.shape != (rows, cols, 2):
            raise LowcamError(f"{name}: the velocity pass must be ({rows}, {cols}, 2) like the render, "
                              f"got {velocity.shape}")
        if not np.isfinite(velocity).all():
            raise LowcamError(f"{name}: the velocity pass has NaN or Inf pixels")
    if depth is not None:
        depth = np.ascontiguousarray(depth, np.float32)
        if depth.shape != (rows, cols):
            raise LowcamError(f"{name}: the depth pass must be ({rows}, {cols}) like the render, got {depth.shape}")
        if np.isnan(depth).any() or (depth <= 0).any():
            raise LowcamError(f"{name}: the depth pass has NaN, zero or negative pixels")
    return RenderPasses(velocity, depth)


def from_blender(vector: np.ndarray | None, depth: np.ndarray | None, fps: float,
                 metres_per_unit: float = 1.0) -> RenderPasses:
    """Passes from Blender's Vector pass (H, W, 4) and Depth pass (H, W, scene units of ``metres_per_unit``) at
    ``fps`` frames per second.

    Cycles stores ``(previous - current, current - next)`` positions in raster pixels (y up), so the forward
    velocity is ``-(X + Z) / 2`` and ``(Y + W) / 2`` pixels per frame in image axes (checked with a moving plane
    in ``tests/test_blender.py``).
    """
    velocity = None
    if vector is not None:
        vector = np.asarray(vector, np.float32)
        velocity = np.stack([-(vector[..., 0] + vector[..., 2]), vector[..., 1] + vector[..., 3]], -1) * (fps / 2)
    if depth is not None:
        depth = np.asarray(depth, np.float32) * np.float32(metres_per_unit)
    return RenderPasses(velocity, depth)
