"""``lowcam demo --footage``: real phone footage as the plate, its gyro log driving the camera.

The engine reads the clip (:mod:`lowcam.gyro_footage`); this module renders the inserted objects with Cycles from a
camera that turns with the integrated gyro (so they stay fixed in the world), then composites every frame twice:
plain (alpha over the plate) and through the camera profile with the frame's gyro rate, logged exposure and
rolling shutter. The profile is the base profile set to the clip's camera, then estimated from the plate
(``lowcam calibrate plate``); it is saved as ``plate_profile.toml``. It writes ``side_by_side.png`` (the middle
frame) and ``side_by_side.gif`` (the clip).

Contents
--------
- :data:`WORLD_FROM_LOWCAM`: Lowcam's world axes (the first frame's camera: x right, y down, z forward) to Blender's
- :func:`build_footage_scene`: a Cycles scene with the inserted objects and a camera set to the profile's render field
- :func:`render_footage`: one premultiplied RGBA render (EXR) per frame from the gyro-turned camera
- :data:`PLATE_FRAMES`: how many of the clip's frames ``lowcam calibrate plate``'s estimate looks at
- :func:`run_footage_demo`: the whole demo: clip, profile, renders, composites, PNG and GIF, with progress
"""
from __future__ import annotations

import time
from pathlib import Path

import bpy
import numpy as np

from ..blender_compat import shader_nodes
from .frames import aim_render_camera
from .render import render_still

#: Lowcam's world axes (the first frame's camera: x right, y down, z forward) to Blender's (x right, y forward, z up).
WORLD_FROM_LOWCAM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Frames of the clip the plate estimate looks at (evenly spread; the estimate costs about 5 s a frame on 2 cores).
PLATE_FRAMES = 8
#: Blender's camera axes (x right, y up, looking down -z) to Lowcam's camera axes.
_BLENDER_CAM_TO_LOWCAM = np.diag([1.0, -1.0, -1.0])


def _material(name, colour, metallic=0.0, roughness=0.4):
    m = bpy.data.materials.new(name)
    bsdf = shader_nodes(m).nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    return m


def build_footage_scene(hfov_deg: float, width: int, height: int, samples: int = 8, projection: str = "pinhole"):
    """A fresh Cycles scene (CPU, ``samples`` samples, transparent film, single-layer float EXR output) with a
    sphere and a cube standing about 25 m ahead and up-left of the first frame's view, lit by a sun; returns
    (scene, camera). The camera's horizontal field is ``hfov_deg`` in ``projection`` (the render the profile needs,
    :func:`lowcam.pipeline.render_camera`)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    r = scene.render
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.film_transparent = True
    r.use_compositing = False
    settings = r.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGBA"
    settings.color_depth = "32"

    def at(lowcam_world):   # a point given in Lowcam's world axes (m), in Blender's
        return tuple(float(v) for v in WORLD_FROM_LOWCAM @ np.asarray(lowcam_world, float))

    bpy.ops.mesh.primitive_uv_sphere_add(radius=2.2, location=at((-6.5, -5.0, 26.0)), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(_material("Gold", (0.95, 0.6, 0.15), metallic=0.6, roughness=0.3))
    bpy.ops.mesh.primitive_cube_add(size=2.6, location=at((-1.0, -4.0, 24.0)), rotation=(0.5, 0.3, 0.7))
    bpy.context.object.data.materials.append(_material("Red", (0.8, 0.08, 0.05)))
    bpy.ops.object.light_add(type="SUN", rotation=(0.7, 0.2, 0.9))
    bpy.context.object.data.energy = 4.0
    world = bpy.data.worlds.new("World")
    shader_nodes(world).nodes["Background"].inputs["Color"].default_value = (0.75, 0.78, 0.82, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.8
    scene.world = world

    bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0))
    camera = bpy.context.object
    aim_render_camera(camera.data, {"projection": projection, "hfov_deg": hfov_deg})
    camera.data.clip_start, camera.data.clip_end = 0.1, 1000.0
    scene.camera = camera
    return scene, camera


def render_footage(rotations, folder, hfov_deg: float, width: int, height: int, samples: int = 8,
                   progress=None, projection: str = "pinhole") -> list[Path]:
    """Render one float EXR per camera-to-world rotation (Lowcam axes, (n, 3, 3)) into ``folder``; returns the
    paths. The camera's Blender matrix is ``WORLD_FROM_LOWCAM @ R @ diag(1, -1, -1)``."""
    from mathutils import Matrix

    scene, camera = build_footage_scene(hfov_deg, width, height, samples, projection)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i, rot in enumerate(rotations):
        m = WORLD_FROM_LOWCAM @ np.asarray(rot) @ _BLENDER_CAM_TO_LOWCAM
        camera.matrix_world = Matrix([[*m[0], 0.0], [*m[1], 0.0], [*m[2], 0.0], [0.0, 0.0, 0.0, 1.0]])
        path = folder / f"{i:04d}.exr"
        scene.render.filepath = str(path)
        render_still(scene, f"footage frame {i}")   # Ctrl-C during it ends the demo (render.interruptible)
        out.append(path)
        if progress:
            progress(i)
    return out


