"""Benchmark: the full Fire-i chain on a 3000x2250 RGBA float32 render (the paper's size) -> 640x480 frame.

Prints the median ms/frame and the peak memory of the engine, and the same for Blender's own compositor doing
Lens Distortion + Blur + Filter on the same image in the same run, with their ratio. Each side runs in its own
process so their memory does not mix.

    .venv/bin/python benchmarks/bench_pipeline.py [--repeats 15]
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OMEGA = (0.05, 0.8, 0.1)  # rad/s: a moderate hand-held pan, so motion blur does real work


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def peak_mb() -> float:
    """This process's peak resident memory (VmHWM; unlike ru_maxrss it is not inherited over fork)."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 1024


def run_engine(render_path: str, repeats: int) -> dict:
    import numpy as np

    import lowcam
    from lowcam.sample import sample_plate

    render = np.load(render_path)
    profile = lowcam.load_profile("fire-i")
    plate = sample_plate(profile)
    lowcam.run(render, profile, plate, OMEGA)  # warm-up: builds the lens maps once per render size
    base = rss_mb()
    times = []
    for frame in range(repeats):
        t = time.perf_counter()
        lowcam.run(render, profile, plate, OMEGA, seed=0, frame=frame)
        times.append(1e3 * (time.perf_counter() - t))
    return {"median_ms": statistics.median(times), "min_ms": min(times), "peak_mb": peak_mb(),
            "working_mb": peak_mb() - base}


def run_blender(exr_path: str, repeats: int) -> dict:
    import bpy

    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 3000, 2250, 100
    scene.render.use_compositing = True
    tree = bpy.data.node_groups.new("Comp", "CompositorNodeTree")
    scene.compositing_node_group = tree
    tree.interface.new_socket(name="Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    image = tree.nodes.new("CompositorNodeImage")
    image.image = bpy.data.images.load(exr_path)
    lens = tree.nodes.new("CompositorNodeLensdist")
    lens.inputs["Distortion"].default_value = -0.2
    blur = tree.nodes.new("CompositorNodeBlur")
    blur.inputs["Size"].default_value = (3.0, 3.0)
    filt = tree.nodes.new("CompositorNodeFilter")
    filt.inputs["Type"].default_value = "Box Sharpen"
    out = tree.nodes.new("NodeGroupOutput")
    chain = [image.outputs["Image"], lens, blur, filt, out]
    tree.links.new(chain[0], lens.inputs["Image"])
    for a, b in zip(chain[1:-1], chain[2:]):
        tree.links.new(a.outputs[0], b.inputs[0])
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(Path(tempfile.mkdtemp()) / "blender.exr")
    bpy.ops.render.render(write_still=True)  # warm-up
    base = rss_mb()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        times.append(1e3 * (time.perf_counter() - t))
    return {"median_ms": statistics.median(times), "min_ms": min(times), "peak_mb": peak_mb(),
            "working_mb": peak_mb() - base}


def child(kind: str, path: str, repeats: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", kind, path, "--repeats", str(repeats)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--blender-repeats", type=int, default=5)
    parser.add_argument("--child", nargs=2, metavar=("KIND", "PATH"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, path = args.child
        fn = run_engine if kind == "engine" else run_blender
        print(json.dumps(fn(path, args.repeats)))
        return

    import numpy as np

    from lowcam.outputs import write_exr
    from lowcam.sample import sample_render

    tmp = Path(tempfile.mkdtemp())
    render = sample_render("fire-i", 3000)
    assert render.shape == (2250, 3000, 4) and render.dtype == np.float32
    np.save(tmp / "render.npy", render)
    write_exr(tmp / "render.exr", render)
    print(f"Fire-i chain, 3000x2250 RGBA float32 -> 640x480, w = {OMEGA} rad/s, 2 CPU threads")
    print("[1/2] engine ...", flush=True)
    engine = child("engine", str(tmp / "render.npy"), args.repeats)
    print("[2/2] Blender compositor (Lens Distortion + Blur + Filter) ...", flush=True)
    blender = child("blender", str(tmp / "render.exr"), args.blender_repeats)
    print(f"{'':28s}{'median ms':>12s}{'min ms':>10s}{'peak RSS MB':>14s}{'working MB':>12s}")
    for name, r in (("lowcam fire-i (full chain)", engine), ("Blender compositor", blender)):
        print(f"{name:28s}{r['median_ms']:12.1f}{r['min_ms']:10.1f}{r['peak_mb']:14.0f}{r['working_mb']:12.0f}")
    print(f"speed-up over the compositor: {blender['median_ms'] / engine['median_ms']:.1f}x "
          f"(target: engine <= 150 ms and >= 10x)")
    results = ROOT / "benchmarks" / "results"
    results.mkdir(exist_ok=True)
    (results / "pipeline.json").write_text(json.dumps({"engine": engine, "blender": blender}, indent=2))


if __name__ == "__main__":
    main()
