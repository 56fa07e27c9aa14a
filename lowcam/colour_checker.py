"""The ColorChecker Classic (24 patches, 6 x 4) as a measurement target: its reference colours, the chart found in
a frame, and each patch's mean colour and the noise of that mean.

The reference colours are colour-science's ``"ColorChecker24 - After November 2014"`` chromaticities (X-Rite's
published values, CIE xyY under the chart's illuminant, ICC D50), adapted to the working space (linear Rec.709 /
sRGB primaries, D65; Bradford adaptation) as render values 0-1: the light a render would hold for the chart lit
by a white of 1. The chart is found by ``colour-checker-detection``'s segmentation (which needs the black gaps
between the patches); its quadrilateral is turned so that the neutral row (patches 19-24) is where the reference
puts it, judged by brightness, so a camera's colour matrix cannot mislead the orientation.

Each patch is read over the inner :data:`INNER` of its cell (away from the edges, the gaps and the chart's own
blur), centred on the patch as found (a lens bends the grid, which one homography cannot follow), rectified at
about one pixel per frame pixel. Its noise is the spread of the
means of 4x4 blocks over that area (the noise of the patch mean, spatially correlated noise such as a
demosaic's included), divided by the square root of the block count.

Contents
--------
- :data:`CHART`: the colour-science reference data the colours come from
- :data:`COLUMNS`, :data:`ROWS`: the chart's patch grid
- :data:`NEUTRALS`: the indices of the neutral patches (19-24: white to black)
- :data:`INNER`: the share of a patch's cell (per side) that is read
- :func:`reference_colours`: the 24 patches' colours, linear Rec.709 D65 render values (24, 3)
- :class:`PatchReading`: the patches' means, the noise of each mean, the pixels read and the clipped ones
- :func:`find_chart`: the chart's four corners (pixels) in a frame, or None
- :func:`locate_patches`: the chart's corners and each patch's centre (pixels) in a frame, or None
- :func:`read_patches`: each patch's mean and noise in a frame from the chart's corners (and patch centres)
- :func:`patch_cells`: each patch's cell corners (pixels) from the chart's corners
- :func:`patch_areas`: the area read of each patch (pixels), moved onto the patch's own centre
- :data:`MOVED_PX`: how far a frame of a static view may lie from the first
- :func:`read_colour_checker`: the patches of the chart in frames (found once, on the mean frame), every problem
  naming a frame
- :func:`mark_clipped`: mark the patches clipped in any of several frames

References
----------
- [Colour] colour-science, ``colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]`` (X-Rite's
  published L*a*b* D50 values for charts made after November 2014).
- [CCD] colour-checker-detection, ``detect_colour_checkers_segmentation`` (Colour Developers).
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from .errors import LowcamError

#: The colour-science reference data the colours come from.
CHART = "ColorChecker24 - After November 2014"
#: The patch grid: 6 columns, 4 rows; patch k (0-23) is at row k // 6, column k % 6, the first at the top-left
#: (dark skin), the neutral row at the bottom.
COLUMNS, ROWS = 6, 4
#: The neutral patches, white (0.95 reflectance) to black (0.03).
NEUTRALS = tuple(range(18, 24))
#: The share of a patch's cell (per side, from the cell's centre) that is read: the patch fills about 0.85 of its
#: cell, so 0.5 keeps well away from its edges even where the corners are a few per cent off.
INNER = 0.5
_BLOCK = 4  # pixels per side of the blocks whose means give the noise


@functools.lru_cache(maxsize=1)
def reference_colours() -> np.ndarray:
    """(24, 3): the patches' colours as linear Rec.709 / sRGB-primaries D65 render values (the chart under a white
    of 1), from colour-science's :data:`CHART` chromaticities under the chart's illuminant, Bradford-adapted.

    >>> grey = reference_colours()[18:]                 # the neutral row, white to black: near-grey, darkening
    >>> bool(np.all(np.ptp(grey, axis=1) < 0.06 * grey.mean(axis=1)) and np.all(np.diff(grey.mean(axis=1)) < 0))
    True
    """
    colour = _colour()
    data = colour.CCS_COLOURCHECKERS[CHART]
    xyy = np.array(list(data.data.values()), np.float64)
    xyz = colour.xyY_to_XYZ(xyy)
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], illuminant=data.illuminant,
                            chromatic_adaptation_transform="Bradford", apply_cctf_encoding=False)
    out = np.asarray(rgb, np.float64)
    out.setflags(write=False)
    return out


def _colour():
    try:
        import colour
    except ImportError:  # pragma: no cover - a dependency
        raise LowcamError("ColorChecker targets need colour-science (pip install colour-science)") from None
    return colour


@dataclass
class PatchReading:
    """The patches read from a chart: ``mean`` (24, 3) in the frames' units, ``noise`` (24, 3) the standard
    deviation of each mean, ``pixels`` (24,) how many pixels each mean is over, ``clipped`` (24,) True where a
    patch touches the frames' floor or ceiling (its mean is then not the light's), ``corners`` (4, 2) the chart's
    corners in the mean frame (pixels: top-left of patch 1, top-right, bottom-right, bottom-left), ``notes``
    (frames skipped)."""

    mean: np.ndarray
    noise: np.ndarray
    pixels: np.ndarray
    clipped: np.ndarray
    corners: np.ndarray
    centres: np.ndarray | None = None
    notes: list = field(default_factory=list)


def _detection_image(image: np.ndarray) -> np.ndarray:
    """A float image 0-1 for the detector (which encodes it for display itself): normalised by a high
    percentile."""
    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    top = float(np.percentile(img, 99.5)) or 1.0
    return np.clip(img / top, 0.0, 1.0)


def find_chart(image: np.ndarray) -> np.ndarray | None:
    """The ColorChecker's four corners (4, 2), pixels in ``image``, or None (:func:`locate_patches`)."""
    found = locate_patches(image)
    return None if found is None else found[0]


