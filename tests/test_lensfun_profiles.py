"""``lowcam profile from-lensfun`` against lensfun itself (lensfunpy's Modifier), lens by lens.

Each case writes a profile with the command, loads it back, and compares what Lowcam does with it to what lensfun's
own ``lfModifier`` does for the same lens, setting and frame:

- geometry: lensfun's ``apply_geometry_distortion`` (corrected pixel -> pixel of the distorted frame) against the
  profile's lens (camera-plane point of that corrected pixel -> output pixel), over the whole frame;
- TCA: lensfun's reverse ``apply_subpixel_distortion`` (where red and blue sample, per pixel of the distorted
  frame) against the profile's chromatic-aberration grid as Bayer sampling reads it; and the whole chain (lensfun's
  ``apply_subpixel_geometry_distortion``, distortion then TCA) against the lens and the grid together;
- vignetting: lensfun's reverse ``apply_color_modification`` on a flat float image against the gain the profile's
  vignetting stage applies to every sensel.

Lensfun 0.3's SSE paths (four pixels at a time) are inexact for poly3 and ptlens (see tests/test_lens.py), so
lensfun is asked for one column at a time, where its scalar code answers.
"""
import numpy as np
import pytest

from lowcam.cli import main
from lowcam.geometry import sample_texture
from lowcam.profile import load_profile

lensfunpy = pytest.importorskip("lensfunpy")

# (maker, model, focal mm, f-number, crop factor or None (the lens's own)): real lenses of every lensfun model.
CASES = [
    # poly3 distortion, poly3 TCA, pa vignetting; a zoom between its calibrated focal lengths
    pytest.param("Sony", "Sony DT 18-55mm f/3.5-5.6 SAM (SAL1855)", 24.0, 5.6, None, id="poly3-SAL1855-24mm"),
    pytest.param("Pentax", "Pentax SMC Takumar 50mm f/1.4", 50.0, 2.0, 1.9, id="poly3-Takumar50-cropped"),
    pytest.param("Olympus", "Olympus Tough TG-4 & compatibles", 7.0, None, None, id="poly3-TG4-7mm"),
    # poly5: the database's only poly5 lens, at two focal lengths
    pytest.param("Canon", "Canon PowerShot G12 & compatibles (Standard)", 6.1, None, None, id="poly5-G12-6.1mm"),
    pytest.param("Canon", "Canon PowerShot G12 & compatibles (Standard)", 12.0, None, 5.5, id="poly5-G12-12mm"),
    # ptlens, with poly3 and linear TCA and pa vignetting
    pytest.param("Fujifilm", "Fujifilm X-S1", 20.0, 4.0, None, id="ptlens-XS1-20mm"),
    pytest.param("Canon", "Canon G7 X & compatibles", 15.0, 2.8, None, id="ptlens-G7X-15mm"),
    pytest.param("DJI", "FC2103 & compatibles", 4.5, None, None, id="ptlens-DJI-FC2103"),
    pytest.param("Nikon", "Nikon AF-S DX Nikkor 35mm f/1.8G", 35.0, 2.8, None, id="ptlens-linearTCA-Nikon35"),
]


@pytest.fixture(scope="module")
def big_base(tmp_path_factory):
    """fire-i on a 1600 x 1200 frame: offsets four times the 640 x 480 frame's, so the checks have teeth."""
    base = load_profile("fire-i")
    base.camera.width, base.camera.height = 1600, 1200
    return str(base.save(tmp_path_factory.mktemp("base") / "big.toml"))


def make(tmp_path, base, maker, model, focal, aperture=None, crop=None, name="lens.toml"):
    args = ["profile", "from-lensfun", "--maker", maker, "--model", model, "--focal-mm", str(focal),
            "--base", base, "-o", str(tmp_path / name)]
    if aperture is not None:
        args += ["--aperture", str(aperture)]
    if crop is not None:
        args += ["--crop-factor", str(crop)]
    assert main(args) == 0
    return load_profile(tmp_path / name)


def database_lens(maker, model, crop):
    found = [lens for lens in lensfunpy.Database().lenses if lens.maker == maker and lens.model == model]
    return min(found, key=lambda lens: abs(lens.crop_factor - (crop or lens.crop_factor)))


