"""Lens calibration from views of a planar target (Klein & Murray 2010, sec. 4.1): the fit ``lowcam calibrate lens``
runs.

From views of a chessboard or ChArUco board, the poses start from OpenCV's pinhole calibration (Zhang's method);
intrinsics, distortion and poses are then refined together by Levenberg-Marquardt on the reprojection error (the
paper uses damped Gauss-Newton). OpenCV's fisheye (Kannala-Brandt) model is fitted by OpenCV itself
(``cv2.fisheye.calibrate``), which starts from an equidistant lens and reaches the least reprojection error.

Contents
--------
- :class:`LensFit`: result of :func:`fit_lens`: the fitted parameters and the reprojection errors
- :func:`fit_lens`: fit a lens ``model`` (``"fov"``, ``"opencv"`` or ``"fisheye"``) to views of a planar target
  (sec. 4.1)
- :class:`IllConditionedView`: ``cv2.fisheye.calibrate``'s conditioning check failed at one view (which one), or
  it could not find that view's initial pose

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Zhang2000] Z. Zhang, "A Flexible New Technique for Camera Calibration", IEEE TPAMI 22(11), 1330-1334, 2000.
- [Kannala2006] J. Kannala and S. S. Brandt, "A Generic Camera Model and Calibration Method for Conventional,
  Wide-Angle, and Fish-Eye Lenses", IEEE TPAMI 28(8), 1335-1340, 2006.
"""
from __future__ import annotations

import re

import cv2
import numpy as np

from .lens import LensDistortion
from .lens_models import FovLens, OpenCVLens


class LensFit:
    """Result of :func:`fit_lens`: the fitted :class:`LensDistortion` parameters and the reprojection errors."""

    def __init__(self, model, params, residuals, rvecs, tvecs, image_size):
        self.model = model
        self.params = params
        self.residuals = residuals  # list of (N, 2) arrays, pixels
        self.rvecs, self.tvecs = rvecs, tvecs
        self.image_size = image_size

    @property
    def rms(self) -> float:
        r = np.concatenate(self.residuals)
        return float(np.sqrt((r ** 2).sum(axis=1).mean()))

    @property
    def per_frame_rms(self) -> list[float]:
        return [float(np.sqrt((r ** 2).sum(axis=1).mean())) for r in self.residuals]

    def effect(self, **extra) -> LensDistortion:
        return LensDistortion(model=self.model, **self.params, **extra)


def _unpack(model, p, width, height, fix_aspect):
    if model == "fov":
        fx, cx, cy, w = p[0], p[1], p[2], p[3]
        fy = fx * width / height if fix_aspect else p[4]
        params = dict(fx=fx, fy=fy, cx=cx, cy=cy, w=w)
        return FovLens(width, height, fx, fy, cx, cy, w), params
    f, cx, cy, k1, k2, p1, p2, k3 = p[:8]
    fy = f if fix_aspect else p[8]
    params = dict(fx_px=f, fy_px=fy, cx_px=cx, cy_px=cy, k1=k1, k2=k2, k3=k3, p1=p1, p2=p2)
    return OpenCVLens(width, height, f, fy, cx, cy, k1, k2, k3, p1, p2), params


class IllConditionedView(ValueError):
    """``cv2.fisheye.calibrate``'s conditioning check (``CALIB_CHECK_COND``) failed at the pose of view ``index``
    (the target too small, far or edge-on in it, or the intrinsics spoilt by another view's wrong detection), or
    OpenCV could not find that view's initial pose at all (a degenerate detection)."""

    def __init__(self, index: int):
        super().__init__(f"view {index} is ill-conditioned")
        self.index = index


#: ``cv2.fisheye.calibrate``'s flags: the poses re-solved after each step of the intrinsics, no skew, and the
#: views' conditioning checked (where it fails, :class:`IllConditionedView`).
FISHEYE_FLAGS = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW | cv2.fisheye.CALIB_CHECK_COND


#: The fisheye's coefficients held at 0 from the highest: ``fisheye_terms`` 4 fits k1..k4, 3 holds k4, and so on.
_FISHEYE_HOLD = {4: 0, 3: cv2.fisheye.CALIB_FIX_K4, 2: cv2.fisheye.CALIB_FIX_K4 | cv2.fisheye.CALIB_FIX_K3,
                 1: cv2.fisheye.CALIB_FIX_K4 | cv2.fisheye.CALIB_FIX_K3 | cv2.fisheye.CALIB_FIX_K2}


def _fisheye_calibrate(obj, img, image_size, flags: int):
    """``cv2.fisheye.calibrate`` on the views, raising :class:`IllConditionedView` for the view it could not use.

    OpenCV names the view whose pose fails its conditioning check. A view whose initial pose cannot be found at all
    (a degenerate detection: OpenCV 4.11 asserts ``fabs(norm_u1) > 0`` in ``InitExtrinsics``) is not named; it is
    the first view whose absence lets that step through. Any other failure is ``cv2.error``.
    """
    def calibrate(views):
        try:
            return cv2.fisheye.calibrate(
                [obj[j].reshape(-1, 1, 3) for j in views], [img[j].reshape(-1, 1, 2) for j in views],
                tuple(image_size), np.eye(3), np.zeros(4), flags=flags,
                criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10))
        except cv2.error as e:
            bad = re.search(r"Ill-conditioned matrix for input array (\d+)", str(e))
            if bad:
                raise IllConditionedView(views[int(bad.group(1))]) from None
            raise

    views = list(range(len(obj)))
    try:
        return calibrate(views)
    except cv2.error as e:
        if "InitExtrinsics" not in str(e):
            raise
        for left in views:
            try:
                calibrate(views[:left] + views[left + 1:])
            except cv2.error as again:
                if "InitExtrinsics" in str(again):
                    continue
            except IllConditionedView:
                pass
            raise IllConditionedView(left) from None
        raise


