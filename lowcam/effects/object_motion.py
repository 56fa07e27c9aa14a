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
- :func:`painted`: the pixels of an image with a non-zero channel
- :func:`path_kernel`: the weights one pixel leaves along its path (a group on one path is filtered with them)
- :func:`edge_velocity_from_cover`: partly covered pixels take the velocity of their most covered neighbour
- :class:`ObjectMotion`: blur along each pixel's velocity minus the camera rotation's (needs a velocity pass)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..window import grow_window
from .base import Effect, Param
from .motion_blur import shutter_s


def rotation_velocity(angular_velocity, focal_px: float, shape, window=None) -> np.ndarray:
    """(rows, cols, 2) image velocity (px/s, x right, y down) of a static scene seen by a pinhole camera of
    ``focal_px`` (centred, ``shape`` = (rows, cols)) turning at ``angular_velocity`` (rad/s, camera frame); only
    inside ``window`` ((rows, cols) slices) when given, the same values.

    A static direction ``d`` is seen at ``R(-t) d`` (:func:`~lowcam.effects.motion_blur.tap_offsets`), so
    ``d' = -w x d`` and, for ``d = (x, y, 1)``, ``x' = d'_x - x d'_z``, ``y' = d'_y - y d'_z``.
    """
    wx, wy, wz = (float(c) for c in angular_velocity)
    rows, cols = shape
    window_rows, window_cols = window or (slice(0, rows), slice(0, cols))
    x = ((np.arange(window_cols.start, window_cols.stop) - cols / 2 + 0.5) / focal_px)[None, :]
    y = ((np.arange(window_rows.start, window_rows.stop) - rows / 2 + 0.5) / focal_px)[:, None]
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


def splat_along(image: np.ndarray, shift_px: np.ndarray, min_shift_px: float = 0.5, *,
                by_pixel: bool = False) -> np.ndarray:
    """Spread each pixel of premultiplied RGBA ``image`` evenly along the segment ``[-shift/2, +shift/2]``
    around it (``shift_px`` (H, W, 2): the pixel's path over the exposure, px).

    Pixels that move less than ``min_shift_px`` stay as they are; the moving ones are spread with bilinear
    weights at taps at most 1 px apart and laid over the still ones (premultiplied "over").

    Pixels that share one path exactly (an object translating across the image under a still camera) are
    spread together: their deposits are the convolution of those pixels with the path's tap kernel
    (:func:`path_kernel`), applied as a few small float32 filters of under 50 weights each (OpenCV sums those
    directly, so nothing lands where no tap reaches) instead of one deposit per pixel and tap. Summed in float32,
    each value differs from spreading pixel by pixel (float64 sums) by at most 4e-6 of itself (1.4e-6 measured;
    the 8-bit frames of ``benchmarks/bench_passes.py`` are the same). Pixels whose path fewer than 64 others
    share, or whose group's box is cheaper to spread pixel by pixel, and every pixel with ``by_pixel``, get one
    bilinear deposit per tap (``np.bincount``).
    """
    spread = _spread(image, shift_px, min_shift_px, by_pixel)
    return image if spread is None else _lay_over(image.astype(np.float32), *spread)


def _spread(image, shift_px, min_shift_px, by_pixel):
    """:func:`splat_along`'s deposits: ``(ys, xs, spread, y0, x0)``, the moving pixels and the float32 canvas of
    what they leave (``spread``, its origin ``(y0, x0)`` in ``image``, reaching past its edges), or None when
    nothing moves."""
    ys, xs = np.nonzero(painted(image))                 # a transparent black pixel spreads nothing
    shifts = shift_px[ys, xs]
    length = np.hypot(shifts[:, 0], shifts[:, 1])
    moving = length >= min_shift_px
    if not moving.any():
        return None
    ys, xs, shifts = ys[moving], xs[moving], np.ascontiguousarray(shifts[moving])
    rows, cols, channels = image.shape
    longest = float(length[moving].max())
    reach = int(np.ceil(longest / 2)) + 2               # a canvas the paths stay inside, cropped to the image later
    y0, x0 = ys.min() - reach, xs.min() - reach
    h, w = ys.max() + reach + 1 - y0, xs.max() + reach + 1 - x0
    taps = max(2, int(np.ceil(longest)) + 1)
    grouped = np.zeros((h, w, channels), np.float32) if not by_pixel else None   # the groups' deposits
    alone = np.ones(len(ys), bool)
    if not by_pixel:
        for members in _groups(shifts.view(np.uint64).ravel()):             # the same path, bit for bit
            if _spread_group(grouped, image, ys[members], xs[members], shifts[members[0]], taps, y0, x0):
                alone[members] = False
    if alone.any():
        acc = np.zeros((channels, h * w), np.float64)
        _spread_pixels(acc, image, ys[alone], xs[alone], shifts[alone].astype(np.float64), taps, y0, x0, w)
        acc = acc.T.reshape(h, w, channels)
        spread = ((acc if grouped is None or not (~alone).any() else acc + grouped) / taps).astype(np.float32)
    else:
        spread = grouped / np.float32(taps)
    if spread[..., 3].max() > 1:
        spread /= np.maximum(spread[..., 3:], 1.0)     # paths that cross add up; keep alpha <= 1
    return ys, xs, spread, y0, x0


