"""Composites registered to the calibration: a direction lands in the delivered frame where OpenCV's projection of
the profile's calibration puts it (``cv2.fisheye.projectPoints`` at the calibration's size, scaled to the frame:
``u' = (u + 1/2) s - 1/2``).

The profiles are made by ``lowcam profile from-gyroflow`` from two published Gyroflow calibrations (CC0, from
https://github.com/gyroflow/lens_profiles) on the Fire-i's sensor and processing, whose 2x2-block demosaicing
moves the picture half a pixel left and down: a Google Pixel 8 (25 mm, 2048x1536, about 70 deg across, rendered
through a pinhole) and the GoPro HERO11 Wide of tests/test_gyroflow.py (about 151 deg across the diagonal,
rendered through Cycles' equidistant fisheye). The fast tests draw small Gaussian spots into the render by the
render conventions written out here (a centred pinhole; Cycles' ``fisheye_to_direction``) and run the engine; the
Blender test renders small emissive spheres with Cycles through ``lowcam render``. Each measures the spots' green
centroids in the composite. The demosaicing methods' own shifts are measured on spots sampled at the sensels.
"""
import json
import math

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.cli import main
from lowcam.effects.bayer import DEMOSAIC_SHIFT_PX, DEMOSAICERS, sensel_shift_px
from lowcam.geometry import FrameGeometry
from lowcam.pipeline import render_camera, run
from lowcam.profile import BUNDLED_PROFILES

from test_fisheye_render import cycles_equidistant_pixel
from test_gyroflow import GOPRO

#: Google Pixel 8, 25 mm, full sensor (MotionCam), 2048x1536 at 24 fps, calibrated by Sebastijan: Gyroflow's
#: "Google_Pixel 8_25mm_Full sensor motioncam_2k_4by3_2048x1536-24.00fps.json" (its numbers as published).
PIXEL8 = {
    "name": "Google_Pixel 8_25mm_Full sensor motioncam_2k_4by3_2048x1536-24.00fps", "calibrated_by": "Sebastijan",
    "camera_brand": "Google", "camera_model": "Pixel 8", "lens_model": "25mm",
    "camera_setting": "Full sensor motioncam",
    "calib_dimension": {"w": 2048, "h": 1536}, "frame_readout_time": 4.53, "fps": 24.003803,
    "fisheye_params": {"RMS_error": 0.47685433223703094,
                       "camera_matrix": [[1446.401372515127, 0.0, 1019.9445843158144],
                                         [0.0, 1446.7100680036383, 757.8567673115901], [0.0, 0.0, 1.0]],
                       "distortion_coeffs": [0.6673209853824125, -2.6536128952101654, 9.15039124447416,
                                             -9.745242310487429]},
}
#: (Gyroflow file, the render's projection, the widest ray drawn (deg))
LENSES = {"pixel8": (PIXEL8, "pinhole", 38.0), "gopro": (GOPRO, "fisheye_equidistant", 70.0)}
#: The most the spots' mean may lie from OpenCV's projection (px), and any one spot.
MEAN_PX, EACH_PX = 0.1, 0.3


def small_fire_i(folder, width=320, height=240):
    """The Fire-i's sensor and processing on a ``width`` x ``height`` frame (a quarter of its pixels: the lens maps
    of a Kannala-Brandt lens take a quarter of the time), saved in ``folder``; its path."""
    text = (BUNDLED_PROFILES / "fire-i.toml").read_text()
    text = text.replace('texture = "fire-i/', f'texture = "{BUNDLED_PROFILES}/fire-i/')
    text = text.replace("width = 640", f"width = {width}").replace("height = 480", f"height = {height}")
    path = folder / "fire-i-small.toml"
    path.write_text(text)
    assert lowcam.load_profile(path).geometry.width == width
    return path


