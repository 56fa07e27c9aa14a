"""The camera look in the 3D viewport (``nodes/viewport.py``, the Viewport Look operator) with real bpy: the
viewport compositor switched on for "Lowcam Camera", the group built only from node kinds the viewport compositor
runs, the user's own 3D view settings given back (and views the look never set left alone), and the GPU
compositor (the viewport compositor's node implementations) giving the CPU compositor's frame."""
import bpy
import numpy as np
import pytest

from lowcam_blender import submodule

pytestmark = pytest.mark.blender  # real bpy: the Blender tier


def _views():
    viewport = submodule("nodes.viewport")
    return viewport.view3d_spaces(bpy.data.screens)


def _settings(views):
    return {key: (space.shading.type, space.shading.use_compositor) for key, space in views}


@pytest.fixture
def home():
    """Blender's default file, its 3D views given distinct settings of the user's own."""
    submodule("addon.render")                    # registers the add-on
    bpy.ops.wm.read_homefile(use_empty=False)
    views = _views()
    assert len(views) >= 2
    for (key, space), (kind, compositor) in zip(views, [("SOLID", "DISABLED"), ("RENDERED", "CAMERA"),
                                                        ("WIREFRAME", "DISABLED")] * len(views)):
        space.shading.type, space.shading.use_compositor = kind, compositor
    return views


@pytest.mark.skipif(bpy.app.version < (5, 0, 0), reason="the viewport look needs Blender 5.0")
def test_viewport_look_switches_the_compositor_on_and_gives_the_users_settings_back(home):
    viewport = submodule("nodes.viewport")
    compat = submodule("blender_compat")
    scene = bpy.context.scene
    before = _settings(home)

    assert bpy.ops.lowcam.viewport_look() == {"FINISHED"}
    assert viewport.is_on(scene)
    for key, space in home:
        assert space.shading.use_compositor == "ALWAYS", key
        assert space.shading.type in ("MATERIAL", "RENDERED"), key   # Solid shows no compositing
    tree = compat.compositor_tree(scene)
    node = next(n for n in tree.nodes if n.bl_idname == "LowcamCameraNode")
    assert node.outputs["Image"].links[0].to_socket == compat.compositor_output(tree)
    kinds = viewport.node_kinds(tree)
    assert {"CompositorNodeMapUV", "CompositorNodeConvolve", "CompositorNodeImage"} <= set(kinds)
    assert sum(kinds.values()) > 300                                 # the group's nodes were counted
    assert viewport.unsupported_in_viewport(tree) == []

    # the user sets a view while the look is on: switching off gives every view its own settings from before
    home[0][1].shading.use_compositor = "CAMERA"
    assert bpy.ops.lowcam.viewport_look() == {"FINISHED"}
    assert _settings(home) == before
    assert not viewport.is_on(scene)
    assert node.name in tree.nodes                                   # the compositor itself is the user's now


def test_switching_off_leaves_views_the_look_never_set_alone(home):
    viewport = submodule("nodes.viewport")
    scene = bpy.context.scene
    before = _settings(home)
    first, others = home[:1], home[1:]
    assert viewport.switch_on(scene, first, "CAMERA") == 1
    assert first[0][1].shading.use_compositor == "CAMERA" and first[0][1].shading.type == "MATERIAL"
    assert _settings(others) == {k: before[k] for k, _ in others}
    others[0][1].shading.use_compositor = "ALWAYS"                   # the user's own change to another view
    assert viewport.switch_off(scene, home) == 1
    after = _settings(home)
    assert after[first[0][0]] == before[first[0][0]]
    assert after[others[0][0]] == (before[others[0][0]][0], "ALWAYS")
    assert viewport.SAVED not in scene


@pytest.mark.skipif(bpy.app.version >= (5, 0, 0), reason="Blender 4.x only")
def test_viewport_look_refuses_before_5_0_and_touches_nothing(home):
    before = _settings(home)
    with pytest.raises(RuntimeError, match="needs Blender 5.0"):
        bpy.ops.lowcam.viewport_look()
    assert _settings(home) == before


def test_a_node_the_viewport_compositor_is_not_known_to_run_is_named():
    viewport = submodule("nodes.viewport")
    tree = bpy.data.node_groups.new("viewport probe", "CompositorNodeTree")
    try:
        tree.nodes.new("CompositorNodeOutputFile")
        tree.nodes.new("CompositorNodeMapUV")
        assert viewport.unsupported_in_viewport(tree) == ["CompositorNodeOutputFile"]
    finally:
        bpy.data.node_groups.remove(tree)


@pytest.mark.slow
@pytest.mark.skipif(bpy.app.version < (5, 0, 0), reason="the viewport look needs Blender 5.0")
def test_gpu_compositor_gives_the_cpu_compositors_frame(fire_i, tmp_path):
    """The viewport compositor's node implementations (the GPU compositor; here Mesa's software OpenGL) run the
    whole group and give the CPU compositor's 8-bit frame within 1 DN."""
    from lowcam.node_maps import bake
    from lowcam.sample import sample_plate, sample_render

    build, parity = submodule("nodes.build"), submodule("nodes.parity")
    render = build.image_from_array("viewport render", sample_render(fire_i, 320))
    render.alpha_mode = "PREMUL"
    plate = parity.plate_image(sample_plate(fire_i))
    group = build.build_camera_group(bake(fire_i, (240, 320)), name="viewport camera")
    frames = {}
    for device in ("CPU", "GPU"):
        parity._compositor_scene(320, 240).render.compositor_device = device
        frames[device] = parity.render_group(group, {"Image": render, "Plate": plate, "Noise": 0.0}, (240, 320),
                                             tmp_path / f"{device}.png").astype(np.int16)
    assert frames["CPU"].std() > 10                                  # a frame, not a blank
    assert np.abs(frames["CPU"] - frames["GPU"]).max() <= 1
