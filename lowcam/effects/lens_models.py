"""Lens models: the ideal pinhole camera plane to output pixels and back (Klein & Murray 2010, sec. 4.1).

A lens model maps the ideal pinhole camera plane (``x = X/Z``, ``y = Y/Z``; x right, y down, z forward) to output
pixels and back: :meth:`LensModel.distort` and :meth:`LensModel.undistort`. Pixel centres are on integers.

Models
------
``fov``
    Devernay & Faugeras' field-of-view model as in PTAM's ``ATANCamera``: ``r_d = atan(2 r tan(w/2)) / w``.
    Parameters ``fx, fy, cx, cy`` are normalised by the frame size (``fx_px = W fx``, ``cx_px = W cx - 0.5``),
    ``w`` in radians. Unlike PTAM, the small-radius branches use the continuous limit (PTAM switches to a factor
    of 1, which jumps by ``2 tan(w/2) / w`` at the centre).
``opencv``
    Brown-Conrady as in OpenCV: ``fx_px, fy_px, cx_px, cy_px`` and ``k1, k2, k3, p1, p2``. Without tangential
    terms, the inverse solves the radius alone; beyond the peak of ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)``, where
    the model has no inverse, it gives the peak.
``fisheye``
    OpenCV's fisheye model (Kannala-Brandt), as ``cv2.fisheye``: ``fx_px, fy_px, cx_px, cy_px`` and
    ``fisheye_k1 .. fisheye_k4`` on the ray's angle (see :class:`KannalaBrandtLens`).
``polynomial``, ``division``, ``nuke``, ``brown``
    Blender's motion-tracking camera models (libmv), with the names of ``clip.tracking.camera``: ``focal_length``
    and ``sensor_width`` in mm, ``principal_point`` in Blender's normalised frame coordinates (-1..1, y up),
    ``pixel_aspect`` and ``k1, k2, k3`` / ``division_k1, division_k2`` / ``nuke_k1, nuke_k2`` /
    ``brown_k1..brown_k4, brown_p1, brown_p2``. They are evaluated in Blender's pixel frame (origin bottom-left,
    y up), so a camera solved in Blender is used as it is.
``poly3``, ``poly5``, ``ptlens``
    Lensfun's distortion models with lensfun's normalisation and crop factors, so a lens-database entry is used
    as it is: ``focal_length`` (mm), ``crop_factor`` (the camera's), ``calibration_crop_factor`` and
    ``calibration_aspect_ratio`` (the lens entry's ``cropfactor`` and ``aspect-ratio``), ``lensfun_center`` and
    ``lensfun_k1`` / ``lensfun_k1, lensfun_k2`` / ``lensfun_a, lensfun_b, lensfun_c`` (see :class:`LensfunLens`).
    ``lensfun_geometry`` is the lens's projection, lensfun's lens type: ``rectilinear`` (the default),
    ``fisheye`` (equidistant), ``fisheye_equisolid``, ``fisheye_stereographic``, ``fisheye_orthographic`` or
    ``fisheye_thoby``; the distortion acts on the radius the projection gives, as in lensfun's geometry
    conversion, and the fisheyes see rays beyond 90 degrees (:meth:`LensModel.undistort_ray`).

Contents
--------
- :class:`LensModel`: mapping between the pinhole camera plane and output pixels, both ways
- :class:`PinholeLens`: no distortion: ``u = cx + fx x``
- :class:`FovLens`: Devernay & Faugeras' FOV model with PTAM's normalised parameters (``fov`` above)
- :class:`OpenCVLens`: Brown-Conrady with OpenCV's coefficients: radial k1, k2, k3 and tangential p1, p2
- :class:`KannalaBrandtLens`: OpenCV's fisheye model (``cv2.fisheye``): the ray's angle, distorted by an odd polynomial
- :class:`BlenderLens`: Blender's tracking-camera models (libmv), in Blender's pixel frame
- :data:`FULL_FRAME_HALF_DIAGONAL_MM`: half the diagonal of a 36 x 24 mm frame, the crop factors' reference
- :func:`lensfun_frame`: lensfun's normalised unit (px) and distortion centre on a frame (shared by TCA and
  vignetting)
- :data:`LENSFUN_GEOMETRIES`: lensfun's lens geometries (lens types) :class:`LensfunLens` projects
- :func:`lensfun_projection`, :func:`lensfun_projection_angle`: a ray's image radius in focal lengths through
  one of them, and back
- :func:`lensfun_projection_limit`: the largest ray angle a lensfun geometry maps one to one
- :class:`LensfunLens`: lensfun's poly3, poly5 and ptlens models on its lens geometries, normalised as lensfun does
- :data:`LENSFUN_FRAME_PARAMS`: the parameters placing lensfun's normalised coordinates on the frame
- :data:`MODEL_KEYS`, :data:`BLENDER_MODELS`, :data:`BLENDER_KEYS`, :data:`LENSFUN_MODELS`, :data:`LENSFUN_KEYS`: the
  models' names and each model's parameters
- :func:`border_points`: points along the border of a region of the frame
- :func:`field_needed`: the pinhole half-extents the border of a region of the frame sees through a lens

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Devernay2001] F. Devernay and O. Faugeras, "Straight lines have to be straight", Machine Vision and Applications
  13(1), 14-24, 2001.
- [Klein2007] G. Klein and D. Murray, "Parallel Tracking and Mapping for Small AR Workspaces", ISMAR 2007 (PTAM).
- [Brown1966] D. C. Brown, "Decentering Distortion of Lenses", Photogrammetric Engineering 32(3), 444-462, 1966.
- [Lensfun] A. Zabolotny et al., lensfun 0.3.4, ``libs/lensfun/modifier.cpp`` (the ``lfModifier`` constructor:
  normalisation and crop factors; ``Initialize``: the geometry's focal length) and ``libs/lensfun/mod-coord.cpp``
  (``ModifyCoord_Dist_Poly3/Poly5/PTLens``; ``AddCoordCallbackGeometry`` and ``ModifyCoord_Geom_*``: the lens
  geometries), https://github.com/lensfun/lensfun (tag v0.3.4).
- [Kannala2006] J. Kannala and S. S. Brandt, "A Generic Camera Model and Calibration Method for Conventional,
  Wide-Angle, and Fish-Eye Lenses", IEEE TPAMI 28(8), 1335-1340, 2006; OpenCV's ``cv2.fisheye`` module.
- [Dersch] H. Dersch, Panorama Tools (``a, b, c`` radial polynomial, the ``ptlens`` form), and lensfun's
  ``ModifyCoord_Dist_PTLens``; [Triggs2000] B. Triggs et al., "Bundle Adjustment - A Modern Synthesis", Vision
  Algorithms: Theory and Practice, LNCS 1883, 298-372, 2000 (robust losses in least squares, sec. 3.3).
"""
from __future__ import annotations