def gyroflow_profile(folder, lens: str, base="fire-i"):
    """The profile ``lowcam profile from-gyroflow`` makes of ``lens`` (a key of :data:`LENSES`) on ``base`` (a
    name or a file), without its noise and quantisation, saved as ``folder/<lens>.toml``: (profile, path)."""
    path = folder / f"{lens}.json"
    path.write_text(json.dumps(LENSES[lens][0]))
    made = folder / f"{lens}-made.toml"
    frame = lowcam.load_profile(base).geometry  # made at the base's frame (not the calibration's 2048 or 4000 px)
    assert main(["profile", "from-gyroflow", str(path), "--base", str(base), "--size", f"{frame.width},{frame.height}",
                 "-o", str(made)]) == 0
    profile = lowcam.load_profile(made).quiet()
    return profile, profile.save(folder / f"{lens}.toml")


def directions(lens: str, rings=4, per_ring=8, frame=(640, 480), margin_px=12):
    """Unit rays (n, 3), camera frame (x right, y down, z forward): the axis and ``rings`` rings of ``per_ring``
    rays out to the lens's widest drawn angle, each ring turned by half a step from the last; those OpenCV puts
    at least ``margin_px`` inside a ``frame`` (w, h)."""
    widest = math.radians(LENSES[lens][2])
    theta = [0.0] + [widest * (i + 1) / rings for i in range(rings) for _ in range(per_ring)]
    phi = [0.0] + [2 * math.pi * (j + 0.5 * (i % 2)) / per_ring for i in range(rings) for j in range(per_ring)]
    theta, phi = np.array(theta), np.array(phi)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    u, v = opencv_pixels(lens, rays, frame).T
    return rays[(u >= margin_px) & (u <= frame[0] - 1 - margin_px) & (v >= margin_px) & (v <= frame[1] - 1 - margin_px)]


def opencv_pixels(lens: str, rays, frame=(640, 480), distortion=True):
    """Where OpenCV's fisheye projection of the Gyroflow calibration puts ``rays`` at its own size, scaled to a
    ``frame`` (w, h) of the same aspect ratio (pixel centres on integers); without ``distortion``, the pinhole of
    its camera matrix (``cv2.projectPoints``)."""
    doc = LENSES[lens][0]
    p = doc["fisheye_params"]
    if distortion:
        pts, _ = cv2.fisheye.projectPoints(rays[:, None].astype(np.float64), np.zeros(3), np.zeros(3),
                                           np.array(p["camera_matrix"]), np.array(p["distortion_coeffs"]))
    else:
        pts, _ = cv2.projectPoints(rays[:, None].astype(np.float64), np.zeros(3), np.zeros(3),
                                   np.array(p["camera_matrix"]), np.zeros(5))
    scale = frame[0] / doc["calib_dimension"]["w"]
    return (pts[:, 0] + 0.5) * scale - 0.5


