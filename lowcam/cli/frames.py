"""The commands that film frames: ``lowcam apply`` (one render), ``lowcam stages`` (every stage's picture) and ``lowcam
batch`` (a shot, resumable, optionally on Dask).

Contents
--------
- :func:`cmd_apply`: ``lowcam apply``: simulate the camera on one render
- :func:`save_stages`: write each stage's picture as PNG (the working image premultiplied over black)
- :func:`cmd_stages`: ``lowcam stages``: every stage's intermediate output as an image
- :func:`gyro_motion`: each frame's motion from ``--gyro`` and its options, and the frame rate (batch and motion)
- :func:`gyro_options`: add ``--gyro`` and its options to a command
- :func:`cmd_batch`: ``lowcam batch``: run the camera over a shot, resumable, optionally on Dask
- :func:`add_commands`: add this module's commands to the ``lowcam`` sub-parsers
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..arguments import Number, Reads, Text, Writes, angular_velocity, bounded_int, defocus, frame_number, seed
from ..batch import Shot, check_shot_outputs, parse_frames, run_shot, summary
from ..effects import trusted_modules
from ..errors import LowcamError
from ..io import read_plate, read_render
from ..gyro_logs import gyro_log_motion
from ..motion import read_motion_json
from ..outputs import IMAGE_SUFFIXES, check_image_output, check_output, check_output_folder, make_output_folder, write_image, write_png
from ..passes import needed_passes, read_render_and_passes
from ..pipeline import run
from ..profile import load_profile
from ..sample import sample_plate, sample_render
from ..video import VIDEO_OUTPUTS, is_video, write_shot_video
from .common import EXPOSURE_S, FPS, FRAMES, LAYER, METRES_PER_UNIT, PROFILE, RENDER_SPACE, plate_colour_option


def _load_inputs(args, profile):
    render = read_render(args.render, args.layer, args.render_space)
    plate = None
    if args.plate:
        c = profile.camera
        plate = read_plate(args.plate, c.width, c.height, channels=None if profile.is_raw else 3)
    return render, plate


def _pass_effects(args) -> tuple:
    """The effects ``--object-motion`` and ``--defocus`` add to the profile, as ``(name, ((key, value), ...))``."""
    effects = []
    if args.object_motion:
        effects.append(("object_motion", ()))
    if args.defocus:
        effects.append(("depth_of_field", (("focus_distance_m", args.defocus[0]), ("aperture_mm", args.defocus[1]))))
    return tuple(effects)


def _pass_options(p, fps: bool) -> None:
    """``--object-motion``, ``--defocus`` and the units of the render passes they read (apply and batch)."""
    p.add_argument("--object-motion", action="store_true",
                   help="blur moving objects along the render's Vector pass (a Blender multilayer EXR)")
    p.add_argument("--defocus", type=defocus, metavar="FOCUS_M,APERTURE_MM",
                   help="defocus from the render's Depth (Z) pass: focus distance (m), aperture diameter (mm)")
    if fps:
        p.add_argument("--fps", type=FPS, default=24.0,
                       help="frame rate of the render's Vector pass (pixels per frame; default 24)")
    p.add_argument("--metres-per-unit", type=METRES_PER_UNIT, default=1.0,
                   help="the Depth pass's unit in metres (Blender's Unit Scale; default 1)")


def _render_space_option(p) -> None:
    p.add_argument("--render-space", type=RENDER_SPACE, metavar="SPACE",
                   help="the renders' colour space: linear-rec709, linear-rec2020, acescg (or Blender's name); "
                        "default: the one an OpenEXR header names, else linear-rec709")


def cmd_apply(args) -> int:
    check_image_output(args.output)
    profile = load_profile(args.profile)
    for name, values in _pass_effects(args):
        profile = profile.with_effect(name, **dict(values))
    render, passes = read_render_and_passes(args.render, args.layer, needed_passes(profile), args.fps,
                                            args.metres_per_unit, args.render_space)
    c = profile.camera
    plate = read_plate(args.plate, c.width, c.height, channels=None if profile.is_raw else 3) if args.plate else None
    t0 = time.perf_counter()
    result = run(render, profile, plate, args.angular_velocity, args.exposure_s, args.seed, args.frame,
                 passes=passes)
    write_image(args.output, result.frame)
    print(f"{args.output}: {profile.name}, {result.frame.shape[1]}x{result.frame.shape[0]}, "
          f"{100 * result.footprint.mean():.1f} % of pixels from the render, {1e3 * (time.perf_counter() - t0):.0f} ms")
    return 0


def save_stages(stages, folder: Path) -> list[Path]:
    """Write each stage's picture as PNG (the working image as premultiplied-over-black RGB)."""
    make_output_folder(folder)
    paths = []
    for name, img in stages.items():
        if img.dtype != np.uint8:
            img = np.clip(img[..., :3] * 255.0 + 0.5, 0, 255).astype(np.uint8)
        paths.append(write_png(folder / f"{name}.png", img))
    return paths


