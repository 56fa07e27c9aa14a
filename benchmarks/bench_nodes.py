"""Benchmark: what the "Lowcam Camera" node group costs in Blender's compositor, per frame.

The sample scene's render (:func:`lowcam.sample.sample_render`, premultiplied float) and plate go in through Image
nodes; the group is baked for the render's size and composited at that size by ``bpy.ops.render.render`` (nothing
to render: the compositor alone). Sizes: the profile's own frame (Fire-i: 640x480) and 1920 px wide at the
profile's aspect ratio (Fire-i: 1920x1440; a 1920x1080 render covers too little vertically for a 4:3 camera and
the bake refuses it, so a 1080p-wide workflow renders 1920x1440 for it). Each case also
times a pass-through compositor (the render straight to the output), so the group's own cost is the difference.
Prints the first composite (which includes loading the group's maps and, on the GPU device, compiling its shaders)
and the median of the following ones, in ms.

    .venv/bin/python benchmarks/bench_nodes.py [--repeats 5] [--device CPU GPU] [--profile fire-i] [--stages]

``--stages`` instead times the chain cut after each stage (``build_camera_group(until=...)``) at the profile's
size, so each stage's share is the step from the one before.

Runs in whatever Blender imports as ``bpy`` (the bpy module 5.0 in the project's venv; a real binary with
``blender -b --python benchmarks/bench_nodes.py -- ARGS``). ``--device GPU`` uses Blender's GPU compositor, which
on a machine without a GPU runs on Mesa's software OpenGL (llvmpipe): that figure is not a GPU's.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time


def _args(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--device", nargs="+", default=["CPU"], choices=["CPU", "GPU"])
    parser.add_argument("--profile", default="fire-i")
    parser.add_argument("--stages", action="store_true", help="time the chain cut after each stage")
    return parser.parse_args(argv)


def _composite_times(scene, repeats: int) -> tuple[float, float]:
    """(first composite, median of ``repeats`` more) in ms."""
    import bpy

    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        with bpy.context.temp_override(scene=scene):
            bpy.ops.render.render(write_still=False, scene=scene.name)
        times.append((time.perf_counter() - t0) * 1000.0)
    return times[0], statistics.median(times[1:])


def _scene(group, render_image, plate_image, shape, device: str):
    """A scene whose compositor is Image nodes -> ``group`` (or straight through when None) -> output."""
    import bpy

    from lowcam_blender import submodule

    compat = submodule("blender_compat")
    parity = submodule("nodes.parity")
    scene = parity._compositor_scene(shape[1], shape[0])
    scene.render.compositor_device = device
    scene.render.use_compositing = True
    tree = compat.compositor_tree(scene)
    tree.nodes.clear()
    src = tree.nodes.new("CompositorNodeImage")
    src.image = render_image
    if group is None:
        tree.links.new(src.outputs[0], compat.compositor_output(tree))
        return scene
    node = tree.nodes.new("CompositorNodeGroup")
    node.node_tree = group
    plate = tree.nodes.new("CompositorNodeImage")
    plate.image = plate_image
    tree.links.new(src.outputs[0], node.inputs["Image"])
    tree.links.new(plate.outputs[0], node.inputs["Plate"])
    tree.links.new(node.outputs["Image"], compat.compositor_output(tree))
    return scene


def main(argv=None) -> None:
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = _args(argv)

    import bpy

    from lowcam.node_maps import bake
    from lowcam.profile import load_profile
    from lowcam.sample import sample_plate, sample_render
    from lowcam_blender import submodule

    build = submodule("nodes.build")
    parity = submodule("nodes.parity")
    profile = load_profile(args.profile)
    plate = parity.plate_image(sample_plate(profile))
    sizes = [(profile.camera.height, profile.camera.width),
             (round(1920 * profile.camera.height / profile.camera.width), 1920)]
    if args.stages:
        h, w = sizes[0]
        render = build.image_from_array(f"bench render {w}x{h}", sample_render(profile, w, h))
        render.alpha_mode = "PREMUL"
        camera = bake(profile, (h, w))
        print(f"Blender {bpy.app.version_string}, {args.device[0]} {w}x{h}, the chain cut after each stage, "
              f"median of {args.repeats} (ms):")
        last = _composite_times(_scene(None, render, plate, (h, w), args.device[0]), args.repeats)[1]
        for stage in build.group_stages(camera):
            group = build.build_camera_group(camera, name=f"bench until {stage}", until=stage)
            ms = _composite_times(_scene(group, render, plate, (h, w), args.device[0]), args.repeats)[1]
            print(f"{stage:20s} {ms:8.0f} (+{ms - last:.0f})")
            last = ms
        return
    print(f"Blender {bpy.app.version_string}, profile {args.profile}, first composite and median of "
          f"{args.repeats} (ms):")
    for device in args.device:
        for h, w in sizes:
            render = build.image_from_array(f"bench render {w}x{h}", sample_render(profile, w, h))
            render.alpha_mode = "PREMUL"
            group = build.build_camera_group(bake(profile, (h, w)), name=f"bench camera {w}x{h}")
            nodes = sum(submodule("nodes.viewport").node_kinds(group).values())
            through = _composite_times(_scene(None, render, plate, (h, w), device), args.repeats)
            camera = _composite_times(_scene(group, render, plate, (h, w), device), args.repeats)
            print(f"{device} {w}x{h}: pass-through first {through[0]:.0f} median {through[1]:.0f}; "
                  f"Lowcam Camera ({nodes} nodes) first {camera[0]:.0f} median {camera[1]:.0f}; "
                  f"the group's own {camera[1] - through[1]:.0f}")


if __name__ == "__main__":
    main()
