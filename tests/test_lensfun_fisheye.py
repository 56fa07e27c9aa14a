"""Lensfun's fisheye lenses in ``lowcam profile from-lensfun`` against lensfun itself (lensfunpy's Modifier).

Lensfun corrects a fisheye by converting its geometry: each pixel of a rectilinear (or equirectangular) target is
a ray, put through the lens's projection (equidistant, equisolid, stereographic, orthographic, Thoby) and its
distortion into the fisheye's frame (``apply_geometry_distortion`` with ``ModifyFlags.GEOMETRY``). The profile's
lens must put the same ray on the same pixel (:meth:`~lowcam.effects.lens_models.LensModel.distort_ray`) and see
it there (``undistort_ray``):

- a GoPro-class fisheye and fisheyes drawn at random (seeded) from the database, each of its fisheye geometries,
  through the command, against the rectilinear conversion over the frame;
- rays beyond 90 degrees, against lensfun's conversion to an equirectangular target;
- the orthographic and Thoby geometries (the database has no such lens) on lenses written in lensfun's XML;
- through the engine: the profile films a render whose pixels hold the rays they see;
- folds: lensfun's own mapping shows where a lens's distortion stops rising, short of the frame's corner (refused,
  named with its setting) or within the last fraction of it (the Samsung Galaxy S21 ultrawide, imported).

Lensfun 0.3's SSE paths are inexact for poly3 and ptlens (see tests/test_lens.py), so lensfun is asked for one
column at a time, where its scalar code answers.
"""
import random

import numpy as np
import pytest

from lowcam.cli import main
from lowcam.effects.lens import LENSFUN_FOLD_TOLERANCE, LensDistortion, lens_model_from
from lowcam.effects.lens_models import lensfun_projection, lensfun_projection_limit
from lowcam.profile import load_profile

lensfunpy = pytest.importorskip("lensfunpy")

from lowcam import lensdb  # noqa: E402  (after the skip: lensdb's entries need lensfunpy)

FLAGS = lensfunpy.ModifyFlags
W, H = 800, 600  # the frame for the comparisons with lensfun


def fisheyes():
    """(entry, focal) of every database fisheye with a distortion calibration that the command imports at its own
    crop factor (the others fold inside the frame: :func:`test_a_circular_fisheye_on_a_full_frame_folds`)."""
    out = []
    for e in lensdb.lens_entries():
        if e.lens_type.startswith("fisheye") and e.lens.calib_distortion and e.model != "HD2 & compatibles":
            focal = e.lens.calib_distortion[0].focal
            values = lensdb.lens_setting(e, focal).effects()["lens_distortion"]
            try:
                LensDistortion(**values)
            except Exception:
                continue
            out.append((e, lensdb._f32(focal)))
    return out


def drawn(seed=2026, per_type=2):
    """``per_type`` fisheyes of each geometry the database has, drawn at random (seeded)."""
    found = fisheyes()
    rng = random.Random(seed)
    out = []
    for kind in sorted({e.lens_type for e, _ in found}):
        of_kind = [(e, f) for e, f in found if e.lens_type == kind]
        out += rng.sample(of_kind, min(per_type, len(of_kind)))  # (the GoPro HD2 is a case of its own)
    return out


CASES = [pytest.param("GoPro", "HD2 & compatibles", 2.5, None, id="gopro-hd2-fisheye")] + [
    pytest.param(e.maker, e.model, f, e.crop_factor, id=f"{e.lens_type}-{e.name[:30]}") for e, f in drawn()]


@pytest.fixture(scope="module")
def big_base(tmp_path_factory):
    base = load_profile("fire-i")
    base.camera.width, base.camera.height = W, H
    return str(base.save(tmp_path_factory.mktemp("base") / "big.toml"))


