"""Independent OpenCV calls side by side, on as many threads as OpenCV is given.

OpenCV's functions release the GIL, but its own threads help only large calls: the Bayer stage's many small
remaps and the scans of a render's zero margins run on one core however many OpenCV has. Running independent
calls of that kind side by side uses the others. Results never depend on the number of threads: each call does
the same arithmetic in the same order as it would alone.

Contents
--------
- :func:`threads`: how many threads the engine uses (``cv2.getNumThreads()``, at most 8)
- :func:`thread_map`: ``fn`` over items on those threads, results in order
- :func:`row_strips`: an image's rows cut into one strip per thread
- :func:`one_malloc_arena`: every thread's C allocations from one glibc arena (a leaner peak for threaded fits)
"""
from __future__ import annotations

import ctypes
import os
import platform
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

_pools: dict = {}
_lock = threading.Lock()
_inside = threading.local()


def threads() -> int:
    """The engine's threads: OpenCV's own count (``cv2.setNumThreads``, ``OPENCV_FOR_THREADS_NUM``), at most 8."""
    return max(1, min(8, cv2.getNumThreads()))


def _pool(n: int) -> ThreadPoolExecutor:
    """A pool of ``n`` threads for this process (a forked child makes its own: the parent's threads are gone)."""
    key = (os.getpid(), n)
    with _lock:
        if key not in _pools:
            _pools[key] = ThreadPoolExecutor(n, thread_name_prefix="lowcam",
                                             initializer=lambda: setattr(_inside, "pool", True))
        return _pools[key]


def thread_map(fn, items) -> list:
    """``[fn(item) for item in items]``, the calls run side by side on :func:`threads` threads (in the calling
    thread alone when there is one thread, one item, or the caller is itself one of the pool's threads).

    >>> thread_map(lambda x: x * x, range(4))
    [0, 1, 4, 9]
    """
    items = list(items)
    n = min(threads(), len(items))
    if n < 2 or getattr(_inside, "pool", False):
        return [fn(item) for item in items]
    return list(_pool(n).map(fn, items))


def row_strips(rows: int, min_rows: int = 64) -> list[slice]:
    """``rows`` cut into one slice of consecutive rows per thread (fewer where a strip would be under
    ``min_rows``).

    >>> sum(strip.stop - strip.start for strip in row_strips(1000))
    1000
    """
    parts = max(1, min(threads(), rows // min_rows))
    bounds = np.linspace(0, rows, parts + 1).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


#: glibc's ``mallopt`` parameter for the number of arenas (``malloc.h``).
_M_ARENA_MAX = -8


def one_malloc_arena() -> bool:
    """Serve every thread's C allocations from one glibc malloc arena (``mallopt(M_ARENA_MAX, 1)``); True where
    that was done (Linux with glibc), False elsewhere. By default each new thread may get its own arena (up to 8 per
    core), and the frame-sized buffers that threaded fits free stay mapped in each: diagnosis of the standard set
    peaks at about 1.05 GB that way and 0.9 GB with one arena, in the same time (``benchmarks/bench_diagnose.py``)."""
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        return bool(ctypes.CDLL(None).mallopt(_M_ARENA_MAX, 1))
    except (OSError, AttributeError, TypeError):
        return False
