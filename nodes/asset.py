"""The node group as an asset library: a .blend holding "Lowcam Camera (<profile>)", marked as an asset.

The .blend holds the group with its stage groups and packed maps, for the Asset Browser or File > Append in any
Blender 5 file (no add-on needed). The maps are baked for one profile, render size and camera rotation
(:func:`lowcam.node_maps.bake`); the add-on's Lowcam Camera node rebakes them when those change, the asset cannot.

Contents
--------
- :func:`write_asset`: write the asset .blend to ``path`` (atomically) and return it
"""
from __future__ import annotations

import os
from pathlib import Path

import bpy

from lowcam.node_maps import bake
from lowcam.pipeline import render_camera
from lowcam.profile import load_profile

from ..blender_compat import mark_asset
from .build import build_camera_group


def write_asset(path, profile="fire-i", render_width: int = 1600, angular_velocity=(0.0, 0.0, 0.0),
                exposure_s: float | None = None) -> Path:
    """Write the asset .blend to ``path`` (atomically) and return it. The group's input Image is a render
    ``render_width`` wide at the projection and field of view :func:`lowcam.pipeline.render_camera` gives."""
    profile = load_profile(profile)
    cam = render_camera(profile, render_width)
    camera = bake(profile, (cam["height"], cam["width"]), angular_velocity, exposure_s)
    group = build_camera_group(camera, f"Lowcam Camera ({profile.name})")
    mark_asset(group, (
        f"{profile.camera.name}: Klein & Murray's low-cost camera model for a {cam['width']}x{cam['height']} "
        f"render with a {cam['hfov_deg']:.2f} deg horizontal field of view"
        f"{'' if cam['projection'] == 'pinhole' else ' through Cycles equidistant fisheye camera'}, camera rotation "
        f"{tuple(angular_velocity)} rad/s. Inputs: the render (premultiplied), the plate, seed, noise strength."),
        ("lowcam", "camera", profile.name))
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial.blend")
    bpy.data.libraries.write(str(partial), {group}, fake_user=True, compress=True)   # with what it uses
    os.replace(partial, path)
    return path
