"""The sample scene: a real photograph filmed by the camera as the plate, inserted objects, and a panning camera.

The plate is what the camera filmed: the photograph run through the scene's profile with the camera's own motion
for each frame (:func:`lowcam.sample.film`), its noise from a seed independent of the graphics'
(:func:`lowcam.sample.plate_seed`), written as ``plate/####.png``.

``sample_scenes/build_sample_scene.py`` runs this; ``lowcam demo`` renders it.

Contents
--------
- :func:`build_sample_scene`: write ``folder/sample_scene.blend`` (and its plates ``plate/####.png``); returns its path
"""
from __future__ import annotations

import math
from pathlib import Path

import bpy

from ..blender_compat import shader_nodes


def _material(name, colour, emission=0.0):
    m = bpy.data.materials.new(name)
    bsdf = shader_nodes(m).nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    if emission:
        bsdf.inputs["Emission Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission
    return m


def build_sample_scene(folder, profile: str = "fire-i", render_width: int = 800, frames: int = 2,
                       pan_rad_s: float = 0.6, samples: int = 16, sphere_m_s: float = 3.0) -> Path:
    """Write ``folder/sample_scene.blend`` (and its plates ``plate/####.png``); returns the .blend path.

    The plate is the bundled photograph filmed through the camera with each frame's camera motion (the scene's
    motion source, as the render handler sees it) and the scene's exposure; a cube and a sphere stand in front of
    it, the sphere moving sideways at ``sphere_m_s`` (object motion); a green crosshair in the "Overlays"
    collection is excluded from the camera simulation; the camera pans at ``pan_rad_s`` about its vertical axis.
    Cycles on the CPU with ``samples`` samples.
    """
    from lowcam.outputs import write_png
    from lowcam.sample import film, plate_seed, sample_photograph

    from ..blender_compat import action_fcurves
    from .frames import motion, scene_profile, setup_scene

    folder = Path(folder).resolve()
    folder.mkdir(parents=True, exist_ok=True)

    # not read_factory_settings: that also resets the preferences, which disables an installed add-on (this one)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = "Lowcam sample"
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.frame_start, scene.frame_end = 1, frames
    scene.render.fps = 24

    stage = bpy.data.collections.new("Scene Objects")
    scene.collection.children.link(stage)
    bpy.context.view_layer.active_layer_collection = bpy.context.view_layer.layer_collection.children[stage.name]
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-0.5, 3.0, 0.0), rotation=(0.4, 0.3, 0.6))
    bpy.context.object.data.materials.append(_material("Red", (0.8, 0.1, 0.05)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(0.6, 2.6, -0.2), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    sphere = bpy.context.object
    sphere.data.materials.append(_material("White", (0.9, 0.9, 0.85)))
    bpy.ops.object.light_add(type="SUN", rotation=(0.6, 0.2, 0.8))
    bpy.context.object.data.energy = 6.0
    world = bpy.data.worlds.new("World")
    shader_nodes(world).nodes["Background"].inputs["Strength"].default_value = 1.0
    scene.world = world

    overlays = bpy.data.collections.new("Overlays")
    scene.collection.children.link(overlays)
    green = _material("HUD", (0.0, 1.0, 0.0), emission=1.0)
    for size in ((0.5, 0.06, 0.06), (0.06, 0.06, 0.5)):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 2.0, 0.0))
        ob = bpy.context.object
        ob.scale = size
        ob.data.materials.append(green)
        for c in list(ob.users_collection):
            c.objects.unlink(ob)
        overlays.objects.link(ob)

    bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0), rotation=(math.pi / 2, 0.0, 0.0))
    camera = bpy.context.object
    scene.camera = camera
    # pan: rotate about the world's vertical axis, linear in time; the sphere moves along x
    x0 = sphere.location.x
    for f in (scene.frame_start - 1, scene.frame_end + 1):
        t = (f - 1) / scene.render.fps
        camera.rotation_euler = (math.pi / 2, 0.0, pan_rad_s * t)
        camera.keyframe_insert("rotation_euler", frame=f)
        sphere.location.x = x0 + sphere_m_s * t
        sphere.keyframe_insert("location", index=0, frame=f)
    for ob in (camera, sphere):
        for fc in action_fcurves(ob):
            for k in fc.keyframe_points:
                k.interpolation = "LINEAR"

    s = scene.lowcam
    s.profile = profile
    s.enabled = True
    s.motion_source = "CAMERA"
    s.exclude_collection = overlays
    s.output = "//lowcam/####.png"
    scene.render.filepath = "//render/####.exr"
    setup_scene(scene, render_width)
    # the plate: the photograph filmed by this camera, frame by frame, as the render handler will see the motion
    filmed_profile, photo = scene_profile(scene), sample_photograph(profile)
    for f in range(scene.frame_start, scene.frame_end + 1):
        w = motion(scene, f, s.exposure_s).angular_velocity
        write_png(folder / "plate" / f"{f:04d}.png",
                  film(photo, filmed_profile, w, s.exposure_s, plate_seed(s.seed), f, render_width))
    scene.frame_set(scene.frame_start)
    s.plate_source = "SEQUENCE"
    s.plate_pattern = "//plate/####.png"
    path = folder / "sample_scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), relative_remap=True)
    return path
