"""The Blender side with real bpy: the sample scene rendered through the render handler (as ``blender -b -a``
does), the excluded overlay, camera motion from the scene, and the compositor node group against the engine."""
import os

import bpy
import numpy as np
import pytest

from lowcam.effects.yuv import rgb_to_yuv
from lowcam.errors import LowcamError
from lowcam_blender import submodule
from lowcam.io import read_image, read_plate
from lowcam.pipeline import plain_composite
from lowcam.profile import BUNDLED_PROFILES
from lowcam.scene import OVERLAY_LAYER, overlay_in_frame, read_layers, read_passes

pytestmark = pytest.mark.blender  # real bpy: the Blender tier

#: Blender 4.x builds the node group (blender_compat.py: Translate taps stand in for Convolve, baked masks and noise
#: for Image Coordinates and White Noise on 4.2), but its composite does not match the engine there yet: on 4.5.15
#: the asset's frame is 15 DN off on average and the stage-by-stage parity runs past 10 minutes; on 4.2.23 the
#: parity render is killed. Blender 5.0 and later are checked.
node_group_matches_from_5_0 = pytest.mark.skipif(
    bpy.app.version < (5, 0, 0), reason=f"Blender {bpy.app.version_string}: the node group's composite is only "
                                        "checked against the engine from Blender 5.0 (4.x differs, see above)")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The sample scene at 400 px, frames 1-2 rendered with the handler on (bpy.ops.render.render(animation)),
    object motion on (the default) and defocus from depth on, focused on the cube with a small aperture."""
    folder = tmp_path_factory.mktemp("sample")
    blend = submodule("addon.sample").build_sample_scene(folder, render_width=400, samples=8)
    scene = submodule("addon.render").open_scene(blend)
    s = scene.lowcam
    s.use_depth_of_field, s.focus_distance_m, s.aperture_mm = True, 3.0, 1.0
    s.video_output = "//lowcam/shot.mp4"
    submodule("addon.frames").setup_scene(scene, 400)
    bpy.ops.wm.save_mainfile()
    bpy.ops.render.render(animation=True)
    return folder


def _objects(render):
    """(cube, sphere) masks of the sample scene's opaque, not-edge pixels: the cube stands left of the sphere."""
    import cv2

    solid = cv2.erode((render[..., 3] > 0.999).astype(np.uint8), np.ones((5, 5), np.uint8))
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(solid)
    biggest = sorted(range(1, n), key=lambda i: -stats[i, cv2.CC_STAT_AREA])[:2]
    cube, sphere = sorted(biggest, key=lambda i: centroids[i][0])
    return labels == cube, labels == sphere


def _frame_data(folder, frame):
    out = read_image(folder / "lowcam" / f"{frame:04d}.png")
    render, overlay = read_layers(folder / "render" / f"{frame:04d}.exr", "ViewLayer", OVERLAY_LAYER)
    plate = read_plate(folder / "plate" / f"{frame:04d}.png", 640, 480)
    return out, render, overlay, plate