import numpy as np

from .base import Param


class LensModel:
    """Mapping between the pinhole camera plane and output pixels. Subclasses give one direction in closed form;
    the other is solved by Newton's method unless it also has a closed form."""

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)

    def distort(self, x, y):
        """Camera plane (x, y) -> output pixel (u, v)."""
        return self._solve(self.undistort, x, y, self.pinhole_distort)

    def undistort(self, u, v):
        """Output pixel (u, v) -> camera plane (x, y)."""
        return self._solve(self.distort, u, v, self.pinhole_undistort)

    def undistort_ray(self, u, v):
        """Output pixel (u, v) -> the ray it sees, as (theta, phi): the angle from the optical axis (rad, may pass
        90 degrees for a fisheye) and the azimuth ``atan2(y, x)`` on the camera plane (x right, y down)."""
        x, y = self.undistort(u, v)
        return np.arctan(np.hypot(x, y)), np.arctan2(y, x)

    def distort_ray(self, theta, phi):
        """The ray (theta, phi) (see :meth:`undistort_ray`) -> output pixel (u, v); rays at 90 degrees and beyond
        only for models that see them."""
        r = np.tan(np.asarray(theta, np.float64))
        return self.distort(r * np.cos(phi), r * np.sin(phi))

    # The pinhole part, used for starting guesses and by :meth:`pinhole`.
    def pinhole_distort(self, x, y):
        fx, fy, cx, cy = self.pinhole_intrinsics()
        return cx + fx * np.asarray(x), cy + fy * np.asarray(y)

    def pinhole_undistort(self, u, v):
        fx, fy, cx, cy = self.pinhole_intrinsics()
        return (np.asarray(u) - cx) / fx, (np.asarray(v) - cy) / fy

    def pinhole_intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in output pixels of the model without distortion."""
        raise NotImplementedError

    def pinhole(self) -> "PinholeLens":
        return PinholeLens(self.width, self.height, *self.pinhole_intrinsics())

    @staticmethod
    def _solve(forward, a, b, guess, iterations: int = 40, tol: float = 1e-12):
        """Solve ``forward(p, q) = (a, b)`` for (p, q) elementwise by damped Newton with a numeric Jacobian."""
        a = np.asarray(a, np.float64)
        b = np.asarray(b, np.float64)
        p, q = guess(a, b)
        p = np.array(p, np.float64)
        q = np.array(q, np.float64)
        h = 1e-7 * (1.0 + np.abs(p).max(initial=0.0) + np.abs(q).max(initial=0.0))
        for _ in range(iterations):
            fa, fb = forward(p, q)
            ra, rb = fa - a, fb - b
            if max(np.abs(ra).max(initial=0.0), np.abs(rb).max(initial=0.0)) < tol:
                break
            pa, pb = forward(p + h, q)
            qa, qb = forward(p, q + h)
            j11, j21 = (pa - fa) / h, (pb - fb) / h
            j12, j22 = (qa - fa) / h, (qb - fb) / h
            det = j11 * j22 - j12 * j21
            det = np.where(np.abs(det) < 1e-300, 1e-300, det)
            dp = (j22 * ra - j12 * rb) / det
            dq = (j11 * rb - j21 * ra) / det
            p -= dp
            q -= dq
        return p, q


def _solve_rising(value, slope, target, start, upper: float) -> np.ndarray:
    """For each of ``target`` (1-D), the ``x`` in [0, ``upper``] where the rising ``value(x)`` equals it: Newton's
    method with ``slope`` (the derivative) from ``start``, each point until its own step is below 1e-14, at most 50
    steps (the radial inverses of :class:`OpenCVLens` and :class:`KannalaBrandtLens`)."""
    x = np.clip(start, 0.0, upper)
    out = x.copy()
    active = np.arange(x.size)
    for _ in range(50):
        d = slope(x)
        step = (value(x) - target) / np.where(np.abs(d) < 1e-12, 1e-12, d)
        x = np.clip(x - step, 0.0, upper)
        out[active] = x
        moving = np.abs(step) >= 1e-14
        if not moving.any():
            break
        active, x, target = active[moving], x[moving], target[moving]
    return out


class PinholeLens(LensModel):
    """No distortion: ``u = cx + fx x``."""

    def __init__(self, width, height, fx, fy, cx, cy):
        super().__init__(width, height)
        self._k = (float(fx), float(fy), float(cx), float(cy))

    def pinhole_intrinsics(self):
        return self._k

    def distort(self, x, y):
        return self.pinhole_distort(x, y)

    def undistort(self, u, v):
        return self.pinhole_undistort(u, v)


class FovLens(LensModel):
    """Devernay & Faugeras' FOV model with PTAM's normalised parameters (see the module docstring)."""

    def __init__(self, width, height, fx, fy, cx, cy, w):
        super().__init__(width, height)
        self.fx, self.fy = width * fx, height * fy
        self.cx, self.cy = width * cx - 0.5, height * cy - 0.5
        self.w = float(w)
        self.d = 2.0 * np.tan(self.w / 2.0)

    def pinhole_intrinsics(self):
        return self.fx, self.fy, self.cx, self.cy

    def _radial_factor(self, r):
        """f(r) = atan(r d) / (w r): distorted radius over undistorted radius."""
        if self.w == 0.0:
            return np.ones_like(r)
        rd = r * self.d
        small = rd < 1e-4
        safe = np.where(small, 1.0, r)
        exact = np.arctan(safe * self.d) / (self.w * safe)
        series = (self.d / self.w) * (1.0 - rd * rd / 3.0)
        return np.where(small, series, exact)

    def _inverse_factor(self, rd):
        """g(rd) = tan(rd w) / (d rd): undistorted radius over distorted radius."""
        if self.w == 0.0:
            return np.ones_like(rd)
        t = rd * self.w
        small = t < 1e-4
        safe = np.where(small, 1.0, rd)
        exact = np.tan(safe * self.w) / (self.d * safe)
        series = (self.w / self.d) * (1.0 + t * t / 3.0)
        return np.where(small, series, exact)

    def distort(self, x, y):
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        f = self._radial_factor(np.hypot(x, y))
        return self.cx + self.fx * f * x, self.cy + self.fy * f * y

    def undistort(self, u, v):
        xd = (np.asarray(u, np.float64) - self.cx) / self.fx
        yd = (np.asarray(v, np.float64) - self.cy) / self.fy
        rd = np.hypot(xd, yd)
        if self.w > 0:
            # Beyond rd w = pi/2 the model has no inverse (the ray points backwards): clamp just inside.
            rd_max = (np.pi / 2 - 1e-6) / self.w
            scale = np.where(rd > rd_max, rd_max / np.maximum(rd, 1e-300), 1.0)
            xd, yd, rd = xd * scale, yd * scale, rd * scale
        g = self._inverse_factor(rd)
        return xd * g, yd * g


class OpenCVLens(LensModel):
    """Brown-Conrady with OpenCV's coefficients: radial k1, k2, k3 and tangential p1, p2."""

    def __init__(self, width, height, fx_px, fy_px, cx_px, cy_px, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0):
        super().__init__(width, height)
        self._k = (fx_px, fy_px, cx_px, cy_px)
        self.k1, self.k2, self.k3, self.p1, self.p2 = k1, k2, k3, p1, p2

    def pinhole_intrinsics(self):
        return self._k

    def distort(self, x, y):
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return self.pinhole_distort(xd, yd)

    def undistort(self, u, v):
        """Without tangential terms, the radius alone: Newton's method on ``r (1 + k1 r^2 + k2 r^4 + k3 r^6) = r_d``
        from one fixed-point step, ``r = r_d / (1 + k1 r_d^2 + ...)``, each point until its own step is below
        1e-14; beyond the rising branch's peak, where the model has no inverse, the peak. With tangential terms,
        the general 2-D solve."""
        if self.p1 or self.p2:
            return super().undistort(u, v)
        xd, yd = self.pinhole_undistort(np.asarray(u, np.float64), np.asarray(v, np.float64))
        if not (self.k1 or self.k2 or self.k3):
            return xd, yd
        rd = np.hypot(xd, yd)
        k1, k2, k3 = self.k1, self.k2, self.k3

        def radial(r2):
            return 1 + r2 * (k1 + r2 * (k2 + r2 * k3))

        peaks = [z.real for z in np.roots([7 * k3, 5 * k2, 3 * k1, 1.0]) if abs(z.imag) < 1e-12 and z.real > 0]
        r_max = float(np.sqrt(min(peaks))) if peaks else np.inf  # the slope's first zero (found in r^2)
        rd_max = r_max * radial(r_max ** 2) if peaks else np.inf
        r = np.full_like(rd, r_max)
        active = np.flatnonzero(rd < rd_max)
        target = rd.ravel()[active]
        guess = radial(target * target)

        def slope(x):
            x2 = x * x
            return 1 + x2 * (3 * k1 + x2 * (5 * k2 + 7 * k3 * x2))

        r.ravel()[active] = _solve_rising(lambda x: x * radial(x * x), slope, target,
                                          target / np.where(guess > 1e-3, guess, 1e-3), r_max)
        g = np.where(rd > 0, r / np.maximum(rd, 1e-300), 1.0)
        return xd * g, yd * g


