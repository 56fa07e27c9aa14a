"""Windows around non-zero pixels and the warps that compute only inside them: the same
result as the plain ``cv2.remap`` of the whole image, bit for bit, and no invalid pixel left unchecked."""
import cv2
import numpy as np
import pytest

import lowcam
from lowcam.errors import LowcamError
from lowcam.io import check_render, check_render_window
from lowcam.sample import sample_render
from lowcam.window import WindowedRemap, nonzero_window


def _reference_window(image):
    nonzero = image != 0
    if nonzero.ndim == 3:
        nonzero = nonzero.any(axis=2)
    rows, cols = np.flatnonzero(nonzero.any(axis=1)), np.flatnonzero(nonzero.any(axis=0))
    if rows.size == 0:
        return None
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


@pytest.mark.parametrize("shape", [(97, 131, 4), (64, 64, 2), (50, 333)])
@pytest.mark.parametrize("block", [1, 7, 32])
def test_nonzero_window_is_the_smallest_window_holding_every_nonzero_element(rng, shape, block):
    for trial in range(40):
        image = np.zeros(shape, np.float32)
        for _ in range(rng.integers(1, 6)):  # a few specks, anywhere, edges included
            index = tuple(int(rng.integers(0, n)) for n in shape)
            image[index] = rng.choice([1.0, -3.0, 1e-30, np.nan, np.inf])
        assert nonzero_window(image, block) == _reference_window(image), (trial, np.argwhere(image != 0))


def test_nonzero_window_of_zeros_full_frames_and_negative_zero():
    assert nonzero_window(np.zeros((40, 40, 4), np.float32)) is None
    assert nonzero_window(np.full((40, 40, 4), -0.0, np.float32)) is None  # -0.0 == 0
    assert nonzero_window(np.ones((40, 30, 4), np.float32)) == (slice(0, 40), slice(0, 30))


def _coordinates(rng, blocks, rows, cols, src_shape):
    """Smooth, stretched, partly out-of-range source coordinates with a few NaN entries (no source)."""
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float32)
    xs, ys = [], []
    for b in range(blocks):
        a, c = rng.uniform(0.5, 2.0, 2)
        xs.append(a * x + 3 * np.sin(y / 7) + rng.uniform(-10, 10) - 0.3 * b)
        ys.append(c * y + 2 * np.cos(x / 9) + rng.uniform(-10, 10) + 0.7 * b)
    x, y = np.stack(xs).astype(np.float32), np.stack(ys).astype(np.float32)
    x[0, :3, :5] = np.nan
    return x, y


