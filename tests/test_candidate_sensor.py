"""Sensor-side candidates against data made outside the engine: the noise law under a black level,
hot pixels against DSNU, and blur where it acts in the chain.

Every hidden effect here is made by code written in this file (an analytic EMVA 1288 sensor, sparse hot pixels or
a dense offset map added to frames, a Gaussian blur by OpenCV), never by Lowcam's own effect.
"""
import re

import cv2
import numpy as np
import pytest

import lowcam
from helpers import diagnose_set, quiet_fire_i
from lowcam.errors import LowcamError, ProfileError
from lowcam.outputs import write_png


# --- 1. the noise law with a black level (EMVA 1288) -------------------------------------------------------------

def emva_sensor_stack(K, sigma_d_e, dark_dn, full_well_e, frames=32, level_dn=None, size=(240, 480), eta=0.6,
                      seed=0):
    """Frames (N, H, W, 3) uint8 of the EMVA 1288 linear camera model, independent per channel: photons
    (a horizontal ramp of irradiance, or one level) -> electrons ``Poisson(eta mu_p)`` plus dark noise
    ``N(0, sigma_d)`` (e-), clipped at the full well -> DN ``K e + dark_dn``, rounded and clipped to [0, 255].

    Its photon-transfer law is ``sigma_y^2 = K^2 sigma_d^2 + 1/12 + K (mu_y - dark_dn)`` (EMVA 1288 eq. 9)."""
    rng = np.random.default_rng(seed)
    h, w = size
    if level_dn is None:
        mu_e = np.tile(np.linspace(0.0, (235.0 - dark_dn) / K, w), (h, 1))
    else:
        mu_e = np.full((h, w), (level_dn - dark_dn) / K)
    mu_p = np.repeat(mu_e[..., None], 3, axis=2) / eta
    out = []
    for _ in range(frames):
        e = rng.poisson(eta * mu_p) + rng.normal(0.0, sigma_d_e, mu_p.shape)
        e = np.minimum(e, full_well_e)
        out.append(np.clip(np.round(K * e + dark_dn), 0, 255).astype(np.uint8))
    return np.stack(out)


def save_stack(stack, folder):
    folder.mkdir(parents=True, exist_ok=True)
    return [str(write_png(folder / f"f{i:02d}.png", f)) for i, f in enumerate(stack)]


# (K DN/e-, dark noise e-, black level DN, full well e-): intercepts from -1.8 to +3.0 DN^2
EMVA_SENSORS = [(0.1, 8.0, 16.0, 4000.0), (0.2, 4.0, 12.0, 2000.0), (0.08, 10.0, 25.0, 5000.0),
                (0.1, 20.0, 10.0, 6000.0)]


@pytest.mark.parametrize("K, sigma_d, dark, full_well", EMVA_SENSORS)
def test_noise_calibration_recovers_the_emva_1288_law_with_its_black_level(tmp_path, K, sigma_d, dark,
                                                                          full_well):
    from lowcam.calibrate import calibrate_noise

    stack = emva_sensor_stack(K, sigma_d, dark, full_well, seed=int(10 * K + dark))
    # per-channel sensels, no demosaic averaging: "bilinear" applies no green scaling
    cal = calibrate_noise(save_stack(stack, tmp_path / "stack"), "bilinear", "variance_linear")
    intercept = K * K * sigma_d ** 2 - K * dark  # the quantisation's 1/12 is removed by the fit
    for channel in ("red", "green", "blue"):
        a, b = cal.values["noise"][channel]
        assert b == pytest.approx(K, rel=0.02), (channel, b, K)
        assert a == pytest.approx(intercept, rel=0.06), (channel, a, intercept)
    # the profile takes the negative intercept, and its noise stays finite and >= 0 at black
    profile = lowcam.load_profile("fire-i").with_effect("noise", law="variance_linear",
                                                        **{c: cal.values["noise"][c] for c in ("red", "green", "blue")})
    sigma = profile.effect("noise").sigma("red", np.array([0.0, dark, 128.0]))
    assert np.all(np.isfinite(sigma)) and np.all(sigma >= 0)
    assert sigma[2] == pytest.approx(np.sqrt(intercept + K * 128.0), rel=0.03)


@pytest.mark.parametrize("level_dn", [60.0, 180.0])
def test_a_noise_stack_of_one_brightness_level_is_refused_in_one_line(tmp_path, level_dn):
    from lowcam.calibrate import calibrate_noise
    from lowcam.effects.noise import fit_noise

    stack = emva_sensor_stack(0.1, 8.0, 16.0, 4000.0, level_dn=level_dn)
    paths = save_stack(stack, tmp_path / "flat")
    with pytest.raises(LowcamError) as e:
        calibrate_noise(paths, "bilinear", "variance_linear")
    message = str(e.value)
    assert "\n" not in message and "f00.png" in message and "at least 3 levels" in message, message
    with pytest.raises(ValueError, match="at least 3 levels"):
        fit_noise(stack, demosaic="bilinear")


