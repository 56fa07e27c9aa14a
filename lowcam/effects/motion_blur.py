"""Motion blur from camera rotation during the exposure (Klein & Murray 2010, sec. 5.2 step 4).

Rotation only, as in the paper. Pixel p at time t sees the ray ``R(t) d_p`` of the mid-exposure camera,
``R(t) = exp([w]x t)`` for the body rate ``w`` (rad/s, camera frame: x right, y down, z forward); the taps are
these exact projections at the midpoints of equal slices of the exposure, on a 24x18-cell grid (the paper takes
16 straight taps along the local flow).

Contents
--------
- :func:`rotation_matrices`: rotations ``exp([w]x t)`` for a constant body rate at ``times``
- :func:`tap_offsets`: where pixel (u, v) looks in the mid-exposure image at each tap of the exposure
- :func:`shutter_s`: the exposure (s) the motion effects integrate over: the frame's, the effect's or the camera's
- :class:`MotionBlur`: ``taps``-tap motion blur along the flow the camera's rotation produces over the exposure

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import grid_points
from .base import Effect, NodeStage, Param, Search


def rotation_matrices(angular_velocity, times) -> np.ndarray:
    """Rotations ``exp([w]x t)`` for a constant body rate ``angular_velocity`` (rad/s, camera frame) at ``times``."""
    w = np.asarray(angular_velocity, np.float64)
    return np.stack([cv2.Rodrigues(w * t)[0] for t in np.asarray(times, np.float64)])


def tap_offsets(lens, u, v, angular_velocity, exposure_s: float, taps: int) -> np.ndarray:
    """Where pixel (u, v) looks in the mid-exposure image at each of ``taps`` instants of the exposure.

    Pixel p at time t sees the ray ``R(t) d_p`` of the mid-exposure camera, ``R(t) = exp([w]x t)``, so its
    value is the render's value at ``pi(R(t) d_p)``. Times are the midpoints of ``taps`` equal slices of
    ``[-T/2, T/2]``. Returns offsets of shape ``u.shape + (taps, 2)`` in output pixels; rays that turn behind
    the camera get a far-away offset (they sample transparency).
    """
    t = ((np.arange(taps) + 0.5) / taps - 0.5) * exposure_s
    rot = rotation_matrices(angular_velocity, t)
    x, y = lens.undistort(u, v)
    d = np.stack([x, y, np.ones_like(x)], -1)
    d2 = np.einsum("kij,...j->...ki", rot, d)
    z = d2[..., 2]
    ok = z > 1e-6
    z = np.where(ok, z, 1.0)
    u2, v2 = lens.distort(d2[..., 0] / z, d2[..., 1] / z)
    off = np.stack([u2 - u[..., None], v2 - v[..., None]], -1)
    off[~ok] = 1e6
    return off


def shutter_s(state) -> float:
    """The exposure (s) the motion effects integrate over: the frame's own, else the ``motion_blur`` effect's
    ``exposure_s``, else the camera's."""
    if state.exposure_s is not None:
        return state.exposure_s
    effect = state.profile.effect("motion_blur")
    return (effect.exposure_s if effect is not None else 0.0) or state.camera.exposure_s


class MotionBlur(Effect):
    """``taps``-tap motion blur along the flow that the camera's rotation produces over the exposure.

    Rotation only, as in the paper. The taps are exact projections of the rotated rays on a 24x18-cell grid
    (the paper uses straight taps along the local tangent) and are bilinearly interpolated per sensel; the
    Bayer-sampling stage averages the taps, so the blur costs a few small lookups instead of 16 full-image
    passes. The render is taken to show the middle of the exposure. ``exposure_s`` = 0 uses the camera's.
    """

    name = "motion_blur"
    section = "5.2 step 4"
    writes = "sampling"
    order = 50
    node = NodeStage("Motion Blur", "image", baked_into="bayer_sampling")
    searches = (Search("motion_blur", "moving captures are smeared as by a {exposure_s:.4f} s exposure",
                       bounds={"exposure_s": (0.0005, 0.1)}, captures="moving"),)
    params = {
        "taps": Param(16, int, low=2, high=256),
        "exposure_s": Param(0.0, low=0.0, high=10.0, unit="s", doc="0: the camera's exposure_s"),
        "grid": Param([24.0, 18.0], "vector", length=2, low=1, high=256, whole=True,
                       doc="cells (columns, rows)"),
    }

    def apply(self, state):
        w = np.asarray(state.angular_velocity, np.float64)
        exposure = shutter_s(state)
        if not np.any(w) or exposure <= 0:
            return
        u, v = grid_points(state.geometry.working_extent, tuple(int(c) for c in self.grid))
        off = tap_offsets(state.lens, u, v, w, exposure, self.taps)
        state.motion_taps = off.reshape(off.shape[:2] + (-1,)).astype(np.float32)
        gaps = np.linalg.norm(np.diff(off, axis=2), axis=-1).max(axis=2)
        state.motion_tap_spacing = np.minimum(gaps, 1e3).astype(np.float32)
