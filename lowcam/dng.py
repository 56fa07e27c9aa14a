"""A camera's sensor from its DNG metadata: noise, colour, levels and CFA pattern (``lowcam profile from-dng``).

Phones and many cameras write DNG files whose tags describe the sensor (Adobe, *Digital Negative (DNG)
Specification* 1.6.0.0, 2020; "DNG spec" below). The tags are read with tifffile (IFD0 and the raw image's SubIFD;
no TIFF is parsed by hand) and turned into Lowcam's effects:

- **Levels** (BlackLevel, WhiteLevel; DNG spec ch. 5 "Mapping Raw Values to Linear Reference Values"): the raw value
  ``r`` becomes the linear signal ``x = (r - black) / (white - black)`` in 0..1. Lowcam's DN are black-subtracted
  (0 DN is black, a render value 1.0 is 255 DN), so the black level is no offset in the chain: it sets where 0 DN
  lies and is recorded in the provenance. (On a scale that keeps the pedestal the same law would show the black
  level as a negative intercept, ``a - b * black``, EMVA 1288's ``K^2 sigma_d^2 - K mu_dark``; Lowcam's is not
  such a scale.) White minus black is the DN scale; a raw-Bayer base profile's ``raw_blend.bits`` becomes
  ``ceil(log2(white + 1))``.
- **Noise** (NoiseProfile, tag 51041; DNG spec ch. 4, "NoiseProfile"): per CFA plane ``k`` a pair ``(S_k, O_k)``
  with ``variance(x) = S_k x + O_k`` for the normalised raw signal ``x``. Lowcam adds its noise to the sensel
  planes after the colour mixing, on white-balanced values (a white surface is 255 DN in every plane), so the raw
  signal of plane k at ``d`` DN is ``x = g_k d / 255`` with ``g_k = n_k / max(n)`` (``n``: AsShotNeutral, the raw
  response to white; the plane with the largest neutral clips first at 255 DN). The white-balance gain ``1 / g_k``
  scales the noise too, so with ``d = 255 x / g_k``::

      var(d) = (255 / g_k)^2 (S_k g_k d / 255 + O_k) = 255^2 O_k / g_k^2  +  (255 S_k / g_k) d

  which is :class:`~lowcam.effects.Noise`'s ``variance_linear`` law ``[a, b] = [255^2 O_k / g_k^2,
  255 S_k / g_k]`` per sensel (green's law is the green plane's own: a sensel law, no demosaicing factor). Without
  AsShotNeutral ``g_k = 1``. A DNG without NoiseProfile keeps the base profile's noise (reported).
- **Colour** (ColorMatrix1/2, CalibrationIlluminant1/2, CameraCalibration, AnalogBalance, ForwardMatrix1/2,
  AsShotNeutral or AsShotWhiteXY; DNG spec ch. 6 "Mapping Camera Color Space to CIE XYZ Space"). The render is
  linear sRGB (IEC 61966-2-1, D65 white) of a scene whose light the render shows as white. Two matrices follow:

  * the sensor's own mixing, :class:`~lowcam.effects.Crosstalk`'s ``matrix`` (before the noise): the camera's
    white-balanced response to the render's primaries,
    ``K = diag(1/n) (AB CC CM(w)) Bradford(D65 -> w) M_sRGB->XYZ`` with ``w`` the as-shot white (the render's
    white is the scene light), ``CM(w)`` the colour matrices interpolated in inverse colour temperature as the
    spec prescribes, and ``n = AB CC CM(w) XYZ_w`` (rows sum to 1: white stays white; ``extra_mixing`` 0);
  * the image processor's colour correction, :class:`~lowcam.effects.Saturation`'s ``colour_correction`` C
    (after the noise, so it mixes the noise as a phone's ISP does): with ForwardMatrix,
    ``C = M_XYZ->sRGB Bradford(D50 -> D65) FM(w) D inv(AB CC) diag(n)`` (the spec's ``CameraToXYZ_D50``,
    ``D = diag(1 / inv(AB CC) n)``), rows renormalised to 1; without it, ``C = K^-1`` (the spec's inverse
    ColorMatrix route, which undoes the sensor mixing exactly). C is set only where the base profile has a
    saturation stage (an image processor); a raw-Bayer base delivers the sensor's colours, so only K is set.

  Both are needed: the crosstalk alone (the form :func:`~lowcam.effects.crosstalk.fit_colour_mixing` places "in
  the sensor") would give the raw camera's desaturated colours; with C the colours come out right while the noise
  is mixed as the camera mixes it.
- **CFA pattern** (CFAPattern, CFARepeatPatternDim, CFAPlaneColor; TIFF/EP and DNG spec ch. 4): a 2x2 pattern of
  red, green and blue becomes the profile's ``bayer_pattern``.

Contents
--------
- :class:`DngError`: a file that is not a readable DNG, or lacks what a sensor profile needs (one line)
- :class:`DngSensor`: the sensor tags of one DNG, as numbers
- :func:`read_dng`: the sensor tags of a DNG file (tifffile)
- :data:`ILLUMINANT_TEMPERATURE_K`: the nominal colour temperature of each CalibrationIlluminant code
- :func:`xy_to_cct`: the correlated colour temperature (K) of a chromaticity (McCamy 1992)
- :func:`noise_laws`: the per-channel ``variance_linear`` laws ``[a, b]`` (8-bit DN) from NoiseProfile
- :func:`as_shot_white`: the as-shot white (xy) from AsShotNeutral or AsShotWhiteXY (DNG spec ch. 6)
- :func:`colour_matrices`: the sensor's crosstalk K and the processor's colour correction C (see above)
- :func:`profile_from_dng`: a base profile with the DNG's sensor put in, its provenance and notes

References
----------
- [DNG] Adobe, "Digital Negative (DNG) Specification", version 1.6.0.0, 2020: ch. 4 (NoiseProfile, CFAPattern,
  BlackLevel, WhiteLevel, ColorMatrix, ForwardMatrix, AsShotNeutral), ch. 5 (linearisation), ch. 6 (colour).
- [sRGB] IEC 61966-2-1:1999, the sRGB primaries and D65 white (matrix as tabulated by B. Lindbloom).
- [Bradford] K. M. Lam, "Metamerism and Colour Constancy", PhD thesis, University of Bradford, 1985.
- [McCamy] C. S. McCamy, "Correlated color temperature as an explicit function of chromaticity coordinates",
  Color Research & Application 17(2), 142-144, 1992.
- [EMVA1288] EMVA Standard 1288 release 4.0, 2021 (a black level as a negative variance intercept).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tifffile

from .errors import LowcamError
from .profile import check_provenance
from .render_spaces import D65_XY, bradford, xy_to_xyz

#: Linear sRGB (D65) to XYZ [sRGB].
SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
D50_XY = (0.3457, 0.3585)

#: Nominal colour temperature (K) of each DNG CalibrationIlluminant code (EXIF LightSource values; the CIE
#: illuminants' own temperatures, fluorescent classes at their nominal centres).
ILLUMINANT_TEMPERATURE_K = {
    1: 5500.0, 2: 4150.0, 3: 2856.0, 4: 5500.0, 9: 5500.0, 10: 6500.0, 11: 7500.0, 12: 6430.0, 13: 5000.0,
    14: 4150.0, 15: 3450.0, 16: 2940.0, 17: 2856.0, 18: 4874.0, 19: 6774.0, 20: 5503.0, 21: 6504.0, 22: 7504.0,
    23: 5003.0, 24: 3200.0,
}
_PLANE = {0: "R", 1: "G", 2: "B"}


class DngError(LowcamError):
    """A file that is not a readable DNG, or lacks what a sensor profile needs (one line naming the file)."""


@dataclass
class DngSensor:
    """The sensor tags of one DNG, as numbers (None where the file has no such tag)."""

    path: Path
    camera: str
    bayer_pattern: str | None
    black_level: float
    white_level: float
    colour_matrices: list[tuple[int, np.ndarray]]          # (CalibrationIlluminant code, XYZ -> camera 3x3)
    forward_matrices: list[np.ndarray] = field(default_factory=list)  # camera -> XYZ D50, same order
    camera_calibration: list[np.ndarray] = field(default_factory=list)
    analog_balance: np.ndarray | None = None
    as_shot_neutral: np.ndarray | None = None
    as_shot_white_xy: tuple[float, float] | None = None
    noise_profile: list[tuple[float, float]] | None = None  # (S, O) per CFA plane, or one pair for all
    plane_colours: tuple[int, ...] = (0, 1, 2)


def _values(tags, name):
    tag = tags.get(name)
    if tag is None:
        return None
    v = tag.value
    if isinstance(v, bytes):
        return tuple(v)
    return tuple(v) if isinstance(v, (tuple, list, np.ndarray)) else (v,)


def _rationals(values, path, name, count):
    """TIFF (S)RATIONAL values: tifffile gives them as flat (numerator, denominator) pairs."""
    if values is None:
        return None
    if len(values) == 2 * count:
        num, den = np.asarray(values[0::2], np.float64), np.asarray(values[1::2], np.float64)
        if np.any(den == 0):
            raise DngError(f"{path}: {name} has a zero denominator")
        return num / den
    if len(values) == count:
        return np.asarray(values, np.float64)
    raise DngError(f"{path}: {name} has {len(values)} values, expected {count}")


def _finite(values, path, name):
    """``values`` (an array or None), refused unless every one is finite."""
    if values is not None and not np.all(np.isfinite(values)):
        raise DngError(f"{path}: {name} has a value that is not a finite number ({np.asarray(values).tolist()})")
    return values


def _matrix(values, path, name):
    """A 3x3 tag (ColorMatrix, ForwardMatrix, CameraCalibration) as a matrix: finite, not all zero, invertible
    (a condition number below 1e10), each refused in one line naming the file and the tag."""
    if values is None:
        return None
    m = _finite(values, path, name).reshape(3, 3)
    if not np.any(m):
        raise DngError(f"{path}: {name} is all zero")
    if not np.linalg.cond(m) < 1e10:
        raise DngError(f"{path}: {name} is singular (no colour can be recovered through it)")
    return m


def _invertible(m, path, what) -> np.ndarray:
    """``m`` checked invertible and finite before it is solved with: one line naming the file otherwise."""
    if not (np.all(np.isfinite(m)) and np.linalg.cond(m) < 1e10):
        raise DngError(f"{path}: {what} is singular")
    return m


def read_dng(path) -> DngSensor:
    """The sensor tags of a DNG file, read with tifffile: colour tags from IFD0, levels and CFA from the raw image
    (the SubIFD whose NewSubfileType is 0, else IFD0). A file that is not a DNG, or has no ColorMatrix1, is a
    :class:`DngError` naming the file."""

    path = Path(path)
    if not path.is_file():
        raise DngError(f"{path}: no such file")
    try:
        with tifffile.TiffFile(path) as tif:
            ifd0 = tif.pages[0]
            tags0 = {t.name: t for t in ifd0.tags}
            raw = ifd0
            for sub in (getattr(ifd0, "pages", None) or []):
                if int(getattr(sub.tags.get("NewSubfileType"), "value", 0) or 0) == 0:
                    raw = sub
                    break
            rtags = {t.name: t for t in raw.tags}
            return _sensor(path, tags0, rtags)
    except DngError:
        raise
    except (tifffile.TiffFileError, ValueError, IndexError, KeyError, struct.error) as e:
        raise DngError(f"{path}: not a readable DNG file ({e})") from None


def _sensor(path, tags0, rtags) -> DngSensor:
    if "DNGVersion" not in tags0:
        raise DngError(f"{path}: not a DNG file (a TIFF without the DNGVersion tag)")

    def get(name):  # raw IFD first, then IFD0 (the spec allows either for most tags)
        v = _values(rtags, name)
        return v if v is not None else _values(tags0, name)

    def matrix(name):
        return _matrix(_rationals(_values(tags0, name), path, name, 9), path, name)

    cms = []
    for k in (1, 2):
        m = matrix(f"ColorMatrix{k}")
        if m is not None:
            ill = _values(tags0, f"CalibrationIlluminant{k}")
            cms.append((int(ill[0]) if ill else 21 if k == 2 else 17, m))
    if not cms:
        raise DngError(f"{path}: no ColorMatrix1 tag: the DNG does not say how the camera sees colour")
    fms = [m for k in range(1, len(cms) + 1) if (m := matrix(f"ForwardMatrix{k}")) is not None]
    if len(fms) != len(cms):
        fms = []
    ccs = [m for k in range(1, len(cms) + 1) if (m := matrix(f"CameraCalibration{k}")) is not None]
    if len(ccs) != len(cms):
        ccs = []
    ab = _finite(_rationals(_values(tags0, "AnalogBalance"), path, "AnalogBalance", 3), path, "AnalogBalance")
    if ab is not None and np.any(ab <= 0):
        raise DngError(f"{path}: AnalogBalance {ab.tolist()} must be positive (a zero gain is singular)")
    neutral = _finite(_rationals(_values(tags0, "AsShotNeutral"), path, "AsShotNeutral", 3), path, "AsShotNeutral")
    if neutral is not None and np.any(neutral <= 0):
        raise DngError(f"{path}: AsShotNeutral {neutral.tolist()} must be positive")
    wxy = _finite(_rationals(_values(tags0, "AsShotWhiteXY"), path, "AsShotWhiteXY", 2), path, "AsShotWhiteXY")
    if wxy is not None and not (wxy[0] > 0 and wxy[1] > 0 and wxy[0] + wxy[1] < 1):
        raise DngError(f"{path}: AsShotWhiteXY ({wxy[0]:g}, {wxy[1]:g}) is no chromaticity (x > 0, y > 0, "
                       f"x + y < 1)")

    bits = get("BitsPerSample")
    white = get("WhiteLevel")
    white_level = float(min(white)) if white else float(2 ** min(int(bits[0]), 32) - 1 if bits else 65535)
    if not math.isfinite(white_level) or white_level <= 0:
        raise DngError(f"{path}: WhiteLevel {white_level:g} must be a finite number above 0")
    black = get("BlackLevel")
    if black is None:
        black_level = 0.0
    else:
        tag = rtags.get("BlackLevel") or tags0.get("BlackLevel")
        vals = _rationals(black, path, "BlackLevel", len(black) // 2) if tag.dtype in (5, 10) else \
            np.asarray(black, np.float64)
        _finite(vals, path, "BlackLevel")
        if np.any(vals < 0):
            raise DngError(f"{path}: BlackLevel {np.asarray(vals).tolist()} must be >= 0")
        black_level = float(np.mean(vals))
    if not white_level > black_level:
        raise DngError(f"{path}: WhiteLevel {white_level:g} is not above BlackLevel {black_level:g}")

    plane_colours = tuple(int(v) for v in (get("CFAPlaneColor") or (0, 1, 2)))
    pattern = None
    cfa = get("CFAPattern")
    if cfa is not None:
        dim = tuple(int(v) for v in (get("CFARepeatPatternDim") or (2, 2)))
        if dim != (2, 2) or len(cfa) != 4:
            raise DngError(f"{path}: CFA repeat pattern {dim[0]}x{dim[1]}; Lowcam models a 2x2 Bayer pattern")
        try:
            pattern = "".join(_PLANE[plane_colours[int(v)]] for v in cfa)
        except (IndexError, KeyError):
            raise DngError(f"{path}: CFAPattern {list(cfa)} is not made of red, green and blue") from None
        if pattern not in ("RGGB", "BGGR", "GRBG", "GBRG"):
            raise DngError(f"{path}: CFA pattern {pattern} is not a Bayer pattern (RGGB, BGGR, GRBG or GBRG)")

    noise = None
    nv = get("NoiseProfile")
    if nv is not None:
        nv = [float(v) for v in nv]
        if len(nv) % 2 or not nv or len(nv) // 2 not in (1, len(plane_colours)):
            raise DngError(f"{path}: NoiseProfile has {len(nv)} values: expected one (S, O) pair, or one per "
                           f"CFA plane ({len(plane_colours)})")
        noise = list(zip(nv[0::2], nv[1::2]))
        if any(not (math.isfinite(s) and math.isfinite(o)) or s < 0 or o < 0 for s, o in noise):
            raise DngError(f"{path}: NoiseProfile {nv}: S and O must be finite and >= 0")
    name = " ".join(str(tags0[k].value).strip() for k in ("Make", "Model") if k in tags0) or \
        str(getattr(tags0.get("UniqueCameraModel"), "value", "")) or path.stem
    return DngSensor(path, name, pattern, black_level, white_level, cms, fms, ccs, ab, neutral,
                     tuple(wxy) if wxy is not None else None, noise, plane_colours)


def xy_to_cct(xy) -> float:
    """Correlated colour temperature (K) of chromaticity ``xy``, McCamy's cubic [McCamy] (within 2 K of
    Robertson's method from 2856 to 6504 K)."""
    x, y = xy
    if y == 0.1858:  # the cubic's pole, far from any white: take the nearest value that has one
        y = 0.1858 + 1e-9
    n = (x - 0.3320) / (0.1858 - y)
    return float(449.0 * n ** 3 + 3525.0 * n ** 2 + 6823.3 * n + 5520.33)


