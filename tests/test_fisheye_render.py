"""Lenses wider than a pinhole render covers, rendered through Cycles' equidistant fisheye camera.

The fast tests check the engine's map from output pixels to the fisheye render against OpenCV's fisheye
(``cv2.fisheye.undistortPoints``) where OpenCV is defined (rays short of 90 degrees) and against the Kannala-Brandt
angle solved here by bisection beyond; the render's convention (Cycles' ``fisheye_to_direction`` with the
panoramic viewplane [0, 1] x [0, 1]: ``rho = theta / (fov / 2)`` of the half-width and half-height from the centre,
x right, y down on the written image) is written out here and checked against a real Cycles render in the Blender
tier (:func:`test_cycles_fisheye_render_shows_each_output_pixel_the_ray_its_lens_sees`). The lens is the published
GoPro HERO11 Wide Gyroflow profile (tests/test_gyroflow.py) on fire-i's 640x480 frame, about 151 deg across the
frame's diagonal, and a made-up 224 deg fisheye.
"""
import math

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

import lowcam
from lowcam.effects.bayer import sensel_shift_px
from lowcam.errors import LowcamError
from lowcam.gyroflow import profile_from_gyroflow
from lowcam.pipeline import render_camera, render_field_of_view, simulate
from lowcam.profile import BUNDLED_PROFILES

from test_gyroflow import GOPRO

#: OpenCV's fisheye solved to the end (its default stops after 10 steps)
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)


@pytest.fixture(scope="module")
def gopro(tmp_path_factory):
    """The GoPro HERO11 Wide (Gyroflow) on fire-i's 640x480 frame: a third of the calibration's 1920x1440."""
    path = tmp_path_factory.mktemp("gopro") / "gopro.json"
    import json
    path.write_text(json.dumps(GOPRO))
    profile, _ = profile_from_gyroflow(path, lowcam.load_profile("fire-i"), (640, 480))
    return profile


#: A made-up fisheye seeing 224 deg across the 640x480 frame's diagonal (its corner 111.9 deg from the axis).
WIDE = dict(model="fisheye", fx_px=215.0, fy_px=215.0, cx_px=319.5, cy_px=239.5, fisheye_k1=-0.02,
            fisheye_k2=0.002, fisheye_k3=0.0, fisheye_k4=0.0)


def _frame_samples(step=16):
    """Output pixels over the whole frame, border pixels' outer edges included (fire-i's 640x480)."""
    u = np.concatenate([[-0.5], np.arange(0, 640, step, dtype=np.float64), [639.5]])
    v = np.concatenate([[-0.5], np.arange(0, 480, step, dtype=np.float64), [479.5]])
    return [a.ravel() for a in np.meshgrid(u, v)]


def cycles_equidistant_pixel(theta, phi, fov, shape):
    """Where Cycles' equidistant fisheye of ``fov`` (rad) puts the ray (theta, phi) (phi from x right towards y
    down) in a render of ``shape`` (rows, cols), pixel centres on integers: the viewplane spans [0, 1] on both
    axes, ``rho = theta / (fov / 2)`` (Cycles' ``fisheye_to_direction``)."""
    rows, cols = shape
    rho = theta / (fov / 2)
    return (1 + rho * np.cos(phi)) * cols / 2 - 0.5, (1 + rho * np.sin(phi)) * rows / 2 - 0.5


def kb_angle(rd, k, upper):
    """The Kannala-Brandt angle with distorted radius ``rd``: bisection on ``theta (1 + k1 theta^2 + ...)``."""
    lo, hi = np.zeros_like(rd), np.full_like(rd, upper)
    for _ in range(80):
        mid = (lo + hi) / 2
        t2 = mid * mid
        below = mid * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) < rd
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return (lo + hi) / 2


