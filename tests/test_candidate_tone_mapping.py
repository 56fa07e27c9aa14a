"""An image processor's local tone mapping (CLAHE), hidden by code no one here wrote, behind the Fire-i.

The hidden stage is scikit-image's contrast-limited adaptive histogram equalisation (``skimage.exposure``'s
``_clahe``, the core of ``equalize_adapthist``: its own histogram clipping, redistribution, padding and
interpolation) on the luma of OpenCV's YCrCb conversion, the chroma passed through, mixed with the original luma at
seeded random clip limits, region sizes and strengths. The public wrapper also stretches each frame's own minimum
and maximum to the full range before and after, which no camera does frame by frame (a flat field's noise would be
stretched to 0-255); the core is called on the fixed 8-bit range instead.

Diagnosis must name ``local_tone_mapping`` first with a verdict that is not confidently wrong; a set without tone
mapping gets it not named first. The stage's own physics is checked against analytic constructions.
"""
import numpy as np
import pytest

import lowcam
from helpers import check_named_first, diagnose_set, drawn, quiet_fire_i
from lowcam.effects.delivered_frame import to_ycc
from lowcam.effects.local_tone_mapping import tone_map_frame
from lowcam.errors import ProfileError

skimage_clahe = pytest.importorskip("skimage.exposure._adapthist")


def to_uint8(x):
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


# --- the physics --------------------------------------------------------------------------------------------------

def low_contrast_steps(shape=(240, 320), seed=0):
    """Grey blocks of 100 and 112 DN in a checkerboard of 40 px cells, with 1 DN of noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    grey = np.where(((yy // 40) + (xx // 40)) % 2 == 0, 100.0, 112.0)
    return to_uint8(grey[..., None] + rng.standard_normal(shape + (3,)))


def test_tone_mapping_raises_local_contrast_and_keeps_the_chroma():
    frame = low_contrast_steps()
    out = tone_map_frame(frame, clip_limit=3.0, tiles=4, strength=1.0)
    y_in, y_out = to_ycc(frame), to_ycc(out)
    dark, bright = (slice(5, 35), slice(5, 35)), (slice(5, 35), slice(45, 75))
    step_in = y_in[bright][..., 0].mean() - y_in[dark][..., 0].mean()
    step_out = y_out[bright][..., 0].mean() - y_out[dark][..., 0].mean()
    # each region: two levels ~5 bins wide, far over a clip of 3x the mean bin count; the clipped excess spread
    # over 256 bins leaves a slope of ~0.9 elsewhere and ~3.9 within each level: the step about doubles
    assert abs(step_in - 12.0) < 0.5 and 1.6 * step_in < step_out < 3.0 * step_in, (step_in, step_out)
    steeper = to_ycc(tone_map_frame(frame, clip_limit=6.0, tiles=4, strength=1.0))
    assert steeper[bright][..., 0].mean() - steeper[dark][..., 0].mean() > step_out + 5.0  # a higher clip: steeper
    assert np.abs(y_out[..., 1:] - y_in[..., 1:]).max() < 1.0  # the change is the same in R, G and B: chroma kept


def test_strength_zero_is_the_identity_and_the_strength_mixes_linearly():
    frame = low_contrast_steps(seed=1)
    assert np.array_equal(tone_map_frame(frame, 4.0, 8, 0.0), frame)
    full = tone_map_frame(frame, 4.0, 8, 1.0).astype(float) - frame
    half = tone_map_frame(frame, 4.0, 8, 0.5).astype(float) - frame
    assert np.abs(half - 0.5 * full).max() <= 1.0  # the luma's change halved, each rounded once
    assert np.abs(full).mean() > 3.0


def test_a_clip_limit_of_one_leaves_a_flat_histogram_region_nearly_untouched():
    """A clip at the mean bin count flattens every region's histogram: its tone curve is the identity."""
    rng = np.random.default_rng(2)
    frame = np.repeat(rng.integers(0, 256, (240, 320, 1), dtype=np.uint8), 3, axis=2)
    out = tone_map_frame(frame, clip_limit=1.0, tiles=4, strength=1.0)
    assert np.abs(out.astype(float) - frame).mean() < 1.5


@pytest.mark.parametrize("key,value", [("clip_limit", 0.5), ("tiles", 0), ("tiles", 2.5), ("strength", 1.5)])
def test_out_of_range_parameters_are_refused_naming_the_key(key, value):
    with pytest.raises(ProfileError, match=key) as e:
        lowcam.load_profile("fire-i").with_effect("local_tone_mapping", **{key: value})
    assert "\n" not in str(e.value)


# --- hidden by other code, named by diagnosis ---------------------------------------------------------------------

