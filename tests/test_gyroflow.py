"""Gyroflow lens profiles into Lowcam profiles (``lowcam profile from-gyroflow``), checked against OpenCV.

The fisheye numbers are those of a published Gyroflow profile (GoPro HERO11 Black, Wide, 1920x1440 at 59.94 fps,
calibrated by Eric John Gangob, from https://github.com/gyroflow/lens_profiles); the files are written here. Each
lens is checked against OpenCV's own projection at the calibration size (``cv2.fisheye.distortPoints``,
``cv2.projectPoints``), scaled to the profile's frame: ``u' = (u + 1/2) s - 1/2``.
"""
import json
import os
import tarfile
from pathlib import Path

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.cli import main
from lowcam.errors import LowcamError
from lowcam.gyroflow import profile_from_gyroflow

GOPRO = {
    "name": "GoPro_HERO11 Black_Wide_NO-EIS_1440p_4by3_1920x1440-59.94fps", "calibrated_by": "Eric John Gangob",
    "camera_brand": "GoPro", "camera_model": "Hero11 Black", "lens_model": "Wide", "camera_setting": "",
    "calib_dimension": {"w": 1920, "h": 1440}, "frame_readout_time": None, "fps": 59.94006,
    "fisheye_params": {"RMS_error": 0.3026169636660809,
                       "camera_matrix": [[850.9258300101518, 0.0, 955.4606669132976],
                                         [0.0, 851.2297124259651, 703.684385237145], [0.0, 0.0, 1.0]],
                       "distortion_coeffs": [0.04811393335542556, 0.014462655278865172, 0.015455756126129904,
                                             -0.016796419293154025]},
    "distortion_model": None,
}


def _write(tmp_path, doc, name="lens.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _rays(n=400, max_deg=60.0, seed=2):
    rng = np.random.default_rng(seed)
    theta, phi = rng.uniform(0, np.radians(max_deg), n), rng.uniform(0, 2 * np.pi, n)
    return np.tan(theta) * np.cos(phi), np.tan(theta) * np.sin(phi)


def test_a_gyroflow_fisheye_profile_is_opencvs_fisheye_scaled_to_the_frame(tmp_path, capsys):
    """The GoPro's fisheye on fire-i's 640x480 frame (a third of 1920x1440) puts every ray where OpenCV's fisheye
    at 1920x1440 does, scaled: within 1e-6 px. The frame rate bounds the exposure (fire-i's 1/30 s becomes one
    frame at 59.94 frames/s); the name and provenance come from the file."""
    path = _write(tmp_path, GOPRO)
    assert main(["profile", "from-gyroflow", str(path), "--base", "fire-i", "--size", "640,480", "-o",
                 str(tmp_path / "gopro.toml")]) == 0
    assert "scaled from 1920x1440 to 640x480" in capsys.readouterr().out
    profile = lowcam.load_profile(tmp_path / "gopro.toml")
    x, y = _rays()
    p = GOPRO["fisheye_params"]
    theirs = cv2.fisheye.distortPoints(np.stack([x, y], -1)[:, None], np.array(p["camera_matrix"]),
                                       np.array(p["distortion_coeffs"]))[:, 0]
    u, v = profile.effect("lens_distortion").model_for(640, 480).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - ((theirs + 0.5) / 3 - 0.5)).max() < 1e-6
    assert profile.effect("rolling_shutter") is None                       # no read-out time in the file
    assert abs(profile.camera.exposure_s - 1 / 59.94006) < 1e-9
    assert profile.camera.name == "GoPro Hero11 Black Wide"
    assert "lens.json" in profile.provenance["lens_distortion"] and "Eric John Gangob" in \
        profile.provenance["lens_distortion"] and "59.94" in profile.provenance["camera.exposure_s"]


