"""Ideal views of printed targets for captures that give ``target`` instead of ``ideal``.

The board's pose is estimated from the mean of the frames through the profile's lens. Before the camera is
blamed for anything, the target's own nuisances are fitted to the frames (:func:`fit_board_nuisances`):

- the **paper white and black** (render units, at the board's centre),
- a smooth **illumination field** on the paper, in board coordinates ``(s, t)`` (each -1..1 across the squares),
  one per capture: ``L = 1 + sum_k c_k s^i t^j`` over :data:`LIGHT_TERMS` (bilinear, then the terms of degree 2
  and 3). Lighting lives on the paper, so the field is written in board coordinates. The camera's vignetting is
  radial in image coordinates: on the board it is a smooth function a cubic could follow, and within one view
  nothing tells the two apart. The bilinear part of a fall-off goes to the light (a tilted lamp makes it too),
  as the bilinear field always did; its curvature does not: the terms beyond bilinear are kept orthogonal to the
  view's ``rho^2`` (:func:`_radial_free`), so an even bowl or dome on the board (``~ s^2 + t^2`` for a centred
  view) stays the camera's, while saddles, one-sided curvature and the cubic terms are the paper's. The terms
  beyond bilinear carry a small ridge (:data:`LIGHT_RIDGE`) and are used only when the white squares are
  measured (not clipped) and the richer light predicts squares held out of its fit better
  (:func:`_richer_light_holds`); else the light stays bilinear.
- the **white paper margin** around the squares, per side (left, top, right, bottom, in squares, continuous): the
  first strong falling edge of the measured paper-ness ``r / (white L)`` outward from the squares' outer edge.
  The paper is rendered out to it, the frames' own mean (the plate) lies beyond.
- the **outliers** of the fit (:func:`_board_outliers`): regions where the frames are not the fitted board (a
  hand or a finger, a glint, a stain, the paper's edge where the print does not end as modelled), found in the
  flat-equivalent domain as departures from the fit beyond what is smooth in the image, grown into connected
  regions. The light is fitted again without them. Those that show evidence of something other than the
  camera (:func:`earned_outliers`: they change between the frames, or their colour is not the paper's) are the
  capture's mask (:class:`~lowcam.measure.compare.CaptureInputs`), left out of the comparison; the others stay in
  it, since a departure from the board may be the model's own failure. They come from the data and the profile the board is
  fitted through (in diagnosis, the diagnosed one), so every candidate is compared on the same pixels.

The fit is made in the profile's own "flat-equivalent render value" domain: the quiet profile (no noise, no
quantisation) is run once per profile on flat renders at :data:`FLAT_LEVELS`, and each measured mean pixel is
inverted through its own response curve (piecewise linear). Vignetting, the tone curve, the bit depth and the
gains of the profile are thereby camera effects kept out of the nuisances: they are common to all views and
come from the profile. The fit itself is then linear least squares (alternating between the field and the
black/white ratio, with outliers such as fingers on the board rejected), under a second per capture once the
profile's flat responses are cached.

Contents
--------
- :data:`FLAT_LEVELS`: the flat render values at which the profile's response is tabulated
- :data:`MAX_MARGIN`: the widest paper margin searched for, in squares
- :data:`OUTLIER_LEVEL`, :data:`OUTLIER_SIGMAS`: how far from the board fit an outlier departs
- :data:`LIGHT_TERMS`, :data:`LIGHT_RIDGE`, :data:`RICH_LIGHT_SUPPORT`: the illumination field's terms and when
  the terms beyond bilinear are used
- :data:`EARNED_MOTION`, :data:`EARNED_SHARE`, :data:`EARNED_CHROMA_DN`: the evidence an outlier region needs to be masked
- :func:`earned_outliers`: the outlier regions that show evidence of something other than the camera
- :class:`BoardNuisances`: the fitted paper white, black, illumination field, margins and outliers of one capture
- :func:`flat_response`: the quiet profile's per-pixel output (channel mean, DN) for flat renders, cached
- :data:`FALL_OFF_LEVELS`, :func:`patch_fall_off`: the share of each ColorChecker patch's light the profile passes
- :func:`board_coordinates`: per output pixel, the board coordinates (in squares) through the lens and the pose
- :func:`fit_board_nuisances`: white, black, illumination, margins and outliers from a capture's mean, pose and
  profile
- :func:`board_texture`: a printed chessboard with its paper margin, lit, and its pixel -> metre origin offset
- :func:`render_board_view`: a pinhole render (premultiplied RGBA, opaque on the paper) of a chessboard at a pose
- :func:`board_pose`: a ``target`` capture's board description and pose (through the profile's lens)
- :func:`fit_target`: a ``target`` capture's pose and nuisances, with one render-then-simulate pass
- :data:`COMPARED`: the share of a ColorChecker patch's cell compared
- :func:`colour_checker_view`: (ideal render, plate, mask) for a ``target = "colorchecker"`` capture
- :func:`ideal_from_target`: (ideal render, plate, mask) for a ``target`` capture, the board's pose and nuisances fitted

A ``colorchecker`` capture (:func:`colour_checker_view`) is rendered from the chart found in its frames
(:mod:`lowcam.colour_checker`): each patch's cell filled with its reference colour (linear Rec.709, D65) times one
exposure per capture, placed through the profile's lens; around it a grey at the frames' own flat-equivalent
level, so the model's noise covers the whole frame as the camera's does (the row-noise family is whole-frame).
Only the inner 40 % of each patch is compared (the mask), so the patches are the measurements. The exposure is
fitted on the neutral patches in the profile's flat-equivalent domain (as the board's white; then corrected by
one render-then-simulate pass), so the profile's tone curve and gains stay the camera's and a missing colour matrix or tone curve shows on the patches.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..captures import detect_target, parse_target
from ..colour_checker import (COLUMNS, NEUTRALS, ROWS, mark_clipped, patch_areas, patch_cells, read_colour_checker,
                              read_patches, reference_colours)
from ..errors import LowcamError
from ..pipeline import prefix_key, prepare, render_field_of_view, resume

#: Flat render values at which the profile's response is tabulated (denser where tone curves bend most).
FLAT_LEVELS = (0.0, 0.03, 0.08, 0.16, 0.3, 0.5, 0.75, 1.05, 1.5)
#: The widest white paper margin searched for around the squares, in squares.
MAX_MARGIN = 2.0
#: An outlier of the board fit departs from it by this much at least (paper whites, flat-equivalent) ...
OUTLIER_LEVEL = 0.08
#: ... and by this many robust sigmas of the fit's departures (:func:`_board_outliers`).
OUTLIER_SIGMAS = 5.0
#: An outlier region is masked when its pixels' temporal noise is this many times the frames' own at their level
#: (:func:`earned_outliers`) ...
EARNED_MOTION = 3.0
#: ... in this share of its pixels at least ...
EARNED_SHARE = 0.2
#: ... or its chroma departs from the paper's by this much (DN, and 4 robust sigmas).
EARNED_CHROMA_DN = 4.0
_RESPONSES: OrderedDict = OrderedDict()
_CHECKERS: OrderedDict = OrderedDict()  # id(frames) -> (frames, the ColorChecker read from them)
#: The share of a ColorChecker patch's cell (per side) compared: less than the calibration reads
#: (:data:`~lowcam.colour_checker.INNER`), since the lens bends the patches and the chain blurs their edges.
COMPARED = 0.4


#: The illumination polynomial's terms after the constant, as exponents (i, j) of ``s^i t^j``: the bilinear ones
#: first, then those of degree 2 and 3.
LIGHT_TERMS = ((1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 1), (1, 2), (3, 0), (0, 3))
_BILINEAR = 3
#: The ridge on the light's terms beyond the bilinear ones (per white sample; the terms' mean squares are ~0.1-0.3
#: over the board, so a term the white squares determine is shrunk by a few per cent only).
LIGHT_RIDGE = 0.01
#: The light beyond bilinear is fitted only where at least this share of the white squares' pixels is measured
#: (not clipped: clipped white squares do not tell the light), and where it predicts held-out squares better.
RICH_LIGHT_SUPPORT = 0.8


@dataclass
class BoardNuisances:
    """A board's nuisances. ``white``/``black``: render values of the paper at the board's centre;
    ``illumination``: the coefficients ``c_k`` of ``L = 1 + sum_k c_k s^i t^j`` over :data:`LIGHT_TERMS` (the
    first three: ``s``, ``t``, ``s t``; a shorter tuple leaves the later terms at 0) with ``s, t`` in -1..1
    across the squares; ``margins``: white paper beyond the squares (left, top, right, bottom) in squares;
    ``flipped``: the square at the first inner corner's top-left is white (the parity seen in the frames);
    ``outliers``: (H, W) bool, the output pixels where the frames are not the fitted board (an occluder, a
    reflection, the paper's edge where it is not modelled), or None when not looked for; ``paper``: (H, W) bool,
    the output pixels on the paper (with its margins), or None."""

    white: float = 0.9
    black: float = 0.1
    illumination: tuple = (0.0, 0.0, 0.0)
    margins: tuple = (1.0, 1.0, 1.0, 1.0)
    flipped: bool = False
    outliers: np.ndarray | None = field(default=None, repr=False)
    paper: np.ndarray | None = field(default=None, repr=False)

    def light(self, s, t):
        """The illumination field at board coordinates (s, t)."""
        out = 1.0
        for c, (i, j) in zip(self.illumination, LIGHT_TERMS):
            out = out + c * s ** i * t ** j
        return out


def flat_response(profile) -> np.ndarray:
    """(len(FLAT_LEVELS), H, W) float32: the quiet profile's output (mean of the channels, DN) for a flat opaque
    grey render at each of :data:`FLAT_LEVELS`. Cached per profile (its camera and effects)."""
    quiet = profile.quiet()
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


#: The flat render values between which :func:`patch_fall_off` reads the profile's gain (both well inside the
#: output's range, above a toe and below white).
FALL_OFF_LEVELS = (0.16, 0.5)


def patch_fall_off(profile, reading) -> np.ndarray:
    """(24,): the share of the light of each ColorChecker patch the profile passes to its output, relative to the
    patch that keeps the most: its vignetting and whatever else gains or loses light across the frame (the lens's
    stretching of the picture included), read over each patch's area (``reading``: its corners and centres, as
    :func:`lowcam.colour_checker.read_patches` reads it) as the slope of the quiet profile's flat response
    (:func:`flat_response`) between :data:`FALL_OFF_LEVELS`, its tone curve left out (the colour fit takes that
    along)."""
    curve = profile.effect("tone_curve")
    linear = profile.without("tone_curve") if curve is not None and curve.enabled else profile
    table = flat_response(linear)
    lo, hi = (FLAT_LEVELS.index(v) for v in FALL_OFF_LEVELS)
    slope = (table[hi] - table[lo]) / (FLAT_LEVELS[hi] - FLAT_LEVELS[lo])
    gain = read_patches(np.repeat(slope[..., None], 3, axis=2), reading.corners, -np.inf, np.inf,
                        reading.centres).mean[:, 0]
    return gain / gain.max()


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


def _light_basis(s, t, terms=LIGHT_TERMS) -> np.ndarray:
    """(N, 1 + len(terms)): the constant and ``s^i t^j`` for each term."""
    return np.column_stack([np.ones_like(s)] + [s ** i * t ** j for i, j in terms])


def _radial_free(basis: np.ndarray, rho2: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(K, K - 1): the light's coefficient vectors that keep the camera's radial fall-off out of it.

    In one view, a fall-off fixed in the image, ``1 + k2 rho^2 (+ ...)`` (``rho``: radius from the frame's centre
    over the half-diagonal, as :func:`lowcam.effects.vignetting.radial_vignetting` has it), is a smooth function on
    the paper that a cubic in ``(s, t)`` could follow, and nothing in the view tells the two apart. Its bilinear
    part is left to the light (as the bilinear field always did: a tilted lamp makes it too); the rest,
    ``rho^2_perp`` (orthogonal to the bilinear terms under the fit's ``weight``), is not: the higher terms'
    combination ``H a_h`` must be orthogonal to it, ``rho^2_perp^T W H a_h = 0``. The returned basis spans the
    bilinear coefficients and the null space of that 1 x (K - 4) constraint: a light fitted in it cannot take the
    fall-off's curvature (an even bowl or dome on the board, which a lamp's pool centred on it also makes, is
    therefore left to the camera too); it takes saddles, one-sided curvature and the cubic terms."""
    nb = 1 + _BILINEAR
    bil, high = basis[:, :nb], basis[:, nb:]
    sw = np.sqrt(weight)
    perp = rho2 - bil @ np.linalg.lstsq(bil * sw[:, None], rho2 * sw, rcond=None)[0]
    c = (perp * weight) @ high
    c /= max(float(np.linalg.norm(c)), 1e-12)
    free = np.linalg.svd(c[None, :])[2][1:].T
    out = np.zeros((basis.shape[1], nb + free.shape[1]))
    out[:nb, :nb] = np.eye(nb)
    out[nb:, nb:] = free
    return out