def make(tmp_path, base, maker, model, focal, crop=None, name="lens.toml"):
    args = ["profile", "from-lensfun", "--maker", maker, "--model", model, "--focal-mm", str(focal), "--base", base,
            "-o", str(tmp_path / name)]
    if crop is not None:
        args += ["--crop-factor", str(crop)]
    assert main(args) == 0
    return load_profile(tmp_path / name)


def database_lens(maker, model, crop=None):
    found = [lens for lens in lensfunpy.Database().lenses if lens.maker == maker and lens.model == model]
    return min(found, key=lambda lens: abs(lens.crop_factor - (crop or lens.crop_factor)))


def columns(fn, xs, y0, height):
    """lensfun's coordinates for columns starting at (x, y0), one column at a time: (height, len(xs), 2)."""
    return np.concatenate([fn(float(x), float(y0), 1, height) for x in xs], axis=1).astype(np.float64)


def rectilinear_rays(lf, scale, w, h):
    """The rays of a rectilinear target of ``w`` x ``h`` zoomed out by ``scale`` (lensfun's ``scale``), centred
    where the lens is: (theta, phi) per pixel."""
    fx, fy, cx, cy = lf.pinhole_intrinsics()
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x, y = (u - cx) / (fx * scale), (v - cy) / (fy * scale)
    return np.arctan(np.hypot(x, y)), np.arctan2(y, x)


def compare_with_lensfun(lf, lens, crop, focal, targeom=lensfunpy.LensType.RECTILINEAR, scale=None,
                         frame_only=True):
    """Max px distance between the profile's pixel of each target pixel's ray and lensfun's, over the target; the
    largest angle (deg) compared; and the max px distance between the ray the profile sees at lensfun's pixels
    (``undistort_ray``) and the target's, where lensfun's pixel is in the frame and the lens maps one to one; and
    whether lensfun's pixels reach the frame's four sides. An equirectangular target is compared where its rays
    fall in the frame, or without ``frame_only`` out to 150 degrees (lensfun's float32 loses the back pole)."""
    m = lensfunpy.Modifier(lens, crop, W, H)
    if scale is None:  # the rectilinear target's corner sees 80 degrees
        corner = np.hypot(W - 1, H - 1) / 2 / lf.unit_px
        scale = corner / (lf.scale * np.tan(np.radians(80.0)))
    m.initialize(focal, lens.min_aperture or 2.8, 1000.0, scale=scale, targeom=targeom,
                 flags=FLAGS.DISTORTION | FLAGS.GEOMETRY | FLAGS.SCALE)
    ref = columns(m.apply_geometry_distortion, range(W), 0, H)
    if targeom == lensfunpy.LensType.RECTILINEAR:
        theta, phi = rectilinear_rays(lf, scale, W, H)
    else:  # equirectangular: longitude and latitude in focal lengths, lensfun's ModifyCoord_Geom_ERect_*
        fx, fy, cx, cy = lf.pinhole_intrinsics()
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        lon, lat = (u - cx) / (fx * scale), (v - cy) / (fy * scale)
        theta = np.arccos(np.clip(np.cos(lat) * np.cos(lon), -1, 1))
        phi = np.arctan2(np.sin(lat), np.cos(lat) * np.sin(lon))
    keep = theta < np.pi - 1e-3
    inside = (ref[..., 0] >= 0) & (ref[..., 0] <= W - 1) & (ref[..., 1] >= 0) & (ref[..., 1] <= H - 1)
    if targeom != lensfunpy.LensType.RECTILINEAR:
        keep &= (np.abs(lat) < np.pi / 2) & (np.abs(lon) < np.pi) & (inside if frame_only else theta < np.radians(150))
    keep &= lf.scale * lensfun_projection(lf.geometry, theta) < lf.ru_max() * (1 - 1e-6)  # maps one to one
    keep &= theta < lensfun_projection_limit(lf.geometry)
    ud, vd = lf.distort_ray(theta, phi)
    forward = np.hypot(ud - ref[..., 0], vd - ref[..., 1])[keep].max()
    inside &= keep
    pu, pv = ref[..., 0][inside], ref[..., 1][inside]
    t2, p2 = lf.undistort_ray(pu, pv)  # the profile's ray at lensfun's pixel ...
    u2, v2 = lf.distort_ray(theta[inside], phi[inside])  # ... put back, against the target's ray put there
    u3, v3 = lf.distort_ray(t2, p2)
    backward = np.hypot(u3 - u2, v3 - v2).max()
    assert np.hypot(u3 - pu, v3 - pv).max() < 1e-6  # undistort_ray inverts distort_ray
    # each side of the frame reached, or seeing beyond the target's widest ray at its middle
    widest = theta[keep].max()
    sides = [(0.0, (H - 1) / 2), (W - 1.0, (H - 1) / 2), ((W - 1) / 2, 0.0), ((W - 1) / 2, H - 1.0)]
    beyond = [lf.undistort_ray(su, sv)[0] > widest for su, sv in sides]
    reach = [pu.min() < 2, pu.max() > W - 3, pv.min() < 2, pv.max() > H - 3]
    return forward, float(np.degrees(widest)), backward, all(r or b for r, b in zip(reach, beyond))