def cmd_stages(args) -> int:
    check_output_folder(args.output, force=args.force)
    profile = load_profile(args.profile)
    if args.render:
        render, plate = _load_inputs(args, profile)
    else:
        render, plate = sample_render(profile, 1600), sample_plate(profile)
    result = run(render, profile, plate, args.angular_velocity, args.exposure_s, args.seed, args.frame,
                 keep_stages=True)
    paths = save_stages(result.stages, Path(args.output))
    print(f"{args.output}: {len(paths)} stage images ({', '.join(p.stem for p in paths)})")
    return 0


def gyro_motion(args, frames) -> tuple[dict, float]:
    """Each frame's motion from ``--gyro`` (a Gyroflow ``.gcsv`` log or ``.gyroflow`` project, a clip with its own
    gyro, or Lowcam's CSV), ``--fps`` (or the project's or clip's), ``--exposure-s``, ``--gyro-t0`` and ``--gyro-first-frame`` (batch and motion),
    and the frame rate used."""
    if args.exposure_s is None:
        raise LowcamError(f"{args.gyro}: a gyro log needs --exposure-s (and --fps unless it is a Gyroflow project "
                          f"or a video clip, which state it)")
    return gyro_log_motion(args.gyro, frames, args.fps, args.exposure_s, args.gyro_t0, args.gyro_first_frame)


def gyro_options(p) -> None:
    """``--gyro``, ``--fps``, ``--exposure-s``, ``--gyro-t0`` and ``--gyro-first-frame`` (batch and motion)."""
    p.add_argument("--gyro", type=Reads("file"),
                   help="gyro log integrated over each frame's exposure: a Gyroflow .gcsv log or .gyroflow project "
                        "(axes and sync offsets from the file), a video clip that records its own gyro (GoPro, "
                        "Sony, Insta360, DJI: read with telemetry-parser), or a CSV of t, wx, wy, wz (rad/s, "
                        "camera frame)")
    p.add_argument("--fps", type=FPS, help="frame rate, for --gyro (default: a .gyroflow project's or the clip's) "
                                           "and the renders' Vector pass (default 24)")
    p.add_argument("--exposure-s", type=EXPOSURE_S, help="exposure time, for --gyro")
    p.add_argument("--gyro-t0", type=Number(-1e9, 1e9, what="gyro time in s"), default=0.0,
                   help="time (s, the log's clock; a project's: the video's) at which --gyro-first-frame starts")
    p.add_argument("--gyro-first-frame", type=frame_number, default=1)


def cmd_batch(args) -> int:
    frames = parse_frames(args.frames)
    video_out = args.output if Path(args.output).suffix.lower() in VIDEO_OUTPUTS else None
    if video_out:   # the frames as PNG files beside it (resumable), then the video
        check_output(video_out, [args.plates, args.motion, args.gyro])
        args.output = str(Path(video_out + ".frames") / "######.png")
    if args.plate_colour and not is_video(args.plates):
        raise LowcamError(f"--plate-colour {args.plate_colour}: only a video plate has colour tags to override "
                          f"(--plates is {args.plates or 'not given'})")
    check_shot_outputs(args.output, args.renders, args.plates, frames)
    load_profile(args.profile)  # fail early on a bad profile
    motion, require, fps = {}, False, args.fps or 24.0
    if args.motion:
        motion, require = read_motion_json(args.motion), True
    elif args.gyro:
        (motion, fps), require = gyro_motion(args, frames), True
    shot = Shot(args.profile, args.renders, args.output, args.plates, motion, require, args.seed,
                args.video_first_frame, args.layer, args.motion or args.gyro or "the motion file",
                _pass_effects(args), fps, args.metres_per_unit, tuple(sorted(trusted_modules())),
                args.render_space, args.plate_colour)
    shot.load_profile()  # a bad --defocus value fails here, once
    t = time.perf_counter()
    results = run_shot(shot, frames, args.force, args.workers, args.scheduler, args.quiet)
    done = sum(r.status == "written" for r in results)
    elapsed = time.perf_counter() - t
    rate = f" ({done / elapsed:.2f} frames/s written)" if done else ""
    failed = any(r.status == "failed" for r in results)
    print(f"{summary(results)}\n{len(frames)} frames in {elapsed:.1f} s{rate}",
          file=sys.stderr if failed else sys.stdout)
    if video_out and failed:
        print(f"{video_out}: not written until every frame is made; run the same command again", file=sys.stderr)
    elif video_out:
        print(write_shot_video(video_out, [shot.output_path(f) for f in frames], args.fps, shot.plates,
                               shot.plate_colour))
    return 1 if failed else 0


