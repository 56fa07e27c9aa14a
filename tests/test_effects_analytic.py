"""Analytic tests of the effects beyond the paper: rolling shutter, tone curve, veiling glare, hot pixels, PRNU,
DSNU, row noise, vertical blur, defocus, JPEG and asymmetric sharpening.

Every expectation here is computed in the test from a physical or mathematical construction written out in the test
(a rotation's image shift, a power law, the Gaussian mass inside a disc, the moments of a uniform disc, the variance of
a sampled Gaussian, an independent JPEG encoder, ...), never by running the effect's own code a second time. So each
test fails if its effect were a no-op, had the wrong sign, or the wrong size; a self-consistency check (same code,
same answer) could not.

Scenes are exact renders (edges and discs with analytic coverage) of 800x600 pixels on the Fire-i (640x480 frames),
with the stages that would blur the comparison switched off (noise above all). Intermediate states are read with
``lowcam.run(..., stop_after=...)``: ``state.working`` (the distorted RGBA image), ``state.bayer`` (sensel planes
R, Gr, Gb, B in DN) and ``state.rgb`` (the demosaiced frame in DN).
"""
import io

import numpy as np
import pytest
from scipy.special import i0e

import lowcam
from lowcam.effects.bayer import sensel_shift_px

from helpers import flat_render, noise_field

W, H = 800, 600  # render size (4:3, like the Fire-i's 640x480 frame)


def _quiet(profile, *more):
    """The profile with noise and the stages that would blur an exact comparison switched off."""
    return profile.without("noise", "vignetting", "crosstalk", "chromatic_aberration", "motion_blur", *more)


def _render_axes(profile):
    """Camera-plane coordinates (tan angles) of the render's pixel centres along x and y, and its focal length."""
    half_x, _ = lowcam.render_field_of_view(profile)
    focal = W / (2 * half_x)
    return (np.arange(W) - W / 2 + 0.5) / focal, (np.arange(H) - H / 2 + 0.5) / focal, focal


def _grey_render(grey):
    """An opaque render of a greyscale (H, W) image."""
    out = np.ones((H, W, 4), np.float32)
    out[..., :3] = np.asarray(grey, np.float32)[..., None]
    return out


def _edge(profile, x_edge=0.0, lo=0.2, hi=0.6, vertical=True):
    """An opaque render: ``lo`` left of (above) the line x = x_edge (y = x_edge), ``hi`` right of (below) it,
    with exact pixel coverage."""
    x, y, focal = _render_axes(profile)
    t = x if vertical else y
    c = np.clip((t - x_edge) * focal + 0.5, 0, 1)
    c2 = np.broadcast_to(c[None, :] if vertical else c[:, None], (H, W))
    return _grey_render(lo + (hi - lo) * c2)


def _disc(profile, radius, value=1.0):
    """An opaque disc of ``radius`` (tan units) at the optical axis on a transparent background."""
    x, y, focal = _render_axes(profile)
    alpha = np.clip((radius - np.hypot(*np.meshgrid(x, y))) * focal + 0.5, 0, 1).astype(np.float32)
    out = np.zeros((H, W, 4), np.float32)
    out[..., :3] = value * alpha[..., None]
    out[..., 3] = alpha
    return out