def test_a_standard_opencv_profile_and_its_rolling_shutter(tmp_path):
    """A profile in OpenCV's standard model (``k1, k2, p1, p2, k3``) with a read-out time: OpenCV's
    ``projectPoints`` at 1280x960 scaled to 640x480 within 1e-6 px, and the read-out into the rolling shutter."""
    k = [[1000.0, 0.0, 641.3], [0.0, 1002.0, 478.9], [0.0, 0.0, 1.0]]
    d = [-0.21, 0.09, 0.0012, -0.0008, -0.015]
    doc = {"calib_dimension": {"w": 1280, "h": 960}, "use_opencv_fisheye": False, "use_opencv_standard": True,
           "calib_params": {"camera_matrix": k, "distortion_coeffs": d}, "frame_readout_time": 21.5,
           "camera_brand": "Phone", "camera_model": "X"}
    profile, notes = profile_from_gyroflow(_write(tmp_path, doc), lowcam.load_profile("fire-i"), (640, 480))
    x, y = _rays(max_deg=35.0)
    theirs = cv2.projectPoints(np.stack([x, y, np.ones_like(x)], -1)[:, None], np.zeros(3), np.zeros(3),
                               np.array(k), np.array(d))[0][:, 0]
    u, v = profile.effect("lens_distortion").model_for(640, 480).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - ((theirs + 0.5) / 2 - 0.5)).max() < 1e-6
    assert profile.effect("rolling_shutter").readout_s == pytest.approx(0.0215)
    assert any("21.5 ms" in n for n in notes) and "21.5 ms" in profile.provenance["rolling_shutter"]


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(digital_lens="gopro_superview"), "the GoPro SuperView digital lens"),
    (lambda d: d.update(calib_dimension={"w": 1920, "h": 1e9}), "calib_dimension: 'h'"),
    (lambda d: d.update(input_horizontal_stretch=float("inf")), "not a finite number"),
    (lambda d: d["fisheye_params"]["camera_matrix"][0].__setitem__(0, -850.0), "must be positive"),
    (lambda d: d.update(distortion_model="sony"), "'sony' lens model is not one Lowcam reads"),
    (lambda d: d["fisheye_params"].update(distortion_coeffs=[0.1, 0.2]), "distortion_coeffs must hold 4"),
    (lambda d: d["fisheye_params"]["camera_matrix"][0].__setitem__(0, float("nan")), "not a finite number"),
    (lambda d: d["fisheye_params"]["camera_matrix"][0].__setitem__(0, "850"), "camera_matrix[0][0]"),
    (lambda d: d.pop("calib_dimension"), "not a Gyroflow lens profile"),
    (lambda d: d["fisheye_params"].update(distortion_coeffs=[-0.9, 0.0, 0.0, 0.0]),
     "folds over inside the 1920x1440 frame"),
])
def test_a_file_lowcam_cannot_read_is_one_line_naming_it(tmp_path, capsys, change, message):
    doc = json.loads(json.dumps(GOPRO))
    change(doc)
    path = _write(tmp_path, doc)
    code = main(["profile", "from-gyroflow", str(path), "--base", "fire-i", "-o", str(tmp_path / "out.toml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(path) in err and message in err, err
    assert not (tmp_path / "out.toml").exists()


def _opencv_share_beyond_the_peak(k, d, w, h):
    """OpenCV's fisheye radius: the normalised radius where it stops rising, the angle there (rad), and the share
    of the w x h frame's pixels (every other one) beyond. The radius is OpenCV's documented ``theta_d = theta (1 +
    k1 theta^2 + ... + k4 theta^8)`` out to 180 deg, checked against ``cv2.fisheye.distortPoints`` short of 86 deg
    (rays at 90 deg and beyond have no point on its plane)."""
    theta = np.linspace(0.0, np.pi, 60000)
    t2 = theta ** 2
    theta_d = theta * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
    some = theta < 1.5
    u = cv2.fisheye.distortPoints(np.stack([np.tan(theta[some]), np.zeros(some.sum())], -1)[:, None], k, d)[:, 0, 0]
    assert np.allclose((u - k[0, 2]) / k[0, 0], theta_d[some], rtol=1e-9, atol=1e-9)
    peak = int(np.argmax(np.diff(theta_d) <= 0)) if np.any(np.diff(theta_d) <= 0) else len(theta) - 1
    uu, vv = np.meshgrid(np.arange(0, w, 2) + 0.0, np.arange(0, h, 2) + 0.0)
    rd = theta_d[peak]
    return rd, theta[peak], float((np.hypot((uu - k[0, 2]) / k[0, 0], (vv - k[1, 2]) / k[1, 1]) > rd).mean())


@pytest.mark.parametrize("k4", [-0.024, -0.03])
def test_a_fisheye_whose_radius_stops_rising_in_the_corners_imports_if_they_are_small(tmp_path, k4):
    """The GoPro's fisheye with a stronger k4: OpenCV's own radius stops rising inside the 1920x1440 frame, with
    1.3 % of the frame beyond (k4 = -0.024) or 3.4 % (-0.03). Up to 2 % the file imports: rays short of the peak
    land where OpenCV puts them, the corner pixels see the ray at the peak, and the provenance and the notes give
    the share; beyond 2 % it is refused in one line naming the file and the share."""
    doc = json.loads(json.dumps(GOPRO))
    doc["fisheye_params"]["distortion_coeffs"][3] = k4
    k, d = np.array(doc["fisheye_params"]["camera_matrix"]), np.array(doc["fisheye_params"]["distortion_coeffs"])
    rd, theta_peak, share = _opencv_share_beyond_the_peak(k, d, 1920, 1440)
    assert share > 0.0                                          # the corners lie past the peak
    path = _write(tmp_path, doc)
    if share > 0.02:
        with pytest.raises(LowcamError, match=f"{path}: the lens folds over inside the 1920x1440 frame") as e:
            profile_from_gyroflow(path, lowcam.load_profile("fire-i"))
        said = float(str(e.value).split("; ")[1].split(" % of the frame lies beyond")[0])
        assert abs(said - 100 * share) < 0.1 and "\n" not in str(e.value)
        return
    profile, notes = profile_from_gyroflow(path, lowcam.load_profile("fire-i"))
    said = float(profile.provenance["lens_distortion"].split("the outer ")[1].split(" %")[0])
    assert abs(said - 100 * share) < 0.1 and any(f"outer {said:.2g} %" in n for n in notes)
    lens = profile.effect("lens_distortion").model_for(1920, 1440)
    x, y = _rays(max_deg=np.degrees(theta_peak) - 0.5)
    theirs = cv2.fisheye.distortPoints(np.stack([x, y], -1)[:, None], k, d)[:, 0]
    assert np.abs(np.stack(lens.distort(x, y), -1) - theirs).max() < 1e-6
    back = cv2.fisheye.distortPoints(np.stack(lens.undistort(*theirs.T), -1)[:, None], k, d)[:, 0]
    assert np.abs(back - theirs).max() < 0.01                          # each pixel short of the peak: its own ray
    corners = np.array([-0.5, 1919.5]), np.array([-0.5, 1439.5])
    assert np.allclose(lens.undistort_ray(*corners)[0], theta_peak, atol=2e-4)   # the corners: the ray at the peak


@pytest.mark.parametrize("p", [0.0, 0.001])
def test_a_standard_lens_that_folds_inside_its_frame_is_refused(tmp_path, p):
    """OpenCV's standard model with k1 = -0.9 at 1280x960 (f = 1000 px): OpenCV's own radius (``cv2.projectPoints``
    along the frame's diagonal) stops rising before the corner, so the file is refused naming it, without
    tangential terms (the radial limit) and with them (the round trip through the lens)."""
    k = [[1000.0, 0.0, 639.5], [0.0, 1000.0, 479.5], [0.0, 0.0, 1.0]]
    d = [-0.9, 0.0, p, p, 0.0]
    r = np.linspace(0.0, 1.0, 1000)
    pts = np.stack([r * 0.8, r * 0.6, np.ones_like(r)], -1)[:, None]
    u = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.array(k), np.array(d))[0][:, 0]
    radius = np.hypot(u[:, 0] - 639.5, u[:, 1] - 479.5)
    assert np.any(np.diff(radius[radius < 800.0]) < 0)         # folds before the corner, 800 px from the centre
    doc = {"calib_dimension": {"w": 1280, "h": 960}, "use_opencv_fisheye": False, "use_opencv_standard": True,
           "calib_params": {"camera_matrix": k, "distortion_coeffs": d}}
    path = _write(tmp_path, doc)
    with pytest.raises(LowcamError, match=f"{path}: the lens folds over inside the 1280x960 frame"):
        profile_from_gyroflow(path, lowcam.load_profile("fire-i"))


def test_a_file_that_is_not_json_is_one_line(tmp_path, capsys):
    path = tmp_path / "lens.json"
    path.write_bytes(b"\x00\xffnot json")
    assert main(["profile", "from-gyroflow", str(path), "-o", str(tmp_path / "out.toml")]) == 2
    err = capsys.readouterr().err
    assert "not UTF-8" in err and str(path) in err and len(err.strip().splitlines()) == 1
    assert main(["profile", "from-gyroflow", "/dev/zero", "-o", str(tmp_path / "out.toml")]) == 2
    assert "/dev/zero: is a device" in capsys.readouterr().err


# --- every frame shape, every lens the database holds (issue 38) ---

#: The iPhone 12 Pro's telephoto at 3840x2160 (gyroflow/lens_profiles, CC0: "Apple_iPhone 12 Pro_Back Telephoto camera
#: (51mm equiv.)_HDR_4k_16by9_3840x2160-25.00fps.json", calibrated by Tom.my): a narrow lens whose fisheye fit has large
#: terms of alternating sign (k4 = -578) that cancel over its 17 deg field.
TELEPHOTO = {
    "calib_dimension": {"w": 3840, "h": 2160}, "camera_brand": "Apple", "camera_model": "iPhone 12 Pro",
    "lens_model": "Back Telephoto camera (51mm equiv.)", "camera_setting": "HDR", "fps": 25.0,
    "fisheye_params": {"RMS_error": 0.43,
                       "camera_matrix": [[6322.804010879457, 0.0, 1946.6302861778809],
                                         [0.0, 6323.141224292245, 1056.9896688496872], [0.0, 0.0, 1.0]],
                       "distortion_coeffs": [0.38180022048159334, -2.2295144588159466, 79.13003065929205,
                                             -578.016730658399]},
}
#: The draw from the database: LOWCAM_DRAW_SEED redraws it.
DRAW_SEED = int(os.environ.get("LOWCAM_DRAW_SEED", "38"))
DATABASE = Path(os.environ.get("LOWCAM_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data") / \
    "gyroflow-lens-profiles" / "lens_profiles.tar.xz"


def _opencv_pixels(doc, n=300, seed=0, stretch=(1.0, 1.0)):
    """A seeded draw of rays inside the calibrated frame, as OpenCV's fisheye sees them: pixels drawn over the
    recorded frame, taken into the calibration frame (times the stretch) and to their rays by
    ``cv2.fisheye.undistortPoints``; then OpenCV's own projection of those rays (``cv2.fisheye.distortPoints``),
    back in the recorded frame. Returns the rays (x, y on the camera plane) and OpenCV's pixels (n, 2)."""
    p, (w, h) = doc["fisheye_params"], (doc["calib_dimension"]["w"], doc["calib_dimension"]["h"])
    k, d = np.array(p["camera_matrix"], np.float64), np.array(p["distortion_coeffs"], np.float64)
    rng = np.random.default_rng(seed)
    pixels = np.stack([rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n)], -1)
    rays = cv2.fisheye.undistortPoints(pixels[:, None], k, d, criteria=(cv2.TERM_CRITERIA_COUNT |
                                       cv2.TERM_CRITERIA_EPS, 200, 1e-15))[:, 0]
    theirs = cv2.fisheye.distortPoints(rays[:, None], k, d)[:, 0] / np.array(stretch)
    return rays[:, 0], rays[:, 1], theirs


def test_a_16_by_9_profile_is_made_at_its_own_frame_with_any_base(tmp_path, capsys):
    """A 16:9 calibration (the GoPro's lens at 1920x1080) with the 4:3 fire-i base: the profile delivers 1920x1080,
    its lens is OpenCV's fisheye there (a seeded draw of rays, within 0.01 px) and only the sensor and processing
    come from the base (its Bayer pattern, noise, quantisation)."""
    doc = dict(GOPRO, calib_dimension={"w": 1920, "h": 1080})
    doc["fisheye_params"] = dict(GOPRO["fisheye_params"], camera_matrix=[[850.9, 0.0, 961.2], [0.0, 851.2, 541.7],
                                                                          [0.0, 0.0, 1.0]])
    path = _write(tmp_path, doc)
    assert main(["profile", "from-gyroflow", str(path), "-o", str(tmp_path / "wide.toml")]) == 0
    assert "at the recorded frame 1920x1080" in capsys.readouterr().out
    profile, fire_i = lowcam.load_profile(tmp_path / "wide.toml"), lowcam.load_profile("fire-i")
    assert (profile.camera.width, profile.camera.height) == (1920, 1080)
    assert profile.camera.bayer_pattern == fire_i.camera.bayer_pattern
    assert profile.effect("quantisation").bits == 6 and profile.effect("noise").red == fire_i.effect("noise").red
    x, y, theirs = _opencv_pixels(doc, seed=DRAW_SEED)
    u, v = profile.effect("lens_distortion").model_for(1920, 1080).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - theirs).max() < 0.01
    assert "frame 1920x1080" in profile.provenance["camera"]


@pytest.mark.parametrize("size", [(1280, 720), (1080, 1920), (2400, 1012), (1500, 1000)])
def test_a_size_of_any_shape_is_the_frame_scaled_to_cover_it_and_cut_around_the_centre(tmp_path, size):
    """``--size`` of another shape (16:9, portrait, 2.37:1, 3:2 from the 4:3 GoPro): each ray lands where OpenCV's
    fisheye at 1920x1440 puts it, scaled by s = max(w'/w, h'/h) and cut by half the excess on each side:
    ``(u + 1/2) s - 1/2 - (1920 s - w') / 2``, within 0.01 px; rays that leave the cut frame are not compared."""
    path = _write(tmp_path, GOPRO)
    w2, h2 = size
    profile, _ = profile_from_gyroflow(path, lowcam.load_profile("fire-i"), size)
    assert (profile.camera.width, profile.camera.height) == size
    x, y, theirs = _opencv_pixels(GOPRO, seed=DRAW_SEED + 1)
    s = max(w2 / 1920, h2 / 1440)
    expected = (theirs + 0.5) * s - 0.5 - np.array([(1920 * s - w2) / 2, (1440 * s - h2) / 2])
    inside = (expected[:, 0] > -0.5) & (expected[:, 0] < w2 - 0.5) & (expected[:, 1] > -0.5) & \
        (expected[:, 1] < h2 - 0.5)
    assert inside.sum() > 100
    u, v = profile.effect("lens_distortion").model_for(w2, h2).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - expected)[inside].max() < 0.01


