"""Verdicts that are never confidently wrong: a candidate that does not lower the error is not named, an
unexplained residual is named by its family (edges, levels, space or time), read from where it lives, and the
noise's texture (its correlation in space and time) tells a denoising camera from a raw one."""
from dataclasses import replace

import cv2
import numpy as np
import pytest

from lowcam.measure.compare import compare, noise_texture, residual_family
from lowcam.measure.diagnose import NAMED_GAIN, Candidate, Diagnosis
from lowcam.measure.sets import load_set
from lowcam.measure.synth import synthesise

#: family -> (effects added to the data, effects switched off in the profile, scenes that show it)
FAMILIES = {
    "edges": ([("vertical_blur", {"sigma": 1.0})], [], ("chart",)),  # blur: the residual follows the edges
    "levels": ([("tone_curve", {"gamma": 1.6})], [], ("flat-bright", "flat-dark", "photo")),  # a tone curve
    "space": ([], ["vignetting"], ("flat-bright", "photo")),  # fall-off towards the corners
    "time": ([("row_noise", {"sigma_dn": 2.5})], [], ("flat-bright", "photo")),  # noise that changes per frame
}


def comparison_of(tmp_path, fire_i, add, remove, scenes):
    folder = synthesise(fire_i, tmp_path / "set", add=add, seed=7, frames=4, only_scenes=scenes)
    profile = fire_i.without(*remove) if remove else fire_i
    return compare(load_set(folder, profile), profile)


@pytest.mark.slow  # over 4 s each: a synthetic set and a comparison
@pytest.mark.parametrize("family", list(FAMILIES))
def test_the_residual_of_a_hidden_effect_is_named_by_its_family(tmp_path, fire_i, family):
    """Measured (seed 7, 4 frames): blur 37 % of the residual on the 10 % of pixels at edges; tone curve worst
    at 64-96 DN (27.2) against 5.5 at 224-256; vignetting 14.2 top-left against 1.3 in the middle; row noise: rows
    130 against the mean's 0.99."""
    cmp = comparison_of(tmp_path, fire_i, *FAMILIES[family])
    found, numbers = residual_family(cmp)
    print(found, numbers)
    assert found == family, numbers
    assert cmp.error > 1.5


@pytest.mark.slow  # over 4 s: a synthetic set and a comparison
def test_a_candidate_that_does_not_lower_the_error_is_never_named(tmp_path, fire_i):
    """On a set at 1.231, a candidate leaving 1.233 held out (below the 1.25 that would once name it) is not the
    missing effect: the verdict is unexplained, says that nothing lowers the error and names the residual's family.
    One that lowers it by more than NAMED_GAIN is named."""
    real = comparison_of(tmp_path, fire_i, *FAMILIES["levels"])
    at = replace(real, error=1.231)

    def diagnosis(held_out):
        best = Candidate("tone_curve", error_after=1.2, params={}, evidence="", held_out=held_out, base_error=1.231)
        return Diagnosis(at, [best])

    worse = diagnosis(1.233)
    assert worse.verdict == "unexplained"
    assert "no candidate lowers it" in worse.summary() and "one of levels" in worse.summary(), worse.summary()
    assert worse.as_json()["residual_family"] == "levels"
    assert diagnosis(1.231 * (1 - NAMED_GAIN) + 1e-4).verdict == "unexplained"  # within the gain: not earned
    better = diagnosis(1.15)
    assert better.verdict == "missing-effect" and "tone_curve brings it to 1.150" in better.summary()


@pytest.fixture(scope="module")
def plain_set(tmp_path_factory):
    import lowcam

    fire_i = lowcam.load_profile("fire-i")
    folder = synthesise(fire_i, tmp_path_factory.mktemp("texture") / "set", seed=3, frames=6,
                        only_scenes=("flat-bright", "photo"))
    return fire_i, load_set(folder, fire_i)


def _with_frames(mset, change):
    return replace(mset, captures=[replace(c, frames=change(c.frames)) for c in mset.captures])


