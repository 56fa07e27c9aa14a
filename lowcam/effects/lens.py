"""The lens-distortion stage (Klein & Murray 2010, sec. 5.2 step 1) and its diagnosis candidate.

:class:`LensDistortion` warps the render, a pinhole one or for the widest lenses Cycles' equidistant fisheye, through
the profile's lens model (:mod:`.lens_models`) into the working grid, 2x2 supersampled.

Diagnosis (the ``radial_distortion`` candidate, :func:`fit_radial_distortion`): the lens is fitted to where the
optical flow says the measured frames look, by robust least squares (Cauchy's loss) with walls against a lens that
folds over or sees beyond the render before the frame's border, in the profile's form or a wider one (Brown-
Conrady, FOV, Panorama Tools' ptlens [Dersch]).

Contents
--------
- :data:`RENDER_PROJECTIONS`: the render's projections (pinhole, Cycles' equidistant fisheye, or automatic)
- :data:`PINHOLE_FIELD_LIMIT_DEG`: the widest field an automatic projection renders through a pinhole
- :func:`ray_angle_needed`: the widest ray angle the border of a region of the frame sees through a lens
- :data:`ROUND_TRIP_PX`, :func:`frame_round_trip`: how far a point of the frame misses itself through the lens's
  inverse and back (where the mapping folds over inside the frame)
- :data:`FOLD_SHARE`, :func:`share_beyond`: how much of the frame may lie beyond where a radial lens's radius stops
  rising (its corners, held at the ray there)
- :func:`lens_model_from`: the lens model of a dict of :class:`LensDistortion` parameters, unvalidated (a fit's
  trial values)
- :class:`LensDistortion`: warps the pinhole render through the lens into the working grid, 2x2 supersampled (sec.
  5.2 steps 1-2)
- :data:`FIT_KEYS`: per lens model, the parameters the ``radial_distortion`` candidate fits
- :func:`range_of`: the ranges of the parameters the candidate fits in a lens model
- :func:`fold_and_shortfall`: per ray to the frame's border, how far a lens is from seeing it unfolded inside the
  render (continuous in the lens's parameters)
- :func:`fit_radial_distortion`: the candidate: distortion, focal length and centre from the optical flow, the
  render's field of view held, in the profile's lens form or a wider one; :class:`~lowcam.errors.NotFitted` with
  the reason where none can be fitted

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Dersch] H. Dersch, Panorama Tools (``a, b, c`` radial polynomial, the ``ptlens`` form), and lensfun's
  ``ModifyCoord_Dist_PTLens``; [Triggs2000] B. Triggs et al., "Bundle Adjustment - A Modern Synthesis", Vision
  Algorithms: Theory and Practice, LNCS 1883, 298-372, 2000 (robust losses in least squares, sec. 3.3).
"""
from __future__ import annotations

import copy

import cv2
import numpy as np

from ..errors import LowcamError, NotFitted
from ..node_images import stmap
from ..window import WindowedRemap
from .base import Effect, NodeStage, Param, Search
from .bayer import sensel_shift_px
from .lens_models import (BLENDER_KEYS, BLENDER_MODELS, FULL_FRAME_HALF_DIAGONAL_MM, LENSFUN_FRAME_PARAMS,
                          LENSFUN_GEOMETRIES, LENSFUN_KEYS, LENSFUN_MODELS, MODEL_KEYS, BlenderLens, FovLens,
                          KannalaBrandtLens, LensfunLens, LensModel, OpenCVLens, border_points, field_needed,
                          lensfun_frame, lensfun_projection, lensfun_projection_limit)


#: The render's projections (``render_projection``): ``auto`` picks one per lens (:meth:`LensDistortion.projection`).
RENDER_PROJECTIONS = ("auto", "pinhole", "fisheye_equidistant")

#: The widest field (deg, across the frame's diagonal) ``auto`` renders through a pinhole: beyond it a pinhole
#: render spends most of its pixels on the border (its scale there grows as 1 / cos^2 of the ray's angle, 15x at
#: 75 deg) and at 180 deg it sees nothing more.
PINHOLE_FIELD_LIMIT_DEG = 150.0


def ray_angle_needed(lens: LensModel, extent) -> float:
    """The widest angle (rad) from the optical axis that the border of ``extent`` (u0, v0, u1, v1; output pixels)
    sees through ``lens`` (:meth:`LensModel.undistort_ray`: may pass 90 deg)."""
    theta, _ = lens.undistort_ray(*border_points(extent))
    return float(np.max(theta))


#: How far (px) a pixel of the frame may land from itself through the lens's inverse and back
#: (:func:`frame_round_trip`); beyond it the mapping folds over there, or leaves what the model can carry.
ROUND_TRIP_PX = 1e-3


def frame_round_trip(lens: LensModel, width: int, height: int, per_side: int = 33) -> tuple[float, float, float]:
    """``(error, u, v)``: how far (px) a point of a ``width`` x ``height`` frame misses itself when taken to the
    ray it sees (:meth:`LensModel.undistort_ray`) and back (:meth:`LensModel.distort_ray`), the worst over a
    ``per_side`` x ``per_side`` grid and 257 points a side along the border (outer pixel edges, ``-1/2`` to
    ``width - 1/2``), and where (u, v). Inf where a value is not finite. Where the lens maps its rays one to one
    out to the frame's border this is the inverse's precision (Newton's, under 1e-6 px); where its radius stops
    rising inside the frame (a fit's terms beyond the field it was fitted over), the inverse stops at the peak
    and the points beyond miss by their distance to it. For a radial model the border alone decides (a pixel
    inside lies at a smaller radius than some border pixel); the grid covers the tangential terms."""
    gu, gv = np.meshgrid(np.linspace(-0.5, width - 0.5, per_side), np.linspace(-0.5, height - 0.5, per_side))
    bu, bv = border_points((-0.5, -0.5, width - 0.5, height - 0.5))
    u, v = np.concatenate([gu.ravel(), bu]), np.concatenate([gv.ravel(), bv])
    with np.errstate(all="ignore"):
        back_u, back_v = lens.distort_ray(*lens.undistort_ray(u, v))
        error = np.hypot(back_u - u, back_v - v)
    error = np.where(np.isfinite(error), error, np.inf)
    worst = int(np.argmax(error))
    return float(error[worst]), float(u[worst]), float(v[worst])


#: A radial lens's radius may stop rising inside the frame where the frame's pixels beyond make up at most this share
#: of it: a calibration's terms hold over the field its target covered, which seldom reaches the outermost corners
#: (a polynomial fitted there turns just past them). Those pixels see the ray where the radius stops, as the edge of
#: an image circle does.
FOLD_SHARE = 0.02


