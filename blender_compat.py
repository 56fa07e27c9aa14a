"""What differs between the Blender versions Lowcam supports (4.2 LTS to 5.2), in one place.

It sits at the extension's root, below both ``addon/`` and ``nodes/``: both import it, and ``nodes/`` never imports
``addon/`` (which registers the nodes). Every other module of ``addon/`` and ``nodes/`` asks this one instead of
testing ``bpy.app.version`` itself. Each function's docstring says which versions differ and how. Measured on the
bpy module 4.2.23, 4.5.15 and 5.0.1 and on Blender 4.3 / bpy 5.2 (``scripts/test-blenders.sh``).

Contents
--------
- :data:`VERSION`, :data:`MINIMUM`: the running Blender's (major, minor), and the oldest supported
- :class:`CompatError`: a feature this Blender lacks (one line naming the version and what to do)
- :func:`at_least`: whether the running Blender is at least (major, minor)
- :data:`NODE_TYPES`: node roles -> (idname from 5.0 on, idname before 5.0 or None when missing)
- :func:`node_type`, :func:`has_node`: the idname of a node role here / whether this Blender has it
- :func:`compositor_tree`: the scene's compositor node tree (5.0: ``compositing_node_group``; 4.x: ``node_tree``)
- :func:`compositor_output`: the input socket that takes the final image (Group Output / Composite)
- :func:`eevee_engine`: the EEVEE render engine's enum
- :func:`set_multilayer_exr`: set image settings to multilayer OpenEXR
- :func:`working_space`: the .blend's working colour space (5.0+: one of three; 4.x: always Linear Rec.709)
- :func:`action_fcurves`: an object's animation F-curves (slotted actions from 4.4, plain ``action.fcurves`` before)
- :func:`path_options`: the options a blend-relative path property may declare
- :func:`mark_asset`: mark an ID as an asset with a description and tags
- :func:`shader_nodes`: the node tree of a new material or world
"""
from __future__ import annotations

import bpy

#: The running Blender's (major, minor).
VERSION = tuple(bpy.app.version[:2])
#: The oldest Blender the extension supports (blender_manifest.toml's ``blender_version_min``).
MINIMUM = (4, 2)


class CompatError(RuntimeError):
    """A feature this Blender lacks: the message names the version and what to do."""


def at_least(major: int, minor: int) -> bool:
    return VERSION >= (major, minor)


#: Node roles -> (the idname from Blender 5.0 on, the idname in 4.x or None where 4.x lacks it). Blender 5.0 dropped
#: the compositor's own utility nodes (Math, Separate XYZ, Mix, Value) for the shader ones; the shader ones exist in
#: 4.5's compositor too, not in 4.2's. Image Coordinates and White Noise came to the compositor in 4.5, Convolve in
#: 5.0 (4.x: nodes/build.py convolves with Translate taps).
NODE_TYPES = {
    "math": ("ShaderNodeMath", "CompositorNodeMath"),
    "separate_xyz": ("ShaderNodeSeparateXYZ", "CompositorNodeSeparateXYZ"),
    "mix": ("ShaderNodeMix", "CompositorNodeMixRGB"),
    "value": ("ShaderNodeValue", "CompositorNodeValue"),
    "image_coordinates": ("CompositorNodeImageCoordinates", "CompositorNodeImageCoordinates" if at_least(4, 5)
                          else None),
    "white_noise": ("ShaderNodeTexWhiteNoise", "ShaderNodeTexWhiteNoise" if at_least(4, 5) else None),
    "convolve": ("CompositorNodeConvolve", None),
}


def node_type(role: str) -> str:
    """The idname of compositor node ``role`` (a :data:`NODE_TYPES` key) in this Blender; :class:`CompatError`
    where it has none (e.g. Convolve before 5.0, Image Coordinates before 4.5)."""
    new, old = NODE_TYPES[role]
    kind = new if at_least(5, 0) else old
    if kind is None:
        raise CompatError(f"Blender {VERSION[0]}.{VERSION[1]}'s compositor has no {role.replace('_', ' ')} node; "
                          f"use Blender 5.0 or later")
    return kind


def has_node(role: str) -> bool:
    """Whether this Blender's compositor has node ``role``."""
    return (NODE_TYPES[role][0] if at_least(5, 0) else NODE_TYPES[role][1]) is not None