def _fit_light(r, basis, dark, iterations: int = 20, ridge=None):
    """Least squares of r = k (basis @ a), k = 1 on white and beta on black squares (the basis's first column the
    constant): alternating between the field (normal equations) and beta (closed form), outliers beyond 4 robust
    sigmas dropped twice (fingers, glints). ``ridge`` (per column, or None): ``ridge_k * a_k^2`` per white sample
    is added to the squared error, so a term the white squares do not determine (where they are clipped, say)
    stays near 0 rather than following the black squares alone. Returns (a, beta)."""
    n = basis.shape[1]
    ridge = np.zeros(n) if ridge is None else np.asarray(ridge, np.float64)
    keep = np.ones(r.size, bool)
    a, beta = np.zeros(n), 0.1
    a[0] = np.median(r[~dark])
    for rnd in range(3):
        w, b = keep & ~dark, keep & dark
        gw, gb = basis[w].T @ basis[w], basis[b].T @ basis[b]
        hw, hb = basis[w].T @ r[w], basis[b].T @ r[b]
        for _ in range(iterations):
            a = np.linalg.solve(gw + beta ** 2 * gb + np.diag(ridge * w.sum() + 1e-12), hw + beta * hb)
            beta = float(a @ hb / max(a @ gb @ a, 1e-12))
        if rnd < 2:
            resid = r - np.where(dark, beta, 1.0) * (basis @ a)
            mad = 1.4826 * np.median(np.abs(resid[keep])) + 1e-6
            keep = np.abs(resid) < 4 * mad
    return a, beta


