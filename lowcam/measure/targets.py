"""Ideal views of printed targets for captures that give ``target`` instead of ``ideal``.

The board's pose is estimated from the mean of the frames through the profile's lens, its white and black are
taken from the frames, and the frames' own mean is the plate around it.

Contents
--------
- :func:`board_texture`: a printed chessboard with a border of white squares, and its pixel -> metre origin offset
- :func:`render_board_view`: a pinhole render (premultiplied RGBA, opaque on the board) of a chessboard at a pose
- :func:`ideal_from_target`: (ideal render, plate) for a ``target`` capture, the board's pose from the frames
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import LowcamError


def board_texture(inner=(9, 6), px_per_square: int = 60, border: int = 1, white: float = 0.9, black: float = 0.1):
    """A printed chessboard (``inner`` corners) with a ``border`` of white squares, and the pixel->metre origin
    offset in squares (the first inner corner sits at the origin)."""
    cols, rows = inner[0] + 1, inner[1] + 1
    board = np.full(((rows + 2 * border) * px_per_square, (cols + 2 * border) * px_per_square), white, np.float32)
    for i in range(rows):
        for j in range(cols):
            if (i + j) % 2 == 0:
                y0, x0 = (i + border) * px_per_square, (j + border) * px_per_square
                board[y0:y0 + px_per_square, x0:x0 + px_per_square] = black
    return board, border + 1


def render_board_view(profile, rvec, tvec, inner=(9, 6), square=0.025, width=1600, white=0.9, black=0.1,
                      px_per_square: int = 60) -> np.ndarray:
    """A pinhole render (premultiplied RGBA, opaque on the board only) of a chessboard at pose (rvec, tvec)."""
    from ..pipeline import render_field_of_view

    half_x, _ = render_field_of_view(profile)
    height = width * profile.camera.height // profile.camera.width
    f = width / (2 * half_x)
    board, origin = board_texture(inner, px_per_square, 1, white, black)
    k = np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1]])
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    s = square / px_per_square
    to_m = np.array([[s, 0, -origin * square + 0.5 * s], [0, s, -origin * square + 0.5 * s], [0, 0, 1]])
    h = k @ np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64)]) @ to_m
    grey = cv2.warpPerspective(board, h, (width, height), flags=cv2.INTER_AREA, borderValue=0)
    alpha = cv2.warpPerspective(np.ones_like(board), h, (width, height), flags=cv2.INTER_AREA, borderValue=0)
    out = np.zeros((height, width, 4), np.float32)
    out[..., :3] = grey[..., None]
    out[..., 3] = np.clip(alpha, 0, 1)
    return out


def ideal_from_target(profile, capture) -> tuple[np.ndarray, np.ndarray]:
    """(ideal render, plate) for a ``target`` capture: the board's pose from the frames through the profile's
    lens, its white and black from the frames, and the frames' own mean as the plate around it."""
    from ..captures import detect_target, parse_target

    spec = parse_target(capture.target)
    if spec[0] != "checkerboard":
        raise LowcamError(f"capture {capture.name}: only checkerboard targets can be rendered so far")
    mean = capture.mean
    u8 = np.clip(np.rint(mean), 0, 255).astype(np.uint8)
    found = detect_target(u8, spec)
    if found is None:
        raise LowcamError(f"capture {capture.name}: {capture.target} not found in the mean of its frames")
    obj, img = found
    x, y = profile.lens.undistort(img[:, 0], img[:, 1])
    ok, rvec, tvec = cv2.solvePnP(obj, np.column_stack([x, y]), np.eye(3), None)
    if not ok:
        raise LowcamError(f"capture {capture.name}: the board's pose could not be estimated")
    hull = cv2.convexHull(img.astype(np.float32)).astype(np.int32)
    inside = np.zeros(u8.shape[:2], np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    values = mean[..., 1][inside > 0]
    gain = 255.0
    white, black = np.percentile(values, 95) / gain, np.percentile(values, 5) / gain
    ideal = render_board_view(profile, rvec.ravel(), tvec.ravel(), spec[1], spec[2], white=white, black=black)
    return ideal, u8