def compositor_tree(scene, create: bool = True):
    """The scene's compositor node tree, made if missing when ``create`` (else None).

    5.0+: a ``CompositorNodeTree`` node group assigned to ``scene.compositing_node_group``, with an "Image" output
    socket its Group Output node takes. 4.2-4.5: the scene's own tree ``scene.node_tree``, there once
    ``scene.use_nodes`` is True (which adds Render Layers and a Composite node)."""
    if at_least(5, 0):
        tree = scene.compositing_node_group
        if tree is None and create:
            tree = bpy.data.node_groups.new(f"{scene.name} Compositor", "CompositorNodeTree")
            tree.interface.new_socket(name="Image", in_out="OUTPUT", socket_type="NodeSocketColor")
            scene.compositing_node_group = tree
        return tree
    if not scene.use_nodes and not create:
        return None
    scene.use_nodes = True
    return scene.node_tree


def compositor_output(tree):
    """The input socket that takes the composite: 5.0+ the Group Output's first input; 4.x the Composite node's
    Image (each made if missing)."""
    kind = "NodeGroupOutput" if at_least(5, 0) else "CompositorNodeComposite"
    node = next((n for n in tree.nodes if n.bl_idname == kind), None) or tree.nodes.new(kind)
    return node.inputs[0]


def eevee_engine() -> str:
    """EEVEE's ``scene.render.engine`` enum: ``BLENDER_EEVEE_NEXT`` in 4.2-4.5, ``BLENDER_EEVEE`` from 5.0."""
    return "BLENDER_EEVEE" if at_least(5, 0) else "BLENDER_EEVEE_NEXT"


def set_multilayer_exr(image_settings) -> None:
    """Multilayer OpenEXR output. 5.0+: ``media_type = "MULTI_LAYER_IMAGE"`` first (file formats are grouped by
    media type), then ``file_format``; 4.x: ``file_format = "OPEN_EXR_MULTILAYER"`` alone."""
    if at_least(5, 0):
        image_settings.media_type = "MULTI_LAYER_IMAGE"
    image_settings.file_format = "OPEN_EXR_MULTILAYER"


def working_space() -> str:
    """The open .blend's working colour space, the space renders and the compositor hold: 5.0+
    ``bpy.data.colorspace.working_space`` ("Linear Rec.709", "Linear Rec.2020" or "ACEScg"; set with
    ``bpy.ops.wm.set_working_color_space``); 4.2-4.5 have no such choice: "Linear Rec.709"."""
    colorspace = getattr(bpy.data, "colorspace", None)
    return getattr(colorspace, "working_space", "") or "Linear Rec.709"


def action_fcurves(animated) -> list:
    """The F-curves animating ``animated`` (an ID with animation data). 4.4+: slotted actions (the F-curves live
    in the channelbag of the object's slot in the first layer's strip; ``action.fcurves`` is gone in 5.0);
    4.2-4.3: ``action.fcurves``."""
    data = animated.animation_data
    if data is None or data.action is None:
        return []
    if not at_least(4, 4):
        return list(data.action.fcurves)
    bag = data.action.layers[0].strips[0].channelbag(data.action_slot) if data.action.layers else None
    return list(bag.fcurves) if bag is not None else []


def path_options() -> set:
    """Options for a blend-relative file path property: ``PATH_SUPPORTS_BLEND_RELATIVE`` exists from 4.5 (the file
    browser then keeps ``//``); 4.2-4.4 have no such option (paths stay as typed)."""
    return {"PATH_SUPPORTS_BLEND_RELATIVE"} if at_least(4, 5) else set()


def mark_asset(id_data, description: str, tags=()) -> None:
    """Mark ``id_data`` as an asset with ``description`` and ``tags``. The same ``asset_mark`` / ``asset_data`` API
    from 4.2 to 5.2; kept here so that an API change has one place to go."""
    id_data.asset_mark()
    id_data.asset_data.description = description
    for tag in tags:
        id_data.asset_data.tags.new(tag)


def shader_nodes(block):
    """The shader node tree of a new material or world: from 5.0 each is made with its nodes (and ``use_nodes`` is
    deprecated, to be removed in 6.0); 4.x makes them when ``use_nodes`` is set."""
    if block.node_tree is None:
        block.use_nodes = True
    return block.node_tree
