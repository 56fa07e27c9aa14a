"""The lens calibration: FOV and Brown-Conrady lenses from chessboard or ChArUco views (sec. 4.1).

Contents
--------
- :func:`calibrate_lens`: FOV and Brown-Conrady lenses from chessboard or ChArUco views (sec. 4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Zhang2000] Z. Zhang, "A Flexible New Technique for Camera Calibration", IEEE TPAMI 22(11), 1330-1334, 2000.
- [Devernay2001] F. Devernay and O. Faugeras, "Straight lines have to be straight", Machine Vision and Applications
  13(1), 14-24, 2001.
- [Klein2007] G. Klein and D. Murray, "Parallel Tracking and Mapping for Small AR Workspaces", ISMAR 2007 (PTAM).
- [Brown1966] D. C. Brown, "Decentering Distortion of Lenses", Photogrammetric Engineering 32(3), 444-462, 1966.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..captures import detect_target, parse_target
from ..effects.lens_fit import fit_lens
from ..errors import LowcamError
from ..reports import figure
from .checks import load_checked, require_finite
from .outcome import Calibration


def _distinct_views(points, tolerance_px: float = 0.5) -> int:
    """How many of the target's detections differ (by more than ``tolerance_px`` at some corner)."""
    kept: list[np.ndarray] = []
    for p in points:
        if not any(k.shape == p.shape and np.abs(k - p).max() <= tolerance_px for k in kept):
            kept.append(p)
    return len(kept)


def calibrate_lens(patterns, target: str = "checkerboard:9x6:0.025", models=("fov", "opencv"),
                   plot_dir: Path | None = None) -> Calibration:
    frames, names, source = load_checked(patterns, 3, "lens calibration")
    spec = parse_target(target)
    obj, img, used, missing = [], [], [], []
    for f, n in zip(frames, names):
        found = detect_target(f, spec)
        if found is None:
            missing.append(n)
            continue
        obj.append(found[0])
        img.append(found[1])
        used.append(n)
    notes = [f"{n}: {target} not found, frame skipped" for n in missing]
    if len(used) < 3:
        raise LowcamError(f"{source}: the target ({target}) was found in {len(used)} frame(s), at least 3 are "
                          f"needed" + (f"; not found in {', '.join(Path(m).name for m in missing)}" if missing
                                       else ""))
    views = _distinct_views(img)
    if views < 3:
        raise LowcamError(f"{source}: the target ({target}) shows {views} distinct view(s) in {len(used)} frames, "
                          f"so the lens is undetermined; at least 3 views from different angles are needed")
    h, w = frames[0].shape[:2]
    fits = {}
    for m in models:
        try:
            fits[m] = fit_lens(obj, img, (w, h), m)
        except cv2.error:  # OpenCV's initial calibration failed on these views
            raise LowcamError(f"{source}: OpenCV cannot calibrate from these {len(used)} views of the target "
                              f"({target}); tilt the board more between frames") from None
        require_finite(source, f"the {m} lens", **{f"{m} lens": fits[m].params, "RMS error": fits[m].rms})
    best = min(fits, key=lambda m: fits[m].rms)
    numbers = {"frames_used": len(used), "skipped": notes}
    for m, fit in fits.items():
        numbers[m] = {"rms_px": fit.rms, "per_frame_rms_px": dict(zip((Path(u).name for u in used),
                                                                       fit.per_frame_rms)), **fit.params}
    figures = []
    if plot_dir:
        def draw(fig):
            for k, (m, fit) in enumerate(fits.items()):
                ax = fig.add_subplot(1, len(fits), k + 1)
                pts = np.concatenate(img)
                res = np.concatenate(fit.residuals)
                ax.quiver(pts[:, 0], pts[:, 1], res[:, 0], -res[:, 1], np.hypot(res[:, 0], res[:, 1]),
                          angles="xy", scale_units="xy", scale=0.01, cmap="viridis")
                ax.set_xlim(0, w)
                ax.set_ylim(h, 0)
                ax.set_aspect("equal")
                ax.set_title(f"{m}: RMS {fit.rms:.3f} px (arrows x100)")
        figures.append(figure(Path(plot_dir) / "lens_residuals.png", draw, (11, 4.5)))
    summary = (f"lens: {len(used)}/{len(frames)} frames, " +
               ", ".join(f"{m} RMS {fits[m].rms:.3f} px" for m in fits) + f"; profile gets {best}")
    return Calibration("lens", summary, {"lens_distortion": {"model": best, **fits[best].params}}, numbers,
                       figures)


#: Flat fields darker than this (DN, 99th percentile) cannot show the fall-off.
