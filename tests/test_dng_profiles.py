"""`lowcam profile from-dng`: a profile's sensor from a DNG's metadata.

The DNGs are written with PiDNG (an independent DNG writer) carrying known tags; the expected numbers are
computed by hand in the tests from the DNG specification (1.6, ch. 4-6) with colour-science's own sRGB matrix and
Bradford adaptation, never with Lowcam's converter. No real DNG is installed on this machine (none in tifffile,
imageio, colour-science or any other installed package; rawpy and exifread are not installed and their source
packages could not be unpacked), so every DNG here is written by PiDNG, or laid out with SubIFDs by tifffile.
"""
import subprocess
import sys
from pathlib import Path

import colour
import numpy as np
import pytest
from pidng.core import RAW2DNG
from pidng.defs import CalibrationIlluminant, CFAPattern, Orientation, PhotometricInterpretation
from pidng.dng import DNGTags, Tag

import lowcam
from lowcam.dng import profile_from_dng
from lowcam.errors import LowcamError
from lowcam.profile import load_profile

ROOT = Path(__file__).resolve().parent.parent
#: The Raspberry Pi HQ camera's ColorMatrix1 (PiDNG's camdefs), a real camera's matrix (XYZ -> camera).
CM_A = np.array([[0.6759, -0.2379, 0.0751], [-0.4432, 1.3871, 0.5465], [-0.0401, 0.1664, 0.7845]])
CM_D65 = np.array([[0.5603, -0.1351, -0.0600], [-0.2872, 1.1180, 0.2132], [0.0600, 0.0453, 0.5821]])
FM_D65 = np.array([[0.6591, 0.3034, 0.0018], [0.1991, 1.0585, -0.2575], [-0.0493, -0.0919, 0.9663]])


def rationals(m):
    return [[int(round(v * 10000)), 10000] for v in np.ravel(m)]


def write_dng(path, pattern=CFAPattern.RGGB, cm1=CM_D65, ill1=CalibrationIlluminant.D65, cm2=None, fm=None,
              neutral=(0.5, 1.0, 0.625), noise=((2e-4, 3e-6), (1e-4, 2e-6), (3e-4, 4e-6)), black=64, white=1023,
              plane_colour=None):
    t = DNGTags()
    w, h = 32, 24
    for tag, value in ((Tag.ImageWidth, w), (Tag.ImageLength, h), (Tag.TileWidth, w), (Tag.TileLength, h),
                       (Tag.Orientation, Orientation.Horizontal), (Tag.SamplesPerPixel, 1),
                       (Tag.PhotometricInterpretation, PhotometricInterpretation.Color_Filter_Array),
                       (Tag.BitsPerSample, 16), (Tag.CFARepeatPatternDim, [2, 2]), (Tag.CFAPattern, pattern),
                       (Tag.BlackLevel, black), (Tag.WhiteLevel, white), (Tag.Make, "Test"), (Tag.Model, "Cam")):
        t.set(tag, value)
    if cm1 is not None:
        t.set(Tag.ColorMatrix1, rationals(cm1))
        t.set(Tag.CalibrationIlluminant1, ill1)
    if cm2 is not None:
        t.set(Tag.ColorMatrix2, rationals(cm2))
        t.set(Tag.CalibrationIlluminant2, CalibrationIlluminant.D65)
    if fm is not None:
        t.set(Tag.ForwardMatrix1, rationals(fm))
    if neutral is not None:
        t.set(Tag.AsShotNeutral, [[int(round(v * 100000)), 100000] for v in neutral])
    if noise is not None:
        t.set(Tag.NoiseProfile, [float(v) for pair in noise for v in pair])
    if plane_colour is not None:
        t.set(Tag.CFAPlaneColor, plane_colour)
    r = RAW2DNG()
    r.options(t, path="", compress=False)
    r.convert(np.full((h, w), black + 100, np.uint16), filename=str(Path(path).with_suffix("")))
    return Path(path)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


@pytest.fixture(scope="module")
def dng(tmp_path_factory):
    return write_dng(tmp_path_factory.mktemp("dng") / "cam.dng")


