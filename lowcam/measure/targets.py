"""Ideal views of printed targets for captures that give ``target`` instead of ``ideal``.

The board's pose is estimated from the mean of the frames through the profile's lens. Before the camera is
blamed for anything, the target's own nuisances are fitted to the frames (:func:`fit_board_nuisances`):

- the **paper white and black** (render units, at the board's centre),
- a smooth **illumination field** on the paper, bilinear in board coordinates ``(s, t)`` (each -1..1 across the
  squares): ``L = 1 + c_s s + c_t t + c_st s t``, one per capture. Lighting lives on the paper, so the field is
  written in board coordinates. It is kept low order on purpose: the camera's vignetting is radial in image
  coordinates and projects onto the board as ``~ s^2 + t^2`` (rotation-invariant, no ``s t`` term), so a
  bilinear field cannot absorb a centred fall-off; only its one-sided part, which a tilted lamp also makes.
- the **white paper margin** around the squares, per side (left, top, right, bottom, in squares, continuous): the
  first strong falling edge of the measured paper-ness ``r / (white L)`` outward from the squares' outer edge.
  The paper is rendered out to it, the frames' own mean (the plate) lies beyond.

The fit is made in the profile's own "flat-equivalent render value" domain: the quiet profile (no noise, no
quantisation) is run once per profile on flat renders at :data:`FLAT_LEVELS`, and each measured mean pixel is
inverted through its own response curve (piecewise linear). Vignetting, the tone curve, the bit depth and the
gains of the profile are thereby camera effects kept out of the nuisances: they are common to all views and
come from the profile. The fit itself is then linear least squares (alternating between the field and the
black/white ratio, with outliers such as fingers on the board rejected), well under 0.5 s per capture once the
profile's flat responses are cached.

Contents
--------
- :data:`FLAT_LEVELS`: the flat render values at which the profile's response is tabulated
- :data:`MAX_MARGIN`: the widest paper margin searched for, in squares
- :class:`BoardNuisances`: the fitted paper white, black, illumination field and margins of one capture
- :func:`flat_response`: the quiet profile's per-pixel output (channel mean, DN) for flat renders, cached
- :func:`board_coordinates`: per output pixel, the board coordinates (in squares) through the lens and the pose
- :func:`fit_board_nuisances`: white, black, illumination and margins from a capture's mean, pose and profile
- :func:`board_texture`: a printed chessboard with its paper margin, lit, and its pixel -> metre origin offset
- :func:`render_board_view`: a pinhole render (premultiplied RGBA, opaque on the paper) of a chessboard at a pose
- :func:`board_pose`: a ``target`` capture's board description and pose (through the profile's lens)
- :func:`fit_target`: a ``target`` capture's pose and nuisances, with one render-then-simulate pass
- :func:`ideal_from_target`: (ideal render, plate, mask) for a ``target`` capture, the board's pose and nuisances fitted
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import LowcamError

#: Flat render values at which the profile's response is tabulated (denser where tone curves bend most).
FLAT_LEVELS = (0.0, 0.03, 0.08, 0.16, 0.3, 0.5, 0.75, 1.05, 1.5)
#: The widest white paper margin searched for around the squares, in squares.
MAX_MARGIN = 2.0
_RESPONSES: OrderedDict = OrderedDict()


@dataclass
class BoardNuisances:
    """A board's nuisances. ``white``/``black``: render values of the paper at the board's centre;
    ``illumination``: ``(c_s, c_t, c_st)`` of ``L = 1 + c_s s + c_t t + c_st s t`` with ``s, t`` in -1..1
    across the squares; ``margins``: white paper beyond the squares (left, top, right, bottom) in squares;
    ``flipped``: the square at the first inner corner's top-left is white (the parity seen in the frames)."""

    white: float = 0.9
    black: float = 0.1
    illumination: tuple = (0.0, 0.0, 0.0)
    margins: tuple = (1.0, 1.0, 1.0, 1.0)
    flipped: bool = False

    def light(self, s, t):
        """The illumination field at board coordinates (s, t)."""
        cs, ct, cst = self.illumination
        return 1.0 + cs * s + ct * t + cst * s * t


