"""Blender's colour management respected: a render made in any working space Blender offers (5.0: Linear Rec.709,
Linear Rec.2020, ACEScg) gives the same degraded frame, and setting a scene up leaves its view transform and look
alone. The conversion itself is checked against colour-science's (where it is installed: the test extra)."""
import numpy as np
import OpenEXR
import pytest

from lowcam.errors import LowcamError
from lowcam.io import read_exr_tagged, read_render, render_space_of
from lowcam.render_spaces import (LINEAR_REC709, RENDER_SPACES, header_space, render_space, space_from_chromaticities,
                                  to_camera_space, to_rec709_matrix)

#: Test colours in linear Rec.709: saturated, pale, dark, white.
COLOURS = np.array([[0.8, 0.1, 0.05], [0.1, 0.6, 0.3], [0.2, 0.3, 0.9], [0.02, 0.01, 0.015], [1.0, 1.0, 1.0]])


def _colour_science(name):
    """colour-science's own colourspace, its matrices derived from primaries and white (as Blender's are)."""
    colour = pytest.importorskip("colour")
    space = colour.RGB_COLOURSPACES[name].copy()
    space.use_derived_transformation_matrices(True)
    return space


@pytest.mark.parametrize("ours, theirs", [("acescg", "ACEScg"), ("linear-rec2020", "ITU-R BT.2020"),
                                          ("aces2065-1", "ACES2065-1"), ("linear-p3-d65", "P3-D65")])
def test_conversion_matches_colour_science(ours, theirs):
    """Each space -> linear Rec.709 (Bradford between the whites) as colour-science converts it, within 2e-6."""
    colour = pytest.importorskip("colour")
    rgb = np.linalg.solve(to_rec709_matrix(render_space(ours)), COLOURS.T).T      # the colours in that space
    expected = colour.RGB_to_RGB(rgb, _colour_science(theirs), _colour_science("sRGB"),
                                 chromatic_adaptation_transform="Bradford")
    got = to_camera_space(np.concatenate([rgb, np.ones((len(rgb), 1))], -1)[None].astype(np.float32),
                          render_space(ours))[0]
    assert np.abs(got[:, :3] - expected).max() < 2e-6
    assert np.abs(got[:, :3] - COLOURS).max() < 2e-6
    assert np.array_equal(got[:, 3], np.ones(len(rgb)))


def test_acescg_matches_blenders_own_conversion():
    """Blender 5.0 turned the world colour (0.8, 0.2, 0.1) into ACEScg (0.56312, 0.24077, 0.12539) and Linear
    Rec.2020 (0.57211, 0.24032, 0.12028) (wm.set_working_color_space, printed to 5 places)."""
    for name, seen in (("acescg", (0.56312, 0.24077, 0.12539)), ("linear-rec2020", (0.57211, 0.24032, 0.12028))):
        assert np.allclose(to_rec709_matrix(render_space(name)) @ seen, (0.8, 0.2, 0.1), atol=1e-5)


def test_rec709_is_left_as_it_is():
    rgba = np.random.default_rng(1).random((4, 5, 4), dtype=np.float32)
    assert to_camera_space(rgba, LINEAR_REC709) is rgba
    assert to_camera_space(rgba, None) is rgba
    assert np.array_equal(to_rec709_matrix(LINEAR_REC709), np.eye(3)) or \
        np.abs(to_rec709_matrix(LINEAR_REC709) - np.eye(3)).max() < 1e-12