def test_large_coefficients_of_alternating_sign_are_judged_by_the_mapping(tmp_path):
    """The iPhone telephoto's terms (k3 = 79, k4 = -578) cancel over its frame: imported at 3840x2160, OpenCV's
    projection of a seeded draw of rays within 0.01 px. The same terms over a frame they do not hold out to (the
    focal length halved: the corner at 0.53 rad, past where the radius stops rising, 0.35 rad) are refused, naming
    the file and the fold."""
    path = _write(tmp_path, TELEPHOTO)
    profile, _ = profile_from_gyroflow(path, lowcam.load_profile("fire-i"))
    x, y, theirs = _opencv_pixels(TELEPHOTO, seed=DRAW_SEED + 2)
    u, v = profile.effect("lens_distortion").model_for(3840, 2160).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - theirs).max() < 0.01
    wide = json.loads(json.dumps(TELEPHOTO))
    k = wide["fisheye_params"]["camera_matrix"]
    k[0][0], k[1][1] = k[0][0] / 2, k[1][1] / 2
    # OpenCV's own radius along the diagonal stops rising before the corner: an independent check of the refusal
    corner = np.hypot(3840 - 0.5 - k[0][2], 1056.99 + 0.5)           # the farthest corner from the centre, px
    theta = np.linspace(0.0, 1.2, 2000)
    rays = np.stack([np.tan(theta), np.zeros_like(theta)], -1)[:, None]
    radius = cv2.fisheye.distortPoints(rays, np.array(k), np.array(wide["fisheye_params"]["distortion_coeffs"]))[
        :, 0, 0] - k[0][2]
    assert np.any(np.diff(radius[radius <= corner]) < 0) or radius.max() < corner
    path = _write(tmp_path, wide, "wide.json")
    with pytest.raises(LowcamError, match="wide.json: the lens folds over inside the 3840x2160 frame"):
        profile_from_gyroflow(path, lowcam.load_profile("fire-i"))


