"""Object motion's spreading (beyond the paper, Fig. 15): pixels on one path filtered together against one by one,
against a disc's continuous streak, and the window it works in."""
import cv2
import numpy as np
import pytest

from lowcam.effects.object_motion import (edge_velocity_from_cover, painted, path_kernel, rotation_velocity,
                                          splat_along)

# float32 sums of the group filter against float64 sums pixel by pixel: a few float32 steps of the value
GROUPED_RELATIVE_ERROR = 4e-6


def _piecewise_field(rng, rows=160, cols=220, objects=6):
    """Premultiplied RGBA objects (rectangles and discs, some half transparent, some overlapping), each moving on
    its own path (px over the exposure, any direction, up to 60 px); one object's pixels each on a random path."""
    image = np.zeros((rows, cols, 4), np.float32)
    shift = np.zeros((rows, cols, 2), np.float32)
    yy, xx = np.mgrid[:rows, :cols]
    for k in range(objects):
        cy, cx, size = rng.integers(20, rows - 20), rng.integers(20, cols - 20), rng.integers(6, 30)
        inside = (np.hypot(yy - cy, xx - cx) < size) if k % 2 else (
            (abs(yy - cy) < size) & (abs(xx - cx) < size * 1.5))
        alpha = rng.choice([1.0, 0.5])
        image[inside] = np.append(rng.uniform(0, 1, 3), 1.0) * alpha
        length, angle = rng.uniform(0, 60), rng.uniform(0, 2 * np.pi)
        shift[inside] = (length * np.cos(angle), length * np.sin(angle))
        if k == objects - 1:                                       # no two pixels share a path
            shift[inside] = rng.uniform(-20, 20, (int(inside.sum()), 2))
    return image, shift


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pixels_on_one_path_spread_together_as_they_do_one_by_one(seed):
    rng = np.random.default_rng(seed)
    image, shift = _piecewise_field(rng)
    grouped = splat_along(image, shift)
    one_by_one = splat_along(image, shift, by_pixel=True)
    assert np.abs(grouped - one_by_one).max() > 0                  # the groups were filtered, not spread by pixel
    assert np.all(np.abs(grouped - one_by_one) <= GROUPED_RELATIVE_ERROR * np.abs(one_by_one))   # zeros stay zero


def test_a_random_path_per_pixel_is_spread_one_by_one():
    rng = np.random.default_rng(7)
    image = np.zeros((60, 80, 4), np.float32)
    image[20:40, 25:55] = rng.uniform(0, 1, (20, 30, 4))
    shift = rng.uniform(-15, 15, (60, 80, 2)).astype(np.float32)
    assert np.array_equal(splat_along(image, shift), splat_along(image, shift, by_pixel=True))


def test_a_moving_disc_is_its_continuous_streak():
    """A disc moving (39.6, -29.7) px over the exposure against the disc's pixels each spread over the same path
    in 4000 steps (the continuous motion) by bilinear deposits: the taps 1 px apart differ from it by less than a
    tap's share, the light is kept, and the streak ends about half a path from the disc's edge each way."""
    rows, cols, radius, path = 140, 180, 15, np.array([39.6, -29.7])
    yy, xx = np.mgrid[:rows, :cols]
    disc = np.hypot(yy - 70, xx - 90) <= radius
    image = np.zeros((rows, cols, 4), np.float32)
    image[disc] = (0.8, 0.4, 0.2, 1.0)
    shift = np.zeros((rows, cols, 2), np.float32)
    shift[disc] = path
    out = splat_along(image, shift)
    ys, xs = np.nonzero(disc)
    continuous = np.zeros((rows + 1, cols + 1))
    for t in (np.arange(4000) + 0.5) / 4000 - 0.5:
        x, y = xs + path[0] * t, ys + path[1] * t
        xi, yi = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = x - xi, y - yi
        for dy, dx, weight in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy),
                               (1, 1, fx * fy)):
            np.add.at(continuous, (yi + dy, xi + dx), weight / 4000)
    continuous = continuous[:rows, :cols]
    taps = int(np.ceil(np.hypot(*path))) + 1
    assert np.abs(out[..., 3] - continuous).max() < 1.0 / taps
    assert out[..., 3].sum() == pytest.approx(disc.sum(), rel=1e-5)
    assert np.allclose(out[..., :3], out[..., 3:] * (0.8, 0.4, 0.2), atol=1e-6)
    lit_x = np.nonzero(out[..., 3].any(axis=0))[0]
    last_tap = (0.5 - 0.5 / taps) * path[0]                        # 19.4 px: half a tap step short of half the path
    assert lit_x.min() == np.floor(90 - radius - last_tap) and lit_x.max() == np.floor(90 + radius + last_tap) + 1


