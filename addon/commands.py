"""The Blender-driving commands of ``lowcam``: ``demo``, ``render``, ``motion`` and ``node-asset``.

They live on the Blender side and reach the ``lowcam`` command through the ``lowcam.commands`` entry point
(pyproject.toml), so the engine imports nothing of ``addon/`` or ``nodes/``. Importing this module imports no bpy;
each command loads the extension (the repository root as the package ``lowcam_blender``) when it runs. Every
option declares what it reads, writes or takes (:mod:`lowcam.arguments`), so ``lowcam``'s error boundary refuses
an output that is an input (the .blend, a profile) before Blender starts.
``lowcam demo --synthetic`` needs no Blender: the engine alone on a generated render.

Contents
--------
- :func:`cmd_demo`: ``lowcam demo``: the sample scene rendered with Cycles, plain and degraded side by side
  (``--footage``: real phone footage with its gyro log, :mod:`addon.footage`)
- :data:`FOOTAGE_DEFAULT`: where ``--footage`` looks without a folder, beside the repository
- :func:`cmd_render`: ``lowcam render``: render frames of a .blend and write their degraded composites
- :func:`cmd_motion`: ``lowcam motion``: each frame's camera motion as motion.json, from a .blend or from a gyro
  log (``--gyro``: a Gyroflow ``.gcsv`` or ``.gyroflow`` file, or Lowcam's CSV; no Blender needed)
- :func:`cmd_node_asset`: ``lowcam node-asset``: the node group as an asset .blend
- :func:`add_commands`: add the Blender-driving sub-commands to the ``lowcam`` parser (the entry point)
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from lowcam.arguments import Reads, Writes, angular_velocity, bounded_int, seed
from lowcam.cli import FRAMES, PROFILE
from lowcam.cli.frames import gyro_options
from tqdm import tqdm


def _side(name: str):
    """The extension's module ``name`` (``"addon.render"``), the add-on registered with Blender once."""
    from .. import submodule

    return submodule(name)


def cmd_demo(args) -> int:
    """Build the sample scene, render it headless with Cycles on the CPU through the add-on, and write the plain
    and degraded composites side by side (``--synthetic``: the engine alone on a generated render)."""
    from lowcam.outputs import output_folder
    from lowcam.profile import load_profile

    if args.footage is not None:
        return _footage_demo(args)
    profile = load_profile(args.profile)
    with output_folder(args.output, force=args.force) as out:  # a failed demo leaves no half-made folder
        return _sample_demo(args, profile, out.resolve())


def _sample_demo(args, profile, out: Path) -> int:
    """``lowcam demo`` (``--synthetic`` or with Blender) into the folder ``out``, made for it."""
    from lowcam.io import read_image, read_plate
    from lowcam.outputs import write_png
    from lowcam.pipeline import plain_composite
    from lowcam.sample import side_by_side

    steps = ["building the sample scene", "rendering with Cycles and simulating the camera", "writing the composites"]
    say = lambda i: print(f"[{i + 1}/{len(steps)}] {steps[i]}", flush=True)  # noqa: E731
    say(0)
    if args.synthetic:
        from lowcam.outputs import write_exr
        from lowcam.pipeline import run
        from lowcam.sample import sample_plate, sample_render

        render = sample_render(profile, args.render_width)
        write_exr(out / "sample_render.exr", render)
        plate = sample_plate(profile, args.angular_velocity, None, args.seed, 0)   # filmed by the same camera
        say(1)
        frame = run(render, profile, plate, args.angular_velocity, None, args.seed, 0).frame
        title = f"lowcam ({profile.name}), w = {args.angular_velocity} rad/s"
    else:
        from lowcam.scene import OVERLAY_LAYER, over_frame, overlay_in_frame, read_layers

        blend = _side("addon.sample").build_sample_scene(out, args.profile, args.render_width)
        say(1)
        t0 = time.perf_counter()
        composite = _side("addon.render").render(blend, [1], str(out / "lowcam" / "####.png"), force=True,
                                                 keep_renders=str(out / "render"))[0]
        print(f"      rendered and simulated in {time.perf_counter() - t0:.1f} s", flush=True)
        frame = read_image(composite)
        render, overlay = read_layers(out / "render" / "0001.exr", "ViewLayer", OVERLAY_LAYER)
        plate = read_plate(out / "plate" / "0001.png", profile.camera.width, profile.camera.height)
        title = f"lowcam ({profile.name}), camera panning, sphere moving"
    say(2)
    plain = plain_composite(render, profile, plate)
    if not args.synthetic:
        plain = over_frame(plain, overlay_in_frame(overlay, profile))
    write_png(out / "lowcam.png", frame)
    write_png(out / "plain.png", plain)
    write_png(out / "side_by_side.png", side_by_side(plain, frame, "plain composite", title))
    print(f"{out / 'side_by_side.png'}: plain composite (left) next to the {profile.name} camera (right)")
    return 0