def _quiet(profile):
    names = [n for n in ("noise", "row_noise", "quantisation") if profile.effect(n) is not None]
    return profile.without(*names) if names else profile


def flat_response(profile) -> np.ndarray:
    """(len(FLAT_LEVELS), H, W) float32: the quiet profile's output (mean of the channels, DN) for a flat opaque
    grey render at each of :data:`FLAT_LEVELS`. Cached per profile (its camera and effects)."""
    from ..pipeline import prepare, resume
    from .compare import prefix_key

    quiet = _quiet(profile)
    key = prefix_key(quiet, len(quiet.effects))
    if key in _RESPONSES:
        _RESPONSES.move_to_end(key)
        return _RESPONSES[key]
    h, w = profile.camera.height, profile.camera.width
    table = np.empty((len(FLAT_LEVELS), h, w), np.float32)
    for k, v in enumerate(FLAT_LEVELS):
        flat = np.ones((h, w, 4), np.float32)
        flat[..., :3] = v
        table[k] = resume(prepare(flat, quiet), 0, 0, quiet).astype(np.float32).mean(axis=2)
    _RESPONSES[key] = table
    while len(_RESPONSES) > 4:
        _RESPONSES.popitem(last=False)
    return table


def _invert_response(table: np.ndarray, measured: np.ndarray):
    """Per pixel, the flat render value whose output is ``measured`` (piecewise linear through ``table``, which is
    (K, N)), and where that inversion is trustworthy (inside the table's range, not clipped)."""
    levels = np.asarray(FLAT_LEVELS, np.float32)
    k = np.clip((table <= measured[None]).sum(axis=0) - 1, 0, len(levels) - 2)
    cols = np.arange(measured.size)
    lo, hi = table[k, cols], table[k + 1, cols]
    step = np.maximum(hi - lo, 1e-3)
    value = levels[k] + (measured - lo) / step * (levels[k + 1] - levels[k])
    ok = (hi - lo > 0.5) & (measured < min(254.5, float(table[-1].max()))) & (measured <= table[-1][cols])
    return value, ok


def board_coordinates(profile, rvec, tvec, square: float) -> tuple[np.ndarray, np.ndarray]:
    """(u, v), each (H, W): board coordinates in squares (the first inner corner at 0, 0) of every output pixel,
    through the profile's lens (undistorted on an 8-px grid, interpolated) and the board's pose (metres)."""
    h, w = profile.camera.height, profile.camera.width
    step = 8
    gy, gx = np.mgrid[0:h + step:step, 0:w + step:step].astype(np.float64)
    x, y = profile.lens.undistort(gx.ravel(), gy.ravel())
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    hom = np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64).ravel()])
    p = np.linalg.solve(hom, np.vstack([x, y, np.ones_like(x)]))
    uv = (p[:2] / p[2] / square).reshape(2, *gx.shape).astype(np.float32)
    my, mx = np.mgrid[0:h, 0:w].astype(np.float32) / step
    return tuple(cv2.remap(c, mx, my, cv2.INTER_LINEAR) for c in uv)


def _board_st(u, v, inner):
    """Board coordinates (squares) -> (s, t), each -1..1 across the squares."""
    cols, rows = inner[0] + 1, inner[1] + 1
    return (u - (inner[0] - 1) / 2) / (cols / 2), (v - (inner[1] - 1) / 2) / (rows / 2)


