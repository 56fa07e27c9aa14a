"""Windows around a picture's non-zero pixels, and warps that compute only inside them.

Inserted graphics usually cover a small part of the render; the rest is transparent black (premultiplied, so
every channel is 0). A bilinear warp of zeros is zeros, so the warps of the chain (the lens, sec. 5.2 step 1, and
the Bayer sampling, step 5) compute only the output pixels whose source neighbourhood meets the window around the
non-zero pixels. The result is the same, bit for bit: ``cv2.remap`` computes each output pixel from its own map
entry alone.

Contents
--------
- :func:`nonzero_window`: the smallest (rows, cols) window holding every non-zero element of an image
- :func:`window_union`: the window holding the windows found in strips of an image's rows
- :func:`grow_window`: a window grown by a margin, within an image
- :class:`WindowedRemap`: ``cv2.remap`` with fixed maps that computes only what can be non-zero
- :func:`filter_in_strips`: a neighbourhood filter of an image run in strips of rows on every thread, same result
"""
from __future__ import annotations

import cv2
import numpy as np

from .parallel import row_strips, thread_map, threads


def nonzero_window(image: np.ndarray, block: int = 32) -> tuple[slice, slice] | None:
    """The smallest (rows, cols) window holding every non-zero element of ``image`` (H, W[, C]), or None when
    every element is zero. NaN counts as non-zero, -0.0 as zero.

    Rows are scanned in blocks of ``block`` inwards from the top and the bottom, stopping at the first non-zero
    one; then each block of rows between is searched only left of the leftmost and right of the rightmost
    non-zero column found so far. It reads the zero margins and little else, in row order: almost nothing for a
    full frame, and about a tenth of ``cv2.inRange``'s time over the whole image for sparse graphics.

    The image is cut into one strip of rows per thread (:func:`~lowcam.parallel.row_strips`), scanned side by
    side; the window is the union of the strips' windows.

    >>> a = np.zeros((40, 50, 4), np.float32); a[10, 20:23, 1] = 1.0
    >>> nonzero_window(a)
    (slice(10, 11, None), slice(20, 23, None))
    """
    strips = row_strips(image.shape[0], min_rows=4 * block)
    return window_union([(strip.start, window) for strip, window in
                         zip(strips, thread_map(lambda strip: _strip_window(image[strip], block), strips))])


def window_union(found: list[tuple[int, tuple[slice, slice] | None]]) -> tuple[slice, slice] | None:
    """The smallest window holding the windows of strips of rows, each given as (the strip's first row, its own
    window or None); None where every strip's is None.

    >>> window_union([(0, None), (10, (slice(2, 4), slice(5, 9))), (20, (slice(0, 1), slice(1, 3)))])
    (slice(12, 21, None), slice(1, 9, None))
    """
    found = [(top, window) for top, window in found if window is not None]
    if not found:
        return None
    return (slice(min(top + rows.start for top, (rows, _) in found), max(top + rows.stop for top, (rows, _) in found)),
            slice(min(cols.start for _, (_, cols) in found), max(cols.stop for _, (_, cols) in found)))


def _strip_window(image: np.ndarray, block: int) -> tuple[slice, slice] | None:
    """:func:`nonzero_window` of one strip of rows, in the calling thread."""
    h, w = image.shape[:2]
    flat = image.reshape(h, -1)  # (H, W * C): cv2.countNonZero takes one channel
    c = flat.shape[1] // w

    def first(n, nonzero) -> int | None:
        """The first of ``n`` lines for which ``nonzero(start, stop)`` holds, testing blocks, then lines."""
        for start in range(0, n, block):
            stop = min(n, start + block)
            if nonzero(start, stop):
                return next(i for i in range(start, stop) if nonzero(i, i + 1))
        return None

    top = first(h, lambda s, e: cv2.countNonZero(flat[s:e]) > 0)
    if top is None:
        return None
    bottom = h - first(h, lambda s, e: cv2.countNonZero(flat[h - e:h - s]) > 0)
    left, right = w, 0
    for row in range(top, bottom, block):
        rows = flat[row:min(bottom, row + block)]
        if left > 0 and cv2.countNonZero(rows[:, :left * c]):
            left = first(left, lambda s, e: cv2.countNonZero(rows[:, s * c:e * c]) > 0)
        if right < w and cv2.countNonZero(rows[:, right * c:]):
            right = w - first(w - right, lambda s, e: cv2.countNonZero(rows[:, (w - e) * c:(w - s) * c]) > 0)
    return slice(top, bottom), slice(left, right)


def grow_window(window: tuple[slice, slice], margin: int, shape) -> tuple[slice, slice]:
    """``window`` (rows, cols) grown by ``margin`` pixels on every side, within an image of ``shape`` (rows,
    cols, ...): where a filter of that radius can make the window's pixels reach.

    >>> grow_window((slice(2, 5), slice(8, 9)), 3, (6, 10))
    (slice(0, 6, None), slice(5, 10, None))
    """
    rows, cols = window
    return (slice(max(0, rows.start - margin), min(shape[0], rows.stop + margin)),
            slice(max(0, cols.start - margin), min(shape[1], cols.stop + margin)))