def test_an_anamorphic_stretch_is_taken_out_as_gyroflow_takes_it(tmp_path):
    """An anamorphic calibration (``input_horizontal_stretch`` 1.5 of a 1920x1080 recording, calibrated
    stretched at 2880x1080): the profile delivers the recorded 1920x1080 and puts each ray where OpenCV's fisheye
    in the stretched frame does, its x divided by 1.5 (Gyroflow: ``uv.x /= input_horizontal_stretch``), within
    0.01 px; non-square pixels (fx / fy = 1 / 1.5)."""
    doc = dict(GOPRO, calib_dimension={"w": 2880, "h": 1080}, input_horizontal_stretch=1.5,
               input_vertical_stretch=1.0)
    doc["fisheye_params"] = dict(GOPRO["fisheye_params"], camera_matrix=[[1400.0, 0.0, 1441.3], [0.0, 1401.0, 538.2],
                                                                          [0.0, 0.0, 1.0]])
    profile, notes = profile_from_gyroflow(_write(tmp_path, doc), lowcam.load_profile("fire-i"))
    assert (profile.camera.width, profile.camera.height) == (1920, 1080)
    assert "anamorphic stretch 1.5x1 taken out (2880x1080 -> 1920x1080)" in notes[0]
    lens = profile.effect("lens_distortion")
    assert lens.fx_px == pytest.approx(1400.0 / 1.5) and lens.fy_px == pytest.approx(1401.0)
    x, y, theirs = _opencv_pixels(doc, seed=DRAW_SEED + 3, stretch=(1.5, 1.0))
    u, v = lens.model_for(1920, 1080).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - theirs).max() < 0.01