def columns(fn, width, height):
    """lensfun's coordinates for every pixel, asked one column at a time: (H, W, ...)."""
    return np.concatenate([fn(x, 0, 1, height) for x in range(width)], axis=1).astype(np.float64)


@pytest.mark.parametrize("maker, model, focal, aperture, crop", CASES)
def test_profile_matches_lensfuns_modifier(tmp_path, big_base, maker, model, focal, aperture, crop):
    profile = make(tmp_path, big_base, maker, model, focal, aperture, crop)
    lens = database_lens(maker, model, crop)
    w, h = profile.camera.width, profile.camera.height
    crop = crop or lens.crop_factor
    aperture = aperture or lens.min_aperture or 2.8  # the command's default too
    flags = lensfunpy.ModifyFlags

    # geometry: corrected pixel -> distorted pixel
    m = lensfunpy.Modifier(lens, crop, w, h)
    m.initialize(focal, aperture, 1000.0, scale=1.0, flags=flags.DISTORTION)
    ref = columns(m.apply_geometry_distortion, w, h)
    lf = profile.lens
    fx, fy, cx, cy = lf.pinhole_intrinsics()
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ud, vd = lf.distort((u - cx) / fx, (v - cy) / fy)
    assert np.hypot(ref[..., 0] - u, ref[..., 1] - v).max() > 1.0, "a distortion worth checking"
    geometric = np.hypot(ud - ref[..., 0], vd - ref[..., 1]).max()
    assert geometric <= 0.05, geometric
    report = [f"geometry {geometric:.4f} px"]

    ca = profile.effect("chromatic_aberration")
    if lens.calib_tca:
        grid = ca.grid(w, h)
        offsets = sample_texture(grid, profile.geometry.frame_extent, u, v)  # as Bayer sampling reads it
        # TCA alone, lensfun correcting (closed form): green at p is where red (blue) is at lensfun's TCA(p), so
        # the red (blue) sensel there must sample at p
        m = lensfunpy.Modifier(lens, crop, w, h)
        m.initialize(focal, aperture, 1000.0, scale=1.0, flags=flags.TCA)
        sub = columns(m.apply_subpixel_distortion, w, h)  # (H, W, 3, 2)
        size = 0.0
        for channel, k in ((0, 0), (2, 2)):
            pu, pv = sub[..., channel, 0], sub[..., channel, 1]
            size = max(size, np.hypot(pu - u, pv - v).max())
            inside = (pu >= 0) & (pu <= w - 1) & (pv >= 0) & (pv <= h - 1)
            off = sample_texture(grid, profile.geometry.frame_extent, pu, pv)
            err = np.hypot(pu + off[..., k] - u, pv + off[..., k + 1] - v)[inside].max()
            assert err <= 0.01, (channel, err)
            report.append(f"TCA {'RGB'[channel]} {err:.4f} px")
        assert size > 0.05, f"a TCA worth checking ({size:.3f} px)"
        # and lensfun simulating the lens (reverse: Newton to lensfun's own tolerance, 1e-5 normalised units)
        m = lensfunpy.Modifier(lens, crop, w, h)
        m.initialize(focal, aperture, 1000.0, scale=1.0, flags=flags.TCA, reverse=True)
        sub = columns(m.apply_subpixel_distortion, w, h)
        for channel, k in ((0, 0), (2, 2)):
            du, dv = sub[..., channel, 0] - u, sub[..., channel, 1] - v
            err = np.hypot(offsets[..., k] - du, offsets[..., k + 1] - dv).max()
            assert err <= 0.05, (channel, err)
            report.append(f"TCA {'RGB'[channel]} (reverse) {err:.4f} px")
        # the whole chain (lensfun correcting: corrected pixel -> distortion -> TCA -> source pixel): the red
        # (blue) sensel at lensfun's source pixel must look where green does at the distorted pixel
        m = lensfunpy.Modifier(lens, crop, w, h)
        m.initialize(focal, aperture, 1000.0, scale=1.0, flags=flags.TCA | flags.DISTORTION)
        chain = columns(m.apply_subpixel_geometry_distortion, w, h)
        step = 7  # every 7th pixel is plenty here
        for channel, k in ((0, 0), (2, 2)):
            pu, pv = chain[::step, ::step, channel, 0], chain[::step, ::step, channel, 1]
            inside = (pu > 0) & (pu < w - 1) & (pv > 0) & (pv < h - 1)
            off = sample_texture(grid, profile.geometry.frame_extent, pu, pv)
            err = np.hypot(pu + off[..., k] - ud[::step, ::step], pv + off[..., k + 1] - vd[::step, ::step])
            assert err[inside].max() <= 0.05, (channel, err[inside].max())
            report.append(f"chain {'RGB'[channel]} {err[inside].max():.4f} px")
    else:  # no TCA in the database: the base's stays
        assert ca.model == "radial" and ca.texture

    vig = profile.effect("vignetting")
    if lens.calib_vignetting:
        m = lensfunpy.Modifier(lens, crop, w, h)
        m.initialize(focal, aperture, 1000.0, scale=1.0, pixel_format=np.float32, flags=flags.VIGNETTING,
                     reverse=True)
        flat = np.ones((h, w, 3), np.float32)
        assert m.apply_color_modification(flat)
        pos = profile.geometry.sensel_positions
        gain = vig.gain_planes(profile.geometry)
        iu, iv = np.rint(pos[..., 0]).astype(int), np.rint(pos[..., 1]).astype(int)
        inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        assert np.allclose(pos[..., 0][inside], iu[inside]) and np.allclose(pos[..., 1][inside], iv[inside])
        truth = flat[iv[inside], iu[inside], 1]
        assert truth.min() < 0.95, "a vignetting worth checking"
        assert np.abs(gain[inside] / truth - 1).max() <= 0.01
        report.append(f"vignetting {100 * np.abs(gain[inside] / truth - 1).max():.4f} % (min {truth.min():.3f})")
    else:
        assert vig.model == "radial" and vig.texture
    print(model, focal, "mm:", ", ".join(report))