def green_centroids(frame, expected, radius=6):
    """The centroid of the green channel above its window's border level within ``radius`` px of each of
    ``expected`` (n, 2) (u, v) in ``frame``; (n, 2)."""
    g = frame[..., 1].astype(np.float64)
    out = []
    for u, v in expected:
        iu, iv = int(round(u)), int(round(v))
        win = g[iv - radius:iv + radius + 1, iu - radius:iu + radius + 1]
        border = np.concatenate([win[0], win[-1], win[:, 0], win[:, -1]])
        w = np.clip(win - np.median(border), 0, None)
        yy, xx = np.mgrid[iv - radius:iv + radius + 1, iu - radius:iu + radius + 1]
        out.append(((w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()))
    return np.array(out)


def spot_render(cam, rays, sigma_px=1.6):
    """A render of ``cam`` (:func:`lowcam.pipeline.render_camera`) holding a green Gaussian spot (``sigma_px``
    render px) at each ray: a centred pinhole (``u = f x / z + W / 2 - 1/2``, ``f = W / (2 tan(hfov / 2))``) or
    Cycles' equidistant fisheye (``cycles_equidistant_pixel``)."""
    w, h = cam["width"], cam["height"]
    if cam["projection"] == "pinhole":
        f = w / (2 * math.tan(math.radians(cam["hfov_deg"]) / 2))
        ru, rv = f * rays[:, 0] / rays[:, 2] + w / 2 - 0.5, f * rays[:, 1] / rays[:, 2] + h / 2 - 0.5
    else:
        theta = np.arccos(np.clip(rays[:, 2], -1, 1))
        ru, rv = cycles_equidistant_pixel(theta, np.arctan2(rays[:, 1], rays[:, 0]), math.radians(cam["hfov_deg"]),
                                          (h, w))
    render = np.zeros((h, w, 4), np.float32)
    for a, b in zip(ru, rv):
        x0, y0 = int(a) - 8, int(b) - 8
        yy, xx = np.mgrid[y0:y0 + 17, x0:x0 + 17]
        spot = np.exp(-((xx - a) ** 2 + (yy - b) ** 2) / (2 * sigma_px ** 2)).astype(np.float32)
        render[y0:y0 + 17, x0:x0 + 17, 1] += 0.6 * spot
        render[y0:y0 + 17, x0:x0 + 17, 3] += spot
    render[..., 3] = np.minimum(render[..., 3], 1.0)
    return render


def offsets(lens, profile, frame, rays):
    """Each ray's green centroid in ``frame`` minus OpenCV's projection (n, 2) (without distortion where the
    profile's lens stage is off)."""
    distortion = profile.effect("lens_distortion").enabled
    expected = opencv_pixels(lens, rays, (profile.camera.width, profile.camera.height), distortion)
    return green_centroids(frame, expected) - expected


def check_registered(lens, profile, render_width=1024):
    """Spots at :func:`directions` drawn into a render of ``render_width`` px through ``profile``'s render camera
    land, in the delivered frame, where OpenCV projects the calibration: the mean within :data:`MEAN_PX`, each within
    :data:`EACH_PX`. Returns the offsets."""
    frame_size = (profile.camera.width, profile.camera.height)
    rays = directions(lens, frame=frame_size, margin_px=6 if frame_size[0] < 640 else 12)
    cam = render_camera(profile, render_width)
    d = offsets(lens, profile, run(spot_render(cam, rays), profile).frame, rays)
    method = profile.effect("demosaic").method
    assert np.hypot(*d.mean(0)) <= MEAN_PX, (method, d.mean(0))
    assert np.hypot(d[:, 0], d[:, 1]).max() <= EACH_PX, (method, np.abs(d).max(0))
    return d


def test_each_demosaicing_moves_a_spot_by_its_declared_shift():
    """A small Gaussian spot sampled at every sensel's own pixel, demosaiced: its centroid in each colour moves by
    the method's :data:`DEMOSAIC_SHIFT_PX` within 0.02 px (the Fire-i's blocks: half a pixel left and down, as
    each sensel fills the block it is the top-right corner of; the interpolating methods: none). Every method
    declares one."""
    assert set(DEMOSAIC_SHIFT_PX) == set(DEMOSAICERS)
    g = FrameGeometry(64, 48)
    pos = g.sensel_positions
    yy, xx = np.mgrid[0:48, 0:64]
    for method, demosaic in DEMOSAICERS.items():
        for centre in ((30.3, 21.8), (33.0, 24.5)):
            planes = 40 + 200 * np.exp(-((pos[..., 0] - centre[0]) ** 2 + (pos[..., 1] - centre[1]) ** 2) / 8.0)
            out = demosaic(planes.astype(np.float32), g) - 40
            for c in range(3):
                w = out[..., c]
                seen = np.array([(w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()]) - centre
                assert np.abs(seen - DEMOSAIC_SHIFT_PX[method]).max() < 0.02, (method, c, seen)


@pytest.mark.parametrize("lens", sorted(LENSES))
def test_the_engine_delivers_each_ray_where_opencv_projects_the_calibration(lens, tmp_path):
    """The profile ``from-gyroflow`` makes on the Fire-i's sensor (2x2 blocks; at 320x240): spots drawn into the
    render at the directions the frame sees (the Pixel 8 through a pinhole render, the GoPro through Cycles'
    equidistant fisheye) have their green centroids where ``cv2.fisheye.projectPoints`` puts them, the mean within
    0.1 px (measured: 0.003 px) and each within 0.3 px (measured: 0.04 px). Before the lens stage laid the
    working grid out where the blocks deliver each sensel, every spot lay (-0.5, +0.5) px off. With bilinear
    demosaicing each sensel is delivered at its own pixel, and the spots lie as close."""
    block, _ = gyroflow_profile(tmp_path, lens, small_fire_i(tmp_path))
    assert render_camera(block)["projection"] == LENSES[lens][1]
    for profile in (block, block.with_effect("demosaic", method="bilinear")):
        method = profile.effect("demosaic").method
        assert sensel_shift_px(profile) == ((-0.5, 0.5) if method == "block" else (0.0, 0.0))
        check_registered(lens, profile, render_width=640)


def sphere_scene(folder, profile_path, lens, rays, render_width=640, samples=16, distance_m=10.0):
    """A .blend whose camera (at the origin, looking down -Z, Y up) sees a small emissive green sphere at each of
    ``rays`` (camera frame: x right, y down, z forward), ``distance_m`` away and about 1.2 output px in radius,
    through ``profile_path`` with a black plate and no camera motion; Cycles on the CPU, ``samples`` samples, a
    ``render_width`` px render. Returns its path."""
    import bpy

    from lowcam_blender import submodule

    submodule("addon.frames")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = "CPU", samples, False, False
    scene.render.resolution_x = render_width
    material = bpy.data.materials.new("spot")
    if material.node_tree is None:         # Blender 4 (5 gives every material its nodes)
        material.use_nodes = True
    tree = material.node_tree
    tree.nodes.clear()
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (0.15, 0.6, 0.15, 1.0)
    tree.links.new(emission.outputs["Emission"], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    profile = lowcam.load_profile(profile_path)
    radius = distance_m * 1.2 / profile.effect("lens_distortion").fx_px
    for x, y, z in rays:
        bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=(distance_m * x, -distance_m * y,
                                                                      -distance_m * z), segments=32, ring_count=16)
        bpy.context.object.data.materials.append(material)
    bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0))
    scene.camera = bpy.context.object
    s = scene.lowcam
    s.profile_file = str(profile_path)
    s.plate_source, s.motion_source = "NONE", "NONE"
    path = folder / "spheres.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