def add_commands(sub) -> None:
    """Add this module's commands to ``sub`` (the ``lowcam`` sub-parsers)."""
    def frame_options(p, render_required=True):
        p.add_argument("--profile", type=PROFILE, default="fire-i", help="profile name or TOML path (default fire-i)")
        p.add_argument("--render", type=Reads("file"), required=render_required,
                       help="premultiplied RGBA render (EXR or PNG)")
        p.add_argument("--layer", type=LAYER, help="the view layer to take from a multilayer EXR with several")
        _render_space_option(p)
        p.add_argument("--plate", type=Reads("file"), help="the video frame (PNG/JPEG) at the camera's size")
        p.add_argument("--angular-velocity", type=angular_velocity, default=(0.0, 0.0, 0.0), metavar="WX,WY,WZ",
                       help="camera rotation in rad/s, camera frame: x right, y down, z forward")
        p.add_argument("--exposure-s", type=EXPOSURE_S, default=None, help="exposure time (s); default: the profile's")
        p.add_argument("--seed", type=seed, default=0, help="noise seed, 0 <= seed < 2^64")
        p.add_argument("--frame", type=frame_number, default=0, help="frame number (noise differs per frame)")

    p = sub.add_parser("apply", help="simulate the camera on one render")
    frame_options(p)
    _pass_options(p, fps=True)
    p.add_argument("-o", "--output", type=Writes("file", IMAGE_SUFFIXES), required=True,
                   help="output frame: .png, .jpg or .exr (code values / 255)")
    p.set_defaults(func=cmd_apply)

    p = sub.add_parser("stages", help="write every stage's intermediate output as an image")
    frame_options(p, render_required=False)
    p.add_argument("-o", "--output", type=Writes("folder"), required=True,
                   help="folder for the stage images (new, empty or Lowcam's)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files")
    p.set_defaults(func=cmd_stages)

    p = sub.add_parser("batch", help="run the camera over a shot (frame sequence), resumable, optionally on Dask")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--renders", type=Reads("pattern"), required=True, help="render pattern, '#' for frame digits: renders/####.exr")
    p.add_argument("--layer", type=LAYER, help="the view layer to take from multilayer EXRs with several")
    _render_space_option(p)
    p.add_argument("--plates", type=Reads("pattern"), help="plate pattern (plate/####.png) or one video file")
    p.add_argument("--video-first-frame", type=frame_number, default=1,
                   help="shot frame shown by the video's first frame")
    plate_colour_option(p)
    p.add_argument("--motion", type=Reads("file"), help="motion.json: per-frame angular velocity and exposure")
    gyro_options(p)
    p.add_argument("--frames", type=FRAMES, required=True, help="e.g. 1-240, 1-10,15, 1-240x2")
    p.add_argument("-o", "--output", type=Writes("pattern", IMAGE_SUFFIXES + tuple(VIDEO_OUTPUTS)), required=True,
                   help="output pattern: out/####.png; or a video file (shot.mp4, .mov, .mkv) coded as the plate "
                        "video is, its frames kept in shot.mp4.frames/")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--force", action="store_true", help="redo frames whose output exists")
    p.add_argument("--workers", type=bounded_int(0, 1024), default=0,
                   help="run on a Dask LocalCluster of N processes")
    p.add_argument("--scheduler", type=Text(what="tcp://HOST:PORT"), help="run on an existing Dask cluster: tcp://host:port")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _pass_options(p, fps=False)
    p.set_defaults(func=cmd_batch)

