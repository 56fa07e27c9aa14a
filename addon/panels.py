"""Panels: Output Properties > Lowcam Camera, and the Compositor sidebar's Lowcam tab.

Contents
--------
- :func:`draw_settings`: the settings both panels show
- :class:`LOWCAM_PT_output`: Output Properties > Lowcam Camera
- :class:`LOWCAM_PT_compositor`: the compositor sidebar's Lowcam tab
- :data:`classes`: the panel classes, for registration
"""
from __future__ import annotations

import bpy


def draw_settings(layout, scene):
    s = scene.lowcam
    layout.use_property_split = True
    layout.prop(s, "enabled")
    layout.prop(s, "profile")
    col = layout.column(align=True)
    col.prop(s, "sharpness")
    col.prop(s, "saturation")
    col.prop(s, "exposure_s")
    col.prop(s, "seed")
    layout.prop(s, "plate_source")
    if s.plate_source == "CLIP":
        layout.prop(s, "plate_clip")
        layout.prop(s, "use_clip_lens")
    elif s.plate_source == "SEQUENCE":
        layout.prop(s, "plate_pattern")
    layout.prop(s, "motion_source")
    if s.motion_source == "FILE":
        layout.prop(s, "motion_file")
    layout.prop(s, "use_object_motion")
    layout.prop(s, "use_depth_of_field")
    if s.use_depth_of_field:
        col = layout.column(align=True)
        col.prop(s, "focus_distance_m")
        col.prop(s, "aperture_mm")
    layout.prop(s, "exclude_collection")
    layout.prop(s, "output")
    row = layout.row(align=True)
    row.operator("lowcam.setup_scene")
    row.operator("lowcam.apply")


class LOWCAM_PT_output(bpy.types.Panel):
    bl_label = "Lowcam Camera"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "output"

    def draw(self, context):
        draw_settings(self.layout, context.scene)


class LOWCAM_PT_compositor(bpy.types.Panel):
    bl_label = "Lowcam Camera"
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Lowcam"

    @classmethod
    def poll(cls, context):
        return getattr(context.space_data, "tree_type", "") == "CompositorNodeTree"

    def draw(self, context):
        draw_settings(self.layout, context.scene)
        self.layout.operator("lowcam.add_camera_node")


classes = (LOWCAM_PT_output, LOWCAM_PT_compositor)
