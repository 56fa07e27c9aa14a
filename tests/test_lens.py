"""Lens models: exact inverses, agreement with OpenCV, continuity (paper sec. 4.1; PTAM's FOV model)."""
import functools

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.effects.lens import LensDistortion, fold_and_shortfall
from lowcam.effects.lens_models import BlenderLens, FovLens, OpenCVLens

W, H = 640, 480


def frame_grid(margin=16, step=1):
    u, v = np.meshgrid(np.arange(-margin, W + margin, step, dtype=np.float64),
                       np.arange(-margin, H + margin, step, dtype=np.float64))
    return u, v


@pytest.mark.parametrize("w", [0.0, 0.3, 0.93, 1.2])
def test_fov_round_trip_within_1e6_px_over_the_frame(w):
    lens = FovLens(W, H, 0.57, 0.76, 0.5, 0.5, w)
    u, v = frame_grid()
    x, y = lens.undistort(u, v)
    u2, v2 = lens.distort(x, y)
    assert np.abs(u2 - u).max() < 1e-6 and np.abs(v2 - v).max() < 1e-6


def test_fov_is_continuous_through_the_centre():
    # PTAM switches to factor 1 below r = 0.001, a jump of 2 tan(w/2)/w; the continuous limit has none.
    lens = FovLens(W, H, 0.57, 0.76, 0.5, 0.5, 0.93)
    r = np.array([0.0, 5e-5, 9.99e-5, 1.0001e-4, 2e-4, 1e-3])
    u, _ = lens.distort(r, np.zeros_like(r))
    slope = np.diff(u) / np.diff(r)
    assert np.allclose(slope, lens.fx * lens.d / lens.w, rtol=1e-6)


def test_fov_barrel_pulls_the_corners_in():
    lens = FovLens(W, H, 0.57, 0.76, 0.5, 0.5, 0.93)
    x, y = lens.undistort(np.array([0.0]), np.array([0.0]))  # a corner pixel
    pin = lens.pinhole()
    u_pin, v_pin = pin.distort(x, y)
    assert u_pin[0] < -100 and v_pin[0] < -60  # the pinhole would put that ray far outside the frame