class KannalaBrandtLens(LensModel):
    """OpenCV's fisheye model (``cv2.fisheye``, after Kannala & Brandt [Kannala2006]): a ray at angle
    ``theta = atan(r)`` from the axis lands at radius ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
    k4 theta^8)`` on the normalised image plane, ``u = fx theta_d x / r + cx`` (pixel centres on integers, as
    OpenCV's). Rays at 90 degrees and beyond cannot be written as ``x = X/Z``; the inverse gives the angle where
    ``theta_d`` stops rising, or just short of 90 degrees."""

    def __init__(self, width, height, fx_px, fy_px, cx_px, cy_px, k1=0.0, k2=0.0, k3=0.0, k4=0.0):
        super().__init__(width, height)
        self._k = (fx_px, fy_px, cx_px, cy_px)
        self.k = (float(k1), float(k2), float(k3), float(k4))

    def pinhole_intrinsics(self):
        return self._k

    def theta_d(self, theta):
        """The distorted angle (normalised image radius) of a ray ``theta`` rad from the axis."""
        k1, k2, k3, k4 = self.k
        t2 = np.asarray(theta, np.float64) ** 2
        return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def theta_rising(self) -> float:
        """The largest angle (rad) the model maps one to one: where ``theta_d`` stops rising, at most 180 degrees."""
        k1, k2, k3, k4 = self.k
        roots = np.roots([9 * k4, 7 * k3, 5 * k2, 3 * k1, 1.0]) if any(self.k) else []   # the slope's zeros in theta^2
        peaks = [float(np.sqrt(z.real)) for z in roots if abs(z.imag) < 1e-12 and z.real > 0]
        return min(peaks + [np.pi])

    def theta_max(self) -> float:
        """The largest angle (rad) the camera plane ``x = X/Z`` can carry: :meth:`theta_rising`, at most just short
        of 90 degrees."""
        return min(self.theta_rising(), np.pi / 2 - 1e-3)

    def distort(self, x, y):
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        r = np.hypot(x, y)
        theta = np.arctan(r)
        scale = np.where(r > 1e-12, self.theta_d(theta) / np.maximum(r, 1e-300), 1.0)
        return self.pinhole_distort(x * scale, y * scale)

    def distort_ray(self, theta, phi):
        rd = self.theta_d(np.asarray(theta, np.float64))
        return self.pinhole_distort(rd * np.cos(phi), rd * np.sin(phi))

    def _theta(self, rd, t_max):
        """The angle whose distorted radius is ``rd``: Newton's method on ``theta_d(theta) = rd``
        (:func:`_solve_rising`) from ``theta = rd``, or where that stalls, from just below the root; beyond ``t_max``,
        ``t_max``."""
        k1, k2, k3, k4 = self.k

        def slope(t):
            t2 = t * t
            return 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + 9 * k4 * t2)))

        theta = np.full_like(rd, t_max)
        active = np.flatnonzero(rd < self.theta_d(t_max))
        target = rd.ravel()[active]
        solved = _solve_rising(self.theta_d, slope, target, target, t_max)
        # From rd itself, past the peak of theta_d (slope 0 there), Newton stalls at t_max for radii just short of
        # the peak's: those start again just below their root, found by bisection to t_max / 2^24
        stalled = np.flatnonzero(np.abs(self.theta_d(solved) - target) > 1e-9)
        if stalled.size:
            low, high = np.zeros(stalled.size), np.full(stalled.size, t_max)
            for _ in range(24):
                mid = 0.5 * (low + high)
                below = self.theta_d(mid) < target[stalled]
                low, high = np.where(below, mid, low), np.where(below, high, mid)
            solved[stalled] = _solve_rising(self.theta_d, slope, target[stalled], low, t_max)
        theta.ravel()[active] = solved
        return theta

    def undistort(self, u, v):
        """The camera plane's point of each pixel; beyond :meth:`theta_max`, the ray at ``theta_max``."""
        xd, yd = self.pinhole_undistort(np.asarray(u, np.float64), np.asarray(v, np.float64))
        rd = np.hypot(xd, yd)
        theta = self._theta(rd, self.theta_max())
        g = np.where(rd > 0, np.tan(theta) / np.maximum(rd, 1e-300), 1.0)
        return xd * g, yd * g

    def undistort_ray(self, u, v):
        """The ray of each pixel, out to :meth:`theta_rising` (beyond it, the ray at ``theta_rising``)."""
        xd, yd = self.pinhole_undistort(np.asarray(u, np.float64), np.asarray(v, np.float64))
        return self._theta(np.hypot(xd, yd), self.theta_rising()), np.arctan2(yd, xd)


