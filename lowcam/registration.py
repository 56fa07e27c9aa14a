"""Frame-to-frame registration of footage: what lets temporal statistics see a moving camera.

Two frames of a still scene differ by noise alone. A camera that pans moves the scene across the frame, and the
difference of two frames is then mostly the scene; people walking through a fixed camera's view move part of it.
Each pair of frames is registered by a homography: Shi-Tomasi corners [Shi1994] of the first frame tracked into
the second by pyramidal Lucas-Kanade [Bouguet2000], kept where tracking back returns within
:data:`FORWARD_BACKWARD_PX`, and a homography fitted to them by RANSAC [Fischler1981] (OpenCV). Where the inlier
tracks scatter about a shift by whole pixels (none, else their median displacement rounded) no more than
:data:`STILL_RATIO` times they scatter about that homography (median against median), the pair is that shift:
the identity for a still pair (a homography would fit the tracker's noise, or a flat scene's aperture-bound
tracks), a whole-pixel translation for a digital pan or a crop moved over a larger frame (a homography's
perspective terms, fitted to the tracker's noise, would move the corners by a tenth of a pixel, and the pixels
compared would be read off by that much). A pair with fewer than :data:`MIN_INLIERS` consistent tracks (a flat
scene) keeps the identity unregistered: only its flat pixels are compared, where a small motion changes nothing.
A gyro log would give a rotating camera's homography ``K R K^-1`` [Hartley2004], but on the phone-gyro-video clip it predicts the tracked
corners to a median 1.34 px (:mod:`lowcam.motion`), far above the tenth of a pixel the difference needs, and
footage read with a gyro knows neither its lens's K nor the gyro's axes: the frames register themselves.

The second frame is read at the first one's pixels by **nearest-neighbour** sampling: every value compared is one
of the frame's own pixels, so the noise keeps its variance and its spatial correlation (bilinear interpolation at
half a pixel averages two or four neighbours and would shrink white noise's variance by a factor of 2 to 4, less
for noise that demosaicing or a codec has already correlated). The scene's offset left by rounding (at most half a
pixel per axis) is taken out to first order, ``b(p) ~ b(n) + grad b(n) . (p - n)``, with the gradient of the
frame smoothed by a Gaussian of :data:`GRADIENT_SIGMA_PX` (the noise it adds is a few per cent of the noise
variance). A pixel is compared only where

- both frames see it (and neither is clipped below :data:`DARK_DN` or above :data:`SATURATED_DN`);
- the misalignment left (px) times the local gradient (DN/px, of the first frame's grey smoothed by
  :data:`MASK_SIGMA_PX`, which the noise itself barely steepens: a mask the noise chose would keep its quieter
  pixels) stays below :data:`GRADIENT_SHARE` of the noise's standard deviation (a first, robust estimate on the
  flattest pixels), so the misregistered scene adds at most ``GRADIENT_SHARE^2`` of the noise variance there. The
  misalignment is the registration's own error (``eps``: the RANSAC inliers' reprojection error over the square
  root of the inliers per degree of freedom, at least :data:`MIN_ERROR_PX`; locally, where the tracks fit the
  homography worse than the inliers typically do, by that excess: a rolling shutter bends the frame, near
  objects show parallax, a moving object moves) plus the rounding offset ``|p - n|`` (the first-order correction
  takes out its smooth part, not fine texture the smoothed gradient misses: on sub-pixel pans of scikit-image's
  photographs, leaving it out read up to 20 % more noise);
- the difference, averaged over a Gaussian window of :data:`STRUCTURE_SIGMA_PX`, lies within
  :data:`STRUCTURE_LIMIT` robust standard deviations of that average over the frame (noise averages away; a
  moving object, parallax or a lighting change does not), grown by :data:`STRUCTURE_GROW_PX`.

Contents
--------
- :data:`FORWARD_BACKWARD_PX`, :data:`MIN_INLIERS`, :data:`RANSAC_PX`, :data:`STILL_RATIO`: the tracking's
  acceptance, and when it says the pair holds still
- :data:`GRADIENT_SIGMA_PX`, :data:`MASK_SIGMA_PX`, :data:`MIN_ERROR_PX`, :data:`ERROR_CELL_PX`,
  :data:`GRADIENT_SHARE`: the first-order correction and the gradient mask
- :data:`STRUCTURE_SIGMA_PX`, :data:`STRUCTURE_LIMIT`, :data:`STRUCTURE_GROW_PX`: the moving-object mask
- :data:`DARK_DN`, :data:`SATURATED_DN`: clipped values left out
- :class:`Registration`: one pair's homography, how many tracks agreed with it and its error (px)
- :func:`register_pair`: the homography taking frame ``a``'s pixels to frame ``b``'s
- :class:`RegisteredPairs`: registered differences of frame pairs on the first frames' grids (NaN where not
  compared), sliceable like a stack of frames
- :func:`registered_difference`: one pair's level and difference (DN), NaN where not compared
- :data:`PAIR_GAP`, :data:`GAP_GAIN_PX`: how many frames ahead a pair's second frame may lie, and how much smaller
  a farther frame's rounding offset must be for it to be paired instead
- :func:`rounding_offset`: the sub-pixel offset (px) nearest-neighbour sampling leaves under a homography, and
  how much it varies over the frame
- :func:`register_frames`: :class:`RegisteredPairs` of frame pairs of a shot, each with the frame (of the next
  few) that nearest-neighbour sampling reads most exactly
- :data:`GRID_WINDOW`, :data:`GRID_CHAIN_PX`: how many frames ahead a block coder's grid is looked for, and how
  near a chain of registrations must come to it (px)
- :func:`grid_shift`: whether a registration is a whole-pixel shift by a multiple of a coder's grid
- :func:`register_on_grid`: :class:`RegisteredPairs` of frame pairs a multiple of a coder's grid apart

References
----------
- [Shi1994] J. Shi and C. Tomasi, "Good Features to Track", CVPR 1994, 593-600.
- [Bouguet2000] J.-Y. Bouguet, "Pyramidal Implementation of the Lucas Kanade Feature Tracker", Intel Corporation,
  Microprocessor Research Labs, 2000 (OpenCV's calcOpticalFlowPyrLK).
- [Fischler1981] M. A. Fischler and R. C. Bolles, "Random Sample Consensus", Communications of the ACM 24(6),
  381-395, 1981.
- [Hartley2004] R. Hartley and A. Zisserman, Multiple View Geometry in Computer Vision, 2nd ed., 2004, ch. 4
  (the homography between two views of a plane or of a rotating camera).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

FORWARD_BACKWARD_PX = 0.5
MIN_INLIERS = 12
RANSAC_PX = 1.0
STILL_RATIO = 1.5
GAP_GAIN_PX = 0.05
PAIR_GAP = 3
GRID_WINDOW = 24
GRID_CHAIN_PX = 0.5
GRADIENT_SIGMA_PX = 0.7
MASK_SIGMA_PX = 1.5
MIN_ERROR_PX = 0.03
ERROR_CELL_PX = 32
GRADIENT_SHARE = 0.3
STRUCTURE_SIGMA_PX = 2.0
STRUCTURE_LIMIT = 4.0
STRUCTURE_GROW_PX = 3
DARK_DN = 4.0
SATURATED_DN = 250.0


@dataclass
class Registration:
    """``H``: 3x3 homography taking frame a's pixel coordinates (x right, y down, centres on integers) to frame
    b's; ``tracks``: corners tracked both ways; ``inliers``: those RANSAC kept; ``error_px``: the homography's
    error at a typical pixel (px); ``registered``: whether the tracks determined it (else the identity);
    ``motion_px``: the largest displacement (px) of the frame's corners and centre under ``H`` (NaN: unknown);
    ``local_error_px``: a coarse map of :data:`ERROR_CELL_PX` cells, how much worse than the inliers' the tracks
    there fit ``H`` (px): a rolling shutter's bend, parallax or a moving object the one homography misses."""

    H: np.ndarray
    tracks: int
    inliers: int
    error_px: float
    registered: bool
    motion_px: float = float("nan")
    local_error_px: np.ndarray | None = None


