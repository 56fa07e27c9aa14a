"""Gyroflow lens profiles into Lowcam profiles (``lowcam profile from-gyroflow``), checked against OpenCV.

The fisheye numbers are those of a published Gyroflow profile (GoPro HERO11 Black, Wide, 1920x1440 at 59.94 fps,
calibrated by Eric John Gangob, from https://github.com/gyroflow/lens_profiles); the files are written here. Each
lens is checked against OpenCV's own projection at the calibration size (``cv2.fisheye.distortPoints``,
``cv2.projectPoints``), scaled to the profile's frame: ``u' = (u + 1/2) s - 1/2``.
"""
import json

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.cli import main
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
    assert main(["profile", "from-gyroflow", str(path), "--base", "fire-i", "-o", str(tmp_path / "gopro.toml")]) == 0
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
    profile, notes = profile_from_gyroflow(_write(tmp_path, doc), lowcam.load_profile("fire-i"))
    x, y = _rays(max_deg=35.0)
    theirs = cv2.projectPoints(np.stack([x, y, np.ones_like(x)], -1)[:, None], np.zeros(3), np.zeros(3),
                               np.array(k), np.array(d))[0][:, 0]
    u, v = profile.effect("lens_distortion").model_for(640, 480).distort(x, y)
    assert np.abs(np.stack([u, v], -1) - ((theirs + 0.5) / 2 - 0.5)).max() < 1e-6
    assert profile.effect("rolling_shutter").readout_s == pytest.approx(0.0215)
    assert any("21.5 ms" in n for n in notes) and "21.5 ms" in profile.provenance["rolling_shutter"]


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(calib_dimension={"w": 1920, "h": 1080}), "the calibration's aspect ratio"),
    (lambda d: d.update(distortion_model="sony"), "'sony' lens model is not one Lowcam reads"),
    (lambda d: d["fisheye_params"].update(distortion_coeffs=[0.1, 0.2]), "distortion_coeffs must hold 4"),
    (lambda d: d["fisheye_params"]["camera_matrix"][0].__setitem__(0, float("nan")), "not a finite number"),
    (lambda d: d["fisheye_params"]["camera_matrix"][0].__setitem__(0, "850"), "camera_matrix[0][0]"),
    (lambda d: d.pop("calib_dimension"), "not a Gyroflow lens profile"),
    (lambda d: d["fisheye_params"].update(distortion_coeffs=[-0.9, 0.0, 0.0, 0.0]), "folds over inside the frame"),
])
def test_a_file_lowcam_cannot_read_is_one_line_naming_it(tmp_path, capsys, change, message):
    doc = json.loads(json.dumps(GOPRO))
    change(doc)
    path = _write(tmp_path, doc)
    code = main(["profile", "from-gyroflow", str(path), "--base", "fire-i", "-o", str(tmp_path / "out.toml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(path) in err and message in err, err
    assert not (tmp_path / "out.toml").exists()


def test_a_file_that_is_not_json_is_one_line(tmp_path, capsys):
    path = tmp_path / "lens.json"
    path.write_bytes(b"\x00\xffnot json")
    assert main(["profile", "from-gyroflow", str(path), "-o", str(tmp_path / "out.toml")]) == 2
    err = capsys.readouterr().err
    assert "not UTF-8" in err and str(path) in err and len(err.strip().splitlines()) == 1
    assert main(["profile", "from-gyroflow", "/dev/zero", "-o", str(tmp_path / "out.toml")]) == 2
    assert "/dev/zero: is a device" in capsys.readouterr().err