def test_gopro_output_pixels_land_where_opencvs_fisheye_rays_lie_in_the_equidistant_render(gopro):
    """The GoPro sees about 151 deg across its frame: rendered through an equidistant fisheye (chosen
    automatically), each output pixel's render pixel is where OpenCV's fisheye ray lies in Cycles' equidistant
    mapping, within 0.05 px of a 512x512 render (measured: 2e-5 px); the frame's bottom corners, 80.0 and
    78.4 deg from the axis, lie just short of the 81.2 deg where this polynomial stops rising, and there OpenCV
    finds the root beyond the peak: the Kannala-Brandt angle is taken there. The render camera is square, its
    field the working grid's plus 2 %."""
    lens, g = gopro.effect("lens_distortion"), gopro.geometry
    assert lens.projection(g) == "fisheye_equidistant"
    fov = lens.render_fisheye_field(g)
    cam = render_camera(gopro, 512)
    assert cam["projection"] == "fisheye_equidistant" and (cam["width"], cam["height"]) == (512, 512)
    assert cam["hfov_deg"] == pytest.approx(math.degrees(fov)) and 160 < cam["hfov_deg"] < 170
    u, v = _frame_samples()
    x, y = lens.render_pixel_coordinates(g, u, v, (512, 512))
    p = GOPRO["fisheye_params"]
    calib = np.stack([(u + 0.5) * 3 - 0.5, (v + 0.5) * 3 - 0.5], -1)[:, None]   # 640x480 -> 1920x1440 pixels
    und = cv2.fisheye.undistortPoints(calib, np.array(p["camera_matrix"]), np.array(p["distortion_coeffs"]),
                                      criteria=CRITERIA)[:, 0]
    theta, phi = np.arctan(np.hypot(und[:, 0], und[:, 1])), np.arctan2(und[:, 1], und[:, 0])
    # OpenCV's Newton passes the peak of theta_d (81.2 deg) at the two bottom corners (80.0 and 78.4 deg, just
    # inside it): a second root, beyond the peak; there the Kannala-Brandt angle is solved here by bisection
    k = tuple(p["distortion_coeffs"])
    kk = np.array(p["camera_matrix"])
    rd = np.hypot((calib[:, 0, 0] - kk[0, 2]) / kk[0, 0], (calib[:, 0, 1] - kk[1, 2]) / kk[1, 1])
    rising = lens.model_for(640, 480).theta_rising()
    past_peak = theta > rising
    assert past_peak.sum() == 2
    theta[past_peak] = kb_angle(rd[past_peak], k, rising)
    assert np.degrees(theta.max()) > 79.9
    ex, ey = cycles_equidistant_pixel(theta, phi, fov, (512, 512))
    assert np.hypot(x - ex, y - ey).max() < 0.05


def test_a_fisheye_seeing_224_degrees_lands_on_the_kannala_brandt_angle_beyond_90(fire_i):
    """A fisheye seeing 224 deg: its render is an equidistant fisheye over 241 deg (a pinhole cannot hold rays
    at 90 deg and beyond); each output pixel's render pixel is the Kannala-Brandt angle's (bisection here) within
    0.05 px of a 512x512 render, and OpenCV's ray where OpenCV is defined (under 90 deg)."""
    profile = fire_i.with_effect("lens_distortion", replace=True, **WIDE)
    lens, g = profile.effect("lens_distortion"), profile.geometry
    assert lens.projection(g) == "fisheye_equidistant"
    fov = lens.render_fisheye_field(g)
    assert math.degrees(fov) > 240
    u, v = _frame_samples()
    x, y = lens.render_pixel_coordinates(g, u, v, (512, 512))
    k = (WIDE["fisheye_k1"], WIDE["fisheye_k2"], 0.0, 0.0)
    xd, yd = (u - 319.5) / 215.0, (v - 239.5) / 215.0
    theta = kb_angle(np.hypot(xd, yd), k, np.radians(150))
    phi = np.arctan2(yd, xd)
    assert np.degrees(theta.max()) > 111.8
    ex, ey = cycles_equidistant_pixel(theta, phi, fov, (512, 512))
    assert np.hypot(x - ex, y - ey).max() < 0.05
    inside = theta < np.radians(85)
    kk = np.array([[215.0, 0, 319.5], [0, 215.0, 239.5], [0, 0, 1]])
    und = cv2.fisheye.undistortPoints(np.stack([u, v], -1)[inside][:, None], kk, np.array(k + (0.0, 0.0))[:4],
                                      criteria=CRITERIA)[:, 0]
    ox, oy = cycles_equidistant_pixel(np.arctan(np.hypot(und[:, 0], und[:, 1])), np.arctan2(und[:, 1], und[:, 0]),
                                      fov, (512, 512))
    assert inside.sum() > 500 and np.hypot(x[inside] - ox, y[inside] - oy).max() < 0.05