def _weight(sensor: DngSensor, xy) -> float:
    """The weight of the first calibration's matrices at white ``xy``: linear in inverse colour temperature
    between the two calibration illuminants, clipped (DNG spec ch. 6)."""
    if len(sensor.colour_matrices) < 2:
        return 1.0
    t1, t2 = (ILLUMINANT_TEMPERATURE_K.get(ill, 5000.0) for ill, _ in sensor.colour_matrices)
    if t1 == t2:
        return 1.0
    t = xy_to_cct(xy)
    if not (math.isfinite(t) and t > 0):  # far outside the cubic's range: the nearer end of the two illuminants
        return 1.0 if t1 < t2 else 0.0
    g = (1.0 / t - 1.0 / t2) / (1.0 / t1 - 1.0 / t2)
    return float(np.clip(g, 0.0, 1.0))


def _mix(matrices, g):
    return matrices[0] if len(matrices) == 1 else g * matrices[0] + (1 - g) * matrices[1]


def _xyz_to_camera(sensor: DngSensor, xy) -> np.ndarray:
    """``AB CC CM`` at white ``xy``: XYZ to camera (DNG spec ch. 6)."""
    g = _weight(sensor, xy)
    m = _mix([cm for _, cm in sensor.colour_matrices], g)
    if sensor.camera_calibration:
        m = _mix(sensor.camera_calibration, g) @ m
    if sensor.analog_balance is not None:
        m = np.diag(sensor.analog_balance) @ m
    return m


