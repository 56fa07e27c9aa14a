"""The colour spaces a render may arrive in, and its conversion to the camera's linear Rec.709.

The profiles' colour (crosstalk, saturation, YUV, the plate blend) takes a render in linear Rec.709 with a D65
white: Blender's default working space. Blender 5 can also render in Linear Rec.2020 or ACEScg; its OpenEXR files
then name the space in their header (``colorInteropID``, e.g. ``lin_ap1_scene``), and other programs write the
standard ``chromaticities`` attribute. A render in another space is converted by the 3x3 matrix from its primaries
and white point to linear Rec.709 [SMPTE RP 177], with the Bradford chromatic adaptation [Lam1985] to D65 where the
whites differ, as Blender's OpenColorIO configuration does for ACEScg. A render in linear Rec.709 is left as it
is (the same bytes).

Contents
--------
- :class:`RenderSpace`: a linear RGB space by its name, primaries and white point (CIE 1931 xy)
- :data:`LINEAR_REC709`: the camera's linear space (the profiles' assumption)
- :data:`RENDER_SPACES`: the spaces known by name (``--render-space`` values) with their other names
- :func:`render_space`: the space for a name: a ``--render-space`` value, Blender's name or an OpenEXR colorInteropID
- :func:`space_from_chromaticities`: the space of an OpenEXR ``chromaticities`` attribute (a known one when it matches)
- :func:`header_space`: the space an OpenEXR header names (colorInteropID, else chromaticities), or None
- :data:`D65_XY`, :data:`BRADFORD`: the D65 white, the Bradford cone response matrix
- :func:`xy_to_xyz`: a chromaticity's XYZ (Y = 1)
- :func:`bradford`: the Bradford chromatic adaptation matrix between two whites (xy)
- :func:`rgb_to_xyz`: a space's RGB -> CIE XYZ matrix (its white maps to Y = 1)
- :func:`to_rec709_matrix`: a space's RGB -> linear Rec.709 matrix (Bradford adaptation between the whites)
- :func:`to_camera_space`: a premultiplied RGBA render from its space to linear Rec.709 (Rec.709: the same array)

References
----------
- [SMPTE RP 177] SMPTE RP 177-1993, "Derivation of Basic Television Color Equations".
- [Lam1985] K. M. Lam, "Metamerism and Colour Constancy", PhD thesis, University of Bradford, 1985 (the Bradford
  cone response matrix).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import LowcamError

#: CIE 1931 xy of the D65 white.
D65_XY = (0.3127, 0.3290)
_ACES_WHITE = (0.32168, 0.33767)
#: Bradford cone response matrix (XYZ -> sharpened cone space) [Lam1985].
BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])


@dataclass(frozen=True)
class RenderSpace:
    """A linear RGB space: ``name`` (Blender's), ``primaries`` ((R, G, B) CIE 1931 xy) and ``white`` (xy)."""
    name: str
    primaries: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    white: tuple[float, float]


LINEAR_REC709 = RenderSpace("Linear Rec.709", ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06)), D65_XY)
#: ``--render-space`` value -> (the space, its other names: Blender's and OpenColorIO's interop IDs).
RENDER_SPACES = {
    "linear-rec709": (LINEAR_REC709, ("Linear Rec.709", "lin_rec709_scene", "lin_rec709", "lin_srgb", "rec709")),
    "linear-rec2020": (RenderSpace("Linear Rec.2020", ((0.708, 0.292), (0.170, 0.797), (0.131, 0.046)), D65_XY),
                       ("Linear Rec.2020", "lin_rec2020_scene", "lin_rec2020", "rec2020")),
    "acescg": (RenderSpace("ACEScg", ((0.713, 0.293), (0.165, 0.830), (0.128, 0.044)), _ACES_WHITE),
               ("ACEScg", "lin_ap1_scene", "lin_ap1")),
    "aces2065-1": (RenderSpace("ACES2065-1", ((0.7347, 0.2653), (0.0, 1.0), (0.0001, -0.0770)), _ACES_WHITE),
                   ("ACES2065-1", "lin_ap0_scene", "lin_ap0")),
    "linear-p3-d65": (RenderSpace("Linear DCI-P3 D65", ((0.680, 0.320), (0.265, 0.690), (0.150, 0.060)), D65_XY),
                      ("Linear DCI-P3 D65", "lin_p3d65_scene", "lin_p3d65")),
}
_BY_NAME = {alias.lower(): space for key, (space, aliases) in RENDER_SPACES.items() for alias in (key, *aliases)}