@pytest.mark.parametrize("maker, model, focal, crop", CASES)
def test_fisheye_profile_sees_the_rays_lensfun_converts(tmp_path, big_base, maker, model, focal, crop):
    """The command's profile and lensfun's geometry conversion to a rectilinear target zoomed out until its corner
    sees 80 degrees: the same pixel for every ray within 0.05 px, and the same ray at lensfun's pixels."""
    profile = make(tmp_path, big_base, maker, model, focal, crop)  # the entry's crop factor (one name, two entries)
    lens = database_lens(maker, model, crop)
    lf = profile.lens
    assert lf.geometry == lens.type.name.lower() != "rectilinear"
    assert profile.effect("lens_distortion").lensfun_geometry == lf.geometry
    forward, widest, backward, reach = compare_with_lensfun(lf, lens, lens.crop_factor, focal)
    print(f"{model} ({lf.geometry}): {forward:.4f} px out to {widest:.1f} deg; at lensfun's pixels {backward:.4f} px")
    assert widest > 79.0 and reach  # lensfun's pixels reach all four sides of the frame
    assert forward <= 0.05 and backward <= 0.05, (forward, backward)


def test_rays_beyond_90_degrees_as_lensfun_converts_them_to_equirectangular(tmp_path, big_base):
    """A fisheye whose frame sees beyond 90 degrees (the Sigma 8 mm circular, equisolid, on a crop-1.62 camera:
    lensfun's equisolid conversion) and an equidistant one: lensfun's equirectangular target reaches past 90
    degrees from the axis, and the profile puts those rays where lensfun does."""
    profile = make(tmp_path, big_base, "Sigma", "Sigma 8mm f/3.5 EX DG Circular", 8, crop=1.62)
    lens = database_lens("Sigma", "Sigma 8mm f/3.5 EX DG Circular", 1.62)
    lf = profile.lens
    corner_theta, _ = lf.undistort_ray(0.0, 0.0)
    assert np.degrees(corner_theta) > 100  # the frame's corner sees beyond 90 degrees
    forward, widest, backward, reach = compare_with_lensfun(lf, lens, lens.crop_factor, 8.0,
                                                            lensfunpy.LensType.EQUIRECTANGULAR, scale=0.5)
    print(f"Sigma 8 mm circular: {forward:.4f} px out to {widest:.1f} deg")
    assert widest > 110 and forward <= 0.05 and backward <= 0.05 and reach, (widest, forward, backward)
    hd2 = make(tmp_path, big_base, "GoPro", "HD2 & compatibles", 2.5, name="hd2.toml")
    forward, widest, _, _ = compare_with_lensfun(hd2.lens, database_lens("GoPro", "HD2 & compatibles"), 6.4, 2.5,
                                                 lensfunpy.LensType.EQUIRECTANGULAR, scale=0.5, frame_only=False)
    print(f"GoPro HD2 beyond its frame: {forward:.4f} px out to {widest:.1f} deg")
    assert widest > 95 and forward <= 0.05, (widest, forward)


