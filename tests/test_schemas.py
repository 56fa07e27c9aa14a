"""Schemas at every edge: every bad value in a user's file is a one-line LowcamError naming the file and the key.

Each case builds a bad file in ``tmp_path`` and checks the error: a :class:`~lowcam.errors.LowcamError` (a
:class:`~lowcam.errors.ProfileError` for profiles), one line, naming the file and the key or row, never a
traceback of another type.
"""
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

import lowcam
from lowcam import LowcamError, ProfileError, schema
from lowcam.captures import parse_target, read_chart_layout, read_patches_csv
from lowcam.effects.chromatic_aberration import CSV_COLUMNS, read_ca_grid
from lowcam.measure.sets import load_set
from lowcam.motion import gyro_to_motion, read_gyro_csv, read_motion_json
from lowcam.profile import BUNDLED_PROFILES

FIRE_I_TEXT = (BUNDLED_PROFILES / "fire-i.toml").read_text()


def refused(call, *names, error=LowcamError):
    """Run ``call``; it must raise ``error`` with a one-line message naming each of ``names``."""
    with pytest.raises(error) as e:
        call()
    message = str(e.value)
    assert "\n" not in message, message
    for name in names:
        assert str(name) in message, (name, message)
    return message


def refused_file(path, content: bytes, read, *names):
    """Write ``content`` to ``path``; ``read(path)`` must refuse it in one line that starts with the path."""
    path.write_bytes(content)
    assert refused(lambda: read(path), *names).startswith(str(path))


# --- the helpers ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("value, key_part", [
    (float("inf"), "finite"), (float("nan"), "finite"), (True, "number"), ("3", "number"), (None, "number"),
    (10 ** 400, "finite"), (-1.0, "out of range"), (11, "out of range"),
])
def test_number_refuses_non_finite_bools_strings_and_out_of_range(value, key_part):
    message = refused(lambda: schema.number(value, "f.toml: [t]", "k", 0.0, 10.0), "f.toml: [t]", "'k'", key_part)
    assert message.startswith("f.toml")


def test_integer_boolean_string_table_numbers():
    assert schema.integer(24.0, "f", "k") == 24 and isinstance(schema.integer(24.0, "f", "k"), int)
    refused(lambda: schema.integer(2.5, "f", "k"), "'k' must be a whole number")
    refused(lambda: schema.integer(float("inf"), "f", "k"), "'k' must be a finite number")
    refused(lambda: schema.integer(True, "f", "k"), "'k' must be a number")
    refused(lambda: schema.boolean(1, "f", "k"), "'k' must be true or false")
    refused(lambda: schema.string(5, "f", "k"), "'k' must be a string")
    refused(lambda: schema.string("x", "f", "k", choices=("a", "b")), "'k' must be one of a, b")
    refused(lambda: schema.table(5, "f", "k"), "'k' must be a table")
    refused(lambda: schema.table({"a": 1, "z": 2}, "f", "k", known={"a"}), "unknown key 'z'")
    refused(lambda: schema.table({}, "f", "k", required=("a",)), "'k' needs 'a'")
    refused(lambda: schema.numbers([1, "x"], "f", "v"), "'v[1]' must be a number")
    refused(lambda: schema.numbers([1, 2], "f", "v", length=3), "'v' must have 3 entries")
    refused(lambda: schema.numbers([1, 2e7], "f", "v", high=100), "'v[1]' = 20000000.0 is out of range")
    assert schema.numbers([1, 2.0], "f", "v", whole=True) == [1, 2]


@pytest.mark.parametrize("content, problem", [
    (b"{", "not valid JSON"), (b'{"a": 1e400}', "1e400"), (b'{"a": NaN}', "NaN"), (b'{"a": -Infinity}', "Infinity"),
    (b"\xff\xfe\x00\x01", "not UTF-8"), (b"[" * 100000, "not valid JSON"), (b'{"a": ' + b"9" * 5000 + b"}", "JSON"),
])
def test_read_json_refuses_bad_files(tmp_path, content, problem):
    path = tmp_path / "doc.json"
    path.write_bytes(content)
    refused(lambda: schema.read_json(path, "document"), path, problem)