def _sensel_coords(profile, plane_shape, channel):
    """Output-pixel coordinates (u of each column, v of each row) where a sensel plane of ``channel`` (R, Gr, Gb, B)
    samples the frame: its pixels, moved by the profile's demosaicing (``sensel_shift_px``, half a pixel left and
    down for the Fire-i's blocks)."""
    g = profile.geometry
    hb, wb = plane_shape
    by, bx = (hb - g.height // 2) // 2, (wb - g.width // 2) // 2
    dy, dx = g.cfa[channel]
    su, sv = sensel_shift_px(profile)
    return 2 * (np.arange(wb) - bx) + dx + su, 2 * (np.arange(hb) - by) + dy + sv


# --- 1. rolling shutter -------------------------------------------------------------------------------------------

def _centre_focal_px(profile):
    """Horizontal focal length (output px per tan unit) of the lens at the optical axis, by finite differences."""
    eps = 1e-5
    u1, _ = profile.lens.distort(np.array([eps]), np.array([0.0]))
    u0, _ = profile.lens.distort(np.array([-eps]), np.array([0.0]))
    return float(u1[0] - u0[0]) / (2 * eps)


def _bar_centres(profile, render, omega):
    """The bar's centroid u (output px) on every Gr sensel row near the centre, and those rows' v."""
    b = lowcam.run(render, profile, angular_velocity=omega, stop_after="bayer_sampling").state.bayer[1]
    u, v = _sensel_coords(profile, b.shape, "Gr")
    cols = np.abs(u - profile.geometry.width / 2) < 70
    w = b[:, cols]
    return (w * u[cols]).sum(axis=1) / w.sum(axis=1), v


@pytest.mark.parametrize("wy, readout", [(1.0, 0.05), (-1.5, 0.05), (1.0, -0.05)])
def test_rolling_shutter_skews_a_vertical_bar_by_f_w_readout(fire_i, wy, readout):
    """Row v is exposed t(v) = (v/H - 1/2) R after the middle row, when the camera has turned by wy t(v) about y:
    a bar at x = 0 is seen at x = -tan(wy t), i.e. at u ~ cx - f wy t(v), so du/dv = -f wy R / H (f: the lens's
    focal length at the centre). Positive wy pans right, so later (lower) rows see the bar further left; a negative
    read-out (Gyroflow's bottom row first) skews the other way."""
    profile = _quiet(fire_i).with_effect("rolling_shutter", readout_s=readout)
    x, _, focal = _render_axes(profile)
    half_width = 0.02
    bar = _grey_render(np.broadcast_to(np.clip((half_width - np.abs(x)) * focal + 0.5, 0, 1)[None, :], (H, W)))
    f = _centre_focal_px(profile)
    height = profile.geometry.height
    predicted_slope = -f * wy * readout / height  # px of u per row

    still, v = _bar_centres(profile, bar, (0.0, 0.0, 0.0))
    moving, _ = _bar_centres(profile, bar, (0.0, wy, 0.0))
    cy = height / 2 - 0.5
    # central half of the frame: the lens's horizontal scale there is within a few % of the centre's
    central = np.abs(v - cy) < height / 4
    slope = np.polyfit(v[central], moving[central] - still[central], 1)[0]
    assert np.sign(slope) == -np.sign(wy * readout)
    assert slope == pytest.approx(predicted_slope, rel=0.06)
    # top rows against bottom rows (a fraction 0.75 of the frame apart): ~ f wy R * 0.75, less the barrel's
    # shrinking of the horizontal scale away from the centre
    top = np.abs(v - (cy - 0.375 * height)) < 6
    bottom = np.abs(v - (cy + 0.375 * height)) < 6
    skew = (moving[bottom] - still[bottom]).mean() - (moving[top] - still[top]).mean()
    assert skew == pytest.approx(-f * wy * readout * 0.75, rel=0.15)
    # the middle row is exposed at t = 0: it does not move
    assert np.abs(moving - still)[np.abs(v - cy) < 2].max() < 0.1


# --- 2. tone curve ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("gamma", [2.2, 0.5])
def test_tone_curve_is_the_power_law_on_flat_fields(fire_i, gamma):
    """out = 255 (in / 255)^(1 / gamma) per channel on straight colour; a flat render of value c gives in = 255 c,
    and a half-covered pixel (alpha 0.5) keeps its alpha: out = 0.5 * 255 c^(1 / gamma)."""
    profile = _quiet(fire_i, "quantisation", "saturation").with_effect("tone_curve", gamma=gamma)
    for value, alpha in ((0.1, 1.0), (0.5, 1.0), (0.4, 0.5)):
        rgb = lowcam.run(flat_render(value, W, H, alpha), profile, stop_after="tone_curve").state.rgb
        inner = rgb[20:-20, 20:-20]
        expected = alpha * 255.0 * value ** (1.0 / gamma)
        assert np.abs(inner - expected).max() < 0.05, (value, alpha)
    # and it is the curve, not a constant gain: two levels' ratio is (c1 / c2)^(1 / gamma)
    lo = lowcam.run(flat_render(0.1, W, H), profile, stop_after="tone_curve").state.rgb[240, 320, 1]
    hi = lowcam.run(flat_render(0.5, W, H), profile, stop_after="tone_curve").state.rgb[240, 320, 1]
    assert hi / lo == pytest.approx(5.0 ** (1.0 / gamma), rel=1e-3)


# --- 3. veiling glare ---------------------------------------------------------------------------------------------

def _glare_states(profile, render):
    before = lowcam.run(render, profile, stop_after="spatial_blur").state.working
    after = lowcam.run(render, profile, stop_after="veiling_glare").state.working
    return before, after


def test_veiling_glare_adds_strength_times_the_light_spread_as_a_gaussian(fire_i):
    """The haze is s * (image convolved with a Gaussian of sigma = radius_px working-scaled). Its total is s times
    the light: sum(after) = (1 + s) sum(before). For a uniform disc of radius R and level I the haze at distance rho
    from its centre is s I / sigma^2 int_0^R p exp(-(rho^2 + p^2) / 2 sigma^2) I0(rho p / sigma^2) dp, which is
    s I (1 - exp(-R^2 / 2 sigma^2)) at the centre."""
    strength, radius_px = 0.3, 20.0
    profile = _quiet(fire_i).with_effect("veiling_glare", strength=strength, radius_px=radius_px)
    before, after = _glare_states(profile, _disc(profile, 0.06))
    sigma = radius_px * min(profile.geometry.working_scale)

    total0, total1 = before[..., :3].sum(), after[..., :3].sum()
    assert total1 / total0 == pytest.approx(1 + strength, rel=0.02)
    assert np.array_equal(after[..., 3], before[..., 3])  # light without coverage: alpha is untouched

    alpha = before[..., 3]
    r_disc = np.sqrt(alpha.sum() / np.pi)
    yy, xx = np.mgrid[0:alpha.shape[0], 0:alpha.shape[1]]
    cx, cy = (alpha * xx).sum() / alpha.sum(), (alpha * yy).sum() / alpha.sum()
    rho = np.hypot(xx - cx, yy - cy)
    level = before[..., 1][rho < 0.5 * r_disc].mean()
    haze = after[..., 1] - before[..., 1]

    def predicted(r):
        p = np.linspace(0, r_disc, 2001)
        f = p * np.exp(-(r - p) ** 2 / (2 * sigma ** 2)) * i0e(r * p / sigma ** 2)
        return strength * level / sigma ** 2 * ((f[1:] + f[:-1]) / 2 * np.diff(p)).sum()

    assert predicted(0.0) == pytest.approx(strength * level * (1 - np.exp(-r_disc ** 2 / (2 * sigma ** 2))))
    assert haze[rho < 3].mean() == pytest.approx(predicted(0.0), rel=0.05)
    for r in (r_disc + sigma, r_disc + 2 * sigma, r_disc + 3 * sigma):
        ring = np.abs(rho - r) < 1.5
        assert before[..., 1][ring].max() == 0  # outside the disc there was no light ...
        assert haze[ring].mean() == pytest.approx(predicted(r), rel=0.08), r  # ... now there is haze


def test_veiling_glare_of_strength_zero_is_the_identity(fire_i):
    """s = 0: after = before + 0 * haze, bit for bit."""
    profile = _quiet(fire_i).with_effect("veiling_glare", strength=0.0, radius_px=40.0)
    before, after = _glare_states(profile, _disc(profile, 0.06))
    assert np.array_equal(before, after)


# --- 4-6. fixed-pattern sensor defects ----------------------------------------------------------------------------

def _rgb_pair(profile, name, render):
    """The demosaiced frame (DN) without the fixed-pattern effect ``name`` and with it."""
    clean = lowcam.run(render, profile, stop_after="demosaic").state.rgb
    out = lowcam.run(render, profile, stop_after=name).state.rgb
    return clean, out


def test_hot_pixels_are_where_the_seeded_draw_puts_them_and_add_strength(fire_i):
    """A pixel is hot where U < fraction, U ~ uniform drawn from default_rng(pattern_seed) over the (480, 640)
    frame; it gains ``strength`` DN in every channel, the others nothing; count ~ Binomial(N, fraction)."""
    strength, fraction, seed = 120.0, 0.002, 7
    profile = _quiet(fire_i).with_effect("hot_pixels", strength=strength, fraction=fraction, pattern_seed=seed)
    clean, out = _rgb_pair(profile, "hot_pixels", flat_render(0.05, W, H))  # a dark field: 12.75 DN
    diff = out - clean
    found = (diff > strength / 2).all(axis=2)
    h, w = found.shape
    drawn = np.random.default_rng(seed).random((h, w)) < fraction
    assert np.array_equal(found, drawn)
    assert np.abs(diff[found] - strength).max() < 1e-3
    assert np.abs(diff[~found]).max() < 1e-3
    n = h * w
    assert abs(found.sum() - fraction * n) < 4 * np.sqrt(n * fraction * (1 - fraction))
    other = lowcam.run(flat_render(0.05, W, H), profile.with_effect("hot_pixels", pattern_seed=seed + 1),
                       stop_after="hot_pixels").state.rgb
    assert (((other - clean) > strength / 2).all(axis=2) & found).sum() < 0.05 * found.sum()  # another sensor


def test_prnu_is_a_per_pixel_gain_with_sigma_strength(fire_i):
    """out = clean (1 + g), g ~ N(0, strength^2) fixed per pixel: out / clean has mean 1 and std strength, and the
    same ratio map at every brightness (a gain, not an offset)."""
    strength = 0.03
    profile = _quiet(fire_i, "quantisation").with_effect("prnu", strength=strength)
    ratios = []
    for level in (0.2, 0.6):
        clean, out = _rgb_pair(profile, "prnu", flat_render(level, W, H))
        ratios.append(out / clean)
    r = ratios[0]
    assert r.mean() == pytest.approx(1.0, abs=1e-3)
    assert r.std() == pytest.approx(strength, rel=0.02)
    assert np.abs(ratios[1] - ratios[0]).max() < 1e-4
    g = r[..., 1] - 1  # independent per pixel: neighbours uncorrelated
    assert abs(np.corrcoef(g[:, :-1].ravel(), g[:, 1:].ravel())[0, 1]) < 0.02


def test_dsnu_is_a_per_pixel_offset_independent_of_brightness(fire_i):
    """out = clean + o, o ~ N(0, strength^2) DN fixed per pixel: out - clean has std strength and is the same map at
    two brightness levels (while the ratio out / clean is not)."""
    strength = 3.0
    profile = _quiet(fire_i, "quantisation").with_effect("dsnu", strength=strength)
    offsets, ratios = [], []
    for level in (0.2, 0.6):
        clean, out = _rgb_pair(profile, "dsnu", flat_render(level, W, H))
        offsets.append(out - clean)
        ratios.append(out / clean)
    assert np.abs(offsets[1] - offsets[0]).max() < 1e-3
    assert offsets[0].std() == pytest.approx(strength, rel=0.02)
    assert abs(offsets[0].mean()) < 0.02 * strength
    assert np.abs(ratios[1] - ratios[0]).max() > 0.05  # not a gain


# --- 7. row noise -------------------------------------------------------------------------------------------------

def _row_offsets(profile, render, seed, frame):
    """Each sensel plane's per-row offset (DN) added by row noise, (4, rows); asserts it is constant along rows."""
    clean = lowcam.run(render, profile, stop_after="bayer_sampling").state.bayer
    noisy = lowcam.run(render, profile, seed=seed, frame=frame, stop_after="row_noise").state.bayer
    diff = noisy - clean
    assert diff.std(axis=2).max() < 1e-3  # the same offset along a whole row
    return diff.mean(axis=2)


def test_row_noise_offsets_whole_rows_with_sigma_per_frame(fire_i):
    """Each sensor row v gets sigma_dn * z_v, z_v ~ N(0, 1) drawn per (seed, frame): row means have std sigma_dn,
    the sensels of one sensor row (R and Gr; Gb and B) share it, another frame draws anew, the same (seed, frame)
    repeats it exactly."""
    sigma = 2.0
    profile = _quiet(fire_i).with_effect("row_noise", sigma_dn=sigma)
    render = flat_render(0.4, W, H)
    off = _row_offsets(profile, render, seed=3, frame=0)
    cfa = profile.geometry.cfa
    names = ("R", "Gr", "Gb", "B")
    for a, b in (("R", "Gr"), ("Gb", "B")):
        assert cfa[a][0] == cfa[b][0]
        assert np.abs(off[names.index(a)] - off[names.index(b)]).max() < 1e-4
    independent = np.concatenate([off[names.index("R")], off[names.index("Gb")]])  # every sensor row once
    assert independent.std() == pytest.approx(sigma, rel=0.12)
    again = _row_offsets(profile, render, seed=3, frame=0)
    assert np.array_equal(off, again)
    later = _row_offsets(profile, render, seed=3, frame=1)
    assert later.std() == pytest.approx(sigma, rel=0.12)
    assert abs(np.corrcoef(off[0], later[0])[0, 1]) < 0.2


# --- 8. vertical blur ---------------------------------------------------------------------------------------------

def _lsf_variance(profile_1d):
    """Second central moment (sensels^2) of the line-spread function (the derivative of an edge profile)."""
    d = np.diff(profile_1d)
    i = int(np.argmax(np.abs(d)))
    w = d[i - 12:i + 13]
    k = np.arange(w.size)
    m = (w * k).sum() / w.sum()
    return (w * (k - m) ** 2).sum() / w.sum()


def test_vertical_blur_widens_a_horizontal_edge_by_its_kernel_variance_only(fire_i):
    """Convolution adds variances: a horizontal edge's line-spread variance grows by the kernel's,
    sum(k^2 g_k) / sum(g_k) with g_k = exp(-k^2 / 2 sigma^2), k = -(taps-1)/2 .. (taps-1)/2 (sensels); a vertical
    edge (constant along columns) is left as it was."""
    sigma, taps = 1.5, 9
    profile = _quiet(fire_i, "quantisation").with_effect("vertical_blur", sigma=sigma, taps=taps)
    k = np.arange(taps) - (taps - 1) / 2
    g = np.exp(-0.5 * (k / sigma) ** 2)
    kernel_var = (g * k ** 2).sum() / g.sum()
    widened = {}
    for vertical in (False, True):
        render = _edge(profile, vertical=vertical)
        b0 = lowcam.run(render, profile, stop_after="horizontal_blur").state.bayer[1]
        b1 = lowcam.run(render, profile, stop_after="vertical_blur").state.bayer[1]
        hb, wb = b0.shape
        if vertical:  # profile across the edge: along a row
            p0, p1 = b0[hb // 2 - 40:hb // 2 + 40].mean(0), b1[hb // 2 - 40:hb // 2 + 40].mean(0)
        else:  # along a column
            p0, p1 = b0[:, wb // 2 - 40:wb // 2 + 40].mean(1), b1[:, wb // 2 - 40:wb // 2 + 40].mean(1)
        widened[vertical] = _lsf_variance(p1) - _lsf_variance(p0)
    assert widened[False] == pytest.approx(kernel_var, rel=0.03)
    assert abs(widened[True]) < 0.01 * kernel_var


# --- 9. defocus ---------------------------------------------------------------------------------------------------

def _moments(img):
    """Total, centroid (x, y) and variance along x plus along y of a non-negative image."""
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    m = img.sum()
    cx, cy = (img * xx).sum() / m, (img * yy).sum() / m
    return m, cx, cy, (img * ((xx - cx) ** 2 + (yy - cy) ** 2)).sum() / m


def test_defocus_spreads_a_point_into_a_uniform_disc_of_the_radius(fire_i):
    """A point through a pillbox of radius R (= radius_px times the working scale): energy conserved and all within
    R, a fraction (r / R)^2 within r, a flat top of height E / (pi R^2), and its spread grows by a uniform disc's
    E[rho^2] = R^2 / 2."""
    radius_px = 6.0
    profile = _quiet(fire_i).with_effect("defocus", radius_px=radius_px)
    point = _disc(profile, 0.003)
    before = lowcam.run(point, profile, stop_after="spatial_blur").state.working[..., 1]
    after = lowcam.run(point, profile, stop_after="defocus").state.working[..., 1]
    big_r = radius_px * min(profile.geometry.working_scale)

    e0, _, _, var0 = _moments(before)
    e1, cx, cy, var1 = _moments(after)
    assert e1 == pytest.approx(e0, rel=1e-4)
    assert var1 - var0 == pytest.approx(big_r ** 2 / 2, rel=0.04)
    yy, xx = np.mgrid[0:after.shape[0], 0:after.shape[1]]
    rho = np.hypot(xx - cx, yy - cy)
    assert after[rho < big_r + 4].sum() > 0.999 * e1  # R plus the point's own few working px
    inner = rho < big_r / 2  # uniform: the share of the disc's area within r, (r / R)^2 counted in pixels
    assert after[inner].sum() / e1 == pytest.approx(inner.sum() / (np.pi * big_r ** 2), rel=0.02)
    top = after[rho < big_r - 3]
    assert top.std() < 0.02 * top.mean()  # flat-topped
    assert top.mean() == pytest.approx(e1 / (np.pi * big_r ** 2), rel=0.04)
    # the point itself was much smaller and higher
    assert before.max() > 5 * top.mean()


def test_defocus_of_radius_zero_is_the_identity(fire_i):
    """radius 0: a disc of radius 0 is a delta."""
    profile = _quiet(fire_i).with_effect("defocus", radius_px=0.0)
    point = _disc(profile, 0.003)
    before = lowcam.run(point, profile, stop_after="spatial_blur").state.working
    after = lowcam.run(point, profile, stop_after="defocus").state.working
    assert np.array_equal(before, after)


# --- 10. JPEG -----------------------------------------------------------------------------------------------------

def _blockiness(frame):
    """Mean |step| between neighbouring pixels across 8-px block boundaries over that inside blocks, (x, y)."""
    g = frame.astype(np.float64).mean(axis=2)
    out = []
    for axis in (1, 0):
        d = np.abs(np.diff(g, axis=axis))
        at = np.take(d, np.arange(7, d.shape[axis], 8), axis=axis).mean()
        inside = np.delete(d, np.arange(7, d.shape[axis], 8), axis=axis).mean()
        out.append(at / inside)
    return out


@pytest.mark.parametrize("quality", [10, 50])
def test_jpeg_has_8x8_blocks_and_matches_an_independent_encoder(fire_i, quality):
    """Baseline JPEG codes 8x8 DCT blocks independently: at low quality steps across block boundaries exceed those
    inside blocks. The frame is what Pillow's encoder (4:2:0) makes of the uncompressed frame at that quality."""
    Image = pytest.importorskip("PIL.Image")
    profile = fire_i.without("noise")
    scene = noise_field(W, H, cells=(40, 30))  # smooth: its own steps do not line up with the blocks
    plain = lowcam.run(scene, profile).frame
    coded = lowcam.run(scene, profile.with_effect("jpeg", quality=quality)).frame
    bx, by = _blockiness(coded)
    px, py = _blockiness(plain)
    assert max(px, py) < 1.2
    if quality <= 10:
        assert min(bx, by) > 2.0
    else:
        assert min(bx, by) > 1.1
    buf = io.BytesIO()
    Image.fromarray(plain).save(buf, "JPEG", quality=quality, subsampling=2)
    reference = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB")).astype(np.int16)
    loss = np.abs(coded.astype(np.int16) - plain).mean()
    assert loss > 1.0  # compression changed the frame ...
    assert np.abs(coded - reference).mean() < 0.05 * loss  # ... the way an independent JPEG encoder does


# --- 11. asymmetric sharpening ------------------------------------------------------------------------------------

def _halos(profile, shift, lo=0.3, hi=0.6):
    """Undershoot left of and overshoot right of a dark-to-bright vertical edge midway between two Gr sensel
    columns' samples (u = 320 moved by the demosaicing's ``sensel_shift_px``), in DN, from the mean Gr row; and the
    profiles before and after sharpening."""
    q = profile.with_effect("sharpening", shift=shift)
    u_edge = 320.0 + sensel_shift_px(q)[0]
    x_edge, _ = q.lens.undistort(np.array([u_edge]), np.array([q.geometry.height / 2 - 0.5]))
    render = _edge(q, float(x_edge[0]), lo, hi)
    b0 = lowcam.run(render, q, stop_after="horizontal_blur").state.bayer[1]
    b1 = lowcam.run(render, q, stop_after="sharpening").state.bayer[1]
    hb = b1.shape[0]
    p0, p1 = b0[hb // 2 - 60:hb // 2 + 60].mean(0), b1[hb // 2 - 60:hb // 2 + 60].mean(0)
    u, _ = _sensel_coords(q, b1.shape, "Gr")
    left = (u < u_edge) & (u > u_edge - 30)
    right = (u > u_edge) & (u < u_edge + 30)
    return 255 * lo - p1[left].min(), p1[right].max() - 255 * hi, p0, p1


def test_sharpening_shift_moves_the_halo_to_one_side_and_its_sign_mirrors_it(fire_i):
    """F = I + a (I - L), L the Gaussian low-pass centred ``shift`` taps off: with shift 0 the halos either side of
    a symmetric edge are equal; with shift > 0 the halo (undershoot) left of the edge is larger than the one right of
    it (L reads the image shift sensels to the right), and shift -> -shift mirrors left and right."""
    profile = _quiet(fire_i, "quantisation")
    under0, over0, _, _ = _halos(profile, 0.0)
    assert under0 > 0.5 and over0 > 0.5
    assert under0 == pytest.approx(over0, abs=0.3)
    s = 1.0
    under_p, over_p, _, _ = _halos(profile, s)
    under_m, over_m, _, _ = _halos(profile, -s)
    assert under_p > 3 * max(over_p, 1.0) and under_p > 2 * under0
    assert over_m > 3 * max(under_m, 1.0) and over_m > 2 * over0
    assert under_p == pytest.approx(over_m, rel=0.1)  # the mirror image
    assert over_p == pytest.approx(under_m, abs=0.1 * under_p)


def test_sharpening_with_shift_follows_its_formula_on_a_measured_edge(fire_i):
    """F(i) = (1 + a) I(i) - a sum_t G(t - shift) I(i + t) / sum_t G(t - shift), t = -(taps-1)/2 .. (taps-1)/2,
    G(t) = exp(-t^2 / 2 sigma^2), a = gain_per_unit * sharpness, on the edge profile I measured before sharpening."""
    profile = _quiet(fire_i, "quantisation")
    sharp = profile.effect("sharpening")
    a, sigma, taps = sharp.gain_per_unit * sharp.sharpness, sharp.sigma, sharp.taps
    t = np.arange(taps) - (taps - 1) // 2
    for shift in (0.7, -0.7):
        _, _, before, after = _halos(profile, shift)
        g = np.exp(-0.5 * ((t - shift) / sigma) ** 2)
        g /= g.sum()
        n = before.size
        i = np.arange(taps, n - taps)
        low = sum(gk * before[i + tk] for gk, tk in zip(g, t))
        expected = (1 + a) * before[i] - a * low
        assert np.abs(after[i] - expected).max() < 0.01 * 255 * 0.3