def as_shot_white(sensor: DngSensor) -> tuple[tuple[float, float], str]:
    """The as-shot white (xy) and where it came from: AsShotWhiteXY, or AsShotNeutral translated by the spec's
    iteration (ch. 6, "Translating Camera Neutral Coordinates to White Balance xy Coordinates"), else D65."""
    if sensor.as_shot_white_xy is not None:
        return tuple(map(float, sensor.as_shot_white_xy)), "AsShotWhiteXY"
    if sensor.as_shot_neutral is None:
        return D65_XY, "no AsShotNeutral: D65 assumed"
    xy = D50_XY
    for _ in range(50):
        m = _invertible(_xyz_to_camera(sensor, xy), sensor.path, "the colour matrix at the as-shot white")
        xyz = np.linalg.solve(m, sensor.as_shot_neutral)
        if not (xyz.sum() > 0 and xyz[1] > 0 and np.all(np.isfinite(xyz))):
            raise DngError(f"{sensor.path}: AsShotNeutral {sensor.as_shot_neutral.tolist()} is no colour the "
                           f"ColorMatrix can see as white (XYZ {xyz.round(4).tolist()})")
        new = (xyz[0] / xyz.sum(), xyz[1] / xyz.sum())
        if abs(new[0] - xy[0]) + abs(new[1] - xy[1]) < 1e-9:
            break
        xy = new
    return (float(new[0]), float(new[1])), "AsShotNeutral"