def _grey8(frame: np.ndarray) -> np.ndarray:
    f = np.asarray(frame, np.float32)
    g = f.mean(axis=2) if f.ndim == 3 else f
    return np.clip(np.rint(g), 0, 255).astype(np.uint8)


def register_pair(a: np.ndarray, b: np.ndarray, max_corners: int = 500) -> Registration:
    """The homography taking frame ``a``'s pixels to frame ``b``'s (frames (H, W, 3) or (H, W), DN), from
    corners tracked forward and back (module docstring). Too few consistent tracks: the identity, not
    ``registered``."""
    ga, gb = _grey8(a), _grey8(b)
    identity = Registration(np.eye(3), 0, 0, float("inf"), False, float("nan"))
    p0 = cv2.goodFeaturesToTrack(ga, max_corners, 0.01, 8, blockSize=7)
    if p0 is None or len(p0) < MIN_INLIERS:
        return identity
    lk = dict(winSize=(21, 21), maxLevel=4, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.01))
    p1, st, _ = cv2.calcOpticalFlowPyrLK(ga, gb, p0, None, **lk)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(gb, ga, p1, None, **lk)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
                                                   < FORWARD_BACKWARD_PX)
    if ok.sum() < MIN_INLIERS:
        return Registration(np.eye(3), int(ok.sum()), 0, float("inf"), False, float("nan"))
    src, dst = p0[ok].reshape(-1, 2), p1[ok].reshape(-1, 2)
    H, inl = cv2.findHomography(src, dst, cv2.RANSAC, RANSAC_PX, maxIters=2000, confidence=0.999)
    if H is None or inl is None or inl.sum() < MIN_INLIERS:
        return Registration(np.eye(3), int(ok.sum()), 0, float("inf"), False, float("nan"))
    inl = inl.ravel().astype(bool)
    # refit on the inliers by least squares (RANSAC's minimal-sample model is noisier)
    H, _ = cv2.findHomography(src[inl], dst[inl], 0)
    H = H / H[2, 2]
    residual = np.linalg.norm(cv2.perspectiveTransform(src[None], H)[0] - dst, axis=1)
    for shift in (np.zeros(2), np.rint(np.median(dst[inl] - src[inl], axis=0))):  # still first
        about_shift = np.linalg.norm(dst - src - shift, axis=1)
        if np.median(about_shift[inl]) <= STILL_RATIO * np.median(residual[inl]):
            # the tracks move by whole pixels as far as their scatter tells (none: still): a homography would fit
            # their noise
            H = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]])
            residual = about_shift
            break
    rms = float(np.sqrt(np.mean(residual[inl] ** 2)))
    error = max(rms * np.sqrt(8.0 / inl.sum()), MIN_ERROR_PX)
    h, w = ga.shape
    probe = np.float32([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]])
    motion = float(np.linalg.norm(cv2.perspectiveTransform(probe[None], H)[0] - probe, axis=1).max())
    return Registration(H, int(ok.sum()), int(inl.sum()), error, True, motion,
                        _local_error(src, residual - float(np.median(residual[inl])), (h, w)))