#: ``lowcam demo --footage`` without a folder: ``shared/data/phone-gyro-video`` beside the repository (or beside
#: the folder of worktrees the repository sits in).
FOOTAGE_DEFAULT = Path("shared") / "data" / "phone-gyro-video"


def _footage_demo(args) -> int:
    """``lowcam demo --footage [DIR]``: :func:`addon.footage.run_footage_demo` on the phone clip."""
    from lowcam.errors import LowcamError
    from lowcam.gyro_footage import find_footage
    from lowcam.outputs import check_output_folder, make_output_folder

    folder = args.footage
    if not folder:
        root = Path(__file__).resolve().parent.parent
        found = [p / FOOTAGE_DEFAULT for p in (root.parent, root.parent.parent) if (p / FOOTAGE_DEFAULT).is_dir()]
        if not found:
            raise LowcamError(f"{root.parent / FOOTAGE_DEFAULT}: no such folder: give the phone-gyro-video data set "
                              f"as --footage DIR")
        folder = found[0]
    find_footage(folder)   # before the output folder is made: a missing data set writes nothing
    out = Path(check_output_folder(args.output, force=args.force)).resolve()
    footage = _side("addon.footage")
    # a failure or Ctrl-C (during a render too) leaves no half-made folder
    with _built_beside(out) as building, _side("addon.render").interruptible():
        result = footage.run_footage_demo(folder, make_output_folder(building), args.profile,
                                          frames=args.footage_frames, seed=args.seed)
    print(f"{out / result['png'].name}: plain composite (left) next to the camera (right); the clip: "
          f"{out / result['gif'].name}")
    return 0


@contextmanager
def _built_beside(out: Path):
    """A new folder beside ``out`` to build an output in: moved into ``out`` when the block ends, removed (with
    everything in it) when it fails or is interrupted, so ``out`` never holds a half-made output."""
    out.parent.mkdir(parents=True, exist_ok=True)
    building = Path(tempfile.mkdtemp(prefix=f".{out.name}.lowcam-building-", dir=out.parent))
    try:
        yield building
        _move_into(building, out)
    finally:
        shutil.rmtree(building, ignore_errors=True)


def _move_into(built: Path, out: Path) -> None:
    """Move everything in ``built`` into ``out`` (renamed whole when ``out`` does not exist), file by file."""
    if not out.exists():
        os.replace(built, out)
        return
    for item in built.iterdir():
        target = out / item.name
        if item.is_dir() and target.is_dir():
            _move_into(item, target)
        else:
            os.replace(item, target)


def cmd_render(args) -> int:

    from lowcam.batch import parse_frames

    frames = parse_frames(args.frames)
    bar = tqdm(total=len(frames), unit="frame", desc="lowcam render", disable=None)  # on a terminal only
    written = _side("addon.render").render(args.blend, frames, args.output, args.force,
                                           progress=lambda f, p: bar.update(1), compression=args.render_compression)
    bar.close()
    print(f"{len(written)} composites in {written[0].parent if written else args.output}")
    return 0


def cmd_motion(args) -> int:
    """``lowcam motion``: each frame's camera motion as motion.json, from a .blend's camera (Blender) or from a
    gyro log (``--gyro``: the engine alone, no Blender)."""
    from lowcam.batch import parse_frames
    from lowcam.cli.frames import gyro_motion
    from lowcam.errors import LowcamError
    from lowcam.motion import write_motion_json
    from lowcam.outputs import check_output

    if (args.blend is None) == (args.gyro is None):
        raise LowcamError("--gyro: give either a .blend (its camera's motion) or --gyro LOG (a gyro log's), not "
                          + ("both" if args.blend else "neither"))
    if args.blend is not None and (args.fps is not None or args.exposure_s is not None):
        raise LowcamError(f"{'--fps' if args.fps is not None else '--exposure-s'}: for --gyro only (a .blend's "
                          f"frame rate and exposure are its scene's)")
    if not args.output.lower().endswith(".json"):
        raise LowcamError(f"{args.output}: the motion is written as a .json file")
    check_output(args.output)
    frames = parse_frames(args.frames)
    if args.gyro is not None:
        path = write_motion_json(args.output, *gyro_motion(args, frames))
    else:
        path = _side("addon.render").write_motion(args.blend, frames, args.output)
    print(f"{path}: camera motion of {len(frames)} frames")
    return 0


