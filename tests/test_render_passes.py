"""Object motion from a velocity pass and defocus from a depth pass (beyond the paper, Fig. 15), on the engine."""
import numpy as np
import pytest

import lowcam
from lowcam.effects.lens_models import PinholeLens
from lowcam.effects.motion_blur import tap_offsets
from lowcam.effects.object_motion import rotation_velocity
from lowcam.errors import LowcamError
from lowcam.passes import RenderPasses
from lowcam.pipeline import render_focal_px

ROWS, COLS = 600, 800


def _square(top=250, left=350, size=100):
    render = np.zeros((ROWS, COLS, 4), np.float32)
    render[top:top + size, left:left + size] = 1.0
    return render


def _render_stage(profile, render, passes, stage, **kw):
    return lowcam.run(render, profile, passes=passes, stop_after=stage, **kw).state.render


def test_rotation_velocity_is_how_fast_static_points_cross_the_image():
    """Minus the rate at which a pixel's line of sight sweeps over the mid-exposure image (motion_blur's taps)."""
    focal = 262.0
    lens = PinholeLens(COLS, ROWS, focal, focal, COLS / 2 - 0.5, ROWS / 2 - 0.5)
    w = (0.2, 0.6, 0.3)
    u, v = np.meshgrid(np.arange(0, COLS, 100.0), np.arange(0, ROWS, 100.0))
    dt = 1e-4
    taps = tap_offsets(lens, u, v, w, dt, 2)                       # at -dt/4 and +dt/4
    sweep = (taps[..., 1, :] - taps[..., 0, :]) / (dt / 2)
    velocity = rotation_velocity(w, focal, (ROWS, COLS))[v.astype(int), u.astype(int)]
    assert np.abs(velocity + sweep).max() < 1e-3 * np.abs(sweep).max()
    assert rotation_velocity((0, 0.6, 0), focal, (ROWS, COLS))[ROWS // 2, COLS // 2, 0] < 0   # pan right: moves left


def test_a_moving_square_is_smeared_over_its_path_during_the_exposure(fire_i):
    render = _square()
    render[100:140, 100:140] = 0.5                                  # a still object
    velocity = np.zeros((ROWS, COLS, 2), np.float32)
    velocity[250:350, 350:450] = (1500.0, 0.0)                      # px/s: 49.5 px over 0.033 s
    out = _render_stage(fire_i.with_effect("object_motion"), render, RenderPasses(velocity), "object_motion")
    row = out[300, :, 3]
    covered = np.nonzero(row > 1e-6)[0]
    assert covered.min() == 350 - 25 and covered.max() == 449 + 25   # half the path each way
    assert row.sum() == pytest.approx(100.0, rel=1e-5)               # nothing is lost or made
    ramp = row[326:374]
    assert np.allclose(np.diff(ramp), 1 / 49.5, atol=2e-3)           # a box over the path: linear edges
    assert np.array_equal(out[100:140, 100:140], render[100:140, 100:140])
    swept = np.zeros((ROWS, COLS), bool)
    swept[250:350, 325:475] = True
    assert np.array_equal(out[~swept], render[~swept])              # nothing else moves


def test_velocity_the_camera_rotation_explains_is_left_to_motion_blur(fire_i):
    """A static scene's velocity pass under a turning camera is all rotation: object motion changes nothing."""
    w = (0.1, 0.6, 0.2)
    velocity = rotation_velocity(w, render_focal_px(fire_i, COLS, ROWS), (ROWS, COLS))
    render = _square()
    profile = fire_i.with_effect("object_motion")
    assert np.array_equal(_render_stage(profile, render, RenderPasses(velocity), "object_motion", angular_velocity=w),
                          render)
    moved = _render_stage(profile, render, RenderPasses(velocity), "object_motion")   # camera still: it moved
    assert not np.array_equal(moved, render)


def test_a_velocity_pass_filtered_at_edges_leaves_a_still_objects_edges_sharp(fire_i):
    """A still object under a turning camera, its velocity pass filtered at the anti-aliased edge as Blender 5.2
    writes it (each edge pixel mixes the object's velocity with a background velocity that is not the camera's):
    the edge takes the object's velocity, so object motion changes nothing. Unfixed, the edge smears."""
    import cv2

    w = (0.0, 0.6, 0.0)
    camera = rotation_velocity(w, render_focal_px(fire_i, COLS, ROWS), (ROWS, COLS))
    big = np.zeros((ROWS * 4, COLS * 4), np.float32)
    cv2.circle(big, (COLS * 2, ROWS * 2), 240, 1.0, -1)
    alpha = cv2.resize(big, (COLS, ROWS), interpolation=cv2.INTER_AREA)               # exact coverage at the edge
    render = np.dstack([alpha * 0.6, alpha * 0.3, alpha * 0.2, alpha]).astype(np.float32)
    background = np.broadcast_to(np.float32([-300.0, 80.0]), camera.shape)
    velocity = (alpha[..., None] * camera + (1 - alpha[..., None]) * background).astype(np.float32)
    edge = (alpha > 0) & (alpha < 1)
    assert edge.sum() > 100
    profile = fire_i.with_effect("object_motion")
    out = _render_stage(profile, render, RenderPasses(velocity), "object_motion", angular_velocity=w)
    assert np.array_equal(out, render)


def test_defocus_grows_with_distance_from_the_focus_plane(fire_i):
    render = _square(top=200, left=200, size=60) + _square(top=300, left=500, size=60)
    depth = np.full((ROWS, COLS), np.inf, np.float32)
    depth[200:260, 200:260] = 2.0                                   # in focus
    depth[300:360, 500:560] = 0.5                                   # near
    profile = fire_i.with_effect("depth_of_field", focus_distance_m=2.0, aperture_mm=20.0)
    out = _render_stage(profile, render, RenderPasses(None, depth), "depth_of_field")
    assert np.array_equal(out[190:270, 190:270], render[190:270, 190:270])
    radius = 0.5 * 20e-3 * (1 / 0.5 - 1 / 2.0) * render_focal_px(fire_i, COLS, ROWS)   # 3.9 px
    row = out[330, :, 3]
    covered = np.nonzero(row > 1e-6)[0]
    assert abs((covered.max() - covered.min() + 1) - (60 + 2 * radius)) <= 2
    assert out[..., 3].sum() == pytest.approx(render[..., 3].sum(), rel=1e-4)
    assert row[500] == pytest.approx(0.5, abs=0.1)                   # the edge is half covered


def test_pass_effects_need_their_pass_and_sane_values(fire_i):
    render = _square()
    with pytest.raises(LowcamError, match="object_motion.*velocity pass"):
        lowcam.run(render, fire_i.with_effect("object_motion"))
    with pytest.raises(LowcamError, match="depth_of_field.*depth pass"):
        lowcam.run(render, fire_i.with_effect("depth_of_field"))
    with pytest.raises(LowcamError, match="velocity pass must be"):
        lowcam.run(render, fire_i, passes=RenderPasses(np.zeros((ROWS, COLS, 3))))
    with pytest.raises(LowcamError, match="depth pass has NaN"):
        lowcam.run(render, fire_i, passes=RenderPasses(None, np.full((ROWS, COLS), np.nan)))
    with pytest.raises(LowcamError, match="aperture_mm.*out of range"):
        fire_i.with_effect("depth_of_field", aperture_mm=-1.0)


def test_the_node_group_leaves_pass_effects_to_the_handler(fire_i):
    from lowcam.node_maps import bake

    with_passes = bake(fire_i.with_effect("object_motion").with_effect("depth_of_field"), (300, 400))
    plain = bake(fire_i, (300, 400))
    assert with_passes.stages == plain.stages
    assert np.array_equal(with_passes.images["lens_uv"], plain.images["lens_uv"])


def test_a_frame_without_the_pass_an_effect_needs_names_the_file(fire_i, tmp_path):
    from lowcam.outputs import write_exr
    from lowcam.scene import degrade_frame

    path = write_exr(tmp_path / "0001.exr", _square())
    with pytest.raises(LowcamError, match=r"0001\.exr: view layer 'ViewLayer' has no Vector pass"):
        degrade_frame(path, tmp_path / "out.png", fire_i.with_effect("object_motion"))
    assert not (tmp_path / "out.png").exists()
    degrade_frame(path, tmp_path / "out.png", fire_i)                 # without the effect the frame is made
    assert (tmp_path / "out.png").stat().st_size > 0


# --- the passes of Blender's multilayer OpenEXR files, read by `lowcam apply` and `lowcam batch` (farms) ---------

FPS = 25.0


def _cli(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def _write_multilayer(path, render, vector=None, depth=None, depth_key="ViewLayer.Depth.Z"):
    """A Blender-style multilayer EXR written with OpenEXR itself: ``ViewLayer.Combined.R``..``A``,
    ``ViewLayer.Vector.X``..``W`` and the depth under ``depth_key``."""
    import OpenEXR

    channels = {f"ViewLayer.Combined.{c}": render[..., i].copy() for i, c in enumerate("RGBA")}
    if vector is not None:
        channels.update({f"ViewLayer.Vector.{a}": vector[..., i].copy() for i, a in enumerate("XYZW")})
    if depth is not None:
        channels[depth_key] = depth.astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))
    return path


