"""``lowcam render``: render frames of a .blend with the bpy module and write their degraded composites.

Before any frame is rendered, the scene must have a camera, every frame's plate must be readable and every output
must be writable and none of the inputs (the .blend included, even where a composite of that name exists). Ctrl-C
during a render ends the job (Blender itself would report the interruption inside its render engine and go on with
the half-rendered frame); a full disk stops it at the first write that fails, saying how to resume.

Contents
--------
- :func:`open_scene`: open a .blend and return its scene (a clear error when it cannot)
- :func:`write_motion`: ``lowcam motion``: each frame's camera motion from a .blend's scene as a motion.json
- :func:`interruptible`: while it lasts, Ctrl-C during a Blender render raises ``KeyboardInterrupt`` after it
- :func:`render_still`: ``bpy.ops.render.render(write_still=True)``: Blender's refusals and Ctrl-C made clear
- :func:`check_scene`: check, before any render, the scene's camera and every frame's plate and motion
- :func:`render_frame`: render a frame to a multilayer EXR and write its degraded composite
- :func:`render`: render and degrade frames of a .blend's scene, skipping finished ones unless ``force`` (resumes)
"""
from __future__ import annotations

import contextlib
import gc
import signal
import sys
import tempfile
import threading
from pathlib import Path

import bpy

from lowcam.errors import DiskFull, LowcamError
from lowcam.io import quiet_stderr
from lowcam.outputs import check_image_output, check_output

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


_ctrl_c = {"pressed": False}


@contextlib.contextmanager
def interruptible():
    """While it lasts, Ctrl-C during a Blender render raises ``KeyboardInterrupt`` once the render returns
    (:func:`render_still`). Blender catches the interruption inside its render engine's Python, prints a traceback
    and returns with a half-rendered frame, so a plain ``KeyboardInterrupt`` never reaches the caller. Only in the
    main thread, and only where Ctrl-C is not ignored."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return

    def on_ctrl_c(signum, frame):
        _ctrl_c["pressed"] = True
        raise KeyboardInterrupt

    _ctrl_c["pressed"] = False
    signal.signal(signal.SIGINT, on_ctrl_c)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        _ctrl_c["pressed"] = False


def render_still(scene, what: str = "the scene") -> None:
    """``bpy.ops.render.render(write_still=True)`` for ``scene``: Blender's refusal ("Cannot render, no camera") is a
    one-line :class:`LowcamError` naming ``what``; Ctrl-C during it (:func:`interruptible`) a ``KeyboardInterrupt``
    after it, with Blender's report of it kept off the terminal."""
    try:
        with quiet_stderr(stdout=True), bpy.context.temp_override(scene=scene):  # progress is ours
            bpy.ops.render.render(write_still=True, scene=scene.name)
    except RuntimeError as e:
        raise LowcamError(f"{what}: Blender cannot render it ({str(e).splitlines()[0].removeprefix('Error: ')})") \
            from None
    if _ctrl_c["pressed"]:
        # the engine's traceback holds its render object, which Blender has freed: when Python lets it go, its
        # __del__ meets a "StructRNA ... has been removed" ReferenceError, which is no news to the user
        sys.unraisablehook = _without_freed_engine(sys.unraisablehook)
        sys.last_type = sys.last_value = sys.last_traceback = None
        with quiet_stderr():
            gc.collect()
        raise KeyboardInterrupt


def _without_freed_engine(hook):
    if getattr(hook, "drops_freed_engine", False):
        return hook

    def quiet(unraisable):
        if not (unraisable.exc_type is ReferenceError and "has been removed" in str(unraisable.exc_value)):
            hook(unraisable)

    quiet.drops_freed_engine = True
    return quiet


def check_scene(scene, blend, frame_list) -> None:
    """Check, before any render, that ``scene`` has a camera and that every frame of ``frame_list`` has its plate
    and its camera motion (a one-line :class:`LowcamError` naming the .blend, the frame or the file)."""
    if scene.camera is None:
        raise LowcamError(f"{blend}: scene '{scene.name}' has no camera; give it one (Scene properties > Camera)")
    profile = frames.scene_profile(scene)
    for frame in frame_list:
        try:
            frames.plate(scene, frame, profile)
            frames.motion(scene, frame, scene.lowcam.exposure_s)
        except LowcamError as e:
            raise LowcamError(f"{blend}: frame {frame}: {e}") from None


def render_frame(scene, frame: int, render_path: Path) -> Path:
    """Render ``frame`` to ``render_path`` (multilayer EXR) and write its degraded composite."""
    old_path = scene.render.filepath
    handlers.suspended = True
    try:
        scene.frame_set(frame)
        scene.render.filepath = str(render_path)
        render_still(scene, f"scene '{scene.name}' frame {frame}")
        return frames.degrade(scene, render_path, frame)
    finally:
        handlers.suspended = False
        scene.render.filepath = old_path


def render(blend, frame_list, output: str | None = None, force: bool = False, keep_renders: str | None = None,
           progress=None, compression: str | None = None) -> list[Path]:
    """Render and degrade ``frame_list`` of ``blend``'s scene; frames whose composite exists are skipped unless
    ``force`` (so an interrupted job resumes). ``output`` (a #### pattern) overrides the scene's setting, and
    ``compression`` (an OpenEXR codec of Render Compression) the scene's. Renders are removed once their
    composite is written, unless kept in the folder ``keep_renders``."""
    scene = open_scene(blend)
    if compression:
        scene.lowcam.render_codec = compression
    if output:
        scene.lowcam.output = str(Path(output).resolve()) if "#" in output or "%" in output else \
            str(Path(output).resolve() / "####.png")
    frames.setup_scene(scene, scene.render.resolution_x)
    for frame in frame_list:  # before any rendering: every composite can be written, none replaces an input
        out = frames.output_path(scene, frame)     # one that exists too: it may be the .blend, not a composite
        check_image_output(check_output(out, [blend]), [blend])
    todo = [f for f in frame_list if force or not frames.output_path(scene, f).exists()]
    check_scene(scene, blend, todo)
    written, rendered = [], 0
    with tempfile.TemporaryDirectory(prefix="lowcam-render-") as scratch, interruptible():  # scratch is removed
        renders = Path(keep_renders or scratch)
        for frame in frame_list:
            out = frames.output_path(scene, frame)
            if frame not in todo:
                written.append(out)
            else:
                try:
                    written.append(render_frame(scene, frame, renders / f"{frame:04d}.exr"))
                    if not keep_renders:   # an uncompressed render is large: gone once its composite is written
                        (renders / f"{frame:04d}.exr").unlink(missing_ok=True)
                except DiskFull as e:
                    done = sum(frames.output_path(scene, f).exists() for f in frame_list)
                    raise DiskFull(f"{e}; the render stopped there: {rendered} composite{'s' * (rendered != 1)} "
                                   f"written by this run, {done} of {len(frame_list)} done in all; free some space "
                                   "and run the same command again to resume (finished frames are skipped)") \
                        from None
                rendered += 1
            if progress:
                progress(frame, written[-1])
    return written
