"""Motion blur from everything the camera's rotation does not explain: moving objects, the camera's translation.

This goes beyond the paper, which blurs camera rotation only (its Fig. 15 lists this as a drawback).

The renderer's velocity pass (:class:`lowcam.passes.RenderPasses`) gives each pixel's image velocity. The part a
static scene would have under the camera's angular velocity, :func:`rotation_velocity` (a pinhole render) or
:func:`fisheye_rotation_velocity` (an equidistant fisheye render), is left to
:class:`~lowcam.effects.MotionBlur`; what remains is spread over the exposure here, in the render's pixel grid
before the lens. The two blurs are applied one after the other, so a moving object seen by a turning camera gets
the convolution of both streaks: its extent is right, its profile a trapezoid instead of a box.

Contents
--------
- :func:`rotation_velocity`: (rows, cols, 2) image velocity (px/s) of a static scene under a turning pinhole camera
- :func:`fisheye_rotation_velocity`: the same under a turning equidistant fisheye (Cycles' panoramic camera)
- :func:`splat_along`: spread each pixel of a premultiplied RGBA image evenly along its path over the exposure
- :func:`edge_velocity_from_cover`: partly covered pixels take the velocity of their most covered neighbour
- :class:`ObjectMotion`: blur along each pixel's velocity minus the camera rotation's (needs a velocity pass)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import numpy as np

from .base import Effect, Param
from .motion_blur import shutter_s


def rotation_velocity(angular_velocity, focal_px: float, shape) -> np.ndarray:
    """(rows, cols, 2) image velocity (px/s, x right, y down) of a static scene seen by a pinhole camera of
    ``focal_px`` (centred, ``shape`` = (rows, cols)) turning at ``angular_velocity`` (rad/s, camera frame).

    A static direction ``d`` is seen at ``R(-t) d`` (:func:`~lowcam.effects.motion_blur.tap_offsets`), so
    ``d' = -w x d`` and, for ``d = (x, y, 1)``, ``x' = d'_x - x d'_z``, ``y' = d'_y - y d'_z``.
    """
    wx, wy, wz = (float(c) for c in angular_velocity)
    rows, cols = shape
    x = ((np.arange(cols) - cols / 2 + 0.5) / focal_px)[None, :]
    y = ((np.arange(rows) - rows / 2 + 0.5) / focal_px)[:, None]
    dx, dy, dz = -(wy - wz * y), -(wz * x - wx), -(wx * y - wy * x)
    return (focal_px * np.stack(np.broadcast_arrays(dx - x * dz, dy - y * dz), -1)).astype(np.float32)


def fisheye_rotation_velocity(angular_velocity, field_rad: float, shape) -> np.ndarray:
    """(rows, cols, 2) image velocity (px/s, x right, y down) of a static scene seen by an equidistant fisheye
    render (Cycles': ``field_rad`` across its width and its height, ``shape`` = (rows, cols)) turning at
    ``angular_velocity`` (rad/s, camera frame).

    The pixel at ``rho`` of the half-width and half-height from the centre sees the ray ``theta = rho field / 2``;
    its direction ``d`` moves at ``d' = -w x d`` (as in :func:`rotation_velocity`), which turns the ray by
    ``theta' = s' cos theta - sin theta d'_z`` (``s`` the direction's distance from the axis) and about the axis
    by ``phi' = (d'_y cos phi - d'_x sin phi) / sin theta``.
    """
    wx, wy, wz = (float(c) for c in angular_velocity)
    rows, cols = shape
    a, b = np.broadcast_arrays(((np.arange(cols) + 0.5) * 2 / cols - 1)[None, :],
                               ((np.arange(rows) + 0.5) * 2 / rows - 1)[:, None])
    rho = np.hypot(a, b)
    cos_phi = np.where(rho > 0, a / np.maximum(rho, 1e-300), 1.0)
    sin_phi = np.where(rho > 0, b / np.maximum(rho, 1e-300), 0.0)
    theta = rho * field_rad / 2
    s, z = np.sin(theta), np.cos(theta)
    x, y = s * cos_phi, s * sin_phi
    dx, dy, dz = -(wy * z - wz * y), -(wz * x - wx * z), -(wx * y - wy * x)
    theta_rate = (cos_phi * dx + sin_phi * dy) * z - s * dz
    turn = np.where(s > 1e-12, theta / np.maximum(s, 1e-300), 1.0) * (cos_phi * dy - sin_phi * dx)  # theta phi'
    scale = 2 / field_rad
    return np.stack([cols / 2 * scale * (theta_rate * cos_phi - turn * sin_phi),
                     rows / 2 * scale * (theta_rate * sin_phi + turn * cos_phi)], -1).astype(np.float32)


def splat_along(image: np.ndarray, shift_px: np.ndarray, min_shift_px: float = 0.5) -> np.ndarray:
    """Spread each pixel of premultiplied RGBA ``image`` evenly along the segment ``[-shift/2, +shift/2]``
    around it (``shift_px`` (H, W, 2): the pixel's path over the exposure, px).

    Pixels that move less than ``min_shift_px`` stay as they are; the moving ones are scattered with bilinear
    weights at taps at most 1 px apart and laid over the still ones (premultiplied "over").
    """
    length = np.hypot(shift_px[..., 0], shift_px[..., 1])
    moving = (length >= min_shift_px) & (np.abs(image) > 0).any(axis=-1)
    if not moving.any():
        return image
    rows, cols = image.shape[:2]
    ys, xs = np.nonzero(moving)
    longest = float(length[moving].max())
    reach = int(np.ceil(longest / 2)) + 2               # a canvas the paths stay inside, cropped to the image later
    y0, x0 = ys.min() - reach, xs.min() - reach
    h, w = ys.max() + reach + 1 - y0, xs.max() + reach + 1 - x0
    values = image[ys, xs].astype(np.float64).T         # (channels, moving pixels)
    shift = shift_px[ys, xs].astype(np.float64)
    taps = max(2, int(np.ceil(longest)) + 1)
    acc = np.zeros((image.shape[2], h * w), np.float64)
    chunk = max(1, 1_000_000 // len(xs))                # taps per bincount: about a million entries
    for first in range(0, taps, chunk):
        t = ((np.arange(first, min(first + chunk, taps)) + 0.5) / taps - 0.5)[:, None]
        x = (xs - x0) + shift[:, 0] * t                  # (taps in chunk, moving pixels)
        y = (ys - y0) + shift[:, 1] * t
        xi, yi = np.floor(x), np.floor(y)
        fx, fy = x - xi, y - yi
        index = (yi * w + xi).astype(np.int64)
        for offset, weight in ((0, (1 - fx) * (1 - fy)), (1, fx * (1 - fy)), (w, (1 - fx) * fy), (w + 1, fx * fy)):
            flat = (index + offset).ravel()
            for c in range(image.shape[2]):
                acc[c] += np.bincount(flat, (weight * values[c]).ravel(), minlength=h * w)
    spread = (acc.T / taps).reshape(h, w, -1).astype(np.float32)
    spread /= np.maximum(spread[..., 3:], 1.0)         # paths that cross add up; keep alpha <= 1
    out = np.where(moving[..., None], 0.0, image).astype(np.float32)
    top, left = max(y0, 0), max(x0, 0)
    bottom, right = min(y0 + h, rows), min(x0 + w, cols)
    spread = spread[top - y0:bottom - y0, left - x0:right - x0]
    out[top:bottom, left:right] = spread + (1.0 - spread[..., 3:]) * out[top:bottom, left:right]
    return out


def edge_velocity_from_cover(velocity: np.ndarray, alpha: np.ndarray, radius: int = 2) -> np.ndarray:
    """``velocity`` (H, W, 2) with each partly covered pixel (0 < ``alpha`` < 1) given the velocity of the most
    covered pixel within ``radius`` px (itself on ties).

    A renderer may filter its velocity pass at an object's anti-aliased edge, mixing in the background's (Blender
    5.2 writes a non-zero background velocity there; 5.0 writes the object's): the mixture belongs to neither and
    would smear the edge. The graphics at such a pixel are the object's, so the object's velocity is used."""
    ys, xs = np.nonzero((alpha > 0) & (alpha < 1))
    if not len(ys):
        return velocity
    rows, cols = alpha.shape
    best_alpha, best_y, best_x = alpha[ys, xs].copy(), ys.copy(), xs.copy()
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            y, x = np.clip(ys + dy, 0, rows - 1), np.clip(xs + dx, 0, cols - 1)
            better = alpha[y, x] > best_alpha
            best_alpha[better], best_y[better], best_x[better] = alpha[y, x][better], y[better], x[better]
    out = velocity.copy()
    out[ys, xs] = velocity[best_y, best_x]
    return out


class ObjectMotion(Effect):
    """Blur along each pixel's image velocity minus the camera rotation's, over the shutter (needs a velocity
    pass: Blender's Vector pass through the add-on or ``lowcam render``)."""

    name = "object_motion"
    section = "beyond the paper (Fig. 15: object motion)"
    writes = "render"
    order = 0
    needs_pass = "velocity"
    params = {
        "min_shift_px": Param(0.5, low=0.0, high=100.0, unit="px (render)",
                              doc="pixels whose path over the exposure is shorter stay sharp"),
    }

    def apply(self, state):
        velocity = state.render_pass(self)
        exposure = shutter_s(state)
        if exposure <= 0:
            return
        lens, shape = state.profile.effect("lens_distortion"), state.render.shape[:2]
        if lens.projection(state.geometry) == "fisheye_equidistant":
            camera = fisheye_rotation_velocity(state.angular_velocity, lens.render_fisheye_field(state.geometry),
                                               shape)
        else:
            camera = rotation_velocity(state.angular_velocity, state.render_focal_px(), shape)
        velocity = edge_velocity_from_cover(velocity, state.render[..., 3])
        state.render = splat_along(state.render, (velocity - camera) * exposure, self.min_shift_px)