def test_handler_writes_composites_that_keep_the_plate_and_degrade_the_object(rendered):
    import cv2

    for frame in (1, 2):
        out, render, overlay, plate = _frame_data(rendered, frame)
        plain = plain_composite(render, "fire-i", plate)
        reach = (plain != plate).any(axis=2) | (overlay_in_frame(overlay, "fire-i")[..., 3] > 0)
        far = ~cv2.dilate(reach.astype(np.uint8), np.ones((41, 41), np.uint8)).astype(bool)
        assert far.mean() > 0.3
        assert np.array_equal(out[far], plate[far])
    out1, render, overlay, plate = _frame_data(rendered, 1)
    out2 = read_image(rendered / "lowcam" / "0002.png")
    plain = plain_composite(render, "fire-i", plate)
    core = cv2.erode((plain != plate).any(axis=2).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert core.sum() > 500
    # degraded, not the plain composite, and the noise differs between frames
    assert np.abs(out1[core].astype(float) - plain[core]).mean() > 2.0
    assert (out1[core] != out2[core]).mean() > 0.3


def test_the_animation_render_codes_its_composites_into_the_video_output(rendered):
    """The render_complete handler codes frames 1-2 into //lowcam/shot.mp4: H.264 (the plate is an image
    sequence), BT.709 tagged, each frame its own composite within the coding's loss."""
    from lowcam.video import VideoReader

    with VideoReader(rendered / "lowcam" / "shot.mp4") as video:
        frames = [rgb.astype(np.float32) for _, rgb in video.frames(10)]
        assert video.stream.codec_context.name == "h264" and video.colour.matrix == "bt709"
    composites = [read_image(rendered / "lowcam" / f"{f:04d}.png").astype(np.float32) for f in (1, 2)]
    assert len(frames) == 2
    for k, frame in enumerate(frames):
        own, other = np.abs(frame - composites[k]).mean(), np.abs(frame - composites[1 - k]).mean()
        assert own < 4 and own < 0.8 * other, (own, other)   # CRF 18 on noisy frames: 2.6 DN; not the other frame


def test_object_carries_411_chroma(rendered):
    out, render, overlay, plate = _frame_data(rendered, 1)
    plain = plain_composite(render, "fire-i", plate)

    # groups the excluded crosshair touches, or where 8-bit clipping cut the sum, are left out
    skip = (overlay_in_frame(overlay, "fire-i")[..., 3] > 0) | (out.min(axis=2) == 0) | (out.max(axis=2) == 255)
    skip = skip.reshape(480, 160, 4).any(axis=2)

    def chroma_spread(frame):
        d = rgb_to_yuv(frame.astype(np.float32) - plate.astype(np.float32))
        groups = d[..., 1:].reshape(480, 160, 4, 2)
        touched = (np.abs(groups).max(axis=(2, 3)) > 8) & ~skip
        assert touched.sum() > 300
        return np.ptp(groups, axis=2).max(axis=-1)[touched]

    assert np.percentile(chroma_spread(out), 95) <= 2.0          # one U, V per 4 pixels (8-bit rounding aside)
    assert np.percentile(chroma_spread(plain), 95) > 4.0          # the plain composite has full chroma


def test_object_shows_6_bit_levels(tmp_path):
    """With saturation at the identity and no chroma subsampling, opaque object pixels are block-demosaiced
    6-bit values: red and blue multiples of 4 DN, green (the mean of two greens) of 2."""
    text = (BUNDLED_PROFILES / "fire-i.toml").read_text()
    text = text.replace('texture = "fire-i/', f'texture = "{BUNDLED_PROFILES}/fire-i/')
    text = text.replace("saturation = 90.0", "saturation = 65.0").replace("group = 4", "group = 1")
    (tmp_path / "fire-i-6bit.toml").write_text(text)
    os.environ["LOWCAM_PROFILE_PATH"] = str(tmp_path)
    try:
        blend = submodule("addon.sample").build_sample_scene(tmp_path, "fire-i-6bit", render_width=400, samples=8,
                                                             sphere_m_s=0.0)   # no streaks over the plate
        out = read_image(submodule("addon.render").render(blend, [1], str(tmp_path / "out"),
                                                          keep_renders=str(tmp_path / "render"))[0])
    finally:
        del os.environ["LOWCAM_PROFILE_PATH"]
    import cv2

    render, overlay = read_layers(tmp_path / "render" / "0001.exr", "ViewLayer", OVERLAY_LAYER)
    plate = read_plate(tmp_path / "plate" / "0001.png", 640, 480)
    opaque = plain_composite(np.repeat(render[..., 3:], 4, axis=-1), "fire-i", None)   # white where covered
    core = cv2.erode((opaque.min(axis=2) == 255).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    ov = overlay_in_frame(overlay, "fire-i")[..., 3] > 0
    core &= ~cv2.dilate(ov.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    core &= (out.min(axis=2) > 0) & (out.max(axis=2) < 255)
    assert core.sum() > 300
    px = out[core].astype(int)
    assert (px[:, 0] % 4 == 0).mean() > 0.99 and (px[:, 2] % 4 == 0).mean() > 0.99
    assert (px[:, 1] % 2 == 0).mean() > 0.99
    assert not (plate[core].astype(int) % 4 == 0).all()


def test_excluded_objects_stay_crisp_and_noise_free(rendered):
    for frame in (1, 2):
        out, render, overlay, plate = _frame_data(rendered, frame)
        ov = overlay_in_frame(overlay, "fire-i")
        solid = ov[..., 3] > 0.999
        assert solid.sum() > 100
        expected = np.rint(np.clip(ov[..., :3] * 255, 0, 255)).astype(np.uint8)
        assert np.array_equal(out[solid], expected[solid])   # no blur, noise, quantisation or chroma


def test_angular_velocity_from_the_panning_camera(rendered):
    frames = submodule("addon.frames")
    scene = submodule("addon.render").open_scene(rendered / "sample_scene.blend")
    m = frames.motion(scene, 1, 0.033)
    # the sample camera turns left (counter-clockwise seen from above) at 0.6 rad/s about the world's vertical,
    # its own up axis: a rotation about our y (down) axis, negative because positive y pans right
    assert np.allclose(m.angular_velocity, (0.0, -0.6, 0.0), atol=1e-4)
    assert m.exposure_s == pytest.approx(0.033)


def test_vector_pass_reads_as_image_velocity(tmp_path):
    """A plane moving diagonally in front of a still camera: the Vector pass, read by ``read_passes``, is its
    projected velocity in px/s with y down."""
    import math

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine, scene.cycles.samples, scene.cycles.device = "CYCLES", 1, "CPU"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.fps = 200, 150, 25
    scene.render.film_transparent, scene.render.use_motion_blur = True, False
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera, camera.location = camera, (0.0, 0.0, 10.0)                  # looking down -z, image x = world x
    camera.data.sensor_fit, camera.data.angle = "HORIZONTAL", math.radians(60)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.object
    for frame, x in ((1, 0.0), (3, 1.0)):                                    # 0.5 m per frame right, 0.25 up
        plane.location = (x, 0.5 * x, 0.0)
        plane.keyframe_insert("location", frame=frame)
    compat = submodule("blender_compat")                                       # Blender 4.2 to 5.x
    for fc in compat.action_fcurves(plane):
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    scene.view_layers[0].use_pass_vector = scene.view_layers[0].use_pass_z = True
    settings = scene.render.image_settings
    compat.set_multilayer_exr(settings)
    settings.color_depth = "32"
    scene.frame_set(2)
    scene.render.filepath = str(tmp_path / "plane.exr")
    bpy.ops.render.render(write_still=True)

    passes = read_passes(tmp_path / "plane.exr", "ViewLayer", fps=25.0, needs=("Vector", "Depth"))
    render, _ = read_layers(tmp_path / "plane.exr", "ViewLayer")
    inside = render[..., 3] > 0.999
    focal = 100.0 / math.tan(math.radians(30))                                 # px
    expected = np.array([0.5, -0.25]) * 25.0 * focal / 10.0                    # m/frame -> px/s at 10 m
    assert np.allclose(np.median(passes.velocity_px_s[inside], axis=0), expected, rtol=0.01)
    assert np.allclose(passes.depth_m[inside], 10.0, rtol=1e-4)


def test_object_motion_is_what_the_camera_rotation_leaves(rendered):
    """In the sample scene the camera pans and the sphere moves 3 m/s along x: after taking out the rotation's
    velocity the cube is still and the sphere moves at f 3 / z px/s, z from the Depth pass."""
    from lowcam.effects.object_motion import rotation_velocity
    from lowcam.pipeline import render_focal_px

    frames = submodule("addon.frames")
    scene = submodule("addon.render").open_scene(rendered / "sample_scene.blend")
    w = frames.motion(scene, 1, 0.033).angular_velocity
    render, _ = read_layers(rendered / "render" / "0001.exr", "ViewLayer")
    passes = read_passes(rendered / "render" / "0001.exr", "ViewLayer", fps=24.0, needs=("Vector", "Depth"))
    focal = render_focal_px(frames.scene_profile(scene), render.shape[1], render.shape[0])
    camera = rotation_velocity(w, focal, render.shape[:2])
    residual = passes.velocity_px_s - camera
    cube, sphere = _objects(render)
    assert cube.sum() > 300 and sphere.sum() > 300
    assert np.percentile(np.abs(camera[cube][:, 0]), 5) > 50                 # the pan moves it 50+ px/s ...
    assert np.percentile(np.abs(residual[cube]), 95) < 1.0                   # ... and explains all of it
    expected = focal * 3.0 / passes.depth_m[sphere]
    assert np.median(np.abs(residual[sphere][:, 0] / expected - 1)) < 0.02
    assert np.percentile(np.abs(residual[sphere][:, 1]), 95) < 0.05 * expected.min()
    assert passes.depth_m[sphere].min() == pytest.approx(2.6 - 0.35, rel=0.01)   # the sphere's nearest point


def test_object_motion_changes_the_frame_only_around_the_moving_sphere(rendered, tmp_path):
    """Degrading frame 1 again gives the handler's bytes; without object motion only the sphere's surroundings
    change (the noise is the same: it depends on seed and frame only)."""
    import cv2

    frames = submodule("addon.frames")
    scene = submodule("addon.render").open_scene(rendered / "sample_scene.blend")
    scene.lowcam.output = str(tmp_path / "####.png")
    exr = rendered / "render" / "0001.exr"
    again = read_image(frames.degrade(scene, exr, 1))
    assert np.array_equal(again, read_image(rendered / "lowcam" / "0001.png"))
    scene.lowcam.use_object_motion = False
    still = read_image(frames.degrade(scene, exr, 1))
    changed = (still != again).any(axis=2)
    render, _ = read_layers(exr, "ViewLayer")
    cube, sphere = _objects(render)
    sphere = cv2.dilate(sphere.astype(np.uint8), np.ones((7, 7), np.uint8))      # its edge back
    sphere_frame = plain_composite(np.repeat(sphere[..., None].astype(np.float32), 4, -1), "fire-i")[..., 0] > 0
    near_sphere = cv2.dilate(sphere_frame.astype(np.uint8), np.ones((31, 31), np.uint8)).astype(bool)
    assert changed.sum() > 200
    assert not changed[~near_sphere].any()


@node_group_matches_from_5_0
def test_node_group_matches_the_engine(fire_i):
    """Blender's compositor running "Lowcam Camera" against the engine, noise off: every stage within 2/255."""
    from lowcam.sample import sample_plate, sample_render

    parity = submodule("nodes.parity").parity
    results = parity(sample_render(fire_i, 800), sample_plate(fire_i), fire_i, angular_velocity=(0.0, 0.3, 0.1))
    worst = max(results, key=lambda s: results[s]["mad"])
    print("worst stage:", worst, results[worst])
    assert set(results) >= {"lens_distortion", "bayer_sampling", "sharpening", "quantisation", "demosaic",
                            "chroma_subsampling", "plate_blend"}
    assert all(r["mad"] <= 2.0 for r in results.values()), results
    assert results["plate_blend"]["mad_object"] <= 2.0
    assert results["plate_blend"]["max_outside"] == 0.0          # the plate passes bit for bit


@node_group_matches_from_5_0
def test_node_asset_appends_into_a_new_file_and_matches_the_engine(fire_i, tmp_path):
    """The asset .blend written by ``lowcam node-asset``: appended into an empty file, the group is an asset with
    its maps packed, and its composite is the engine's frame (noise off) within 2 DN, the plate exact."""
    from lowcam.cli import main
    from lowcam.pipeline import run
    from lowcam.sample import sample_plate, sample_render

    path = tmp_path / "lowcam-camera.blend"
    assert main(["node-asset", "-o", str(path), "--render-width", "800", "--angular-velocity", "0,0.3,0.1"]) == 0
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(str(path), assets_only=True) as (source, target):
        assert source.node_groups == ["Lowcam Camera (fire-i)"]
        target.node_groups = source.node_groups
    group = bpy.data.node_groups["Lowcam Camera (fire-i)"]
    assert group.asset_data is not None and "lowcam" in [t.name for t in group.asset_data.tags]
    maps = [im for im in bpy.data.images if im.name.startswith("Lowcam")]
    assert maps and all(im.packed_file is not None for im in maps)

    parity = submodule("nodes.parity")
    render, plate = sample_render(fire_i, 800), sample_plate(fire_i)
    image = parity.image_from_array("render", render)
    image.alpha_mode = "PREMUL"
    node = parity.render_group(group, {"Image": image, "Plate": parity.plate_image(plate), "Noise": 0.0},
                               plate.shape[:2], tmp_path / "asset.png")
    quiet = fire_i.without("noise")
    engine = run(render, quiet, plate, (0.0, 0.3, 0.1))
    diff = np.abs(node.astype(float) - engine.frame)
    assert diff.mean() <= 2.0
    assert diff[~engine.footprint].max() == 0


def test_lowcam_render_resumes_and_leaves_no_scratch_renders(tmp_path, monkeypatch, capsys):
    """``lowcam render``: two composites; a second run redoes only the missing one; renders that are not kept
    go to a scratch folder that is removed."""
    import tempfile

    from lowcam.cli import main

    blend = submodule("addon.sample").build_sample_scene(tmp_path / "scene", render_width=400, samples=4)
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    out = tmp_path / "out"
    assert main(["render", str(blend), "--frames", "1-2", "-o", str(out)]) == 0
    first, second = out / "0001.png", out / "0002.png"
    assert read_image(first).shape == (480, 640, 3) and second.is_file()
    before = first.stat().st_mtime_ns
    second.unlink()
    assert main(["render", str(blend), "--frames", "1-2", "-o", str(out)]) == 0
    assert first.stat().st_mtime_ns == before and second.is_file()
    assert "2 composites in" in capsys.readouterr().out
    assert list(scratch.iterdir()) == []
    # each scratch render is gone once its composite is written; --render-compression sets the renders' codec
    import OpenEXR

    left = []
    submodule("addon.render").render(blend, [1, 2], str(out), force=True,
                                     progress=lambda f, p: left.append(sorted(scratch.rglob("*.exr"))))
    assert left == [[], []]
    assert main(["render", str(blend), "--frames", "1", "-o", str(out), "--force",
                 "--render-compression", "ZIP"]) == 0
    kept = tmp_path / "kept"
    submodule("addon.render").render(blend, [1], str(out), force=True, keep_renders=str(kept), compression="PIZ")
    with OpenEXR.File(str(kept / "0001.exr"), header_only=True) as f:
        assert {str(part.header["compression"]) for part in f.parts} == {"Compression.PIZ_COMPRESSION"}


def test_add_camera_node_gives_the_scene_the_render_the_node_is_baked_for(fire_i):
    """From Blender's default 1920x1080 scene: the render camera's field of view and 4:3 size, the compositor on,
    and a built "Lowcam Camera" between Render Layers and the output."""
    import math

    from lowcam.pipeline import render_camera

    submodule("addon.render")
    bpy.ops.wm.read_homefile(use_empty=False)
    scene = bpy.context.scene
    assert (scene.render.resolution_x, scene.render.resolution_y) == (1920, 1080)
    assert bpy.ops.lowcam.add_camera_node() == {"FINISHED"}
    cam = render_camera(fire_i, 1920 * scene.render.resolution_percentage // 100)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (cam["width"], cam["height"])
    assert scene.camera.data.angle == pytest.approx(math.radians(cam["hfov_deg"]), rel=1e-6)
    assert scene.render.use_compositing and scene.render.film_transparent
    compat = submodule("blender_compat")
    tree = compat.compositor_tree(scene, create=False)
    node = next(n for n in tree.nodes if n.bl_idname == "LowcamCameraNode")
    assert list(node.node_tree["lowcam_stages"])[-1] == "plate_blend"          # the group was built
    assert node.inputs["Image"].links[0].from_node.bl_idname == "CompositorNodeRLayers"
    assert node.outputs["Image"].links[0].to_socket == compat.compositor_output(tree)


def test_lowcam_motion_writes_the_scene_cameras_motion_for_batch(rendered, tmp_path):
    from lowcam.cli import main
    from lowcam.motion import read_motion_json

    path = tmp_path / "motion.json"
    assert main(["motion", str(rendered / "sample_scene.blend"), "--frames", "1-2", "-o", str(path)]) == 0
    table = read_motion_json(path)
    assert sorted(table) == [1, 2]
    for m in table.values():
        assert np.allclose(m.angular_velocity, (0.0, -0.6, 0.0), atol=1e-4) and m.exposure_s == pytest.approx(0.033)


def test_motion_from_a_file_json_or_gyro_csv(rendered, tmp_path):
    from lowcam.motion import FrameMotion, write_motion_json

    frames = submodule("addon.frames")
    scene = submodule("addon.render").open_scene(rendered / "sample_scene.blend")
    scene.lowcam.motion_source = "FILE"
    gyro = tmp_path / "gyro.csv"
    gyro.write_text("t,wx,wy,wz\n" + "".join(f"{t / 100},0.1,{0.2 + t / 1000},0.3\n" for t in range(100)))
    scene.lowcam.motion_file = str(gyro)
    # frame 2 is exposed over [1/24, 1/24 + 0.033] s: wy averages 0.2 + 10 (1/24 + 0.0165) / 100
    assert np.allclose(frames.motion(scene, 2, 0.033).angular_velocity, (0.1, 0.2 + (1 / 24 + 0.0165) / 10, 0.3))
    path = write_motion_json(tmp_path / "motion.json", {1: FrameMotion((0.0, 0.5, 0.0), 0.02)})
    scene.lowcam.motion_file = str(path)
    assert frames.motion(scene, 1, 0.033).angular_velocity == (0.0, 0.5, 0.0)
    with pytest.raises(LowcamError, match="no entry for frame 2"):
        frames.motion(scene, 2, 0.033)


def test_renders_are_uncompressed_by_default_and_every_compression_gives_the_same_composite(tmp_path):
    """Render Compression: Blender writes the add-on's renders uncompressed unless asked otherwise, Lowcam reads them
    itself as the OpenEXR binding does, and a ZIP render of the same frame holds the same channel bits and gives the
    same composite, byte for byte."""
    import OpenEXR

    from lowcam.uncompressed_exr import read_uncompressed_exr

    blend = submodule("addon.sample").build_sample_scene(tmp_path / "scene", render_width=400, samples=4)
    scene = submodule("addon.render").open_scene(blend)
    assert scene.lowcam.render_codec == "NONE"
    channels, composites, sizes = {}, {}, {}
    for codec in ("NONE", "ZIP"):
        scene.lowcam.render_codec = codec
        scene.lowcam.output = str(tmp_path / codec / "####.png")
        submodule("addon.frames").setup_scene(scene, 400)
        assert scene.render.image_settings.exr_codec == codec
        path = tmp_path / codec / "render.exr"
        composites[codec] = read_image(submodule("addon.render").render_frame(scene, 1, path)).tobytes()
        with OpenEXR.File(str(path), separate_channels=True) as f:
            assert {str(p.header["compression"]) for p in f.parts} == \
                {f"Compression.{'NO' if codec == 'NONE' else codec}_COMPRESSION"}
            channels[codec] = {name: c.pixels.tobytes() for part in f.parts for name, c in part.channels.items()}
        sizes[codec] = path.stat().st_size
        if codec == "NONE":      # Lowcam reads Blender's uncompressed render itself: the binding's channels, bits
            parts, _ = read_uncompressed_exr(path)
            mine = {name: pixels for _, part in parts for name, pixels in part.items()}
            with OpenEXR.File(str(path)) as f:
                theirs = {name: c.pixels for part in f.parts for name, c in part.channels.items()}
            assert list(mine) == list(theirs)        # one part per layer (bpy 5) or every layer in one (bpy 4)
            assert all(mine[n].dtype == theirs[n].dtype and mine[n].tobytes() == theirs[n].tobytes() for n in theirs)
    assert any(".Vector." in name for name in channels["NONE"]) and channels["NONE"] == channels["ZIP"]
    assert composites["NONE"] == composites["ZIP"]
    assert sizes["NONE"] > 2 * sizes["ZIP"]   # bpy 5.0: over 5x; bpy 5.2: 3.1x


def test_half_float_renders_round_only_the_colour_and_nearly_keep_the_composite(tmp_path):
    """Render Depth "Half Float": Blender writes the Combined pass as half float (the 32-bit render's values
    rounded), keeps the Depth and Vector passes 32-bit, and the composite stands within the bounds the engine's
    test holds (tests/test_io.py) of the 32-bit render's."""
    import OpenEXR

    blend = submodule("addon.sample").build_sample_scene(tmp_path / "scene", render_width=400, samples=4)
    scene = submodule("addon.render").open_scene(blend)
    scene.lowcam.use_depth_of_field = True
    channels, composites = {}, {}
    for depth in ("32", "16"):
        scene.lowcam.render_depth = depth
        scene.lowcam.output = str(tmp_path / depth / "####.png")
        submodule("addon.frames").setup_scene(scene, 400)
        out = submodule("addon.render").render_frame(scene, 1, tmp_path / depth / "render.exr")
        composites[depth] = read_image(out).astype(int)
        with OpenEXR.File(str(tmp_path / depth / "render.exr"), separate_channels=True) as f:
            channels[depth] = {name: c.pixels for part in f.parts for name, c in part.channels.items()}
    colour = [n for n in channels["32"] if n.startswith("ViewLayer.Combined.")]
    data = [n for n in channels["32"] if n.startswith(("ViewLayer.Depth.", "ViewLayer.Vector."))]
    assert len(colour) == 4 and len(data) == 5
    for name in colour:
        assert channels["16"][name].dtype == np.float16
        assert np.array_equal(channels["16"][name], channels["32"][name].astype(np.float16))
    for name in data:
        assert channels["16"][name].dtype == np.float32
        assert np.array_equal(channels["16"][name], channels["32"][name])
    diff = np.abs(composites["16"] - composites["32"])
    assert 0 < (diff > 0).mean() <= 0.005 and diff.max() <= 4


def test_headless_blender_hands_no_render_result_in_memory(tmp_path):
    """Why the render handler reads the file Blender wrote: rendering headless, neither the Render Result image nor
    a compositor Viewer node's image holds the render's pixels for Python (a world of colour 0.5, Cycles at 32x24
    px), while the file the same render writes does. When a Blender does hand them over, this fails and the
    handler can take them instead."""
    scene = bpy.data.scenes.new("lowcam-memory-probe")
    scene.render.engine, scene.cycles.samples, scene.cycles.use_denoising = "CYCLES", 1, False
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 32, 24, 100
    scene.world = bpy.data.worlds.new("lowcam-memory-probe")
    scene.world.color = (0.5, 0.5, 0.5)
    scene.camera = bpy.data.objects.new("lowcam-memory-probe", bpy.data.cameras.new("lowcam-memory-probe"))
    scene.collection.objects.link(scene.camera)
    if bpy.app.version >= (5, 0, 0):
        tree = bpy.data.node_groups.new("lowcam-memory-probe", "CompositorNodeTree")
        tree.interface.new_socket(name="Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        scene.compositing_node_group = tree
        layers, out = tree.nodes.new("CompositorNodeRLayers"), tree.nodes.new("NodeGroupOutput")
    else:
        scene.use_nodes = True
        tree = scene.node_tree
        layers, out = (next(n for n in tree.nodes if n.type == t) for t in ("R_LAYERS", "COMPOSITE"))
    layers.scene = scene
    tree.links.new(layers.outputs["Image"], out.inputs[0])
    tree.links.new(layers.outputs["Image"], tree.nodes.new("CompositorNodeViewer").inputs[0])
    scene.render.filepath = str(tmp_path / "probe.png")
    try:
        bpy.ops.render.render(scene=scene.name, write_still=True)
        assert read_image(tmp_path / "probe.png").min() > 50       # the render itself: the world's grey
        held = {}
        for image in bpy.data.images:
            if image.type in ("RENDER_RESULT", "COMPOSITING"):
                pixels = np.zeros(len(image.pixels), np.float32)
                image.pixels.foreach_get(pixels)
                held[image.name] = float(np.abs(pixels).max(initial=0.0))
        assert "Render Result" in held and held and max(held.values()) == 0.0, held
    finally:
        bpy.data.scenes.remove(scene)
