"""Lowcam's nodes in the compositor's Add menu: ``CompositorNodeCustomGroup`` containers of built-in nodes.

"Lowcam Camera" holds the whole chain; one node per stage holds that stage alone. Each node's properties mirror
its profile parameters (and the profile it starts from); changing one rebakes the maps and rebuilds the node's
inner group from the engine. Python nodes that compute pixels would crash the compositor; these only contain.

Contents
--------
- :data:`RENDER_WIDTH`: the render width (px) the maps assume until the node sees a scene
- :class:`LowcamNodeBase`: what the camera node and the stage nodes share
- :class:`LowcamStageNode`: one stage of the chain as a node
- :class:`LowcamCameraNode`: the whole camera: render (premultiplied) and plate in, the camera's frame out
- :data:`STAGE_NODES`: the stages with a node of their own (those not baked into another's maps)
- :data:`classes`: the node classes, for registration
- :class:`NODE_MT_lowcam_add`: the Add > Lowcam menu
- :func:`draw_add_menu`: adds the Lowcam menu to the compositor's Add menu
- :func:`register`: register the nodes and the menu
- :func:`unregister`: unregister them
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, StringProperty

from lowcam.effects import effect_class
from lowcam.node_maps import bake, node_stages

from .build import build_camera_group, build_stage_group, stage_label

RENDER_WIDTH = 1600  # px the maps assume until the node sees a scene


def _render_shape(context, profile):
    """(rows, cols) of the render the maps are baked for: the scene's width at the render camera's aspect ratio
    (what Set Up Scene gives the scene, :func:`lowcam.pipeline.render_camera`)."""
    from lowcam.pipeline import render_camera

    scene = getattr(context, "scene", None)
    width = RENDER_WIDTH if scene is None else scene.render.resolution_x * scene.render.resolution_percentage // 100
    cam = render_camera(profile, width)
    return cam["height"], cam["width"]


def _profile_items(self, context):
    from lowcam.profile import list_profiles

    return [(name, name, str(path)) for name, path in list_profiles()] or [("fire-i", "fire-i", "")]


def _param_property(key, param):
    """A Blender property mirroring one effect parameter (same default, range and description)."""
    doc = (param.doc or key) + (f" ({param.unit})" if param.unit else "")
    update = _rebuild
    if param.kind == "matrix":
        flat = [float(x) for row in param.default for x in row]
        return FloatVectorProperty(name=key, size=len(flat), default=flat, description=doc, update=update)
    if param.kind == "vector":
        return FloatVectorProperty(name=key, size=len(param.default), default=[float(x) for x in param.default],
                                   description=doc, update=update)
    if param.kind in (str, "path"):
        if param.choices:
            return EnumProperty(name=key, items=[(c, c, "") for c in param.choices], default=param.default,
                                description=doc, update=update)
        return StringProperty(name=key, default=str(param.default or ""), description=doc, update=update)
    if param.kind is bool:
        return BoolProperty(name=key, default=bool(param.default), description=doc, update=update)
    limits = {k: v for k, v in (("min", param.low), ("max", param.high)) if v is not None}
    if param.kind is int:
        return IntProperty(name=key, default=int(param.default), description=doc, update=update,
                           **{k: int(v) for k, v in limits.items()})
    return FloatProperty(name=key, default=float(param.default), description=doc, update=update, **limits)


def _param_values(node, effect_name):
    values = {}
    for key, param in effect_class(effect_name).params.items():
        value = getattr(node, key)
        if param.kind == "matrix":
            n = int(len(value) ** 0.5)
            value = [list(value[i * n:(i + 1) * n]) for i in range(n)]
        elif param.kind == "vector":
            value = list(value)
        elif param.kind == "path" and not value:
            continue
        values[key] = value
    return values


def _rebuild(node, context):
    node.rebuild(context)


class LowcamNodeBase:
    bl_width_default = 200

    @classmethod
    def poll(cls, tree):
        return tree.bl_idname == "CompositorNodeTree"

    def group_name(self):
        return f"{self.bl_label} ({self.name})"

    def init(self, context):
        self.node_tree = bpy.data.node_groups.new(self.group_name(), "CompositorNodeTree")
        self.load_profile_values()
        self.rebuild(context)

    def copy(self, node):
        self.node_tree = None
        self.rebuild(bpy.context)

    def free(self):
        if self.node_tree is not None and self.node_tree.users <= 1:
            bpy.data.node_groups.remove(self.node_tree)

    def draw_buttons(self, context, layout):
        layout.prop(self, "profile")
        for key in self.mirrored:
            layout.prop(self, key)

    def rebuild(self, context):
        """Rebake the maps and rebuild the inner group; a profile the group cannot simulate is reported."""
        if self.get("_loading"):
            return
        from lowcam.errors import LowcamError

        try:
            self.node_tree = self.build(context)
        except LowcamError as e:
            print(f"lowcam: {self.name}: {e}")


class LowcamStageNode(LowcamNodeBase):
    effect = ""
    mirrored: tuple = ()

    def profile_with_values(self):
        from lowcam.profile import load_profile

        return load_profile(self.profile).with_effect(self.effect, **_param_values(self, self.effect))

    def load_profile_values(self):
        from lowcam.profile import load_profile

        effect = load_profile(self.profile).effect(self.effect)
        if effect is None:
            return
        self["_loading"] = True
        for key, param in effect_class(self.effect).params.items():
            value = getattr(effect, key)
            if param.kind == "matrix":
                value = [float(x) for row in value for x in row]
            try:
                setattr(self, key, value)
            except (TypeError, ValueError):
                pass
        self["_loading"] = False

    def build(self, context):
        profile = self.profile_with_values()
        return build_stage_group(self.stage, bake(profile, _render_shape(context, profile)), self.group_name())


class LowcamCameraNode(LowcamNodeBase, bpy.types.CompositorNodeCustomGroup):
    """The whole camera: render (premultiplied) and plate in, the camera's frame out."""

    bl_idname = "LowcamCameraNode"
    bl_label = "Lowcam Camera"
    effect = ""
    mirrored = ("sharpness", "saturation", "exposure_s", "angular_velocity")
    profile: EnumProperty(name="Profile", items=_profile_items, update=lambda self, c: self.on_profile(c))
    profile_file: StringProperty(name="Profile File", subtype="FILE_PATH", update=lambda self, c: self.on_profile(c),
                                 description="A profile .toml anywhere; when given, it replaces the menu's name")
    use_scene_profile: BoolProperty(name="Scene's Profile", default=False, update=lambda self, c: self.on_profile(c),
                                    description="Simulate the profile the scene's Lowcam settings choose (its "
                                                "Profile or Profile File), and rebuild when it changes")
    sharpness: FloatProperty(name="Sharpness", default=80.0, min=0.0, max=255.0, update=_rebuild)
    saturation: FloatProperty(name="Saturation", default=90.0, min=0.0, max=255.0, update=_rebuild)
    exposure_s: FloatProperty(name="Exposure (s)", default=0.033, min=0.0, max=10.0, update=_rebuild)
    angular_velocity: FloatVectorProperty(name="Angular Velocity (rad/s)", size=3, update=_rebuild,
                                          description="Camera rotation rate (x right, y down, z forward)")

    def draw_buttons(self, context, layout):
        layout.prop(self, "use_scene_profile")
        if not self.use_scene_profile:
            layout.prop(self, "profile")
            layout.prop(self, "profile_file", text="File")
        for key in self.mirrored:
            layout.prop(self, key)

    def profile_source(self, context=None) -> str:
        """The profile the node simulates: the scene's (Scene's Profile: its settings' ``profile_ref()``), its Profile
        File, or its menu's name."""
        scene = getattr(context or bpy.context, "scene", None)
        if self.use_scene_profile and scene is not None:
            return scene.lowcam.profile_ref()
        return bpy.path.abspath(self.profile_file) if self.profile_file else self.profile

    def on_profile(self, context):
        self.load_profile_values()
        self.rebuild(context)

    def load_profile_values(self):
        from lowcam.errors import LowcamError
        from lowcam.profile import load_profile

        try:
            controls = load_profile(self.profile_source()).controls()
        except LowcamError as e:
            print(f"lowcam: {self.name}: {e}")
            return
        self["_loading"] = True
        for key, value in controls.items():
            setattr(self, key, value)
        self["_loading"] = False

    def build(self, context):
        from lowcam.profile import load_profile

        profile = load_profile(self.profile_source(context)).with_controls(self.sharpness, self.saturation)
        camera = bake(profile, _render_shape(context, profile), tuple(self.angular_velocity), self.exposure_s)
        return build_camera_group(camera, name=self.group_name())