def test_a_fisheye_render_may_have_any_size_and_its_field_may_be_given(gopro):
    """A 600x400 render of the same fisheye is stretched on both axes (Cycles spans its field across each), and
    a given field must cover the frame: a narrower one is refused in one line."""
    lens, g = gopro.effect("lens_distortion"), gopro.geometry
    u, v = _frame_samples(step=40)
    theta, phi = lens.model_for(640, 480).undistort_ray(u, v)
    x, y = lens.render_pixel_coordinates(g, u, v, (400, 600))
    ex, ey = cycles_equidistant_pixel(theta, phi, lens.render_fisheye_field(g), (400, 600))
    assert np.hypot(x - ex, y - ey).max() < 1e-3
    given = gopro.with_effect("lens_distortion", render_hfov_deg=190.0)
    assert given.effect("lens_distortion").render_fisheye_field(g) == pytest.approx(math.radians(190.0))
    assert render_camera(given, 400)["hfov_deg"] == pytest.approx(190.0)
    narrow = gopro.with_effect("lens_distortion", render_hfov_deg=140.0)
    with pytest.raises(LowcamError, match=r"render_hfov_deg = 140.0 is narrower than the 16\d\.\d deg the frame sees"):
        render_camera(narrow, 400)


def test_the_pinhole_paths_refuse_a_fisheye_render_and_the_pinhole_choice_keeps_todays_render(gopro, fire_i):
    """What needs a pinhole render (its field of view, its focal length for defocus from depth) refuses a fisheye render in one line naming the way out; ``render_projection = "pinhole"`` gives the
    pinhole render of before; a pinhole render of 180 deg is refused; every bundled profile stays a pinhole."""
    g = gopro.geometry
    with pytest.raises(LowcamError, match="needs a pinhole render, and this lens is rendered through an "
                                          r"equidistant fisheye \(16\d\.\d deg\): set render_projection"):
        render_field_of_view(gopro)
    with pytest.raises(LowcamError, match="focal length .defocus from depth. needs a pinhole"):
        gopro.effect("lens_distortion").render_focal_px(g, 512, 512)
    pinhole = gopro.with_effect("lens_distortion", render_projection="pinhole")
    cam = render_camera(pinhole, 640)
    assert cam["projection"] == "pinhole" and 150 < cam["hfov_deg"] < 180 and cam["height"] == 480
    with pytest.raises(LowcamError, match="render_hfov_deg = 185.0: a pinhole render's field is under 180 deg"):
        render_camera(pinhole.with_effect("lens_distortion", render_hfov_deg=185.0), 640)
    with pytest.raises(LowcamError, match="folds over inside the frame .its radius stops rising at 89.9 deg"):
        fire_i.with_effect("lens_distortion", replace=True, render_projection="pinhole", **WIDE)
    for path in sorted(BUNDLED_PROFILES.glob("*.toml")):
        p = lowcam.load_profile(path)
        assert p.effect("lens_distortion").projection(p.geometry) == "pinhole", path.name


