"""The camera look in the 3D viewport: Blender's viewport compositor running the scene's compositor with "Lowcam
Camera" in it.

The viewport compositor (the 3D viewport's shading popover > Compositor; ``View3DShading.use_compositor``:
"DISABLED", "CAMERA" (in camera view only) or "ALWAYS") runs the scene's compositor on the GPU on every redraw,
in Material Preview and Rendered shading only (Solid and Wireframe show no compositing). It runs the compositor's
GPU node implementations; its Render Layers node gives the viewport's image (other passes are empty unless the
engine is EEVEE). The group's maps fix its output size (the render it was baked for); the viewport image is sampled
through them.

What was checked (November 2026, no GPU: Mesa llvmpipe OpenGL 4.5):

- Blender 5.0 (bpy module): the group's node kinds (Map UV, Convolve, Image, Image Coordinates, Separate / Combine
  Color, Scene Time, Math, Separate XYZ, White Noise, groups) all run on the GPU compositor
  (``scene.render.compositor_device = "GPU"``, the implementations the viewport compositor uses) and give the CPU
  compositor's frame within 1 DN. The bpy module cannot draw a 3D viewport, so the 5.x viewport itself is unseen.
- Blender 4.3 (the Debian binary under Xvfb): the viewport compositor runs an Invert node and the group's first
  three stages (lens distortion, half-sampling, crosstalk), but with the spatial blur (4.x convolves with
  Translate taps, Convolve came in 5.0) Blender crashes (segmentation fault), and without it the frame is black.
  So before 5.0 the look refuses to switch on (:data:`BEFORE_5_0`).

Switching the look on keeps each 3D view's own shading and Compositor setting in the scene
(``scene["lowcam_viewport"]``, keyed by screen and area) and switching it off puts exactly those back; views the
look never touched stay as they are.

Contents
--------
- :data:`VIEWPORT_NODE_KINDS`: the node kinds (``bl_idname``) the group may contain in the viewport compositor
- :data:`BEFORE_5_0`: why the look refuses to switch on before Blender 5.0
- :data:`SAVED`: the scene's custom property holding the 3D views' own settings while the look is on
- :func:`node_kinds`: every node kind in a node tree, groups opened: {bl_idname: count}
- :func:`unsupported_in_viewport`: the kinds of a tree the viewport compositor is not known to run, sorted
- :func:`view3d_spaces`: the 3D views of some screens as (key, space) pairs
- :func:`is_on`: whether the look is on in a scene
- :func:`switch_on`: set the 3D views' Compositor to ``mode`` (and Solid shading to Material Preview), keeping
  each view's own settings
- :func:`switch_off`: give back each 3D view the settings it had before :func:`switch_on`
"""
from __future__ import annotations

#: Node kinds the group may contain in the viewport compositor: the group's built-in nodes in Blender 5.x and
#: their 4.x stand-ins (Math, Separate XYZ, Mix RGB, Value from the compositor, Translate taps for Convolve), its
#: containers, and the inputs the Add Camera Node operator connects (Render Layers, Movie Clip, Image).
VIEWPORT_NODE_KINDS = frozenset({
    "CompositorNodeMapUV", "CompositorNodeConvolve", "CompositorNodeImage", "CompositorNodeImageCoordinates",
    "CompositorNodeSeparateColor", "CompositorNodeCombineColor", "CompositorNodeSceneTime", "CompositorNodeTime",
    "ShaderNodeMath", "ShaderNodeSeparateXYZ", "ShaderNodeTexWhiteNoise", "ShaderNodeValue", "ShaderNodeMix",
    "CompositorNodeMath", "CompositorNodeSeparateXYZ", "CompositorNodeMixRGB", "CompositorNodeValue",
    "CompositorNodeTranslate", "CompositorNodeGroup", "NodeGroupInput", "NodeGroupOutput", "NodeReroute",
    "NodeFrame", "CompositorNodeRLayers", "CompositorNodeMovieClip", "CompositorNodeComposite",
    "CompositorNodeViewer", "LowcamCameraNode",
})
#: Why the look refuses to switch on before Blender 5.0 (one line for the operator's report).
BEFORE_5_0 = ("the viewport look needs Blender 5.0 or later: 4.x's viewport compositor crashes on the group's "
              "spatial blur (Translate taps); render the frame instead (Apply Camera)")
#: The scene's custom property holding the 3D views' own Compositor settings while the look is on.
SAVED = "lowcam_viewport"


def node_kinds(tree, kinds: dict | None = None) -> dict:
    """Every node kind in ``tree``, node groups (and Lowcam's custom group nodes) opened: {bl_idname: count}."""
    kinds = {} if kinds is None else kinds
    for node in tree.nodes:
        kinds[node.bl_idname] = kinds.get(node.bl_idname, 0) + 1
        inner = getattr(node, "node_tree", None)
        if inner is not None:
            node_kinds(inner, kinds)
    return kinds


def unsupported_in_viewport(tree) -> list[str]:
    """The node kinds in ``tree`` that the viewport compositor is not known to run (sorted; empty when all are)."""
    return sorted(k for k in node_kinds(tree) if k not in VIEWPORT_NODE_KINDS and not k.startswith("Lowcam"))


def view3d_spaces(screens) -> list[tuple[str, object]]:
    """The 3D views of ``screens`` as ("<screen>/<area index>", View3D space) pairs."""
    return [(f"{screen.name}/{i}", area.spaces.active) for screen in screens
            for i, area in enumerate(screen.areas) if area.type == "VIEW_3D"]


def is_on(scene) -> bool:
    return SAVED in scene


def switch_on(scene, spaces, mode: str = "ALWAYS") -> int:
    """Set the Compositor of the 3D views ``spaces`` ((key, space) pairs) to ``mode`` ("ALWAYS" or "CAMERA"), and
    their shading to Material Preview where it is Wireframe or Solid (the viewport compositor runs in Material
    Preview and Rendered only), keeping each view's own settings in ``scene[SAVED]`` (a view already kept keeps
    its first ones); returns how many views were set."""
    saved = {key: dict(value) for key, value in scene.get(SAVED, {}).items()}
    for key, space in spaces:
        shading = space.shading
        saved.setdefault(key, {"type": shading.type, "compositor": shading.use_compositor})
        if shading.type in ("WIREFRAME", "SOLID"):
            shading.type = "MATERIAL"
        shading.use_compositor = mode
    scene[SAVED] = saved
    return len(spaces)


def switch_off(scene, spaces) -> int:
    """Give each of the 3D views ``spaces`` the shading and Compositor setting it had before :func:`switch_on`;
    views the look did not set stay as they are. Forgets the kept settings; returns how many views were given
    theirs back."""
    saved = scene.get(SAVED, {})
    restored = 0
    for key, space in spaces:
        if key in saved:
            space.shading.type = saved[key]["type"]
            space.shading.use_compositor = saved[key]["compositor"]
            restored += 1
    if SAVED in scene:
        del scene[SAVED]
    return restored
