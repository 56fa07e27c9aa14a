"""Sensor-side candidates against data made outside the engine (issue 12): the noise law under a black level,
hot pixels against DSNU, and blur where it acts in the chain.

Every hidden effect here is made by code written in this file (an analytic EMVA 1288 sensor, sparse hot pixels or
a dense offset map added to frames, a Gaussian blur by OpenCV), never by Lowcam's own effect.
"""
import re

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.errors import LowcamError, ProfileError
from lowcam.io import write_png


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
