"""Render passes beyond the colour: image velocity and depth, for object motion blur and defocus from depth.

Both are render-sized arrays in the render's pixel grid (top row first), like the render itself:

``velocity_px_s``
    (H, W, 2) float32: how fast the surface seen at each pixel moves across the image at mid-exposure, in render
    pixels per second, x right and y down. It holds everything that moves: the camera's rotation and
    translation and the objects' own motion (:class:`lowcam.effects.ObjectMotion` takes the rotation out).
``depth_m``
    (H, W) float32: distance of the seen surface from the camera along its viewing axis (m); ``inf`` or very
    large where nothing was rendered.

Blender writes them as the Vector and Depth passes (:func:`from_blender`) into its multilayer OpenEXR files, where
:func:`read_blender_passes` finds them (``ViewLayer.Vector.X``..``W`` or a grouped ``ViewLayer.Vector``;
``ViewLayer.Depth.Z``, ``ViewLayer.Depth`` or the older ``ViewLayer.Z``), so ``lowcam apply`` and ``lowcam batch``
on a farm blur moving objects and defocus as the add-on does (:func:`read_render_and_passes`).

Contents
--------
- :data:`PASS_FIELDS`: each kind of pass ("velocity", "depth") -> its :class:`RenderPasses` field
- :data:`BLENDER_PASS`: each kind of pass -> the Blender pass that holds it
- :class:`RenderPasses`: a render's image velocity (px/s) and depth (m), validated
- :func:`check_passes`: validate passes against a render of ``render_shape``; returns them as float32
- :func:`from_blender`: passes from Blender's Vector and Depth passes, at ``fps`` and ``metres_per_unit``
- :data:`PASS_HELP`: each Blender pass -> where to turn it on
- :func:`needed_passes`: the Blender passes a profile's enabled effects need ("Vector", "Depth")
- :func:`render_layer`: the view layer a multilayer EXR's render comes from ("" for a single-layer file)
- :func:`find_blender_passes`: a view layer's Vector (H, W, 4) and Depth (H, W) arrays among an EXR's channels
- :func:`read_blender_passes`: a view layer's passes from a Blender OpenEXR file as :class:`RenderPasses`
- :func:`read_render_and_passes`: a render and the passes its profile needs, reading the file once
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import LowcamError
from .io import OVERLAY_LAYER, _exists, _format, exr_render, read_checked_render, read_exr, read_exr_tagged


#: Each kind of pass: its :class:`RenderPasses` field and the Blender pass that holds it.
PASS_FIELDS = {"velocity": "velocity_px_s", "depth": "depth_m"}
BLENDER_PASS = {"velocity": "Vector", "depth": "Depth"}


@dataclass(frozen=True)
class RenderPasses:
    velocity_px_s: np.ndarray | None = None
    depth_m: np.ndarray | None = None

    def get(self, kind: str, effect) -> np.ndarray:
        """The pass of ``kind`` ("velocity", "depth") that ``effect`` needs; a clear error when it is missing."""
        value = getattr(self, PASS_FIELDS[kind])
        if value is None:
            raise effect.error(f"needs a {kind} pass (Blender's {BLENDER_PASS[kind]} pass: turn it on, or run the "
                               "add-on's Set Up Scene); or disable the effect")
        return value


def check_passes(passes: RenderPasses | None, render_shape, name: str = "render") -> RenderPasses | None:
    """Validate ``passes`` against a render of ``render_shape`` (rows, cols, ...); returns them as float32."""
    if passes is None:
        return None
    rows, cols = render_shape[:2]
    velocity, depth = passes.velocity_px_s, passes.depth_m
    if velocity is not None:
        velocity = np.ascontiguousarray(velocity, np.float32)
        if velocity.shape != (rows, cols, 2):
            raise LowcamError(f"{name}: the velocity pass must be ({rows}, {cols}, 2) like the render, "
                              f"got {velocity.shape}")
        if not np.isfinite(velocity).all():
            raise LowcamError(f"{name}: the velocity pass has NaN or Inf pixels")
    if depth is not None:
        depth = np.ascontiguousarray(depth, np.float32)
        if depth.shape != (rows, cols):
            raise LowcamError(f"{name}: the depth pass must be ({rows}, {cols}) like the render, got {depth.shape}")
        if np.isnan(depth).any() or (depth <= 0).any():
            raise LowcamError(f"{name}: the depth pass has NaN, zero or negative pixels")
    return RenderPasses(velocity, depth)


def from_blender(vector: np.ndarray | None, depth: np.ndarray | None, fps: float,
                 metres_per_unit: float = 1.0) -> RenderPasses:
    """Passes from Blender's Vector pass (H, W, 4), or its X, Y, Z and W channels as four (H, W) arrays, and Depth
    pass (H, W, scene units of ``metres_per_unit``) at ``fps`` frames per second.

    Cycles stores ``(previous - current, current - next)`` positions in raster pixels (y up), so the forward
    velocity is ``-(X + Z) / 2`` and ``(Y + W) / 2`` pixels per frame in image axes (checked with a moving plane
    in ``tests/test_blender.py``).
    """
    velocity = None
    if vector is not None:
        # X, Y, Z, W as four (H, W) planes (an (H, W, 4) array's views, or the file's separate channels): the
        # velocity is written straight into its (H, W, 2) array, no (H, W, 4) copy; the same float32 operations
        # in the same order as -(X + Z) and Y + W scaled by fps / 2
        x, y, z, w = (np.asarray(c, np.float32) for c in
                      ((vector[..., i] for i in range(4)) if isinstance(vector, np.ndarray) else vector))
        scale = np.float32(fps / 2)
        velocity = np.empty(x.shape + (2,), np.float32)
        along = np.add(x, z)
        np.multiply(np.negative(along, out=along), scale, out=velocity[..., 0])
        np.multiply(np.add(y, w, out=along), scale, out=velocity[..., 1])
    if depth is not None:
        depth = np.asarray(depth, np.float32) * np.float32(metres_per_unit)
    return RenderPasses(velocity, depth)


#: Each Blender pass -> where to turn it on (for the one-line error when a needed pass is missing).
PASS_HELP = {
    "Vector": "enable the Vector pass in View Layer Properties > Passes > Data (Cycles or EEVEE, with the "
              "render's own motion blur off) or run Lowcam's Set Up Scene",
    "Depth": "enable the Z pass in View Layer Properties > Passes > Data or run Lowcam's Set Up Scene",
}


def needed_passes(profile) -> tuple[str, ...]:
    """The Blender passes (``"Vector"``, ``"Depth"``) that ``profile``'s enabled effects need, in chain order."""
    names = [BLENDER_PASS[e.needs_pass] for e in profile.effects if e.enabled and e.needs_pass]
    return tuple(dict.fromkeys(names))