def colour_matrices(sensor: DngSensor) -> dict:
    """The sensor's crosstalk ``K`` and the processor's colour correction ``C`` (module docstring), rows summing
    to 1, with the as-shot white ``xy``, the camera ``neutral`` (raw response to white) and the ``route`` of C
    ("ForwardMatrix" or "inverse ColorMatrix")."""
    path = sensor.path
    xy, _ = as_shot_white(sensor)
    m = _invertible(_xyz_to_camera(sensor, xy), path, "the colour matrix at the as-shot white")
    xyz_w = xy_to_xyz(xy)
    n = m @ xyz_w
    if np.any(n <= 0):
        raise DngError(f"{path}: the colour matrix gives a non-positive response to white {n.round(4)}")
    k = _rows_to_one(np.diag(1.0 / n) @ m @ bradford(D65_XY, xy) @ SRGB_TO_XYZ, path, "the sensor's crosstalk")
    if sensor.forward_matrices:
        fm = _mix(sensor.forward_matrices, _weight(sensor, xy))
        abcc = np.eye(3)
        if sensor.camera_calibration:
            abcc = _mix(sensor.camera_calibration, _weight(sensor, xy))
        if sensor.analog_balance is not None:
            abcc = np.diag(sensor.analog_balance) @ abcc
        _invertible(abcc, path, "AnalogBalance times CameraCalibration")
        n_ref = np.linalg.solve(abcc, n)
        if not np.all(n_ref > 0):
            raise DngError(f"{path}: AnalogBalance and CameraCalibration give a non-positive reference neutral "
                           f"{n_ref.round(4).tolist()}")
        cam_to_xyz = fm @ np.diag(1.0 / n_ref) @ np.linalg.inv(abcc) @ np.diag(n)
        c = np.linalg.inv(SRGB_TO_XYZ) @ bradford(D50_XY, D65_XY) @ cam_to_xyz
        route = "ForwardMatrix"
    else:
        c = np.linalg.inv(_invertible(k, path, "the sensor's crosstalk (ColorMatrix at the as-shot white)"))
        route = "inverse ColorMatrix"
    c = _rows_to_one(c, path, f"the colour correction ({route})")
    return {"crosstalk": k, "colour_correction": c, "white_xy": xy, "neutral": n / n.max(), "route": route}


