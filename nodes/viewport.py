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
  compositor's frame within 1 DN. The bpy module has no window, but once its GPU module is up (one EEVEE render
  starts it: :func:`start_gpu`) it draws a 3D view offscreen, viewport compositor included
  (:func:`draw_through_camera`): the look of ``scripts/viewport_picture.py`` and ``tests/test_viewport_look.py``.
- Blender 4.3 (the Debian binary under Xvfb): the viewport compositor runs an Invert node and the group's first
  three stages (lens distortion, half-sampling, crosstalk), but with the spatial blur (4.x convolves with
  Translate taps, Convolve came in 5.0) Blender crashes (segmentation fault), and without it the frame is black.
  So before 5.0 the look refuses to switch on (:data:`BEFORE_5_0`).

Switching the look on keeps each 3D view's own shading and Compositor setting in the scene
(``scene["lowcam_viewport"]``, keyed by screen and area) and switching it off puts exactly those back; views the
look never touched stay as they are. The group's output is the camera's 8-bit frame, which shows as it is only
under the Standard view on an sRGB display (under AgX, Blender 5's default, the sample plate's pixels shift by 8
levels on average): while the look is on the scene shows through those settings, and its own come back with the
views'.

Contents
--------
- :data:`VIEWPORT_NODE_KINDS`: the node kinds (``bl_idname``) the group may contain in the viewport compositor
- :data:`BEFORE_5_0`: why the look refuses to switch on before Blender 5.0
- :data:`SAVED`: the scene's custom property holding the 3D views' own settings while the look is on
- :data:`SCENE_DISPLAY`: the key under which it keeps the scene's own display and view settings
- :func:`node_kinds`: every node kind in a node tree, groups opened: {bl_idname: count}
- :func:`unsupported_in_viewport`: the kinds of a tree the viewport compositor is not known to run, sorted
- :func:`view3d_spaces`: the 3D views of some screens as (key, space) pairs
- :func:`is_on`: whether the look is on in a scene
- :func:`switch_on`: set the 3D views' Compositor to ``mode`` (and Solid shading to Material Preview) and the
  scene's display to the Standard view, keeping each view's own settings and the scene's
- :func:`switch_off`: give back each 3D view the settings it had before :func:`switch_on`, and the scene its own
- :func:`start_gpu`: start Blender's GPU module in a background process (one tiny EEVEE render)
- :func:`draw_through_camera`: a 3D view drawn offscreen through the scene camera, its compositor included
"""
from __future__ import annotations

import bpy
import numpy as np

from .. import blender_compat as compat
from .build import CODE_DISPLAY, set_code_display

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
#: The key in ``scene[SAVED]`` under which the scene's own display and view settings are kept.
SCENE_DISPLAY = "scene display"


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


def _display(scene) -> dict:
    return {"display": scene.display_settings, "view": scene.view_settings}


def switch_on(scene, spaces, mode: str = "ALWAYS") -> int:
    """Set the Compositor of the 3D views ``spaces`` ((key, space) pairs) to ``mode`` ("ALWAYS" or "CAMERA"), and
    their shading to Material Preview where it is Wireframe or Solid (the viewport compositor runs in Material
    Preview and Rendered only), and the scene's display to the codes' (:func:`~nodes.build.set_code_display`),
    keeping each view's own settings and the scene's in ``scene[SAVED]`` (settings already kept keep their first
    values); returns how many views were set."""
    saved = {key: dict(value) for key, value in scene.get(SAVED, {}).items()}
    settings = _display(scene)
    saved.setdefault(SCENE_DISPLAY, {name: getattr(settings[part], name) for part, name, _ in CODE_DISPLAY
                                     if hasattr(settings[part], name)})
    set_code_display(scene.display_settings, scene.view_settings)
    for key, space in spaces:
        shading = space.shading
        saved.setdefault(key, {"type": shading.type, "compositor": shading.use_compositor})
        if shading.type in ("WIREFRAME", "SOLID"):
            shading.type = "MATERIAL"
        shading.use_compositor = mode
    scene[SAVED] = saved
    return len(spaces)


def switch_off(scene, spaces) -> int:
    """Give the scene its own display settings back, and each of the 3D views ``spaces`` the shading and
    Compositor setting it had before :func:`switch_on`; views the look did not set stay as they are. Forgets the
    kept settings; returns how many views were given theirs back."""
    saved = scene.get(SAVED, {})
    own, settings = saved.get(SCENE_DISPLAY, {}), _display(scene)
    for part, name, _ in CODE_DISPLAY:    # the view transform before its look
        try:
            setattr(settings[part], name, own[name])
        except (KeyError, TypeError, AttributeError):  # not kept, or unknown to this colour configuration
            pass
    restored = 0
    for key, space in spaces:
        if key in saved:
            space.shading.type = saved[key]["type"]
            space.shading.use_compositor = saved[key]["compositor"]
            restored += 1
    if SAVED in scene:
        del scene[SAVED]
    return restored


def start_gpu() -> None:
    """Start Blender's GPU module in a background process (``blender -b``, the bpy module), where drawing is
    refused until a render has started it: one 8x8 EEVEE render of a scene made for it and removed. Does nothing
    where the module is up (a window, or a render before)."""
    import gpu

    try:
        gpu.platform.backend_type_get()
        return
    except SystemError:  # "GPU functions for drawing are not available in background mode"
        pass
    scene = bpy.data.scenes.new("Lowcam GPU start")
    camera = bpy.data.objects.new("Lowcam GPU start", bpy.data.cameras.new("Lowcam GPU start"))
    try:
        scene.collection.objects.link(camera)
        scene.camera = camera
        scene.render.engine = compat.eevee_engine()
        scene.render.resolution_x = scene.render.resolution_y = 8
        bpy.ops.render.render(scene=scene.name)
    finally:
        data = camera.data
        bpy.data.objects.remove(camera)
        bpy.data.cameras.remove(data)
        bpy.data.scenes.remove(scene)


def draw_through_camera(scene, area, width: int, height: int) -> np.ndarray:
    """The 3D view of ``area`` drawn offscreen through ``scene``'s camera, ``width`` x ``height`` pixels, with the
    view's own shading and Compositor setting (the viewport compositor runs as on screen) and the scene's display
    colour management: (height, width, 4) float32, the top row first. Needs the GPU module (:func:`start_gpu`)."""
    import gpu

    region = next(r for r in area.regions if r.type == "WINDOW")
    camera = scene.camera
    if camera is None:
        raise ValueError(f"scene '{scene.name}' has no camera to draw through")
    layer = bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0]
    projection = camera.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=width, y=height)
    offscreen = gpu.types.GPUOffScreen(width, height)
    try:
        with offscreen.bind():
            offscreen.draw_view3d(scene, layer, area.spaces.active, region,
                                  camera.matrix_world.inverted(), projection, do_color_management=True)
            pixels = gpu.state.active_framebuffer_get().read_color(0, 0, width, height, 4, 0, "FLOAT")
    finally:
        offscreen.free()
    pixels.dimensions = width * height * 4
    return np.array(pixels, np.float32).reshape(height, width, 4)[::-1].copy()