def cmd_node_asset(args) -> int:
    from lowcam.errors import LowcamError
    from lowcam.outputs import check_output

    if not args.output.lower().endswith(".blend"):
        raise LowcamError(f"{args.output}: the asset is written as a .blend file")
    check_output(args.output)
    path = _side("nodes.asset").write_asset(args.output, args.profile, args.render_width, args.angular_velocity)
    print(f"{path}: \"Lowcam Camera ({args.profile})\" asset ({path.stat().st_size / 1e6:.0f} MB)")
    return 0


def add_commands(sub) -> None:
    """Add the Blender-driving sub-commands to the ``lowcam`` parser (the ``lowcam.commands`` entry point)."""
    p = sub.add_parser("demo", help="the main job on the bundled sample scene")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("-o", "--output", type=Writes("folder"), default="demo-output",
                   help="folder for the results, new, empty or Lowcam's (default demo-output)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files")
    p.add_argument("--angular-velocity", type=angular_velocity, default=(0.05, 0.6, 0.1), metavar="WX,WY,WZ",
                   help="with --synthetic: the camera's rotation (the sample scene's camera pans by itself)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--render-width", type=bounded_int(64, 8192), default=800, help="width of the sample render (px)")
    p.add_argument("--synthetic", action="store_true", help="skip Blender: the engine on a generated render")
    p.add_argument("--footage", type=Reads("folder"), nargs="?", const="", metavar="DIR",
                   help="real phone footage as the plate, its gyro driving the camera (default: "
                        "../shared/data/phone-gyro-video beside the repository)")
    p.add_argument("--footage-frames", type=bounded_int(2, 103), default=24, help="with --footage: frames (from 99)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("render", help="render frames of a .blend with Blender (bpy) and write degraded composites")
    p.add_argument("blend", type=Reads("file"), help="the .blend file (its scene's Lowcam settings are used)")
    p.add_argument("--frames", type=FRAMES, required=True, help="frames: 1-10, 1-10,15, 1-240x2")
    p.add_argument("-o", "--output", type=Writes("pattern"),
                   help="folder or #### pattern for the composites (default: the scene's)")
    p.add_argument("--force", action="store_true", help="redo frames whose composite exists")
    p.add_argument("--render-compression", choices=("NONE", "RLE", "ZIPS", "ZIP", "PIZ"),
                   help="how Blender compresses the renders Lowcam reads (lossless; the same composites): the "
                        "scene's Render Compression by default (None, the fastest; ZIP, the smallest files)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("motion", help="write the camera motion of a .blend scene or of a gyro log as motion.json "
                                      "(for lowcam batch)")
    p.add_argument("blend", type=Reads("file"), nargs="?",
                   help="the .blend file (its Lowcam motion source and exposure are used); or give --gyro")
    gyro_options(p)
    p.add_argument("--frames", type=FRAMES, required=True, help="frames: 1-10, 1-10,15, 1-240x2")
    p.add_argument("-o", "--output", type=Writes("file", (".json",)), required=True, help="the motion.json to write")
    p.set_defaults(func=cmd_motion)

    p = sub.add_parser("node-asset", help="write the compositor node group as an asset .blend")
    p.add_argument("-o", "--output", type=Writes("file", (".blend",)), required=True, help="the .blend to write")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--render-width", type=bounded_int(64, 16384), default=1600,
                   help="width of the renders it will take (px)")
    p.add_argument("--angular-velocity", type=angular_velocity, default=(0.0, 0.0, 0.0), metavar="WX,WY,WZ",
                   help="camera rotation baked into the maps (rad/s, camera frame)")
    p.set_defaults(func=cmd_node_asset)