def test_path_kernel_holds_every_tap_weight():
    for path in ((49.5, 0.0), (-12.25, 30.0), (0.3, -0.2)):
        taps = int(np.ceil(np.hypot(*path))) + 1
        kernel, dy0, dx0 = path_kernel(np.array(path), taps)
        assert kernel.sum() == pytest.approx(taps)
        ii, jj = np.nonzero(kernel)
        centre_y, centre_x = (kernel * (np.arange(kernel.shape[0])[:, None] + dy0)).sum() / taps, \
            (kernel * (np.arange(kernel.shape[1]) + dx0)).sum() / taps
        assert centre_x == pytest.approx(0, abs=1e-9) and centre_y == pytest.approx(0, abs=1e-9)   # about the pixel


def _pieces_by_growing_lists(kernel, most=49):
    """The kernel's pieces as first written: each weight, in the same order, added to the current piece unless
    the piece's box would then exceed ``most`` entries; the box recomputed from the whole list every time."""
    ii, jj = np.nonzero(kernel)
    order = np.lexsort((ii, jj) if kernel.shape[1] >= kernel.shape[0] else (jj, ii))
    pieces, members = [], []
    for k in order:
        trial = members + [k]
        if members and (np.ptp(ii[trial]) + 1) * (np.ptp(jj[trial]) + 1) > most:
            pieces.append(members)
            trial = [k]
        members = trial
    pieces.append(members)
    return [(int(ii[m].min()), int(jj[m].min()), (int(np.ptp(ii[m])) + 1, int(np.ptp(jj[m])) + 1)) for m in pieces]


def test_kernel_pieces_are_small_rectangles_that_hold_the_kernel_once():
    """A path's kernel cut for OpenCV's direct filters: every piece under 50 entries, every weight in exactly one
    piece, and the same cuts as recomputing each piece's box from its list (the cuts fix the summation order, so
    the frame's bytes)."""
    from lowcam.effects.object_motion import _kernel_pieces

    rng = np.random.default_rng(9)
    for _ in range(300):
        path = rng.uniform(-80, 80, 2) * rng.choice([1.0, 0.1, 0.01])
        kernel = path_kernel(path, int(np.ceil(np.hypot(*path))) + 1)[0]
        pieces = _kernel_pieces(kernel)
        assert [(top, left, block.shape) for top, left, block in pieces] == _pieces_by_growing_lists(kernel)
        rebuilt = np.zeros_like(kernel)
        for top, left, block in pieces:
            assert block.size <= 49
            assert not rebuilt[top:top + block.shape[0], left:left + block.shape[1]][block != 0].any()
            rebuilt[top:top + block.shape[0], left:left + block.shape[1]] += block
        assert np.array_equal(rebuilt, kernel.astype(np.float32))


def test_edge_velocities_are_the_first_most_covered_neighbours():
    """The dilated search finds the same neighbour as trying every offset in turn (the first strictly better)."""
    rng = np.random.default_rng(4)
    for trial in range(12):
        rows, cols = rng.integers(4, 60, 2)
        alpha = rng.choice([0.0, 1.0, 0.25, 0.5, 0.75], size=(rows, cols)).astype(np.float32)
        if trial % 2:
            alpha = cv2.GaussianBlur(alpha, (5, 5), 1.0)
        velocity = rng.normal(size=(rows, cols, 2)).astype(np.float32)
        expected = velocity.copy()
        for y, x in zip(*np.nonzero((alpha > 0) & (alpha < 1))):
            best = (alpha[y, x], y, x)
            for dy in range(-2, 3):
                for dx in range(-2, 3):
                    ny, nx = min(max(y + dy, 0), rows - 1), min(max(x + dx, 0), cols - 1)
                    if alpha[ny, nx] > best[0]:
                        best = (alpha[ny, nx], ny, nx)
            expected[y, x] = velocity[best[1], best[2]]
        assert np.array_equal(edge_velocity_from_cover(velocity, alpha), expected)


def test_rotation_velocity_in_a_window_is_the_whole_images_there():
    window = (slice(37, 120), slice(5, 211))
    whole = rotation_velocity((0.2, -0.5, 0.3), 300.0, (240, 320))
    assert np.array_equal(rotation_velocity((0.2, -0.5, 0.3), 300.0, (240, 320), window), whole[window])


def test_painted_pixels_have_a_non_zero_channel():
    image = np.zeros((3, 4, 4), np.float32)
    image[0, 0, 2], image[1, 1, 3], image[2, 2, 0] = 1e-30, -0.5, -0.0
    assert np.array_equal(painted(image), (np.abs(image) > 0).any(axis=-1))
    assert np.array_equal(painted(image[..., :3]), (np.abs(image[..., :3]) > 0).any(axis=-1))