def _fit_fisheye(obj, img, image_size, terms: int) -> LensFit:
    """OpenCV's fisheye calibration (``cv2.fisheye.calibrate``, :data:`FISHEYE_FLAGS`, k1..k``terms`` free, fx and
    fy apart). Its solve reaches the least reprojection error (a joint Levenberg-Marquardt refinement from it
    moved no parameter by 1e-4 on the tests' views), so it is the fit."""
    _, k, d, rvecs, tvecs = _fisheye_calibrate(obj, img, image_size, FISHEYE_FLAGS | _FISHEYE_HOLD[terms])
    d = d.ravel()
    params = dict(fx_px=k[0, 0], fy_px=k[1, 1], cx_px=k[0, 2], cy_px=k[1, 2],
                  **{f"fisheye_k{n + 1}": d[n] for n in range(4)})
    res = [cv2.fisheye.projectPoints(o.reshape(-1, 1, 3), r, t, k, d)[0].reshape(-1, 2) - i
           for o, i, r, t in zip(obj, img, rvecs, tvecs)]
    return LensFit("fisheye", {key: float(v) for key, v in params.items()}, res, [r.ravel() for r in rvecs],
                   [t.ravel() for t in tvecs], image_size)


def fit_lens(object_points, image_points, image_size, model: str = "fov", fix_aspect: bool = True,
             fisheye_terms: int = 4) -> LensFit:
    """Fit a lens ``model`` (``"fov"``, ``"opencv"`` or ``"fisheye"``) to views of a planar target.

    ``object_points``: per view (N, 3) target coordinates (z = 0); ``image_points``: per view (N, 2) detected
    pixels. The poses start from OpenCV's pinhole calibration; then intrinsics and poses are refined together by
    Levenberg-Marquardt on the reprojection error (the paper uses damped Gauss-Newton, sec. 4.1). ``fix_aspect``
    ties fy to fx (square pixels). The fisheye model (k1..k``fisheye_terms`` free, the rest 0; fx and fy apart,
    as OpenCV fits them, ``fix_aspect`` not applied) is OpenCV's own fisheye calibration
    (``cv2.fisheye.calibrate``); it raises :class:`IllConditionedView` naming the view where OpenCV's
    conditioning check failed, and ``cv2.error`` where OpenCV's solve fails.
    """
    from scipy.optimize import least_squares

    width, height = image_size
    obj = [np.asarray(o, np.float64).reshape(-1, 3) for o in object_points]
    img = [np.asarray(i, np.float64).reshape(-1, 2) for i in image_points]
    if model == "fisheye":
        return _fit_fisheye(obj, img, image_size, fisheye_terms)
    flags = cv2.CALIB_FIX_ASPECT_RATIO if fix_aspect else 0
    k0 = np.array([[0.8 * width, 0, width / 2 - 0.5], [0, 0.8 * width, height / 2 - 0.5], [0, 0, 1]])
    _, k, dist, rvecs, tvecs = cv2.calibrateCamera([o.astype(np.float32) for o in obj],
                                                   [i.astype(np.float32) for i in img], (width, height), k0,
                                                   None, flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS)
    if model == "fov":
        p0 = [k[0, 0] / width, (k[0, 2] + 0.5) / width, (k[1, 2] + 0.5) / height, 0.3]
        if not fix_aspect:
            p0.append(k[1, 1] / height)
    else:
        d = dist.ravel()
        p0 = [k[0, 0], k[0, 2], k[1, 2], d[0], d[1], d[2], d[3], d[4] if len(d) > 4 else 0.0]
        if not fix_aspect:
            p0.append(k[1, 1])
    n_in = len(p0)
    poses = np.concatenate([np.concatenate([r.ravel(), t.ravel()]) for r, t in zip(rvecs, tvecs)])

    def residuals(p):
        lens, _ = _unpack(model, p[:n_in], width, height, fix_aspect)
        out = []
        for v, (o, i) in enumerate(zip(obj, img)):
            r = cv2.Rodrigues(p[n_in + 6 * v:n_in + 6 * v + 3])[0]
            cam = o @ r.T + p[n_in + 6 * v + 3:n_in + 6 * v + 6]
            u, vv = lens.distort(cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2])
            out.append(np.column_stack([u, vv]) - i)
        return np.concatenate(out).ravel()

    sol = least_squares(residuals, np.concatenate([p0, poses]), method="lm", x_scale="jac", max_nfev=2000)
    _, params = _unpack(model, sol.x[:n_in], width, height, fix_aspect)
    res = residuals(sol.x).reshape(-1, 2)
    split = np.cumsum([len(o) for o in obj])[:-1]
    rv = [sol.x[n_in + 6 * v:n_in + 6 * v + 3] for v in range(len(obj))]
    tv = [sol.x[n_in + 6 * v + 3:n_in + 6 * v + 6] for v in range(len(obj))]
    return LensFit(model, {k: float(v) for k, v in params.items()}, np.split(res, split), rv, tv, image_size)