def share_beyond(lens: LensModel, rd_limit: float, extent) -> float:
    """The share of the frame ``extent`` (left, top, right, bottom: outer pixel edges) whose points lie beyond the
    normalised distorted radius ``rd_limit`` of ``lens``'s principal point, on a 512 x 512 grid of equal cells.

    >>> from lowcam.effects.lens_models import PinholeLens
    >>> round(share_beyond(PinholeLens(100, 100, 50.0, 50.0, 49.5, 49.5), 1.0, (-0.5, -0.5, 99.5, 99.5)), 2)
    0.21
    """
    fx, fy, cx, cy = lens.pinhole_intrinsics()
    left, top, right, bottom = extent
    cells = (np.arange(512) + 0.5) / 512
    u, v = left + (right - left) * cells, top + (bottom - top) * cells
    return float((np.hypot(*np.meshgrid((u - cx) / fx, (v - cy) / fy)) > rd_limit).mean())


def lens_model_from(values: dict, width: int, height: int) -> LensModel:
    """The lens model of ``values`` (:class:`LensDistortion`'s parameters, missing ones at their defaults) for an
    output frame of ``width`` x ``height`` pixels. The values are not validated (a fit's trial values may fold
    the lens: :meth:`LensDistortion.check`)."""
    def get(key):
        return values.get(key, LensDistortion.params[key].default)

    model = get("model")
    if model == "fov":
        return FovLens(width, height, get("fx"), get("fy"), get("cx"), get("cy"), get("w"))
    if model == "opencv":
        return OpenCVLens(width, height, *(get(k) for k in MODEL_KEYS["opencv"]))
    if model == "fisheye":
        return KannalaBrandtLens(width, height, *(get(k) for k in MODEL_KEYS["fisheye"]))
    if model in LENSFUN_MODELS:
        return LensfunLens(width, height, model, [get(k) for k in MODEL_KEYS[model]], get("focal_length"),
                           get("crop_factor"), get("calibration_crop_factor"), get("calibration_aspect_ratio"),
                           tuple(get("lensfun_center")), get("lensfun_geometry"))
    return BlenderLens(width, height, model, get("focal_length"), get("sensor_width"), tuple(get("principal_point")),
                       get("pixel_aspect"), **{k: get(k) for k in MODEL_KEYS[model]})