def _rows_to_one(m, path, what) -> np.ndarray:
    """``m`` with each row divided by its sum (white stays white); a row summing to zero, or a value that is not
    finite, is one line naming the file."""
    sums = m.sum(axis=1, keepdims=True)
    if not (np.all(np.isfinite(m)) and np.all(np.abs(sums) > 1e-6)):
        raise DngError(f"{path}: {what} maps white to black or to no number (row sums {sums.ravel().round(6)})")
    out = m / sums
    if not np.all(np.isfinite(out)):
        raise DngError(f"{path}: {what} is not finite")
    return out


def noise_laws(sensor: DngSensor) -> dict[str, list[float]] | None:
    """Per-channel ``variance_linear`` laws ``[a, b]`` in 8-bit DN from NoiseProfile: ``a = 255^2 O / g^2``,
    ``b = 255 S / g`` with ``g = n / max(n)`` the plane's raw response to white (module docstring); None without
    NoiseProfile."""
    if sensor.noise_profile is None:
        return None
    pairs = sensor.noise_profile
    if len(pairs) == 1:
        pairs = pairs * len(sensor.plane_colours)
    neutral = sensor.as_shot_neutral
    gain = np.ones(3) if neutral is None else np.asarray(neutral, np.float64) / float(np.max(neutral))
    out = {}
    for plane, (s, o) in zip(sensor.plane_colours, pairs):
        channel = {0: "red", 1: "green", 2: "blue"}.get(plane)
        if channel is None or channel in out:
            continue
        g = float(gain[plane])
        out[channel] = [255.0 ** 2 * o / g ** 2, 255.0 * s / g]
    missing = {"red", "green", "blue"} - set(out)
    if missing:
        raise DngError(f"{sensor.path}: NoiseProfile covers no {', '.join(sorted(missing))} plane")
    return out


