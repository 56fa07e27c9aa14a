"""The Blender side with real bpy: the sample scene rendered through the render handler (as ``blender -b -a``
does), the excluded overlay, camera motion from the scene, and the compositor node group against the engine."""
import os

import bpy
import numpy as np
import pytest

from lowcam.effects.yuv import rgb_to_yuv
from lowcam.extension import submodule
from lowcam.io import read_image, read_plate
from lowcam.pipeline import plain_composite
from lowcam.profile import BUNDLED_PROFILES
from lowcam.scene import OVERLAY_LAYER, overlay_in_frame, read_layers


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The sample scene at 400 px, frames 1-2 rendered with the handler on (bpy.ops.render.render(animation))."""
    folder = tmp_path_factory.mktemp("sample")
    blend = submodule("addon.sample").build_sample_scene(folder, render_width=400, samples=8)
    submodule("addon.render").open_scene(blend)
    bpy.ops.render.render(animation=True)
    return folder


def _frame_data(folder, frame):
    out = read_image(folder / "lowcam" / f"{frame:04d}.png")
    render, overlay = read_layers(folder / "render" / f"{frame:04d}.exr", "ViewLayer", OVERLAY_LAYER)
    plate = read_plate(folder / "plate.png", 640, 480)
    return out, render, overlay, plate


def test_handler_writes_composites_that_keep_the_plate_and_degrade_the_object(rendered):
    import cv2

    out1, render, overlay, plate = _frame_data(rendered, 1)
    out2 = read_image(rendered / "lowcam" / "0002.png")
    plain = plain_composite(render, "fire-i", plate)
    reach = (plain != plate).any(axis=2) | (overlay_in_frame(overlay, "fire-i")[..., 3] > 0)
    far = ~cv2.dilate(reach.astype(np.uint8), np.ones((41, 41), np.uint8)).astype(bool)
    assert far.mean() > 0.3
    assert np.array_equal(out1[far], plate[far]) and np.array_equal(out2[far], plate[far])
    core = cv2.erode((plain != plate).any(axis=2).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert core.sum() > 500
    # degraded, not the plain composite, and the noise differs between frames
    assert np.abs(out1[core].astype(float) - plain[core]).mean() > 2.0
    assert (out1[core] != out2[core]).mean() > 0.3


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
        blend = submodule("addon.sample").build_sample_scene(tmp_path, "fire-i-6bit", render_width=400, samples=8)
        out = read_image(submodule("addon.render").render(blend, [1], str(tmp_path / "out"),
                                                          keep_renders=str(tmp_path / "render"))[0])
    finally:
        del os.environ["LOWCAM_PROFILE_PATH"]
    import cv2

    render, overlay = read_layers(tmp_path / "render" / "0001.exr", "ViewLayer", OVERLAY_LAYER)
    plate = read_plate(tmp_path / "plate.png", 640, 480)
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
    # the sample camera pans at 0.6 rad/s about the world's vertical, its own up axis: our y (down) axis
    assert np.allclose(np.abs(m.angular_velocity), (0.0, 0.6, 0.0), atol=1e-4)
    assert m.exposure_s == pytest.approx(0.033)


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