XML = """<lensdatabase version="1"><lens><maker>Test</maker><model>{model}</model><mount>Generic</mount>
<cropfactor>1.53</cropfactor><aspect-ratio>3:2</aspect-ratio><type>{type}</type><calibration>
<distortion model="ptlens" focal="16" a="0.021" b="-0.064" c="0.033"/></calibration></lens></lensdatabase>"""


@pytest.mark.parametrize("geometry, xml_type", [("fisheye_orthographic", "orthographic"),
                                                 ("fisheye_thoby", "fisheye_thoby")])
def test_orthographic_and_thoby_as_lensfun(geometry, xml_type):
    """The geometries the database has no lens of, on a lens written in lensfun's XML: the same mapping as
    lensfun's, out to where the geometry stops rising (90 degrees orthographic, 126 Thoby)."""
    db = lensfunpy.Database(xml=XML.format(model=xml_type, type=xml_type), load_common=False, load_bundled=False)
    lens = db.lenses[0]
    assert lens.type.name.lower() == geometry
    effect = LensDistortion(model="ptlens", focal_length=16.0, crop_factor=1.53, calibration_crop_factor=1.53,
                            calibration_aspect_ratio=1.5, lensfun_a=0.021, lensfun_b=-0.064, lensfun_c=0.033,
                            lensfun_geometry=geometry)
    lf = effect.model_for(W, H)
    forward, widest, backward, reach = compare_with_lensfun(lf, lens, 1.53, 16.0)
    assert forward <= 0.05 and backward <= 0.05 and reach, (forward, backward)
    forward, widest, _, _ = compare_with_lensfun(lf, lens, 1.53, 16.0, lensfunpy.LensType.EQUIRECTANGULAR, 0.3,
                                                 frame_only=False)
    print(f"{geometry}: {forward:.4f} px out to {widest:.1f} deg")
    limit = {"fisheye_orthographic": 90, "fisheye_thoby": 90 / 0.713}[geometry]
    assert forward <= 0.05 and limit - 1 < widest < limit, (forward, widest)


def test_the_engine_films_the_rays_lensfun_sees(tmp_path):
    """A fisheye profile made by the command (the GoPro HERO4, equisolid, 128 degrees across the diagonal: a
    pinhole render covers it) films a render whose pixels hold the camera-plane point they see: each pixel of the
    working grid holds the ray lensfun's reverse conversion gives its place in the frame (2x2 supersampled: the
    mean of four rays)."""
    import lowcam
    from lowcam.effects.bayer import sensel_shift_px

    profile = make(tmp_path, "fire-i", "GoPro", "HERO4", 3.0)
    lens = database_lens("GoPro", "HERO4")
    geo = profile.geometry
    lf = profile.lens
    assert lf.geometry == "fisheye_equisolid"
    assert 60 < np.degrees(lf.undistort_ray(-0.5, -0.5)[0]) < 75
    stage = profile.effect("lens_distortion")
    rows, cols = 1500, 2000  # cv2.remap places samples to 1/32 render px: 0.02 px of the frame here
    focal = stage.render_focal_px(geo, cols, rows)
    render = np.ones((rows, cols, 4), np.float32)
    render[..., 0] = 4 + ((np.arange(cols) - cols / 2 + 0.5) / focal)[None, :]  # positive: kept as it is
    render[..., 1] = 4 + ((np.arange(rows) - rows / 2 + 0.5) / focal)[:, None]
    render[..., 2] = 0.0
    working = lowcam.run(render, profile, None, stop_after="lens_distortion").state.working
    u, v = geo.working_pixel_centres(factor=1)
    du, dv = sensel_shift_px(profile)  # the working grid is laid out on the sensor, where the 2x2 blocks deliver it
    u, v = u + du, v + dv
    # every third working pixel sits on lensfun's unit grid (working scale 1.5): lensfun's reverse conversion there
    assert geo.working_scale == (1.5, 1.5)
    m = lensfunpy.Modifier(lens, lens.crop_factor, geo.width, geo.height)
    m.initialize(3.0, lens.min_aperture or 2.8, 1000.0, scale=1.0, flags=FLAGS.DISTORTION | FLAGS.GEOMETRY,
                 reverse=True)
    pick_u, pick_v = u[0, ::3], v[::3, 0]
    ref = columns(m.apply_geometry_distortion, pick_u, pick_v[0], 2 * len(pick_v))[::2]
    fx, fy, cx, cy = lf.pinhole_intrinsics()
    x_ref, y_ref = (ref[..., 0] - cx) / fx, (ref[..., 1] - cy) / fy
    seen = working[::3, ::3]
    inside = ((pick_u[None, :] >= 0) & (pick_u[None, :] <= geo.width - 1) & (pick_v[:, None] >= 0)
              & (pick_v[:, None] <= geo.height - 1))
    err_px = np.hypot(seen[..., 0] - 4 - x_ref, seen[..., 1] - 4 - y_ref) * fx  # pinhole px (at least the frame's)
    print(f"engine vs lensfun: {err_px[inside].max():.4f} pinhole px over {inside.sum()} pixels")
    assert err_px[inside].max() <= 0.05, err_px[inside].max()