def test_names_headers_and_refusals():
    """Blender's names and interop IDs find the spaces; chromaticities match a known space or make their own;
    an interop ID Lowcam does not know is one line naming the file."""
    assert render_space("ACEScg") is render_space("lin_ap1_scene") is RENDER_SPACES["acescg"][0]
    assert render_space("Linear Rec.2020") is RENDER_SPACES["linear-rec2020"][0]
    ap1 = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)
    assert space_from_chromaticities(np.float32(ap1)) is RENDER_SPACES["acescg"][0]
    odd = space_from_chromaticities((0.7, 0.3, 0.2, 0.7, 0.15, 0.05, 0.3127, 0.329))
    assert odd.name.startswith("chromaticities") and odd.white == pytest.approx((0.3127, 0.329))
    assert header_space({}) is None
    assert header_space({"colorInteropID": "lin_rec709_scene"}) is LINEAR_REC709
    with pytest.raises(LowcamError, match=r"^r\.exr: rendered in colour space 'srgb_tx'.*--render-space"):
        header_space({"colorInteropID": "srgb_tx"}, "r.exr")
    with pytest.raises(LowcamError, match="unknown render colour space 'p3'"):
        render_space("p3")


def _exr(path, rgba, **header):
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **header},
                 {"RGBA": rgba}).write(str(path))
    return path


def test_read_render_converts_by_header_or_stated_space(tmp_path):
    """An EXR naming ACEScg (Blender's colorInteropID or the chromaticities) reads as linear Rec.709; one naming
    nothing reads as it is, unless a space is stated; linear Rec.709 gives the same bytes as before."""
    rng = np.random.default_rng(2)
    rgba = np.zeros((48, 64, 4), np.float32)
    rgba[8:40, 8:56] = rng.random((32, 48, 4), dtype=np.float32)
    rgba[..., :3] *= rgba[..., 3:]
    ap1 = RENDER_SPACES["acescg"][0]
    expected = to_camera_space(rgba, ap1)
    by_id = _exr(tmp_path / "id.exr", rgba, colorInteropID="lin_ap1_scene")
    by_xy = _exr(tmp_path / "xy.exr", rgba, chromaticities=(0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168,
                                                            0.33767))
    bare = _exr(tmp_path / "bare.exr", rgba)
    rec709 = _exr(tmp_path / "709.exr", rgba, colorInteropID="lin_rec709_scene")
    assert render_space_of(by_id, None, read_exr_tagged(by_id)[1]) is ap1
    assert np.array_equal(read_render(by_id), expected)
    assert np.array_equal(read_render(by_xy), expected)
    assert np.array_equal(read_render(bare), rgba)
    assert np.array_equal(read_render(rec709), rgba)
    assert np.array_equal(read_render(bare, render_space="acescg"), expected)
    assert np.array_equal(read_render(by_id, render_space="linear-rec709"), rgba)      # stated wins
    assert np.abs(expected - rgba).max() > 0.05                                         # a real change
    odd_id = _exr(tmp_path / "odd.exr", rgba, colorInteropID="srgb_tx")
    with pytest.raises(LowcamError, match=r"odd\.exr: rendered in colour space 'srgb_tx'"):
        read_render(odd_id)
    assert np.array_equal(read_render(odd_id, render_space="acescg"), expected)       # as the refusal advises
    for name, xy in (("flat", (0.3, 0.3) * 4), ("y0", (0.7, 0.0, 0.2, 0.7, 0.15, 0.05, 0.3127, 0.329))):
        bad = _exr(tmp_path / f"{name}.exr", rgba, chromaticities=xy)
        with pytest.raises(LowcamError, match=rf"^{bad}: its chromaticities .* make no RGB colour space; name"):
            read_render(bad)
        assert np.array_equal(read_render(bad, render_space="linear-rec709"), rgba)