def test_provenance_names_the_lens_and_the_base(tmp_path, capsys):
    make(tmp_path, "fire-i", "DJI", "FC2103", 4.5, name="drone.toml")
    capsys.readouterr()
    assert main(["profiles", str(tmp_path / "drone.toml")]) == 0
    shown = capsys.readouterr().out
    for effect in ("lens_distortion", "chromatic_aberration", "vignetting"):
        line = next(line for line in shown.splitlines() if line.strip().startswith(effect))
        assert "lensfun 0.3" in line and "DJI FC2103 & compatibles" in line and "4.5 mm" in line, line
    assert "ptlens terms 0.01522, -0.10515, 0.13917" in shown
    noise = next(line for line in shown.splitlines() if line.strip().startswith("noise "))
    assert "(from base fire-i)" in noise


def test_search_lists_matching_lenses_with_their_calibrations(capsys):
    assert main(["profile", "search", "powershot", "g12"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == "1 lens, 1 camera"
    lens = next(row for row in out if " | rectilinear | " in row)
    assert lens.startswith("Canon | Canon PowerShot G12 & compatibles (Standard) | rectilinear | canonG12 | "
                           "6.1-30.5 mm")
    assert "distortion poly5, TCA poly3, -" in lens
    assert main(["profile", "search", "FC2103"]) == 0
    assert "distortion ptlens, TCA poly3, vignetting (2)" in capsys.readouterr().out


def test_search_filters_by_type_and_focal_length_and_corrects_a_typo(capsys):
    """``--type fisheye`` keeps every fisheye projection and nothing else, ``--focal-mm`` the lenses whose range
    holds it; a mistyped word is replaced by the database's nearest word, said on stderr."""
    def rows(*args):
        assert main(["profile", "search", *args]) == 0
        captured = capsys.readouterr()
        return captured.out.splitlines()[:-1], captured.err

    every, _ = rows("Sony", "--limit", "0")
    fisheyes, _ = rows("Sony", "--type", "fisheye", "--limit", "0")
    assert fisheyes and len(fisheyes) < len(every)
    assert all(row.split(" | ")[2].startswith("fisheye") for row in fisheyes)
    assert {row.split(" | ")[2] for row in rows("Samyang", "--type", "fisheye")[0]} >= {"fisheye stereographic"}
    at_16, _ = rows("Sony", "--focal-mm", "16", "--limit", "0")
    assert at_16 and len(at_16) < len(every)
    for row in at_16:
        focal = row.split(" | ")[4].removesuffix(" mm").split("-")
        assert float(focal[0]) <= 16 <= float(focal[-1]), row
    phones, err = rows("iphnoe")
    assert "showing 'iphone'" in err and phones and all("iPhone" in row for row in phones)
    assert main(["profile", "search", "Sony", "--type", "fishy"]) == 2
    assert "no such lens type" in capsys.readouterr().err


def test_a_lens_not_in_the_database_is_one_line_with_the_nearest_names(tmp_path, capsys):
    code = main(["profile", "from-lensfun", "--maker", "Canon", "--model", "PowerShot G13", "--focal-mm", "6.1",
                 "--base", "fire-i", "-o", str(tmp_path / "x.toml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "not in the lensfun database" in err and "'Canon PowerShot G16 & compatibles'" in err
    assert not (tmp_path / "x.toml").exists()
    assert main(["profile", "search", "Zorki", "nonexistent"]) == 2
    assert "nothing in the lensfun database matches 'Zorki nonexistent'" in capsys.readouterr().err


def test_bad_settings_are_one_line_errors(tmp_path, capsys):
    base = ["profile", "from-lensfun", "--maker", "DJI", "--model", "FC2103", "--base", "fire-i", "-o",
            str(tmp_path / "x.toml")]
    assert main(base + ["--focal-mm", "12"]) == 2
    assert "outside the lens's range 4.5-4.5 mm" in capsys.readouterr().err
    assert main(base + ["--focal-mm", "4.5", "--aperture", "1.2"]) == 2
    assert "wider than the lens's widest aperture" in capsys.readouterr().err


def test_missing_lensfunpy_says_how_to_install(tmp_path, capsys, monkeypatch):
    import sys

    from lowcam import lensdb

    lensdb._database.cache_clear()
    lensdb.lens_entries.cache_clear()
    lensdb.camera_entries.cache_clear()
    monkeypatch.setitem(sys.modules, "lensfunpy", None)  # import lensfunpy -> ImportError
    code = main(["profile", "search", "G12"])
    err = capsys.readouterr().err
    assert code == 2 and "pip install lowcam[lensfun]" in err and len(err.strip().splitlines()) == 1
    lensdb._database.cache_clear()
    lensdb.lens_entries.cache_clear()


def test_camera_crop_factor_comes_from_the_database(tmp_path):
    cams = [c for c in lensfunpy.Database().cameras if c.maker == "Canon" and c.model == "Canon PowerShot G12"]
    p = make(tmp_path, "fire-i", "Canon", "G12", 6.1, name="g12.toml")  # default: the lens's crop factor
    assert main(["profile", "from-lensfun", "--maker", "Canon", "--model", "G12", "--focal-mm", "6.1",
                 "--camera-maker", "Canon", "--camera-model", "PowerShot G12", "--base", "fire-i",
                 "-o", str(tmp_path / "g12cam.toml")]) == 0
    q = load_profile(tmp_path / "g12cam.toml")
    assert q.effect("lens_distortion").crop_factor == pytest.approx(cams[0].crop_factor)
    assert "Canon PowerShot G12 in the lensfun database" in q.provenance["lens_distortion"]
    assert p.effect("lens_distortion").calibration_crop_factor == pytest.approx(4.63, abs=1e-3)


def test_the_bundled_lensfun_profile_is_what_its_script_makes(tmp_path):
    """profiles/iphone-xs-lens.toml is what profiles/make_profiles.sh's command writes today, and states where every
    number came from."""
    import shlex

    from lowcam.profile import BUNDLED_PROFILES

    script = (BUNDLED_PROFILES / "make_profiles.sh").read_text().replace("\\\n", " ")
    line = next(line for line in script.splitlines() if "iphone-xs-lens.toml" in line)
    args = shlex.split(line)[2:]  # drop "$PY" -m
    args = [a for a in args if a != "lowcam.cli"]
    args[args.index("--base") + 1] = str(BUNDLED_PROFILES / "fire-i.toml")
    args[args.index("-o") + 1] = str(tmp_path / "again.toml")
    assert main(args) == 0
    bundled, again = load_profile("iphone-xs-lens"), load_profile(tmp_path / "again.toml")
    for name in ("lens_distortion", "chromatic_aberration", "vignetting"):
        assert bundled.effect(name).values() == again.effect(name).values(), name
        assert "lensfun 0.3" in bundled.provenance_of(name) and "iPhone XS" in bundled.provenance_of(name)
    assert bundled.effect("chromatic_aberration").model == "lensfun"
    assert bundled.effect("vignetting").model == "lensfun_pa"
    for e in bundled.effects:
        assert bundled.provenance_of(e.name), e.name
    assert "(from base fire-i)" in bundled.provenance["camera"]


def test_the_new_profile_is_named_after_its_lens_unless_named(tmp_path):
    """The base's sensor with another lens is another camera: named after the lens and focal length (not the base's
    'Unibrain Fire-i, 2.1 mm lens'), or as ``--name`` says; the description keeps the base."""
    made = make(tmp_path, "fire-i", "DJI", "FC2103", 4.5)
    assert made.camera.name == "DJI FC2103 & compatibles at 4.5 mm"
    assert "Unibrain Fire-i" in made.camera.description and "from the lens" in made.provenance["camera"]
    assert main(["profile", "from-lensfun", "--maker", "DJI", "--model", "FC2103", "--focal-mm", "4.5", "--base",
                 "fire-i", "--name", "Drone", "-o", str(tmp_path / "named.toml")]) == 0
    assert load_profile(tmp_path / "named.toml").camera.name == "Drone"


def test_a_lens_that_folds_on_the_frame_is_named_with_its_setting(tmp_path, capsys):
    """The Olympus 14-42 at 14 mm (its poly3 stops rising 8 % short of its own frame's corner: the corners have no
    ray, tests/test_lensfun_fisheye.py shows it with lensfun's own numbers) folds over inside fire-i's frame at its
    own crop factor: one line naming the lens, the focal length, the crop factor and the frame, not the base's
    file."""
    code = main(["profile", "from-lensfun", "--maker", "Olympus", "--model",
                 "Olympus M.Zuiko Digital ED 14-42mm f/3.5-5.6",
                 "--focal-mm", "14", "--base", "fire-i", "-o", str(tmp_path / "olympus.toml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "Olympus M.Zuiko Digital ED 14-42mm f/3.5-5.6 at 14 mm, crop factor 2, on fire-i's 640x480 frame" in err, err
    assert "folds over" in err and "fire-i.toml" not in err and not (tmp_path / "olympus.toml").exists()


def test_a_size_of_another_shape_is_lensfuns_own_lens_at_that_frame(tmp_path, capsys):
    """``--size 1920,1080`` on the 4:3 fire-i base: a 16:9 profile whose lens is lensfun's own ``Modifier`` for a
    1920x1080 image of the same camera (lensfun's calibrations hold at any frame: it scales by the crop factor and
    the frame's diagonal), within 0.05 px; a size the camera cannot deliver is one line naming --size."""
    maker, model, focal = "Canon", "Canon EF-S 18-55mm f/3.5-5.6", 18.0
    args = ["profile", "from-lensfun", "--maker", maker, "--model", model, "--focal-mm", str(focal), "--base",
            "fire-i", "--size", "1920,1080", "-o", str(tmp_path / "hd.toml")]
    assert main(args) == 0
    profile = load_profile(tmp_path / "hd.toml")
    w, h = profile.camera.width, profile.camera.height
    assert (w, h) == (1920, 1080)
    lens = database_lens(maker, model, None)
    m = lensfunpy.Modifier(lens, lens.crop_factor, w, h)
    m.initialize(focal, lens.min_aperture or 2.8, 1000.0, scale=1.0, flags=lensfunpy.ModifyFlags.DISTORTION)
    u, v = np.meshgrid(np.arange(0, w, 7, dtype=np.float64), np.arange(0, h, 7, dtype=np.float64))
    ref = np.concatenate([m.apply_geometry_distortion(x, 0, 1, h) for x in range(0, w, 7)], axis=1)[::7]
    ref = ref.astype(np.float64)                      # one column at a time, as columns() asks lensfun
    fx, fy, cx, cy = profile.lens.pinhole_intrinsics()
    ud, vd = profile.lens.distort((u - cx) / fx, (v - cy) / fy)
    assert np.hypot(ref[..., 0] - u, ref[..., 1] - v).max() > 1.0
    assert np.hypot(ud - ref[..., 0], vd - ref[..., 1]).max() <= 0.05
    assert main(args[:-4] + ["--size", "1922,1080", "-o", str(tmp_path / "odd.toml")]) == 2
    err = capsys.readouterr().err
    assert "--size 1922,1080: the frame must be a multiple of 4 wide" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "odd.toml").exists()