def lensfun_distorted_radius_peak(lens, crop, focal, w=640, h=480):
    """The largest distorted radius lensfun's own distortion mapping reaches along the centre row, over the
    frame's half-diagonal (px): below 1, the frame's corners have no undistorted radius."""
    m = lensfunpy.Modifier(lens, crop, w, h)
    m.initialize(focal, lens.min_aperture or 2.8, 1000.0, scale=1.0, flags=FLAGS.DISTORTION)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    down = m.apply_geometry_distortion(cx, cy, 1, 40 * h).astype(np.float64)[:, 0, 1] - cy  # one column: scalar code
    falls = np.flatnonzero(np.diff(down) < 0)
    return float(down[:falls[0] + 1].max() if falls.size else down.max()) / (np.hypot(w - 1, h - 1) / 2)


def test_the_s21_ultrawide_imports_at_its_own_crop_factor_and_real_folds_are_refused(tmp_path, capsys):
    """Lensfun's own mapping: the Samsung Galaxy S21 ultrawide's ptlens stops rising 0.16 % short of its own
    frame's corner (within the terms' three decimals: imported, its last corner pixels see the ray where it stops),
    the Olympus 14-42 at 14 mm 8 % short (refused); the Canon 8-15 at 8 mm on a full frame, a circular fisheye, puts
    the ray 179 degrees from the axis well inside the frame's corner (refused). Each refusal is one line naming the
    lens and the setting."""
    s21 = database_lens("Samsung", "Samsung Galaxy S21 ultrawide")
    peak = lensfun_distorted_radius_peak(s21, 6.0, 2.2)
    assert 1 - LENSFUN_FOLD_TOLERANCE < peak < 1
    profile = make(tmp_path, "fire-i", "Samsung", "Galaxy S21 ultrawide", 2.2, name="s21.toml")
    lf = profile.lens
    assert profile.effect("lens_distortion").crop_factor == 6.0
    assert lf.rd_max() * lf.unit_px / (np.hypot(639, 479) / 2) == pytest.approx(peak, abs=2e-4)
    x, y = lf.undistort(np.array([0.0, 639.0]), np.array([0.0, 479.0]))  # the corners: the ray where it stops
    assert np.all(np.isfinite(x)) and np.hypot(x, y) * lf.scale == pytest.approx(lf.ru_max(), rel=1e-9)

    olympus = database_lens("Olympus", "Olympus M.Zuiko Digital ED 14-42mm f/3.5-5.6")
    assert lensfun_distorted_radius_peak(olympus, olympus.crop_factor, 14) < 0.93
    canon = database_lens("Canon", "Canon EF 8-15mm f/4L Fisheye USM")
    m = lensfunpy.Modifier(canon, 1.0, 640, 480)
    m.initialize(8.0, 4.0, 1000.0, scale=1.0, targeom=lensfunpy.LensType.EQUIRECTANGULAR,
                 flags=FLAGS.DISTORTION | FLAGS.GEOMETRY)
    values = lensdb.lens_setting(lensdb.find_lens("Canon", canon.model), 8.0).effects()["lens_distortion"]
    dist_px = lens_model_from(values, 640, 480).pinhole_intrinsics()[0]  # the focal length in px, unvalidated
    back = m.apply_geometry_distortion(319.5 + dist_px * np.radians(179), 239.5, 1, 1)[0, 0]  # longitude 179 deg
    assert np.hypot(back[0] - 319.5, back[1] - 239.5) < 0.85 * np.hypot(639, 479) / 2
    for maker, model, focal, why in [("Olympus", olympus.model, 14, "folds over inside the frame"),
                                     ("Canon", canon.model, 8, "an image circle inside the frame")]:
        code = main(["profile", "from-lensfun", "--maker", maker, "--model", model, "--focal-mm", str(focal),
                     "--base", "fire-i", "-o", str(tmp_path / "folds.toml")])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        crop = database_lens(maker, model).crop_factor
        assert f"{model} at {focal} mm, crop factor {crop:.3g}, on fire-i's 640x480 frame" in err, err
        assert why in err and not (tmp_path / "folds.toml").exists()