def _moving_square(speed_px_s: float):
    """The square moving right at ``speed_px_s``: its analytic velocity (px/s, y down) and the Vector pass Blender
    writes for it: (previous - current, current - next) positions in pixels per frame, y up."""
    velocity = np.zeros((ROWS, COLS, 2), np.float32)
    velocity[250:350, 350:450, 0] = speed_px_s
    vector = np.zeros((ROWS, COLS, 4), np.float32)
    vector[250:350, 350:450, 0] = vector[250:350, 350:450, 2] = -speed_px_s / FPS
    return velocity, vector


def _extent(frame: np.ndarray, axis: int) -> int:
    """How many columns (axis 0) or rows (axis 1) of a frame over a black plate the graphics reach."""
    touched = np.nonzero((frame > 8).any(axis=2).any(axis=axis))[0]
    return int(touched.max() - touched.min() + 1)


def test_apply_blurs_moving_objects_from_the_exrs_vector_pass(fire_i, tmp_path):
    import cv2

    velocity, vector = _moving_square(1500.0)                       # 49.5 render px over the 33 ms exposure
    exr = _write_multilayer(tmp_path / "render.exr", _square(), vector, np.full((ROWS, COLS), 4.0))
    r = _cli("apply", "--render", exr, "--object-motion", "--fps", FPS, "--seed", 3, "--frame", 7,
             "-o", tmp_path / "moving.png")
    assert r.returncode == 0, r.stderr
    moving = cv2.cvtColor(cv2.imread(str(tmp_path / "moving.png")), cv2.COLOR_BGR2RGB)
    expected = lowcam.simulate(_square(), fire_i.with_effect("object_motion"), seed=3, frame=7,
                               passes=RenderPasses(velocity))
    assert np.array_equal(moving, expected)                         # the pass was found and read as px/s, y down
    assert _cli("apply", "--render", exr, "--seed", 3, "--frame", 7, "-o", tmp_path / "still.png").returncode == 0
    still = cv2.imread(str(tmp_path / "still.png"))
    assert _extent(moving, 0) >= _extent(still, 0) + 15             # smeared along the motion ...
    assert abs(_extent(moving, 1) - _extent(still, 1)) <= 1         # ... and not across it


