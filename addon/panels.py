"""Panels: Output Properties > Lowcam Camera and > Lowcam Match, and the same two in the Compositor sidebar's
Lowcam tab.

Contents
--------
- :func:`draw_settings`: the settings both Lowcam Camera panels show
- :class:`LOWCAM_PT_output`: Output Properties > Lowcam Camera
- :class:`LOWCAM_PT_compositor`: the compositor sidebar's Lowcam tab
- :class:`LOWCAM_UL_candidates`: the diagnosis's ranked candidates, an Add button on each row
- :class:`LOWCAM_UL_versions`: the profile versions and their errors
- :func:`draw_match`: the Match panel: plate, measurement set, jobs, results, candidates, versions, history
- :class:`LOWCAM_PT_match_output`: Output Properties > Lowcam Match
- :class:`LOWCAM_PT_match_compositor`: the compositor sidebar's Lowcam Match panel
- :data:`classes`: the panel and list classes, for registration
"""
from __future__ import annotations

import bpy


def draw_settings(layout, scene):
    s = scene.lowcam
    layout.use_property_split = True
    layout.prop(s, "enabled")
    layout.prop(s, "profile")
    row = layout.row(align=True)
    row.prop(s, "profile_file", text="Profile File")
    row.operator("lowcam.save_profile_as", text="", icon="FILE_TICK")
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
    layout.prop(s, "render_depth")
    layout.prop(s, "render_codec")
    layout.prop(s, "output")
    layout.prop(s, "video_output")
    row = layout.row(align=True)
    row.operator("lowcam.setup_scene")
    row.operator("lowcam.apply")
    on = "lowcam_viewport" in scene                 # nodes.viewport.SAVED: the look is on
    layout.operator("lowcam.viewport_look", text="Viewport Look", icon="NODE_COMPOSITING", depress=on)


class _OutputProperties:
    """Where a panel sits: Output Properties."""
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "output"


class _CompositorSidebar:
    """Where a panel sits: the compositor's sidebar, Lowcam tab."""
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Lowcam"

    @classmethod
    def poll(cls, context):
        return getattr(context.space_data, "tree_type", "") == "CompositorNodeTree"


class LOWCAM_PT_output(_OutputProperties, bpy.types.Panel):
    bl_label = "Lowcam Camera"

    def draw(self, context):
        draw_settings(self.layout, context.scene)


class LOWCAM_PT_compositor(_CompositorSidebar, bpy.types.Panel):
    bl_label = "Lowcam Camera"

    def draw(self, context):
        draw_settings(self.layout, context.scene)
        self.layout.operator("lowcam.add_camera_node")


def _image(layout, name: str) -> None:
    """The picture ``name`` (its full-size preview, made when it was loaded) in a square box as wide as the panel
    (the pictures are drawn near square), at least 12 UI units."""
    image = bpy.data.images.get(name)
    icon = getattr(getattr(image, "preview", None), "icon_id", 0)
    if not icon:
        return
    region = getattr(bpy.context, "region", None)
    unit = 20 * getattr(bpy.context.preferences.system, "ui_scale", 1.0)
    width_units = (region.width - 2 * unit) / unit if region is not None and region.width > 0 else 12.0
    layout.template_icon(icon_value=icon, scale=max(12.0, width_units))


class LOWCAM_UL_candidates(bpy.types.UIList):
    """Effect, error after adding it, held-out error, and an Add button."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.label(text=item.effect)
        row.label(text=f"{item.error_after:.3f}")
        row.label(text="-" if item.held_out < 0 else f"{item.held_out:.3f}")
        row.operator("lowcam.match_add", text="Add").index = index


class LOWCAM_UL_versions(bpy.types.UIList):
    """Each profile version: what it added and its error."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.label(text=f"v{index + 1}  {item.label}")
        row.label(text="-" if item.error < 0 else f"{item.error:.3f}")


def draw_match(layout, scene) -> None:
    import textwrap

    from . import jobs
    from .properties import profile_ref

    s, m = scene.lowcam, scene.lowcam_match
    plate = {"CLIP": getattr(s.plate_clip, "name", "no clip chosen"), "SEQUENCE": s.plate_pattern}.get(
        s.plate_source, "none (Lowcam Camera > Plate)")
    col = layout.column(align=True)
    col.label(text=f"Plate: {plate}", icon="IMAGE_DATA")
    col.label(text=f"Profile: {profile_ref(s)}", icon="PRESET")
    layout.prop(m, "measurement_set")
    row = layout.row(align=True)
    row.prop(m, "only")
    row.prop(m, "max_steps", text="Steps")
    row = layout.row(align=True)
    row.operator("lowcam.match_estimate", icon="IMPORT")
    row.operator("lowcam.match_compare", icon="ZOOM_ALL")
    row.operator("lowcam.match_diagnose", icon="VIEWZOOM")
    job = jobs.current()
    if job is not None:
        row = layout.row(align=True)
        row.label(text=job.progress, icon="SORTTIME")
        row.operator("lowcam.match_cancel", icon="CANCEL")
    if m.job_error:
        col = layout.box().column(align=True)
        for k, line in enumerate(textwrap.wrap(m.job_error, 70)):
            col.label(text=line, icon="ERROR" if k == 0 else "BLANK1")
    if m.error >= 0:
        box = layout.box()
        col = box.column(align=True)
        col.label(text=f"Error {m.error:.3f} (noise 1.0, explained below 1.1): {m.verdict}")
        if m.families:
            col.label(text=m.families)
        for line in m.where.split("; ") if m.where else ():
            col.label(text=f"where: {line}")
        if m.report:
            row = box.row(align=True)
            row.label(text=m.report)
            row.operator("lowcam.match_open_report", text="", icon="URL")
        _image(box, "Lowcam Residual Map")
    if m.summary:
        col = layout.column(align=True)
        for line in textwrap.wrap(m.summary, 70):
            col.label(text=line)
    if len(m.candidates):
        layout.label(text="Candidates: effect, error after, held out")
        layout.template_list("LOWCAM_UL_candidates", "", m, "candidates", m, "candidate_index", rows=3)
        if 0 <= m.candidate_index < len(m.candidates):
            c = m.candidates[m.candidate_index]
            col = layout.column(align=True)
            for line in textwrap.wrap(c.evidence + (f" [{c.flags}]" if c.flags else ""), 70):
                col.label(text=line)
        row = layout.row(align=True)
        row.operator("lowcam.match_add", text="Add Best").index = -1
        row.operator("lowcam.match_until_explained")
    if len(m.versions):
        layout.label(text="Versions: error against the measurements")
        layout.template_list("LOWCAM_UL_versions", "", m, "versions", m, "version_index", rows=3)
        layout.operator("lowcam.match_undo").index = -1
        _image(layout, "Lowcam Error History")


class LOWCAM_PT_match_output(_OutputProperties, bpy.types.Panel):
    bl_label = "Lowcam Match"

    def draw(self, context):
        draw_match(self.layout, context.scene)


class LOWCAM_PT_match_compositor(_CompositorSidebar, bpy.types.Panel):
    bl_label = "Lowcam Match"

    def draw(self, context):
        draw_match(self.layout, context.scene)


classes = (LOWCAM_PT_output, LOWCAM_PT_compositor, LOWCAM_UL_candidates, LOWCAM_UL_versions, LOWCAM_PT_match_output,
           LOWCAM_PT_match_compositor)