class BlenderLens(LensModel):
    """Blender's tracking-camera models (libmv), in Blender's pixel frame (origin bottom-left, y up)."""

    def __init__(self, width, height, model, focal_length, sensor_width, principal_point=(0.0, 0.0),
                 pixel_aspect=1.0, **coefficients):
        super().__init__(width, height)
        self.model = model
        self.c = coefficients
        self.f = focal_length / sensor_width * width
        self.aspect = pixel_aspect
        # Blender's normalised principal point (-1..1) -> pixels from the bottom-left corner.
        self.ppx = (principal_point[0] + 1.0) * 0.5 * width
        self.ppy = (principal_point[1] + 1.0) * 0.5 * height * pixel_aspect

    def _to_blender(self, u, v):
        return np.asarray(u, np.float64) + 0.5, (self.height - 0.5 - np.asarray(v, np.float64)) * self.aspect

    def _from_blender(self, bx, by):
        return bx - 0.5, self.height - 0.5 - by / self.aspect

    def pinhole_intrinsics(self):
        # y flips between the camera plane (down) and Blender's pixels (up); the y focal length is negative there.
        cx, cy = self._from_blender(self.ppx, self.ppy)
        return self.f, self.f / self.aspect, cx, cy

    def _apply(self, x, y):
        """libmv's Apply*DistortionModel: normalised (y up) -> Blender pixels."""
        c, f = self.c, self.f
        r2 = x * x + y * y
        if self.model == "polynomial":
            radial = 1 + r2 * (c.get("k1", 0) + r2 * (c.get("k2", 0) + r2 * c.get("k3", 0)))
            return f * x * radial + self.ppx, f * y * radial + self.ppy
        if self.model == "division":
            den = 1 + r2 * (c.get("division_k1", 0) + r2 * c.get("division_k2", 0))
            return f * x / den + self.ppx, f * y / den + self.ppy
        if self.model == "brown":
            k1, k2, k3, k4 = (c.get(f"brown_k{i}", 0) for i in range(1, 5))
            p1, p2 = c.get("brown_p1", 0), c.get("brown_p2", 0)
            radial = 1 + (((k4 * r2 + k3) * r2 + k2) * r2 + k1) * r2
            xd = x * radial + p1 * (r2 + 2 * x * x) + p2 * 2 * x * y
            yd = y * radial + p2 * (r2 + 2 * y * y) + p1 * 2 * x * y
            return f * xd + self.ppx, f * yd + self.ppy
        # nuke: closed form only in the inverse direction
        return LensModel._solve(self._invert_nuke, x, y, lambda a, b: (f * a + self.ppx, f * b + self.ppy))

    def _invert_nuke(self, bx, by):
        """libmv's InvertNukeDistortionModel: Blender pixels -> normalised (y up)."""
        half = max(self.width, self.height) * 0.5
        xd, yd = (bx - self.ppx) / half, (by - self.ppy) / half
        rd2 = xd * xd + yd * yd
        k = 1.0 / (1 + rd2 * (self.c.get("nuke_k1", 0) + rd2 * self.c.get("nuke_k2", 0)))
        return xd * k * half / self.f, yd * k * half / self.f

    def distort(self, x, y):
        bx, by = self._apply(np.asarray(x, np.float64), -np.asarray(y, np.float64))
        return self._from_blender(bx, by)

    def undistort(self, u, v):
        bx, by = self._to_blender(u, v)
        if self.model == "nuke":
            xn, yn = self._invert_nuke(bx, by)
        else:
            xn, yn = LensModel._solve(self._apply, bx, by,
                                      lambda a, b: ((a - self.ppx) / self.f, (b - self.ppy) / self.f))
        return xn, -yn


