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
    view = scene.view_settings
    view.view_transform, view.look, view.exposure = "AgX", "AgX - Punchy", 0.5     # the user's own view
    view.gamma, view.use_curve_mapping = 1.2, True

    assert bpy.ops.lowcam.viewport_look() == {"FINISHED"}
    assert viewport.is_on(scene)
    assert (view.view_transform, view.look, view.exposure, view.gamma, view.use_curve_mapping,
            scene.display_settings.display_device) == ("Standard", "None", 0.0, 1.0, False, "sRGB")  # the codes
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
    assert (view.view_transform, view.look, view.exposure, view.gamma, view.use_curve_mapping) == \
        ("AgX", "AgX - Punchy", 0.5, pytest.approx(1.2), True)
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
    whole group and give the CPU compositor's 8-bit frame within 1 DN, but where a sensel's light lies on a 6-bit
    level's edge to within the two compositors' rounding: there the level may differ by one step (4 DN; half of it
    in green, the mean of two sensels), at a handful of values (2 of 230,400 seen)."""
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
    diff = np.abs(frames["CPU"] - frames["GPU"])
    assert diff.max() <= 4 and (diff > 1).sum() <= 10, (diff.max(), (diff > 1).sum())


@pytest.mark.slow
@pytest.mark.skipif(bpy.app.version < (5, 0, 0), reason="the viewport look needs Blender 5.0")
def test_the_3d_view_shows_the_cameras_frame_over_the_plate(tmp_path):
    """Blender 5's own 3D view, drawn through the sample scene's camera (offscreen, Mesa's software OpenGL): with
    Viewport Look on, the viewport compositor runs "Lowcam Camera" on the viewport's image and the plate that Add
    Camera Node connected (the Plate pattern's frames), so where no object is the view shows the plate's own
    pixels; with the view's Compositor off it shows the viewport's world instead. The look's view transform is
    what makes the pixels the plate's: under the scene's AgX they are far off."""
    import cv2

    from lowcam.io import read_image
    from lowcam.profile import load_profile

    submodule("addon.render")
    blend = submodule("addon.sample").build_sample_scene(tmp_path, render_width=400, samples=4, frames=3)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    scene.view_settings.view_transform = "AgX"
    viewport = submodule("nodes.viewport")
    assert bpy.ops.lowcam.viewport_look() == {"FINISHED"}
    tree = submodule("blender_compat").compositor_tree(scene)
    node = next(n for n in tree.nodes if n.bl_idname == "LowcamCameraNode")
    plate_image = node.inputs["Plate"].links[0].from_node.image
    assert plate_image.source == "SEQUENCE" and plate_image.filepath == "//plate/0001.png"
    viewport.start_gpu()
    area = next(a for s in bpy.data.screens for a in s.areas if a.type == "VIEW_3D")
    camera = load_profile(scene.lowcam.profile).camera
    size = (camera.width, camera.height)                             # the frame drawn pixel for pixel
    scene.frame_set(3)                                               # frame N shows the plate's file N
    plate = read_image(tmp_path / "plate" / "0003.png").astype(np.float64)
    sky = (slice(0, camera.height // 4), slice(None))                # no object in the frame's top quarter

    def drawn(compositor):
        area.spaces.active.shading.use_compositor = compositor
        picture = viewport.draw_through_camera(scene, area, *size)[..., :3]
        return np.clip(np.rint(picture * 255.0), 0, 255)

    look = drawn("ALWAYS")
    assert np.abs(look - plate)[sky].mean() < 1.0                  # the plate's pixels (0.5 measured)
    first = read_image(tmp_path / "plate" / "0001.png").astype(np.float64)
    assert np.abs(look - first)[sky].mean() > 2 * np.abs(look - plate)[sky].mean()   # not frame 1's
    assert np.abs(look - plate)[camera.height // 3:, :].mean() > 3  # the objects are in the frame
    assert np.abs(drawn("DISABLED") - plate)[sky].mean() > 30      # the world's grey, not the plate
    area.spaces.active.shading.use_compositor = "ALWAYS"
    scene.view_settings.view_transform = "AgX"                      # the user's view while the look is on
    assert np.abs(drawn("ALWAYS") - plate)[sky].mean() > 4         # 8.4 measured
    assert cv2.countNonZero((look.mean(axis=2) > 0).astype(np.uint8)) > 0.9 * look.shape[0] * look.shape[1]


def test_add_camera_node_connects_the_plate_pattern_only_where_blender_can_play_it(tmp_path):
    """The Plate pattern becomes the node's image sequence only where Blender can play it: a frame number that is
    not the last number in the file's name, or a first frame without a file, leaves the Plate input unconnected
    (the operator says why; the render handler reads such patterns itself)."""
    import cv2

    submodule("addon.render")
    bpy.ops.wm.read_homefile(use_empty=False)
    scene = bpy.context.scene
    compat = submodule("blender_compat")
    s = scene.lowcam
    s.plate_source = "SEQUENCE"
    for f in (1, 2):
        cv2.imwrite(str(tmp_path / f"{f:04d}_v2.png"), np.full((8, 8, 3), 40 * f, np.uint8))

    def plate_input(pattern):
        s.plate_pattern = str(tmp_path / pattern)
        assert bpy.ops.lowcam.add_camera_node() == {"FINISHED"}
        node = [n for n in compat.compositor_tree(scene).nodes if n.bl_idname == "LowcamCameraNode"][-1]
        return node.inputs["Plate"]

    assert not plate_input("####_v2.png").is_linked          # Blender would number the sequence by the 2
    assert not plate_input("v2_####.png").is_linked          # no file for the first frame
    for f in (1, 2):
        (tmp_path / f"{f:04d}_v2.png").rename(tmp_path / f"v2_{f:04d}.png")
    image = plate_input("v2_####.png").links[0].from_node.image
    assert image.source == "SEQUENCE" and image.filepath.endswith("v2_0001.png")