@pytest.mark.parametrize("depth_key", ["ViewLayer.Depth.Z", "ViewLayer.Z"])
def test_apply_defocuses_from_the_exrs_depth_pass(fire_i, tmp_path, depth_key):
    import cv2

    depth = np.full((ROWS, COLS), 0.5, np.float32)                  # near: 3.9 render px of blur (20 mm aperture)
    exr = _write_multilayer(tmp_path / "render.exr", _square(), depth=depth, depth_key=depth_key)
    r = _cli("apply", "--render", exr, "--defocus", "2,20", "-o", tmp_path / "near.png")
    assert r.returncode == 0, r.stderr
    near = cv2.cvtColor(cv2.imread(str(tmp_path / "near.png")), cv2.COLOR_BGR2RGB)
    profile = fire_i.with_effect("depth_of_field", focus_distance_m=2.0, aperture_mm=20.0)
    assert np.array_equal(near, lowcam.simulate(_square(), profile, passes=RenderPasses(None, depth)))
    assert _cli("apply", "--render", exr, "-o", tmp_path / "sharp.png").returncode == 0
    sharp = cv2.imread(str(tmp_path / "sharp.png"))
    assert _extent(near, 0) > _extent(sharp, 0) and _extent(near, 1) > _extent(sharp, 1)   # blurred both ways