@pytest.mark.parametrize("blocks, tile", [(1, 32), (3, 8), (5, 5)])
def test_windowed_remap_equals_a_remap_of_the_whole_image(rng, blocks, tile):
    src_shape = (120, 150, 2)
    x, y = _coordinates(rng, blocks, 70, 90, src_shape)
    warp = WindowedRemap(x, y, tile=tile)
    plain = [cv2.remap(np.zeros(src_shape, np.float32), x.reshape(-1, 90), y.reshape(-1, 90), cv2.INTER_LINEAR)]
    assert not plain[0].any()
    for trial in range(30):
        src = np.zeros(src_shape, np.float32)
        r0, c0 = rng.integers(0, 110), rng.integers(0, 140)
        r1, c1 = r0 + rng.integers(1, 40), c0 + rng.integers(1, 40)
        src[r0:r1, c0:c1] = rng.uniform(-1, 2, (min(r1, 120) - r0, min(c1, 150) - c0, 2))
        window = nonzero_window(src)
        expected = cv2.remap(src, x.reshape(-1, 90), y.reshape(-1, 90), cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        got = warp(src, window)
        assert got.shape == expected.shape
        assert np.array_equal(got, expected), (trial, window, np.abs(got - expected).max())
    assert not warp(np.zeros(src_shape, np.float32), None).any()


def test_lens_and_bayer_sampling_of_sparse_graphics_equal_plain_remaps_of_the_whole_image(fire_i):
    """The windowed warps of the chain against plain cv2.remap calls over everything, with float maps."""
    render = sample_render(fire_i, 1600)
    assert nonzero_window(render) != (slice(0, render.shape[0]), slice(0, render.shape[1]))  # sparse graphics
    state = lowcam.run(render, fire_i, None, (0.05, 0.8, 0.1), stop_after="lens_distortion").state
    x, y = fire_i.effect("lens_distortion").render_coordinates(state, render.shape[:2])  # the supersampled grid
    supersampled = cv2.remap(render, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    assert np.array_equal(state.working, cv2.resize(supersampled, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))

    state = lowcam.run(render, fire_i, None, (0.05, 0.8, 0.1), stop_after="bayer_sampling").state
    before = lowcam.run(render, fire_i, None, (0.05, 0.8, 0.1), stop_after="spatial_blur").state.working
    x, y = fire_i.effect("bayer_sampling").sample_positions(state)  # (4, taps, rows, cols)
    for plane in range(4):
        colour = (0, 1, 1, 2)[plane]
        pair = np.ascontiguousarray(before[..., [colour, 3]])
        taps = [cv2.remap(pair, x[plane, t], y[plane, t], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
                for t in range(x.shape[1])]
        mean = np.mean(np.stack(taps), axis=0)
        assert np.array_equal(state.bayer_alpha[plane], mean[..., 1])
        assert np.array_equal(state.bayer[plane], mean[..., 0] * np.float32(255.0))


@pytest.mark.parametrize("value, message", [(np.nan, "NaN or Inf"), (np.inf, "NaN or Inf"),
                                            (1e30, "beyond a render's range"), (-1e30, "beyond a render's range")])
def test_a_bad_value_far_from_the_graphics_is_still_refused(value, message):
    """Only the window around non-zero pixels is checked in full: a bad value anywhere must widen it."""
    rgba = np.zeros((300, 400, 4), np.float32)
    rgba[100:120, 150:170] = 0.5
    assert check_render_window(rgba)[1] == (slice(100, 120), slice(150, 170))
    rgba[297, 3, 2] = value
    with pytest.raises(LowcamError, match=f"^render: .*{message}"):
        check_render(rgba)


def test_alpha_out_of_range_far_from_the_colour_is_refused():
    rgba = np.zeros((300, 400, 4), np.float32)
    rgba[100:120, 150:170] = 0.5
    rgba[2, 390, 3] = 1.5  # a stray alpha with no colour
    with pytest.raises(LowcamError, match=r"^render: alpha must lie in \[0, 1\]"):
        check_render(rgba)


@pytest.mark.parametrize("corner", [False, True])
def test_varying_blur_in_a_window_equals_the_blur_of_the_whole_image(rng, corner):
    from lowcam.effects.blur import varying_gaussian

    image = np.zeros((180, 240, 4), np.float32)
    rows, cols = (slice(0, 30), slice(200, 240)) if corner else (slice(70, 95), slice(100, 160))
    image[rows, cols] = rng.uniform(0, 1, image[rows, cols].shape)
    sigma = np.linspace(0.2, 3.5, 24 * 18, dtype=np.float32).reshape(18, 24)  # several blur levels
    window = nonzero_window(image)
    assert np.array_equal(varying_gaussian(image, sigma, window), varying_gaussian(image, sigma))
    whole = varying_gaussian(image, sigma)
    assert varying_gaussian(image, sigma, window, in_place=True) is image and np.array_equal(image, whole)
    assert np.array_equal(varying_gaussian(image, sigma, (slice(0, 180), slice(0, 240))),
                          varying_gaussian(image, sigma))


def test_a_render_changed_in_place_by_an_effect_gets_its_window_found_again(fire_i):
    """The window found while validating serves only until an effect that writes the render runs: one may change
    it in place. Effects that write other images leave it standing."""
    from lowcam.pipeline import _start

    render = np.zeros((450, 600, 4), np.float32)
    render[200:220, 300:330] = 0.5
    state, _ = _start(render, fire_i, None, (0, 0, 0), None, 0, 0, None)
    assert state.window("render") == (slice(200, 220), slice(300, 330))
    state.render[10, 20, 0] = 1.0  # an effect brightening one pixel, in place
    state.applied.append(fire_i.effect("lens_distortion"))  # writes the working image
    assert state.window("render") == (slice(200, 220), slice(300, 330))
    state.applied.append(fire_i.with_effect("object_motion").effect("object_motion"))  # writes the render
    assert state.window("render") == (slice(10, 220), slice(20, 330))


@pytest.mark.parametrize("shape, strip", [((70, 90), 4), ((64, 96), 256)])
def test_halved_warp_equals_the_area_halving_of_the_whole_warp(rng, shape, strip):
    src_shape = (120, 150, 4)
    x, y = _coordinates(rng, 1, *shape, src_shape)
    warp = WindowedRemap(x, y, tile=8)
    for trial in range(20):
        src = np.zeros(src_shape, np.float32)
        r0, c0 = rng.integers(0, 110), rng.integers(0, 140)
        r1, c1 = r0 + rng.integers(1, 40), c0 + rng.integers(1, 40)
        src[r0:r1, c0:c1] = rng.uniform(-1, 2, (min(r1, 120) - r0, min(c1, 150) - c0, 4))
        whole = cv2.remap(src, x[0], y[0], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        expected = cv2.resize(whole, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        got = warp.halved(src, nonzero_window(src), strip)
        assert np.array_equal(got, expected), (trial, np.abs(got - expected).max())
    assert not warp.halved(np.zeros(src_shape, np.float32), None).any()


@pytest.mark.parametrize("region", [(slice(0, 120), slice(0, 150)), (slice(30, 45), slice(40, 60))])
def test_tap_mean_equals_the_mean_of_every_tap(rng, region):
    """Both ways: one call for a source covering the frame, tap by tap for a small one."""
    src_shape = (120, 150, 2)
    x, y = _coordinates(rng, 12, 40, 50, src_shape)  # 3 groups of 4 taps
    warp = WindowedRemap(x, y, tile=8)
    src = np.zeros(src_shape, np.float32)
    src[region] = rng.uniform(0, 1, src[region].shape)
    expected = warp(src, (slice(0, 120), slice(0, 150))).reshape(3, 4, 40, 50, 2)
    assert np.array_equal(warp.mean(src, nonzero_window(src), 4), expected.mean(axis=1))


@pytest.mark.parametrize("effect", [None, "veiling_glare", "defocus"])
def test_windows_kept_between_effects_give_the_frames_of_windows_found_every_time(fire_i, monkeypatch, effect):
    """The lens, half-sampling, crosstalk and blur hand their output's window on; an effect that writes the working
    image in place (veiling glare spreads light everywhere) must end that, or its light is lost."""
    from lowcam.pipeline import SimState

    profile = fire_i if effect is None else fire_i.with_effect(
        effect, **({"strength": 0.2} if effect == "veiling_glare" else {"radius_px": 2.0}))
    render = sample_render(fire_i, 1200)
    kept = lowcam.run(render, profile, None, (0.05, 0.8, 0.1), seed=4)
    monkeypatch.setattr(SimState, "window", lambda state, name: nonzero_window(getattr(state, name)))
    found = lowcam.run(render, profile, None, (0.05, 0.8, 0.1), seed=4)
    assert np.array_equal(kept.frame, found.frame)
    if effect == "veiling_glare":  # the haze lights about twice the sensels the graphics cover (0.22 of them)
        assert (kept.state.bayer > 0).mean() > 1.5 * (kept.state.bayer_alpha > 0).mean()
