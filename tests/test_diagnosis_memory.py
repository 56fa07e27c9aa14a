"""What keeps diagnosis lean without changing a number: profile copies share their geometry and sensel gains, the
kept chain fronts share each capture's plates, the noise-free frames are kept as 8-bit, and the comparison's
frame statistics are summed one frame at a time."""
import copy
import subprocess
import sys

import numpy as np
import pytest

import lowcam
from lowcam.measure.compare import _mean_and_squares, simulate_capture
from lowcam.measure.diagnose import Context
from lowcam.measure.sets import load_set
from lowcam.measure.synth import synthesise


def test_profile_copies_share_one_read_only_geometry(fire_i):
    positions = fire_i.geometry.sensel_positions
    for other in (fire_i.copy(), fire_i.quiet(), fire_i.with_effect("tone_curve", gamma=2.0), copy.deepcopy(fire_i)):
        assert other.geometry is fire_i.geometry and other.geometry.sensel_positions is positions
    with pytest.raises(ValueError):
        positions[0, 0, 0, 0] = 1.0


@pytest.mark.parametrize("count", [1, 2, 5, 9])
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_frame_statistics_one_frame_at_a_time_are_the_same_bits(count, dtype):
    frames = (np.random.default_rng(count).random((count, 30, 40, 3)) * 255).astype(dtype)
    whole = frames.astype(np.float32)
    mean, squares = _mean_and_squares(frames)
    assert mean.dtype == squares.dtype == np.float32
    assert np.array_equal(mean, whole.mean(0)) and np.array_equal(squares, ((whole - whole.mean(0)) ** 2).sum(0))


def test_kept_fronts_share_their_captures_plates_and_clean_frames_are_kept_as_8_bit(tmp_path, fire_i):
    folder = synthesise(fire_i, tmp_path / "set", frames=2, only_scenes=["photo"])
    mset = load_set(folder, fire_i)
    capture, cache = mset.captures[0], {}
    for profile in (fire_i, fire_i.without("crosstalk")):     # two fronts: the crosstalk comes before the noise
        simulate_capture(profile, capture, 1, cache=cache)
    (a, _, a_u8), (b, _, b_u8) = cache.values()
    assert a is not b and a.plate is b.plate and a_u8 is b_u8

    ctx = Context(mset, fire_i, tmp_path / "work")
    clean = ctx.clean(fire_i)[0]
    kept = next(iter(ctx.memo.values()))
    assert kept.dtype == np.uint8 and clean.dtype == np.float32 and np.array_equal(kept, clean)


def test_one_malloc_arena_takes_on_glibc():
    """The diagnosis command has glibc serve its threads from one arena (a lower peak, the same numbers); elsewhere
    it does nothing and says so."""
    import platform

    code = "from lowcam.parallel import one_malloc_arena; print(one_malloc_arena())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    assert out == str(glibc)


def test_sensel_gains_are_kept_for_every_copy_of_a_profile_and_redone_when_a_value_changes(fire_i):
    """The vignetting's gain planes (a texture sampled at every sensel) are computed once for all the frames and
    profile copies that share its values; another fall-off gets its own, the same as computed afresh."""
    vignetting = fire_i.effect("vignetting")
    gains = vignetting.gain_planes(fire_i.geometry)
    assert not gains.flags.writeable
    assert fire_i.copy().effect("vignetting").gain_planes(fire_i.geometry) is gains
    other = fire_i.with_effect("vignetting", texture="", k2=-0.3, k4=0.05, replace=True).effect("vignetting")
    other_gains = other.gain_planes(fire_i.geometry)
    assert other_gains is not gains and not np.array_equal(other_gains, gains)
    assert np.array_equal(other_gains, other._gain_planes(fire_i.geometry))
    assert np.array_equal(gains, vignetting._gain_planes(fire_i.geometry))