def test_the_noise_law_takes_a_negative_intercept_but_no_negative_slope(fire_i):
    noise = fire_i.with_effect("noise", law="variance_linear", red=[-2.0, 0.1]).effect("noise")
    assert noise.sigma("red", 10.0) == 0.0  # the variance is clamped, the coefficient kept
    assert noise.sigma("red", 100.0) == pytest.approx(np.sqrt(8.0))
    assert noise.red == [-2.0, 0.1]
    with pytest.raises(ProfileError, match="slope"):
        fire_i.with_effect("noise", red=[1.0, -0.1])
    render = np.ones((300, 400, 4), np.float32)
    render[..., :3] = 0.02
    out = lowcam.simulate(render, fire_i.with_effect("noise", law="variance_linear", red=[-2.0, 0.1]))
    assert out.dtype == np.uint8


# --- measurement sets whose hidden effect is made here ------------------------------------------------------------

def add_offset(offset):
    return lambda frame: np.clip(np.round(frame + offset), 0, 255).astype(np.uint8)


# --- 2. hot pixels (a few outliers) against DSNU (a dense offset map) --------------------------------------------

FLATS_AND_PHOTO = ("flat-dark", "flat-bright", "photo")


def hot_pixel_offsets(shape, density, seed):
    """Sparse hot pixels: a ``density`` share of pixels, each bright by its own 8-150 DN (log-uniform), half in
    all channels, half in one."""
    rng = np.random.default_rng(seed)
    hot = rng.random(shape[:2]) < density
    strength = np.exp(rng.uniform(np.log(8.0), np.log(150.0), shape[:2]))
    one, channel = rng.random(shape[:2]) < 0.5, rng.integers(0, 3, shape[:2])
    return np.stack([np.where(hot & (~one | (channel == c)), strength, 0.0) for c in range(3)], axis=-1), hot


@pytest.mark.parametrize("density", [0.001, 0.004])
def test_sparse_hot_pixels_are_named_hot_pixels_not_dsnu(tmp_path, density):
    profile = quiet_fire_i()
    offset, hot = hot_pixel_offsets((profile.camera.height, profile.camera.width, 3), density, seed=11)
    d = diagnose_set(tmp_path, profile, ["hot_pixels", "dsnu", "prnu"], scenes=FLATS_AND_PHOTO,
                     post=add_offset(offset))
    ranking = [(c.effect, round(c.error_after, 3), round(c.score, 3)) for c in d.candidates]
    best = d.candidates[0]
    assert d.error > 1.1 and best.effect == "hot_pixels", ranking
    assert best.error_after <= 1.25, ranking
    assert "sparse outliers" in best.evidence, best.evidence
    # the weakest (8 DN) are within the noise of 12 frames: most, not all, are found
    assert 0.7 * hot.sum() <= best.params["count"] <= 1.1 * hot.sum(), (best.params["count"], hot.sum())
    # DSNU saw where the offset sits and refused: it is not offered for this set
    assert "dsnu" not in [c.effect for c in d.candidates if "(with" not in c.evidence], ranking


@pytest.mark.parametrize("sigma_dn, density", [(2.0, 1.0), (3.0, 0.3)])
def test_a_dense_offset_map_is_named_dsnu_not_hot_pixels(tmp_path, sigma_dn, density):
    profile = quiet_fire_i()
    rng = np.random.default_rng(12)
    shape = (profile.camera.height, profile.camera.width, 3)
    offset = rng.normal(0.0, sigma_dn, shape) * (rng.random(shape[:2]) < density)[..., None]
    d = diagnose_set(tmp_path, profile, ["dsnu", "hot_pixels", "prnu"], scenes=FLATS_AND_PHOTO,
                     post=add_offset(offset))
    ranking = [(c.effect, round(c.error_after, 3), round(c.score, 3)) for c in d.candidates]
    best = d.candidates[0]
    assert d.error > 1.1 and best.effect == "dsnu", ranking
    assert best.error_after <= 1.25, ranking
    assert "dense per-pixel offset map" in best.evidence, best.evidence
    assert "hot_pixels" not in [c.effect for c in d.candidates], ranking


# --- 3. blur where it acts in the chain ---------------------------------------------------------------------------