def _small(frame: np.ndarray, scale: float) -> np.ndarray:
    import cv2

    return cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def run_footage_demo(footage_dir, out: Path, base_profile, frames: int = 24, first: int = 99,
                     render_width: int = 640, samples: int = 8, seed: int = 0) -> dict:
    """The whole demo (see the module docstring); returns the paths written and the figures shown. Under
    :func:`addon.render.interruptible`, Ctrl-C during a render ends it."""
    from lowcam.gyro_footage import camera_rotations, frame_motion, read_footage_clip, write_gif
    from lowcam.io import read_plate, read_render
    from lowcam.outputs import write_png
    from lowcam.pipeline import plain_composite, render_camera, simulate
    from lowcam.sample import side_by_side

    steps = ["reading the clip and its gyro log", "estimating the profile from the plate",
             f"rendering {frames} frames with Cycles", f"simulating the camera on {frames} frames",
             "writing the side-by-side PNG and GIF"]
    say = lambda i: print(f"[{i + 1}/{len(steps)}] {steps[i]}", flush=True)  # noqa: E731
    say(0)
    clip = read_footage_clip(footage_dir, first, frames)
    say(1)
    profile, note = _plate_profile(clip, base_profile)
    print(f"      {note}", flush=True)
    profile.save(out / "plate_profile.toml")
    say(2)
    height = int(round(render_width * clip.height / clip.width))
    cam = render_camera(profile, render_width, height)
    t0 = time.perf_counter()
    tick = lambda i: print(f"      frame {i + 1}/{frames} rendered", flush=True)  # noqa: E731
    exrs = render_footage(camera_rotations(clip), out / "render", cam["hfov_deg"], render_width, height, samples,
                          progress=tick, projection=cam["projection"])
    print(f"      rendered in {time.perf_counter() - t0:.1f} s", flush=True)
    say(3)
    pairs, rates = [], []
    for i, exr in enumerate(exrs):
        render = read_render(str(exr))
        plate = read_plate(str(clip.frames[i]), clip.width, clip.height)
        w, exposure = frame_motion(clip, i)
        rates.append(w)
        pairs.append((plain_composite(render, profile, plate),
                      simulate(render, profile, plate, w, exposure, seed, clip.numbers[i])))
        print(f"      frame {i + 1}/{frames}: w = ({w[0]:+.2f}, {w[1]:+.2f}, {w[2]:+.2f}) rad/s, "
              f"exposure {exposure * 1e3:.1f} ms", flush=True)
    say(4)
    mid = len(pairs) // 2
    w = rates[mid]
    title = f"lowcam (plate estimate on {base_profile}), gyro w = ({w[0]:+.2f}, {w[1]:+.2f}, {w[2]:+.2f}) rad/s"
    write_png(out / "plain.png", pairs[mid][0])
    write_png(out / "lowcam.png", pairs[mid][1])
    png = write_png(out / "side_by_side.png", side_by_side(*pairs[mid], "plain composite", title))
    gif = write_gif(out / "side_by_side.gif",
                    [_small(side_by_side(p, q, "plain", "lowcam"), 0.5) for p, q in pairs],
                    fps=30.0 / 2)
    return {"png": png, "gif": gif, "profile": profile, "note": note, "frames": clip.numbers}


def _plate_profile(clip, base_profile):
    """The profile for the clip: the base profile set to the clip's camera (K, read-out, gyro), then
    ``lowcam calibrate plate``'s estimates from :data:`PLATE_FRAMES` of the clip's frames."""
    from lowcam.gyro_footage import plate_profile
    from lowcam.profile import load_profile

    estimated, estimates = plate_profile(load_profile(base_profile), clip, PLATE_FRAMES)
    used = [e for e in estimates if e.applied]
    return estimated, (f"profile estimated from {min(len(clip.frames), PLATE_FRAMES)} frames of the plate "
                       f"({len(used)} of {len(estimates)} estimates applied) on the {base_profile} profile set to the "
                       f"clip's camera")