def _richer_light_holds(r, bilinear, rich, dark, blocks) -> bool:
    """True when the light ``rich`` (basis columns; its first ``1 + 3`` the bilinear ones) predicts squares held
    out of its fit better than ``bilinear``: two-fold, the board split into blocks of 2 x 2 squares
    (``blocks``: True on one half), each half fitted (:func:`_fit_light`) and scored on the other by the median
    absolute error; the richer light must lower it by 2 % at least."""
    def held_out(basis):
        ridge = np.r_[np.zeros(1 + _BILINEAR), np.full(basis.shape[1] - 1 - _BILINEAR, LIGHT_RIDGE)]
        errors = []
        for fold in (blocks, ~blocks):
            if fold.sum() < 100 or (~fold).sum() < 100:
                return np.inf
            a, beta = _fit_light(r[fold], basis[fold], dark[fold], ridge=ridge)
            errors.append(np.abs(r[~fold] - np.where(dark[~fold], beta, 1.0) * (basis[~fold] @ a)))
        return float(np.median(np.concatenate(errors)))
    return held_out(rich) < 0.98 * held_out(bilinear)


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


def _board_outliers(rel: np.ndarray, detect: np.ndarray, dark: np.ndarray, square_px: float) -> np.ndarray:
    """(H, W) bool: the regions where the frames are not the fitted board.

    ``rel`` is the measured flat-equivalent value less the fitted board's, over the paper white there (H, W), looked
    at on ``detect`` (the squares' and margin's pixels away from every edge: blur and sharpening live at the edges,
    and they are the camera's). Per square colour (``dark`` or not), a cubic in image coordinates is fitted to
    ``rel`` robustly (from the median, points beyond the threshold left out, four times): what is smooth in the
    image (the camera's fall-off, a haze on the black squares) stays with the camera. A seed departs from it by
    more than :data:`OUTLIER_LEVEL` paper whites and :data:`OUTLIER_SIGMAS` robust sigmas; a region is the pixels
    departing by half of that connected to at least ``(square_px / 6)^2`` seeds (one pixel's noise or a JPEG block
    is not an occluder), grown over the edges between the squares (a dilation and closing by 4 px)."""
    h, w = rel.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xn, yn = (xx - (w - 1) / 2) / (w / 2), (yy - (h - 1) / 2) / (w / 2)
    seeds, weak = np.zeros(rel.shape, bool), np.zeros(rel.shape, bool)
    for cls in (dark, ~dark):
        sel = detect & cls
        if sel.sum() < 50:
            continue
        basis = np.column_stack([xn[sel] ** i * yn[sel] ** j for i in range(4) for j in range(4 - i)])
        e = rel[sel].astype(np.float64)
        d = e - np.median(e)
        for k in range(5):
            if k:
                d = e - basis @ np.linalg.lstsq(basis[keep], e[keep], rcond=None)[0]
            thr = max(OUTLIER_SIGMAS * 1.4826 * float(np.median(np.abs(d if k == 0 else d[keep]))), OUTLIER_LEVEL)
            keep = np.abs(d) < thr
        seeds[sel], weak[sel] = np.abs(d) >= thr, np.abs(d) >= thr / 2
    if not seeds.any():
        return seeds
    n, labels = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
    count = np.bincount(labels[seeds], minlength=n)
    count[0] = 0
    region = (count >= max(10.0, (square_px / 6) ** 2))[labels]
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9))
    region = cv2.dilate(region.astype(np.uint8), disc)
    return cv2.morphologyEx(region, cv2.MORPH_CLOSE, disc) > 0