#: Half the diagonal of a 36 x 24 mm frame, the crop factors' reference (lensfun's ``NormalizedInMillimeters``).
FULL_FRAME_HALF_DIAGONAL_MM = 0.5 * float(np.hypot(36.0, 24.0))


def lensfun_frame(width, height, crop_factor=1.0, calibration_crop_factor=1.0, calibration_aspect_ratio=1.5,
                  center=(0.0, 0.0)) -> tuple[float, float, float]:
    """Lensfun's normalised coordinates on a ``width`` x ``height`` frame (pixel centres at integers):
    ``(unit_px, u0, v0)``, the length of one normalised unit in pixels and the centre of the distortion, TCA and
    vignetting models (lensfun 0.3.4 ``lfModifier`` constructor: ``NormScale``, ``CenterX``, ``CenterY``).

    One unit is half the shorter side of the *calibration* sensor: ``hypot(W - 1, H - 1) / 2 * crop_factor /
    calibration_crop_factor / sqrt(1 + calibration_aspect_ratio^2)`` px; the centre is the frame centre moved by
    ``center`` (the lens entry's ``center``) in half the frame's shorter side. Lensfun's vignetting radius is this
    normalised radius over ``sqrt(1 + calibration_aspect_ratio^2)`` (1 at the calibration sensor's corner).
    """
    a = float(np.sqrt(1.0 + calibration_aspect_ratio ** 2))
    unit_px = 0.5 * float(np.hypot(width - 1.0, height - 1.0)) * crop_factor / calibration_crop_factor / a
    half = 0.5 * min(width - 1.0, height - 1.0)
    return unit_px, 0.5 * (width - 1.0) + center[0] * half, 0.5 * (height - 1.0) + center[1] * half


#: Lensfun's lens geometries (its ``lfLensType`` names, lower case) that :class:`LensfunLens` projects.
LENSFUN_GEOMETRIES = ("rectilinear", "fisheye", "fisheye_equisolid", "fisheye_stereographic", "fisheye_orthographic",
                      "fisheye_thoby")
