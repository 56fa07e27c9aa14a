"""The engine's own threads: results never depend on how many there are, and a forked child gets its own."""
import hashlib
import multiprocessing
import threading

import cv2
import numpy as np
import pytest

import lowcam
from lowcam.parallel import row_strips, thread_map, threads
from lowcam.sample import sample_plate, sample_render
from lowcam.window import nonzero_window


@pytest.fixture
def opencv_threads():
    """Set OpenCV's (and so the engine's) thread count within a test; restored after."""
    before = cv2.getNumThreads()
    yield cv2.setNumThreads
    cv2.setNumThreads(before)


def frame_digest(profile, render, plate, frame):
    result = lowcam.run(render, profile, plate, (0.05, 0.8, 0.1), seed=5, frame=frame)
    return hashlib.sha256(result.frame.tobytes()).hexdigest()


@pytest.mark.parametrize("name", ["fire-i", "phone-video"])
def test_a_frame_is_the_same_bytes_on_one_thread_and_on_four(opencv_threads, name):
    profile = lowcam.load_profile(name)
    render, plate = sample_render(profile, 1200), sample_plate(profile)
    opencv_threads(1)
    assert threads() == 1
    alone = [frame_digest(profile, render, plate, f) for f in range(2)]
    opencv_threads(4)
    assert threads() == 4
    assert [frame_digest(profile, render, plate, f) for f in range(2)] == alone
    assert alone[0] != alone[1]  # the noise differs per frame: the digests see the frame


def brute_window(image):
    rows, cols = np.nonzero((image != 0).reshape(image.shape[0], image.shape[1], -1).any(axis=-1))
    return (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1)) if rows.size else None


def test_nonzero_window_in_strips_is_the_exact_window(opencv_threads):
    """Graphics in one strip, across the strips' border, a single NaN near the bottom, nothing at all."""
    rng = np.random.default_rng(1)
    opencv_threads(4)
    assert len(row_strips(600, min_rows=128)) == 4
    for trial in range(40):
        image = np.zeros((600, 500, 4), np.float32)
        for _ in range(trial % 4):
            y, x = rng.integers(0, 600), rng.integers(0, 500)
            image[y:y + rng.integers(1, 200), x:x + rng.integers(1, 200), rng.integers(0, 4)] = rng.normal()
        if trial % 7 == 0:
            image[rng.integers(450, 600), rng.integers(0, 500), 2] = np.nan
        assert nonzero_window(image) == brute_window(image), trial


def test_thread_map_keeps_order_and_raises_the_callers_error(opencv_threads):
    opencv_threads(2)
    assert thread_map(lambda x: x * 10, range(7)) == [0, 10, 20, 30, 40, 50, 60]

    def refuse(x):
        if x == 3:
            raise ValueError("three")
        return x
    with pytest.raises(ValueError, match="three"):
        thread_map(refuse, range(5))


def _child_sum(queue):
    queue.put(sum(thread_map(lambda x: x + 1, range(100))))


def test_a_forked_child_runs_its_own_threads(opencv_threads):
    """A batch worker forked after the engine has run (its pool's threads exist only in the parent) still runs."""
    opencv_threads(2)
    # both of the parent's pool threads are started (an inherited full pool never starts one in the child)
    both = threading.Barrier(2, timeout=10)
    assert sorted(thread_map(lambda _: both.wait(), [0, 1])) == [0, 1]
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_child_sum, args=(queue,))
    child.start()
    child.join(30)
    if child.exitcode is None:
        child.kill()
    assert child.exitcode == 0 and queue.get(timeout=5) == sum(range(1, 101))


#: SHA-256 of frame 1 of the full-frame case below, as the chain gave it on one thread, with the Fire-i's working
#: grid laid out where its 2x2 blocks deliver each sensel (``bayer.sensel_shift_px``; before that:
#: a40a7b09b9ff5d0b90101b3e748a2786306f52fd6d065c87d2376dc711ba546d).
FULL_FRAME_SHA256 = "b13db1578a8f1b742d9b816039830e5b017fed9fa48c99acfadab9f9b30c2887"


def test_a_full_frame_keeps_its_bytes_on_one_thread_and_on_four(opencv_threads):
    """Every render pixel opaque (a virtual set): the warps, the blurs and the render check run in strips on
    every thread, each pixel computed as in one call, so the frame is the bytes it always was."""
    profile = lowcam.load_profile("fire-i")
    render = sample_render(profile, 1200)
    render = render + np.float32([0.3, 0.4, 0.5, 1.0]) * (1 - render[..., 3:])
    plate = sample_plate(profile)
    for n in (1, 4):
        opencv_threads(n)
        assert frame_digest(profile, render, plate, 1) == FULL_FRAME_SHA256, n


@pytest.mark.parametrize("shape", [(600, 500, 4), (257, 130, 2), (90, 70)])
def test_filters_in_strips_are_the_filters_of_the_whole_image(opencv_threads, shape):
    """A wide Gaussian (reflected border), a 3-tap filter with a zero border, and a blend with weight maps."""
    from lowcam.window import filter_in_strips

    rng = np.random.default_rng(3)
    image = rng.uniform(-1, 2, shape).astype(np.float32)
    weights = rng.uniform(0, 1, shape[:2]).astype(np.float32)
    k = np.float32([0.05, 0.9, 0.05])
    filters = [(lambda a: cv2.GaussianBlur(a, (0, 0), 4.0), 18),
               (lambda a: cv2.sepFilter2D(a, -1, k, k, borderType=cv2.BORDER_CONSTANT), 2),
               (lambda a, w: cv2.blendLinear(a, cv2.GaussianBlur(a, (0, 0), 1.0), w, 1 - w), 6)]
    opencv_threads(4)
    for fn, halo in filters:
        also = (weights,) if fn.__code__.co_argcount == 2 else ()
        assert np.array_equal(filter_in_strips(fn, image, halo, *also), fn(image, *also))
    # too short a halo shows: the test sees the strips' seams
    assert not np.array_equal(filter_in_strips(filters[0][0], image, 2), filters[0][0](image)) or shape[0] < 256


def test_exr_renders_decode_on_the_engines_threads_with_the_same_pixels(opencv_threads, tmp_path):
    """OpenEXR decodes in the calling thread unless told otherwise; a render is read on the engine's threads (in the
    calling thread in a Dask worker, which sets OpenCV to one), and its pixels do not depend on how many."""
    import OpenEXR

    from lowcam.io import read_render

    render = sample_render("fire-i", 1000)
    path = tmp_path / "render.exr"
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"RGBA": render}).write(str(path))
    read = {}
    for n in (1, 3):
        opencv_threads(n)
        read[n] = read_render(path)
        assert OpenEXR.global_thread_count() == (0 if n == 1 else n)
    assert np.array_equal(read[1], read[3]) and np.array_equal(read[1], render)