def _local_error(points: np.ndarray, excess: np.ndarray, shape) -> np.ndarray:
    """(rows, cols) map of :data:`ERROR_CELL_PX` cells: the median excess residual (px) of the tracks in each cell
    over the inliers' typical one (the tracker's own noise), at least 0; a cell without tracks takes its nearest
    cell's value."""
    h, w = shape
    rows, cols = -(-h // ERROR_CELL_PX), -(-w // ERROR_CELL_PX)
    cell = (np.clip(points[:, 1] // ERROR_CELL_PX, 0, rows - 1) * cols
            + np.clip(points[:, 0] // ERROR_CELL_PX, 0, cols - 1)).astype(np.intp)
    out = np.full(rows * cols, np.nan, np.float32)
    for c in np.unique(cell):
        out[c] = max(float(np.median(excess[cell == c])), 0.0)
    out = out.reshape(rows, cols)
    empty = ~np.isfinite(out)
    if empty.all():
        return np.zeros((rows, cols), np.float32)
    if empty.any():  # the nearest measured cell's value
        _, labels = cv2.distanceTransformWithLabels(empty.astype(np.uint8), cv2.DIST_L2, 5,
                                                     labelType=cv2.DIST_LABEL_PIXEL)
        ys, xs = np.nonzero(~empty)
        value = np.zeros(labels.max() + 1, np.float32)
        value[labels[ys, xs]] = out[ys, xs]
        out = value[labels]
    return out


@dataclass
class RegisteredPairs:
    """Registered differences of frame pairs, each on its first frame's pixel grid: ``level`` (P, H, W, C), the
    mean of the two frames (DN), and ``diff`` (P, H, W, C), first frame less the registered second (DN); both NaN
    where the pixel is not compared (not seen by both, clipped, too steep for the registration's error, or moving).
    ``registrations``: each pair's :class:`Registration` (``[]`` for a slice); ``pairs``: the frame numbers
    paired. Slicing ``pairs[:, rows, cols]`` cuts both arrays, as a stack of frames is cut into tiles."""

    level: np.ndarray
    diff: np.ndarray
    registrations: list
    pairs: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.level)

    def __getitem__(self, key) -> "RegisteredPairs":
        return RegisteredPairs(self.level[key], self.diff[key], [])

    def select(self, pairs) -> "RegisteredPairs":
        """The pairs numbered ``pairs`` (a list of indices), with their registrations."""
        pairs = list(pairs)
        return RegisteredPairs(self.level[pairs], self.diff[pairs], [self.registrations[k] for k in pairs],
                               [self.pairs[k] for k in pairs] if self.pairs else [])

    @property
    def compared(self) -> float:
        """The share of pixels compared (0..1)."""
        return float(np.isfinite(self.diff[..., 0]).mean()) if self.diff.size else 0.0


def _noise_scale(d: np.ndarray) -> float:
    """A robust standard deviation (DN) of the finite values of ``d`` (1.4826 MAD)."""
    v = d[np.isfinite(d)]
    if v.size < 16:
        return float("nan")
    return float(1.4826 * np.median(np.abs(v - np.median(v))))


def registered_difference(a: np.ndarray, b: np.ndarray, reg: Registration) -> tuple[np.ndarray, np.ndarray]:
    """(level, diff), each (H, W, C) float32 DN on frame ``a``'s grid: ``(a + b')/2`` and ``a - b'``, where
    ``b'`` is frame ``b`` read at ``reg.H``'s image of each pixel by nearest neighbour with the first-order
    correction, NaN where the pixel is not compared (module docstring)."""
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    h, w, c = a.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if reg.registered:
        px, py = cv2.split(cv2.perspectiveTransform(cv2.merge([xx, yy]), reg.H))
    else:
        px, py = xx, yy
    nx, ny = np.rint(px), np.rint(py)
    seen = (nx >= 1) & (nx <= w - 2) & (ny >= 1) & (ny <= h - 2)
    dx, dy = px - nx, py - ny

    def nearest(img):  # img at (nx, ny): each value one of its own pixels
        out = cv2.remap(img, nx, ny, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return out[..., None] if out.ndim == 2 else out

    soft = cv2.GaussianBlur(b, (0, 0), GRADIENT_SIGMA_PX)
    bn = nearest(b)
    warped = (bn + nearest(cv2.Sobel(soft, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)) * dx[..., None]
              + nearest(cv2.Sobel(soft, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)) * dy[..., None])
    diff = a - warped
    level = 0.5 * (a + warped)
    keep = seen & ((a > DARK_DN) & (a < SATURATED_DN) & (bn > DARK_DN) & (bn < SATURATED_DN)).all(axis=2)
    # the flattest pixels give a first noise scale; steeper pixels are kept while the registration's error times
    # their gradient stays a small share of it
    steep = cv2.GaussianBlur(a.mean(axis=2), (0, 0), MASK_SIGMA_PX)  # smooth enough that noise barely steepens it
    grad = np.hypot(cv2.Sobel(steep, cv2.CV_32F, 1, 0, ksize=1, scale=0.5),
                    cv2.Sobel(steep, cv2.CV_32F, 0, 1, ksize=1, scale=0.5))
    if reg.registered:  # the homography's own error, and where the tracks say it misses by more
        eps = np.full((h, w), reg.error_px, np.float32)
        if reg.local_error_px is not None:
            local = cv2.resize(reg.local_error_px, (reg.local_error_px.shape[1] * ERROR_CELL_PX,
                                                    reg.local_error_px.shape[0] * ERROR_CELL_PX),
                               interpolation=cv2.INTER_NEAREST)[:h, :w]
            eps = np.maximum(eps, local)
    else:  # unregistered: up to half a pixel's motion may be missed
        eps = np.full((h, w), 0.5, np.float32)
    if keep.any():
        flat = keep & (grad <= np.quantile(grad[keep], 0.25))
        sigma0 = np.nanmedian([_noise_scale(diff[..., k][flat]) for k in range(c)]) / np.sqrt(2.0)
        if np.isfinite(sigma0) and sigma0 > 0:
            keep &= grad * (eps + np.hypot(dx, dy)) <= GRADIENT_SHARE * max(sigma0, 0.25)
    # structure: the difference averaged over a window stays near 0 where only noise differs
    if keep.any():
        filled = np.where(keep[..., None], diff, 0.0).astype(np.float32)
        weight = cv2.GaussianBlur(keep.astype(np.float32), (0, 0), STRUCTURE_SIGMA_PX)
        mean = cv2.GaussianBlur(filled, (0, 0), STRUCTURE_SIGMA_PX).reshape(h, w, c)
        mean = mean / np.maximum(weight, 1e-3)[..., None]
        moving = np.zeros((h, w), bool)
        for k in range(c):
            m = mean[..., k]
            scale = _noise_scale(m[keep])
            if np.isfinite(scale) and scale > 0:
                moving |= keep & (np.abs(m - np.median(m[keep])) > STRUCTURE_LIMIT * scale)
        if moving.any():
            size = 2 * STRUCTURE_GROW_PX + 1
            moving = cv2.dilate(moving.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
            keep &= ~moving
    diff[~keep] = np.nan
    level[~keep] = np.nan
    return level, diff


def rounding_offset(H: np.ndarray, shape, step: int = 16) -> tuple[float, float]:
    """(mean, spread) of the offsets (px) between the images under ``H`` of a grid of pixels (every ``step`` px of
    a frame of ``shape`` (rows, cols)) and the pixels nearest them: what nearest-neighbour sampling leaves to the
    first-order correction (0 for the identity or a whole-pixel shift). ``spread``: their standard deviation per
    axis, about 0.29 px (uniform) where a rotation or zoom varies them over the frame, near 0 for a shift."""
    yy, xx = np.mgrid[0:shape[0]:step, 0:shape[1]:step].astype(np.float32)
    p = cv2.perspectiveTransform(np.stack([xx, yy], -1).reshape(1, -1, 2), np.asarray(H, np.float64))[0]
    off = p - np.rint(p)
    return float(np.linalg.norm(off, axis=1).mean()), float(off.std(axis=0).max())


def _frame(frames, i) -> np.ndarray:
    """Frame ``i`` of ``frames`` as float32 (H, W, C)."""
    f = np.asarray(frames[i], np.float32)
    return f[..., None] if f.ndim == 2 else f


def _consecutive(frames, cache: dict | None):
    """``step(i)``: frame ``i`` registered with frame ``i + 1``, each pair once (kept in ``cache``, a dict that
    callers registering the same frames may share)."""
    cache = {} if cache is None else cache

    def step(i):
        if i not in cache:
            cache[i] = register_pair(_frame(frames, i), _frame(frames, i + 1))
        return cache[i]
    return step


def _pairs_of(frames, found) -> RegisteredPairs:
    """:class:`RegisteredPairs` of ``found``, a list of ``(i, j, registration)``."""
    levels, diffs = [], []
    for i, j, reg in found:
        level, diff = registered_difference(_frame(frames, i), _frame(frames, j), reg)
        levels.append(level)
        diffs.append(diff)
    if not levels:
        empty = np.zeros((0,) + _frame(frames, 0).shape, np.float32)
        return RegisteredPairs(empty, empty.copy(), [])
    return RegisteredPairs(np.stack(levels), np.stack(diffs), [r for _, _, r in found],
                           [(i, j) for i, j, _ in found])


def register_frames(frames, starts=None, max_gap: int = PAIR_GAP, cache: dict | None = None) -> RegisteredPairs:
    """:class:`RegisteredPairs` of frames (a stack (T, H, W, C) DN, or any sequence of frames), one pair from
    each of ``starts`` (default: every frame but the last), registered (:func:`register_pair`) and differenced
    (:func:`registered_difference`). Each start is paired with the next frame, or (``max_gap`` > 1) with the
    one of the next ``max_gap`` frames whose registration (the consecutive ones chained) leaves the smallest
    :func:`rounding_offset`, where that is :data:`GAP_GAIN_PX` smaller than the next frame's: a camera panning
    1.37 px a frame is compared across 3 frames (4.11 px), where nearest-neighbour sampling is nearly exact. (Only
    where the motion is about a shift, its offsets much the same over the frame; a rotation's vary anyway.)
    ``pairs`` of the result lists the frame numbers paired; ``cache``: consecutive registrations to share
    (:func:`register_on_grid`)."""
    count = len(frames)
    starts = list(range(count - 1)) if starts is None else [i for i in starts if i + 1 < count]
    step = _consecutive(frames, cache)
    found = []
    for i in starts:
        reg, j = step(i), i + 1
        shape = np.shape(frames[i])[:2]
        best, spread = rounding_offset(reg.H, shape)
        if max_gap > 1 and reg.registered and best > GAP_GAIN_PX and spread < 0.15:  # a shift: another may fit
            H = reg.H
            for k in range(i + 2, min(i + max_gap, count - 1) + 1):
                nxt = step(k - 1)
                if not nxt.registered:
                    break
                H = nxt.H @ H
                score = rounding_offset(H, shape)[0]
                if score < best - GAP_GAIN_PX:
                    best, j = score, k
            if j > i + 1:
                direct = register_pair(_frame(frames, i), _frame(frames, j))
                reg = direct if direct.registered else reg
                j = j if direct.registered else i + 1
        found.append((i, j, reg))
    return _pairs_of(frames, found)


def grid_shift(reg: Registration, grid_px: int) -> bool:
    """Whether ``reg`` moves the frame by a whole-pixel shift that is a multiple of ``grid_px`` on both axes, and
    not 0 (a still pair): a block coder's grid (JPEG's 8 px), placed alike in every frame, then falls on the same
    content in both frames."""
    H = reg.H
    shift = H[:2, 2]
    return bool(reg.registered and np.allclose(H[:2, :2], np.eye(2)) and np.allclose(H[2], [0, 0, 1])
                and np.any(shift != 0) and np.all(np.mod(shift, grid_px) == 0))


def register_on_grid(frames, starts, grid_px: int = 8, window: int = GRID_WINDOW,
                     cache: dict | None = None) -> RegisteredPairs:
    """:class:`RegisteredPairs` of frames (a stack (T, H, W, C) DN, or any sequence of frames) whose camera moved
    by whole multiples of ``grid_px`` between them (:func:`grid_shift`), at most one pair from each of
    ``starts``: the first of the next ``window`` frames that does. The consecutive registrations (``cache``,
    shared with :func:`register_frames`) are chained; where the chain moves the frame's corners and centre within
    :data:`GRID_CHAIN_PX` of a common multiple of the grid, the two frames are registered directly
    (:func:`register_pair`, which takes whole-pixel shifts as such) and paired where that registration is such a
    shift. The chain stops where a registration fails, where the motion stops being a shift (its corners move
    apart by more than :data:`GRID_CHAIN_PX`: the camera rotates, tilts or zooms, and the grid falls differently
    on each part of the frame) or where the frames no longer share half their width or height. A JPEG's coding
    error of a moving scene changes with the grid's place on it; in such pairs it is the same content's on the
    same grid, and cancels in the difference as a still shot's does."""
    count = len(frames)
    step = _consecutive(frames, cache)
    h, w = _frame(frames, 0).shape[:2]
    probe = np.float32([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]])
    found = []
    for i in starts:
        H = np.eye(3)
        for j in range(i + 1, min(i + window, count - 1) + 1):
            reg = step(j - 1)
            if not reg.registered:
                break
            H = reg.H @ H
            move = cv2.perspectiveTransform(probe[None], H)[0] - probe
            mean = move.mean(axis=0)
            if np.abs(move - mean).max() > GRID_CHAIN_PX or abs(mean[0]) > w / 2 or abs(mean[1]) > h / 2:
                break
            near = grid_px * np.rint(mean / grid_px)
            if np.any(near != 0) and np.abs(mean - near).max() <= GRID_CHAIN_PX:
                direct = register_pair(_frame(frames, i), _frame(frames, j))
                if grid_shift(direct, grid_px):
                    found.append((i, j, direct))
                    break
    return _pairs_of(frames, found)