def test_with_effect_after_places_a_second_effect_and_the_order_survives_save_and_load(tmp_path, fire_i):
    p = fire_i.with_effect("vertical_blur", sigma=0.4)  # at its order: before the sharpening
    p = p.with_effect("vertical_blur", after="sharpening", sigma=0.9)
    names = [e.name for e in p.effects]
    i = names.index("sharpening")
    assert names[i + 1] == "vertical_blur" and names.index("vertical_blur") < i, names
    assert [e.sigma for e in p.effects if e.name == "vertical_blur"] == [0.4, 0.9]
    # again: the effect right after sharpening is changed, not a third one added
    p = p.with_effect("vertical_blur", after="sharpening", sigma=1.1)
    assert [e.sigma for e in p.effects if e.name == "vertical_blur"] == [0.4, 1.1]
    loaded = lowcam.load_profile(p.save(tmp_path / "two-blurs.toml"))
    assert [e.name for e in loaded.effects] == [e.name for e in p.effects]
    assert [e.sigma for e in loaded.effects if e.name == "vertical_blur"] == [0.4, 1.1]
    with pytest.raises(ProfileError, match="no effect 'jpeg' to place 'vertical_blur' after"):
        fire_i.with_effect("vertical_blur", after="jpeg", sigma=1.0)


def vertical_blur(image, sigma_px):
    """OpenCV's Gaussian blur along columns only (sigma in pixels)."""
    k = cv2.getGaussianKernel(2 * int(np.ceil(4 * sigma_px)) + 1, sigma_px).astype(np.float32)
    return cv2.sepFilter2D(np.asarray(image, np.float32), -1, np.ones((1, 1), np.float32), k,
                           borderType=cv2.BORDER_REPLICATE)


BLUR_CANDIDATES = ["vertical_blur_after_sharpening", "vertical_blur", "defocus"]


def _after_sharpening_and_demosaic(candidate):
    names = [e.name for e in candidate.profile.effects]
    return names.index("demosaic") < len(names) - 1 - names[::-1].index("vertical_blur")


@pytest.mark.parametrize("sigma_px", [1.2, pytest.param(2.0, marks=pytest.mark.slow)])
def test_a_vertical_blur_of_the_delivered_frames_is_fitted_after_sharpening(tmp_path, fire_i, sigma_px):
    post = lambda f: np.clip(np.round(vertical_blur(f, sigma_px)), 0, 255).astype(np.uint8)  # noqa: E731
    d = diagnose_set(tmp_path, fire_i, BLUR_CANDIDATES, scenes=("chart", "noise-field"), post=post)
    ranking = [(c.effect, round(c.error_after, 3)) for c in d.candidates]
    best = d.candidates[0]
    assert d.error > 1.1 and best.effect == "vertical_blur_after_sharpening", ranking
    assert best.error_after <= 1.25 and _after_sharpening_and_demosaic(best), ranking


def disc_blur(image, radius_px):
    """OpenCV convolution with an anti-aliased uniform disc (a defocused lens's blur)."""
    n = int(np.ceil(radius_px)) + 1
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1].astype(np.float32)
    k = np.clip(radius_px + 0.5 - np.hypot(xx, yy), 0.0, 1.0)
    return cv2.filter2D(np.asarray(image, np.float32), -1, k / k.sum(), borderType=cv2.BORDER_REPLICATE)


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_an_optical_blur_is_still_fitted_before_sharpening(tmp_path, fire_i):
    """A defocus made on the ideal render (before the sensor, its noise and the sharpening): the optical
    candidate, before the sharpening, beats the blur after it. (Defocus reaches about 1.4 here, not 1.25: through
    the Fire-i's wide-angle lens a disc uniform on the render is a 3.8 px disc at the centre and a 0.8 x 2.2 px
    ellipse at the corners of the frame, which no one disc matches; a disc uniform on the sensor closes to 1.03,
    tests/test_candidate_motion_optics.py.)"""
    pre = lambda ideal: disc_blur(ideal, 2.0)  # noqa: E731
    d = diagnose_set(tmp_path, fire_i, BLUR_CANDIDATES, rounds=1, scenes=("chart", "noise-field"), pre=pre)
    ranking = [(c.effect, round(c.error_after, 3)) for c in d.candidates]
    best = d.candidates[0]
    assert d.error > 1.1 and best.effect == "defocus", ranking
    assert best.error_after < 0.5 * d.error, ranking
    names = [e.name for e in best.profile.effects]
    assert names.index("defocus") < names.index("sharpening")
    late = next(c for c in d.candidates if c.effect == "vertical_blur_after_sharpening")
    assert late.error_after > 1.2 * best.error_after, ranking
