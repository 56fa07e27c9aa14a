"""Motion blur from camera rotation during the exposure (Klein & Murray 2010, sec. 5.2 step 4).

Rotation only, as in the paper. Pixel p at time t sees the ray ``R(t) d_p`` of the mid-exposure camera,
``R(t) = exp([w]x t)`` for the body rate ``w`` (rad/s, camera frame: x right, y down, z forward); the taps are
these exact projections at the midpoints of equal slices of the exposure, on a 24x18-cell grid (the paper takes
16 straight taps along the local flow).

Contents
--------
- :func:`rotation_matrices`: rotations ``exp([w]x t)`` for a constant body rate at ``times``
- :func:`ray_directions`: unit directions of the rays output pixels see through a lens (beyond 90 deg too)
- :func:`direction_pixels`: the output pixels where a lens puts directions
- :func:`tap_offsets`: where pixel (u, v) looks in the mid-exposure image at each tap of the exposure
- :func:`shutter_s`: the exposure (s) the motion effects integrate over: the frame's, the effect's or the camera's
- :func:`gyro_motion_from_plate`: angular velocity per frame from the footage's gyro log (its plate probe)
- :class:`MotionBlur`: ``taps``-tap motion blur along the flow the camera's rotation produces over the exposure

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from ..errors import LowcamError
from ..geometry import grid_points
from ..motion import average_rate
from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, NodeStage, Param, Search


def rotation_matrices(angular_velocity, times) -> np.ndarray:
    """Rotations ``exp([w]x t)`` for a constant body rate ``angular_velocity`` (rad/s, camera frame) at ``times``."""
    w = np.asarray(angular_velocity, np.float64)
    return np.stack([cv2.Rodrigues(w * t)[0] for t in np.asarray(times, np.float64)])


def ray_directions(lens, u, v) -> np.ndarray:
    """Unit directions (..., 3) (x right, y down, z forward) of the rays output pixels (u, v) see through
    ``lens`` (:meth:`~lowcam.effects.lens_models.LensModel.undistort_ray`: at 90 deg and beyond too)."""
    theta, phi = lens.undistort_ray(u, v)
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], -1)


def direction_pixels(lens, d) -> tuple[np.ndarray, np.ndarray]:
    """The output pixels (u, v) where ``lens`` puts directions ``d`` (..., 3)
    (:meth:`~lowcam.effects.lens_models.LensModel.distort_ray`)."""
    theta = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
    return lens.distort_ray(theta, np.arctan2(d[..., 1], d[..., 0]))


def tap_offsets(lens, u, v, angular_velocity, exposure_s: float, taps: int, wide: bool = False) -> np.ndarray:
    """Where pixel (u, v) looks in the mid-exposure image at each of ``taps`` instants of the exposure.

    Pixel p at time t sees the ray ``R(t) d_p`` of the mid-exposure camera, ``R(t) = exp([w]x t)``, so its
    value is the render's value at ``pi(R(t) d_p)``. Times are the midpoints of ``taps`` equal slices of
    ``[-T/2, T/2]``. Returns offsets of shape ``u.shape + (taps, 2)`` in output pixels; rays that turn behind
    the camera get a far-away offset (they sample transparency). ``wide`` (a lens rendered through a fisheye):
    the rays are unit directions (:func:`ray_directions`, :func:`direction_pixels`), at 90 deg and beyond too.
    """
    t = ((np.arange(taps) + 0.5) / taps - 0.5) * exposure_s
    rot = rotation_matrices(angular_velocity, t)
    if wide:
        u2, v2 = direction_pixels(lens, np.einsum("kij,...j->...ki", rot, ray_directions(lens, u, v)))
        return np.stack([u2 - u[..., None], v2 - v[..., None]], -1)
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


def gyro_motion_from_plate(footage, base=None, film=None) -> PlateEstimate:
    """The angular velocity per frame (rad/s) from the footage's gyro log (:func:`lowcam.motion.average_rate`
    over each frame's exposure), or a report that motion is left to the tracked camera. It sets no profile
    parameter: the motion is per frame (``lowcam batch`` takes it as a motion.json)."""
    if footage.gyro is None:
        return PlateEstimate("gyro_motion", "motion_blur", {}, {}, 0.0,
                             "no gyro: motion left to the tracked camera")
    samples = footage.gyro
    exposure = float(getattr(getattr(base, "camera", None), "exposure_s", 0.0) or 1.0 / footage.fps)
    frame_ids = _frame_numbers(footage)
    if footage.frame_times is not None:
        times = footage.frame_times
        starts = [times[f] if 0 <= f < len(times) else np.nan for f in frame_ids]
    else:
        starts = [samples[0, 0] + i / footage.fps for i in range(len(footage))]
    rates, missing = [], 0
    for t0 in starts:
        try:
            rates.append(average_rate(samples, t0, t0 + exposure) if np.isfinite(t0) else None)
        except LowcamError:
            rates.append(None)
        missing += rates[-1] is None
    found = [r for r in rates if r is not None]
    if not found:
        return PlateEstimate("gyro_motion", "motion_blur", {"frames_outside_log": missing}, {}, 0.0,
                             "the gyro log does not cover the footage's frames")
    w = np.array(found)
    speed = np.linalg.norm(w, axis=1)
    measured = {"angular_velocity_rad_s": [None if r is None else [float(v) for v in r] for r in rates],
                "median_speed_rad_s": float(np.median(speed)), "max_speed_rad_s": float(speed.max()),
                "exposure_s": exposure, "frames_outside_log": missing}
    return PlateEstimate("gyro_motion", "motion_blur", measured, {}, len(found) / len(rates),
                         f"gyro covers {len(found)} of {len(rates)} frames; per-frame motion, not a profile value")


def _frame_numbers(footage) -> list[int]:
    """Each frame's index into the frame stamps: the last number in its file name (``RE_frame-99.jpg`` -> 99),
    else its position."""
    out = []
    for i in range(len(footage)):
        name = Path(footage.names[i]).stem if i < len(footage.names) else ""
        digits = re.findall(r"\d+", name)
        out.append(int(digits[-1]) if digits else i)
    return out


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
    plate_probe = PlateProbe("gyro_motion", gyro_motion_from_plate, lambda frames: {}, order=60,
                             about="angular velocity per frame from a gyro log")
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
        wide = state.profile.effect("lens_distortion").projection(state.geometry) != "pinhole"
        off = tap_offsets(state.lens, u, v, w, exposure, self.taps, wide)
        state.motion_taps = off.reshape(off.shape[:2] + (-1,)).astype(np.float32)
        gaps = np.linalg.norm(np.diff(off, axis=2), axis=-1).max(axis=2)
        state.motion_tap_spacing = np.minimum(gaps, 1e3).astype(np.float32)