def _fit_light(r, s, t, dark, iterations: int = 20):
    """Least squares of r = k (a0 + a1 s + a2 t + a3 s t), k = 1 on white and beta on black squares: alternating
    between the field (4x4 normal equations) and beta (closed form), outliers beyond 4 robust sigmas dropped
    twice (fingers, glints). Returns (a, beta)."""
    basis = np.column_stack([np.ones_like(s), s, t, s * t])
    keep = np.ones(r.size, bool)
    a, beta = np.array([np.median(r[~dark]), 0.0, 0.0, 0.0]), 0.1
    for rnd in range(3):
        w, b = keep & ~dark, keep & dark
        gw, gb = basis[w].T @ basis[w], basis[b].T @ basis[b]
        hw, hb = basis[w].T @ r[w], basis[b].T @ r[b]
        for _ in range(iterations):
            a = np.linalg.solve(gw + beta ** 2 * gb + 1e-12 * np.eye(4), hw + beta * hb)
            beta = float(a @ hb / max(a @ gb @ a, 1e-12))
        if rnd < 2:
            resid = r - np.where(dark, beta, 1.0) * (basis @ a)
            mad = 1.4826 * np.median(np.abs(resid[keep])) + 1e-6
            keep = np.abs(resid) < 4 * mad
    return a, beta


def _margin(d, q, max_margin: float) -> float:
    """Where the paper ends: the first strong falling edge of the paper-ness q (1 on paper) against the distance
    d (squares) outward from the squares' outer edge (negative: the paper cuts into the outer squares), or
    ``max_margin`` when there is none (the paper goes on)."""
    bin_w, start = 0.02, -1.0
    nb = int(round((max_margin - start) / bin_w))
    idx = np.floor((d - start) / bin_w).astype(int)
    sel = (idx >= 0) & (idx < nb)
    if sel.sum() < 20:
        return max_margin
    order = np.argsort(idx[sel], kind="stable")
    ids, qs = idx[sel][order], q[sel][order]
    starts = np.searchsorted(ids, np.arange(nb + 1))
    prof = np.array([np.median(qs[a:b]) if b - a >= 3 else np.nan for a, b in zip(starts[:-1], starts[1:])])
    valid = np.nonzero(np.isfinite(prof))[0]
    if len(valid) < 5:
        return max_margin
    first, last = valid[0], valid[-1]
    prof = np.interp(np.arange(nb), valid, prof[valid])
    prof = np.convolve(np.pad(prof, 2, mode="edge"), [1 / 9, 2 / 9, 3 / 9, 2 / 9, 1 / 9], "valid")
    slope = np.diff(prof)
    slope[:first] = 0
    slope[last:] = 0
    if slope.min() > -0.15 / 8:  # no edge that drops the paper-ness by ~0.15 within ~8 bins
        return max_margin
    strong = slope <= 0.5 * slope.min()
    i = int(np.argmax(strong))
    while i + 1 < len(slope) and slope[i + 1] < slope[i]:  # walk down to the edge's steepest point
        i += 1
    y0, y1, y2 = (slope[max(i - 1, 0)], slope[i], slope[min(i + 1, len(slope) - 1)])
    den = y0 - 2 * y1 + y2
    frac = 0.5 * (y0 - y2) / den if abs(den) > 1e-12 else 0.0
    return float(np.clip(start + (i + 1 + np.clip(frac, -0.5, 0.5)) * bin_w, start, max_margin))