def scikit_image_clahe(clip_limit, regions, strength):
    """Each delivered frame through OpenCV's YCrCb: its 8-bit luma equalised by scikit-image's CLAHE core with
    ``clip_limit`` (scikit-image's, a share of a region's pixels) over regions of 1/``regions`` of the frame's
    height and width, mixed with the luma by ``strength``; chroma kept, back to RGB."""
    import cv2

    gray = skimage_clahe.NR_OF_GRAY - 1

    def post(frame):
        ycc = cv2.cvtColor(frame, cv2.COLOR_RGB2YCrCb)
        y = ycc[..., 0].astype(np.float64)
        kernel = [max(s // regions, 1) for s in y.shape]
        eq = skimage_clahe._clahe(np.round(y * gray / 255).astype(np.uint16), kernel, clip_limit, 256)
        eq = eq.astype(np.float64) * 255 / gray  # its 14-bit levels back to 8-bit DN
        ycc[..., 0] = to_uint8(y + strength * (eq - y))
        return cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB)
    return post


def test_below_two_over_nbins_scikit_images_core_gains_instead_of_equalising():
    """Why a draw's clip limit under 2/256 is not CLAHE: scikit-image's ``clip_histogram`` tests the bins against
    the clip after adding the redistributed excess to them, so where that excess is over half the clip per bin (a
    flat region) every bin is raised to the clip. The histogram then holds 256 x clip times the region's pixels
    and the tone curve (its cumulative sum over the region's pixel count) gains that factor, saturating; above
    it the pixel count is kept within a few per cent, as OpenCV's CLAHE keeps it exactly."""
    n = 48 * 64  # a region of a 480x640 frame cut into 10x10
    flat = np.zeros(256, np.int64)
    flat[150:160] = n // 10
    flat[150] += n - flat.sum()
    weak = int(0.0062 * n)
    assert skimage_clahe.clip_histogram(flat.copy(), weak).sum() == 256 * weak > 1.5 * n
    for clip in (0.01, 0.0146, 0.02):
        assert abs(skimage_clahe.clip_histogram(flat.copy(), int(clip * n)).sum() - n) < 0.05 * n, clip
    rng = np.random.default_rng(3)
    grey = np.repeat(np.clip(np.round(158 + 3 * rng.standard_normal((480, 640, 1))), 0, 255), 3, axis=2)
    grey = grey.astype(np.uint8)
    assert scikit_image_clahe(0.0062, 10, 1.0)(grey).mean() > 225  # gained 1.5x
    assert abs(scikit_image_clahe(0.0146, 10, 1.0)(grey).mean() - 158) < 8  # equalised: the grey kept
    assert abs(tone_map_frame(grey, 1.58, 10, 1.0).mean() - 158) < 2  # OpenCV's at the same clip: kept


TM_DECOYS = ["tone_curve", "veiling_glare"]  # a global curve, a veil lifting the shadows
SCENES = ("flat-dark", "photo", "chart")


def test_scikit_image_clahe_on_the_luma_is_named_local_tone_mapping(tmp_path):
    """The fast case: scikit-image's CLAHE at its default clip limit and region size (1/8 of the frame), mixed at
    0.7, on three scenes of three frames."""
    d = diagnose_set(tmp_path, quiet_fire_i(), ["local_tone_mapping", *TM_DECOYS], rounds=1, scenes=SCENES,
                     frames=3, post=scikit_image_clahe(0.01, 8, 0.7), seed=51)
    check_named_first(d, "local_tone_mapping")


#: Draws whose case is known to stop short: seed -> why (strict: a pass fails it).
SHORT = {
    53: "clip 0.0062 over 10x10 regions, mixed at 0.57: below 2/256 scikit-image's clip_histogram fills every bin of "
        "a flat region to the clip, so its tone curves gain 256 x 0.0062 = 1.58 (a grey of 158 DN comes out at 235; "
        "test_below_two_over_nbins_scikit_images_core_gains_instead_of_equalising): no CLAHE, and no camera's local "
        "tone mapping: error 7.60, veiling_glare first at 5.12 held out, local_tone_mapping 5.76 (unexplained)",
}


@pytest.mark.slow  # diagnoses take minutes
@pytest.mark.parametrize("seed", [pytest.param(s, marks=pytest.mark.xfail(strict=True, reason=SHORT[s])) if s in SHORT
                                  else s for s in (52, 53, 55, 56, 57)])
def test_scikit_image_clahe_at_random_parameters_is_named_local_tone_mapping(tmp_path, seed):
    p = drawn(seed, clip_limit=(0.006, 0.02), regions=[6, 8, 10], strength=(0.4, 0.9))
    d = diagnose_set(tmp_path, quiet_fire_i(), ["local_tone_mapping", *TM_DECOYS, "noise_reduction"], rounds=1,
                     scenes=("flat-dark", "flat-bright", "photo", "chart"), post=scikit_image_clahe(**p), seed=seed)
    print(p)
    check_named_first(d, "local_tone_mapping")


def test_a_set_without_tone_mapping_does_not_get_it_first(tmp_path):
    """A global tone curve (a power law on the delivered frames, written here) is no local tone mapping: the
    tone curve comes first, and a verdict that names an effect does not name the tone mapping."""
    def power_law(frame):
        return to_uint8(255.0 * (frame / 255.0) ** 0.75)

    d = diagnose_set(tmp_path, quiet_fire_i(), ["local_tone_mapping", "tone_curve"], rounds=1, scenes=SCENES,
                     frames=3, post=power_law, seed=54)
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    print(f"error {d.error:.2f}: {ranking}; {d.verdict}")
    assert d.candidates[0].effect != "local_tone_mapping", ranking
    assert d.verdict != "missing-effect" or d.best.effect != "local_tone_mapping", d.summary()
