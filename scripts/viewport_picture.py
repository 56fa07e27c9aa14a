"""The camera look in Blender 5's 3D viewport, seen: ``docs/lowcam-viewport.png`` and the viewport compositor's cost.

    .venv/bin/python scripts/viewport_picture.py [OUT_DIR] [--size 640x480] [--repeats 3]

In the bpy 5.0 module (no window, no GPU needed: Mesa's software OpenGL), it builds the sample scene with the
add-on, switches *Viewport Look* on (which adds "Lowcam Camera" with the scene's plate connected) and draws the 3D
view through the scene camera offscreen, the viewport compositor running the group as it does on screen
(:func:`nodes.viewport.draw_through_camera`), and once more with the view's Compositor off. Writes
``lowcam-viewport.png``: the view without the look beside it with the look. Prints the median time of a draw
with and without the compositor (after a first draw of each, which compiles the shaders).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def timed_draws(viewport, scene, area, size, repeats: int):
    """(picture, median seconds) of ``repeats`` draws after a first one."""
    picture = viewport.draw_through_camera(scene, area, *size)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        picture = viewport.draw_through_camera(scene, area, *size)
        times.append(time.perf_counter() - started)
    return picture, statistics.median(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(REPO / "docs"))
    parser.add_argument("--size", default="640x480", help="the picture's size, WIDTHxHEIGHT (each half)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

    import bpy
    import cv2
    import numpy as np

    from lowcam_blender import submodule

    viewport = submodule("nodes.viewport")
    with tempfile.TemporaryDirectory() as tmp:
        print("building the sample scene ...", flush=True)
        blend = submodule("addon.sample").build_sample_scene(tmp, render_width=400, samples=4, frames=3)
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        scene = bpy.context.scene
        bpy.ops.lowcam.viewport_look()             # adds "Lowcam Camera", the sample plate connected
        viewport.start_gpu()
        area = next(a for s in bpy.data.screens for a in s.areas if a.type == "VIEW_3D")
        shading = area.spaces.active.shading
        pictures, seconds = {}, {}
        for mode in ("DISABLED", "ALWAYS"):
            shading.use_compositor = mode
            print(f"drawing the 3D view, Compositor {mode.lower()} ...", flush=True)
            pictures[mode], seconds[mode] = timed_draws(viewport, scene, area, (width, height), args.repeats)
    print(f"a {width}x{height} draw: {seconds['DISABLED']:.2f} s without the compositor, {seconds['ALWAYS']:.2f} s "
          f"with Lowcam Camera in it (median of {args.repeats}, {bpy.app.version_string}, "
          f"{__import__('gpu').platform.renderer_get()})")
    side_by_side = np.concatenate([pictures["DISABLED"], pictures["ALWAYS"]], axis=1)[..., 2::-1]
    u8 = (np.clip(side_by_side, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    path = Path(args.out) / "lowcam-viewport.png"
    ok, data = cv2.imencode(".png", u8, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    part = path.with_suffix(".png.part")
    part.write_bytes(data.tobytes())
    os.replace(part, path)
    print(f"{path} ({len(data) // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