def fit_board_nuisances(profile, mean: np.ndarray, rvec, tvec, inner, square: float,
                        max_margin: float = MAX_MARGIN, max_samples: int = 30000, simulated=None,
                        previous: BoardNuisances | None = None) -> BoardNuisances:
    """Fit a board's paper white and black, its bilinear illumination field and its paper margins to the mean
    of a capture's frames (H, W, 3, DN), given the board's pose (see the module docstring for the method).
    ``simulated`` (the quiet profile's frame of the board rendered with ``previous``) corrects the squares for
    what the chain does beyond a flat field (sharpening halos near the edges): measured x model / simulated.

    Two passes: white, black and light on the inner squares (the outer ones may be cut by the paper's edge),
    then the margins, then white, black and light again on every square inside the paper. Pixels within 3 px
    of a square's edge are left out (the camera's blur lives there); at most ``max_samples`` pixels are used."""
    table = flat_response(profile)
    u, v = board_coordinates(profile, rvec, tvec, square)
    x0, x1, y0, y1 = -1.0, float(inner[0]), -1.0, float(inner[1])  # the squares' outer edges, in squares
    near = (u > x0 - max_margin) & (u < x1 + max_margin) & (v > y0 - max_margin) & (v < y1 + max_margin)
    on_squares = (u > x0) & (u < x1) & (v > y0) & (v < y1)
    parity = (np.floor(u) + np.floor(v)).astype(np.int64) % 2 == 0  # the first corner's top-left square's
    kernel = np.ones((7, 7), np.uint8)
    cores = [cv2.erode((on_squares & (parity == p)).astype(np.uint8), kernel) > 0 for p in (True, False)]
    pick = near.ravel()
    value = np.zeros(u.size, np.float32)
    ok = np.zeros(u.size, bool)
    value[pick], ok[pick] = _invert_response(table.reshape(len(FLAT_LEVELS), -1)[:, pick],
                                             mean.mean(axis=2).astype(np.float32).ravel()[pick])
    value, ok = value.reshape(u.shape), ok.reshape(u.shape)
    light_value = value
    if simulated is not None and previous is not None:
        sim_value, sim_ok = _invert_response(table.reshape(len(FLAT_LEVELS), -1)[:, pick],
                                             np.asarray(simulated, np.float32).mean(axis=2).ravel()[pick])
        model = np.zeros(u.size, np.float32)
        ss, tt = _board_st(u.ravel()[pick], v.ravel()[pick], inner)
        dark_prev = (parity.ravel()[pick] != previous.flipped)
        model[pick] = np.where(dark_prev, previous.black, previous.white) * previous.light(ss, tt)
        ratio = np.ones(u.size, np.float32)
        good = np.zeros(u.size, bool)
        good[pick] = sim_ok & (sim_value > 1e-3)
        ratio[good] = model[good] / sim_value[good[pick]]
        light_value = value * ratio.reshape(u.shape)
        ok = ok & good.reshape(u.shape)
    inner_sq = (u > x0 + 1) & (u < x1 - 1) & (v > y0 + 1) & (v < y1 - 1)
    if min((c & ok & inner_sq).sum() for c in cores) < 50:
        raise LowcamError("the board's squares are too small in the frame to fit its paper and lighting")
    even_dark = bool(np.median(value[cores[0] & ok & inner_sq]) < np.median(value[cores[1] & ok & inner_sq]))

    def light_fit(region):
        idx = np.flatnonzero((cores[0] | cores[1]) & ok & region)
        idx = idx[::max(1, len(idx) // max_samples)]
        s, t = _board_st(u.flat[idx], v.flat[idx], inner)
        a, beta = _fit_light(light_value.flat[idx].astype(np.float64), s, t, cores[0].flat[idx] == even_dark)
        if a[0] <= 0:
            raise LowcamError("the board's paper white could not be fitted (is the board lit?)")
        return BoardNuisances(white=float(a[0]), black=float(beta * a[0]),
                              illumination=tuple(float(c) for c in a[1:] / a[0]), flipped=not even_dark)

    nuis = light_fit(inner_sq)
    # the paper margin, side by side: paper-ness r / (white L) against the distance from the squares' edge;
    # inside the outer squares (the paper may cut into them) only their white ones count
    ss, tt = _board_st(u, v, inner)
    paperness = value / np.maximum(nuis.white * nuis.light(ss, tt), 1e-6)
    light_sq = ~(on_squares & (parity == even_dark))
    sides = [(x0 - u, (v > y0 + 0.5) & (v < y1 - 0.5)), (y0 - v, (u > x0 + 0.5) & (u < x1 - 0.5)),
             (u - x1, (v > y0 + 0.5) & (v < y1 - 0.5)), (v - y1, (u > x0 + 0.5) & (u < x1 - 0.5))]
    margins = []
    for d, along in sides:
        m = along & ok & (d >= -1) & (d < max_margin) & light_sq
        margins.append(_margin(d[m], paperness[m], max_margin))
    left, top, right, bottom = margins
    paper = (u > x0 - left) & (u < x1 + right) & (v > y0 - top) & (v < y1 + bottom)
    paper = cv2.erode(paper.astype(np.uint8), kernel) > 0
    nuis = light_fit(paper)
    nuis.margins = tuple(margins)
    return nuis


def board_texture(inner=(9, 6), px_per_square: int = 60, border: int = 1, white: float = 0.9, black: float = 0.1,
                  nuisances: BoardNuisances | None = None):
    """A printed chessboard (``inner`` corners), premultiplied (value, alpha) planes, and the pixel->square
    offset (x, y) of its first inner corner. Without ``nuisances``: a ``border`` of white squares, flat light;
    with them: their paper margins (fractional at the paper's edge), white, black, parity and illumination."""
    cols, rows = inner[0] + 1, inner[1] + 1
    n = nuisances or BoardNuisances(white, black, margins=(float(border),) * 4)
    left, top, right, bottom = n.margins
    pad = int(np.ceil(max(n.margins))) + 1
    size = ((rows + 2 * pad) * px_per_square, (cols + 2 * pad) * px_per_square)
    # pixel centres in board squares (the first inner corner at 0, 0)
    us = (np.arange(size[1]) + 0.5) / px_per_square - pad - 1
    vs = (np.arange(size[0]) + 0.5) / px_per_square - pad - 1
    half = 0.5 / px_per_square

    def cover(c, lo, hi):  # fraction of each pixel inside [lo, hi]
        return np.clip(np.minimum(c + half, hi) - np.maximum(c - half, lo), 0, 2 * half) * px_per_square

    alpha = cover(vs, -1 - top, inner[1] + bottom)[:, None] * cover(us, -1 - left, inner[0] + right)[None, :]
    iu, iv = np.floor(us).astype(int), np.floor(vs).astype(int)
    in_u, in_v = (iu >= -1) & (iu < inner[0]), (iv >= -1) & (iv < inner[1])
    dark = (((iv[:, None] + iu[None, :]) % 2 == 0) != n.flipped) & in_v[:, None] & in_u[None, :]
    s, t = _board_st(us[None, :], vs[:, None], inner)
    reflect = np.where(dark, n.black, n.white)
    value = (reflect * np.maximum(n.light(s, t), 0.0) * alpha).astype(np.float32)
    return value, alpha.astype(np.float32), (pad + 1, pad + 1)


def render_board_view(profile, rvec, tvec, inner=(9, 6), square=0.025, width=1600, white=0.9, black=0.1,
                      px_per_square: int = 60, nuisances: BoardNuisances | None = None) -> np.ndarray:
    """A pinhole render (premultiplied RGBA, opaque on the paper only) of a chessboard at pose (rvec, tvec);
    ``nuisances`` (fitted) give its margins, white, black and lighting, else a one-square white border."""
    from ..pipeline import render_field_of_view

    half_x, _ = render_field_of_view(profile)
    height = width * profile.camera.height // profile.camera.width
    f = width / (2 * half_x)
    value, alpha, origin = board_texture(inner, px_per_square, 1, white, black, nuisances)
    k = np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1]])
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    s = square / px_per_square
    to_m = np.array([[s, 0, -origin[0] * square + 0.5 * s], [0, s, -origin[1] * square + 0.5 * s], [0, 0, 1]])
    h = k @ np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64).ravel()]) @ to_m
    grey = cv2.warpPerspective(value, h, (width, height), flags=cv2.INTER_LINEAR, borderValue=0)
    cover = cv2.warpPerspective(alpha, h, (width, height), flags=cv2.INTER_LINEAR, borderValue=0)
    out = np.zeros((height, width, 4), np.float32)
    out[..., :3] = grey[..., None]
    out[..., 3] = np.clip(cover, 0, 1)
    return out