def test_the_noise_simulated_with_the_profile_matches_the_noise_profile(dng):
    """Flat greys through the written profile: each sensel plane's variance is S x + O of the DNG, taken to
    white-balanced 8-bit DN by hand: x = g v (g = neutral / max neutral), d = 255 v, var(d) = (255 / g)^2 var(x)."""
    profile, _ = profile_from_dng(dng, load_profile("ueye"))
    profile = profile.without("vignetting", "spatial_blur", "chromatic_aberration")
    neutral = np.array([0.5, 1.0, 0.625])
    g = neutral / neutral.max()
    s_o = {"red": (2e-4, 3e-6), "green": (1e-4, 2e-6), "blue": (3e-4, 4e-6)}
    plane = {"red": 0, "green": 1, "blue": 2}
    cam = lowcam.render_camera(profile)
    for v in (0.2, 0.7):
        render = np.zeros((cam["height"], cam["width"], 4), np.float32)
        render[...] = (v, v, v, 1.0)
        bayer = lowcam.run(render, profile, stop_after="noise", seed=3).state.bayer
        # the four planes in Bayer order of RGGB: R, G, G, B; keep the middle, away from the lens border
        h, w = bayer.shape[1:]
        mid = bayer[:, h // 4: 3 * h // 4, w // 4: 3 * w // 4]
        for k, channel in enumerate(("red", "green", "green", "blue")):
            s, o = s_o[channel]
            gk = g[plane[channel]]
            expected = (255.0 / gk) ** 2 * (s * gk * v + o)
            measured = float(mid[k].var())
            assert abs(float(mid[k].mean()) - 255 * v) < 0.5, (channel, v, mid[k].mean())
            assert measured == pytest.approx(expected, rel=0.04), (channel, v, measured, expected)


@pytest.mark.parametrize("pattern, name", [(CFAPattern.RGGB, "RGGB"), (CFAPattern.GBRG, "GBRG"),
                                           (CFAPattern.BGGR, "BGGR"), (CFAPattern.GRBG, "GRBG")])
def test_the_cfa_pattern_becomes_the_bayer_pattern(tmp_path, pattern, name):
    profile, _ = profile_from_dng(write_dng(tmp_path / "p.dng", pattern=pattern), load_profile("fire-i"))
    assert profile.camera.bayer_pattern == name
    assert "CFAPattern" in profile.provenance["camera"]


def test_cfa_plane_colours_are_honoured(tmp_path):
    """CFAPattern values index CFAPlaneColor: planes listed as B, G, R turn the pattern values 0 1 1 2 into BGGR."""
    profile, _ = profile_from_dng(write_dng(tmp_path / "p.dng", pattern=[0, 1, 1, 2], plane_colour=[2, 1, 0],
                                            noise=((1e-4, 1e-6),)), load_profile("fire-i"))
    assert profile.camera.bayer_pattern == "BGGR"


def hand_crosstalk(cm, neutral):
    """XYZ -> camera of the render's primaries, white-balanced (DNG spec ch. 6), by colour-science."""
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    xyz_w = np.linalg.solve(cm, np.asarray(neutral, float))
    xyz_w = xyz_w / xyz_w[1]
    d65 = colour.xy_to_XYZ(srgb.whitepoint)
    cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(d65, xyz_w, transform="Bradford")
    k = np.diag(1.0 / (cm @ xyz_w)) @ cm @ cat @ srgb.matrix_RGB_to_XYZ
    return k / k.sum(axis=1, keepdims=True), xyz_w


def test_the_crosstalk_is_the_colour_matrix_at_the_as_shot_white(dng):
    profile, _ = profile_from_dng(dng, load_profile("fire-i"))
    k, _ = hand_crosstalk(CM_D65, (0.5, 1.0, 0.625))
    assert np.abs(np.asarray(profile.effect("crosstalk").matrix) - k).max() < 2e-3
    assert profile.effect("crosstalk").extra_mixing == 0.0
    # without ForwardMatrix the processor undoes the sensor exactly: colours right, noise mixed
    c = np.asarray(profile.effect("saturation").colour_correction)
    assert np.abs(c @ np.asarray(profile.effect("crosstalk").matrix) - np.eye(3)).max() < 1e-4
    assert np.abs(c - np.linalg.inv(k)).max() < 1e-2


def test_two_colour_matrices_are_interpolated_at_the_as_shot_white(tmp_path):
    """A neutral that is the D65 matrix's response to D65 white: the white is found to be D65 and the D65 matrix
    is used alone (its weight 1 in inverse colour temperature), whatever the tungsten matrix says."""
    neutral = CM_D65 @ colour.xy_to_XYZ([0.3127, 0.3290])
    neutral = neutral / neutral.max()
    path = write_dng(tmp_path / "two.dng", cm1=CM_A, ill1=CalibrationIlluminant.Standard_Light_A, cm2=CM_D65,
                     neutral=neutral)
    profile, _ = profile_from_dng(path, load_profile("fire-i"))
    k, xyz_w = hand_crosstalk(CM_D65, neutral)
    assert np.allclose(colour.XYZ_to_xy(xyz_w), [0.3127, 0.3290], atol=2e-4)
    assert np.abs(np.asarray(profile.effect("crosstalk").matrix) - k).max() < 2e-3


def test_the_forward_matrix_gives_the_colour_correction(tmp_path):
    """With ForwardMatrix (and no AnalogBalance or CameraCalibration) white-balanced camera RGB goes to XYZ D50 by
    FM; then Bradford to D65 and colour-science's XYZ -> sRGB."""
    path = write_dng(tmp_path / "fm.dng", fm=FM_D65)
    profile, _ = profile_from_dng(path, load_profile("fire-i"))
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        colour.xy_to_XYZ([0.3457, 0.3585]), colour.xy_to_XYZ(srgb.whitepoint), transform="Bradford")
    c = srgb.matrix_XYZ_to_RGB @ cat @ FM_D65
    c = c / c.sum(axis=1, keepdims=True)
    assert np.abs(np.asarray(profile.effect("saturation").colour_correction) - c).max() < 2e-3
    assert "ForwardMatrix" in profile.provenance["saturation.colour_correction"]