class LensDistortion(Effect):
    """Warps the ideal pinhole render through the lens into the working grid (sec. 5.2 steps 1 and 2).

    The render is sampled (bilinear) on the supersampled working grid, twice the working resolution, and each
    working pixel is the mean of its 2x2 box of samples: the half-sampling of step 2, taken here so the
    supersampled image is never held (:class:`~lowcam.effects.half_sampling.HalfSampling` adds the box's
    enlargement).

    The render is a pinhole one or an equidistant fisheye one (``render_projection``, see :meth:`projection`).
    A pinhole render covers a field of view of ``render_hfov_deg`` horizontally (square pixels, centred); with
    0 the engine picks the field that just covers the working grid (frame plus margin) for a render of the
    frame's aspect ratio (see :meth:`render_field_of_view`). A fisheye render is Cycles' equidistant fisheye
    camera: ``render_hfov_deg`` is its field across the render's width and across its height (the image circle
    touches all four sides; a square render has square pixels), 0 for the working grid's field plus 2 %
    (:meth:`render_fisheye_field`). The maps are exact per pixel and computed once per render size.
    """

    name = "lens_distortion"
    section = "4.1, 5.2 step 1"
    writes = "working"
    order = 20
    calibration = "lens"
    node = NodeStage("Lens Distortion", "image", "lens_distortion")
    searches = tuple(Search("radial_distortion", "lens {fitted}", when={"model": m}, captures="textured",
                            fit=lambda ctx, effect: fit_radial_distortion(ctx, effect)) for m in MODEL_KEYS)
    always_runs = True
    params = {
        "model": Param("fov", str, choices=tuple(MODEL_KEYS)),
        "fx": Param(0.57, low=0.01, high=10.0, doc="FOV model: focal length / frame width"),
        "fy": Param(0.76, low=0.01, high=10.0, doc="FOV model: focal length / frame height"),
        "cx": Param(0.5, low=-1.0, high=2.0, doc="FOV model: principal point / frame width"),
        "cy": Param(0.5, low=-1.0, high=2.0, doc="FOV model: principal point / frame height"),
        "w": Param(0.0, low=0.0, high=3.0, unit="rad", doc="FOV model: field-of-view distortion parameter"),
        "fx_px": Param(500.0, low=1.0, high=1e6, unit="px"),
        "fy_px": Param(500.0, low=1.0, high=1e6, unit="px"),
        "cx_px": Param(319.5, low=-1e5, high=1e5, unit="px"),
        "cy_px": Param(239.5, low=-1e5, high=1e5, unit="px"),
        # OpenCV's coefficients: any finite value (a narrow lens's fit has large terms of alternating sign that
        # cancel over its field); a lens is judged by its mapping over the frame (check, frame_round_trip)
        "k1": Param(0.0),
        "k2": Param(0.0),
        "k3": Param(0.0),
        "p1": Param(0.0, low=-10.0, high=10.0),
        "p2": Param(0.0, low=-10.0, high=10.0),
        "fisheye_k1": Param(0.0, doc="fisheye (OpenCV's Kannala-Brandt) model"),
        "fisheye_k2": Param(0.0),
        "fisheye_k3": Param(0.0),
        "fisheye_k4": Param(0.0),
        "focal_length": Param(4.0, low=0.01, high=5000.0, unit="mm",
                              doc="Blender and lensfun models (lensfun: of the undistorted coordinates)"),
        "sensor_width": Param(3.6, low=0.01, high=500.0, unit="mm"),
        "principal_point": Param([0.0, 0.0], "vector", length=2, low=-3.0, high=3.0,
                                 doc="Blender's normalised (-1..1, y up)"),
        "pixel_aspect": Param(1.0, low=0.1, high=10.0),
        "division_k1": Param(0.0, low=-100.0, high=100.0),
        "division_k2": Param(0.0, low=-100.0, high=100.0),
        "nuke_k1": Param(0.0, low=-100.0, high=100.0),
        "nuke_k2": Param(0.0, low=-100.0, high=100.0),
        "brown_k1": Param(0.0, low=-100.0, high=100.0),
        "brown_k2": Param(0.0, low=-100.0, high=100.0),
        "brown_k3": Param(0.0, low=-100.0, high=100.0),
        "brown_k4": Param(0.0, low=-100.0, high=100.0),
        "brown_p1": Param(0.0, low=-10.0, high=10.0),
        "brown_p2": Param(0.0, low=-10.0, high=10.0),
        **LENSFUN_FRAME_PARAMS,
        "lensfun_k1": Param(0.0, low=-10.0, high=10.0, doc="lensfun poly3 / poly5 k1"),
        "lensfun_k2": Param(0.0, low=-10.0, high=10.0, doc="lensfun poly5 k2"),
        "lensfun_a": Param(0.0, low=-10.0, high=10.0, doc="lensfun ptlens a"),
        "lensfun_b": Param(0.0, low=-10.0, high=10.0, doc="lensfun ptlens b"),
        "lensfun_c": Param(0.0, low=-10.0, high=10.0, doc="lensfun ptlens c"),
        "lensfun_geometry": Param("rectilinear", str, choices=LENSFUN_GEOMETRIES,
                                  doc="lensfun models: the lens's projection (lensfun's lens type)"),
        "render_hfov_deg": Param(0.0, low=0.0, high=360.0, unit="deg",
                                 doc="0: automatic; a given field must cover the frame (a pinhole's under 180)"),
        "render_projection": Param("auto", str, choices=RENDER_PROJECTIONS,
                                   doc="the render's projection; auto: an equidistant fisheye where the frame "
                                       f"sees wider than {PINHOLE_FIELD_LIMIT_DEG:g} deg, else a pinhole"),
    }

    @staticmethod
    def keys_of(model: str) -> set[str]:
        """The parameter names that belong to a lens ``model``."""
        allowed = {"model", "render_hfov_deg", "render_projection", *MODEL_KEYS.get(model, ())}
        if model in BLENDER_MODELS:
            allowed.update(BLENDER_KEYS)
        if model in LENSFUN_MODELS:
            allowed.update(LENSFUN_KEYS)
        return allowed

    def values(self):
        keys = self.keys_of(self.model)
        if self.lensfun_geometry == "rectilinear":  # the default, unwritten (profiles from before it stay the same)
            keys = keys - {"lensfun_geometry"}
        return {k: v for k, v in super().values().items() if k in keys}

    def __init__(self, enabled=True, source="<python>", base_dir=None, **values):
        model = values.get("model", "fov")
        allowed = self.keys_of(model)
        stray = sorted(k for k in values if k in self.params and k not in allowed)
        super().__init__(enabled, source, base_dir, **values)
        if stray:
            raise self.error(f"key '{stray[0]}' does not belong to the '{model}' lens model "
                             f"(its keys: {', '.join(sorted(allowed - {'model'}))})")
        self._maps: dict = {}

    def check(self):
        if self.model == "fisheye":
            # the frame the principal point centres (2 cx + 1 by 2 cy + 1 px) must see rays the model maps one to
            # one (theta_d still rising) and the render holds (short of 90 deg in a pinhole render, out to
            # theta_rising in a fisheye one), but for at most FOLD_SHARE of it in the corners
            lens = self.model_for(2, 2)
            fx, fy, cx, cy = lens.pinhole_intrinsics()
            corners = [np.hypot((u - cx) / fx, (v - cy) / fy) for u in (-0.5, self.cx_px * 2 + 0.5)
                       for v in (-0.5, self.cy_px * 2 + 0.5)]
            limit = lens.theta_max() if self.render_projection == "pinhole" else lens.theta_rising()
            peak = lens.theta_d(limit)
            beyond = 0.0 if peak >= max(corners) else \
                share_beyond(lens, peak, (-0.5, -0.5, self.cx_px * 2 + 0.5, self.cy_px * 2 + 0.5))
            if beyond > FOLD_SHARE:
                raise self.error(f"the fisheye distortion folds over inside the frame (its radius stops rising at "
                                 f"{np.degrees(limit):.1f} deg from the axis, before the corner; {100 * beyond:.1f} % "
                                 f"of the frame lies beyond, more than the {100 * FOLD_SHARE:g} % allowed): check "
                                 "the coefficients and the intrinsics")
        if self.model in LENSFUN_MODELS:
            # The frame's corner in lensfun's normalised distorted radius (the crop factors are ratios of
            # diagonals) must lie where the distortion is still invertible (Rd rising with Ru) and the geometry
            # still projects; the outermost LENSFUN_FOLD_TOLERANCE of it may lie beyond (it sees the last ray).
            corner = np.sqrt(1 + self.calibration_aspect_ratio ** 2) * self.calibration_crop_factor / self.crop_factor
            lens = self.model_for(2, 2)
            if lens.rd_max() < (1 - LENSFUN_FOLD_TOLERANCE) * corner:
                limit = lensfun_projection_limit(lens.geometry)
                if lens.ru_max() >= lens.scale * lensfun_projection(lens.geometry, limit) * (1 - 1e-9):
                    raise self.error(f"the frame's corner (normalised radius {corner:.3f}) lies beyond what the "
                                     f"{lens.geometry.replace('_', ' ')} lens sees, {np.degrees(limit):.0f} deg from "
                                     f"the axis at normalised radius {lens.rd_max():.3f} (an image circle inside "
                                     "the frame): a larger crop factor takes a part of it")
                raise self.error(f"the {self.model} distortion folds over inside the frame (its radius stops rising "
                                 f"at normalised radius {lens.rd_max():.3f}, before the corner's {corner:.3f}): "
                                 "check the coefficients and the crop factors")

    def __deepcopy__(self, memo):
        """Copies share the cache of render maps: its keys hold every parameter, so sharing is safe and saves
        recomputing (and copying) maps of several million pixels whenever a profile is varied."""
        new = copy.copy(self)
        new.principal_point = list(self.principal_point)
        new.lensfun_center = list(self.lensfun_center)
        return new

    def model_for(self, width: int, height: int) -> LensModel:
        """The lens model for an output frame of ``width`` x ``height`` pixels."""
        return lens_model_from(self.values(), width, height)

    def lens_model(self, geometry) -> LensModel:
        """The lens of the output frame: this model, or a pinhole when the stage is disabled."""
        model = self.model_for(geometry.width, geometry.height)
        return model if self.enabled else model.pinhole()

    def projection(self, geometry) -> str:
        """The render's projection: ``render_projection``, or with ``auto`` an equidistant fisheye where the frame
        sees wider than :data:`PINHOLE_FIELD_LIMIT_DEG` (or a given ``render_hfov_deg`` is 180 deg or more), else
        a pinhole."""
        if self.render_projection != "auto":
            return self.render_projection
        key = ("projection", geometry, self.enabled, repr(self.values()))
        if key not in self._maps:
            wide = (self.render_hfov_deg >= 180.0 or
                    2 * np.degrees(ray_angle_needed(self.lens_model(geometry), geometry.frame_extent))
                    > PINHOLE_FIELD_LIMIT_DEG)
            self._maps[key] = "fisheye_equidistant" if wide else "pinhole"
        return self._maps[key]

    def _refuse_fisheye(self, geometry, needs: str):
        if self.projection(geometry) != "pinhole":
            raise LowcamError(f"{self.source}: {needs} needs a pinhole render, and this lens is rendered through an "
                              f"equidistant fisheye ({np.degrees(self.render_fisheye_field(geometry)):.1f} deg): set "
                              f"render_projection = \"pinhole\" (fields under 180 deg)")

    def render_fisheye_field(self, geometry) -> float:
        """The field (rad) an equidistant fisheye render spans across its width and its height: the given
        ``render_hfov_deg``, which must cover the frame, or with 0 the widest ray the working grid's border sees
        (:func:`ray_angle_needed`) plus 2 %, at most 360 deg."""
        key = ("fisheye", geometry, self.enabled, repr(self.values()))
        if key not in self._maps:
            lens = self.lens_model(geometry)
            if self.render_hfov_deg > 0:
                field = float(np.radians(self.render_hfov_deg))
                need = 2 * ray_angle_needed(lens, geometry.frame_extent)
                if field < need:
                    raise LowcamError(f"{self.source}: render_hfov_deg = {self.render_hfov_deg} is narrower than "
                                      f"the {np.degrees(need):.1f} deg the frame sees")
            else:
                field = min(2 * 1.02 * ray_angle_needed(lens, geometry.working_extent), 2 * np.pi)
            self._maps[key] = field
        return self._maps[key]

    def render_field_of_view(self, geometry) -> tuple[float, float]:
        """Pinhole half-extents (X, Y) = (tan of half the horizontal, vertical field) that the render must cover.

        With ``render_hfov_deg`` = 0 the horizontal extent is chosen to just cover the working grid (frame plus
        margin) for a render of the frame's aspect ratio, plus 2 %. A given ``render_hfov_deg`` (a render made
        already, e.g. a capture's ideal) must cover the frame; where it does not reach into the margin around
        the frame, the margin reads as transparent. Returns the extent the engine maps the render's width onto
        (X) and the least vertical extent it needs (Y). A fisheye render (:meth:`projection`) has none: refused.
        """
        self._refuse_fisheye(geometry, "a pinhole field of view")
        key = ("fov", geometry, self.enabled, repr(self.values()))
        if key not in self._maps:
            lens = self.lens_model(geometry)
            if self.render_hfov_deg >= 180:
                raise LowcamError(f"{self.source}: render_hfov_deg = {self.render_hfov_deg}: a pinhole render's "
                                  f"field is under 180 deg")
            if self.render_hfov_deg > 0:
                need_x, need_y = field_needed(lens, geometry.frame_extent)
                half_x = float(np.tan(np.radians(self.render_hfov_deg) / 2))
                if half_x < need_x:
                    raise LowcamError(f"{self.source}: render_hfov_deg = {self.render_hfov_deg} is narrower than "
                                      f"the {np.degrees(2 * np.arctan(need_x)):.1f} deg the frame sees")
            else:
                need_x, need_y = field_needed(lens, geometry.working_extent)
                half_x = 1.02 * max(need_x, need_y * geometry.width / geometry.height)
            self._maps[key] = (half_x, need_y)
        return self._maps[key]

    def render_focal_px(self, geometry, width: int, height: int) -> float:
        """Focal length in render pixels for a pinhole render of ``width`` x ``height`` (square pixels, centred);
        a fisheye render (:meth:`projection`) has none: refused (defocus from depth)."""
        self._refuse_fisheye(geometry, "the render's focal length (defocus from depth)")
        half_x, need_y = self.render_field_of_view(geometry)
        focal = width / (2 * half_x)
        if height / (2 * focal) < need_y * 0.999:
            raise LowcamError(f"a {width}x{height} render covers too little vertically for this camera: use the "
                              f"aspect ratio {geometry.width}:{geometry.height} or a taller one")
        return focal

    def render_pixel_coordinates(self, geometry, u, v, render_shape) -> tuple[np.ndarray, np.ndarray]:
        """Where output-frame points (u, v) (output pixels, through the lens) lie in a render of ``render_shape``
        (rows, cols): float32 render pixel coordinates, centres at integers (cv2.remap maps).

        A fisheye render: the ray (theta, phi) of :meth:`LensModel.undistort_ray` lies at ``rho = theta /
        (field / 2)`` of the half-width and half-height from the render's centre (Cycles' equidistant fisheye,
        ``fisheye_to_direction``: x right, y down on the image as written)."""
        hr, wr = render_shape
        lens = self.lens_model(geometry)
        if self.projection(geometry) == "fisheye_equidistant":
            theta, phi = lens.undistort_ray(u, v)
            rho = theta / (self.render_fisheye_field(geometry) / 2)
            return (((1 + rho * np.cos(phi)) * wr / 2.0 - 0.5).astype(np.float32),
                    ((1 + rho * np.sin(phi)) * hr / 2.0 - 0.5).astype(np.float32))
        x, y = lens.undistort(u, v)
        focal = self.render_focal_px(geometry, wr, hr)
        return (focal * x + wr / 2.0 - 0.5).astype(np.float32), (focal * y + hr / 2.0 - 0.5).astype(np.float32)

    def bake_node(self, state, bake) -> None:
        """The node's Map UV from the supersampled working grid into the render (``lens_uv``)."""
        rows, cols = bake.render_shape
        x, y = self.render_coordinates(state, (rows, cols))
        bake.images["lens_uv"] = stmap(x, y, cols, rows)

    def render_coordinates(self, state, render_shape) -> tuple[np.ndarray, np.ndarray]:
        """Render pixel coordinates (x, y), float32, of every supersampled working-grid pixel: where each one
        looks in a render of ``render_shape`` (rows, cols); pixel centres are integers. The working grid is laid
        out on the sensor: its pixel at ``s`` holds what the lens puts at ``s + d`` in the delivered frame, ``d``
        where the demosaicing shows a sensel (:func:`~lowcam.effects.bayer.sensel_shift_px`; the Fire-i's blocks:
        half a pixel left and down), so each ray lands where the calibration puts it."""
        u, v = state.geometry.working_pixel_centres(factor=2)
        du, dv = sensel_shift_px(state.profile)
        return self.render_pixel_coordinates(state.geometry, u + du, v + dv, render_shape)

    def render_warp(self, state, render_shape) -> WindowedRemap:
        """The warp from a render of ``render_shape`` (rows, cols) to the supersampled working grid, kept."""
        key = (render_shape, state.geometry, self.enabled, repr(self.values()), sensel_shift_px(state.profile))
        if key not in self._maps:
            if len(self._maps) > 8:
                self._maps.clear()
            x, y = self.render_coordinates(state, render_shape)
            self._maps[key] = WindowedRemap(x[None], y[None], tile=16)
        return self._maps[key]

    def apply(self, state):
        warp = self.render_warp(state, state.render.shape[:2])
        window = state.window("render")
        state.working = warp.halved(state.render, window)  # the 2x2 box of step 2 (half_sampling)
        rows, cols = warp.output_window(window) or (slice(0, 0), slice(0, 0))
        state.keep_window("working", None if window is None else (slice(rows.start // 2, -(-rows.stop // 2)),
                                                                  slice(cols.start // 2, -(-cols.stop // 2))), self)


# --- diagnosis: the radial_distortion candidate ---------------------------------------------------------

#: Per lens model, the parameters the ``radial_distortion`` candidate fits: (key, index into a vector key or None).
#: The focal length and the centre always, then the distortion coefficients from the lowest order in the radius
#: (ptlens: ``c`` of ``Ru^2``, then ``b``, ``a``); fy follows fx (square pixels kept).
FIT_KEYS = {
    "fov": (("fx", None), ("cx", None), ("cy", None), ("w", None)),
    "opencv": (("fx_px", None), ("cx_px", None), ("cy_px", None), ("k1", None), ("k2", None), ("k3", None)),
    "fisheye": (("fx_px", None), ("cx_px", None), ("cy_px", None), ("fisheye_k1", None), ("fisheye_k2", None),
                ("fisheye_k3", None), ("fisheye_k4", None)),
    "polynomial": (("focal_length", None), ("principal_point", 0), ("principal_point", 1), ("k1", None),
                   ("k2", None), ("k3", None)),
    "division": (("focal_length", None), ("principal_point", 0), ("principal_point", 1), ("division_k1", None),
                 ("division_k2", None)),
    "nuke": (("focal_length", None), ("principal_point", 0), ("principal_point", 1), ("nuke_k1", None),
             ("nuke_k2", None)),
    "brown": (("focal_length", None), ("principal_point", 0), ("principal_point", 1), ("brown_k1", None),
              ("brown_k2", None), ("brown_k3", None)),
    "poly3": (("focal_length", None), ("lensfun_center", 0), ("lensfun_center", 1), ("lensfun_k1", None)),
    "poly5": (("focal_length", None), ("lensfun_center", 0), ("lensfun_center", 1), ("lensfun_k1", None),
              ("lensfun_k2", None)),
    "ptlens": (("focal_length", None), ("lensfun_center", 0), ("lensfun_center", 1), ("lensfun_c", None),
               ("lensfun_b", None), ("lensfun_a", None)),
}
_TIED = {"fov": ("fy", "fx"), "opencv": ("fy_px", "fx_px"), "fisheye": ("fy_px", "fx_px")}  # (follower, leader): the ratio is kept


#: The ranges the ``radial_distortion`` candidate fits OpenCV's coefficients within (a profile accepts any finite
#: value): wide enough for every real lens's fit from optical flow, narrow enough to keep the search bounded.
FIT_BOUNDS = {**{k: (-100.0, 100.0) for k in ("k1", "k2", "k3")},
              **{f"fisheye_k{i}": (-10.0, 10.0) for i in range(1, 5)}}


def range_of(model: str) -> tuple[np.ndarray, np.ndarray]:
    """The ranges (low, high) of the parameters :data:`FIT_KEYS` fits in lens ``model``: :data:`FIT_BOUNDS`, else
    as the profile accepts them (:attr:`LensDistortion.params`)."""
    bounds = [FIT_BOUNDS.get(key, (LensDistortion.params[key].low, LensDistortion.params[key].high))
              for key, _ in FIT_KEYS[model]]
    return (np.array([-np.inf if low is None else low for low, _ in bounds]),
            np.array([np.inf if high is None else high for _, high in bounds]))


def _lens_values(values: dict, model: str, theta) -> dict:
    """The lens's parameters with the fitted ones (:data:`FIT_KEYS`) set to ``theta``."""
    out = {k: (list(v) if isinstance(v, list) else v) for k, v in values.items()}
    for (key, index), value in zip(FIT_KEYS[model], theta):
        if index is None:
            out[key] = float(value)
        else:
            out[key][index] = float(value)
    if model in _TIED:
        follower, leader = _TIED[model]
        out[follower] = values[follower] * out[leader] / values[leader]
    return out


def _flow_targets(means, clean, lens_model, stride: int = 6):
    """Where the measured frames look: at sample pixels u of the output frame, the camera-plane point the
    model's lens sees at ``u + d``, ``d`` being the optical flow from the measured mean to the clean model
    (OpenCV's DIS flow, Kroeger et al. 2016), kept where the texture is strong and the flow is consistent both
    ways. Returns (u, v, x, y) arrays."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    out = []
    for m, s in zip(means, clean):
        a = np.clip(m.mean(-1), 0, 255).astype(np.uint8)
        b = np.clip(s.mean(-1), 0, 255).astype(np.uint8)
        fwd = dis.calc(a, b, None)
        bwd = dis.calc(b, a, None)
        h, w = a.shape
        v, u = np.mgrid[stride // 2:h:stride, stride // 2:w:stride].astype(np.float64)
        iu, iv = u.astype(int), v.astype(int)
        du, dv = fwd[iv, iu, 0].astype(np.float64), fwd[iv, iu, 1].astype(np.float64)
        back = cv2.remap(bwd, (u + du).astype(np.float32), (v + dv).astype(np.float32), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(1e3, 1e3))
        gy, gx = np.gradient(cv2.GaussianBlur(b.astype(np.float32), (0, 0), 1.5))
        texture = np.hypot(gx, gy)[iv, iu]
        ok = (np.hypot(du + back[..., 0], dv + back[..., 1]) < 0.5) & (texture > 2.0)
        ok &= (u + du > 0) & (u + du < w - 1) & (v + dv > 0) & (v + dv < h - 1)
        x, y = lens_model.undistort(u[ok] + du[ok], v[ok] + dv[ok])
        out.append((u[ok], v[ok], x, y))
    return tuple(np.concatenate(c) for c in zip(*out))


#: A lens the ``radial_distortion`` candidate simulates is kept only where it lowers the noise-free SSE against the
#: measured means by this fraction: less is the flow's noise (where the frames already look through the profile's
#: lens), not worth a candidate.
SSE_GAIN = 1e-3
#: The ``radial_distortion`` candidate needs the optical flow to hold at this many sample points per fitted
#: parameter (each gives two offsets, px): fewer, and the frames show too little texture, or lie too far from the model.
FLOW_POINTS_PER_PARAMETER = 10
#: After its second round, the ``radial_distortion`` candidate goes on only while the flow reaches this much further
#: out (a fraction of the frame's half-diagonal) than in the round before: a lens fitted to the flow reaching only
#: the inner frame, then simulated, lets the next round's flow reach further.
REACH_GAIN = 0.02
#: The lens forms the ``radial_distortion`` candidate may switch a profile's lens to when its own cannot follow the
#: measured geometry: the engine's general forms (Brown-Conrady k1..k3 with the centre, the FOV model, and
#: Panorama Tools' quartic radial polynomial as lensfun's ``ptlens``, the form of most of lensfun's database,
#: whose ``Ru^2`` term Brown-Conrady's odd powers lack).
SWITCH_MODELS = ("opencv", "fov", "ptlens")
#: The forms whose start is solved linearly from the flow (:func:`_family_start`); such a start is refined only
#: where its residual as it stands could make it the chosen form.
LINEAR_STARTS = ("opencv", "ptlens")
#: Another lens form replaces the profile's own when its robust residual is below this fraction of the own's.
SWITCH_GAIN = 0.7


#: A fitted lensfun form must stay invertible out to this multiple of the frame's half-diagonal, as a pinhole
#: radius (a wall well inside :meth:`LensDistortion.check`'s, which needs ``Rd`` rising out to the corner).
LENSFUN_FOLD_MARGIN = 1.25
#: :meth:`LensDistortion.check` lets a lensfun lens's distortion stop rising this fraction of the corner's radius
#: short of the corner (those corner pixels see the ray where it stops): a database's terms, given to three
#: decimals, place that radius no better (the Samsung Galaxy S21 ultrawide's stops 0.16 % short of its own
#: frame's corner).
LENSFUN_FOLD_TOLERANCE = 0.005
#: The scale of Cauchy's loss on the candidate's flow offsets, px: offsets well above it hardly pull the lens.
CAUCHY_SCALE_PX = 0.5
#: Weight of :func:`fold_and_shortfall` in the candidate's residuals: pixels per fraction of a ray's length.
FOLD_WEIGHT = 1e4
#: Border points :func:`fold_and_shortfall` casts a ray to: the corners and three more on each edge.
FOLD_RAYS = 16


def fold_and_shortfall(lens: LensModel, geometry, half_x: float, half_y: float, fold_px: float = 0.0) -> np.ndarray:
    """Per ray from the lens's centre ``(cx, cy)`` to a point of the frame's border (:data:`FOLD_RAYS`: the
    corners and three more points on each edge): how far ``lens`` is from seeing that point, without folding
    over, inside a render of pinhole half-extents ``half_x``, ``half_y``; 0 where it does.

    On the ray, camera-plane points whose pinhole image lies a fraction ``t`` of the way to the border point
    (``t`` up to the render's edge, and up to a pinhole radius of ``fold_px`` pixels if further) are distorted
    and projected on the ray: ``s(t)`` is the fraction of the way to the border point of the distorted one. The
    lens folds where ``s`` falls: each fall counts until ``s`` has risen to the border of the working grid (the
    frame and its margin; its weight falls linearly to 0 over the last 0.05 of ``s``) and, with ``fold_px``,
    until ``t`` reaches that radius (lensfun's forms: :data:`LENSFUN_FOLD_MARGIN`). It falls short by
    ``1 - max s`` where ``s`` stays below 1 up to the render's edge. Returns the counted falls plus the
    shortfall per ray, in fractions of the ray's length: continuous in the lens's parameters, unlike an inverse
    that stops converging where the lens folds."""
    fx, fy, cx, cy = lens.pinhole_intrinsics()
    u0, v0, u1, v1 = geometry.frame_extent
    t = np.linspace(0.0, 1.0, FOLD_RAYS // 4 + 1)[:-1]
    n = len(t)
    du = np.concatenate([u0 + (u1 - u0) * t, np.full(n, u1), u1 - (u1 - u0) * t, np.full(n, u0)]) - cx
    dv = np.concatenate([np.full(n, v0), v0 + (v1 - v0) * t, np.full(n, v1), v1 - (v1 - v0) * t]) - cy
    length = np.maximum(np.hypot(du, dv), 1e-6)
    wu0, wv0, wu1, wv1 = geometry.working_extent
    with np.errstate(divide="ignore", invalid="ignore"):  # where the ray leaves the working grid
        past = np.minimum(np.where(du > 0, (wu1 - cx) / du, np.where(du < 0, (wu0 - cx) / du, np.inf)),
                          np.where(dv > 0, (wv1 - cy) / dv, np.where(dv < 0, (wv0 - cy) / dv, np.inf)))
    edge = np.minimum(half_x * fx / np.maximum(np.abs(du), 1e-12), half_y * fy / np.maximum(np.abs(dv), 1e-12))
    span = np.maximum(edge, fold_px / length)
    t = span[:, None] * np.linspace(0.0, 1.0, 81)[1:]
    u, v = lens.distort(du[:, None] / fx * t, dv[:, None] / fy * t)
    s = ((u - cx) * du[:, None] + (v - cy) * dv[:, None]) / (length * length)[:, None]
    s = np.concatenate([np.zeros((len(s), 1)), np.where(np.isfinite(s), s, -1.0)], axis=1)
    t = np.concatenate([np.zeros((len(t), 1)), t], axis=1)[:, :-1]  # at the start of each step
    weight = np.clip((past[:, None] - np.maximum.accumulate(s, axis=1)[:, :-1]) / 0.05, 0.0, 1.0)
    if fold_px > 0:
        weight = np.maximum(weight, np.clip((fold_px / length[:, None] - t) / (0.05 * fold_px / length[:, None]),
                                            0.0, 1.0))
    fold = (np.maximum(s[:, :-1] - s[:, 1:], 0.0) * weight).sum(axis=1)
    inside = t <= edge[:, None] + 1e-12
    return fold + np.maximum(1.0 - np.where(inside, s[:, 1:], -np.inf).max(axis=1), 0.0)


def _family_start(values: dict, model: str, lens: LensModel, targets) -> dict:
    """``values`` with the lens form ``model`` started at ``lens``'s centre, from the ``targets`` (u, v, x, y:
    pixels and the camera-plane points they see, ``r = hypot(x, y)``).

    Brown-Conrady: the focal length and k1..k3 solved linearly, as ``u - cx = fx x (1 + k1 r^2 + k2 r^4 +
    k3 r^6)``. Lensfun's ptlens, in the profile's lensfun frame where it has one, else on a frame that is its
    own calibration sensor (crop factors 1, the frame's aspect ratio; one unit ``U`` px is half its shorter
    side): ``U Rd = F r (1 - a - b - c) + (F^2 c / U) r^2 + (F^3 b / U^2) r^3 + (F^4 a / U^3) r^4`` with ``Ru =
    F r / U``, linear in its four coefficients ``A1..A4``; then ``F = A1 + A2 U / F + A3 U^2 / F^2 + A4 U^3 /
    F^3`` by fixed-point iteration from ``A1``, and ``c = A2 U / F^2``, ``b = A3 U^2 / F^3``, ``a = A4 U^3 /
    F^4``. The FOV form: at ``lens``'s focal length with ``w`` 0.5 (where it has a gradient)."""
    fx, fy, cx, cy = lens.pinhole_intrinsics()
    kept = {k: v for k, v in values.items() if k in LensDistortion.keys_of(model)}
    if model == "opencv":
        u, v, x, y = targets
        r2 = x * x + y * y
        powers = np.stack([np.ones_like(r2), r2, r2 ** 2, r2 ** 3], axis=1)
        a = np.linalg.lstsq(np.concatenate([x[:, None] * powers, (fy / fx) * y[:, None] * powers]),
                            np.concatenate([u - cx, v - cy]), rcond=None)[0]
        return dict(kept, model=model, fx_px=a[0], fy_px=a[0] * fy / fx, cx_px=cx, cy_px=cy, k1=a[1] / a[0],
                    k2=a[2] / a[0], k3=a[3] / a[0], p1=0.0, p2=0.0)
    if model == "ptlens":
        width, height = lens.width, lens.height
        frame = dict(crop_factor=1.0, calibration_crop_factor=1.0,
                     calibration_aspect_ratio=max(width, height) / min(width, height))
        frame.update((k, v) for k, v in kept.items() if k in frame)
        half = 0.5 * min(width - 1.0, height - 1.0)
        center = [float(np.clip((cx - 0.5 * (width - 1.0)) / half, -1, 1)),
                  float(np.clip((cy - 0.5 * (height - 1.0)) / half, -1, 1))]
        unit_px, u0, v0 = lensfun_frame(width, height, center=center, **frame)
        u, v, x, y = targets
        r = np.hypot(x, y)
        powers = np.stack([np.ones_like(r), r, r * r, r ** 3], axis=1)
        a = np.linalg.lstsq(np.concatenate([x[:, None] * powers, y[:, None] * powers]),
                            np.concatenate([u - u0, v - v0]), rcond=None)[0]
        focal = a[0]  # F = A1 + A2 U / F + A3 U^2 / F^2 + A4 U^3 / F^3 by fixed-point iteration
        for _ in range(30):
            focal = a[0] + sum(a[k] * (unit_px / focal) ** k for k in (1, 2, 3))
        unit_mm = FULL_FRAME_HALF_DIAGONAL_MM / frame["calibration_crop_factor"] / np.sqrt(
            1.0 + frame["calibration_aspect_ratio"] ** 2)
        return dict(kept, **frame, model=model, focal_length=focal * unit_mm / unit_px, lensfun_center=center,
                    lensfun_c=a[1] * unit_px / focal ** 2, lensfun_b=a[2] * unit_px ** 2 / focal ** 3,
                    lensfun_a=a[3] * unit_px ** 3 / focal ** 4)
    return dict(kept, model=model, fx=fx / lens.width, fy=fy / lens.height, cx=(cx + 0.5) / lens.width,
                cy=(cy + 0.5) / lens.height, w=0.5)


def fit_radial_distortion(ctx, effect: str, rounds: int = 4):
    """The ``radial_distortion`` candidate: the lens model's distortion coefficients, focal length and centre
    (:data:`FIT_KEYS`) fitted together, with the render's field of view held where the profile has it (the
    captures' ideal renders are given: a lens change must not change what they show).

    The geometry is fitted, not the pixels: the optical flow from each measured mean to the clean model says
    where the measured frames look (:func:`_flow_targets`: output pixels and the camera-plane points they see),
    and the lens parameters are fitted to those points by least squares on the pixels the lens maps them to,
    inside the parameters' ranges (no simulation per step). The loss is Cauchy's on the offsets (scale
    :data:`CAUCHY_SCALE_PX`: a few flow mismatches of tens of pixels must not bend the lens) and quadratic on
    the walls of :func:`fold_and_shortfall` (the flow rarely reaches the corners at first, and a polynomial
    fitted inside may turn back, or see beyond the render, before the frame's border). From a pinhole, the
    focal length, centre and the lowest-order coefficient are fitted first (without the walls: a start only),
    then all. Each round fits the current form, the profile's own form from the profile (a switch made on the
    first round's flow, near the centre only, can be undone), the FOV form, and the linear starts of
    :data:`LINEAR_STARTS` where they could win as they stand (:func:`_family_start`); another form replaces the
    current one where its robust residual is below :data:`SWITCH_GAIN` of the current's (a form too narrow for
    the real lens). The unfolded forms are simulated in that order of preference and the first that lowers the
    noise-free SSE against the measured means by :data:`SSE_GAIN` is kept (one that cannot be simulated passes
    to the next; two that do not improve end the search). Then the flow is measured again from the kept lens:
    at least two rounds, more while the flow reaches :data:`REACH_GAIN` further out than the round before,
    ``rounds`` at most. Returns (profile, params, shown values); raises :class:`~lowcam.errors.NotFitted`
    with a one-line reason where the flow holds at too few points, every form folds or sees beyond the render,
    or none brings the model closer to the frames by :data:`SSE_GAIN` (the frames already look through the
    profile's lens).
    """
    from scipy.optimize import least_squares

    p = ctx.profile
    lens = p.effect(effect)
    if lens is None or lens.model not in FIT_KEYS:
        raise NotFitted(f"the profile has no lens in a fitted form ({', '.join(FIT_KEYS)})")
    subset = list(ctx.screen_textured)  # the two most textured captures
    if not subset:
        raise NotFitted("no capture has the texture to show the lens's geometry")
    geometry = p.geometry
    if lens.projection(geometry) != "pinhole":
        raise NotFitted("the candidate fits a lens seen through a pinhole render, and this one's render is an "
                        "equidistant fisheye: set render_projection = \"pinhole\" to fit it (fields under 180 deg)")
    half_x, _ = lens.render_field_of_view(geometry)
    hfov = lens.render_hfov_deg or float(np.degrees(2 * np.arctan(half_x)))
    limit_x = 0.998 * np.tan(np.radians(hfov) / 2)  # a lens must see the frame inside the given render
    limit_y = limit_x * geometry.height / geometry.width
    values = dict(lens.values(), render_hfov_deg=hfov)
    if hfov > PINHOLE_FIELD_LIMIT_DEG:  # the render stays a pinhole while trial lenses see wider
        values["render_projection"] = "pinhole"

    def theta_of(vals):
        return np.array([vals[k] if i is None else vals[k][i] for k, i in FIT_KEYS[vals["model"]]], np.float64)

    def lens_at(vals, t):  # unvalidated: a trial may fold the lens (fold_and_shortfall measures how far)
        return lens_model_from(_lens_values(vals, vals["model"], t), geometry.width, geometry.height)

    def simulate(vals, t):
        try:
            return ctx.clean(p.with_effect(effect, replace=True, **_lens_values(vals, vals["model"], t)), subset)
        except (LowcamError, ValueError):  # out of range, or the lens would see beyond the render
            return None

    def sse(images):
        return sum(float(((m - s) ** 2).sum()) for m, s in zip(means, images))

    def spread(r):
        return 1.4826 * float(np.median(np.abs(r)))

    def fit_form(vals, t, pu, pv, tx, ty):
        """Robust least squares of the form ``vals["model"]`` from ``t`` to the targets, inside the parameters'
        ranges: (theta, the residual's robust spread in px, whether the lens sees the frame unfolded inside the
        render)."""
        fold_px = LENSFUN_FOLD_MARGIN * np.hypot(geometry.width - 1, geometry.height - 1) / 2 \
            if vals["model"] in LENSFUN_MODELS else 0.0

        def offsets(th):  # where the lens puts the targets, less where the flow saw them (px)
            u, v = lens_at(vals, th).distort(tx, ty)
            r = np.concatenate([u - pu, v - pv])
            return np.where(np.isfinite(r), r, 1e3)

        def residual(th, walls):
            if not walls:
                return offsets(th)
            return np.concatenate([offsets(th), FOLD_WEIGHT * fold_and_shortfall(lens_at(vals, th), geometry, limit_x,
                                                                                  limit_y, fold_px)])

        def loss(z, walls):
            # Cauchy's on the offsets (a few flow mismatches of tens of pixels must not bend the lens), plain
            # squares on the walls: rho, rho', rho'' of z = (r / CAUCHY_SCALE_PX)^2 (scipy's callable loss)
            out = np.stack([np.log1p(z), 1 / (1 + z), -1 / (1 + z) ** 2])
            if walls:
                out[0, -FOLD_RAYS:], out[1, -FOLD_RAYS:], out[2, -FOLD_RAYS:] = z[-FOLD_RAYS:], 1.0, 0.0
            return out

        low, high = range_of(vals["model"])

        def solve(start, free, walls):
            def of(sub):
                full = start.copy()
                full[free] = sub
                return full
            r = least_squares(lambda sub: residual(of(sub), walls), start[free], bounds=(low[free], high[free]),
                              loss=lambda z: loss(z, walls), f_scale=CAUCHY_SCALE_PX,
                              x_scale=np.maximum(1e-2 * np.abs(start[free]), 1e-2), max_nfev=60)
            return of(r.x), r.fun

        keys = [key for key, _ in FIT_KEYS[vals["model"]]]
        start_at = np.clip(t, low, high)
        if vals["model"] == "fov" and abs(t[keys.index("w")]) < 0.05:  # the FOV form is even in w: no gradient
            start_at[keys.index("w")] = 0.5                                # at a pinhole
        if len(t) > 4 and not np.any(t[3:]):  # from a pinhole: the lowest order first (a start only: higher
            start_at, _ = solve(start_at, np.arange(4), False)  # orders fitted at once from zero fold the lens)
        theta_fit, r = solve(start_at, np.arange(len(t)), True)
        return theta_fit, spread(r[:-FOLD_RAYS]), bool(np.all(r[-FOLD_RAYS:] < 1e-4 * FOLD_WEIGHT))

    means = [ctx.means[i].astype(np.float64) for i in subset]
    clean = ctx.clean(p, subset)  # the profile as it is (its maps and prefix are likely cached)
    start = best = sse(clean)
    theta = theta_of(values)
    original = values  # the profile's own form restarts from the profile in each round (after a switch, the
                       # next round's flow reaches further out)
    corner = np.hypot((geometry.width - 1) / 2, (geometry.height - 1) / 2)
    why, reached = "no lens form lowers the error", 0.0
    for done in range(rounds):
        here = lens_at(values, theta)
        targets = _flow_targets(means, clean, here)
        pu, pv, tx, ty = targets
        if len(pu) < FLOW_POINTS_PER_PARAMETER * len(theta):
            why = (f"the optical flow from the frames to the model holds at only {len(pu)} points "
                   f"({FLOW_POINTS_PER_PARAMETER * len(theta)} needed): too little texture, or the frames too far "
                   "from the model")
            break
        reach = np.percentile(np.hypot(pu - (geometry.width - 1) / 2, pv - (geometry.height - 1) / 2), 99) / corner
        if done >= 2 and reach < reached + REACH_GAIN:  # the flow shows nothing further out than last round's
            break
        reached = reach

        def preference(vals, residual):  # the current form is kept unless another one fits clearly better
            return residual * (SWITCH_GAIN if vals["model"] == values["model"] else 1.0)

        starts = []
        for m in dict.fromkeys((values["model"], original["model"], *SWITCH_MODELS)):
            if m == values["model"]:
                starts.append((values, theta))
            elif m == original["model"]:
                starts.append((original, theta_of(original)))
            elif m not in LINEAR_STARTS:
                other = _family_start(values, m, here, targets)
                starts.append((other, theta_of(other)))
        forms = [(vals, *fit_form(vals, t, *targets)) for vals, t in starts]  # (values, theta, px, unfolded)
        for m in LINEAR_STARTS:  # refined only where the start as it stands could be chosen
            linear = _family_start(values, m, here, targets)
            u, v = lens_at(linear, np.clip(theta_of(linear), *range_of(m))).distort(tx, ty)
            if preference(linear, spread(np.concatenate([u - pu, v - pv]))) < min(
                    (preference(vals, residual) for vals, _, residual, unfolded in forms if unfolded), default=np.inf):
                forms.append((linear, *fit_form(linear, theta_of(linear), *targets)))
        order = sorted((f for f in forms if f[3]), key=lambda f: preference(f[0], f[2]))
        if not order:
            why = (f"every lens form folds over inside the frame or sees beyond the render's {hfov:.1f} deg field "
                   f"(the flow reaches {reach:.0%} of the frame's radius)")
            break
        kept, simulated = False, 0
        for vals, t, _, _ in order:  # the preferred first, the next where one cannot be simulated or is worse
            trial = simulate(vals, t)
            if trial is None:
                continue
            simulated += 1
            if sse(trial) < (1 - SSE_GAIN) * best:
                values, theta, clean, best, kept = vals, t, trial, sse(trial), True
                break
            if simulated == 2:
                break
        if not kept:
            vals, _, residual, _ = order[0]
            why = (f"no lens form brings the model {SSE_GAIN:.1%} closer to the frames (the closest, {vals['model']}, "
                   f"lies {residual:.2f} px off the flow, which reaches {reach:.0%} of the frame's radius)" if simulated
                   else f"no lens form that follows the flow can be simulated inside the render's {hfov:.1f} deg "
                   f"field")
            break
    if best >= start:
        raise NotFitted(why)
    model, keys = values["model"], FIT_KEYS[values["model"]]
    fitted = _lens_values(values, model, theta)
    changed = {k: fitted[k] for k in dict.fromkeys(k for k, _ in keys)}
    if model in _TIED:
        changed[_TIED[model][0]] = fitted[_TIED[model][0]]
    if model != lens.model:  # a new form: all of its parameters (a lensfun form's frame, Brown-Conrady's p1, p2)
        changed.update((k, v) for k, v in fitted.items() if k in LensDistortion.keys_of(model))
    changed["render_hfov_deg"] = hfov

    def shown(value):
        return "[" + ", ".join(f"{x:.4g}" for x in value) + "]" if isinstance(value, list) else f"{value:.4g}"

    if model != lens.model:
        changed["model"] = model
        text = f"{lens.model} -> {model}: " + ", ".join(f"{k} {shown(changed[k])}"
                                                         for k in dict.fromkeys(k for k, _ in keys))
    else:
        text = f"{model}: " + ", ".join(f"{k} {shown(lens.values()[k])} -> {shown(changed[k])}"
                                        for k in dict.fromkeys(k for k, _ in keys))
    return (p.with_effect(effect, replace=True, **fitted), changed,
            {"fitted": f"{text} (render field {hfov:.2f} deg kept)"})