def board_pose(profile, capture):
    """(target description, rvec, tvec, the frames' mean as uint8) of a ``target`` capture: the board found in the
    mean of its frames, its pose estimated through the profile's lens."""
    from ..captures import detect_target, parse_target

    spec = parse_target(capture.target)
    if spec[0] != "checkerboard":
        raise LowcamError(f"capture {capture.name}: only checkerboard targets can be rendered so far")
    u8 = np.clip(np.rint(capture.mean), 0, 255).astype(np.uint8)
    found = detect_target(u8, spec)
    if found is None:
        raise LowcamError(f"capture {capture.name}: {capture.target} not found in the mean of its frames")
    obj, img = found
    x, y = profile.lens.undistort(img[:, 0], img[:, 1])
    ok, rvec, tvec = cv2.solvePnP(obj, np.column_stack([x, y]), np.eye(3), None)
    if not ok:
        raise LowcamError(f"capture {capture.name}: the board's pose could not be estimated")
    return spec, rvec.ravel(), tvec.ravel(), u8


def _refine_pose(profile, capture, spec, rvec, tvec, fitted, plate):
    """(rvec, tvec, the quiet profile's frame of the fitted board). One pass of render-then-simulate: the corners
    found in the quiet profile's view of the fitted board are
    where the camera chain moves them (half-pixel boxes, blur, aberration); the measured corners are moved back by
    that much and the pose solved again, so the chain's shift is not counted twice."""
    from ..captures import detect_target
    from ..pipeline import prepare, resume

    quiet = _quiet(profile)
    view = render_board_view(profile, rvec, tvec, spec[1], spec[2], nuisances=fitted, px_per_square=120)
    sim = resume(prepare(view, quiet, plate), 0, 0, quiet)
    measured, simulated = detect_target(plate, spec), detect_target(sim, spec)
    if measured is None or simulated is None:
        return rvec, tvec, sim
    obj, img = measured
    if np.abs(simulated[1] - img).max() > 3.0:  # not the same corners (order or detection): keep the pose
        return rvec, tvec, sim
    img = 2 * img - simulated[1]
    x, y = profile.lens.undistort(img[:, 0], img[:, 1])
    ok, r2, t2 = cv2.solvePnP(obj, np.column_stack([x, y]), np.eye(3), None, np.asarray(rvec, np.float64).copy(),
                              np.asarray(tvec, np.float64).copy(), True)
    return (r2.ravel(), t2.ravel(), sim) if ok else (rvec, tvec, sim)


