"""Node group against engine: each stage of "Lowcam Camera" rendered by Blender's compositor, compared.

Each stage is rendered with Blender's compositor and compared with the engine's state after the same effect,
noise off. Mean absolute differences are in DN (1/255).

For each stage, :func:`parity` gives ``{"mad": mean |node - engine| over the frame, "mad_object": the same where
the render reaches, "max": the largest difference, "max_outside": the largest where it does not}``.

Contents
--------
- :func:`render_group`: composite a node group fed by images at ``shape``: EXR paths give floats, PNG 8-bit codes
- :func:`plate_image`: the plate as Blender loads a video frame: an sRGB 8-bit image file
- :func:`parity`: per stage of the node group, noise off, the differences from the engine (DN)
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import bpy
import numpy as np

from lowcam.io import read_exr, read_image
from lowcam.node_images import planes_to_mosaic
from lowcam.node_maps import bake
from lowcam.pipeline import run
from lowcam.profile import load_profile

from ..blender_compat import compositor_output, compositor_tree
from .build import PLATE_BLEND, build_camera_group, group_stages, image_from_array, set_code_view


def _engine_stage(state, stage: str, frame: np.ndarray | None) -> np.ndarray:
    """The engine's state after ``stage`` in the node group's units: the part of the state the stage writes
    (its ``Effect.writes``) as the group's sockets hold it, DN from Bayer sampling on; after the plate blend, the
    8-bit frame."""
    if stage == PLATE_BLEND:
        return frame.astype(np.float32)
    part = state.profile.effect(stage).writes
    if part == "working":
        return state.working * 255.0
    if part == "bayer":
        return planes_to_mosaic(np.stack([state.bayer, state.bayer_alpha * 255.0], -1), state.geometry)
    if part == "rgb":
        return state.rgb
    if part == "output":
        return state.delta_yuv
    raise ValueError(f"node stage {stage!r} writes {part!r}, which the node group does not show")


def _compositor_scene(width: int, height: int):
    scene = bpy.data.scenes.get("Lowcam parity") or bpy.data.scenes.new("Lowcam parity")
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.render.dither_intensity = 0.0
    scene.render.film_transparent = True
    return scene


def render_group(group, inputs: dict, shape, path: Path) -> np.ndarray:
    """Composite ``group`` fed by the images in ``inputs`` (socket name -> bpy image or value) at ``shape``
    (rows, cols); EXR paths give the float output, PNG paths the 8-bit codes after the Standard view."""
    scene = _compositor_scene(shape[1], shape[0])
    tree = compositor_tree(scene)
    tree.nodes.clear()
    node = tree.nodes.new("CompositorNodeGroup")
    node.node_tree = group
    for name, value in inputs.items():
        if isinstance(value, bpy.types.Image):
            src = tree.nodes.new("CompositorNodeImage")
            src.image = value
            tree.links.new(src.outputs[0], node.inputs[name])
        else:
            node.inputs[name].default_value = value
    tree.links.new(node.outputs["Image"], compositor_output(tree))
    settings = scene.render.image_settings
    if path.suffix == ".exr":
        settings.file_format, settings.color_depth, settings.color_mode = "OPEN_EXR", "32", "RGBA"
    else:
        settings.file_format, settings.color_depth, settings.color_mode = "PNG", "8", "RGB"
    set_code_view(settings)             # the output's own view: Standard, whatever the scene's
    scene.render.filepath = str(path)
    with bpy.context.temp_override(scene=scene):
        bpy.ops.render.render(write_still=True, scene=scene.name)
    tree.nodes.clear()
    if path.suffix == ".exr":
        return next(iter(read_exr(path).values()))
    return read_image(path)


def plate_image(plate_u8: np.ndarray) -> bpy.types.Image:
    """The plate as Blender loads a video frame: an sRGB 8-bit image file."""
    from lowcam.outputs import write_png

    with tempfile.TemporaryDirectory(prefix="lowcam-plate-") as folder:
        image = bpy.data.images.load(str(write_png(Path(folder) / "plate.png", plate_u8)), check_existing=False)
        image.pack()                   # the file's bytes, kept in memory once the folder is gone
    image.colorspace_settings.name = "sRGB"
    return image


def parity(render: np.ndarray, plate_u8: np.ndarray, profile="fire-i", angular_velocity=(0.0, 0.0, 0.0),
           exposure_s=None, stages=None, out_dir=None) -> dict:
    """{stage: {"mad": mean |node - engine| over the frame (DN), "mad_object": the same where the render
    reaches, "max": the largest difference, "max_outside": the largest where it does not}} for each stage of the
    node group, noise off. The stages' renders are kept in ``out_dir``, or in a temporary folder removed after."""
    if out_dir is None:
        with tempfile.TemporaryDirectory(prefix="lowcam-parity-") as scratch:
            return parity(render, plate_u8, profile, angular_velocity, exposure_s, stages, scratch)
    out_dir = Path(out_dir)
    profile = load_profile(profile)
    quiet = profile.copy()             # the engine without noise; the group keeps its noise stage at strength 0
    for effect in quiet.effects:
        if effect.random:
            effect.enabled = False
    render_image = image_from_array("Lowcam parity render", render)
    render_image.alpha_mode = "PREMUL"
    plate = plate_image(plate_u8)
    camera = bake(profile, render.shape[:2], angular_velocity, exposure_s)
    all_stages = group_stages(camera)
    results = {}
    for stage in stages or all_stages:
        engine_stop = {PLATE_BLEND: None, "noise": all_stages[all_stages.index(stage) - 1]}.get(stage, stage)
        result = run(render, quiet, plate_u8, angular_velocity, exposure_s, stop_after=engine_stop)
        engine = _engine_stage(result.state, stage, result.frame)
        group = build_camera_group(camera, name="Lowcam parity camera", until=stage)
        suffix = ".png" if stage == PLATE_BLEND else ".exr"
        # the engine's lens warp takes the 2x2 box of half-sampling itself; the group's stays supersampled
        factor = 2 if stage == "lens_distortion" else 1
        shape = (engine.shape[0] * factor, engine.shape[1] * factor)
        node = render_group(group, {"Image": render_image, "Plate": plate, "Noise": 0.0}, shape,
                            out_dir / f"{stage}{suffix}").astype(np.float32)
        if factor == 2:
            node = node.reshape(engine.shape[0], 2, engine.shape[1], 2, -1).mean(axis=(1, 3))
        if stage != PLATE_BLEND and quiet.effect(stage).writes == "bayer":    # the mosaic: value in R, alpha in G
            node = np.stack([node[..., 0], node[..., 1]], -1) * 255.0
        elif stage != PLATE_BLEND:
            node = node[..., :engine.shape[-1]] * 255.0
        diff = np.abs(node - engine)
        reach = (np.abs(engine) > 1e-6).any(axis=-1) if stage != PLATE_BLEND else result.footprint
        results[stage] = {"mad": float(diff.mean()), "max": float(diff.max()),
                          "mad_object": float(diff[reach].mean()) if reach.any() else 0.0,
                          "max_outside": float(diff[~reach].max()) if (~reach).any() else 0.0}
    return results