def _reason(error: Exception, source: str) -> str:
    """A profile error's message without the file name it starts with (the DNG is named already)."""
    text = str(error)
    return text[len(source) + 2:] if text.startswith(f"{source}: ") else text


def profile_from_dng(path, base):
    """The base profile (a :class:`~lowcam.profile.Profile`) with the DNG's sensor put in: the noise law, the
    colour matrices, the raw bit depth and the Bayer pattern, each with a ``[provenance]`` entry. Returns
    ``(profile, notes)``: ``notes`` are lines for the user (what was kept from the base, and why)."""
    sensor = read_dng(path)
    name = Path(path).name
    out = base.copy()
    prov = dict(out.provenance)
    notes = []
    values = out.camera.values()
    values["name"] = f"{sensor.camera} (sensor from DNG)"
    values["description"] = (f"{sensor.camera}: sensor from {name} (black {sensor.black_level:g}, white "
                             f"{sensor.white_level:g}); frame and optics from the base profile {base.name}")
    cam_note = (f"levels from {name}: BlackLevel {sensor.black_level:g} is 0 DN, WhiteLevel {sensor.white_level:g} "
                f"is 255 DN; frame size and timing from the base profile {base.name}")
    if sensor.bayer_pattern:
        values["bayer_pattern"] = sensor.bayer_pattern
        cam_note = f"bayer_pattern {sensor.bayer_pattern} from {name} CFAPattern; " + cam_note
    else:
        notes.append(f"{name}: no CFAPattern (not a CFA raw): Bayer pattern kept from {base.name}")
    src = str(path)  # what the DNG gives is checked as the DNG's: an error names it, not the base profile
    try:
        out.camera = type(out.camera)(src, None, **values)
    except LowcamError as e:
        raise DngError(f"{path}: the levels or CFA give a camera Lowcam cannot hold ({_reason(e, src)})") from None
    prov["camera"] = cam_note

    laws = noise_laws(sensor)
    if laws is None:
        notes.append("no NoiseProfile: noise kept from the base profile; estimate it from the plate with "
                     "`lowcam calibrate plate`")
    else:
        try:
            out = out.with_effect("noise", source=src, law="variance_linear", **laws)
        except LowcamError as e:
            raise DngError(f"{path}: NoiseProfile gives a noise law Lowcam cannot hold ({_reason(e, src)})") \
                from None
        pairs = " ".join(f"({s:.4g}, {o:.4g})" for s, o in sensor.noise_profile)
        gains = "" if sensor.as_shot_neutral is None else \
            f", white-balance gains 1/g from AsShotNeutral {np.round(sensor.as_shot_neutral, 4).tolist()}"
        prov["noise"] = (f"{name} NoiseProfile (S, O) {pairs}, variance = S x + O in normalised raw: "
                         f"a = 255^2 O / g^2, b = 255 S / g DN{gains} (lowcam.dng)")

    colour = colour_matrices(sensor)
    try:
        out = out.with_effect("crosstalk", source=src, matrix=np.round(colour["crosstalk"], 6).tolist(),
                              extra_mixing=0.0)
    except LowcamError as e:
        raise DngError(f"{path}: the colour matrices give a crosstalk Lowcam cannot hold ({_reason(e, src)})") \
            from None
    ills = ", ".join(f"ColorMatrix{k + 1} ({ILLUMINANT_TEMPERATURE_K.get(ill, 0):.0f} K)"
                     for k, (ill, _) in enumerate(sensor.colour_matrices))
    prov["crosstalk"] = (f"{name} {ills} at the as-shot white xy ({colour['white_xy'][0]:.4f}, "
                         f"{colour['white_xy'][1]:.4f}), on linear sRGB primaries, white-balanced (lowcam.dng)")
    if out.effect("saturation") is not None:
        try:
            out = out.with_effect("saturation", source=src,
                                  colour_correction=np.round(colour["colour_correction"], 6).tolist())
        except LowcamError as e:
            raise DngError(f"{path}: the colour matrices give a colour correction Lowcam cannot hold "
                           f"({_reason(e, src)})") from None
        prov["saturation.colour_correction"] = (f"{name} {colour['route']} to linear sRGB (D65), "
                                                f"white-balanced (lowcam.dng)")
    else:
        notes.append(f"the base profile {base.name} has no saturation stage (raw output): only the sensor's "
                     f"crosstalk is set, no processor colour correction")
    raw = out.effect("raw_blend")
    if raw is not None:
        bits = max(1, min(16, math.ceil(math.log2(sensor.white_level + 1))))
        out = out.with_effect("raw_blend", source=src, bits=bits)
        prov["raw_blend.bits"] = f"{name} WhiteLevel {sensor.white_level:g}: {bits} bits"

    out.provenance = check_provenance(prov, out)
    return out, notes
