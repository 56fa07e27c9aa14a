"""Render handlers: every frame Blender writes gets its degraded composite, with no extra step.

With ``scene.lowcam.enabled``, every frame Blender writes (``blender -b scene.blend -a``) gets its degraded
composite written to ``scene.lowcam.output``. ``suspended`` is set while an operator degrades frames itself.

Contents
--------
- :func:`on_render_init`: render_init handler: sets the scene up (render camera, passes) when Simulate Camera is on
- :func:`on_render_write`: render_write handler: degrades every frame Blender writes
- :func:`on_render_complete`: render_complete handler: codes the shot into the Video Output, when one is set
- :data:`HANDLERS`: (Blender handler list, function) pairs
- :func:`register`: append the handlers to Blender's handler lists
- :func:`unregister`: remove them
"""
from __future__ import annotations

import sys

import bpy
from bpy.app.handlers import persistent

from lowcam.errors import LowcamError

suspended = False  # set while an operator degrades frames itself
_frames_written: set[int] = set()  # the composites written since the render began


@persistent
def on_render_init(scene, *args):
    _frames_written.clear()
    if scene.lowcam.enabled and not suspended:
        from .frames import setup_scene

        try:
            setup_scene(scene, scene.render.resolution_x)
        except LowcamError as e:
            print(f"lowcam: {e}", file=sys.stderr)


@persistent
def on_render_write(scene, *args):
    if not scene.lowcam.enabled or suspended:
        return
    from .frames import degrade

    frame = scene.frame_current
    written = bpy.path.abspath(scene.render.frame_path(frame=frame))
    try:
        path = degrade(scene, written, frame)
        _frames_written.add(frame)
        print(f"lowcam: frame {frame} -> {path}", flush=True)
    except LowcamError as e:
        print(f"lowcam: frame {frame}: {e}", file=sys.stderr, flush=True)


@persistent
def on_render_complete(scene, *args):
    """After an animation render (more than one composite written, or the scene's only frame): the Video Output."""
    if not scene.lowcam.enabled or suspended or not scene.lowcam.video_output or not _frames_written:
        return
    if len(_frames_written) < 2 and scene.frame_end > scene.frame_start:
        return   # a still of one frame of a longer shot
    from .frames import write_shot_video

    try:
        print(f"lowcam: {write_shot_video(scene)}", flush=True)
    except LowcamError as e:
        print(f"lowcam: {e}", file=sys.stderr, flush=True)


HANDLERS = ((bpy.app.handlers.render_init, on_render_init), (bpy.app.handlers.render_write, on_render_write),
            (bpy.app.handlers.render_complete, on_render_complete))


def register():
    for handler_list, fn in HANDLERS:
        if fn not in handler_list:
            handler_list.append(fn)


def unregister():
    for handler_list, fn in HANDLERS:
        while fn in handler_list:
            handler_list.remove(fn)