def locate_patches(image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The ColorChecker in ``image`` (H, W, 3; any units, linear or encoded): its four corners (4, 2), pixels, the
    outer corners of its patch grid, top-left (patch 1's corner) first, then clockwise; and each patch's centre
    (24, 2), pixels, as found (a lens's distortion bends the grid). None when not found.

    ``colour-checker-detection``'s segmenter finds the patches (and, in a view not too steep, the chart's
    bounding rectangle); grids are tried from that rectangle and from the patches' own lattice, each refined to
    the homography that puts its cell centres on the patches found (a perspective view is not a rectangle), and
    the grid and orientation kept are those whose brightness follows the reference best with the most patches
    found at their cells' centres (:func:`_orient`)."""
    try:
        from colour_checker_detection.detection.common import reformat_image
        from colour_checker_detection.detection.segmentation import (SETTINGS_SEGMENTATION_COLORCHECKER_CLASSIC,
                                                                     segmenter_default)
    except ImportError:  # pragma: no cover - a dependency
        raise LowcamError("ColorChecker targets need colour-checker-detection: pip install --no-deps "
                          "colour-checker-detection==0.2.1 (it asks for opencv-python, whose cv2 Lowcam's OpenCV "
                          "already is)") from None
    img = _detection_image(image)
    settings = dict(SETTINGS_SEGMENTATION_COLORCHECKER_CLASSIC)
    scale = img.shape[1] / settings["working_width"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            work = reformat_image(img, settings["working_width"], settings["interpolation_method"])
            found = segmenter_default(work, additional_data=True, **settings)
        except (cv2.error, ValueError, IndexError):
            return None
    centres = np.array([np.asarray(c, np.float64).reshape(-1, 2).mean(axis=0) for c in found.swatches])
    quads = []
    if len(found.rectangles):  # the detector's rectangle, its long side first
        rect = np.asarray(found.rectangles[0], np.float64).reshape(4, 2)
        quads.append(rect if np.linalg.norm(rect[1] - rect[0]) >= np.linalg.norm(rect[2] - rect[1])
                     else np.roll(rect, -1, axis=0))
    quads += _lattice_quads(centres)
    best, best_score = None, -np.inf
    for quad in quads:
        oriented, score = _orient(image, _fit_grid(quad, centres) * scale, centres * scale)
        if oriented is not None and score > best_score:
            best, best_score = oriented, score
    return None if best is None else (best, _patch_centres(best, centres * scale))


def _lattice_quads(centres: np.ndarray) -> list:
    """Grids that the patches found could be on (working pixels): their own lattice (the direction and spacing of
    neighbours), as many cells as they span, in every place within the 6 x 4 grid where patches are
    missing at its sides."""
    if len(centres) < 6:
        return []
    mean = centres.mean(axis=0)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    pitch = float(np.median(dist.min(axis=1)))
    # the lattice's direction: the neighbours' directions folded to 90 degrees (a square lattice)
    step = centres[np.argmin(dist, axis=1)] - centres
    theta = np.angle(np.exp(4j * np.arctan2(step[:, 1], step[:, 0])).mean()) / 4
    u = np.array([np.cos(theta), np.sin(theta)])
    v = np.array([-u[1], u[0]])
    s, t = (centres - mean) @ u, (centres - mean) @ v
    out = []
    for (su, sv, n_u, n_v) in ((u, v, COLUMNS, ROWS), (v, -u, COLUMNS, ROWS)):  # the chart lying or standing
        a_, b_ = (s, t) if su is u else (t, -s)
        span_a, span_b = np.ptp(a_), np.ptp(b_)
        na = int(np.clip(round(span_a / pitch) + 1, 1, n_u))
        nb = int(np.clip(round(span_b / pitch) + 1, 1, n_v))
        pa = span_a / (na - 1) if na > 1 else pitch
        pb = span_b / (nb - 1) if nb > 1 else pitch
        for i in range(n_u - na + 1):
            for j in range(n_v - nb + 1):
                o = mean + su * (a_.min() - (i + 0.5) * pa) + sv * (b_.min() - (j + 0.5) * pb)
                big_u, big_v = su * n_u * pa, sv * n_v * pb
                out.append(np.array([o, o + big_u, o + big_u + big_v, o + big_v]))
    return out


def _patch_centres(corners: np.ndarray, found: np.ndarray) -> np.ndarray:
    """(24, 2): each patch's centre, pixels: the patch found nearest its cell's centre (within 0.45 of a cell)
    where there is one, else the cell's centre moved as its found neighbours are (a lens bends the grid, which a
    homography cannot follow)."""
    h = _grid_homography(corners)
    grid = np.array([[k % COLUMNS + 0.5, k // COLUMNS + 0.5] for k in range(COLUMNS * ROWS)], np.float32)
    predicted = cv2.perspectiveTransform(grid[None], h)[0].astype(np.float64)
    offsets = np.full((len(grid), 2), np.nan)
    if len(found):
        uv = cv2.perspectiveTransform(np.asarray(found, np.float32)[None], np.linalg.inv(h))[0]
        for k, g in enumerate(grid):
            d = np.abs(uv - g).max(axis=1)
            if d.min() < 0.45:
                offsets[k] = found[int(np.argmin(d))] - predicted[k]
    known = np.isfinite(offsets[:, 0])
    for k in np.nonzero(~known)[0]:
        near = known & (np.abs(grid - grid[k]).max(axis=1) < 1.5)
        offsets[k] = offsets[near].mean(axis=0) if near.any() else 0.0
    return predicted + offsets


def _grid_homography(quad: np.ndarray):
    return cv2.getPerspectiveTransform(np.array([[0, 0], [COLUMNS, 0], [COLUMNS, ROWS], [0, ROWS]], np.float32),
                                       np.asarray(quad, np.float32))


def _fit_grid(quad: np.ndarray, centres: np.ndarray) -> np.ndarray | None:
    """The grid's corners refined so that its cell centres fall on the patches found (``centres``, pixels), by a
    homography over the patches matched to cells (twice: the first fit brings more patches into their cells)."""
    if len(centres) < 6:
        return quad
    for _ in range(3):
        h = _grid_homography(quad)
        uv = cv2.perspectiveTransform(centres[None].astype(np.float32), np.linalg.inv(h))[0]
        cell = np.floor(uv)
        near = (np.abs(uv - cell - 0.5).max(axis=1) < 0.3) & (cell[:, 0] >= 0) & (cell[:, 0] < COLUMNS) & \
            (cell[:, 1] >= 0) & (cell[:, 1] < ROWS)
        if near.sum() < 6:
            return quad
        fitted, _ = cv2.findHomography((cell[near] + 0.5).astype(np.float32), centres[near].astype(np.float32),
                                       cv2.RANSAC, 5.0)
        if fitted is None:
            return quad
        grid = np.array([[[0, 0], [COLUMNS, 0], [COLUMNS, ROWS], [0, ROWS]]], np.float32)
        quad = cv2.perspectiveTransform(grid, fitted)[0].astype(np.float64)
    return quad


def _orient(image: np.ndarray, quad: np.ndarray, found: np.ndarray) -> tuple[np.ndarray | None, float]:
    """The quadrilateral turned (0 or 180 degrees; 90 where the chart stands on its side; its corners' order
    reversed if need be) so that the patches' brightness follows the reference's best (log brightness,
    correlated): the neutral row at the bottom; and its score, that correlation plus the share of the patches
    ``found`` (pixels) that sit at their cells' centres (within 0.2 of a cell)."""
    ref = np.log(reference_colours().mean(axis=1))
    h = _grid_homography(quad)
    uv = cv2.perspectiveTransform(np.asarray(found, np.float32)[None], np.linalg.inv(h))[0] if len(found) else \
        np.zeros((0, 2))
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < COLUMNS) & (uv[:, 1] >= 0) & (uv[:, 1] < ROWS)
    centred = float(np.mean(inside & (np.abs(uv - np.floor(uv) - 0.5).max(axis=1) < 0.2))) if len(found) else 0.0
    best, best_score = None, -np.inf
    img = np.asarray(image, np.float64)
    for turn in range(8):  # four turns, and mirrored (a corner order the other way round)
        q = np.roll(quad if turn < 4 else quad[::-1], -turn, axis=0)
        means = _cell_means(img, q)
        if means is None:
            continue
        level = np.log(np.maximum(means.mean(axis=1), 1e-6 * max(float(means.max()), 1e-12)))
        score = float(np.corrcoef(level, ref)[0, 1]) if np.ptp(level) > 0 else -np.inf
        if score > best_score:
            best, best_score = q, score
    return best, best_score + centred


def patch_cells(corners: np.ndarray, inner: float = 1.0) -> np.ndarray:
    """(24, 4, 2): each patch's cell (``inner`` of it per side, about its centre), pixels, from the chart's corners
    (top-left, top-right, bottom-right, bottom-left)."""
    h = cv2.getPerspectiveTransform(np.array([[0, 0], [COLUMNS, 0], [COLUMNS, ROWS], [0, ROWS]], np.float32),
                                    np.asarray(corners, np.float32))
    out = []
    for k in range(COLUMNS * ROWS):
        cy, cx = k // COLUMNS + 0.5, k % COLUMNS + 0.5
        d = inner / 2
        square = np.array([[cx - d, cy - d], [cx + d, cy - d], [cx + d, cy + d], [cx - d, cy + d]], np.float32)
        out.append(cv2.perspectiveTransform(square[None], h)[0])
    return np.array(out, np.float64)


def patch_areas(corners: np.ndarray, centres: np.ndarray | None = None, inner: float = INNER) -> np.ndarray:
    """(24, 4, 2): the area read of each patch, pixels: ``inner`` of its cell (per side) from the chart's
    ``corners``, moved onto the patch's own centre where ``centres`` (24, 2) are given."""
    cells = patch_cells(corners, inner)
    if centres is None:
        return cells
    return cells + (np.asarray(centres, np.float64) - cells.mean(axis=1))[:, None, :]


def _cell_size(corners: np.ndarray) -> int:
    c = np.asarray(corners, np.float64)
    width = max(np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[2] - c[3]))
    height = max(np.linalg.norm(c[3] - c[0]), np.linalg.norm(c[2] - c[1]))
    return int(round(min(width / COLUMNS, height / ROWS)))


def _areas(image: np.ndarray, corners: np.ndarray, centres=None, inner: float = INNER):
    """Each patch's area read, rectified (nearest pixel, so values are the frame's own) at about one pixel per
    frame pixel: (side, side, C) arrays, NaN outside the frame; None where the cells are under 8 pixels."""
    cell = _cell_size(corners)
    if cell < 8:
        return None
    side = max(int(round(cell * inner)), 2)
    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    dst = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32)
    out = []
    for quad in patch_areas(corners, centres, inner):
        h = cv2.getPerspectiveTransform(quad.astype(np.float32), dst)
        a = cv2.warpPerspective(img, h, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                borderValue=np.nan)
        out.append(a if a.ndim == 3 else a[..., None])
    return out


def _cell_means(image: np.ndarray, corners: np.ndarray) -> np.ndarray | None:
    areas = _areas(image, corners)
    if areas is None:
        return None
    means = np.array([a.reshape(-1, a.shape[-1]).mean(axis=0) for a in areas])  # NaN: off the frame
    return None if not np.isfinite(means).all() else means


def read_patches(image: np.ndarray, corners: np.ndarray, floor: float = 0.0, ceiling: float = 255.0,
                 centres: np.ndarray | None = None) -> PatchReading:
    """Each patch's mean and the noise of that mean over the inner :data:`INNER` of its cell (module docstring)
    in ``image`` (H, W, 3), from the chart's ``corners`` (and each patch's ``centres`` where found); a patch with
    any pixel at ``floor`` or ``ceiling`` (the frames' range) is marked clipped. Raises :class:`LowcamError`
    where the chart is too small or leaves the frame."""
    areas = _areas(image, corners, centres)
    if areas is None:
        raise LowcamError("the ColorChecker's patches are under 8 pixels across (move closer)")
    means, noise, pixels, clipped = [], [], [], []
    for area in areas:
        if not np.isfinite(area).all():
            raise LowcamError("the ColorChecker runs off the frame (frame the whole chart)")
        h, w, c = area.shape
        b = _BLOCK if min(h, w) >= 4 * _BLOCK else 1
        hb, wb = h // b, w // b
        blocks = area[:hb * b, :wb * b].reshape(hb, b, wb, b, c).mean(axis=(1, 3)).reshape(-1, c)
        means.append(area.reshape(-1, c).mean(axis=0))
        noise.append(blocks.std(axis=0, ddof=1) / np.sqrt(len(blocks)))
        pixels.append(h * w)
        clipped.append(bool(((area <= floor) | (area >= ceiling)).any()))
    return PatchReading(np.array(means, np.float64), np.array(noise, np.float64), np.array(pixels),
                        np.array(clipped), np.asarray(corners, np.float64),
                        centres=None if centres is None else np.asarray(centres, np.float64))


#: The most a frame of a static view may lie from the first (px, registered by phase correlation over the chart)
#: before the capture is refused as moving.
MOVED_PX = 1.0


def _moved_px(frames, corners: np.ndarray) -> list[float]:
    """How far each of ``frames`` lies from the first over the chart's bounding box ``corners`` (px): the
    translation phase correlation finds (Hann-windowed; the noise averages out over the whole chart, where a chart
    found in each noisy frame on its own jitters by pixels)."""
    h, w = frames[0].shape[:2]
    x0, y0 = np.clip(np.floor(corners.min(axis=0)).astype(int), 0, [w - 1, h - 1])
    x1, y1 = np.clip(np.ceil(corners.max(axis=0)).astype(int) + 1, 1, [w, h])
    if min(x1 - x0, y1 - y0) < 16:   # too small to read (read_patches says so): nothing to register
        return [0.0] * len(frames)

    def grey(f):
        return np.asarray(f, np.float64)[y0:y1, x0:x1].reshape(y1 - y0, x1 - x0, -1).mean(axis=2)

    window = cv2.createHanningWindow((x1 - x0, y1 - y0), cv2.CV_64F)
    first = grey(frames[0])
    return [float(np.hypot(*cv2.phaseCorrelate(first, grey(f), window)[0])) for f in frames]


def read_colour_checker(frames, names, floor: float = 0.0, ceiling: float = 255.0,
                        what: str = "ColorChecker") -> PatchReading:
    """The ColorChecker's patches in frames of one static view: the chart found once, on the mean frame (whose
    noise is the mean's, so noisy frames of one view are one view), the patches read there. Where the mean holds
    no chart, the first frame without one is named; a frame that lies more than :data:`MOVED_PX` from the first
    (a moving view) is refused naming it."""
    frames = [np.asarray(f) for f in frames]
    mean = np.mean([f.astype(np.float64) for f in frames], axis=0)
    found = locate_patches(mean)
    if found is None:
        bad = next((n for f, n in zip(frames, names) if locate_patches(f) is None), None) if len(frames) > 1 \
            else names[0]
        if bad is None:
            raise LowcamError(f"{names[0]}: the ColorChecker is found in every frame but not in their mean: it moved "
                              f"(a {what} capture is one static view; give moving views as separate captures)")
        raise LowcamError(f"{bad}: no ColorChecker found in the frame ({what}: the whole chart, its 24 patches "
                          f"and the dark gaps between them, must be in view)")
    corners, centres = found
    if len(frames) > 1:
        moved = _moved_px(frames, corners)
        if max(moved) > MOVED_PX:
            raise LowcamError(f"{names[int(np.argmax(moved))]}: the ColorChecker moved by {max(moved):.1f} px against "
                              f"{names[0]} (a {what} capture is one static view; give moving views as separate "
                              "captures)")
    try:
        reading = read_patches(mean, corners, floor, ceiling, centres)
    except LowcamError as e:
        raise LowcamError(f"{names[0]}: {e}") from None
    return mark_clipped(reading, frames, floor, ceiling)


def mark_clipped(reading: PatchReading, frames, floor: float = 0.0, ceiling: float = 255.0) -> PatchReading:
    """Mark clipped in ``reading`` (read on the frames' mean) each patch with any pixel at ``floor`` or ``ceiling``
    in any of ``frames``: a mean frame hides a pixel clipped in one of them. Returns ``reading``."""
    for f in frames:
        areas = _areas(f, reading.corners, reading.centres)
        if areas is not None:  # None: cells under 8 px, which a reading refuses
            reading.clipped |= [bool(((a <= floor) | (a >= ceiling)).any()) for a in areas]
    return reading
