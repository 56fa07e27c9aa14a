"""The lens calibration: FOV, Brown-Conrady and OpenCV's fisheye lenses from chessboard or ChArUco views (sec. 4.1).

Contents
--------
- :func:`calibrate_lens`: FOV, Brown-Conrady or fisheye lenses from chessboard or ChArUco views (sec. 4.1)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Zhang2000] Z. Zhang, "A Flexible New Technique for Camera Calibration", IEEE TPAMI 22(11), 1330-1334, 2000.
- [Devernay2001] F. Devernay and O. Faugeras, "Straight lines have to be straight", Machine Vision and Applications
  13(1), 14-24, 2001.
- [Klein2007] G. Klein and D. Murray, "Parallel Tracking and Mapping for Small AR Workspaces", ISMAR 2007 (PTAM).
- [Brown1966] D. C. Brown, "Decentering Distortion of Lenses", Photogrammetric Engineering 32(3), 444-462, 1966.
- [Kannala2006] J. Kannala and S. S. Brandt, "A Generic Camera Model and Calibration Method for Conventional,
  Wide-Angle, and Fish-Eye Lenses", IEEE TPAMI 28(8), 1335-1340, 2006 (OpenCV's fisheye model).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..captures import detect_target, parse_target
from ..effects.lens_fit import IllConditionedView, fit_lens
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


def _fisheye_fit_or_none(obj, img, image_size, terms):
    """The fisheye fit, or None where OpenCV finds a view ill-conditioned or its solve fails."""
    try:
        return fit_lens(obj, img, image_size, "fisheye", fisheye_terms=terms)
    except (IllConditionedView, cv2.error):
        return None


def _fit_fisheye(obj, img, used, image_size, source, target, notes):
    """The fisheye fit (``cv2.fisheye.calibrate`` and the joint refinement of :func:`fit_lens`).

    Where OpenCV finds a view's pose ill-conditioned, the view to leave out is the first whose absence lets the
    fit through, tried from the one OpenCV names (the view where its check failed, which another view's wrong
    detection can cause, through the intrinsics all views share), and a note names it; where leaving out one view does not help, or
    fewer than three would remain, the fit is refused in one line. Where the four coefficients fold the lens over
    inside the frame (they trade off, and beyond the views the polynomial may turn back), the highest are held at
    0 (a note says so); refused where even k1 alone folds. Returns (fit, image points, frames) of the views kept.
    """
    for terms in (4, 3, 2, 1):
        try:
            fit = fit_lens(obj, img, image_size, "fisheye", fisheye_terms=terms)
        except IllConditionedView as bad:
            order = [bad.index, *(j for j in range(len(obj)) if j != bad.index)]
            fit = left = None
            if len(obj) > 3:
                for left in order:
                    fit = _fisheye_fit_or_none(obj[:left] + obj[left + 1:], img[:left] + img[left + 1:],
                                               image_size, terms)
                    if fit is not None:
                        break
            if fit is None or _distinct_views(img[:left] + img[left + 1:]) < 3:
                raise LowcamError(f"{source}: OpenCV finds the target's pose ill-conditioned in "
                                  f"{Path(used[bad.index]).name} (or another view spoils it) and leaving out one view "
                                  f"does not help; show the board larger and less edge-on ({target})") from None
            notes.append(f"{used[left]}: the target's pose makes the fisheye fit ill-conditioned (a wrong detection, "
                         f"or the board too small, far or edge-on), frame skipped")
            obj, img, used = obj[:left] + obj[left + 1:], img[:left] + img[left + 1:], used[:left] + used[left + 1:]
        except cv2.error:
            raise LowcamError(f"{source}: OpenCV's fisheye calibration fails on these {len(used)} views of the "
                              f"target ({target}); show the board at more angles and across the frame") from None
        try:
            fit.effect()  # LensDistortion.check: the radius must rise out to the frame's corners
        except LowcamError as e:
            if "folds over" not in str(e):
                raise
            continue
        if terms < 4:
            held = f"k{terms + 1}" + ("..k4" if terms < 3 else "")
            notes.append(f"fisheye: {held} held at 0 (with all four the fitted lens folds over inside the frame: "
                         f"the views do not reach its corners)")
        return fit, img, used
    raise LowcamError(f"{source}: the fisheye lens fitted to these {len(used)} views folds over inside the frame; "
                      f"show the board nearer the frame's corners")


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
    fits, kept = {}, {}  # kept: per model, the (image points, frames) of the views it was fitted to
    for m in models:
        kept[m] = (img, used)
        if m == "fisheye":
            fits[m], *kept[m] = _fit_fisheye(obj, img, used, (w, h), source, target, notes)
        else:
            try:
                fits[m] = fit_lens(obj, img, (w, h), m)
            except cv2.error:  # OpenCV's initial calibration failed on these views
                raise LowcamError(f"{source}: OpenCV cannot calibrate from these {len(used)} views of the target "
                                  f"({target}); tilt the board more between frames") from None
        require_finite(source, f"the {m} lens", **{f"{m} lens": fits[m].params, "RMS error": fits[m].rms})
    best = min(fits, key=lambda m: fits[m].rms)
    numbers = {"frames_used": len(kept[best][1]), "skipped": notes}
    for m, fit in fits.items():
        numbers[m] = {"rms_px": fit.rms, "per_frame_rms_px": dict(zip((Path(u).name for u in kept[m][1]),
                                                                       fit.per_frame_rms)), **fit.params}
        if m == "fisheye":  # what the lens sees: the angle (deg) from the axis to the frame's farthest corner
            theta, _ = fit.effect().model_for(w, h).undistort_ray(np.array([-0.5, w - 0.5, -0.5, w - 0.5]),
                                                                  np.array([-0.5, -0.5, h - 0.5, h - 0.5]))
            numbers[m]["corner_angle_deg"] = float(np.degrees(theta.max()))
    figures = []
    if plot_dir:
        def draw(fig):
            for k, (m, fit) in enumerate(fits.items()):
                ax = fig.add_subplot(1, len(fits), k + 1)
                pts = np.concatenate(kept[m][0])
                res = np.concatenate(fit.residuals)
                ax.quiver(pts[:, 0], pts[:, 1], res[:, 0], -res[:, 1], np.hypot(res[:, 0], res[:, 1]),
                          angles="xy", scale_units="xy", scale=0.01, cmap="viridis")
                ax.set_xlim(0, w)
                ax.set_ylim(h, 0)
                ax.set_aspect("equal")
                ax.set_title(f"{m}: RMS {fit.rms:.3f} px (arrows x100)")
        figures.append(figure(Path(plot_dir) / "lens_residuals.png", draw, (11, 4.5)))
    summary = (f"lens: {len(kept[best][1])}/{len(frames)} frames, " +
               ", ".join(f"{m} RMS {fits[m].rms:.3f} px" for m in fits) + f"; profile gets {best}")
    return Calibration("lens", summary, {"lens_distortion": {"model": best, **fits[best].params}}, numbers,
                       figures)


#: Flat fields darker than this (DN, 99th percentile) cannot show the fall-off.