def test_a_missing_pass_is_one_line_naming_the_file_the_pass_and_the_fix(tmp_path):
    exr = _write_multilayer(tmp_path / "render.exr", _square())
    for option, name in ((["--object-motion"], "Vector"), (["--defocus", "2,20"], "Z")):
        r = _cli("apply", "--render", exr, *option, "-o", tmp_path / "out.png")
        assert r.returncode == 2
        line = r.stderr.strip()
        assert "\n" not in line and "render.exr" in line and f"{'Vector' if name == 'Vector' else 'Depth'} pass" in line
        assert f"enable the {name} pass in View Layer Properties" in line
        assert not (tmp_path / "out.png").exists()
    png = tmp_path / "render.png"
    cv2 = pytest.importorskip("cv2")
    cv2.imwrite(str(png), (255 * _square()).astype(np.uint8))
    r = _cli("apply", "--render", png, "--object-motion", "-o", tmp_path / "out.png")
    assert r.returncode == 2 and "render.png" in r.stderr and "OpenEXR" in r.stderr and "\n" not in r.stderr.strip()
    for frame in (1, 2):
        _write_multilayer(tmp_path / f"{frame:04d}.exr", _square())
    r = _cli("batch", "--renders", tmp_path / "####.exr", "--frames", "1-2", "--object-motion", "--quiet",
             "-o", tmp_path / "out" / "####.png")
    assert r.returncode != 0 and "0001.exr: view layer 'ViewLayer' has no Vector pass" in r.stdout + r.stderr


def test_batch_reads_each_frames_passes(fire_i, tmp_path):
    import cv2

    speeds = {1: 900.0, 2: -1800.0}
    for frame, speed in speeds.items():
        _write_multilayer(tmp_path / f"{frame:04d}.exr", _square(), _moving_square(speed)[1])
    r = _cli("batch", "--renders", tmp_path / "####.exr", "--frames", "1-2", "--object-motion", "--fps", FPS,
             "--seed", 5, "--quiet", "-o", tmp_path / "out" / "####.png")
    assert r.returncode == 0, r.stderr
    profile = fire_i.with_effect("object_motion")
    for frame, speed in speeds.items():
        got = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / f"{frame:04d}.png")), cv2.COLOR_BGR2RGB)
        expected = lowcam.simulate(_square(), profile, seed=5, frame=frame,
                                   passes=RenderPasses(_moving_square(speed)[0]))
        assert np.array_equal(got, expected)


# --- passes rendered by Blender itself (bpy) ------------------------------------------------------------------

def _render_moving_plane(folder, engine: str, width=128, height=96):
    """A 2 m plane 10 m in front of a still camera (60 degree horizontal field of view), moving 0.5 m per frame
    right and 0.25 m up at 25 fps, rendered at frame 2 by ``engine`` with 1 sample to a multilayer EXR with the
    Vector and Z passes; the plane glows white. Returns (path, expected velocity (px/s, x right, y down))."""
    import math

    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    names = ("BLENDER_EEVEE", "BLENDER_EEVEE_NEXT") if engine == "EEVEE" else (engine,)
    for name in names:                                  # EEVEE is BLENDER_EEVEE_NEXT in Blender 4.2-4.5
        try:
            scene.render.engine = name
            break
        except TypeError:
            continue
    if engine == "EEVEE":
        scene.eevee.taa_render_samples = 1
    else:
        scene.cycles.samples, scene.cycles.device, scene.cycles.use_denoising = 1, "CPU", False
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    scene.render.fps, scene.render.film_transparent, scene.render.use_motion_blur = 25, True, False
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera, camera.location = camera, (0.0, 0.0, 10.0)          # looking down -z: image x = world x
    camera.data.sensor_fit, camera.data.angle = "HORIZONTAL", math.radians(60)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.object
    white = bpy.data.materials.new("White")                             # self-lit: the scene has no light
    if white.node_tree is None:  # Blender 4 (5 gives each its nodes)
        white.use_nodes = True
    bsdf = white.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 0.8
    plane.data.materials.append(white)
    for frame, x in ((1, 0.0), (3, 1.0)):
        plane.location = (x, 0.5 * x, 0.0)
        plane.keyframe_insert("location", frame=frame)
    action = plane.animation_data.action
    fcurves = action.fcurves if hasattr(action, "fcurves") else \
        action.layers[0].strips[0].channelbag(plane.animation_data.action_slot).fcurves
    for fc in fcurves:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    scene.view_layers[0].use_pass_vector = scene.view_layers[0].use_pass_z = True
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):                                # Blender 5.0+
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format, settings.color_depth = "OPEN_EXR_MULTILAYER", "32"
    scene.frame_set(2)
    path = folder / f"plane-{engine.lower()}.exr"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    focal = (width / 2) / math.tan(math.radians(30))
    return path, np.array([0.5, -0.25]) * 25.0 * focal / 10.0          # m/frame at 10 m -> px/s, y down