def test_opencv_model_matches_cv2_projectpoints():
    k = dict(k1=-0.26637, k2=-0.03859, p1=0.00178, p2=-0.00028, k3=0.23839)
    lens = OpenCVLens(W, H, 535.916, 535.916, 342.283, 235.571, **k)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, 200), rng.uniform(-0.45, 0.45, 200), np.ones(200)])
    K = np.array([[535.916, 0, 342.283], [0, 535.916, 235.571], [0, 0, 1]])
    dist = np.array([k["k1"], k["k2"], k["p1"], k["p2"], k["k3"]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    u, v = lens.distort(pts[:, 0], pts[:, 1])
    assert np.abs(np.column_stack([u, v]) - ref[:, 0]).max() < 1e-9
    # and undistortion agrees with cv2.undistortPoints
    und = cv2.undistortPointsIter(ref.astype(np.float64), K, dist, None, None,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))
    x, y = lens.undistort(ref[:, 0, 0], ref[:, 0, 1])
    assert np.abs(np.column_stack([x, y]) - pts[:, :2]).max() < 1e-8
    assert np.abs(und[:, 0] - pts[:, :2]).max() < 1e-5


def test_opencv_radial_inverse_matches_cv2_and_stops_at_the_peak():
    """Without tangential terms the inverse solves the radius alone: cv2.projectPoints' pixels come back to their
    rays; a pixel beyond the largest radius the lens reaches (its radius turns back at r = 1.22 here) comes back
    to the ray of that peak, not to a point of the far branch."""
    k = dict(k1=-0.3932, k2=0.3044, k3=-0.1141)  # a compact's 24 mm wide angle fitted by Brown-Conrady
    lens = OpenCVLens(W, H, 487.68, 487.68, 319.5, 239.5, **k)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.95, 0.95, 300), rng.uniform(-0.7, 0.7, 300), np.ones(300)])
    K = np.array([[487.68, 0, 319.5], [0, 487.68, 239.5], [0, 0, 1]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, np.array([k["k1"], k["k2"], 0, 0, k["k3"]]))
    x, y = lens.undistort(ref[:, 0, 0], ref[:, 0, 1])
    assert np.abs(np.column_stack([x, y]) - pts[:, :2]).max() < 1e-9
    r = np.linspace(0, 2, 20001)
    peak = r[np.argmax(r * (1 + r * r * (k["k1"] + r * r * (k["k2"] + r * r * k["k3"]))))]
    x, y = lens.undistort(np.array([319.5 + 500.0]), np.array([239.5]))  # 500 px out: beyond the lens's reach
    assert x[0] == pytest.approx(peak, abs=1e-3) and y[0] == 0.0


def test_fold_and_shortfall_sees_folds_and_a_render_too_narrow_continuously(fire_i):
    """A lens that rises past the working grid's corner inside a 90 deg render: 0. One whose radius turns back at
    374 px (the frame's corner is at 400): the corner rays fold. A pinhole of focal 200 px: the render's edge
    (tan 45 deg) is 200 px out, the edge midpoints 320 px: 1 - 200/320 short. Across the onset of a fold the
    measure moves by steps under 1.5 % of its final value (0.6 % measured; 2.9 % with a weight that drops to 0 at
    once where the radius passes the working grid), so a least-squares fit can walk it."""
    geo = fire_i.geometry
    edge = np.tan(np.radians(45))

    def measure(f, k1, k2, k3):
        return fold_and_shortfall(OpenCVLens(W, H, f, f, 319.5, 239.5, k1, k2, k3), geo, edge, edge * H / W)

    assert np.all(measure(487.68, -0.3932, 0.3044, -0.1141) == 0)
    folded = measure(489.15, -0.4333, 0.442, -0.2445)
    assert folded[0] > 0.05 and folded[2] == 0  # a corner, and the top edge's midpoint 240 px out
    pinhole = measure(200.0, 0.0, 0.0, 0.0)
    assert pinhole[6] == pytest.approx(1 - 200 / 320, abs=1e-9)  # the right edge's midpoint
    onset = np.array([measure(487.68, -0.3932, 0.3044, k3).max() for k3 in np.linspace(-0.1141, -0.16, 200)])
    assert onset[0] == 0 and onset[-1] > 0.05 and np.abs(np.diff(onset)).max() < 0.015 * onset[-1]


@pytest.mark.parametrize("model, coefficients", [
    ("polynomial", dict(k1=-0.12, k2=0.02, k3=-0.003)),
    ("division", dict(division_k1=-0.08, division_k2=0.01)),
    ("nuke", dict(nuke_k1=0.05, nuke_k2=-0.01)),
    ("brown", dict(brown_k1=-0.1, brown_k2=0.01, brown_k3=0.0, brown_k4=0.0, brown_p1=0.002, brown_p2=-0.001)),
])
def test_blender_models_round_trip(model, coefficients):
    lens = BlenderLens(W, H, model, focal_length=4.0, sensor_width=4.8, principal_point=(0.02, -0.03),
                       pixel_aspect=1.0, **coefficients)
    u, v = frame_grid(margin=0, step=8)
    x, y = lens.undistort(u, v)
    u2, v2 = lens.distort(x, y)
    assert np.abs(u2 - u).max() < 1e-6 and np.abs(v2 - v).max() < 1e-6
    # the principal point is where Blender says: (0.02, -0.03) normalised, y up
    cu, cv = lens.distort(np.array([0.0]), np.array([0.0]))
    assert cu[0] == pytest.approx((0.02 + 1) / 2 * W - 0.5) and cv[0] == pytest.approx(H - (-0.03 + 1) / 2 * H - 0.5)


def test_blender_polynomial_agrees_with_opencv_radial_terms():
    # libmv's polynomial radial terms are OpenCV's k1..k3 on the same normalised coordinates.
    f = 4.0 / 4.8 * W
    a = BlenderLens(W, H, "polynomial", 4.0, 4.8, (0.0, 0.0), 1.0, k1=-0.1, k2=0.01, k3=0.001)
    b = OpenCVLens(W, H, f, f, W / 2 - 0.5, H / 2 - 0.5, k1=-0.1, k2=0.01, k3=0.001)
    x = np.linspace(-0.5, 0.5, 11)
    assert np.allclose(a.distort(x, x * 0.7), b.distort(x, x * 0.7), atol=1e-9)


def test_lens_effect_rejects_keys_of_another_model():
    from lowcam import ProfileError

    with pytest.raises(ProfileError, match="does not belong to the 'fov' lens model"):
        LensDistortion(model="fov", k1=0.1)


# --- lensfun's models against lensfun itself (lensfunpy) --------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _lensfun_aspect_ratio(lens):
    """The lens's calibration aspect ratio from lensfun's XML (lensfunpy does not expose it); lensfun's default
    is 3:2."""
    import glob
    import xml.etree.ElementTree as ET

    import lensfunpy

    for path in glob.glob(lensfunpy.__path__[0] + "/db_files/*.xml"):
        for el in ET.parse(path).getroot().iter("lens"):
            if (el.findtext("maker") or "", el.findtext("model")) == lens:
                text = el.findtext("aspect-ratio")
                if text is None:
                    return 1.5
                a, _, b = text.partition(":")
                return float(a) / float(b) if b else float(a)
    return 1.5


LENSFUN_LENSES = [  # (lens model, index of its distortion calibration): poly3, poly5 and ptlens, 4:3 and 3:2
    # (the 14-42 at 18 mm: at 14 mm its poly3 stops rising 8 % short of its own frame's corner, a lens that folds)
    ("Olympus Tough TG-4 & compatibles", 0), ("Olympus M.Zuiko Digital ED 14-42mm f/3.5-5.6", 1),
    ("Tamron SP AF 10-24mm f/3.5-4.5 Di II LD Aspherical (IF)", 0),
    ("Canon PowerShot G12 & compatibles (Standard)", 0), ("Canon PowerShot G12 & compatibles (Standard)", 3),
    ("GoPro Hero3+ black & compatibles", 0), ("Canon PowerShot S120 & compatibles", 0),
    ("Canon PowerShot SX60 HS & compatibles", 0),
]


@pytest.mark.parametrize("name, index", LENSFUN_LENSES)
@pytest.mark.parametrize("crop_ratio", [1.0, 1.4])
def test_lensfun_models_match_lensfunpy_within_0_05_px(name, index, crop_ratio):
    """Lensfun's own ``apply_geometry_distortion`` (corrected pixel -> pixel of the distorted frame), on a camera
    of the lens's crop factor and on one cropped 1.4x further (a lens calibrated on one camera used on another).
    Lensfun 0.3's SSE paths (four pixels at a time) mix up lanes in poly3 and take an approximate square root in
    ptlens (up to 0.9 px here), so lensfun is asked for one column at a time: its scalar code answers."""
    lensfunpy = pytest.importorskip("lensfunpy")
    lens = next(lens for lens in lensfunpy.Database().lenses if lens.model == name)
    cal = lens.calib_distortion[index]
    model = cal.model.name.lower()
    crop = lens.crop_factor * crop_ratio
    m = lensfunpy.Modifier(lens, crop, W, H)
    m.initialize(cal.focal, 2.8, 1000.0, scale=1.0, flags=lensfunpy.ModifyFlags.DISTORTION)
    ref = np.concatenate([m.apply_geometry_distortion(x, 0, 1, H) for x in range(W)], axis=1)
    keys = {"poly3": ("lensfun_k1",), "poly5": ("lensfun_k1", "lensfun_k2"),
            "ptlens": ("lensfun_a", "lensfun_b", "lensfun_c")}[model]
    effect = LensDistortion(model=model, focal_length=cal.focal, crop_factor=crop,
                            calibration_crop_factor=lens.crop_factor,
                            calibration_aspect_ratio=_lensfun_aspect_ratio((lens.maker, lens.model)),
                            lensfun_center=[lens.center_x, lens.center_y],
                            **dict(zip(keys, cal.terms)))
    lf = effect.model_for(W, H)
    fx, fy, cx, cy = lf.pinhole_intrinsics()
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    ud, vd = lf.distort((u - cx) / fx, (v - cy) / fy)
    assert np.hypot(ud - u, vd - v).max() > 1  # a distortion worth checking
    assert np.hypot(ud - ref[..., 0], vd - ref[..., 1]).max() < 0.05
    x, y = lf.undistort(ud, vd)  # and the inverse
    assert np.hypot(x * fx + cx - u, y * fy + cy - v).max() < 1e-6


def test_lensfun_model_is_validated():
    from lowcam import ProfileError

    with pytest.raises(ProfileError, match="folds over"):
        LensDistortion(model="poly3", lensfun_k1=-0.6)
    with pytest.raises(ProfileError, match="does not belong to the 'poly3' lens model"):
        LensDistortion(model="poly3", lensfun_a=0.1)
    LensDistortion(model="ptlens", focal_length=5.2, crop_factor=4.62, calibration_crop_factor=4.62,
                   calibration_aspect_ratio=4 / 3, lensfun_a=0.03458, lensfun_b=-0.14652, lensfun_c=-0.00567)


def test_a_given_render_field_must_cover_the_frame_and_the_margin_beyond_it_reads_transparent(fire_i):
    """A capture's render is made already: its field must cover the frame (else one line), while the working
    grid's margin around the frame may reach beyond it and then reads as transparent (a real lens fitted to a
    capture's render was refused for its margin alone)."""
    import lowcam
    from lowcam.effects.lens_models import field_needed
    from lowcam.errors import LowcamError

    lens = fire_i.effect("lens_distortion")
    model, geo = lens.lens_model(fire_i.geometry), fire_i.geometry
    frame_x, _ = field_needed(model, geo.frame_extent)
    margin_x, _ = field_needed(model, geo.working_extent)
    between = float(np.degrees(np.arctan(frame_x) + np.arctan(margin_x)))  # 2 atan of neither: a field between
    assert 2 * np.degrees(np.arctan(frame_x)) < between < 2 * np.degrees(np.arctan(margin_x))
    profile = fire_i.with_effect("lens_distortion", render_hfov_deg=between)
    render = np.ones((900, 1200, 4), np.float32)  # opaque everywhere the render reaches
    working = lowcam.run(render, profile, None, stop_after="lens_distortion").state.working
    s = geo.working_scale[0]  # working px per output px
    m = int(geo.margin_px * s)
    frame_alpha = working[m + 4:-m - 4, m + 4:-m - 4, 3]
    assert frame_alpha.min() > 0.999  # the frame sees the render everywhere
    assert working[0, 0, 3] == 0 and working[-1, -1, 3] == 0  # the margin's corners lie beyond it
    narrow = fire_i.with_effect("lens_distortion", render_hfov_deg=2 * np.degrees(np.arctan(frame_x)) - 1)
    with pytest.raises(LowcamError, match="is narrower than the .* deg the frame sees"):
        lowcam.run(render, narrow, None, stop_after="lens_distortion")


FISHEYE_K = np.array([[620.0, 0.0, 959.5], [0.0, 618.0, 539.5], [0.0, 0.0, 1.0]])
FISHEYE_D = np.array([0.052, -0.018, 0.0061, -0.0009])  # a GoPro-class wide lens, 1920x1080


def _fisheye():
    from lowcam.effects.lens_models import KannalaBrandtLens

    return KannalaBrandtLens(1920, 1080, 620.0, 618.0, 959.5, 539.5, *FISHEYE_D)


def test_fisheye_model_matches_cv2_fisheye_both_ways():
    """OpenCV's own fisheye (``cv2.fisheye.distortPoints`` and ``undistortPoints``) on rays out to 70 degrees and
    on every 40th pixel of a 1920x1080 frame: within 1e-6 px and 1e-7 in the camera plane. (OpenCV's inverse
    clamps the distorted angle at 90 degrees; pixels beyond it are left out.)"""
    rng = np.random.default_rng(4)
    theta = rng.uniform(0.0, np.radians(70), 500)
    phi = rng.uniform(0.0, 2 * np.pi, 500)
    x, y = np.tan(theta) * np.cos(phi), np.tan(theta) * np.sin(phi)
    theirs = cv2.fisheye.distortPoints(np.stack([x, y], -1)[:, None].astype(np.float64), FISHEYE_K, FISHEYE_D)[:, 0]
    u, v = _fisheye().distort(x, y)
    assert np.abs(np.stack([u, v], -1) - theirs).max() < 1e-6
    uu, vv = np.meshgrid(np.arange(0, 1920, 40.0), np.arange(0, 1080, 40.0))
    inside = np.hypot((uu - 959.5) / 620.0, (vv - 539.5) / 618.0) < np.pi / 2 - 0.01
    uu, vv = uu[inside], vv[inside]
    assert inside.mean() > 0.8
    theirs = cv2.fisheye.undistortPoints(np.stack([uu, vv], -1).reshape(-1, 1, 2), FISHEYE_K, FISHEYE_D,
                                         criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0]
    xs, ys = _fisheye().undistort(uu.ravel(), vv.ravel())
    assert np.abs(np.stack([xs, ys], -1) - theirs).max() < 1e-7


def test_a_fisheye_profile_films_and_a_folding_one_is_refused(fire_i):
    """A profile with the fisheye model runs the chain and bakes its node maps (round trip of the lens's own
    map within 1e-6 px); coefficients whose angle stops rising inside the frame are one line naming the effect."""
    from helpers import disk_render

    from lowcam.node_maps import bake

    values = dict(model="fisheye", fx_px=330.0, fy_px=330.0, cx_px=319.5, cy_px=239.5, fisheye_k1=0.05,
                  fisheye_k2=-0.01)
    fisheye = fire_i.with_effect("lens_distortion", replace=True, **values)
    frame = lowcam.simulate(disk_render(fisheye), fisheye)
    assert frame.shape == (480, 640, 3) and frame.std() > 5
    lens = fisheye.effect("lens_distortion").model_for(640, 480)
    u, v = np.meshgrid(np.arange(0, 640, 16.0), np.arange(0, 480, 16.0))
    assert np.abs(np.stack(lens.distort(*lens.undistort(u, v))) - np.stack([u, v])).max() < 1e-6
    rows, cols = fisheye.geometry.working_shape                  # the lens map reads the 2x2 supersampled grid
    assert bake(fisheye, (600, 800)).images["lens_uv"].shape[:2] == (2 * rows, 2 * cols)
    with pytest.raises(lowcam.LowcamError, match="fisheye distortion folds over inside the frame"):
        fire_i.with_effect("lens_distortion", replace=True, **dict(values, fisheye_k1=-0.6))