def test_the_chain_puts_a_fisheye_renders_object_where_the_lens_sees_it(gopro):
    """A small white square (7 px, exact coverage) in a 512x512 equidistant render at the ray 62 deg from the axis,
    down-right, comes out of the lens stage (sparse render, windowed warp) where the lens puts that ray, within 0.05
    output px (the working grid laid out on the sensor: moved by ``sensel_shift_px``, where the Fire-i's 2x2 blocks
    deliver a sensel), and the whole chain runs on to the 8-bit frame, where it shows there too (within 1.5 px: the
    Fire-i's 4:1:1 chroma and blur move it a little)."""
    lens, g = gopro.effect("lens_distortion"), gopro.geometry
    fov = lens.render_fisheye_field(g)
    theta, phi = np.radians(62.0), np.radians(30.0)
    cx, cy = cycles_equidistant_pixel(theta, phi, fov, (512, 512))
    pixels = np.arange(512.0)
    cover_x = np.clip(np.minimum(pixels + 0.5, cx + 3.5) - np.maximum(pixels - 0.5, cx - 3.5), 0, 1)
    cover_y = np.clip(np.minimum(pixels + 0.5, cy + 3.5) - np.maximum(pixels - 0.5, cy - 3.5), 0, 1)
    render = np.repeat((cover_y[:, None] * cover_x[None, :])[..., None], 4, axis=-1).astype(np.float32)
    expected = np.array(lens.model_for(640, 480).distort_ray(theta, phi), np.float64).ravel()

    def centroid(weights, to_output):
        rows, cols = np.mgrid[0:weights.shape[0], 0:weights.shape[1]]
        x, y = (weights * cols).sum() / weights.sum(), (weights * rows).sum() / weights.sum()
        return np.array(to_output(x, y), np.float64)

    result = lowcam.run(render, gopro, np.zeros((480, 640, 3), np.uint8), seed=1, keep_stages=True)
    working = next(out for name, out in result.stages.items() if name.endswith("lens_distortion"))
    seen = centroid(working[..., 3].astype(np.float64), g.working_to_output) + sensel_shift_px(gopro)
    assert np.hypot(*(seen - expected)) < 0.05
    frame = result.frame.astype(np.float64).mean(axis=-1)
    frame[frame < 0.3 * frame.max()] = 0.0
    assert np.hypot(*(centroid(frame, lambda x, y: (x, y)) - expected)) < 1.5




def test_the_node_groups_lens_map_reads_the_fisheye_render(gopro):
    """The compositor node group's Map UV image (``lens_uv``) for a 256x256 fisheye render reads, at each
    supersampled working pixel (moved by ``sensel_shift_px``: the grid is laid out on the sensor), the render pixel
    of Cycles' mapping of OpenCV-free Kannala-Brandt rays (the model's ``undistort_ray``): within 1e-4 of a render
    pixel (float32 UV)."""
    from types import SimpleNamespace

    from lowcam.node_maps import CameraBake

    g = gopro.geometry
    out = CameraBake(gopro, (256, 256), stages=["lens_distortion"])
    gopro.effect("lens_distortion").bake_node(SimpleNamespace(geometry=g, profile=gopro), out)   # what bake() calls
    uv = out.images["lens_uv"]
    u, v = g.working_pixel_centres(factor=2)
    u, v = u + sensel_shift_px(gopro)[0], v + sensel_shift_px(gopro)[1]
    theta, phi = gopro.effect("lens_distortion").model_for(640, 480).undistort_ray(u[::7, ::7], v[::7, ::7])
    ex, ey = cycles_equidistant_pixel(theta, phi, gopro.effect("lens_distortion").render_fisheye_field(g), (256, 256))
    assert uv.shape[:2] == u.shape
    assert np.abs(uv[::7, ::7, 0] * 256 - 0.5 - ex).max() < 1e-4
    assert np.abs((1 - uv[::7, ::7, 1]) * 256 - 0.5 - ey).max() < 1e-4


def _kb_pixels(d, fx, cx, cy, k):
    """Output pixels of directions ``d`` (..., 3) through a Kannala-Brandt lens (fx = fy), its formula."""
    theta = np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2])
    phi = np.arctan2(d[..., 1], d[..., 0])
    t2 = theta ** 2
    rd = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
    return cx + fx * rd * np.cos(phi), cy + fx * rd * np.sin(phi)