@pytest.mark.blender
@pytest.mark.parametrize("lens", sorted(LENSES))
def test_lowcam_render_delivers_each_sphere_where_opencv_projects_the_calibration(lens, tmp_path):
    """Real Cycles through ``lowcam render``: small emissive spheres at the directions the frame sees, filmed
    through the profile ``from-gyroflow`` makes on the Fire-i's sensor (2x2 blocks; 320x240, 16 samples) by the
    camera Set Up Scene gives it (the Pixel 8: a pinhole render; the GoPro: Cycles' equidistant fisheye). Their
    green centroids lie where ``cv2.fisheye.projectPoints`` puts the directions, the mean within 0.1 px (measured:
    0.01 px) and each within 0.3 px (measured: 0.15 px). Before the lens stage laid the working grid out where
    the blocks deliver each sensel, they lay (-0.5, +0.5) px off on both paths."""
    from lowcam.io import read_image

    profile, path = gyroflow_profile(tmp_path, lens, small_fire_i(tmp_path))
    assert render_camera(profile)["projection"] == LENSES[lens][1]
    rays = directions(lens, frame=(320, 240), margin_px=6)
    blend = sphere_scene(tmp_path, path, lens, rays)
    out = tmp_path / "out"
    assert main(["render", str(blend), "--frames", "1", "-o", str(out)]) == 0
    frame = read_image(out / "0001.png")
    assert frame.shape == (240, 320, 3)
    d = offsets(lens, profile, frame, rays)
    print(lens, "mean", d.mean(0), "largest", np.hypot(*d.T).max())
    assert np.hypot(*d.mean(0)) <= MEAN_PX, d.mean(0)
    assert np.hypot(*d.T).max() <= EACH_PX, np.abs(d).max(0)