def _lay_over(out, ys, xs, spread, y0, x0):
    """``out`` (float32, changed in place) with pixels ``(ys, xs)`` gone and ``spread`` (origin ``(y0, x0)``,
    cropped to ``out``) laid over it (premultiplied "over")."""
    rows, cols = out.shape[:2]
    h, w = spread.shape[:2]
    out[ys, xs] = 0.0                                   # the moving pixels leave
    top, left = max(y0, 0), max(x0, 0)
    bottom, right = min(y0 + h, rows), min(x0 + w, cols)
    spread = spread[top - y0:bottom - y0, left - x0:right - x0]
    under = (1.0 - spread[..., 3:]) * out[top:bottom, left:right]
    under += spread                                     # premultiplied over
    out[top:bottom, left:right] = under
    return out


def painted(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``image`` (H, W, C) with a non-zero channel (-0.0 counts as zero)."""
    nonzero = image != 0
    if image.shape[-1] == 4:                            # the four bools of a pixel read as one 32-bit word
        return np.ascontiguousarray(nonzero).view(np.uint32)[..., 0] != 0
    return nonzero.any(axis=-1)


_MIN_GROUP_PX = 64          # fewer pixels on one path are cheaper to spread one by one


def _groups(keys: np.ndarray) -> list:
    """Indices of ``keys`` that hold the same key, ascending, for each key at least ``_MIN_GROUP_PX`` hold."""
    order = np.argsort(keys, kind="stable")
    _, starts, counts = np.unique(keys[order], return_index=True, return_counts=True)
    return [order[start:start + count] for start, count in zip(starts, counts) if count >= _MIN_GROUP_PX]


def path_kernel(shift_px, taps: int):
    """The deposit of one pixel spread over ``shift_px`` (dx, dy) in ``taps`` bilinear taps, as in
    :func:`splat_along` before its division by ``taps``: ``(kernel, dy0, dx0)``, ``kernel[i, j]`` (float64) the
    weight landing ``(dy0 + i, dx0 + j)`` px from the pixel."""
    t = (np.arange(taps) + 0.5) / taps - 0.5
    x, y = float(shift_px[0]) * t, float(shift_px[1]) * t
    xi, yi = np.floor(x), np.floor(y)
    fx, fy = x - xi, y - yi
    dx0, dy0 = int(xi.min()), int(yi.min())
    kernel = np.zeros((int(yi.max()) - dy0 + 2, int(xi.max()) - dx0 + 2))
    i, j = (yi - dy0).astype(int), (xi - dx0).astype(int)
    for di, dj, weight in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(kernel, (i + di, j + dj), weight)
    return kernel, dy0, dx0


def _kernel_pieces(kernel: np.ndarray, most: int = 49):
    """``kernel``'s non-zero weights cut into rectangles of at most ``most`` entries, walked along the kernel's
    long side: [(top, left, block)]. OpenCV filters larger kernels by DFT, whose rounding would leave faint
    non-zero values where nothing lands; below 50 entries it sums the non-zero weights directly."""
    ii, jj = np.nonzero(kernel)
    order = np.lexsort((ii, jj) if kernel.shape[1] >= kernel.shape[0] else (jj, ii))
    pieces = []                                         # [members, top, bottom, left, right]
    for k, i, j in zip(order.tolist(), ii[order].tolist(), jj[order].tolist()):
        if pieces:
            members, top, bottom, left, right = pieces[-1]
            top, bottom, left, right = min(top, i), max(bottom, i), min(left, j), max(right, j)
            if (bottom - top + 1) * (right - left + 1) <= most:
                members.append(k)
                pieces[-1][1:] = top, bottom, left, right
                continue
        pieces.append([[k], i, i, j, j])
    out = []
    for members, top, bottom, left, right in pieces:
        block = np.zeros((bottom - top + 1, right - left + 1), np.float32)
        block[ii[members] - top, jj[members] - left] = kernel[ii[members], jj[members]]
        out.append((top, left, block))
    return out


def _spread_group(acc, image, ys, xs, shift, taps, y0, x0) -> bool:
    """Add the deposits of pixels ``(ys, xs)`` of ``image``, all on path ``shift``, to ``acc`` (float32 h, w,
    channels; origin ``(y0, x0)`` in the image): their convolution with :func:`path_kernel`. False (nothing
    added) where filtering the group's box would cost more than spreading its pixels one by one."""
    kernel, dy0, dx0 = path_kernel(shift.astype(np.float64), taps)
    pieces = _kernel_pieces(kernel)
    top, left = ys.min(), xs.min()
    box_rows, box_cols = ys.max() + 1 - top, xs.max() + 1 - left
    area = (box_rows + kernel.shape[0]) * (box_cols + kernel.shape[1])
    per_pixel = len(ys) * taps * 16 * 5.0                       # ~ns: bincount entries
    filtered = area * image.shape[2] * (np.count_nonzero(kernel) * 0.3 + len(pieces) * 3.0) + 2e5
    if filtered > per_pixel:
        return False
    margin_y, margin_x = max(b.shape[0] for _, _, b in pieces) - 1, max(b.shape[1] for _, _, b in pieces) - 1
    source = np.zeros((box_rows + margin_y, box_cols + margin_x, image.shape[2]), np.float32)
    source[ys - top + margin_y, xs - left + margin_x] = image[ys, xs]
    for i, j, block in pieces:
        # with the flipped block and the source padded by its size - 1: out[q] = sum_ab block[a, b] source(q - ab),
        # the deposits landing (dy0 + i, dx0 + j) + q px from the box's corner; zeros past the source's end
        pad_y, pad_x = block.shape[0] - 1, block.shape[1] - 1
        padded = source[margin_y - pad_y:, margin_x - pad_x:]
        out = cv2.filter2D(padded, -1, block[::-1, ::-1].copy(), anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
        r, c = top + dy0 + i - y0, left + dx0 + j - x0
        acc[r:r + out.shape[0], c:c + out.shape[1]] += out
    return True


def _spread_pixels(acc, image, ys, xs, shift, taps, y0, x0, w) -> None:
    """Add the deposits of pixels ``(ys, xs)`` of ``image`` (paths ``shift`` (n, 2) px) to ``acc``
    (channels, h * w; origin ``(y0, x0)``, width ``w``), one bilinear deposit per pixel and tap."""
    values = image[ys, xs].astype(np.float64).T         # (channels, pixels)
    chunk = max(1, 1_000_000 // len(xs))                # taps per bincount: about a million entries
    for first in range(0, taps, chunk):
        t = ((np.arange(first, min(first + chunk, taps)) + 0.5) / taps - 0.5)[:, None]
        x = (xs - x0) + shift[:, 0] * t                  # (taps in chunk, pixels)
        y = (ys - y0) + shift[:, 1] * t
        xi, yi = np.floor(x), np.floor(y)
        fx, fy = x - xi, y - yi
        index = (yi * w + xi).astype(np.int64)
        for offset, weight in ((0, (1 - fx) * (1 - fy)), (1, fx * (1 - fy)), (w, (1 - fx) * fy), (w + 1, fx * fy)):
            flat = (index + offset).ravel()
            for c in range(image.shape[2]):
                acc[c] += np.bincount(flat, (weight * values[c]).ravel(), minlength=acc.shape[1])


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
    size = 2 * radius + 1
    most = cv2.dilate(np.ascontiguousarray(alpha), np.ones((size, size), np.uint8))[ys, xs]   # within radius
    best_y, best_x = ys.copy(), xs.copy()
    todo = np.nonzero(most > alpha[ys, xs])[0]          # the rest are the most covered themselves
    for dy in range(-radius, radius + 1):               # the first most covered neighbour in this order
        for dx in range(-radius, radius + 1):
            y, x = np.clip(ys[todo] + dy, 0, rows - 1), np.clip(xs[todo] + dx, 0, cols - 1)
            found = alpha[y, x] == most[todo]
            best_y[todo[found]], best_x[todo[found]] = y[found], x[found]
            todo = todo[~found]
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
        window = state.window("render")
        if window is None:
            return                                      # transparent black everywhere: nothing to spread
        # only the non-zero pixels can move: work in their window, grown by the edge search's reach
        render, shape = state.render, state.render.shape[:2]
        near = grow_window(window, 2, shape)
        lens = state.profile.effect("lens_distortion")
        if lens.projection(state.geometry) == "fisheye_equidistant":
            camera = fisheye_rotation_velocity(state.angular_velocity, lens.render_fisheye_field(state.geometry),
                                               shape)[near]
        else:
            camera = rotation_velocity(state.angular_velocity, state.render_focal_px(), shape, near)
        shift = (edge_velocity_from_cover(velocity[near], render[near][..., 3]) - camera) * exposure
        spread = _spread(render[near], shift, self.min_shift_px, False)
        if spread is None:
            return
        ys, xs, canvas, y0, x0 = spread
        top, left = near[0].start, near[1].start
        state.render = _lay_over(render.astype(np.float32), ys + top, xs + left, canvas, y0 + top, x0 + left)
        (rows, cols), (h, w) = window, canvas.shape[:2]      # the non-zero pixels: the render's and the canvas's
        y0, x0 = y0 + top, x0 + left
        state.keep_window("render", (slice(max(min(rows.start, y0), 0), min(max(rows.stop, y0 + h), shape[0])),
                                     slice(max(min(cols.start, x0), 0), min(max(cols.stop, x0 + w), shape[1]))), self)