def _stage_class(stage: str):
    effect_cls = effect_class(stage)
    annotations = {"profile": EnumProperty(name="Profile", items=_profile_items,
                                           update=lambda self, c: (self.load_profile_values(), self.rebuild(c)))}
    params = effect_cls.params if effect_cls is not None else {}
    for key, param in params.items():
        annotations[key] = _param_property(key, param)
    label = stage_label(stage)
    return type(f"Lowcam{label.replace(' ', '')}Node", (LowcamStageNode, bpy.types.CompositorNodeCustomGroup), {
        "__annotations__": annotations, "bl_idname": f"Lowcam{label.replace(' ', '')}Node",
        "bl_label": f"Lowcam {label}", "stage": stage, "effect": stage if effect_cls is not None else "",
        "mirrored": tuple(params), "__doc__": (effect_cls.__doc__ or label).splitlines()[0] if effect_cls else label,
    })


#: Stages with a node of their own: every effect that declares one and is not baked into another's maps (the
#: plate blend is part of the camera node only).
STAGE_NODES = tuple(name for name, node in node_stages().items() if not node.baked_into)
classes = [LowcamCameraNode] + [_stage_class(s) for s in STAGE_NODES]


class NODE_MT_lowcam_add(bpy.types.Menu):
    bl_idname = "NODE_MT_lowcam_add"
    bl_label = "Lowcam"

    def draw(self, context):
        for cls in classes:
            op = self.layout.operator("node.add_node", text=cls.bl_label)
            op.type = cls.bl_idname
            op.use_transform = True


def draw_add_menu(self, context):
    if getattr(context.space_data, "tree_type", "") == "CompositorNodeTree":
        self.layout.menu(NODE_MT_lowcam_add.bl_idname)


def register():
    for cls in classes + [NODE_MT_lowcam_add]:
        bpy.utils.register_class(cls)
    bpy.types.NODE_MT_add.append(draw_add_menu)


def unregister():
    bpy.types.NODE_MT_add.remove(draw_add_menu)
    for cls in reversed(classes + [NODE_MT_lowcam_add]):
        bpy.utils.unregister_class(cls)