def test_read_number_csv_takes_a_byte_order_mark_and_refuses_devices(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_bytes("\ufeffa,b\r\n1,2\r\n".encode())
    data, lines = schema.read_number_csv(path, ["a", "b"], "table")
    assert data.tolist() == [[1.0, 2.0]] and lines.tolist() == [2]
    refused(lambda: schema.read_number_csv("/dev/zero", ["a"], "gyro CSV"), "/dev/zero", "is a device")


def test_read_text_refuses_missing_files_and_folders(tmp_path):
    refused(lambda: schema.read_text(tmp_path / "none.json", "motion file"), "none.json", "no such motion file")
    (tmp_path / "dir.json").mkdir()
    refused(lambda: schema.read_text(tmp_path / "dir.json", "motion file"), "dir.json", "is a folder")
    refused(lambda: schema.read_toml(tmp_path / "x" / ("a" * 5000), "profile"), "cannot read the profile")


# --- profiles ------------------------------------------------------------------------------------------------------

def _variant(tmp_path, old, new, name="variant.toml"):
    text = FIRE_I_TEXT.replace(old, new, 1)
    assert text != FIRE_I_TEXT
    path = tmp_path / name
    path.write_text(text)
    if not (tmp_path / "fire-i").exists():  # the textures are found relative to the profile file
        (tmp_path / "fire-i").symlink_to(BUNDLED_PROFILES / "fire-i")
    return path


@pytest.mark.parametrize("old, new, names", [
    ("[camera]", "effect = [1, 2]\n[camera]", ["effect"]),
    ('type = "half_sampling"', "type = 5", ["[[effect]] number 2", "'type' must be a string"]),
    ('type = "half_sampling"', 'type = ":X"', ["':X'", "module:Class"]),
    ('type = "half_sampling"', 'type = "a:"', ["'a:'", "module:Class"]),
    ('type = "half_sampling"', 'type = "json:dumps"', ["'json:dumps'", "not a lowcam.effects.Effect"]),
    ('type = "half_sampling"', 'type = "no_such_module_xyz:Effect"', ["cannot be loaded"]),
    ('type = "half_sampling"', 'enabled = 1\ntype = "half_sampling"', ["'enabled' must be true or false"]),
    ("width = 640", "width = inf", ["[camera]", "'width' must be a finite number in [16, 16384], got inf"]),
    ("width = 640", "width = nan", ["'width' must be a finite number", "nan"]),
    ("width = 640", "width = true", ["'width' must be a number"]),
    ("width = 640", "width = 1e300", ["'width'", "out of range"]),
    ("width = 640", "width = 640.5", ["'width' must be a whole number"]),
    ("exposure_s = 0.033", "exposure_s = -inf", ["'exposure_s' must be a finite number"]),
    ('bayer_pattern = "GBRG"', "bayer_pattern = 4", ["'bayer_pattern' must be a string"]),
    ("sigma = 0.7", "sigma = inf", ["effect 'horizontal_blur'", "'sigma' must be a finite number in [0.0, 10.0]"]),
    ("sigma = 0.7", "sigma = nan", ["'sigma' must be a finite number"]),
    ("taps = 16", "taps = 1e400", ["effect 'motion_blur'", "'taps' must be a finite number"]),
    ("grid = [24.0, 18.0]", "grid = [1e7, 1e7]", ["effect 'motion_blur'", "'grid[0]'", "out of range"]),
    ("grid = [24.0, 18.0]", "grid = [24.5, 18.0]", ["'grid[0]' must be a whole number"]),
    ("grid = [24.0, 18.0]", "grid = [24.0]", ["'grid' must have 2 entries"]),
    ("grid = [24.0, 18.0]", 'grid = [24.0, "18"]', ["'grid[1]' must be a number"]),
    ("grid = [24.0, 18.0]", "grid = [nan, 18.0]", ["'grid[0]' must be a finite number"]),
    ("grid = [24.0, 18.0]", "grid = 24", ["'grid' must be a list"]),
    ("red = [1.5, 0.015]", "red = [-300.0, 0.015]", ["effect 'noise'", "'red[0]'", "out of range"]),
    ("red = [1.5, 0.015]", "red = [inf, 0.015]", ["'red[0]' must be a finite number"]),
    ("matrix = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]",
     "matrix = [[0.95, 0.04, 0.01], [0.07, 0.89], [0.00, 0.06, 0.94]]", ["'matrix[1]' must have 3 entries"]),
    ("matrix = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]",
     "matrix = [[0.95, 0.04, 0.01], [0.07, nan, 0.04], [0.00, 0.06, 0.94]]", ["'matrix[1][1]' must be a finite"]),
    ("matrix = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]",
     "matrix = [[1e9, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]", ["'matrix[0][0]'", "out of range"]),
    ("matrix = [[0.95, 0.04, 0.01], [0.07, 0.89, 0.04], [0.00, 0.06, 0.94]]", "matrix = [1, 2, 3]",
     ["'matrix[0]' must be a list"]),
    ("saturation = 90.0", "saturation = 90.0\nluma = [0.3, 0.6, -0.1]", ["'luma[2]'", "out of range"]),
    ('model = "fov"', 'model = "fov"\nprincipal_point = [1e9, 0]', ["'principal_point[0]'", "out of range"]),
    ('texture = "fire-i/vignetting.png"', "texture = 5", ["'texture' must be a string"]),
    ('texture = "fire-i/vignetting.png"', f'texture = "{"a" * 5000}"', ["'texture' names a file that does not"]),
])
def test_bad_profiles_are_one_line_profile_errors(tmp_path, monkeypatch, old, new, names):
    monkeypatch.setenv("LOWCAM_PLUGINS", "json,no_such_module_xyz")  # trusted: the class check is what is tested
    path = _variant(tmp_path, old, new)
    message = refused(lambda: lowcam.load_profile(path), *names, error=ProfileError)
    assert message.startswith(str(path))


def test_a_camera_that_is_not_a_table_is_refused(tmp_path):
    path = tmp_path / "camera5.toml"
    path.write_text("camera = 5\n" + FIRE_I_TEXT[FIRE_I_TEXT.index("[[effect]]"):])
    refused(lambda: lowcam.load_profile(path), path, "'camera' must be a table, got 5", error=ProfileError)


def test_a_plugin_that_fails_on_import_is_a_profile_error(tmp_path, monkeypatch):
    (tmp_path / "broken_plugin_xyz.py").write_text("raise RuntimeError('boom')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "broken_plugin_xyz")
    path = _variant(tmp_path, 'type = "half_sampling"', 'type = "broken_plugin_xyz:Haze"')
    refused(lambda: lowcam.load_profile(path), path, "fails on import", "RuntimeError: boom", error=ProfileError)


def test_unreadable_profile_files_are_profile_errors(tmp_path):
    path = tmp_path / "binary.toml"
    path.write_bytes(b"\xff\xfe[camera]\x00")
    refused(lambda: lowcam.load_profile(path), path, "not UTF-8", error=ProfileError)
    (tmp_path / "folder.toml").mkdir()
    refused(lambda: lowcam.load_profile(tmp_path / "folder.toml"), "folder.toml", "is a folder", error=ProfileError)
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000)
    refused(lambda: lowcam.load_profile(deep), deep, "not valid TOML", error=ProfileError)
    huge = tmp_path / "huge.toml"
    huge.write_text("a = " + "9" * 5000)
    refused(lambda: lowcam.load_profile(huge), huge, "not valid TOML", error=ProfileError)


def test_lowcam_profiles_lists_bad_profiles_as_invalid_and_goes_on(tmp_path):
    folder = tmp_path / "profiles"
    folder.mkdir()
    (folder / "binary.toml").write_bytes(b"\xff\xfe\x00\x01")
    (folder / "dir.toml").mkdir()
    (folder / "camera5.toml").write_text("camera = 5\n")
    (folder / "inf.toml").write_text(FIRE_I_TEXT.replace("width = 640", "width = inf"))
    (folder / "fire-i").symlink_to(BUNDLED_PROFILES / "fire-i")
    env = dict(os.environ, LOWCAM_PROFILE_PATH=str(folder))
    r = subprocess.run([sys.executable, "-m", "lowcam.cli", "profiles"], capture_output=True, text=True, env=env,
                       timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    lines = {line.split()[0]: line for line in r.stdout.splitlines() if line.strip()}
    for name in ("binary", "dir", "camera5", "inf"):
        assert "INVALID" in lines[name], lines[name]
    assert "INVALID" not in lines["fire-i"] and "INVALID" not in lines["ueye"]


@pytest.mark.parametrize("name", sorted(p.stem for p in BUNDLED_PROFILES.glob("*.toml")))
def test_bundled_profiles_still_load(name):
    p = lowcam.load_profile(name)
    assert p.camera.width > 0 and p.effects


def test_a_saved_profile_round_trips_through_the_schemas(tmp_path):
    saved = lowcam.load_profile("fire-i").save(tmp_path / "copy.toml")
    assert lowcam.load_profile(saved).to_dict()["effect"][3] == lowcam.load_profile("fire-i").to_dict()["effect"][3]


# --- chromatic-aberration CSV --------------------------------------------------------------------------------------

def _ca_rows(offset=0.5):
    return [f"{u},{v},{offset},0,{-offset},0" for v in (10, 30) for u in (10, 30)]


@pytest.mark.parametrize("content, names", [
    (b"", ["is empty"]),
    (",".join(CSV_COLUMNS).encode(), ["0 data row(s)"]),
    (b"u\n1\n2\n3\n4\n", ["needs a header naming u,v,red_du"]),
    (b"\x89PNG\r\n\x1a\n\x00\x00\xff", ["not UTF-8"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()[:3] + ["30,30,nan,0,0,0"]).encode(),
     ["line 5", "'red_du' must be a finite number"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows(1e6)).encode(), ["line 2", "'red_du' = 1000000.0", "out of range"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()[:3] + ["30,30,x,0,0,0"]).encode(), ["line 5", "'red_du'"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()[:3] + ["30,30,0,0"]).encode(), ["line 5", "4 values"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()[:3] + ["10,10,0,0,0,0"]).encode(), ["listed twice"]),
    ("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()[:3] + ["50,30,0,0,0,0"]).encode(), ["full grid"]),
])
def test_bad_chromatic_aberration_grids_are_refused(tmp_path, content, names):
    refused_file(tmp_path / "ca.csv", content, read_ca_grid, *names)


def test_a_bad_grid_in_a_profile_names_the_profile_the_key_and_the_csv(tmp_path):
    (tmp_path / "ca.csv").write_text("\n".join([",".join(CSV_COLUMNS)] + _ca_rows(1e6)))
    path = _variant(tmp_path, 'texture = "fire-i/chromatic_aberration.csv"', 'texture = "ca.csv"')
    message = refused(lambda: lowcam.load_profile(path), "effect 'chromatic_aberration'", "'texture'", "ca.csv",
                      "'red_du'", error=ProfileError)
    assert message.startswith(str(path))


def test_a_good_grid_reads(tmp_path):
    path = tmp_path / "ca.csv"
    path.write_text("\n".join([",".join(CSV_COLUMNS)] + _ca_rows()) + "\n")
    assert read_ca_grid(path).shape == (2, 2, 4)


# --- motion.json and gyro CSV --------------------------------------------------------------------------------------

def _motion(tmp_path, frames, **top):
    path = tmp_path / "motion.json"
    doc = {"format": "lowcam-motion", "version": 1, "frames": frames, **top}
    path.write_text(json.dumps(doc) if not isinstance(frames, str) else
                    '{"format": "lowcam-motion", "frames": ' + frames + "}")
    return path


W = [0.0, 0.5, 0.0]


@pytest.mark.parametrize("frames, top, names", [
    (None, {}, ["'frames' must be a list"]),
    ('[{"frame": 1, "angular_velocity": [1e400, 0, 0]}]', {}, ["1e400", "not a finite number"]),
    ('[{"frame": 1, "angular_velocity": [NaN, 0, 0]}]', {}, ["NaN"]),
    ([{"frame": 1.5, "angular_velocity": W}], {}, ["frames[0]", "'frame' must be a whole number"]),
    ([{"frame": True, "angular_velocity": W}], {}, ["frames[0]", "'frame' must be a number"]),
    ([{"frame": 1, "angular_velocity": W}, {"frame": 1, "angular_velocity": W}], {},
     ["frames[1]", "frame 1 is listed twice"]),
    ([{"frame": 1, "angular_velocity": W, "exposure_s": -0.01}], {}, ["frames[0]", "'exposure_s'", "out of range"]),
    ([{"frame": 1, "angular_velocity": W, "exposure_s": "fast"}], {}, ["'exposure_s' must be a number"]),
    ([{"frame": 1, "angular_velocity": [0, 1]}], {}, ["'angular_velocity' must have 3 entries"]),
    ([{"frame": 1, "angular_velocity": [0, "a", 1]}], {}, ["'angular_velocity[1]' must be a number"]),
    ([{"frame": 1, "angular_velocity": [0, 1e6, 1]}], {}, ["'angular_velocity[1]'", "out of range"]),
    ([{"frame": 1}], {}, ["frames[0]", "needs 'angular_velocity'"]),
    ([5], {}, ["frames[0]", "must be a table"]),
    ([{"frame": 1, "angular_velocity": W, "speed": 3}], {}, ["unknown key 'speed'"]),
    ([], {"fps": 0}, ["'fps'", "out of range"]),
    ([], {"extra": 1}, ["unknown key 'extra'"]),
])
def test_bad_motion_files_are_refused(tmp_path, frames, top, names):
    path = _motion(tmp_path, frames, **top)
    message = refused(lambda: read_motion_json(path), *names)
    assert message.startswith(str(path))


def test_good_motion_files_read(tmp_path):
    path = _motion(tmp_path, [{"frame": 1, "angular_velocity": W, "exposure_s": 0.02},
                              {"frame": 2.0, "angular_velocity": W}])
    motion = read_motion_json(path)
    assert motion[1].exposure_s == 0.02 and motion[2].exposure_s is None and motion[2].angular_velocity == (0, 0.5, 0)


@pytest.mark.parametrize("content, names", [
    (b"", ["is empty"]),
    (b"t,wx,wy,wz\n", ["0 data row(s)"]),
    (b"t,wx,wy,wz\n0,0,0,0\n", ["1 data row(s)"]),
    (b"\x00\xff\xfe binary", ["not UTF-8"]),
    (b"t,wx,wy\n0,0,0\n1,0,0\n", ["needs a header naming t,wx,wy,wz"]),
    (b"t,wx,wy,wz\n0,0,0,0\nnan,0,0,0\n", ["line 3", "'t' must be a finite number"]),
    (b"t,wx,wy,wz\n0,0,0,0\n1,0,0\n", ["line 3", "3 values"]),
    (b"t,wx,wy,wz\n0,0,0,0\n1,0,zero,0\n", ["line 3", "'wy' must be a number"]),
    (b"t,wx,wy,wz\n0,0,0,0\n1,0,0,0\n1,0,0,0\n", ["line 4", "'t' = 1 s", "times must increase"]),
    (b"t,wx,wy,wz\n0,0,0,0\n1,0,0,0\n0.5,0,0,0\n", ["line 4", "times must increase"]),
    (b"t wx wy wz\n0 0 0 0\n1 0 0 1e9\n", ["line 3", "'wz'", "out of range"]),
])
def test_bad_gyro_logs_are_refused(tmp_path, content, names):
    refused_file(tmp_path / "gyro.csv", content, read_gyro_csv, *names)


def test_a_good_gyro_log_reads_and_bad_rates_are_refused(tmp_path):
    path = tmp_path / "gyro.csv"
    path.write_text("# a comment\nwz, t, wx, wy\n0.3, 0.0, 0.1, 0.2\n\n0.3, 1.0, 0.1, 0.2\n")
    samples = read_gyro_csv(path)
    assert samples.tolist() == [[0.0, 0.1, 0.2, 0.3], [1.0, 0.1, 0.2, 0.3]]
    assert gyro_to_motion(samples, [1], 24.0, 0.02, source=str(path))[1].angular_velocity == pytest.approx((.1, .2, .3))
    refused(lambda: gyro_to_motion(samples, [1], 0.0, 0.02, source=str(path)), path, "'fps'")
    refused(lambda: gyro_to_motion(samples, [1], 24.0, float("nan"), source=str(path)), path, "'exposure_s'")


# --- set.toml ------------------------------------------------------------------------------------------------------

def _set(tmp_path, capture: str):
    folder = tmp_path / "set"
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    lowcam.write_png(folder / "frames" / "a-000.png", np.full((48, 64, 3), 100, np.uint8))
    (folder / "set.toml").write_text(capture)
    return folder


GOOD_CAPTURE = '[[capture]]\nname = "a"\ntarget = "checkerboard:9x6:0.025"\nframes = ["frames/a-*.png"]\n'


@pytest.mark.parametrize("text, names", [
    ("capture = 5\n", ["'capture' must be a list"]),
    ("capture = [5]\n", ["capture 1: must be a table"]),
    ("colour = 1\n" + GOOD_CAPTURE, ["unknown key 'colour'"]),
    (GOOD_CAPTURE + "speed = 3\n", ["capture 1", "unknown key 'speed'"]),
    (GOOD_CAPTURE + 'angular_velocity = ["a", 0, 0]\n', ["capture 'a'", "'angular_velocity[0]' must be a number"]),
    (GOOD_CAPTURE + "angular_velocity = [0, 0]\n", ["'angular_velocity' must have 3 entries"]),
    (GOOD_CAPTURE + "angular_velocity = 0.5\n", ["'angular_velocity' must be a list"]),
    (GOOD_CAPTURE + 'exposure_s = "fast"\n', ["capture 'a'", "'exposure_s' must be a number"]),
    (GOOD_CAPTURE + "exposure_s = -0.01\n", ["'exposure_s' = -0.01 s is out of range"]),
    (GOOD_CAPTURE + "exposure_s = nan\n", ["'exposure_s' must be a finite number"]),
    (GOOD_CAPTURE.replace('name = "a"', "name = 5"), ["capture 1", "'name' must be a string"]),
    (GOOD_CAPTURE.replace("frames = [\"frames/a-*.png\"]", "frames = 5"), ["'frames' must be a list"]),
    (GOOD_CAPTURE.replace("frames = [\"frames/a-*.png\"]", "frames = []"), ["'frames' must have at least 1"]),
    (GOOD_CAPTURE.replace("frames/a-*", "frames/b-*"), ["'frames': no file matches", "frames/b-*.png"]),
    (GOOD_CAPTURE.replace('"frames/a-*.png"', '"frames/a-*.png", "frames/a-007.png"'),
     ["'frames'", "frames/a-007.png: no such file"]),   # a name without a wildcard must be there
    (GOOD_CAPTURE.replace('target = "checkerboard:9x6:0.025"', 'ideal = "ideal/a.exr"'),
     ["'ideal' names a file that does not exist", "ideal/a.exr"]),
    (GOOD_CAPTURE + 'plate = "plates/a.png"\n', ["'plate' names a file that does not exist", "plates/a.png"]),
    (GOOD_CAPTURE.replace("9x6:0.025", "9x6:nan"), ["capture 'a'", "'target'", "'square' must be a finite"]),
    (GOOD_CAPTURE.replace("9x6:0.025", "0x6:0.025"), ["'target'", "'columns' = 0 is out of range"]),
    (GOOD_CAPTURE.replace("9x6:0.025", "9x6"), ["'target'", "use checkerboard:COLSxROWS"]),
    (GOOD_CAPTURE.replace('"checkerboard:9x6:0.025"', "5"), ["'target' must be a string"]),
    (GOOD_CAPTURE.replace('"checkerboard:9x6:0.025"', '"charuco"'), ["'target': only checkerboard targets"]),
    (GOOD_CAPTURE + GOOD_CAPTURE, ["capture 'a'", "a second capture of that name"]),
    (GOOD_CAPTURE + 'ideal = "x.exr"\n', ["give exactly one of 'ideal' and 'target'"]),
    ("", ["no [[capture]] entries"]),
])
def test_bad_measurement_sets_are_refused(tmp_path, text, names):
    folder = _set(tmp_path, text)
    message = refused(lambda: load_set(folder), *names)
    assert message.startswith(str(folder / "set.toml"))


def test_a_good_measurement_set_loads_and_a_missing_one_is_named(tmp_path):
    folder = _set(tmp_path, GOOD_CAPTURE + "angular_velocity = [0, 0.5, 0]\nexposure_s = 0.02\n")
    capture = load_set(folder).captures[0]
    assert capture.angular_velocity == (0.0, 0.5, 0.0) and capture.exposure_s == 0.02
    assert capture.target == "checkerboard:9x6:0.025" and capture.frames.shape == (1, 48, 64, 3)
    refused(lambda: load_set(tmp_path / "nowhere"), "nowhere", "no such measurement set")


def test_a_set_in_a_folder_named_like_a_pattern_loads_and_a_float_mask_is_read(tmp_path):
    """A folder whose name holds [, ] or * is a path, not a pattern; a floating-point mask (a float TIFF) is white
    above 0.5, as an 8-bit one above 127."""
    folder = _set(tmp_path / "shot[1]*", GOOD_CAPTURE + 'mask = "mask.tif"\n')
    mask = np.zeros((48, 64), np.float32)
    mask[:, :40] = 1.0
    assert cv2.imwrite(str(folder / "mask.tif"), mask)
    capture = load_set(folder).captures[0]
    assert capture.frames.shape == (1, 48, 64, 3) and capture.mask.sum() == 48 * 40
    # frames named by an absolute path, with or without a wildcard, are found wherever the set is
    plain = _set(tmp_path / "plain", GOOD_CAPTURE) / "frames"
    for frames in (plain / "a-000.png", plain / "a-*.png"):
        other = _set(tmp_path / "elsewhere", GOOD_CAPTURE.replace("frames/a-*.png", str(frames)))
        assert load_set(other).captures[0].frame_names == [str(plain / "a-000.png")]


def test_parse_target_without_a_file_names_the_target():
    assert parse_target("checkerboard:9x6:0.025") == ("checkerboard", (9, 6), 0.025)
    refused(lambda: parse_target("checkerboard:9x6:-1"), "target 'checkerboard:9x6:-1'", "'square'")


# --- chart layout JSON and patch CSV -------------------------------------------------------------------------------

def _layout(tmp_path, change=None):
    from lowcam.chart import make_chart

    _, layout = make_chart("a4", dpi=50)
    if change:
        change(layout)
    path = tmp_path / "chart.json"
    path.write_text(json.dumps(layout))
    return path


def _element(layout, kind):
    return next(e for e in layout["elements"] if e["type"] == kind)


@pytest.mark.parametrize("change, names", [
    (lambda d: d.update(format="x"), ["not a lowcam chart layout"]),
    (lambda d: d.update(elements=None), ["'elements' must be a list"]),
    (lambda d: d["elements"].append(5), ["elements[5]", "must be a table"]),
    (lambda d: d["elements"].append({"kind": 1}), ["elements[5]", "needs 'type'"]),
    (lambda d: d["elements"].append({"type": 1}), ["elements[5]", "'type' must be a string"]),
    (lambda d: d.update(elements=[e for e in d["elements"] if e["type"] != "charuco"]), ["no charuco element"]),
    (lambda d: _element(d, "charuco").update(square_mm=-1), ["elements[0]", "'square_mm'", "out of range"]),
    (lambda d: _element(d, "charuco").update(square_mm="big"), ["'square_mm' must be a number"]),
    (lambda d: _element(d, "charuco").update(rect_mm=[1, 2]), ["'rect_mm' must have 4 entries"]),
    (lambda d: _element(d, "charuco").pop("rect_mm"), ["needs 'rect_mm'"]),
    (lambda d: _element(d, "colour_patches")["patches"][2].update(srgb=[0, 300, 0]),
     ["patches[2]", "'srgb[1]' = 300", "out of range"]),
    (lambda d: _element(d, "colour_patches")["patches"][2].update(srgb=[0, 0]), ["'srgb' must have 3 entries"]),
    (lambda d: _element(d, "grey_steps")["patches"][0].update(value=None), ["patches[0]", "'value' must be a number"]),
    (lambda d: _element(d, "grey_steps")["patches"][0].update(rect_mm=[1, 2, 0, 5]),
     ["'rect_mm' must have a positive width"]),
    (lambda d: _element(d, "grey_steps")["patches"][0].update(rect_mm=[1e9, 2, 5, 5]), ["'rect_mm[0]'"]),
    (lambda d: _element(d, "grey_steps").update(patches=3), ["'patches' must be a list"]),
])
def test_bad_chart_layouts_are_refused(tmp_path, change, names):
    path = _layout(tmp_path, change)
    message = refused(lambda: read_chart_layout(path), *names)
    assert message.startswith(str(path))


def test_the_written_chart_layout_reads(tmp_path):
    board, patches = read_chart_layout(_layout(tmp_path))
    assert board["square_mm"] > 0 and len(patches) == 24


HEADER = "ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b"


@pytest.mark.parametrize("content, names", [
    (b"", ["is empty"]),
    (HEADER.encode(), ["0 data row(s)"]),
    ((HEADER + "\n" + "0.5,0.5,0.5,100,100,100\n" * 3).encode(), ["3 data row(s), at least 4"]),
    ((HEADER + "\n" + "0.5,0.5,0.5,100,100,100\n" * 3 + "0.5,0.5,inf,100,100,100\n").encode(),
     ["line 5", "'ideal_b' must be a finite number"]),
    ((HEADER + "\n" + "0.5,0.5,0.5,100,100,100\n" * 3 + "0.5,0.5,0.5,100,100,1000\n").encode(),
     ["line 5", "'measured_b'", "out of range"]),
    (b"\xff\xd8\xff\xe0 a JPEG", ["not UTF-8"]),
])
def test_bad_patch_tables_are_refused(tmp_path, content, names):
    refused_file(tmp_path / "patches.csv", content, read_patches_csv, *names)


def test_a_good_patch_table_reads(tmp_path):
    path = tmp_path / "patches.csv"
    path.write_text(HEADER + "\n" + "".join(f"{k / 10},0.5,0.5,{k * 10},100,100\n" for k in range(5)))
    ideal, measured = read_patches_csv(path)
    assert ideal.shape == measured.shape == (5, 3) and ideal[1, 0] == pytest.approx(25.5)