def earned_outliers(outliers: np.ndarray, frames: np.ndarray, paper: np.ndarray) -> tuple[np.ndarray, list[dict]]:
    """The outlier regions (:func:`_board_outliers`) that show evidence of something other than the camera, and
    what each region showed: ``(earned (H, W) bool, [{"share_px", "evidence"}...])``, ``evidence`` "" when none.

    A departure from the fitted board may be the model's own failure (blur, sharpening, the print's edge), so a
    region is left out of the comparison only where the frames show that something else is there:

    - **it changes between the frames** of the capture: at least :data:`EARNED_SHARE` of its pixels have a
      temporal standard deviation :data:`EARNED_MOTION` times the median the frames' noise gives at their level
      elsewhere (binned by level; noise alone puts under 5 % of pixels there, even with two frames): a hand, a
      moving glint. The share, not the median, since a region is grown around what departs;
    - **its colour is not the board's**: the region's median chroma (R - G, B - G of the mean frame, DN) departs
      from the paper's (the median over ``paper``, (H, W) bool, outside the outliers) by :data:`EARNED_CHROMA_DN`
      and by 4 of the paper's robust sigmas (a finger, a coloured stain); a grey camera shows no colour, so this
      never fires there.

    A mask the set gives (``mask`` in set.toml: a known target defect) is the user's evidence and is kept apart.
    """
    n, labels = cv2.connectedComponents(outliers.astype(np.uint8), connectivity=8)
    frames = np.asarray(frames)
    grey = frames.astype(np.float32).mean(-1)  # (N, H, W)
    mean = grey.mean(0)
    board = ~outliers
    noise_ratio = None
    if len(frames) > 1:
        std = grey.std(0, ddof=1)
        bins = np.clip((mean / 16).astype(int), 0, 15)
        expected = np.array([np.median(std[board & (bins == b)]) if (board & (bins == b)).sum() > 50 else np.nan
                             for b in range(16)])
        expected = np.where(np.isfinite(expected), expected, np.nanmedian(expected))
        noise_ratio = std / np.maximum(expected[bins], 0.3)
    rgb = frames.astype(np.float32).mean(0)
    chroma = np.stack([rgb[..., 0] - rgb[..., 1], rgb[..., 2] - rgb[..., 1]], -1)
    sheet = paper & board
    neutral = np.median(chroma[sheet], 0)
    spread = 1.4826 * np.median(np.abs(chroma[sheet] - neutral), 0)
    earned, regions = np.zeros_like(outliers), []
    for k in range(1, n):
        region = labels == k
        why = []
        moving = 0.0 if noise_ratio is None else float(np.mean(noise_ratio[region] >= EARNED_MOTION))
        if moving >= EARNED_SHARE:
            why.append(f"changes between frames ({moving:.0%} of it beyond {EARNED_MOTION:g} times the noise)")
        departs = np.abs(np.median(chroma[region], 0) - neutral)
        if np.any((departs >= EARNED_CHROMA_DN) & (departs >= 4 * spread)):
            why.append(f"colour unlike the paper's (chroma {departs.max():.1f} DN off)")
        if why:
            earned |= region
        regions.append({"share_px": float(region.mean()), "evidence": "; ".join(why)})
    return earned, regions