#: Thoby's fisheye, ``r = K1 f sin(K2 theta)`` (lensfun's ``THOBY_K1_PARM``, ``THOBY_K2_PARM``).
THOBY_K1, THOBY_K2 = 1.47, 0.713


def lensfun_projection(geometry: str, theta):
    """Image radius, in focal lengths, of a ray ``theta`` rad from the axis through lensfun's lens ``geometry``
    (lensfun 0.3.4 ``mod-coord.cpp``, ``ModifyCoord_Geom_*``): ``tan theta`` (rectilinear), ``theta`` (fisheye,
    equidistant), ``2 sin(theta / 2)`` (equisolid), ``2 tan(theta / 2)`` (stereographic), ``sin theta``
    (orthographic), ``K1 sin(K2 theta)`` (Thoby)."""
    t = np.asarray(theta, np.float64)
    if geometry == "rectilinear":
        return np.tan(t)
    if geometry == "fisheye":
        return t
    if geometry == "fisheye_equisolid":
        return 2.0 * np.sin(t / 2.0)
    if geometry == "fisheye_stereographic":
        return 2.0 * np.tan(t / 2.0)
    if geometry == "fisheye_orthographic":
        return np.sin(t)
    if geometry == "fisheye_thoby":
        return THOBY_K1 * np.sin(THOBY_K2 * t)
    raise ValueError(f"unknown lensfun geometry {geometry!r}")


def lensfun_projection_angle(geometry: str, radius):
    """The ray's angle (rad) from the axis of an image radius in focal lengths: :func:`lensfun_projection`'s
    inverse, out to :func:`lensfun_projection_limit` (radii beyond give the limit)."""
    r = np.maximum(np.asarray(radius, np.float64), 0.0)
    if geometry == "rectilinear":
        return np.arctan(r)
    if geometry == "fisheye":
        return np.minimum(r, np.pi)
    if geometry == "fisheye_equisolid":
        return 2.0 * np.arcsin(np.minimum(r / 2.0, 1.0))
    if geometry == "fisheye_stereographic":
        return 2.0 * np.arctan(r / 2.0)
    if geometry == "fisheye_orthographic":
        return np.arcsin(np.minimum(r, 1.0))
    if geometry == "fisheye_thoby":
        return np.arcsin(np.minimum(r / THOBY_K1, 1.0)) / THOBY_K2
    raise ValueError(f"unknown lensfun geometry {geometry!r}")


def lensfun_projection_limit(geometry: str) -> float:
    """The largest ray angle (rad) a lensfun geometry maps one to one: where its radius stops rising (90 degrees
    for the orthographic fisheye, ``90 / K2`` degrees for Thoby's), else 180 degrees (90, never reached, for the
    rectilinear)."""
    return {"rectilinear": np.pi / 2, "fisheye_orthographic": np.pi / 2,
            "fisheye_thoby": np.pi / 2 / THOBY_K2}.get(geometry, np.pi)


