"""Gyroflow's lens profiles: a profile's lens, rolling shutter and exposure limit from a Gyroflow calibration.

Gyroflow (https://gyroflow.xyz) calibrates action cameras, drones, phones and cinema cameras per video mode; its
community database (https://github.com/gyroflow/lens_profiles, CC0) holds thousands of such files. A lens profile
is JSON; Lowcam reads:

- ``calib_dimension`` ``{"w", "h"}``: the frame size the calibration was made at (px);
- ``distortion_model`` (``"opencv_fisheye"`` or ``"opencv_standard"``; older files say ``use_opencv_fisheye`` or
  ``use_opencv_standard``) and its parameters, ``fisheye_params`` (or ``calib_params``): ``camera_matrix`` (3x3,
  px, OpenCV's pixel-centre convention) and ``distortion_coeffs`` (fisheye: ``k1..k4`` of the ray's angle;
  standard: OpenCV's ``k1, k2, p1, p2, k3``);
- ``frame_readout_time`` (ms, optional): the rolling shutter's read-out, first row to last (negative, or
  ``frame_readout_direction`` ``"BottomToTop"``: read from the bottom row up, Gyroflow's
  ``ReadoutDirection::BottomToTop``; a read-out across the columns is refused);
- ``fps`` (optional): the video's frame rate, which bounds the exposure;
- ``input_horizontal_stretch``, ``input_vertical_stretch`` (optional; 0.01 or less, or absent: 1): an anamorphic
  lens's squeeze. Gyroflow calibrates the frame stretched by these factors (``calib_dimension`` is the stretched
  frame) and maps a point of the stretched frame to the recorded one by dividing its pixel coordinates by them
  (``src/core/stabilization/cpu_undistort.rs``); the recorded frame is ``calib_dimension`` over the stretch,
  rounded (as Gyroflow's database lists its aspect ratio). So ``fx, cx`` are divided by the horizontal stretch and
  ``fy, cy`` by the vertical one;
- ``digital_lens`` (GoPro's SuperView and HyperView: a polynomial warp the camera applies after the lens, from
  its 4:3 wide picture to a 16:9 frame; Gyroflow's ``distortion_models/gopro_superview.rs``): not modelled,
  refused by name;
- ``camera_brand``, ``camera_model``, ``lens_model``, ``camera_setting``, ``calibrated_by`` and the fit's
  ``RMS_error`` (px), for the profile's name and provenance.

The distortion coefficients may take any finite value: a lens is judged by its mapping over the frame, not by its
terms (OpenCV's fit of a narrow lens gives large terms of alternating sign that cancel over its field). A file is
refused where the mapping folds over inside the frame (but for its outermost corners, at most
:data:`~lowcam.effects.lens.FOLD_SHARE` of it, which see the ray where the radius stops), is not finite there,
or needs rays the model cannot carry (:func:`check_lens_over_frame`). Focal lengths that are both negative (a
picture turned 180 degrees, in some files) are the same lens seen upright: made positive (and the tangential
terms' signs turned).

The profile delivers the recorded frame (its width cut down to a multiple of 4 and its height to a multiple of 2,
at the right and the bottom, where it is not one already), or a size asked for: the frame is then scaled by ``s``
to cover it and cut to it around the centre, as a camera makes a smaller or differently shaped video mode from
its sensor: ``f' = f s``, ``c' = (c + 1/2) s - 1/2 - o``, ``o = (n s - n') / 2`` the pixels cut on each side
(pixel centres on integers before and after).

Contents
--------
- :class:`GyroflowLens`: what a Gyroflow lens profile says
- :func:`read_gyroflow_lens`: a Gyroflow lens profile, checked (one line naming the file and the key otherwise)
- :data:`DIGITAL_LENSES`: Gyroflow's digital lenses, by their names there
- :func:`scaled_intrinsics`: OpenCV intrinsics (fx, fy, cx, cy) of one frame size at another of its aspect ratio
- :func:`framed_intrinsics`: OpenCV intrinsics of a frame scaled and cut to another size, as a camera's video mode
- :func:`radial_limit`: how far a radial lens's mapping reaches one to one
- :func:`check_lens_over_frame`: refuse a lens whose mapping folds over (beyond its corners), or is not finite,
  inside the frame
- :func:`lens_in_frame`: the frame a profile of a Gyroflow lens delivers and its lens there, checked
- :func:`profile_from_gyroflow`: the base profile with the file's lens, rolling shutter and exposure limit

References
----------
- [Gyroflow] A. Eddy et al., Gyroflow's lens profile format (``src/core/calibration/lens_profile.rs``),
  https://github.com/gyroflow/gyroflow; the database https://github.com/gyroflow/lens_profiles.
- [Kannala2006] J. Kannala and S. S. Brandt, "A Generic Camera Model and Calibration Method for Conventional,
  Wide-Angle, and Fish-Eye Lenses", IEEE TPAMI 28(8), 1335-1340, 2006; OpenCV's ``cv2.fisheye`` module.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .effects.lens import FOLD_SHARE, ROUND_TRIP_PX, LensDistortion, frame_round_trip, lens_model_from, share_beyond
from .effects.lens_models import KannalaBrandtLens, OpenCVLens
from .errors import LowcamError
from . import schema
from .profile import CameraSpec, check_provenance, inherited_provenance

#: Gyroflow's distortion models Lowcam reads, and its lens model for each.
MODELS = {"opencv_fisheye": "fisheye", "opencv_standard": "opencv"}
#: Gyroflow's digital lenses (``digital_lens``), by their names there: a warp after the lens that Lowcam lacks.
DIGITAL_LENSES = {"gopro_superview": "GoPro SuperView", "gopro_hyperview": "GoPro HyperView",
                  "gopro6_superview": "GoPro HERO6 SuperView"}
#: Gyroflow takes a stretch of this or less (or none) as 1 (``lens_profile.rs``).
NO_STRETCH = 0.01


@dataclass(frozen=True)
class GyroflowLens:
    """A Gyroflow lens profile: ``path``; ``model`` (``"opencv_fisheye"`` or ``"opencv_standard"``); the
    calibration frame ``size`` (w, h px, stretched); ``intrinsics`` (fx, fy, cx, cy px at that size);
    ``coefficients``; ``stretch`` (horizontal, vertical: the anamorphic stretch, 1 for none); ``readout_s`` (0:
    none given; negative: bottom row first) and ``fps`` (0: none given); ``name`` and ``calibration`` (who, the
    fit's error), for the profile; ``turned``: the file's focal lengths were both negative (a picture turned 180
    deg about the axis: the same lens seen from a camera turned so), made positive."""

    path: Path
    model: str
    size: tuple[int, int]
    intrinsics: tuple[float, float, float, float]
    coefficients: tuple[float, ...]
    readout_s: float
    fps: float
    name: str
    calibration: str
    stretch: tuple[float, float] = (1.0, 1.0)
    turned: bool = False

    @property
    def frame(self) -> tuple[int, int]:
        """The recorded frame (w, h px): the calibration frame over the stretch, rounded."""
        return (int(round(self.size[0] / self.stretch[0])), int(round(self.size[1] / self.stretch[1])))

    @property
    def frame_intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) px in the recorded frame: the calibration's divided by the stretch, as Gyroflow maps a
        point of the stretched frame to the recorded one (``uv.x /= input_horizontal_stretch``)."""
        fx, fy, cx, cy = self.intrinsics
        sh, sv = self.stretch
        return fx / sh, fy / sv, cx / sh, cy / sv


def _stretch(doc, path, key) -> float:
    value = doc.get(key)
    if value is None:
        return 1.0
    value = schema.number(value, str(path), key, high=100.0)
    return 1.0 if value <= NO_STRETCH else value


def read_gyroflow_lens(path, doc=None) -> GyroflowLens:
    """The lens profile in ``path`` (``doc``: its JSON, already read): a one-line
    :class:`~lowcam.errors.LowcamError` naming the file and the key for a file that is no Gyroflow lens profile, a
    model or digital lens Lowcam lacks, or a value that is missing or not finite."""
    path = Path(path)
    if doc is None:
        doc = schema.read_json(path, "Gyroflow lens profile")  # a device, a huge file, NaN: refused there
    if not isinstance(doc, dict) or not isinstance(doc.get("calib_dimension"), dict):
        raise LowcamError(f"{path}: not a Gyroflow lens profile (no calib_dimension)")
    model = doc.get("distortion_model") or ("opencv_standard" if doc.get("use_opencv_standard") and
                                            not doc.get("use_opencv_fisheye") else "opencv_fisheye")
    if not isinstance(model, str) or model not in MODELS:
        raise LowcamError(f"{path}: Gyroflow's '{str(model)[:80]}' lens model is not one Lowcam reads "
                          f"({', '.join(MODELS)})")
    digital = doc.get("digital_lens")
    if digital:
        name = DIGITAL_LENSES.get(str(digital), f"'{digital}'")
        raise LowcamError(f"{path}: digital_lens {schema.shown(str(digital))}: the {name} digital lens (a warp the "
                          "camera applies after the lens) is not modelled by Lowcam; take the file of the camera's "
                          "Wide or Linear mode")
    params = doc.get("calib_params") if model == "opencv_standard" and isinstance(doc.get("calib_params"), dict) \
        and doc["calib_params"].get("camera_matrix") else doc.get("fisheye_params")
    if not isinstance(params, dict):
        raise LowcamError(f"{path}: no fisheye_params (the camera matrix and the distortion coefficients)")
    where = f"{path}: {'calib_params' if params is doc.get('calib_params') else 'fisheye_params'}"
    k = schema.array_of(params.get("camera_matrix"), where, "camera_matrix",
                        lambda row, w, key: schema.numbers(row, w, key, 3), 3)
    fx, fy = (schema.number(value, where, key) for key, value in (("fx", k[0][0]), ("fy", k[1][1])))
    turned = fx < 0 and fy < 0        # the picture turned 180 deg: u - cx = fx x' = |fx| (-x') (a radial lens)
    if turned:
        fx, fy = -fx, -fy
    if min(fx, fy) < 1e-6:
        raise LowcamError(f"{where}: camera_matrix has the focal lengths fx = {k[0][0]:g}, fy = {k[1][1]:g} px: "
                          "they must be positive (or both negative: a picture turned 180 degrees)")
    coefficients = params.get("distortion_coeffs")
    wanted = 4 if model == "opencv_fisheye" else 5
    if not isinstance(coefficients, list) or len(coefficients) < wanted:
        raise LowcamError(f"{path}: distortion_coeffs must hold {wanted} numbers for {model}")
    coefficients = schema.numbers(coefficients, where, "distortion_coeffs")      # any finite value
    if turned and model == "opencv_standard":      # (-x, -y) turns the sign of the tangential terms
        coefficients[2:4] = [-coefficients[2], -coefficients[3]]
    if any(coefficients[wanted:]):
        raise LowcamError(f"{path}: {len(coefficients)} distortion_coeffs; {model} has {wanted} (the rational and "
                          "thin-prism terms are not read)")
    size = tuple(schema.integer(doc["calib_dimension"].get(a), f"{path}: calib_dimension", a, 16, 65536, "px")
                 for a in ("w", "h"))
    stretch = (_stretch(doc, path, "input_horizontal_stretch"), _stretch(doc, path, "input_vertical_stretch"))
    readout_ms = doc.get("frame_readout_time")
    readout_s = 0.0 if readout_ms is None else schema.number(readout_ms, str(path), "frame_readout_time", -1000,
                                                             1000, "ms") / 1000      # negative: bottom row first
    direction = doc.get("frame_readout_direction")
    if direction in ("LeftToRight", "RightToLeft"):
        raise LowcamError(f"{path}: frame_readout_direction {direction}: a read-out across the columns is not "
                          "modelled by Lowcam's rolling shutter (rows only)")
    if direction == "BottomToTop":
        readout_s = -abs(readout_s)
    fps = 0.0 if doc.get("fps") in (None, 0) else schema.number(doc["fps"], str(path), "fps", 1e-3, 1000)
    words = [str(doc.get(key) or "").strip() for key in ("camera_brand", "camera_model", "lens_model",
                                                          "camera_setting")]
    name = " ".join(w for w in words if w) or path.stem
    by = str(doc.get("calibrated_by") or "").strip()
    rms = params.get("RMS_error")
    calibration = ", ".join(filter(None, (f"calibrated by {by}" if by else "",
                                           f"RMS {rms:.3g} px" if isinstance(rms, (int, float)) else "")))
    return GyroflowLens(path, model, size, (fx, fy, k[0][2], k[1][2]), tuple(coefficients[:wanted]), readout_s,
                        fps, name, calibration, stretch, turned)


def scaled_intrinsics(intrinsics, size, to_size) -> tuple[float, float, float, float]:
    """OpenCV intrinsics ``(fx, fy, cx, cy)`` of a ``size`` (w, h) frame for the same lens at ``to_size``: ``f s``
    and ``(c + 1/2) s - 1/2`` on each axis, ``s`` the ratio of the sizes (pixel centres on integers)."""
    fx, fy, cx, cy = intrinsics
    sx, sy = to_size[0] / size[0], to_size[1] / size[1]
    return fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5


def framed_intrinsics(intrinsics, size, to_size) -> tuple[float, float, float, float]:
    """OpenCV intrinsics ``(fx, fy, cx, cy)`` of a ``size`` (w, h) frame for the same lens in a ``to_size`` frame
    of any shape, made as a camera makes a video mode: the frame scaled by ``s = max(w'/w, h'/h)`` to cover it,
    then cut to it around the centre, ``o = (n s - n') / 2`` px on each side: ``f s`` and ``(c + 1/2) s - 1/2 -
    o`` (pixel centres on integers). Of the same aspect ratio: :func:`scaled_intrinsics`."""
    (w, h), (w2, h2) = size, to_size
    if w * h2 == w2 * h:
        return scaled_intrinsics(intrinsics, size, to_size)
    fx, fy, cx, cy = intrinsics
    s = max(w2 / w, h2 / h)
    return fx * s, fy * s, (cx + 0.5) * s - 0.5 - (w * s - w2) / 2, (cy + 0.5) * s - 0.5 - (h * s - h2) / 2


def radial_limit(lens) -> tuple[float, float] | None:
    """``(rd, theta)`` for a radial lens (OpenCV's fisheye, or its standard model without tangential terms): the
    largest normalised distorted radius its mapping reaches one to one, and the ray's angle there (rad): where the
    radius stops rising, or for a fisheye that rises to 180 deg, its radius there. None for another lens."""
    if isinstance(lens, KannalaBrandtLens):
        theta = lens.theta_rising()
        return float(lens.theta_d(theta)), theta
    if isinstance(lens, OpenCVLens) and not (lens.p1 or lens.p2):
        k1, k2, k3 = lens.k1, lens.k2, lens.k3
        peaks = [z.real for z in np.roots([7 * k3, 5 * k2, 3 * k1, 1.0]) if abs(z.imag) < 1e-12 and z.real > 0] \
            if (k1 or k2 or k3) else []            # the slope's zeros in r^2
        if not peaks:
            return np.inf, np.pi / 2
        r = float(np.sqrt(min(peaks)))
        return r * (1 + r * r * (k1 + r * r * (k2 + r * r * k3))), float(np.arctan(r))
    return None


def check_lens_over_frame(values: dict, width: int, height: int, where: str) -> float:
    """Refuse, in one line naming ``where``, the ``lens_distortion`` ``values`` whose mapping over the ``width`` x
    ``height`` frame folds over, is not finite or needs rays the model cannot carry; return the share of the frame
    beyond where a radial lens's radius stops rising (0 where it rises out to the corners). A radial lens
    (:func:`radial_limit`): at most :data:`~lowcam.effects.lens.FOLD_SHARE` of the frame (outer pixel edges) may lie
    beyond the radius its mapping reaches one to one (those corner pixels see the ray where it stops). Another lens:
    a point of the frame taken to its ray and back must miss itself by at most
    :data:`~lowcam.effects.lens.ROUND_TRIP_PX` (:func:`~lowcam.effects.lens.frame_round_trip`)."""
    lens = lens_model_from(values, width, height)
    limit = radial_limit(lens)
    if limit is not None:
        fx, fy, cx, cy = lens.pinhole_intrinsics()
        corner = max(np.hypot((u - cx) / fx, (v - cy) / fy) for u in (-0.5, width - 0.5) for v in (-0.5, height - 0.5))
        rd, theta = limit
        if np.isnan(rd) or not np.isfinite(corner):
            raise LowcamError(f"{where}: the lens mapping is not finite over the {width}x{height} frame")
        if corner <= rd:
            return 0.0
        beyond = share_beyond(lens, rd, (-0.5, -0.5, width - 0.5, height - 0.5))
        if beyond <= FOLD_SHARE:
            return beyond
        raise LowcamError(f"{where}: the lens folds over inside the {width}x{height} frame (its radius stops rising "
                          f"{np.degrees(theta):.1f} deg from the axis, {100 * rd / corner:.1f} % of the way to the "
                          f"frame's farthest corner; {100 * beyond:.1f} % of the frame lies beyond, more than the "
                          f"{100 * FOLD_SHARE:g} % allowed): the calibration does not hold out to the frame's corners")
    error, u, v = frame_round_trip(lens, width, height)
    if error <= ROUND_TRIP_PX:
        return 0.0
    if not np.isfinite(error):
        raise LowcamError(f"{where}: the lens mapping is not finite at pixel ({u:g}, {v:g}) of the {width}x"
                          f"{height} frame")
    raise LowcamError(f"{where}: the lens folds over inside the {width}x{height} frame (before pixel ({u:g}, {v:g}): "
                      f"a ray maps there and back {error:.3g} px away): the calibration does not hold out to the "
                      "frame's border")


def lens_in_frame(lens: GyroflowLens, size: tuple[int, int] | None = None):
    """``(w, h, values, rows, beyond)``: the frame (px) a profile of ``lens`` delivers (the recorded one cut to a
    multiple of 4 by 2 px at the right and bottom, or ``size`` made from it as the camera would,
    :func:`framed_intrinsics`), the ``lens_distortion`` values there, checked over that frame
    (:func:`check_lens_over_frame`) and as a profile checks them (:class:`~lowcam.effects.lens.LensDistortion`),
    the share of the recorded rows the frame keeps (for the read-out) and the share of the frame beyond where the
    lens's radius stops rising."""
    wr, hr = lens.frame
    if size is None:
        w, h = wr - wr % 4, hr - hr % 2
        fx, fy, cx, cy = lens.frame_intrinsics            # cut at the right and bottom: the same pixel grid
        rows = h / hr
    else:
        w, h = size
        fx, fy, cx, cy = framed_intrinsics(lens.frame_intrinsics, (wr, hr), (w, h))
        rows = min(1.0, (h / max(w / wr, h / hr)) / hr)
    CameraSpec(f"{lens.path}: the frame", None, width=w, height=h)     # a frame a camera table takes
    values = dict(model=MODELS[lens.model], fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy)
    keys = ("fisheye_k1", "fisheye_k2", "fisheye_k3", "fisheye_k4") if lens.model == "opencv_fisheye" else \
        ("k1", "k2", "p1", "p2", "k3")
    values.update(zip(keys, lens.coefficients))
    beyond = check_lens_over_frame(values, w, h, str(lens.path))
    LensDistortion(True, str(lens.path), **values)     # the profile's own checks: what from-gyroflow meets
    return w, h, values, rows, beyond


def profile_from_gyroflow(path, base, size: tuple[int, int] | None = None):
    """``(profile, notes)``: the ``base`` profile's sensor and processing (a :class:`~lowcam.profile.Profile`, of
    any frame shape) with the Gyroflow lens profile's lens, its rolling shutter read-out and, where the video's
    frame rate is shorter than the base's exposure, the exposure at one frame; each with a ``[provenance]`` entry
    naming the file. The frame is the recorded one (the calibration's over its anamorphic stretch, cut to a
    multiple of 4 by 2 px at the right and bottom), or ``size`` (w, h px) made from it as the camera would
    (:func:`framed_intrinsics`); rows cut away shorten the read-out in proportion. ``notes`` are lines for the
    user."""
    lens = read_gyroflow_lens(path)
    c = base.camera
    (wc, hc), (wr, hr) = lens.size, lens.frame
    w, h, values, rows, beyond = lens_in_frame(lens, size)
    out = base.with_frame(w, h, f"{lens.path}: the frame").with_effect("lens_distortion", replace=True,
                                                                          source=str(lens.path), **values)
    source = f"Gyroflow lens profile {lens.path.name} ({lens.name}; {lens.calibration or 'calibrator not stated'})"
    readout_s = lens.readout_s * rows
    if readout_s != 0:
        out = out.with_effect("rolling_shutter", replace=True, source=str(lens.path), readout_s=readout_s)
    provenance = inherited_provenance(base, ("lens_distortion", "rolling_shutter"))
    sh, sv = lens.stretch
    anamorphic = f", anamorphic stretch {sh:g}x{sv:g} taken out ({wc}x{hc} -> {wr}x{hr})" if (sh, sv) != (1, 1) \
        else ""
    if size is not None:
        made = (f"scaled from {wr}x{hr} to {w}x{h}" if w * hr == wr * h else
                f"scaled and cut around the centre from {wr}x{hr} to {w}x{h}")
    else:
        made = f"at the recorded frame {w}x{h}" if (w, h) == (wr, hr) else \
            f"the recorded {wr}x{hr} cut to {w}x{h} at the right and bottom"
    if lens.turned:
        made += ("; the file's focal lengths are both negative (its picture turned 180 degrees about the axis): "
                 "made positive, the same lens in a camera turned upright")
    if beyond:
        made += (f"; the calibration's radius stops rising short of the corners: the outer {100 * beyond:.2g} % of "
                 "the frame sees the ray where it stops")
    provenance["lens_distortion"] = f"{source}{anamorphic}, {made}"
    notes = [f"lens: {MODELS[lens.model]} model from {lens.model}{anamorphic}, {made}"]
    if readout_s != 0:
        kept = "" if rows == 1 else f" ({lens.readout_s * 1e3:g} ms for the {hr} recorded rows, {rows:.4g} kept)"
        provenance["rolling_shutter"] = f"{source}: frame_readout_time {readout_s * 1e3:.6g} ms{kept}"
        order = "from the first row to the last" if readout_s > 0 else "from the bottom row up to the top"
        notes.append(f"rolling shutter: {abs(readout_s) * 1e3:.6g} ms {order}{kept}")
    out.camera.name = lens.name
    out.camera.description = f"{base.camera.name}'s sensor and processing with the lens of {lens.name} (Gyroflow)"
    named = "name" if (w, h) == (c.width, c.height) else f"name and frame {w}x{h}"
    provenance["camera"] = f"{provenance.get('camera', 'not stated')}; {named} from {lens.path.name}"
    if lens.fps and c.exposure_s > 1 / lens.fps:
        out.camera.exposure_s = 1 / lens.fps
        provenance["camera.exposure_s"] = f"{source}: at most one frame at {lens.fps:g} frames/s"
        notes.append(f"exposure: {c.exposure_s:g} s is longer than a frame at {lens.fps:g} frames/s: "
                     f"{1 / lens.fps:.4g} s")
    out.provenance = check_provenance(provenance, out)
    return out, notes