def _kb_directions(u, v, fx, cx, cy, k):
    theta = kb_angle(np.hypot((u - cx) / fx, (v - cy) / fx), k, np.radians(150))
    phi = np.arctan2(v - cy, u - cx)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def test_the_camera_turning_is_followed_beyond_90_degrees(fire_i):
    """The 224 deg fisheye turning at w: the motion blur's taps and the rolling shutter's offsets are where its
    formula puts each pixel's turned ray (rotations by cv2.Rodrigues), within 1e-6 px, rays beyond 90 deg
    included (a pinhole camera plane cannot carry them: there it is off by pixels)."""
    from lowcam.effects.motion_blur import tap_offsets

    profile = fire_i.with_effect("lens_distortion", replace=True, **WIDE).with_effect("rolling_shutter",
                                                                                     readout_s=0.03)
    w = np.array([0.9, -1.7, 2.3])
    fx, cx, cy, k = 215.0, 319.5, 239.5, (WIDE["fisheye_k1"], WIDE["fisheye_k2"], 0.0, 0.0)
    u = np.array([-0.5, 20.0, 320.0, 639.5, 600.0])
    v = np.array([-0.5, 460.0, 240.0, 479.5, 30.0])
    d = _kb_directions(u, v, fx, cx, cy, k)
    assert np.degrees(np.arccos(d[:, 2])).max() > 100
    times = (np.arange(4) + 0.5) / 4 * 0.02 - 0.01
    turned = np.stack([d @ cv2.Rodrigues(w * t)[0].T for t in times], 1)
    eu, ev = _kb_pixels(turned, fx, cx, cy, k)
    expected = np.stack([eu - u[:, None], ev - v[:, None]], -1)
    taps = tap_offsets(profile.lens, u, v, w, 0.02, 4, wide=True)
    assert np.abs(taps - expected).max() < 1e-6
    assert np.abs(tap_offsets(profile.lens, u, v, w, 0.02, 4) - expected).max() > 1.0      # the camera plane
    state = lowcam.run(np.zeros((512, 512, 4), np.float32), profile, angular_velocity=w, exposure_s=0.02,
                       stop_after="rolling_shutter").state
    g = profile.geometry
    from lowcam.geometry import grid_points
    gu, gv = grid_points(g.working_extent)
    gd = _kb_directions(gu, gv, fx, cx, cy, k)
    rot = np.stack([cv2.Rodrigues(w * t)[0] for t in ((gv / g.height - 0.5) * 0.03).ravel()]).reshape(gu.shape + (3, 3))
    ru, rv = _kb_pixels(np.einsum("...ij,...j->...i", rot, gd), fx, cx, cy, k)
    shutter = np.stack([ru - gu, rv - gv], -1)
    blur = tap_offsets(profile.lens, gu, gv, w, 0.02, 16, wide=True)
    assert np.abs(state.motion_taps - blur.reshape(blur.shape[:2] + (-1,))).max() < 1e-3
    assert np.abs(state.sampling_offset - shutter).max() < 1e-3                            # float32
    assert np.degrees(np.arccos(gd[..., 2])).max() > 100