def test_negative_focal_lengths_are_the_picture_turned_and_a_negative_readout_reads_from_the_bottom(tmp_path):
    """Focal lengths both negative (some files: a picture turned 180 deg) give the same pixels as OpenCV's
    projection of the ray turned 180 deg about the axis; a negative ``frame_readout_time`` (Gyroflow: read from the
    bottom row up) becomes a negative read-out: the bottom row first."""
    doc = json.loads(json.dumps(GOPRO))
    k = doc["fisheye_params"]["camera_matrix"]
    k[0][0], k[1][1] = -k[0][0], -k[1][1]
    doc["frame_readout_time"] = -12.5
    profile, notes = profile_from_gyroflow(_write(tmp_path, doc), lowcam.load_profile("fire-i"))
    x, y, theirs = _opencv_pixels(doc, seed=DRAW_SEED + 4)
    u, v = profile.effect("lens_distortion").model_for(1920, 1440).distort(-x, -y)
    assert np.abs(np.stack([u, v], -1) - theirs).max() < 0.01
    assert profile.effect("rolling_shutter").readout_s == pytest.approx(-0.0125)
    assert any("12.5 ms from the bottom row up" in n for n in notes)
    assert "turned 180 degrees" in profile.provenance["lens_distortion"]


@pytest.mark.slow         # reading the whole archive: about 5 s
@pytest.mark.skipif(not DATABASE.is_file(), reason="../shared/data/gyroflow-lens-profiles is not beside the checkout")
def test_a_seeded_draw_from_gyroflows_database_matches_opencv_or_is_refused_for_a_fold(tmp_path):
    """40 files drawn (LOWCAM_DRAW_SEED) from Gyroflow's whole database (CC0): each imports with the README's
    command's defaults and its lens puts a seeded draw of rays inside the calibrated frame where OpenCV's
    ``cv2.fisheye.distortPoints`` does (over the stretch), within 0.01 px, its radius stopping short of the corners
    only where OpenCV's does so for at most 2 % of the frame; or it is refused in one line naming the file, for a
    digital lens, or for a fold that OpenCV's own radius shows: it stops rising with more than 2 % of the frame
    beyond."""
    files = {}
    with tarfile.open(DATABASE, "r|xz") as tar:            # one pass through the archive, in its order
        for member in tar:
            if member.isfile() and member.name.endswith(".json"):
                files[member.name] = tar.extractfile(member).read()
    names = sorted(files)
    drawn = [names[i] for i in np.random.default_rng(DRAW_SEED).choice(len(names), 40, replace=False)]
    fire_i, imported = lowcam.load_profile("fire-i"), 0
    for i, name in enumerate(drawn):
        path = tmp_path / f"{i:02d}-{Path(name).name}"
        path.write_bytes(files[name])
        doc = json.loads(path.read_text())
        stretch = tuple(doc.get(key) if (doc.get(key) or 0) > 0.01 else 1.0
                        for key in ("input_horizontal_stretch", "input_vertical_stretch"))
        try:
            profile, _ = profile_from_gyroflow(path, fire_i)
        except LowcamError as e:
            assert str(e).startswith(str(path)) and "\n" not in str(e)
            if "digital_lens" in str(e):
                continue
            assert "folds over inside" in str(e), str(e)
            p = doc["fisheye_params"]
            k, d = np.array(p["camera_matrix"], np.float64), np.array(p["distortion_coeffs"], np.float64)
            w, h = doc["calib_dimension"]["w"], doc["calib_dimension"]["h"]
            if "the fisheye distortion folds over" in str(e):   # the profile's own check: the centred frame
                w, h = int(2 * k[0, 2] + 1), int(2 * k[1, 2] + 1)
            assert _opencv_share_beyond_the_peak(k, d, w, h)[2] > 0.019, path.name
            continue
        imported += 1
        if "the calibration's radius stops rising" in profile.provenance["lens_distortion"]:
            p = doc["fisheye_params"]
            k, d = np.array(p["camera_matrix"], np.float64), np.array(p["distortion_coeffs"], np.float64)
            assert _opencv_share_beyond_the_peak(k, d, doc["calib_dimension"]["w"], doc["calib_dimension"]["h"])[2] \
                < 0.021, path.name
        lens = profile.effect("lens_distortion")
        w, h = profile.camera.width, profile.camera.height
        x, y, theirs = _opencv_pixels(doc, n=100, seed=DRAW_SEED + i, stretch=stretch)
        u, v = lens.model_for(w, h).distort(-x, -y) if np.array(doc["fisheye_params"]["camera_matrix"])[0, 0] < 0 \
            else lens.model_for(w, h).distort(x, y)
        inside = (theirs[:, 0] < w - 0.5) & (theirs[:, 1] < h - 0.5)    # a frame cut to a multiple of 4 by 2
        assert np.abs(np.stack([u, v], -1) - theirs)[inside].max() < 0.01, path.name
    assert imported >= 30