def render_space(name: str) -> RenderSpace:
    """The space called ``name``: a ``--render-space`` value, Blender's name ("ACEScg", "Linear Rec.2020") or an
    OpenEXR colorInteropID ("lin_ap1_scene"), any case. Anything else is a one-line :class:`LowcamError`."""
    space = _BY_NAME.get(str(name).strip().lower())
    if space is None:
        raise LowcamError(f"unknown render colour space '{name}' (known: {', '.join(RENDER_SPACES)})")
    return space


def space_from_chromaticities(values, path="render") -> RenderSpace:
    """The space of an OpenEXR ``chromaticities`` attribute (red, green, blue, white xy: 8 numbers): the known
    space it matches (within 5e-4, the attribute being float32), else one named by its numbers. Numbers that
    make no RGB space (not finite, y <= 0, primaries on one line) are a one-line :class:`LowcamError` naming
    ``path``."""
    xy = np.asarray(values, float).reshape(4, 2)
    for space, _ in RENDER_SPACES.values():
        if np.allclose(xy, np.array([*space.primaries, space.white]), atol=5e-4):
            return space
    name = "chromaticities " + " ".join(f"{v:.4f}" for v in xy.ravel())
    if not np.isfinite(xy).all() or (xy[:, 1] <= 0).any() or abs(np.linalg.det(
            np.stack([xy_to_xyz(p) for p in xy[:3]], axis=1))) < 1e-9:
        raise LowcamError(f"{path}: its {name} make no RGB colour space; name the render's space with "
                          "--render-space")
    return RenderSpace(name, tuple(map(tuple, xy[:3])), tuple(xy[3]))


def header_space(header: dict, path="render") -> RenderSpace | None:
    """The space an OpenEXR ``header`` names: its ``colorInteropID`` (Blender 5 writes it), else its
    ``chromaticities``; None when it names none. An interop ID Lowcam does not know, without chromaticities, is a
    one-line :class:`LowcamError` naming ``path``."""
    interop = header.get("colorInteropID")
    if interop:
        interop = interop.decode() if isinstance(interop, bytes) else str(interop)
        if interop.lower() in _BY_NAME:
            return _BY_NAME[interop.lower()]
    if header.get("chromaticities") is not None:
        return space_from_chromaticities(header["chromaticities"], path)
    if interop:
        raise LowcamError(f"{path}: rendered in colour space '{interop}', which Lowcam cannot convert; render in "
                          "Linear Rec.709, Linear Rec.2020 or ACEScg, or name the space with --render-space")
    return None


def xy_to_xyz(xy) -> np.ndarray:
    """The XYZ (Y = 1) of chromaticity ``xy``."""
    x, y = xy
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def bradford(src_xy, dst_xy) -> np.ndarray:
    """The Bradford (von Kries in Bradford cone space) adaptation matrix from white ``src_xy`` to ``dst_xy``:
    ``XYZ_dst = M XYZ_src`` [Lam1985]."""
    s, d = BRADFORD @ xy_to_xyz(src_xy), BRADFORD @ xy_to_xyz(dst_xy)
    return np.linalg.inv(BRADFORD) @ np.diag(d / s) @ BRADFORD


def rgb_to_xyz(space: RenderSpace) -> np.ndarray:
    """``space``'s RGB -> CIE XYZ matrix (3x3, float64): the primaries scaled so that RGB (1, 1, 1) is the white
    with Y = 1 [SMPTE RP 177]."""
    primaries = np.stack([xy_to_xyz(p) for p in space.primaries], axis=1)
    return primaries * np.linalg.solve(primaries, xy_to_xyz(space.white))


def to_rec709_matrix(space: RenderSpace) -> np.ndarray:
    """``space``'s RGB -> linear Rec.709 matrix (3x3, float64), with the Bradford adaptation from its white to D65
    when they differ."""
    m = rgb_to_xyz(space)
    if not np.allclose(space.white, D65_XY, atol=1e-6):
        m = bradford(space.white, D65_XY) @ m
    return np.linalg.solve(rgb_to_xyz(LINEAR_REC709), m)


def to_camera_space(rgba: np.ndarray, space: RenderSpace | None) -> np.ndarray:
    """A premultiplied RGBA render (H, W, 4) in ``space`` as linear Rec.709 (float32, alpha as it was). Linear
    Rec.709 (or None) returns ``rgba`` itself, unchanged. The matrix commutes with premultiplication."""
    if space is None or space == LINEAR_REC709:
        return rgba
    m = to_rec709_matrix(space).astype(np.float32)
    out = np.empty(rgba.shape, np.float32)
    np.matmul(rgba[..., :3], m.T, out=out[..., :3])
    out[..., 3] = rgba[..., 3]
    return out
