"""Operators: set the scene up for Lowcam, apply the camera to the current frame, add the node group.

Contents
--------
- :class:`LOWCAM_OT_setup_scene`: transparent film, multilayer EXR output and the render camera
- :func:`render_and_degrade`: render a frame to a temporary multilayer EXR and write its degraded composite
- :class:`LOWCAM_OT_apply`: render the current frame and apply the camera; the result opens as "Lowcam Result"
- :class:`LOWCAM_OT_add_camera_node`: add a "Lowcam Camera" node to the scene's compositor, with its render camera
  and the scene's plate (a Movie Clip, or the Plate pattern's image sequence) connected
- :class:`LOWCAM_OT_viewport_look`: the camera look in the 3D viewport (the viewport compositor) on or off
- :data:`classes`: the operator classes, for registration
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import bpy

from lowcam.errors import LowcamError

from .. import blender_compat as compat
from ..nodes.build import set_code_view
from . import frames


class LOWCAM_OT_setup_scene(bpy.types.Operator):
    """Transparent film, multilayer EXR output and the render camera's field of view"""

    bl_idname = "lowcam.setup_scene"
    bl_label = "Set Up Scene"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            cam = frames.setup_scene(context.scene)
        except LowcamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        fisheye = "" if cam["projection"] == "pinhole" else " (Cycles' equidistant fisheye)"
        self.report({"INFO"}, f"render {cam['width']}x{cam['height']}, horizontal field {cam['hfov_deg']:.1f} deg"
                              f"{fisheye}")
        return {"FINISHED"}


def render_and_degrade(scene, frame: int) -> Path:
    """Render ``frame`` of ``scene`` to a temporary multilayer EXR and write its degraded composite."""
    from .render import render_frame

    frames.setup_scene(scene, scene.render.resolution_x)
    current = scene.frame_current
    try:
        with tempfile.TemporaryDirectory(prefix="lowcam-render-") as scratch:
            return render_frame(scene, frame, Path(scratch) / "frame.exr")
    finally:
        scene.frame_set(current)


class LOWCAM_OT_apply(bpy.types.Operator):
    """Render the current frame and apply the camera to it and the plate; the result opens as "Lowcam Result\""""

    bl_idname = "lowcam.apply"
    bl_label = "Apply Camera"

    def execute(self, context):
        scene = context.scene
        try:
            path = render_and_degrade(scene, scene.frame_current)
        except LowcamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        image = bpy.data.images.get("Lowcam Result")
        if image is not None:
            bpy.data.images.remove(image)
        image = bpy.data.images.load(str(path))
        image.name = "Lowcam Result"
        for area in getattr(context.screen, "areas", []):
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = image
        self.report({"INFO"}, f"wrote {path}")
        return {"FINISHED"}


class LOWCAM_OT_add_camera_node(bpy.types.Operator):
    """Add a "Lowcam Camera" node between the Render Layers and the output of the scene's compositor, and give the
    scene the render camera it needs"""

    bl_idname = "lowcam.add_camera_node"
    bl_label = "Add Camera Node"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        try:
            frames.setup_render_camera(scene)        # the render the node's maps are baked for
        except LowcamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        scene.render.use_compositing = True
        set_code_view(scene.render.image_settings)   # the output's own Standard view; the scene's is the user's
        tree = compat.compositor_tree(scene)
        layers = next((n for n in tree.nodes if n.bl_idname == "CompositorNodeRLayers"), None) or \
            tree.nodes.new("CompositorNodeRLayers")
        out = compat.compositor_output(tree)
        node = tree.nodes.new("LowcamCameraNode")
        node.use_scene_profile = True               # it follows the scene's Profile or Profile File
        tree.links.new(layers.outputs["Image"], node.inputs["Image"])
        s = scene.lowcam
        if s.plate_source == "CLIP" and s.plate_clip is not None:
            clip = tree.nodes.new("CompositorNodeMovieClip")
            clip.clip = s.plate_clip
            tree.links.new(clip.outputs["Image"], node.inputs["Plate"])
        elif s.plate_source == "SEQUENCE":
            try:
                image = frames.plate_sequence_image(scene)
            except LowcamError as e:
                self.report({"WARNING"}, f"{e}; the node's Plate input is left for you to connect")
            else:
                sequence = tree.nodes.new("CompositorNodeImage")   # frame N shows the pattern's file for frame N
                sequence.image = image
                sequence.frame_start, sequence.frame_offset = 1, 0
                sequence.frame_duration = frames.MAX_FRAME
                tree.links.new(sequence.outputs["Image"], node.inputs["Plate"])
        node.inputs["Seed"].default_value = s.seed
        tree.links.new(node.outputs["Image"], out)
        return {"FINISHED"}


class LOWCAM_OT_viewport_look(bpy.types.Operator):
    """Show the camera look in the 3D viewport (the viewport compositor runs the scene's compositor, shown under
    the Standard view), or give the 3D views their own Compositor setting and the scene its view transform back"""

    bl_idname = "lowcam.viewport_look"
    bl_label = "Viewport Look"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from ..nodes import viewport

        scene = context.scene
        spaces = viewport.view3d_spaces(bpy.data.screens)
        if viewport.is_on(scene):
            viewport.switch_off(scene, spaces)
            self.report({"INFO"}, "viewport look off: the 3D views have their own Compositor setting back, the "
                        "scene its own view transform")
            return {"FINISHED"}
        if not compat.at_least(5, 0):
            self.report({"ERROR"}, viewport.BEFORE_5_0)
            return {"CANCELLED"}
        tree = compat.compositor_tree(scene)
        if not any(n.bl_idname == "LowcamCameraNode" for n in tree.nodes):
            if bpy.ops.lowcam.add_camera_node() != {"FINISHED"}:
                return {"CANCELLED"}
        unsupported = viewport.unsupported_in_viewport(tree)
        if unsupported:
            self.report({"ERROR"}, "the viewport compositor cannot run these nodes of the scene's compositor: "
                        + ", ".join(unsupported) + "; render the frame instead (Apply Camera)")
            return {"CANCELLED"}
        if not spaces:
            self.report({"WARNING"}, "no 3D viewport to show the look in")
            return {"CANCELLED"}
        viewport.switch_on(scene, spaces)
        self.report({"INFO"}, f"viewport look on in {len(spaces)} 3D view(s); best seen through the camera "
                    "(Numpad 0)")
        return {"FINISHED"}


classes = (LOWCAM_OT_setup_scene, LOWCAM_OT_apply, LOWCAM_OT_add_camera_node, LOWCAM_OT_viewport_look)