def test_white_level_sets_the_raw_depth_and_every_number_has_provenance(dng):
    profile, _ = profile_from_dng(dng, load_profile("ueye"))
    assert profile.effect("raw_blend").bits == 10  # WhiteLevel 1023
    for key in ("camera", "noise", "crosstalk", "raw_blend.bits"):
        assert "cam.dng" in profile.provenance[key] or "CFAPattern" in profile.provenance[key], key


def test_the_command_writes_a_profile_that_loads(dng, tmp_path):
    out = tmp_path / "mycam.toml"
    r = run_cli("profile", "from-dng", dng, "--base", "fire-i", "-o", out)
    assert r.returncode == 0, r.stderr
    p = load_profile(out)
    assert p.effect("noise").law == "variance_linear"
    # red: g = 0.5, S = 2e-4, O = 3e-6 -> a = 255^2 3e-6 / 0.25, b = 255 2e-4 / 0.5
    assert p.effect("noise").red == pytest.approx([255 ** 2 * 3e-6 / 0.25, 255 * 2e-4 / 0.5], rel=1e-6)
    assert "noise" in run_cli("profiles", out).stdout


def test_a_dng_without_noise_profile_keeps_the_base_noise_and_says_so(tmp_path):
    path = write_dng(tmp_path / "nonoise.dng", noise=None)
    out = tmp_path / "n.toml"
    r = run_cli("profile", "from-dng", path, "--base", "ueye", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "no NoiseProfile: noise kept from the base profile" in r.stdout and "calibrate plate" in r.stdout
    assert load_profile(out).effect("noise").red == load_profile("ueye").effect("noise").red


def jpeg_named_dng(path):
    path.write_bytes(b"\xff\xd8\xff\xe0 a jpeg")
    return path


@pytest.mark.parametrize("make, message", [
    (lambda d: d / "x.dng", "no such file"),
    (lambda d: jpeg_named_dng(d / "x.dng"), "not a readable DNG"),
    (lambda d: write_dng(d / "nocm.dng", cm1=None), "no ColorMatrix1"),
])
def test_bad_input_is_one_line_naming_the_file(tmp_path, make, message):
    path = make(tmp_path)
    r = run_cli("profile", "from-dng", path, "-o", tmp_path / "o.toml")
    assert r.returncode == 2 and message in r.stderr and str(path) in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o.toml").exists()


def test_a_noise_profile_too_large_for_lowcam_is_one_line_naming_the_file(tmp_path):
    path = write_dng(tmp_path / "loud.dng", noise=((0.5, 0.01),))
    r = run_cli("profile", "from-dng", path, "-o", tmp_path / "o.toml")
    assert r.returncode == 2 and str(path) in r.stderr and "NoiseProfile" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_plain_tiff_is_not_a_dng(tmp_path):
    import tifffile

    path = tmp_path / "plain.tif"
    tifffile.imwrite(path, np.zeros((8, 8), np.uint16))
    with pytest.raises(LowcamError, match="not a DNG"):
        profile_from_dng(path, load_profile("fire-i"))


def numbers(profile):
    """Every value of the profile, texture paths resolved."""
    def plain(v):
        return str(Path(v).resolve()) if isinstance(v, Path) else v
    return (profile.camera.values(), profile.provenance,
            [(e.name, e.enabled, {k: plain(getattr(e, k)) for k in e.params}) for e in profile.effects])


def test_the_bundled_phone_class_profile_is_what_its_script_makes(tmp_path):
    """profiles/rpi-hq.toml is what profiles/make_rpi_hq.py makes from the cited tag values (texture paths are
    relative to each file, so the loaded profiles are compared)."""
    r = subprocess.run([sys.executable, str(ROOT / "profiles" / "make_rpi_hq.py"), "-o", str(tmp_path / "r.toml")],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    p = load_profile("rpi-hq")
    assert numbers(load_profile(tmp_path / "r.toml")) == numbers(p)
    assert p.camera.bayer_pattern == "BGGR"
    for key in ("camera", "noise", "crosstalk", "raw_blend.bits"):
        assert p.provenance_of(*key.split(".")), key


def test_levels_and_cfa_are_read_from_the_raw_subifd(tmp_path):
    """Cameras' DNGs keep a preview in IFD0 and the raw image, with its levels and CFA, in a SubIFD (DNG spec
    ch. 3); this file is laid out so with tifffile's writer (PiDNG writes the raw into IFD0)."""
    import tifffile

    cm = [v for x in np.ravel(CM_D65) for v in (int(round(x * 10000)), 10000)]
    ifd0 = [(50706, 1, 4, (1, 4, 0, 0), True), (50721, 10, 9, tuple(cm), True), (50778, 3, 1, 21, True),
            (50728, 5, 3, (1, 2, 1, 1, 5, 8), True), (51041, 12, 2, (2e-4, 3e-6), True)]
    raw = [(33421, 3, 2, (2, 2), True), (33422, 1, 4, bytes([1, 2, 0, 1]), True), (50714, 3, 1, 512, True),
           (50717, 3, 1, 16383, True)]
    path = tmp_path / "sub.dng"
    with tifffile.TiffWriter(path) as tif:
        tif.write(np.zeros((8, 8, 3), np.uint8), photometric="rgb", subifds=1, subfiletype=1, extratags=ifd0)
        tif.write(np.zeros((16, 16), np.uint16), photometric=32803, subfiletype=0, extratags=raw)
    profile, _ = profile_from_dng(path, load_profile("ueye"))
    assert profile.camera.bayer_pattern == "GBRG"
    assert profile.effect("raw_blend").bits == 14  # WhiteLevel 16383 in the SubIFD, not IFD0's 8 bits
    assert "BlackLevel 512" in profile.provenance["camera"]
    assert profile.effect("noise").red == pytest.approx([255 ** 2 * 3e-6 / 0.25, 255 * 2e-4 / 0.5], rel=1e-6)


# --- degenerate tags: one line naming the DNG and the tag, never a numpy error, never the base profile -------------

def srationals(m):
    return tuple(v for x in np.ravel(m) for v in (int(round(x * 10000)), 10000))


#: A rank-2 matrix: its third row is the first plus the second.
SINGULAR = [[0.6, 0.3, 0.1], [0.2, 0.7, 0.1], [0.8, 1.0, 0.2]]


def tiff_dng(path, tags: dict):
    """A DNG laid out by tifffile with ``tags`` ({code: (TIFF type, count, values)}, None to leave a tag out)
    over a valid base: tifffile writes any type for any tag, so a matrix can be DOUBLEs holding NaN or inf."""
    import tifffile

    base = {50706: (1, 4, (1, 4, 0, 0)), 50721: (10, 9, srationals(CM_D65)), 50778: (3, 1, 21),
            50728: (5, 3, (1, 2, 1, 1, 5, 8)), 51041: (12, 2, (2e-4, 3e-6)), 33421: (3, 2, (2, 2)),
            33422: (1, 4, bytes([0, 1, 1, 2])), 50714: (3, 1, 64), 50717: (3, 1, 1023)}
    base.update(tags)
    extra = [(code, t, n, v, True) for code, spec in base.items() if spec is not None for t, n, v in [spec]]
    tifffile.imwrite(path, np.zeros((16, 16), np.uint16), photometric=32803, extratags=extra)
    return path


NAN_ROW = tuple([float("nan")] + [0.5] * 8)


@pytest.mark.parametrize("tags, said", [
    pytest.param({50721: (10, 9, srationals(SINGULAR))}, "ColorMatrix1 is singular", id="cm1-singular"),
    pytest.param({50722: (10, 9, srationals(SINGULAR)), 50779: (3, 1, 17)}, "ColorMatrix2 is singular",
                 id="cm2-singular"),
    pytest.param({50721: (10, 9, srationals(np.zeros((3, 3))))}, "ColorMatrix1 is all zero", id="cm1-zero"),
    pytest.param({50721: (12, 9, tuple([float("inf")] + [0.5] * 8))}, "ColorMatrix1", id="cm1-inf"),
    pytest.param({50721: (12, 9, NAN_ROW)}, "ColorMatrix1", id="cm1-nan"),
    pytest.param({50727: (5, 3, (0, 1, 1, 1, 1, 1))}, "AnalogBalance", id="analog-balance-zero"),
    pytest.param({50729: (5, 2, (3127, 10000, 0, 1)), 50728: None}, "AsShotWhiteXY", id="white-xy-y0"),
    pytest.param({50729: (12, 2, (0.3127, float("nan"))), 50728: None}, "AsShotWhiteXY", id="white-xy-nan"),
    pytest.param({50964: (10, 9, srationals(np.zeros((3, 3))))}, "ForwardMatrix1 is all zero", id="fm-zero"),
    pytest.param({50964: (10, 9, srationals(SINGULAR))}, "ForwardMatrix1 is singular", id="fm-singular"),
    pytest.param({50714: (12, 1, (float("-inf"),))}, "BlackLevel", id="black-minus-inf"),
    pytest.param({50714: (12, 1, (float("nan"),))}, "BlackLevel", id="black-nan"),
    # finite tags whose colour correction no camera has: named as the DNG's, not the bundled base's
    pytest.param({50721: (12, 9, (0.6, 0.3, 0.1, 0.6, 0.4, 0.1, 0.0, 0.1, 0.9))}, "colour correction",
                 id="derived-correction-out-of-range"),
    pytest.param({50721: (12, 9, (0.6, 0.3, 0.1, 0.6, 0.301, 0.1, 0.0, 0.1, 0.9))}, "crosstalk",
                 id="derived-crosstalk-out-of-range"),
])
def test_degenerate_dng_tags_are_one_line_naming_the_dng_and_the_tag(tmp_path, tags, said):
    path = tiff_dng(tmp_path / "cam.dng", tags)
    before = path.read_bytes()
    r = run_cli("profile", "from-dng", path, "--base", "fire-i", "-o", tmp_path / "o.toml")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(path) in lines[0] and said in lines[0], lines[0]
    assert "fire-i" not in lines[0]  # the error is in the DNG, not in the bundled base profile
    assert not (tmp_path / "o.toml").exists() and path.read_bytes() == before


def test_the_valid_tiff_dng_gives_a_profile(tmp_path):
    """The base the degenerate cases change is itself a good DNG: each refusal above is its tag's doing."""
    profile, _ = profile_from_dng(tiff_dng(tmp_path / "cam.dng", {}), load_profile("fire-i"))
    k, _ = hand_crosstalk(CM_D65, (0.5, 1.0, 0.625))
    assert np.abs(np.asarray(profile.effect("crosstalk").matrix) - k).max() < 2e-3
    assert profile.camera.bayer_pattern == "RGGB"


def test_the_output_may_not_be_the_base_profile(tmp_path, dng):
    """``--base mycam.toml -o mycam.toml`` would replace the base with a profile derived from it."""
    base = tmp_path / "mycam.toml"
    base.write_bytes((ROOT / "profiles" / "fire-i.toml").read_bytes())
    before = base.read_bytes()
    r = run_cli("profile", "from-dng", dng, "--base", base, "-o", base)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "--base" in r.stderr and str(base) in r.stderr and "Traceback" not in r.stderr
    assert base.read_bytes() == before
