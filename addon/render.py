"""``lowcam render``: render frames of a .blend with the bpy module and write their degraded composites.

Contents
--------
- :func:`open_scene`: open a .blend and return its scene (a clear error when it cannot)
- :func:`write_motion`: ``lowcam motion``: each frame's camera motion from a .blend's scene as a motion.json
- :func:`render_frame`: render a frame to a multilayer EXR and write its degraded composite
- :func:`render`: render and degrade frames of a .blend's scene, skipping finished ones unless ``force`` (resumes)
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import bpy

from lowcam.errors import LowcamError
from lowcam.io import check_image_output, quiet_stderr

from . import frames, handlers


def open_scene(blend) -> "bpy.types.Scene":
    path = Path(blend)
    if not path.is_file():
        raise LowcamError(f"{path}: no such .blend file")
    try:
        with quiet_stderr(stdout=True):  # Blender prints the error too; it is in the message below
            bpy.ops.wm.open_mainfile(filepath=str(path.resolve()))
    except RuntimeError as e:
        raise LowcamError(f"{path}: Blender cannot open it ({str(e).splitlines()[0]})") from None
    return bpy.context.scene


def write_motion(blend, frame_list, path) -> Path:
    """``lowcam motion``: each frame's camera motion from ``blend``'s scene (its motion source, e.g. the solved
    camera) as a motion.json for ``lowcam batch`` on renders made elsewhere."""
    from lowcam.motion import write_motion_json

    scene = open_scene(blend)
    exposure = scene.lowcam.exposure_s
    table = {f: frames.motion(scene, f, exposure) for f in frame_list}
    return write_motion_json(path, table, fps=scene.render.fps / scene.render.fps_base)


def render_frame(scene, frame: int, render_path: Path) -> Path:
    """Render ``frame`` to ``render_path`` (multilayer EXR) and write its degraded composite."""
    old_path = scene.render.filepath
    handlers.suspended = True
    try:
        scene.frame_set(frame)
        scene.render.filepath = str(render_path)
        with bpy.context.temp_override(scene=scene):
            bpy.ops.render.render(write_still=True, scene=scene.name)
        return frames.degrade(scene, render_path, frame)
    finally:
        handlers.suspended = False
        scene.render.filepath = old_path


def render(blend, frame_list, output: str | None = None, force: bool = False, keep_renders: str | None = None,
           progress=None) -> list[Path]:
    """Render and degrade ``frame_list`` of ``blend``'s scene; frames whose composite exists are skipped unless
    ``force`` (so an interrupted job resumes). ``output`` (a #### pattern) overrides the scene's setting."""
    scene = open_scene(blend)
    if output:
        scene.lowcam.output = str(Path(output).resolve()) if "#" in output or "%" in output else \
            str(Path(output).resolve() / "####.png")
    frames.setup_scene(scene, scene.render.resolution_x)
    for frame in frame_list:  # before any rendering: every composite can be written, none replaces an input
        out = frames.output_path(scene, frame)
        if force or not out.exists():
            check_image_output(out, [blend])
    written = []
    with tempfile.TemporaryDirectory(prefix="lowcam-render-") as scratch:   # renders not kept are removed
        renders = Path(keep_renders or scratch)
        for frame in frame_list:
            out = frames.output_path(scene, frame)
            if out.exists() and not force:
                written.append(out)
            else:
                written.append(render_frame(scene, frame, renders / f"{frame:04d}.exr"))
            if progress:
                progress(frame, written[-1])
    return written