def test_object_motion_leaves_what_the_fisheye_cameras_turning_explains(gopro):
    """Object motion under a fisheye render: the camera's own image velocity is the equidistant one, which a
    finite difference of Cycles' mapping (rotations by cv2.Rodrigues) gives within 1e-3 px/s; a velocity pass
    holding just that leaves the render as it was, and one with an object's own motion smears it."""
    from lowcam.effects.object_motion import fisheye_rotation_velocity
    from lowcam.passes import RenderPasses

    lens, g = gopro.effect("lens_distortion"), gopro.geometry
    fov, shape, w = lens.render_fisheye_field(g), (96, 128), np.array([0.4, -1.1, 0.8])
    velocity = fisheye_rotation_velocity(w, fov, shape)
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    a, b = (cols + 0.5) * 2 / shape[1] - 1, (rows + 0.5) * 2 / shape[0] - 1
    theta, phi = np.hypot(a, b) * fov / 2, np.arctan2(b, a)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    dt = 1e-4
    ends = []
    for t in (-dt, dt):
        seen = d @ cv2.Rodrigues(-w * t)[0].T               # a static direction is seen at R(-t) d
        x, y = cycles_equidistant_pixel(np.arccos(np.clip(seen[..., 2], -1, 1)),
                                        np.arctan2(seen[..., 1], seen[..., 0]), fov, shape)
        ends.append(np.stack([x, y], -1))
    assert np.abs(velocity - (ends[1] - ends[0]) / (2 * dt)).max() < 1e-3
    assert np.abs(velocity).max() > 50
    profile = gopro.with_effect("object_motion")
    render = np.zeros((512, 512, 4), np.float32)
    render[200:260, 300:330] = 0.8
    still = fisheye_rotation_velocity(w, fov, (512, 512))

    def first_stage(velocity_px_s):
        return lowcam.run(render, profile, angular_velocity=w, exposure_s=0.02, keep_stages=True,
                          stop_after="object_motion",
                          passes=RenderPasses(velocity_px_s=velocity_px_s)).stages["00-object_motion"]

    assert np.array_equal(first_stage(still), render)
    moving = still + np.array([400.0, 0.0], np.float32)
    assert np.abs(first_stage(moving) - render).max() > 0.1


def _ray_render(profile_path, folder, width=384):
    """Cycles (CPU, 1 sample, a 0.01 px Gaussian filter: each pixel's centre) renders a world whose colour encodes
    the incoming direction (Geometry's Incoming, 0.5 + 0.5 I) through the camera the add-on sets up for the
    profile (Set Up Scene's :func:`setup_render_camera`), the camera at the origin looking down -Z, Y up; returns
    the render (premultiplied RGBA, rows top down) and the render camera."""
    import bpy

    from lowcam.io import read_render
    from lowcam_blender import submodule

    frames = submodule("addon.frames")
    submodule("addon.render")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0))
    scene.camera = bpy.context.object
    scene.lowcam.profile_file = str(profile_path)
    cam = frames.setup_render_camera(scene, width)
    assert (scene.camera.data.type, scene.camera.data.panorama_type) == ("PANO", "FISHEYE_EQUIDISTANT")
    assert scene.camera.data.fisheye_fov == pytest.approx(math.radians(cam["hfov_deg"]), rel=1e-6)
    scene.render.film_transparent = False                  # the world is what the test looks at
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = "CPU", 1, False, False
    c.pixel_filter_type, c.filter_width, scene.render.filter_size = "GAUSSIAN", 0.01, 0.01   # (a box is 1 px wide)
    world = bpy.data.worlds.new("rays")
    if world.node_tree is None:  # Blender 4 (5 gives each its nodes)
        world.use_nodes = True
    tree = world.node_tree
    encode = tree.nodes.new("ShaderNodeVectorMath")
    encode.operation = "MULTIPLY_ADD"
    encode.inputs[1].default_value = encode.inputs[2].default_value = (0.5, 0.5, 0.5)
    tree.links.new(tree.nodes.new("ShaderNodeNewGeometry").outputs["Incoming"], encode.inputs[0])
    tree.links.new(encode.outputs["Vector"], tree.nodes["Background"].inputs["Color"])
    scene.world = world
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_depth, settings.color_mode = "OPEN_EXR", "32", "RGBA"
    scene.render.filepath = str(folder / "rays.exr")
    bpy.ops.render.render(write_still=True)
    return read_render(folder / "rays.exr"), cam