def test_cli_render_space(tmp_path, capsys):
    """``lowcam apply --render-space acescg`` on a bare EXR gives the frame of the converted render; an unknown
    space is one line."""
    from lowcam.cli import main
    from lowcam.io import read_image
    from lowcam.pipeline import run

    rgba = np.zeros((480, 640, 4), np.float32)
    rgba[100:380, 150:500] = (0.5, 0.2, 0.1, 1.0)
    bare = _exr(tmp_path / "bare.exr", rgba)
    args = ["apply", "--render", str(bare), "--profile", "fire-i"]
    assert main(args + ["--render-space", "acescg", "-o", str(tmp_path / "a.png")]) == 0
    expected = run(to_camera_space(rgba, render_space("acescg")), "fire-i").frame
    assert np.array_equal(read_image(tmp_path / "a.png"), expected)
    assert not np.array_equal(run(rgba, "fire-i").frame, expected)
    capsys.readouterr()
    assert main(args + ["--render-space", "p3", "-o", str(tmp_path / "b.png")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "lowcam apply: error: argument --render-space: unknown render colour space 'p3' (known: linear-rec709, "
        "linear-rec2020, acescg, aces2065-1, linear-p3-d65) (see lowcam apply --help)"]


# --- the Blender side (real bpy) ------------------------------------------------------------------------------------

#: Each working space with the view transform and look a user might have set before Lowcam's set-up.
USER_VIEWS = {"Linear Rec.709": ("AgX", "AgX - Punchy"), "Linear Rec.2020": ("Khronos PBR Neutral", "None"),
              "ACEScg": ("Filmic", "Medium High Contrast")}


def _emission(bpy, name, rgb):
    m = bpy.data.materials.new(name)
    if m.node_tree is None:  # Blender 4 (5 gives each its nodes)
        m.use_nodes = True
    nodes = m.node_tree.nodes
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Color"].default_value = (*rgb, 1.0)
    out = nodes.new("ShaderNodeOutputMaterial")
    m.node_tree.links.new(emit.outputs[0], out.inputs["Surface"])
    return m


def _scene_in(bpy, folder, working_space):
    """A .blend with three emission planes of :data:`COLOURS` (set in linear Rec.709, then turned into
    ``working_space`` by Blender itself, as a user switching spaces would) before a camera, its view transform and
    look the user's (:data:`USER_VIEWS`); returns its path."""
    import math

    from lowcam_blender import submodule

    submodule("addon")                                         # the add-on registered (scene.lowcam)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", 1, False
    scene.render.resolution_x, scene.render.resolution_y = 320, 240
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera, camera.location = camera, (0.0, 0.0, 6.0)
    camera.data.sensor_fit, camera.data.angle = "HORIZONTAL", math.radians(50)
    for i, rgb in enumerate(COLOURS[:3]):
        bpy.ops.mesh.primitive_plane_add(size=1.4, location=(1.6 * (i - 1), 0.3 * (i - 1), 0.0))
        bpy.context.object.data.materials.append(_emission(bpy, f"C{i}", rgb))
    if working_space != "Linear Rec.709":
        bpy.ops.wm.set_working_color_space(working_space=working_space, convert_colors=True)
    view, look = USER_VIEWS[working_space]
    scene.view_settings.view_transform, scene.view_settings.look = view, look
    s = scene.lowcam
    s.profile, s.seed, s.plate_source, s.motion_source = "fire-i", 7, "NONE", "NONE"
    s.use_object_motion = s.use_depth_of_field = False
    blend = folder / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return blend


@pytest.fixture(scope="module")
def renders_by_space(tmp_path_factory):
    """``lowcam render``'s path (open, set up, render, degrade) on the planes' scene in each working space bpy
    offers: {space: (degraded frame, render EXR path, (view transform, look) after)}."""
    bpy = pytest.importorskip("bpy")
    from lowcam_blender import submodule

    from lowcam.io import read_image

    compat = submodule("blender_compat")
    spaces = ["Linear Rec.709"]
    if hasattr(bpy.data, "colorspace"):                        # 5.0+: the working spaces on offer
        prop = bpy.data.colorspace.bl_rna.properties["working_space"]
        spaces = [item.identifier for item in prop.enum_items]
    render = submodule("addon.render")
    out = {}
    for space in spaces:
        folder = tmp_path_factory.mktemp(space.replace(" ", "_").replace(".", ""))
        blend = _scene_in(bpy, folder, space)
        [frame] = render.render(blend, [1], str(folder / "out" / "####.png"), keep_renders=str(folder))
        scene = bpy.context.scene
        assert compat.working_space() == space
        out[space] = (read_image(frame), folder / "0001.exr",
                      (scene.view_settings.view_transform, scene.view_settings.look))
    return out


@pytest.mark.blender
def test_every_working_space_gives_the_rec709_frame(renders_by_space):
    """Each working space's render, read by the engine, is the Linear Rec.709 render within 1e-5 (0.003 DN;
    measured 6e-6: Blender's and Lowcam's float32 matrices), though its raw values differ by more than 0.1; the
    EXR names its space. The degraded frames (same seed, same noise) agree within 1 DN but for 1 value in 10,000
    and within 4 DN everywhere: a 6e-6 difference can cross a rounding boundary of the Fire-i's 6-bit quantisation
    (4 DN steps). Measured: ACEScg 12 of 921,600 values differ, by 1 or 2 DN; Linear Rec.2020 none. Blender 4.x
    has Linear Rec.709 only, and its EXR names no space (neither colorInteropID nor chromaticities)."""
    import bpy

    names_space = bpy.app.version >= (5, 0, 0)
    frame709, exr709, _ = renders_by_space["Linear Rec.709"]
    raw709 = read_exr_tagged(exr709)[0]["ViewLayer.Combined"]
    render709 = read_render(exr709, "ViewLayer")
    for space, (frame, exr, _) in renders_by_space.items():
        channels, tags = read_exr_tagged(exr)
        assert header_space(tags, exr) is (render_space(space) if names_space else None)        # 4.x writes no colour attribute
        assert np.abs(read_render(exr, "ViewLayer") - render709).max() < 1e-5, space
        diff = np.abs(frame.astype(int) - frame709.astype(int))
        assert diff.max() <= 4 and (diff > 1).mean() < 1e-4, (space, diff.max(), (diff > 1).mean())
        if space != "Linear Rec.709":
            assert np.abs(channels["ViewLayer.Combined"] - raw709).max() > 0.1     # rendered in another space


@pytest.mark.blender
def test_set_up_leaves_the_view_transform_and_look(renders_by_space):
    """After ``lowcam render``'s set-up and render the scene's view transform and look are the user's."""
    for space, (_, _, after) in renders_by_space.items():
        assert after == USER_VIEWS[space], space


@pytest.mark.blender
def test_node_group_gives_the_rec709_frame_in_every_working_space(tmp_path):
    """*Add Camera Node* on the planes' scene in each working space, noise off: the compositor's frame (written
    with the output's own Standard view while the scene keeps the user's view and look) is the Linear Rec.709
    one within 1 DN but for 1 value in 10,000, 4 DN everywhere (a 6-bit step, as above)."""
    bpy = pytest.importorskip("bpy")
    from lowcam_blender import submodule

    from lowcam.io import read_image

    if bpy.app.version < (5, 0, 0):
        pytest.skip(f"Blender {bpy.app.version_string}: the node group's composite is checked from 5.0 on")
    spaces = [item.identifier for item in bpy.data.colorspace.bl_rna.properties["working_space"].enum_items]
    frames = {}
    for space in spaces:
        folder = tmp_path / space.replace(" ", "_").replace(".", "")
        folder.mkdir()
        _scene_in(bpy, folder, space)
        scene = bpy.context.scene
        assert bpy.ops.lowcam.add_camera_node() == {"FINISHED"}
        node = next(n for n in submodule("blender_compat").compositor_tree(scene).nodes
                    if n.bl_idname == "LowcamCameraNode")
        node.inputs["Noise"].default_value = 0.0
        settings = scene.render.image_settings
        settings.file_format, settings.color_depth, settings.color_mode = "PNG", "8", "RGB"
        scene.render.filepath = str(folder / "node.png")
        bpy.ops.render.render(write_still=True)
        assert (scene.view_settings.view_transform, scene.view_settings.look) == USER_VIEWS[space]
        frames[space] = read_image(folder / "node.png").astype(int)
    for space, frame in frames.items():
        diff = np.abs(frame - frames["Linear Rec.709"])
        print(space, "node frame vs Rec.709: max", diff.max(), "DN, share > 1 DN", (diff > 1).mean())
        assert diff.max() <= 4 and (diff > 1).mean() < 1e-4, (space, diff.max(), (diff > 1).mean())
        assert frame.std() > 5                                   # a picture, not a flat field
