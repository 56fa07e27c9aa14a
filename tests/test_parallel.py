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