@pytest.mark.parametrize("name, frame, readout_ms", [("iphone-12-hd", (1920, 1080), 6.6),
                                                     ("gopro-hero8-hd", (1920, 1080), 4.17083)])
def test_the_bundled_16_by_9_profiles_state_where_every_number_came_from(name, frame, readout_ms):
    """The bundled HD phone and action camera: 16:9 frames, a Gyroflow calibration's lens and read-out, every
    effect and the camera with a provenance entry (the rest from phone-video, said so), and they render: the
    pinhole field a render must cover is found."""
    profile = lowcam.load_profile(name)
    assert (profile.camera.width, profile.camera.height) == frame
    assert "Gyroflow lens profile" in profile.provenance["lens_distortion"]
    assert profile.effect("rolling_shutter").readout_s == pytest.approx(readout_ms / 1000)
    assert "(from base phone-video)" in profile.provenance["camera"]
    for e in profile.effects:
        assert profile.provenance_of(e.name) and "not stated" not in profile.provenance_of(e.name), e.name
    cam = lowcam.render_camera(name, 1920)
    assert cam["projection"] == "pinhole" and cam["height"] == 1080


@pytest.mark.skipif(not DATABASE.is_file(), reason="../shared/data/gyroflow-lens-profiles is not beside the checkout")
def test_the_bundled_16_by_9_profiles_are_what_their_script_makes(tmp_path):
    """profiles/make_profiles.sh's from-gyroflow commands, run again on the files of Gyroflow's database: the same
    profiles, value for value."""
    import shlex

    from lowcam.profile import BUNDLED_PROFILES

    script = (BUNDLED_PROFILES / "make_profiles.sh").read_text()
    wanted = {v: shlex.split(script.split(f"\n{v}=", 1)[1].splitlines()[0])[0] for v in ("PHONE", "ACTION")}
    with tarfile.open(DATABASE, "r|xz") as tar:
        for member in tar:
            if member.name in wanted.values():
                (tmp_path / Path(member.name).name).write_bytes(tar.extractfile(member).read())
    for var, name in (("PHONE", "iphone-12-hd"), ("ACTION", "gopro-hero8-hd")):
        path = tmp_path / Path(wanted[var]).name
        assert main(["profile", "from-gyroflow", str(path), "--base", str(BUNDLED_PROFILES / "phone-video.toml"),
                     "-o", str(tmp_path / f"{name}.toml")]) == 0
        bundled, again = lowcam.load_profile(name), lowcam.load_profile(tmp_path / f"{name}.toml")
        assert (bundled.camera.width, bundled.camera.height, bundled.camera.exposure_s) == \
            (again.camera.width, again.camera.height, again.camera.exposure_s)
        def values(profile):    # a texture's path is written relative to the profile: compare where it leads
            return [{k: (Path(e.base_dir, v).resolve() if k == "texture" and v else v) for k, v in e.values().items()}
                    for e in profile.effects]
        assert values(bundled) == values(again), name
        assert bundled.provenance == again.provenance


@pytest.mark.parametrize("value", [None, "x", [], {}, -1, 0, 1e308, True, [[1, 2], [3]], {"w": "1"}])
def test_any_value_of_any_key_is_a_profile_or_one_line(tmp_path, value):
    """Every key of a real lens profile (and the anamorphic, digital-lens and read-out keys), each given a value of
    another kind: the file either makes a profile or is refused in one line naming it; never another exception."""
    keys = [*GOPRO, "input_horizontal_stretch", "input_vertical_stretch", "digital_lens", "frame_readout_direction"]
    fire_i = lowcam.load_profile("fire-i")
    for i, key in enumerate(keys + ["fisheye_params.camera_matrix", "fisheye_params.distortion_coeffs"]):
        doc = json.loads(json.dumps(GOPRO))
        where, _, inner = key.partition(".")
        (doc[where] if inner else doc)[inner or key] = value
        path = _write(tmp_path, doc, f"lens{i}.json")
        try:
            profile_from_gyroflow(path, fire_i)
        except LowcamError as e:
            assert str(e).startswith(str(path)) and "\n" not in str(e), str(e)