class LensfunLens(LensModel):
    """Lensfun's distortion models (``poly3``, ``poly5``, ``ptlens``) on its lens geometries, normalised as lensfun
    0.3 does.

    ``Rd = Ru (1 - k1 + k1 Ru^2)`` (poly3), ``Rd = Ru (1 + k1 Ru^2 + k2 Ru^4)`` (poly5) and
    ``Rd = Ru (a Ru^3 + b Ru^2 + c Ru + 1 - a - b - c)`` (ptlens), with the radii in lensfun's normalised unit:
    half the shorter side of the *calibration* sensor. On a frame of ``W x H`` pixels (pixel centres at
    integers) taken with crop factor ``crop_factor``, one unit is ``hypot(W - 1, H - 1) / 2 * crop_factor /
    calibration_crop_factor / sqrt(1 + calibration_aspect_ratio^2)`` pixels (lensfun's ``lfModifier``
    constructor: ``NormScale = 2 / size * coordinate_correction``; crop factors are ratios of sensor
    diagonals). The distortion centre is the frame centre ``((W - 1) / 2, (H - 1) / 2)`` moved by ``center``
    (lensfun's ``CenterX, CenterY``) in units of half the frame's shorter side (``size / 2``, not corrected).
    The undistorted radius is ``Ru = F g(theta)`` for a ray ``theta`` from the axis, with ``g`` the lens's
    ``geometry`` (:func:`lensfun_projection`: ``tan theta`` for a rectilinear lens, so ``Ru = F r`` on the
    camera plane; ``theta`` for lensfun's ``fisheye``, the equidistant one; equisolid, stereographic,
    orthographic, Thoby) and ``F`` ``focal_length`` (mm) over the unit in mm: ``hypot(36, 24) / 2 /
    calibration_crop_factor / sqrt(1 + calibration_aspect_ratio^2)`` (lensfun's ``NormalizedInMillimeters``;
    as lensfun and Hugin do for poly3 and ptlens, the focal length is the one of the undistorted coordinates, so
    the centre's scale is ``1 - k1`` or ``1 - a - b - c`` of it). Lensfun's geometry conversion
    (``lfModifier::AddCoordCallbackGeometry``) is this ``Ru`` of the ray of the rectilinear pixel.

    Beyond the radius where ``Rd`` stops rising with ``Ru`` the model has no inverse: pixels there see the ray at
    that radius (:meth:`ru_max`), as :class:`OpenCVLens` does. :meth:`undistort_ray` gives rays beyond 90
    degrees for the fisheyes; the camera plane of :meth:`undistort` stops just short of 90 degrees.
    """

    def __init__(self, width, height, model, terms, focal_length, crop_factor=1.0, calibration_crop_factor=1.0,
                 calibration_aspect_ratio=1.5, center=(0.0, 0.0), geometry="rectilinear"):
        super().__init__(width, height)
        self.model, self.terms = model, tuple(float(t) for t in terms)
        if geometry not in LENSFUN_GEOMETRIES:
            raise ValueError(f"unknown lensfun geometry {geometry!r}")
        self.geometry = geometry
        a = float(np.sqrt(1.0 + calibration_aspect_ratio ** 2))
        self.unit_px, self.u0, self.v0 = lensfun_frame(width, height, crop_factor, calibration_crop_factor,
                                                       calibration_aspect_ratio, center)
        self.unit_mm = FULL_FRAME_HALF_DIAGONAL_MM / calibration_crop_factor / a
        self.scale = focal_length / self.unit_mm  # camera plane -> normalised undistorted radius

    def pinhole_intrinsics(self):
        f = self.unit_px * self.scale
        return f, f, self.u0, self.v0

    def factor(self, ru):
        """Rd / Ru at normalised undistorted radius ``ru``."""
        t = self.terms
        if self.model == "poly3":
            return 1.0 - t[0] + t[0] * ru * ru
        if self.model == "poly5":
            r2 = ru * ru
            return 1.0 + r2 * (t[0] + r2 * t[1])
        a, b, c = t
        return ((a * ru + b) * ru + c) * ru + 1.0 - a - b - c

    def _slope(self, ru):
        """d(Rd)/d(Ru)."""
        t = self.terms
        if self.model == "poly3":
            return 1.0 - t[0] + 3.0 * t[0] * ru * ru
        if self.model == "poly5":
            r2 = ru * ru
            return 1.0 + r2 * (3.0 * t[0] + 5.0 * r2 * t[1])
        a, b, c = t
        return ((4.0 * a * ru + 3.0 * b) * ru + 2.0 * c) * ru + 1.0 - a - b - c

    def ru_max(self) -> float:
        """The largest normalised undistorted radius the lens maps one to one: where ``Rd`` stops rising with
        ``Ru`` (the slope's first positive zero), at most the geometry's radius at
        :func:`lensfun_projection_limit` (infinite for a rectilinear lens whose ``Rd`` always rises)."""
        t = self.terms
        if self.model == "poly3":
            slope = [3.0 * t[0], 0.0, 1.0 - t[0]]
        elif self.model == "poly5":
            slope = [5.0 * t[1], 0.0, 3.0 * t[0], 0.0, 1.0]
        else:
            slope = [4.0 * t[0], 3.0 * t[1], 2.0 * t[2], 1.0 - t[0] - t[1] - t[2]]
        peaks = [z.real for z in np.roots(slope) if abs(z.imag) < 1e-12 and z.real > 0] if any(slope[:-1]) else []
        limit = lensfun_projection_limit(self.geometry)
        reach = np.inf if self.geometry == "rectilinear" else self.scale * float(lensfun_projection(self.geometry,
                                                                                                    limit))
        return float(min(peaks + [reach]))

    def rd_max(self) -> float:
        """The normalised distorted radius at :meth:`ru_max`: the frame must lie within it."""
        ru = self.ru_max()
        return float(ru * self.factor(ru)) if np.isfinite(ru) else np.inf

    def _ru(self, rd):
        """The normalised undistorted radius of each distorted radius ``rd`` (Newton's method,
        :func:`_solve_rising`); beyond :meth:`rd_max`, :meth:`ru_max`."""
        ru_max = self.ru_max()
        ru = np.full_like(rd, ru_max)
        active = np.flatnonzero(rd < self.rd_max())
        target = rd.ravel()[active]
        ru.ravel()[active] = _solve_rising(lambda r: r * self.factor(r), self._slope, target,
                                           target / max(self.factor(0.0), 1e-6), ru_max)
        return ru

    def distort(self, x, y):
        if self.geometry != "rectilinear":
            x = np.asarray(x, np.float64)
            y = np.asarray(y, np.float64)
            return self.distort_ray(np.arctan(np.hypot(x, y)), np.arctan2(y, x))
        xn = self.scale * np.asarray(x, np.float64)
        yn = self.scale * np.asarray(y, np.float64)
        f = self.factor(np.hypot(xn, yn)) * self.unit_px
        return self.u0 + f * xn, self.v0 + f * yn

    def distort_ray(self, theta, phi):
        """The output pixel of the ray (theta, phi): ``Ru = F g(theta)`` through the distortion; for the
        fisheyes, rays beyond 90 degrees too."""
        if self.geometry == "rectilinear":
            return super().distort_ray(theta, phi)
        ru = self.scale * lensfun_projection(self.geometry, theta)
        rd = ru * self.factor(ru) * self.unit_px
        return self.u0 + rd * np.cos(phi), self.v0 + rd * np.sin(phi)

    def undistort_ray(self, u, v):
        """The ray of each pixel (theta, phi), out to :meth:`ru_max` (beyond 90 degrees for the fisheyes that
        see so far)."""
        xd = (np.asarray(u, np.float64) - self.u0) / self.unit_px
        yd = (np.asarray(v, np.float64) - self.v0) / self.unit_px
        if self.geometry == "rectilinear":
            x, y = self._undistort_rectilinear(xd, yd)
            return np.arctan(np.hypot(x, y)), np.arctan2(y, x)
        theta = lensfun_projection_angle(self.geometry, self._ru(np.hypot(xd, yd)) / self.scale)
        return theta, np.arctan2(yd, xd)

    def undistort(self, u, v):
        """The camera plane's point of each pixel; for the fisheyes, rays at 90 degrees and beyond give the ray
        just short of 90 degrees (as :class:`KannalaBrandtLens`)."""
        xd = (np.asarray(u, np.float64) - self.u0) / self.unit_px
        yd = (np.asarray(v, np.float64) - self.v0) / self.unit_px
        if self.geometry == "rectilinear":
            return self._undistort_rectilinear(xd, yd)
        theta, phi = self.undistort_ray(u, v)
        r = np.tan(np.minimum(theta, np.pi / 2 - 1e-3))
        return r * np.cos(phi), r * np.sin(phi)

    def _undistort_rectilinear(self, xd, yd):
        """Normalised distorted (xd, yd) -> camera plane, for a rectilinear lens: Newton on Ru(Rd), as lensfun's
        ``ModifyCoord_UnDist_*``; beyond :meth:`rd_max`, :meth:`ru_max`."""
        rd = np.hypot(xd, yd)
        ru = rd / max(self.factor(0.0), 1e-6)
        for _ in range(50):  # Newton on Ru (Rd), as lensfun's ModifyCoord_UnDist_*
            step = (ru * self.factor(ru) - rd) / np.where(np.abs(s := self._slope(ru)) < 1e-9, 1e-9, s)
            ru = np.maximum(ru - step, 0.0)
            if np.abs(step).max(initial=0.0) < 1e-13:
                break
        rd_max = self.rd_max()
        if np.isfinite(rd_max):
            ru = np.where(rd >= rd_max, self.ru_max(), ru)  # no inverse beyond the peak: the peak's ray
        g = np.where(rd > 0, ru / np.maximum(rd, 1e-300), 1.0 / max(self.factor(0.0), 1e-6)) / self.scale
        return xd * g, yd * g


