"""Degrade one frame written by Blender: simulate the camera on its render and blend it onto the plate.

The frame is a multilayer EXR with the graphics' view layer (and optionally an overlay layer of excluded
objects), simulated with the engine and blended onto the plate. No bpy here; ``addon/`` calls it.

Contents
--------
- :data:`OVERLAY_LAYER`: the view layer that renders only the excluded objects ("Lowcam Overlay")
- :func:`read_layers`: (render, overlay) premultiplied RGBA from a Blender multilayer EXR
- :func:`read_passes`: a view layer's Vector and Depth passes as :class:`~lowcam.passes.RenderPasses`
- :func:`overlay_in_frame`: resample the overlay into the frame through the lens geometry only (no degradation)
- :func:`over_frame`: a premultiplied frame-sized overlay (linear, 1.0 = 255 DN) over an 8-bit frame
- :func:`degrade_frame`: simulate the camera on a frame Blender wrote and write the composite (atomically)
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import LowcamError
from .io import OVERLAY_LAYER, _rgba_from_exr, check_render, read_exr_tagged, read_plate, render_space_of
from .outputs import write_image
from .passes import RenderPasses, needed_passes, read_blender_passes
from .pipeline import check_followed_output, follows_previous, run
from .profile import load_profile
from .render_spaces import to_camera_space



def read_layers(path, layer: str, overlay_layer: str | None = None, channels: dict | None = None,
                render_space=None) -> tuple[np.ndarray, np.ndarray | None]:
    """(render, overlay) premultiplied linear Rec.709 RGBA from a Blender multilayer EXR: view layer ``layer``'s
    Combined pass and, when asked, ``overlay_layer``'s. ``channels``: the file's already read; ``render_space``:
    their colour space (a :class:`~lowcam.render_spaces.RenderSpace`; None: the one the file's header names)."""
    if channels is None or render_space is None:
        read, tags = read_exr_tagged(path)
        channels = read if channels is None else channels
        render_space = render_space or render_space_of(path, None, tags)

    def rgba(name, chosen):
        return check_render(to_camera_space(_rgba_from_exr(path, chosen), render_space), name)

    def combined(name):
        key = f"{name}.Combined"
        if key not in channels:
            layers = sorted({k.split(".")[0] for k in channels if "." in k})
            raise LowcamError(f"{path}: no view layer '{name}' (layers: {', '.join(layers) or 'none'})")
        return rgba(f"{path} layer {name}", {key: channels[key]})

    if not any("." in k for k in channels):  # a single-layer file: the whole render
        return rgba(path, channels), None
    return combined(layer), (combined(overlay_layer) if overlay_layer else None)


def read_passes(path, layer: str, fps: float, metres_per_unit: float = 1.0, needs: tuple[str, ...] = (),
                channels: dict | None = None) -> RenderPasses:
    """View layer ``layer``'s Vector and Depth passes (those present) as :class:`RenderPasses`, for a scene at
    ``fps`` whose length unit is ``metres_per_unit``; ``needs`` names the passes that must be there
    (``"Vector"``, ``"Depth"``)."""
    return read_blender_passes(path, layer, fps, metres_per_unit, needs, channels)


def overlay_in_frame(overlay: np.ndarray, profile) -> np.ndarray:
    """Resample a render-sized ``overlay`` into the output frame through the lens geometry only (bilinear), so
    excluded objects land where the camera sees them but get no blur, noise or colour processing."""
    profile = load_profile(profile)
    g = profile.geometry
    u, v = np.meshgrid(np.arange(g.width, dtype=np.float64), np.arange(g.height, dtype=np.float64))
    map_x, map_y = profile.effect("lens_distortion").render_pixel_coordinates(g, u, v, overlay.shape[:2])
    return cv2.remap(overlay, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def over_frame(frame: np.ndarray, overlay: np.ndarray) -> np.ndarray:
    """Premultiplied ``overlay`` (frame-sized, linear, 1.0 = 255 DN like renders) over an 8-bit ``frame``."""
    a = np.clip(overlay[..., 3:], 0.0, 1.0)
    out = overlay[..., :3] * 255.0 + (1.0 - a) * frame.astype(np.float32)
    return np.rint(np.clip(out, 0, 255)).astype(np.uint8)


def degrade_frame(render_path, output_path, profile, plate=None, angular_velocity=(0.0, 0.0, 0.0),
                  exposure_s=None, seed: int = 0, frame: int = 0, layer: str = "ViewLayer",
                  overlay_layer: str | None = None, fps: float = 24.0, metres_per_unit: float = 1.0,
                  render_space: str | None = None, previous_path=None) -> Path:
    """Simulate the camera on the frame Blender wrote to ``render_path`` and write the composite (atomically).
    The view layer's Vector and Depth passes (a scene at ``fps``, ``metres_per_unit``) feed the effects that
    need them (``object_motion``, ``depth_of_field``). The render's colour space is ``render_space`` (a name) when
    given, else the one the file's header names (Blender 5's working space), else linear Rec.709.
    ``previous_path``: the composite of the frame before, for a profile whose frames follow it (a temporal filter,
    :func:`~lowcam.pipeline.follows_previous`): the camera's frame made for it in this process (before any
    overlay), else the file when no overlay covers it, else none (the frame is then made on its own)."""
    profile = load_profile(profile)
    channels, tags = read_exr_tagged(render_path)
    space = render_space_of(render_path, render_space, tags)
    render, overlay = read_layers(render_path, layer, overlay_layer, channels, space)
    needs = needed_passes(profile)
    passes = read_passes(render_path, layer, fps, metres_per_unit, needs, channels)
    previous, follows = None, follows_previous(profile)
    if follows:
        check_followed_output(profile, output_path)
    if previous_path is not None and follows and Path(previous_path).is_file():
        kept = _CAMERA_FRAMES.get("frame")
        if kept is not None and kept[0] == _written(previous_path):
            previous = kept[1]
        elif overlay is None:
            previous = read_plate(previous_path, profile.camera.width, profile.camera.height, 3)
    result = run(render, profile, plate, angular_velocity, exposure_s, seed, frame, passes=passes, previous=previous)
    image = result.frame if overlay is None else over_frame(result.frame, overlay_in_frame(overlay, profile))
    written = write_image(output_path, image)
    if follows:  # the next frame follows this one: the camera's frame, without the overlay
        _CAMERA_FRAMES["frame"] = (_written(written), result.frame)
    return written


#: The camera's last frame made by :func:`degrade_frame` for a profile whose frames follow the one before, with
#: the file it went into (path, size, modification time): the next frame's previous frame, without the overlay
#: drawn over the composite, while that file is the one written.
_CAMERA_FRAMES: dict = {}


def _written(path) -> tuple:
    st = Path(path).stat()
    return str(Path(path).resolve()), st.st_size, st.st_mtime_ns