def fit_board_nuisances(profile, mean: np.ndarray, rvec, tvec, inner, square: float,
                        max_margin: float = MAX_MARGIN, max_samples: int = 30000, simulated=None,
                        previous: BoardNuisances | None = None) -> BoardNuisances:
    """Fit a board's paper white and black, its illumination field, its paper margins and its outliers to the
    mean of a capture's frames (H, W, 3, DN), given the board's pose (see the module docstring for the method).
    ``simulated`` (the quiet profile's frame of the board rendered with ``previous``) corrects the squares for
    what the chain does beyond a flat field (sharpening halos near the edges): measured x model / simulated.

    White, black and a bilinear light on the inner squares (the outer ones may be cut by the paper's edge), then
    the margins, then white, black and the light (:data:`LIGHT_TERMS` where they hold) on every square inside the
    paper, then the outliers of that fit (:func:`_board_outliers`) and the fit again without them. Pixels within
    3 px of a square's edge are left out (the camera's blur lives there); at most ``max_samples`` pixels are
    used."""
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
        dark_prev = (parity.ravel()[pick] != previous.flipped) & on_squares.ravel()[pick]
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

    h, w = u.shape
    rho2_map = ((np.arange(w)[None, :] - (w - 1) / 2) ** 2 + (np.arange(h)[:, None] - (h - 1) / 2) ** 2) / \
        (np.hypot(w, h) / 2) ** 2

    white_cores = cores[1] if even_dark else cores[0]

    def light_fit(region, beta0=None):
        """Bilinear light (``beta0`` None) or the cubic one, kept free of the radial fall-off (:func:`_radial_free`,
        its weights 1 on white and ``beta0^2`` on black squares) when it predicts held-out squares better
        (:func:`_richer_light_holds`)."""
        idx = np.flatnonzero((cores[0] | cores[1]) & ok & region)
        idx = idx[::max(1, len(idx) // max_samples)]
        s, t = _board_st(u.flat[idx], v.flat[idx], inner)
        dark = cores[0].flat[idx] == even_dark
        r = light_value.flat[idx].astype(np.float64)
        basis = _light_basis(s, t, LIGHT_TERMS[:_BILINEAR])
        if beta0 is not None:
            rich = _light_basis(s, t)
            free = _radial_free(rich, rho2_map.flat[idx], np.where(dark, beta0 ** 2, 1.0))
            blocks = (np.floor(u.flat[idx] / 2) + np.floor(v.flat[idx] / 2)).astype(np.int64) % 2 == 0
            measured = (white_cores & region & ok).sum() / max((white_cores & region).sum(), 1)
            if measured >= RICH_LIGHT_SUPPORT and _richer_light_holds(r, basis, rich @ free, dark, blocks):
                basis = rich @ free
        ridge = np.r_[np.zeros(1 + _BILINEAR), np.full(basis.shape[1] - 1 - _BILINEAR, LIGHT_RIDGE)]
        a, beta = _fit_light(r, basis, dark, ridge=ridge)
        if basis.shape[1] > 1 + _BILINEAR:
            a = free @ a
        if a[0] <= 0:
            raise LowcamError("the board's paper white could not be fitted (is the board lit?)")
        return BoardNuisances(white=float(a[0]), black=float(beta * a[0]),
                              illumination=tuple(float(c) for c in a[1:] / a[0]), flipped=not even_dark)

    nuis = light_fit(inner_sq)
    # the paper margin, side by side: paper-ness r / (white L) against the distance from the squares' edge;
    # inside the outer squares (the paper may cut into them) only their white ones count, and not within 3 px of
    # a black one (its blurred edge would make a falling edge where the squares end)
    ss, tt = _board_st(u, v, inner)
    paperness = value / np.maximum(nuis.white * nuis.light(ss, tt), 1e-6)
    light_sq = cv2.dilate((on_squares & (parity == even_dark)).astype(np.uint8), kernel) == 0
    sides = [(x0 - u, (v > y0 + 0.5) & (v < y1 - 0.5)), (y0 - v, (u > x0 + 0.5) & (u < x1 - 0.5)),
             (u - x1, (v > y0 + 0.5) & (v < y1 - 0.5)), (v - y1, (u > x0 + 0.5) & (u < x1 - 0.5))]
    margins = []
    for d, along in sides:
        m = along & ok & (d >= -1) & (d < max_margin) & light_sq
        margins.append(_margin(d[m], paperness[m], max_margin))
    left, top, right, bottom = margins
    beta0 = nuis.black / nuis.white
    paper = (u > x0 - left) & (u < x1 + right) & (v > y0 - top) & (v < y1 + bottom)
    nuis = light_fit(cv2.erode(paper.astype(np.uint8), kernel) > 0, beta0)
    # the outliers of this fit (occluders, the paper's edge), then the fit again without them
    dark_px = on_squares & (parity == even_dark)
    light = nuis.light(ss, tt)
    expected = np.where(dark_px, nuis.black, nuis.white) * light
    rel = (light_value - expected) / np.maximum(nuis.white * light, 1e-6)
    detect = ok & near & paper & np.logical_or.reduce(
        [cv2.erode((paper & part).astype(np.uint8), kernel) > 0 for part in (dark_px, on_squares & ~dark_px,
                                                                             ~on_squares)])
    square_px = float(np.sqrt(max(on_squares.sum(), 1) / ((inner[0] + 1) * (inner[1] + 1))))
    outliers = _board_outliers(rel, detect, dark_px, square_px)
    if outliers.any():
        nuis = light_fit(cv2.erode((paper & ~outliers).astype(np.uint8), kernel) > 0, beta0)
    nuis.margins = tuple(margins)
    nuis.outliers, nuis.paper = outliers, paper
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
    spec = parse_target(capture.target)
    if spec[0] != "checkerboard":
        raise LowcamError(f"{capture.where}: only checkerboard targets can be rendered so far")
    u8 = np.clip(np.rint(capture.mean), 0, 255).astype(np.uint8)
    found = detect_target(u8, spec)
    if found is None:
        raise LowcamError(f"{capture.where}: {capture.target} not found in the mean of its frames")
    obj, img = found
    x, y = profile.lens.undistort(img[:, 0], img[:, 1])
    ok, rvec, tvec = cv2.solvePnP(obj, np.column_stack([x, y]), np.eye(3), None)
    if not ok:
        raise LowcamError(f"{capture.where}: the board's pose could not be estimated")
    return spec, rvec.ravel(), tvec.ravel(), u8


def _refine_pose(profile, capture, spec, rvec, tvec, fitted, plate):
    """(rvec, tvec, the quiet profile's frame of the fitted board). One pass of render-then-simulate: the corners
    found in the quiet profile's view of the fitted board are
    where the camera chain moves them (half-pixel boxes, blur, aberration); the measured corners are moved back by
    that much and the pose solved again, so the chain's shift is not counted twice."""
    quiet = profile.quiet()
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
        raise LowcamError(f"{capture.where}: {e}") from None
    return spec, rvec, tvec, fitted


def _colour_checker_reading(capture):
    """The ColorChecker read from a capture's mean frame (found there once per capture and kept), a patch clipped
    in any frame marked so; a mean without the chart is refused naming the capture's frames."""
    frames = capture.frames
    kept = _CHECKERS.get(id(frames))
    if kept is not None and kept[0] is frames:
        return kept[1]
    names = capture.frame_names or [capture.where]
    if len(frames) == 1:
        reading = read_colour_checker(frames, names[:1], what=f"target colorchecker of {capture.where}")
    else:
        try:
            reading = read_colour_checker([capture.mean], [names[0]], what=f"target colorchecker of {capture.where}")
        except LowcamError as e:  # the mean of a moving chart: name the frames
            raise LowcamError(f"{capture.where}: the mean of the frames: {str(e).partition(': ')[2]}") from None
        mark_clipped(reading, frames)
    _CHECKERS[id(frames)] = (frames, reading)
    while len(_CHECKERS) > 16:
        _CHECKERS.popitem(last=False)
    return reading


def colour_checker_view(profile, capture, width: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ideal render, plate, mask) for a ``target = "colorchecker"`` capture (module docstring): the chart found
    in the frames (a frame without it is refused, naming it), its cells filled with the reference colours times
    the exposure fitted on the neutral patches, placed in a render ``width`` wide (default twice the output's)
    through the profile's lens, opaque grey around it at the frames' level; the mask keeps the inner
    :data:`COMPARED` of each patch whose
    reference colour is inside the working space's gamut (the cyan's red is below 0 in Rec.709)."""
    reading = _colour_checker_reading(capture)
    ref = reference_colours()
    h, w = profile.camera.height, profile.camera.width
    centres = reading.centres if reading.centres is not None else patch_cells(reading.corners, 0.0)[:, 0]
    # exposure: the neutral patches' flat-equivalent render values against their reference (least squares)
    table = flat_response(profile)
    xy = np.clip(np.round(centres).astype(int), 0, [w - 1, h - 1])
    column = table[:, xy[:, 1], xy[:, 0]]  # (K, 24)
    value, ok = _invert_response(column, reading.mean.mean(axis=1).astype(np.float32))
    neutral = np.zeros(len(ref), bool)
    neutral[list(NEUTRALS)] = True
    use = neutral & ok & ~reading.clipped
    if use.sum() < 2:
        raise LowcamError(f"{capture.where}: fewer than 2 of the ColorChecker's neutral patches are unclipped "
                          f"(lower the exposure)")
    level = ref.mean(axis=1)
    exposure = float((value[use] * level[use]).sum() / (level[use] ** 2).sum())
    # the render: cells in the pinhole view, the grid placed by a homography fitted to the undistorted centres
    width = width or 2 * w
    height = width * h // w
    half_x, _ = render_field_of_view(profile)
    f = width / (2 * half_x)
    x, y = profile.lens.undistort(centres[:, 0], centres[:, 1])
    render_xy = np.column_stack([np.asarray(x) * f + width / 2 - 0.5, np.asarray(y) * f + height / 2 - 0.5])
    grid = np.array([[k % COLUMNS + 0.5, k // COLUMNS + 0.5] for k in range(len(ref))], np.float32)
    hom, _ = cv2.findHomography(grid, render_xy.astype(np.float32))
    cell = 32
    colours = np.clip(ref * exposure, 0.0, None).astype(np.float32)
    chart = np.repeat(np.repeat(colours.reshape(ROWS, COLUMNS, 3), cell, axis=0), cell, axis=1)
    to_grid = np.diag([1.0 / cell, 1.0 / cell, 1.0])
    shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # pixel centres
    m = hom @ to_grid @ shift
    # around the chart, the scene is grey at the frames' own flat-equivalent level (never compared: the mask),
    # so the simulated frames carry the camera's noise there as the measured ones do (the row noise is whole-frame)
    around, _ = _invert_response(table.reshape(len(table), -1), capture.mean.mean(axis=2).ravel().astype(np.float32))
    around = cv2.resize(around.reshape(h, w).astype(np.float32), (width, height), interpolation=cv2.INTER_LINEAR)
    cover = cv2.warpPerspective(np.ones(chart.shape[:2], np.float32), m, (width, height), flags=cv2.INTER_LINEAR,
                                borderValue=0)[..., None]
    out = np.ones((height, width, 4), np.float32)
    out[..., :3] = cv2.warpPerspective(chart, m, (width, height), flags=cv2.INTER_NEAREST, borderValue=0) * cover + \
        np.clip(around, 0.0, None)[..., None] * (1.0 - cover)
    # one render-then-simulate pass: the neutral patches of the quiet profile's frame of this render, against
    # the measured ones (both flat-equivalent), correct the exposure for what the chain does between them
    quiet = profile.quiet()
    sim = read_patches(resume(prepare(out, quiet), 0, 0, quiet).astype(np.float64), reading.corners,
                       centres=reading.centres)
    v_sim, ok_sim = _invert_response(column, sim.mean.mean(axis=1).astype(np.float32))
    again = use & ok_sim & (v_sim > 0)
    if again.sum() >= 2:
        gain = float((value[again] * v_sim[again]).sum() / (v_sim[again] ** 2).sum())
        out[..., :3] = np.where(cover > 0, out[..., :3] * gain, out[..., :3])
    mask = np.zeros((h, w), np.uint8)
    for k, poly in enumerate(patch_areas(reading.corners, reading.centres, COMPARED)):
        if (ref[k] > 0).all() and not reading.clipped[k]:
            cv2.fillConvexPoly(mask, np.round(poly).astype(np.int32), 1)
    u8 = np.clip(np.rint(capture.mean), 0, 255).astype(np.uint8)
    return out, u8, mask > 0


def ideal_from_target(profile, capture, nuisances: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(ideal render, plate, mask of compared pixels or None) for a ``target`` capture: the board's pose from the
    frames through the profile's lens (:func:`board_pose`), its nuisances fitted (:func:`fit_board_nuisances`;
    ``nuisances=False``: a one-square white border and the 95th/5th percentiles of the green mean inside the
    corners' hull as white and black, the former behaviour, kept for comparison, and no mask), the frames' own mean
    as the plate around the paper, and the mask: False on the board fit's outliers (None when there are none).
    A ``colorchecker`` capture is :func:`colour_checker_view`'s."""
    if parse_target(capture.target)[0] == "colorchecker":
        return colour_checker_view(profile, capture)
    spec, rvec, tvec, u8 = board_pose(profile, capture)
    if nuisances:
        _, rvec, tvec, fitted = fit_target(profile, capture)
        earned = None if fitted.outliers is None else earned_outliers(fitted.outliers, capture.frames,
                                                                         fitted.paper)[0]
        mask = None if earned is None or not earned.any() else ~earned
        return render_board_view(profile, rvec, tvec, spec[1], spec[2], nuisances=fitted, px_per_square=120), u8, mask

    img = detect_target(u8, spec)[1]
    hull = cv2.convexHull(img.astype(np.float32)).astype(np.int32)
    inside = np.zeros(u8.shape[:2], np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    values = capture.mean[..., 1][inside > 0]
    white, black = np.percentile(values, 95) / 255.0, np.percentile(values, 5) / 255.0
    return render_board_view(profile, rvec, tvec, spec[1], spec[2], white=white, black=black), u8, None