def fit_target(profile, capture):
    """(target description, rvec, tvec, :class:`BoardNuisances`) of a ``target`` capture: the pose, the
    nuisances, one render-then-simulate pass (:func:`_refine_pose`) and the nuisances again, corrected by it."""
    spec, rvec, tvec, u8 = board_pose(profile, capture)
    try:
        fitted = fit_board_nuisances(profile, capture.mean, rvec, tvec, spec[1], spec[2])
        rvec, tvec, sim = _refine_pose(profile, capture, spec, rvec, tvec, fitted, u8)
        fitted = fit_board_nuisances(profile, capture.mean, rvec, tvec, spec[1], spec[2], simulated=sim,
                                     previous=fitted)
    except LowcamError as e:
        raise LowcamError(f"capture {capture.name}: {e}") from None
    return spec, rvec, tvec, fitted


def ideal_from_target(profile, capture, nuisances: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(ideal render, plate, mask of compared pixels or None) for a ``target`` capture: the board's pose from the frames through the profile's
    lens (:func:`board_pose`), its nuisances fitted (:func:`fit_board_nuisances`; ``nuisances=False``: a
    one-square white border and the 95th/5th percentiles of the green mean inside the corners' hull as white and
    black, the former behaviour, kept for comparison), and the frames' own mean as the plate around the paper."""
    spec, rvec, tvec, u8 = board_pose(profile, capture)
    if nuisances:
        _, rvec, tvec, fitted = fit_target(profile, capture)
        return render_board_view(profile, rvec, tvec, spec[1], spec[2], nuisances=fitted, px_per_square=120), u8, None
    from ..captures import detect_target

    img = detect_target(u8, spec)[1]
    hull = cv2.convexHull(img.astype(np.float32)).astype(np.int32)
    inside = np.zeros(u8.shape[:2], np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    values = capture.mean[..., 1][inside > 0]
    white, black = np.percentile(values, 95) / 255.0, np.percentile(values, 5) / 255.0
    return render_board_view(profile, rvec, tvec, spec[1], spec[2], white=white, black=black), u8, None
