"""The engine's fast paths keep the exact behaviour of the plain code they replace."""
import numpy as np
import pytest

import lowcam
from lowcam.errors import LowcamError
from lowcam.io import RENDER_MAX, check_render
from lowcam.sample import sample_render


def _render(value=0.5, alpha=1.0):
    rgba = np.full((32, 32, 4), value, np.float32)
    rgba[..., 3] = alpha
    return rgba


@pytest.mark.parametrize("alpha, ok", [
    (np.float32(1 + 1e-4), False),  # float32(1.0001) is 1.00010001659 > 1 + 1e-4: refused
    (np.nextafter(np.float32(1 + 1e-4), np.float32(0)), True),  # the float32 just below is inside
    (np.float32(-1e-4), True),  # -9.99999975e-05 >= -1e-4
    (np.nextafter(np.float32(-1e-4), np.float32(-1)), False),
])
def test_alpha_limits_are_exact_at_float32_resolution(alpha, ok):
    rgba = _render(alpha=alpha)
    if ok:
        assert check_render(rgba)[0, 0, 3] == alpha
    else:
        with pytest.raises(LowcamError, match=r"^render: alpha must lie in \[0, 1\]"):
            check_render(rgba)


@pytest.mark.parametrize("value, ok", [(np.nextafter(np.float32(RENDER_MAX), np.float32(0)), True),
                                       (np.float32(RENDER_MAX), False),  # cv2.checkRange's range is half-open
                                       (np.float32(-RENDER_MAX), True), (np.float32(np.nan), False)])
def test_colour_limits_are_exact(value, ok):
    rgba = _render()
    rgba[5, 7, 1] = value
    if ok:
        assert check_render(rgba)[5, 7, 1] == value
    else:
        with pytest.raises(LowcamError, match=r"render: .*(beyond a render's range|NaN or Inf \(first at x=7, y=5\))"):
            check_render(rgba)


def test_bayer_maps_kept_for_one_motion_are_not_reused_for_another(fire_i):
    """The Bayer-sampling maps are kept between frames while the motion is the same: a frame after another
    motion must equal the same frame from a profile that never saw the first."""
    render = sample_render(fire_i, 640)
    fast = lowcam.load_profile("fire-i")
    first = lowcam.simulate(render, fast, None, (0.0, 0.9, 0.0), seed=1)
    second = lowcam.simulate(render, fast, None, (0.3, 0.0, 0.2), seed=1)
    fresh = lowcam.simulate(render, lowcam.load_profile("fire-i"), None, (0.3, 0.0, 0.2), seed=1)
    assert not np.array_equal(first, second)
    assert np.array_equal(second, fresh)
    again = lowcam.simulate(render, fast, None, (0.3, 0.0, 0.2), seed=1)  # from the kept maps
    assert np.array_equal(again, fresh)