@pytest.mark.blender
@pytest.mark.slow
@pytest.mark.parametrize("lens", ["gopro", "wide"])
def test_cycles_fisheye_render_shows_each_output_pixel_the_ray_its_lens_sees(lens, gopro, fire_i, tmp_path):
    """Real Cycles through the add-on's fisheye camera (384x384): the engine's map from each output pixel into
    the render reads there (bilinear, exact) the direction that OpenCV's fisheye (``cv2.fisheye.distortPoints``; the
    Kannala-Brandt formula beyond 89 deg) puts back on that pixel within 0.01 px (measured: 0.003 px at most over
    5084 pixels). The GoPro (151 deg across the frame) and the 224 deg fisheye; this is the check of Cycles'
    convention (field across width and height, x right and y up from the centre, the ray opposite the Incoming
    vector)."""
    profile = gopro if lens == "gopro" else fire_i.with_effect("lens_distortion", replace=True, **WIDE)
    profile.save(tmp_path / "lens.toml")
    render, cam = _ray_render(tmp_path / "lens.toml", tmp_path)
    effect, g = profile.effect("lens_distortion"), profile.geometry
    assert cam["projection"] == "fisheye_equidistant" and render.shape[:2] == (384, 384)
    u, v = _frame_samples(step=8)
    x, y = effect.render_pixel_coordinates(g, u, v, render.shape[:2])
    # bilinear at the engine's map (exact: cv2.remap, the engine's, rounds positions to 1/32 px, 0.02 px here)
    seen = np.stack([map_coordinates(render[..., i].astype(np.float64), [y, x], order=1) for i in range(3)], -1)
    ray = -(2 * seen - 1)                                   # Incoming points back along the ray
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    right, down, forward = ray[:, 0], -ray[:, 1], -ray[:, 2]   # Blender's camera: X right, Y up, looking down -Z
    theta, phi = np.arctan2(np.hypot(right, down), forward), np.arctan2(down, right)
    fx, fy, cx, cy = effect.model_for(640, 480).pinhole_intrinsics()
    k = np.array([effect.fisheye_k1, effect.fisheye_k2, effect.fisheye_k3, effect.fisheye_k4])
    t2 = theta ** 2
    rd = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))      # Kannala-Brandt
    back = np.stack([cx + fx * rd * np.cos(phi), cy + fy * rd * np.sin(phi)], -1)
    short = theta < np.radians(89)
    kk = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    plane = np.stack([right / forward, down / forward], -1)[short][:, None]
    back[short] = cv2.fisheye.distortPoints(plane, kk, k)[:, 0]
    error = np.hypot(back[:, 0] - u, back[:, 1] - v)
    assert np.degrees(theta.max()) > (79 if lens == "gopro" else 111.8)
    assert error.max() < 0.01, (error.max(), np.percentile(error, 99))


@pytest.mark.blender
def test_set_up_scene_refuses_eevee_for_a_lens_rendered_through_a_fisheye(gopro, tmp_path):
    """EEVEE has no panoramic camera: Set Up Scene refuses it in one line for the GoPro, and leaves a pinhole
    profile's camera a perspective one of the field the engine needs."""
    import bpy

    from lowcam_blender import submodule

    frames = submodule("addon.frames")
    submodule("addon.render")
    gopro.save(tmp_path / "gopro.toml")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_EEVEE"
    bpy.ops.object.camera_add()
    scene.camera = bpy.context.object
    scene.lowcam.profile_file = str(tmp_path / "gopro.toml")
    with pytest.raises(LowcamError, match=r"^EEVEE has no panoramic camera, .* Cycles' fisheye \(16\d\.\d deg\); set "
                                          "the render engine to Cycles$"):
        frames.setup_render_camera(scene, 256)
    assert scene.camera.data.type == "PERSP"
    scene.camera.data.type = "PANO"
    scene.lowcam.profile_file = ""
    scene.lowcam.profile = "fire-i"
    cam = frames.setup_render_camera(scene, 256)
    assert cam["projection"] == "pinhole" and scene.camera.data.type == "PERSP"
    assert scene.camera.data.angle == pytest.approx(math.radians(cam["hfov_deg"]), rel=1e-6)