def _recursive_filter(frames, carry=0.5):
    """A temporal noise filter: each output frame carries ``carry`` of the last output (written here)."""
    out = frames.astype(np.float32)
    for t in range(1, len(out)):
        out[t] = (1 - carry) * out[t] + carry * out[t - 1]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _blotchy(frames):
    """The frames' noise low-passed by OpenCV's Gaussian (sigma 1 px) and scaled by 1.6, which keeps about the
    same variance: a spatial denoiser's texture at the raw camera's noise level."""
    mean = frames.astype(np.float32).mean(0)
    return np.stack([np.clip(np.rint(mean + 1.6 * cv2.GaussianBlur(f.astype(np.float32) - mean, (0, 0), 1.0)),
                             0, 255).astype(np.uint8) for f in frames])


@pytest.mark.slow  # over 4 s: a synthetic set and three comparisons
def test_the_noise_texture_tells_denoised_frames_from_raw_ones_of_the_same_variance(plain_set):
    """Measured (seed 3, 6 frames): raw frames and the model agree (neighbours 0.66 / 0.50, 47 % of the power in
    the high band, 0.00 from frame to frame). Low-passed noise of about the same variance (error 1.16, near the
    floor): neighbours 0.88 / 0.81, 9 % high. A recursive filter carrying half the last frame: 0.42 from frame to
    frame."""
    fire_i, mset = plain_set
    raw = compare(mset, fire_i).noise_texture
    assert raw["captures"] == 2
    for key in ("lag1_x", "lag1_y", "lag1_t"):
        assert abs(raw["measured"][key] - raw["model"][key]) < 0.05, raw
    assert abs(raw["measured"]["bands"]["high"] - raw["model"]["bands"]["high"]) < 0.05, raw

    blotchy = compare(_with_frames(mset, _blotchy), fire_i)
    tex = blotchy.noise_texture
    assert blotchy.families["variance"] < 1.4, blotchy.families  # the noise's strength is about the same
    assert tex["measured"]["lag1_x"] > tex["model"]["lag1_x"] + 0.15, tex
    assert tex["measured"]["bands"]["high"] < 0.5 * tex["model"]["bands"]["high"], tex
    assert abs(tex["measured"]["lag1_t"]) < 0.05, tex

    carried = compare(_with_frames(mset, _recursive_filter), fire_i).noise_texture
    assert carried["measured"]["lag1_t"] > 0.3 and abs(carried["model"]["lag1_t"]) < 0.05, carried


def test_noise_texture_of_white_noise_and_of_a_recursive_filter():
    """Analytic: white Gaussian noise has no neighbour or frame-to-frame correlation and puts each band's share of
    the frequencies' area in it. A recursive filter carrying a of the last output, y_t = (1 - a) x_t + a y_{t-1},
    makes an AR(1) process: E var(y_{t+1} - y_t) = 2 s^2 (1 - a) and E var(y_t - mean) = s^2 (1 - S / n^2) with
    S = sum over t, u of a^|t - u|, so over n frames the reading is 1 - (1 - a) / ((1 - S / n^2) n / (n - 1))
    (0.43 for a = 0.6 and n = 8: the frames' mean takes part of a slow drift)."""
    rng = np.random.default_rng(0)
    white = (128 + 8 * rng.standard_normal((12, 192, 256, 3))).astype(np.float32)
    tex = noise_texture(white)
    assert abs(tex["lag1_x"]) < 0.02 and abs(tex["lag1_y"]) < 0.02 and abs(tex["lag1_t"]) < 0.05, tex
    fy, fx = np.meshgrid(np.fft.fftfreq(192), np.fft.rfftfreq(256), indexing="ij")
    f = np.hypot(fx, fy)
    area_high = ((f >= 0.2) & (f < 0.71)).mean()
    assert tex["bands"]["high"] == pytest.approx(area_high, abs=0.03)
    ar = white.copy()
    for t in range(1, len(ar)):
        ar[t] = 0.4 * ar[t] + 0.6 * ar[t - 1]
    n, a = 8, 0.6
    total = n + 2 * sum((n - k) * a ** k for k in range(1, n))
    expected = 1 - (1 - a) / ((1 - total / n ** 2) * n / (n - 1))
    assert noise_texture(ar[4:])["lag1_t"] == pytest.approx(expected, abs=0.06)
    assert expected > 0.4
    assert noise_texture(white[:2]) is None
