"""Gyroflow's lens profiles: a profile's lens, rolling shutter and exposure limit from a Gyroflow calibration.

Gyroflow (https://gyroflow.xyz) calibrates action cameras, drones, phones and cinema cameras per video mode; its
community database (https://github.com/gyroflow/lens_profiles, CC0) holds thousands of such files. A lens profile
is JSON; Lowcam reads:

- ``calib_dimension`` ``{"w", "h"}``: the frame size the calibration was made at (px);
- ``distortion_model`` (``"opencv_fisheye"`` or ``"opencv_standard"``; older files say ``use_opencv_fisheye`` or
  ``use_opencv_standard``) and its parameters, ``fisheye_params`` (or ``calib_params``): ``camera_matrix`` (3x3,
  px, OpenCV's pixel-centre convention) and ``distortion_coeffs`` (fisheye: ``k1..k4`` of the ray's angle;
  standard: OpenCV's ``k1, k2, p1, p2, k3``);
- ``frame_readout_time`` (ms, optional): the rolling shutter's read-out, first row to last;
- ``fps`` (optional): the video's frame rate, which bounds the exposure;
- ``camera_brand``, ``camera_model``, ``lens_model``, ``camera_setting``, ``calibrated_by`` and the fit's
  ``RMS_error`` (px), for the profile's name and provenance.

The intrinsics are scaled from the calibration size to the base profile's frame, which must have the same aspect
ratio: ``f' = f s``, ``c' = (c + 1/2) s - 1/2`` (pixel centres on integers before and after).

Contents
--------
- :class:`GyroflowLens`: what a Gyroflow lens profile says
- :func:`read_gyroflow_lens`: a Gyroflow lens profile, checked (one line naming the file and the key otherwise)
- :func:`scaled_intrinsics`: OpenCV intrinsics (fx, fy, cx, cy) of one frame size at another
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

from .errors import LowcamError
from . import schema
from .profile import check_provenance, inherited_provenance

#: Gyroflow's distortion models Lowcam reads, and its lens model for each.
MODELS = {"opencv_fisheye": "fisheye", "opencv_standard": "opencv"}
#: How far the calibration's aspect ratio may be from the base frame's (a share).
ASPECT_TOLERANCE = 0.01


@dataclass(frozen=True)
class GyroflowLens:
    """A Gyroflow lens profile: ``path``; ``model`` (``"opencv_fisheye"`` or ``"opencv_standard"``); the
    calibration frame ``size`` (w, h px); ``intrinsics`` (fx, fy, cx, cy px at that size); ``coefficients``;
    ``readout_s`` (0: none given) and ``fps`` (0: none given); ``name`` and ``calibration`` (who, the fit's
    error), for the profile."""

    path: Path
    model: str
    size: tuple[int, int]
    intrinsics: tuple[float, float, float, float]
    coefficients: tuple[float, ...]
    readout_s: float
    fps: float
    name: str
    calibration: str


def read_gyroflow_lens(path) -> GyroflowLens:
    """The lens profile in ``path``: a one-line :class:`~lowcam.errors.LowcamError` naming the file and the key
    for a file that is no Gyroflow lens profile, a model Lowcam lacks, or a value that is missing or not finite."""
    path = Path(path)
    doc = schema.read_json(path, "Gyroflow lens profile")      # a device, a huge file, NaN: refused there
    if not isinstance(doc, dict) or not isinstance(doc.get("calib_dimension"), dict):
        raise LowcamError(f"{path}: not a Gyroflow lens profile (no calib_dimension)")
    model = doc.get("distortion_model") or ("opencv_standard" if doc.get("use_opencv_standard") and
                                            not doc.get("use_opencv_fisheye") else "opencv_fisheye")
    if model not in MODELS:
        raise LowcamError(f"{path}: Gyroflow's '{model}' lens model is not one Lowcam reads "
                          f"({', '.join(MODELS)})")
    params = doc.get("calib_params") if model == "opencv_standard" and isinstance(doc.get("calib_params"), dict) \
        and doc["calib_params"].get("camera_matrix") else doc.get("fisheye_params")
    if not isinstance(params, dict):
        raise LowcamError(f"{path}: no fisheye_params (the camera matrix and the distortion coefficients)")
    where = f"{path}: {'calib_params' if params is doc.get('calib_params') else 'fisheye_params'}"
    k = schema.array_of(params.get("camera_matrix"), where, "camera_matrix",
                        lambda row, w, key: schema.numbers(row, w, key, 3), 3)
    fx, fy = (schema.number(value, where, key, low=1e-6) for key, value in (("fx", k[0][0]), ("fy", k[1][1])))
    coefficients = params.get("distortion_coeffs")
    wanted = 4 if model == "opencv_fisheye" else 5
    if not isinstance(coefficients, list) or len(coefficients) < wanted:
        raise LowcamError(f"{path}: distortion_coeffs must hold {wanted} numbers for {model}")
    coefficients = schema.numbers(coefficients, where, "distortion_coeffs", low=-100, high=100)
    if any(coefficients[wanted:]):
        raise LowcamError(f"{path}: {len(coefficients)} distortion_coeffs; {model} has {wanted} (the rational and "
                          "thin-prism terms are not read)")
    size = tuple(schema.integer(doc["calib_dimension"].get(a), f"{path}: calib_dimension", a, 16, 65536, "px")
                 for a in ("w", "h"))
    readout_ms = doc.get("frame_readout_time")
    readout_s = 0.0 if readout_ms is None else schema.number(readout_ms, str(path), "frame_readout_time", 0, 1000,
                                                             "ms") / 1000
    fps = 0.0 if doc.get("fps") in (None, 0) else schema.number(doc["fps"], str(path), "fps", 1e-3, 1000)
    words = [str(doc.get(key) or "").strip() for key in ("camera_brand", "camera_model", "lens_model",
                                                          "camera_setting")]
    name = " ".join(w for w in words if w) or path.stem
    by = str(doc.get("calibrated_by") or "").strip()
    rms = params.get("RMS_error")
    calibration = ", ".join(filter(None, (f"calibrated by {by}" if by else "",
                                           f"RMS {rms:.3g} px" if isinstance(rms, (int, float)) else "")))
    return GyroflowLens(path, model, size, (fx, fy, k[0][2], k[1][2]), tuple(coefficients[:wanted]), readout_s,
                        fps, name, calibration)


def scaled_intrinsics(intrinsics, size, to_size) -> tuple[float, float, float, float]:
    """OpenCV intrinsics ``(fx, fy, cx, cy)`` of a ``size`` (w, h) frame for the same lens at ``to_size``: ``f s``
    and ``(c + 1/2) s - 1/2`` on each axis, ``s`` the ratio of the sizes (pixel centres on integers)."""
    fx, fy, cx, cy = intrinsics
    sx, sy = to_size[0] / size[0], to_size[1] / size[1]
    return fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5


def profile_from_gyroflow(path, base):
    """``(profile, notes)``: the ``base`` profile (a :class:`~lowcam.profile.Profile`) with the Gyroflow lens
    profile's lens (scaled to the base's frame, whose aspect ratio must be the calibration's), its rolling shutter
    read-out and, where the video's frame rate is shorter than the base's exposure, the exposure at one frame;
    each with a ``[provenance]`` entry naming the file. ``notes`` are lines for the user."""
    lens = read_gyroflow_lens(path)
    c = base.camera
    (wc, hc), (w, h) = lens.size, (c.width, c.height)
    if abs((w / h) / (wc / hc) - 1) > ASPECT_TOLERANCE:
        raise LowcamError(f"{lens.path}: calibrated at {wc}x{hc} ({wc / hc:.3f}:1), the base {base.name}'s frame "
                          f"is {w}x{h} ({w / h:.3f}:1): give a base whose frame has the calibration's aspect ratio")
    fx, fy, cx, cy = scaled_intrinsics(lens.intrinsics, lens.size, (w, h))
    values = dict(model=MODELS[lens.model], fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy)
    keys = ("fisheye_k1", "fisheye_k2", "fisheye_k3", "fisheye_k4") if lens.model == "opencv_fisheye" else \
        ("k1", "k2", "p1", "p2", "k3")
    values.update(zip(keys, lens.coefficients))
    source = f"Gyroflow lens profile {lens.path.name} ({lens.name}; {lens.calibration or 'calibrator not stated'})"
    out = base.with_effect("lens_distortion", replace=True, source=str(lens.path), **values)
    if lens.readout_s > 0:
        out = out.with_effect("rolling_shutter", replace=True, source=str(lens.path), readout_s=lens.readout_s)
    provenance = inherited_provenance(base, ("lens_distortion", "rolling_shutter"))
    provenance["lens_distortion"] = f"{source}, {wc}x{hc} scaled to {w}x{h}"
    notes = [f"lens: {MODELS[lens.model]} model from {lens.model}, scaled from {wc}x{hc} to {w}x{h}"]
    if lens.readout_s > 0:
        provenance["rolling_shutter"] = f"{source}: frame_readout_time {lens.readout_s * 1e3:g} ms"
        notes.append(f"rolling shutter: {lens.readout_s * 1e3:g} ms from the first row to the last")
    out.camera.name = lens.name
    out.camera.description = f"{base.camera.name}'s sensor and processing with the lens of {lens.name} (Gyroflow)"
    provenance["camera"] = f"{provenance.get('camera', 'not stated')}; name from {lens.path.name}"
    if lens.fps and c.exposure_s > 1 / lens.fps:
        out.camera.exposure_s = 1 / lens.fps
        provenance["camera.exposure_s"] = f"{source}: at most one frame at {lens.fps:g} frames/s"
        notes.append(f"exposure: {c.exposure_s:g} s is longer than a frame at {lens.fps:g} frames/s: "
                     f"{1 / lens.fps:.4g} s")
    out.provenance = check_provenance(provenance, out)
    return out, notes