@pytest.mark.blender
@pytest.mark.slow
def test_eevee_writes_a_vector_pass_lowcam_reads_as_the_objects_motion(tmp_path):
    """EEVEE (llvmpipe here, so slow) gives the same Vector pass convention as Cycles: the plane's velocity in
    px/s, found in the EXR by the reader that ``lowcam apply`` uses."""
    from lowcam.io import read_render
    from lowcam.passes import read_blender_passes

    path, expected = _render_moving_plane(tmp_path, "EEVEE")
    passes = read_blender_passes(path, None, FPS, needs=("Vector", "Depth"))
    inside = read_render(path)[..., 3] > 0.999
    inside[[0, -1]] = inside[:, [0, -1]] = False
    assert inside.sum() > 200
    velocity = passes.velocity_px_s[inside]
    assert np.allclose(np.median(velocity, axis=0), expected, rtol=0.03)   # magnitude and direction
    assert np.percentile(np.abs(velocity - expected), 90) < 0.05 * np.hypot(*expected)
    assert np.allclose(passes.depth_m[inside], 10.0, rtol=1e-3)


@pytest.mark.blender
def test_apply_smears_an_object_along_the_vector_pass_blender_rendered(tmp_path):
    import cv2

    path, expected = _render_moving_plane(tmp_path, "CYCLES")
    runs = {}
    for name, extra in (("moving", ["--object-motion", "--fps", FPS]), ("still", [])):
        r = _cli("apply", "--render", path, *extra, "-o", tmp_path / f"{name}.png")
        assert r.returncode == 0, r.stderr
        runs[name] = cv2.imread(str(tmp_path / f"{name}.png"))
    grow_x = _extent(runs["moving"], 0) - _extent(runs["still"], 0)
    grow_y = _extent(runs["moving"], 1) - _extent(runs["still"], 1)
    assert grow_x >= 10 and grow_x > 1.5 * grow_y                     # twice as fast along x as along y


def test_the_velocity_from_blenders_vector_pass_is_the_formulas_bits_from_planes_or_one_array():
    """from_blender writes -(X + Z) fps / 2 and (Y + W) fps / 2 straight into the velocity array: the same float32
    bits as the formula computed on a stacked (H, W, 4) array with numpy, whether the pass comes as one array or as
    the file's four channels, for frame rates whose half float32 rounds (23.976, 29.97) and for extreme values."""
    from lowcam.passes import from_blender

    rng = np.random.default_rng(2026)
    vector = (rng.standard_normal((48, 64, 4)) * rng.choice([1e-6, 1.0, 300.0, 3e37], (48, 64, 4))).astype(np.float32)
    vector[0, :4] = [[0.0, -0.0, -0.0, 0.0], [np.inf, 1.0, -np.inf, 2.0], [np.nan, 0.0, 1.0, 0.0], [3e38, 3e38, 3e38, 3e38]]
    for fps in (24.0, 23.976, 29.97, 60.0, 1000.0):
        with np.errstate(all="ignore"):
            formula = np.stack([-(vector[..., 0] + vector[..., 2]), vector[..., 1] + vector[..., 3]], -1) * (fps / 2)
            grouped = from_blender(vector, None, fps).velocity_px_s
            planes = from_blender([vector[..., i].copy() for i in range(4)], None, fps).velocity_px_s
        assert formula.dtype == grouped.dtype == planes.dtype == np.float32
        assert grouped.tobytes() == formula.tobytes() == planes.tobytes(), fps
