"""The sample plate is footage: the photograph filmed through the same camera and motion as the graphics.

A plate is what the camera filmed. Lowcam's graphics get the camera's blur, panning motion blur and noise, so the
plate must carry them too: then the plain composite shows sharp graphics on the footage and Lowcam's shows them in
it. The photographs here are analytic (stripes, a flat grey) written in the test; the "graphics" are a card of the
same content laid over part of the frame, so plate and graphics can be compared where they show the same thing.
"""
import cv2
import numpy as np
import pytest

import lowcam
from lowcam.pipeline import plain_composite
from lowcam.sample import film, photograph_render, plate_seed, sample_photograph, sample_plate

PAN = (0.0, 0.6, 0.0)          # rad/s: the sample scene's camera pans about its vertical axis
COLUMNS = slice(200, 440)      # the middle of the 640-pixel frame, where the lens bends vertical lines least


def _photo(values: np.ndarray) -> np.ndarray:
    """A 480x640 uint8 RGB photograph whose columns have ``values``."""
    return np.repeat(np.repeat(values.astype(np.uint8)[None, :, None], 480, 0), 3, 2)


def _stripes() -> np.ndarray:
    """Vertical black-and-white bars, 20 px wide: sharp vertical edges that a horizontal pan smears."""
    return _photo(np.where((np.arange(640) // 20) % 2 == 0, 40, 215))


def _card(photo: np.ndarray, profile) -> np.ndarray:
    """The photograph's own content as graphics: the render of the photograph, transparent outside a band."""
    render = photograph_render(photo, profile)
    rows = render.shape[0]
    render[: int(rows * 0.47)] = 0.0
    render[int(rows * 0.53):] = 0.0
    return render


def _composites(photo, profile, seed=0):
    """(plate, Lowcam composite, plain composite, card rows, plate rows) of the card over the filmed photograph."""
    plate = film(photo, profile, PAN, None, plate_seed(seed), 0)
    card = _card(photo, profile)
    low = lowcam.simulate(card, profile, plate, PAN, None, seed, 0)
    plain = plain_composite(card, profile, plate)
    card_rows = np.nonzero((plain != plate).any(axis=(1, 2)) & (low != plate).any(axis=(1, 2)))[0]
    top, bottom = card_rows.min(), card_rows.max()
    assert 30 < top < bottom < 450
    inner = slice(top + 8, bottom - 7)                          # inside the card, away from its blurred edges
    outside = slice(max(0, top - 70), top - 30)                 # plate only, still near the middle
    assert inner.stop - inner.start >= 10
    return plate, low, plain, inner, outside


def _edge_width_px(img: np.ndarray, rows: slice) -> float:
    """Width of the bars' vertical edges (px): step height over the steepest slope of the rows' mean profile,
    the median over the edges in the middle columns (an ideal step is about 1 px wide)."""
    profile = img[rows, COLUMNS].astype(np.float64).mean(axis=(0, 2))
    slope = np.abs(np.diff(profile))
    step = np.percentile(profile, 95) - np.percentile(profile, 5)
    peaks = [i for i in range(2, len(slope) - 2)
             if slope[i] == slope[i - 2:i + 3].max() and slope[i] > 0.3 * slope.max()]
    assert len(peaks) >= 4
    return float(step / np.median(slope[peaks]))


def _noise_dn(img: np.ndarray, rows: slice) -> float:
    """Standard deviation (DN) of the pixels minus their local mean (a Gaussian of sigma 4 px): the noise in a flat
    region, with vignetting's slow fall-off removed."""
    a = img.astype(np.float32)
    return float((a - cv2.GaussianBlur(a, (0, 0), 4))[rows, COLUMNS].std())


def test_the_plate_is_as_sharp_as_lowcams_graphics_not_the_plain_ones(fire_i):
    plate, low, plain, card, outside = _composites(_stripes(), fire_i)
    footage = _edge_width_px(plate, outside)
    lowcam_card = _edge_width_px(low, card)
    plain_card = _edge_width_px(plain, card)
    assert footage == pytest.approx(lowcam_card, rel=0.15)      # the graphics sit in the footage
    assert plain_card < 0.6 * footage                           # plain graphics float on it, sharper
    assert footage > 3.0                                        # the pan (19.8 px/frame) and the blur reached it


def test_the_plate_has_the_cameras_noise_level_and_its_own_noise(fire_i):
    grey = _photo(np.full(640, 128))
    plate, low, plain, card, outside = _composites(grey, fire_i)
    footage, lowcam_card, plain_card = _noise_dn(plate, outside), _noise_dn(low, card), _noise_dn(plain, card)
    assert footage > 1.0                                        # a photograph of a flat grey has none
    assert footage == pytest.approx(lowcam_card, rel=0.25)
    assert plain_card < 0.1 * footage
    # the same camera with the graphics' seed would make the very same noise: the plate's seed is another
    same_seed = film(grey, fire_i, PAN, None, 0, 0).astype(np.float32)
    own = plate.astype(np.float32)
    hp = [(a - cv2.GaussianBlur(a, (0, 0), 4))[150:330, COLUMNS].ravel() for a in (own, same_seed)]
    assert abs(np.corrcoef(*hp)[0, 1]) < 0.1
    assert plate_seed(0) != 0 and plate_seed(2**64 - 1) != 2**64 - 1


def test_the_sample_plate_is_the_photograph_filmed_while_panning(fire_i):
    """The demo's plate: horizontal detail is lost to the pan more than vertical detail, and the camera's noise is
    added, compared with the bundled photograph itself (what the plate used to be)."""
    photo = sample_photograph(fire_i).astype(np.float32)
    plate = sample_plate(fire_i, PAN).astype(np.float32)
    region = (slice(100, 380), slice(100, 540))

    def detail(img, axis):
        return float(np.abs(np.diff(img, axis=axis))[region].mean())

    across, along = detail(plate, 1) / detail(photo, 1), detail(plate, 0) / detail(photo, 0)
    assert across < 0.75                                        # blurred across the pan
    assert across < along - 0.15                                # and more than along it
    assert not np.array_equal(sample_plate(fire_i, PAN, seed=1), plate.astype(np.uint8))  # noise follows the seed


@pytest.mark.parametrize("name", ["coffee", "astronaut"])
def test_bundled_photographs_are_scikit_images_byte_for_byte(name):
    """The photographs the sample plate and the synthetic sets are made of are scikit-image's own data, read
    without scikit-image (which the Blender extension does not carry): the same uint8 RGB array."""
    from skimage import data

    from lowcam.sample import photograph

    assert np.array_equal(photograph(name), getattr(data, name)())
