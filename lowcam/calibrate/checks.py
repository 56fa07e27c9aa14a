"""The checks every calibration makes on its frames before it fits or writes anything (plots included): enough
frames, readable and of one size, with contrast, not identical copies, and finite fitted values. A refusal is one
line naming the frames.

Contents
--------
- :func:`source_name`: the input as named on the command line or in the manifest, for messages
- :func:`load_checked`: (frames, names, source) of a calibration's frames; too few, unreadable or mixed sizes refused
- :data:`MIN_CONTRAST_DN`: the least spread (DN) a frame must show to hold a target
- :func:`contrast_dn`: the spread (1st to 99th percentile, DN) of an image lightly smoothed
- :func:`identical`: whether the frames are copies of one capture
- :func:`all_finite`: whether every number in a fitted value is finite
- :func:`require_finite`: refuse fitted values that are not finite, naming them
"""
from __future__ import annotations

import cv2
import numpy as np

from ..captures import load_frames
from ..errors import LowcamError


def source_name(patterns) -> str:
    """The input as named on the command line or in the manifest, for messages: a few names, or the first and
    last of many."""
    names = [str(p) for p in patterns]
    if len(names) <= 3:
        return " ".join(names) or "(no frames)"
    return f"{names[0]} ... {names[-1]} ({len(names)} names)"


def load_checked(patterns, min_frames: int, what: str):
    """(frames, names, source) of a calibration's frames; too few, unreadable or mixed sizes are refused."""
    patterns = list(patterns)
    source = source_name(patterns)
    frames, names = load_frames(patterns, min_frames, f"{source}: {what}")
    return frames, names, source


def contrast_dn(image) -> float:
    """Spread (1st to 99th percentile, DN) of an image lightly smoothed, so that pixel noise alone shows little."""
    smooth = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 1.0)
    lo, hi = np.percentile(smooth, [1, 99])
    return float(hi - lo)


def identical(frames) -> bool:
    return all(np.array_equal(f, frames[0]) for f in frames[1:])


def all_finite(value) -> bool:
    if isinstance(value, dict):
        return all(all_finite(v) for v in value.values())
    return bool(np.isfinite(np.asarray(value, np.float64)).all())


def require_finite(source: str, what: str, **fitted) -> None:
    """Refuse a fit whose values came out NaN or infinite: ``what`` names what stays undetermined."""
    for name, value in fitted.items():
        if not all_finite(value):
            raise LowcamError(f"{source}: the fitted {name.replace('_', ' ')} is not finite, so {what} is "
                              f"undetermined")


#: Below this contrast (DN, :func:`contrast_dn`) a frame holds no edge or texture to measure.
MIN_CONTRAST_DN = 10.0