def filter_in_strips(filter_rows, image: np.ndarray, halo: int, *also: np.ndarray,
                     strip_bytes: int = 8 << 20) -> np.ndarray:
    """``filter_rows(image, *also)`` (an array of the image's shape and type) computed in strips of rows shared
    out among the threads (OpenCV's linear filters run on one core), each strip read with ``halo`` rows beyond it
    on either side and cropped. For a filter whose output row reads input rows at most ``halo`` away (and the
    image's own top and bottom border as usual), every output pixel reads the same values in the same order as
    in one call, so the result is the same, bit for bit. ``also`` are arrays of the image's rows cut alongside it
    (e.g. per-pixel weights). A strip holds about ``strip_bytes`` of the image (at least one strip per thread, and
    four halos), so its pieces are reused from the heap rather than fresh pages for every call.

    >>> a = np.random.default_rng(0).random((300, 40), dtype=np.float32)
    >>> blur = lambda x: cv2.GaussianBlur(x, (0, 0), 1.5)
    >>> np.array_equal(filter_in_strips(blur, a, 8), blur(a))
    True
    """
    rows = image.shape[0]
    n = threads()
    if n < 2 or rows < 2 * max(64, 4 * halo):
        return filter_rows(image, *also)
    step = max(64, 4 * halo, min(-(-rows // n), strip_bytes // max(1, image[0].nbytes)))
    out = np.empty_like(image)

    def strip(start: int) -> None:
        stop = min(rows, start + step)
        top, bottom = max(0, start - halo), min(rows, stop + halo)
        out[start:stop] = filter_rows(image[top:bottom], *(a[top:bottom] for a in also))[start - top:stop - top]

    thread_map(strip, range(0, rows, step))
    return out


class WindowedRemap:
    """Bilinear ``cv2.remap`` (constant 0 border) of ``blocks`` stacked outputs through fixed maps, computing only
    the output pixels whose source neighbourhood meets a window (:func:`nonzero_window`) of the source.

    ``x`` and ``y`` (blocks, rows, cols) are the source coordinates of every output pixel, pixel centres at
    integers (e.g. one block per motion-blur tap). The maps are converted once to OpenCV's fixed-point form, and
    the source range of every ``tile`` x ``tile`` tile of the output plane (over all blocks) is kept; a call
    computes, in every block, the output rectangle covering the tiles that reach the window.

    >>> src = np.zeros((20, 30, 2), np.float32); src[5, 7] = 1.0
    >>> y, x = np.mgrid[0:10, 0:15].astype(np.float32) * 2
    >>> warp = WindowedRemap(x[None], y[None])
    >>> out = warp(src, nonzero_window(src))
    >>> out.shape, np.array_equal(out, cv2.remap(src, x, y, cv2.INTER_LINEAR))
    ((10, 15, 2), True)
    """

    def __init__(self, x: np.ndarray, y: np.ndarray, tile: int = 32):
        self.blocks, self.rows, self.cols = x.shape
        self.tile = tile
        self.maps = cv2.convertMaps(x.reshape(-1, self.cols), y.reshape(-1, self.cols), cv2.CV_16SC2)
        self.x_range = _tile_range(x, tile)
        self.y_range = _tile_range(y, tile)

    def output_rect(self, window: tuple[slice, slice]) -> tuple[int, int, int, int] | None:
        """(row0, row1, col0, col1) of the output plane that can be non-zero for a source ``window``; None when
        nothing can. A bilinear tap at x reads columns floor(x) and floor(x) + 1 (x rounded to 1/32 px), so a
        tile matters when its source range comes within 2 px of the window."""
        rows, cols = window
        (x_lo, x_hi), (y_lo, y_hi) = self.x_range, self.y_range
        hit = ((x_hi >= cols.start - 2) & (x_lo <= cols.stop + 1) & (y_hi >= rows.start - 2)
               & (y_lo <= rows.stop + 1))
        tile_rows, tile_cols = np.flatnonzero(hit.any(axis=1)), np.flatnonzero(hit.any(axis=0))
        if tile_rows.size == 0:
            return None
        t = self.tile
        return (tile_rows[0] * t, min(self.rows, (tile_rows[-1] + 1) * t),
                tile_cols[0] * t, min(self.cols, (tile_cols[-1] + 1) * t))

    def output_window(self, window: tuple[slice, slice] | None) -> tuple[slice, slice] | None:
        """The (rows, cols) window of one output block holding every pixel that can be non-zero for a source
        ``window`` (:meth:`output_rect`); None when nothing can."""
        rect = None if window is None else self.output_rect(window)
        return None if rect is None else (slice(rect[0], rect[1]), slice(rect[2], rect[3]))

    def halved(self, src: np.ndarray, window: tuple[slice, slice] | None, strip: int = 32) -> np.ndarray:
        """The warp of ``src`` (one block of even rows and cols) halved by its 2x2 box means: ``cv2.resize(self(src,
        window), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)``, bit for bit, computed ``strip`` rows at a
        time (even), the strips shared out among the threads: the full-size warp is never held, and each strip
        is halved while it is still in cache."""
        m1, m2 = self.maps
        out = np.zeros((self.rows // 2, self.cols // 2) + src.shape[2:], np.float32)
        rect = None if window is None else self.output_rect(window)
        if rect is None:
            return out
        r0, c0 = 2 * (rect[0] // 2), 2 * (rect[2] // 2)
        r1, c1 = min(self.rows, 2 * -(-rect[1] // 2)), min(self.cols, 2 * -(-rect[3] // 2))
        strip += strip % 2

        def halve(top: int) -> None:
            bottom = min(r1, top + strip)
            warped = cv2.remap(src, m1[top:bottom, c0:c1], m2[top:bottom, c0:c1], cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            half = out[top // 2:bottom // 2, c0 // 2:c1 // 2]
            cv2.resize(warped, half.shape[1::-1], dst=half, interpolation=cv2.INTER_AREA)

        thread_map(halve, range(r0, r1, strip))
        return out

    def mean(self, src: np.ndarray, window: tuple[slice, slice] | None, taps: int) -> np.ndarray:
        """The mean of every run of ``taps`` consecutive blocks of the warp of ``src``, as (blocks / taps, rows,
        cols[, channels]): equal to ``self(src, window).reshape(-1, taps, ...).mean(axis=1)`` (the taps added in
        order in float32), computed in strips of rows on every thread (:meth:`mean_jobs`)."""
        out = np.zeros((self.blocks // taps, self.rows, self.cols) + src.shape[2:], np.float32)
        thread_map(lambda job: job(), self.mean_jobs(src, window, taps, out))
        return out

    def mean_jobs(self, src: np.ndarray, window: tuple[slice, slice] | None, taps: int, out: np.ndarray,
                  strip: int = 32) -> list:
        """Independent calls that, run in any order on any threads, write :meth:`mean` into ``out`` (zero, of its
        shape): one per run of taps and strip of ``strip`` output rows, each adding its taps in order in float32
        (a strip stays in cache over the taps, and is small enough that OpenCV does not split it again)."""
        m1, m2 = self.maps
        rect = None if window is None else self.output_rect(window)
        if rect is None:
            return []
        r0, r1, c0, c1 = rect

        def job(group: int, top: int, bottom: int) -> None:
            total = out[group, top:bottom, c0:c1]
            tap = np.empty(total.shape, np.float32)
            for k in range(taps):
                first_row = (group * taps + k) * self.rows
                part = slice(first_row + top, first_row + bottom), slice(c0, c1)
                cv2.remap(src, m1[part], m2[part], cv2.INTER_LINEAR, dst=total if k == 0 else tap,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                if k:
                    cv2.add(total, tap, dst=total)  # in place, like np.add but faster on a strided block
            if taps > 1:
                np.true_divide(total, np.float32(taps), out=total)

        return [lambda g=group, a=top: job(g, a, min(r1, a + strip))
                for group in range(out.shape[0]) for top in range(r0, r1, strip)]

    def __call__(self, src: np.ndarray, window: tuple[slice, slice] | None) -> np.ndarray:
        """The warp of ``src`` (rows, cols[, channels]) as (blocks * rows, cols[, channels]); ``window`` holds
        every non-zero source pixel (None: ``src`` is all zero)."""
        m1, m2 = self.maps
        rect = None if window is None else self.output_rect(window)
        if rect == (0, self.rows, 0, self.cols):
            return cv2.remap(src, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out = np.zeros((self.blocks * self.rows, self.cols) + src.shape[2:], src.dtype)
        if rect is None:
            return out
        r0, r1, c0, c1 = rect
        for first_row in range(0, self.blocks * self.rows, self.rows):
            part = slice(first_row + r0, first_row + r1), slice(c0, c1)
            cv2.remap(src, m1[part], m2[part], cv2.INTER_LINEAR, dst=out[part], borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0)
        return out


def _tile_range(coords: np.ndarray, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """Per ``tile`` x ``tile`` tile of the (rows, cols) plane, the least and greatest value of
    ``coords`` (blocks, rows, cols) over its pixels in every block; NaN (no source) is left out."""
    lo, hi = np.fmin.reduce(coords, axis=0), np.fmax.reduce(coords, axis=0)
    rows, cols = lo.shape
    pad = ((0, -rows % tile), (0, -cols % tile))
    tiles = (-(-rows // tile), tile, -(-cols // tile), tile)
    return (np.fmin.reduce(np.pad(lo, pad, mode="edge").reshape(tiles), axis=(1, 3)),
            np.fmax.reduce(np.pad(hi, pad, mode="edge").reshape(tiles), axis=(1, 3)))
