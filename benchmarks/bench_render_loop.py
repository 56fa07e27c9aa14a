"""Benchmark: the camera inside Blender's own render loop, as ``blender -b scene.blend -a`` runs it.

The sample scene (Cycles at its default 16 samples, 800x600, its frames) is rendered as an animation with bpy, with
the add-on's render handler degrading each frame Blender writes (*Simulate Camera* on) and without it (the same
render set-up, passes and files), for uncompressed renders (the add-on's default) and ZIP. The configurations take
turns. Prints the median wall and CPU time per frame (the process's CPU: Cycles' threads and Lowcam's) and what
the camera adds to Blender's own time per frame (target: at most 50 %).

    .venv/bin/python benchmarks/bench_render_loop.py [--turns 2] [--frames 2]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--turns", type=int, default=2)
    parser.add_argument("--frames", type=int, default=2)
    args = parser.parse_args()

    import bpy

    from lowcam.io import quiet_stderr
    from lowcam_blender import submodule

    tmp = Path(tempfile.mkdtemp(prefix="lowcam-loop-"))
    blend = submodule("addon.sample").build_sample_scene(tmp / "scene", frames=args.frames)
    configs = [(camera, codec) for codec in ("NONE", "ZIP") for camera in (False, True)]
    wall = {c: [] for c in configs}
    cpu = {c: [] for c in configs}
    for _ in range(args.turns):
        for camera, codec in configs:
            scene = submodule("addon.render").open_scene(blend)
            scene.lowcam.render_codec = codec
            submodule("addon.frames").setup_scene(scene, scene.render.resolution_x)
            scene.lowcam.enabled = camera
            scene.render.filepath = str(tmp / f"{codec}-{camera}" / "####.exr")
            scene.lowcam.output = str(tmp / f"{codec}-{camera}" / "lowcam" / "####.png")
            t, c = time.perf_counter(), time.process_time()
            with quiet_stderr(stdout=True):
                bpy.ops.render.render(animation=True, scene=scene.name)
            wall[(camera, codec)].append((time.perf_counter() - t) / args.frames)
            cpu[(camera, codec)].append((time.process_time() - c) / args.frames)
            written = sorted((tmp / f"{codec}-{camera}" / "lowcam").glob("*.png"))
            assert len(written) == (args.frames if camera else 0), written
    print(f"sample scene, {args.frames} frames, medians of {args.turns} turns, per frame:")
    for codec in ("NONE", "ZIP"):
        off, on = (float(np.median(wall[(c, codec)])) for c in (False, True))
        off_c, on_c = (float(np.median(cpu[(c, codec)])) for c in (False, True))
        print(f"  {codec:4s} renders: Blender alone {off:.2f} s wall ({off_c:.2f} s CPU), with the camera "
              f"{on:.2f} s ({on_c:.2f} s CPU): the camera adds {on / off - 1:.0%} of the wall time "
              f"({on_c / off_c - 1:.0%} of the CPU; target <= 50 %)", flush=True)
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