MODEL_KEYS = {
    "fov": ("fx", "fy", "cx", "cy", "w"),
    "opencv": ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "k3", "p1", "p2"),
    "fisheye": ("fx_px", "fy_px", "cx_px", "cy_px", "fisheye_k1", "fisheye_k2", "fisheye_k3", "fisheye_k4"),
    "polynomial": ("k1", "k2", "k3"),
    "division": ("division_k1", "division_k2"),
    "nuke": ("nuke_k1", "nuke_k2"),
    "brown": ("brown_k1", "brown_k2", "brown_k3", "brown_k4", "brown_p1", "brown_p2"),
    "poly3": ("lensfun_k1",),
    "poly5": ("lensfun_k1", "lensfun_k2"),
    "ptlens": ("lensfun_a", "lensfun_b", "lensfun_c"),
}
BLENDER_MODELS = ("polynomial", "division", "nuke", "brown")
LENSFUN_MODELS = ("poly3", "poly5", "ptlens")
LENSFUN_KEYS = ("focal_length", "crop_factor", "calibration_crop_factor", "calibration_aspect_ratio",
                 "lensfun_center", "lensfun_geometry")
BLENDER_KEYS = ("focal_length", "sensor_width", "principal_point", "pixel_aspect")


#: Where lensfun's normalised coordinates sit on the frame (:func:`lensfun_frame`): the parameters every effect in
#: lensfun's terms (distortion, TCA, vignetting) shares.
LENSFUN_FRAME_PARAMS = {
    "crop_factor": Param(1.0, low=0.1, high=100.0, doc="lensfun models: the camera's crop factor"),
    "calibration_crop_factor": Param(1.0, low=0.1, high=100.0,
                                     doc="lensfun models: crop factor of the camera the lens was calibrated on"),
    "calibration_aspect_ratio": Param(1.5, low=1.0, high=10.0,
                                      doc="lensfun models: long / short side of the calibration sensor"),
    "lensfun_center": Param([0.0, 0.0], "vector", length=2, low=-1.0, high=1.0,
                            doc="lensfun models: centre from the frame centre, in half the shorter side, y down"),
}


def border_points(extent, per_side: int = 257) -> tuple[np.ndarray, np.ndarray]:
    """Points (u, v) along the border of ``extent`` (u0, v0, u1, v1; output pixels), ``per_side`` on each side,
    corners included, clockwise from the top-left corner."""
    u0, v0, u1, v1 = extent
    t = np.linspace(0.0, 1.0, per_side)
    return (np.concatenate([u0 + (u1 - u0) * t, np.full_like(t, u1), u1 - (u1 - u0) * t, np.full_like(t, u0)]),
            np.concatenate([np.full_like(t, v0), v0 + (v1 - v0) * t, np.full_like(t, v1), v1 - (v1 - v0) * t]))


def field_needed(lens: LensModel, extent) -> tuple[float, float]:
    """Pinhole half-extents (X, Y) that the border of ``extent`` (u0, v0, u1, v1; output pixels) sees through
    ``lens``."""
    x, y = lens.undistort(*border_points(extent))
    return float(np.abs(x).max()), float(np.abs(y).max())