def render_layer(channels: dict, layer: str | None = None) -> str:
    """The view layer a Blender multilayer EXR's render comes from: ``layer`` when given, else the one layer with
    a ``Combined`` pass (Lowcam's overlay layer aside); ``""`` for a single-layer file (no layer prefix)."""
    if layer:
        return layer
    layers = sorted({k[:-len(".Combined")] for k in channels if k.endswith(".Combined")} - {OVERLAY_LAYER})
    return layers[0] if len(layers) == 1 else ""


def _stacked(channels: dict, base: str, axes: str, planes: bool = False):
    """``base`` as an (H, W, len(axes)) array: one grouped array, or one channel per axis; None when absent.
    ``planes``: the file's separate channels as they are, a list of (H, W) arrays (no stacked copy)."""
    if base in channels and channels[base].ndim == 3 and channels[base].shape[2] == len(axes):
        return channels[base]
    keys = [f"{base}.{a}" for a in axes]
    if all(k in channels for k in keys):
        return [channels[k] for k in keys] if planes else np.stack([channels[k] for k in keys], -1)
    return None


def find_blender_passes(channels: dict, layer: str, planes: bool = False) -> dict[str, np.ndarray]:
    """View layer ``layer``'s Vector pass (H, W, 4) and Depth pass (H, W) among an OpenEXR file's ``channels``
    (:func:`lowcam.io.read_exr`), those present. Blender 4.x/5.x names them ``LAYER.Vector.X``..``W`` and
    ``LAYER.Depth.Z``; grouped arrays (``LAYER.Vector``, ``LAYER.Depth``) and the older ``LAYER.Z`` are taken too.
    ``layer`` ``""`` looks for the unprefixed names of a single-layer file. ``planes``: a Vector pass written as
    separate channels comes as their list of four (H, W) arrays, as :func:`from_blender` takes it."""
    prefix = f"{layer}." if layer else ""
    found = {}
    vector = _stacked(channels, prefix + "Vector", "XYZW", planes)
    if vector is not None:
        found["Vector"] = vector
    for key in (prefix + "Depth.Z", prefix + "Depth", prefix + "Z", prefix + "Z.Z"):
        depth = channels.get(key)
        if depth is not None and depth.ndim == 3 and depth.shape[2] == 1:
            depth = depth[..., 0]
        if depth is not None and depth.ndim == 2:
            found["Depth"] = depth
            break
    return found


def read_blender_passes(path, layer: str | None, fps: float, metres_per_unit: float = 1.0,
                        needs: tuple[str, ...] = (), channels: dict | None = None) -> RenderPasses:
    """View layer ``layer``'s Vector and Depth passes (those present; ``layer`` None: the render's layer,
    :func:`render_layer`) from a Blender OpenEXR file as :class:`RenderPasses` for a scene at ``fps`` whose
    length unit is ``metres_per_unit``. A pass named in ``needs`` that is missing is a one-line error naming the
    file, the layer, the pass and where to turn it on (:data:`PASS_HELP`)."""
    channels = read_exr(path) if channels is None else channels
    layer = render_layer(channels, layer)
    found = find_blender_passes(channels, layer, planes=True)
    for name in needs:
        if name not in found:
            where = f"view layer '{layer}'" if layer else "the file"
            raise LowcamError(f"{path}: {where} has no {name} pass; {PASS_HELP[name]}")
    return from_blender(found.get("Vector"), found.get("Depth"), fps, metres_per_unit)


def read_render_and_passes(path, layer: str | None, needs: tuple[str, ...], fps: float,
                           metres_per_unit: float = 1.0, render_space: str | None = None):
    """``(render, passes)``: the render, checked (a :class:`lowcam.io.CheckedRender`, as
    :func:`lowcam.io.read_checked_render` gives it), in linear Rec.709 from ``render_space`` or the space its header
    names, and, when ``needs`` names passes, its view layer's passes (:func:`read_blender_passes`), the file read
    once; ``passes`` is None when none are needed. A render that is not an OpenEXR file has no passes: asking for
    them is a one-line error."""
    if not needs:
        return read_checked_render(path, layer, render_space), None
    if _format(_exists(path)) != "exr":
        raise LowcamError(f"{path}: a {needs[0]} pass is needed and only an OpenEXR render holds one; render a "
                          f"multilayer OpenEXR ({PASS_HELP[needs[0]]})")
    channels, tags = read_exr_tagged(path)
    return exr_render(path, channels, tags, layer, render_space), read_blender_passes(path, layer, fps,
                                                                                     metres_per_unit, needs, channels)