def test_a_panoramic_lens_is_refused_in_one_line(tmp_path, capsys):
    code = main(["profile", "from-lensfun", "--maker", "Generic", "--model", "Panoramic 10-100mm f/1.0", "--focal-mm",
                 "10", "--base", "fire-i", "-o", str(tmp_path / "pan.toml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "a panoramic lens; Lowcam takes rectilinear and fisheye lenses" in err


def test_a_rectilinear_profile_is_written_as_before(tmp_path):
    """The rectilinear default is not written: a rectilinear lens's profile has no ``lensfun_geometry``."""
    make(tmp_path, "fire-i", "DJI", "FC2103", 4.5, name="dji.toml")
    assert "lensfun_geometry" not in (tmp_path / "dji.toml").read_text()
    assert "lensfun_geometry" in make(tmp_path, "fire-i", "GoPro", "HERO4", 3.0).effect("lens_distortion").values()


def test_a_fisheyes_steep_vignetting_imports_as_lensfun_gives_it(tmp_path):
    """Lensfun's fisheyes fall off steeply: the Canon 8-15 at 8 mm has k3 = -15.2 in the pa model (-27.1 at f/5.7).
    On an APS-C body (crop 1.6) it imports with lensfun's terms as they are."""
    profile = make(tmp_path, "fire-i", "Canon", "Canon EF 8-15mm f/4L Fisheye USM", 8, crop=1.6)
    lens = lensdb.find_lens("Canon", "Canon EF 8-15mm f/4L Fisheye USM")
    terms = lensdb.lens_setting(lens, 8.0).effects()["vignetting"]["lensfun_terms"]
    assert min(terms) < -10 and list(profile.effect("vignetting").lensfun_terms) == pytest.approx(terms)
    steepest = lensdb.lens_setting(lens, 8.0, 5.7).effects()["vignetting"]["lensfun_terms"]
    assert main(["profile", "from-lensfun", "--maker", "Canon", "--model",
                 "Canon EF 8-15mm f/4L Fisheye USM", "--focal-mm", "8", "--aperture", "5.7", "--crop-factor", "1.6",
                 "--base", "fire-i", "-o", str(tmp_path / "f57.toml")]) == 0
    assert min(steepest) < -27
    assert list(load_profile(tmp_path / "f57.toml").effect("vignetting").lensfun_terms) == pytest.approx(steepest)
