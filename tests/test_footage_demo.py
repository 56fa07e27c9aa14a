"""``lowcam demo --footage``: the phone gyro log against the frames it was logged with.

The reality here is the footage: OpenCV's Lucas-Kanade tracks between consecutive frames measure the image motion,
and the camera-frame gyro must predict it through K (a rotation homography written here, Hartley & Zisserman sec.
8.4.2). The data set lives outside the repository (``shared/data/phone-gyro-video`` beside it); the tests skip
without it.
"""
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from lowcam.errors import LowcamError
from lowcam.gyro_footage import (PHONE_K, camera_rotations, footage_profile, frame_motion, read_footage_clip,
                            write_gif)
from lowcam.motion import PHONE_GYRO_TO_CAMERA, read_exposure_log, read_framestamps, read_phone_gyro_log
from lowcam.profile import load_profile

ROOT = Path(__file__).resolve().parent.parent
DATA = next((p / "phone-gyro-video" for p in (Path(os.environ.get("LOWCAM_SHARED_DATA", "/nonexistent")),
                                               ROOT.parent / "shared/data", ROOT.parent.parent / "shared/data")
             if (p / "phone-gyro-video").is_dir()), None)
needs_data = pytest.mark.skipif(DATA is None, reason="the phone-gyro-video data set is not beside the repository")
#: Axis mappings a wrong reading could take: the data set's source code's unsigned swap, the fitted one with the
#: roll flipped, and the phone's axes taken as the camera's.
SOURCE_SWAP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
ROLL_FLIPPED = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _measured_motion(clip):
    """Per consecutive pair: the principal point's shift (px) and the image rotation (rad) of a similarity fitted
    by RANSAC to forward-backward-checked Lucas-Kanade tracks."""
    grey = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in clip.frames]
    c = PHONE_K[:2, 2]
    out = []
    for a, b in zip(grey, grey[1:]):
        p0 = cv2.goodFeaturesToTrack(a, 400, 0.01, 10)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, winSize=(21, 21), maxLevel=3)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, winSize=(21, 21), maxLevel=3)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - p0, axis=-1).ravel() < 0.5)
        m, _ = cv2.estimateAffinePartial2D(p0[ok], p1[ok], method=cv2.RANSAC)
        shift = m[:, :2] @ c + m[:, 2] - c
        out.append([shift[0], shift[1], np.arctan2(m[1, 0], m[0, 0])])
    return np.array(out)


def _predicted_motion(clip):
    """The same from the gyro: a static direction d seen in frame i is seen at R_rel^T d in frame i + 1
    (R_rel = R_i^T R_i+1), so pixels move by the homography K R_rel^T K^-1."""
    rots = camera_rotations(clip)
    c = np.array([*PHONE_K[:2, 2], 1.0])
    out = []
    for ra, rb in zip(rots, rots[1:]):
        h = PHONE_K @ (ra.T @ rb).T @ np.linalg.inv(PHONE_K)
        q = h @ c
        e = h @ (c + [100.0, 0.0, 0.0])
        q, e = q[:2] / q[2], e[:2] / e[2]
        out.append([q[0] - c[0], q[1] - c[1], np.arctan2(e[1] - q[1], e[0] - q[0])])
    return np.array(out)


@pytest.fixture(scope="module")
def measured():
    clip = read_footage_clip(DATA, 99, 60)
    return _measured_motion(clip)


def _agreement(axes, measured):
    pred = _predicted_motion(read_footage_clip(DATA, 99, 60, axes=axes))
    corr = [np.corrcoef(pred[:, k], measured[:, k])[0, 1] for k in range(3)]
    rms = np.sqrt(((pred[:, :2] - measured[:, :2]) ** 2).mean())
    return corr, rms


@needs_data
def test_the_gyro_mapped_to_the_camera_predicts_the_image_motion(measured):
    corr, rms = _agreement(PHONE_GYRO_TO_CAMERA, measured)
    # 59 pairs of frames 99-158: the camera turns up to 0.6 rad/s (shifts up to 6 px a frame)
    assert np.std(measured[:, 1]) > 1.5
    assert corr[0] > 0.85 and corr[1] > 0.98 and corr[2] > 0.6, corr
    assert rms < 0.8, rms   # px per frame pair at the principal point (the car also drives: parallax)


@needs_data
@pytest.mark.parametrize("axes", [SOURCE_SWAP, ROLL_FLIPPED, np.eye(3)], ids=["source-swap", "roll-flipped", "phone"])
def test_a_wrong_axis_mapping_disagrees_with_the_frames(axes, measured):
    corr, rms = _agreement(axes, measured)
    assert min(corr) < 0.3, corr


@needs_data
def test_the_phone_logs_are_read_and_aligned():
    folder = DATA / "20200109_145447"
    stamps = read_framestamps(folder / "framestamp.txt")
    assert len(stamps) == 2146 and abs(np.median(np.diff(stamps)) - 0.033313) < 1e-5   # 30 fps, in s
    exposure = read_exposure_log(folder / "gyro_dump.txt")
    assert len(exposure) == 2146 and 0.0049 <= min(exposure.values()) and max(exposure.values()) <= 0.0060
    gyro = read_phone_gyro_log(folder / "gyro.txt")
    assert abs(1 / np.median(np.diff(gyro[:, 0])) - 412) < 3     # Hz
    raw = np.loadtxt(folder / "gyro.txt", delimiter=",")
    assert np.allclose(gyro[:, 1], -raw[:, 1]) and np.allclose(gyro[:, 2], -raw[:, 0])   # camera x = -gyro y
    clip = read_footage_clip(DATA, 120, 3)
    assert clip.frames[0].name == "RE_frame-120.jpg" and clip.exposures[0] == exposure[120]
    assert abs(clip.starts[0] - stamps[119]) < 0.01


def test_bad_logs_are_one_line_errors(tmp_path):
    bad = tmp_path / "gyro.txt"
    bad.write_text("1,2,3,0.1\n1,2,oops,0.2\n")
    with pytest.raises(LowcamError, match="gyro.txt: not a gyro log"):
        read_phone_gyro_log(bad)
    bad.write_text("1,2,3,0.2\n1,2,3,0.1\n")
    with pytest.raises(LowcamError, match="line 2: .*times must increase"):
        read_phone_gyro_log(bad)
    dump = tmp_path / "gyro_dump.txt"
    dump.write_text("nothing here\n")
    with pytest.raises(LowcamError, match="not a phone exposure log"):
        read_exposure_log(dump)
    with pytest.raises(LowcamError, match="no such footage folder"):
        read_footage_clip(tmp_path / "absent")


@needs_data
def test_motion_blur_length_is_the_gyro_rate_times_exposure_times_focal():
    from lowcam.effects.motion_blur import tap_offsets

    clip = read_footage_clip(DATA, 99, 12)
    profile = footage_profile(load_profile("fire-i"), clip)
    i = int(np.argmax([np.hypot(*frame_motion(clip, k)[0][:2]) for k in range(12)]))
    w, exposure = frame_motion(clip, i)
    taps = 16
    off = tap_offsets(profile.lens, np.array([PHONE_K[0, 2]]), np.array([PHONE_K[1, 2]]), w, exposure, taps)[0]
    length = np.linalg.norm(off[-1] - off[0]) * taps / (taps - 1)       # px over the whole exposure
    expected = np.hypot(w[0] * PHONE_K[1, 1], w[1] * PHONE_K[0, 0]) * exposure
    assert expected > 1.5                               # a blur worth seeing: 0.59 rad/s over 5.3 ms
    assert abs(length - expected) < 0.02 * expected, (length, expected)
    direction = (off[-1] - off[0]) / np.linalg.norm(off[-1] - off[0])
    assert np.dot(direction, np.array([w[1], -w[0]]) / np.hypot(w[0], w[1])) > 0.999   # where a pixel looks later


@needs_data
def test_rolling_shutter_skew_is_the_gyro_rate_times_readout():
    from lowcam.pipeline import run

    clip = read_footage_clip(DATA, 99, 12)
    profile = footage_profile(load_profile("fire-i"), clip)
    w, exposure = frame_motion(clip, 10)    # frame 109: 0.59 rad/s
    render = np.zeros((480, 640, 4), np.float32)
    state = run(render, profile, None, w, exposure, stop_after="rolling_shutter").state
    off = state.sampling_offset                                 # (rows, cols, 2) px on the working grid
    g = state.geometry
    from lowcam.geometry import grid_points

    u, v = grid_points(g.working_extent)
    # row v is read t = (v / H - 1/2) readout after the middle row; the rotation flow field (Longuet-Higgins and
    # Prazdny 1980, first order in the angle) says where a pixel looks after the camera turned by w t
    x, y = (u - PHONE_K[0, 2]) / PHONE_K[0, 0], (v - PHONE_K[1, 2]) / PHONE_K[1, 1]
    t = (v / clip.height - 0.5) * clip.readout_s
    wx, wy, wz = w
    expect_u = PHONE_K[0, 0] * t * (-x * y * wx + (1 + x * x) * wy - y * wz)
    expect_v = PHONE_K[1, 1] * t * (-(1 + y * y) * wx + x * y * wy + x * wz)
    scale = np.abs(expect_u).max() + np.abs(expect_v).max()
    assert scale > 2.0                                       # px: a skew worth seeing (0.6 rad/s over 33 ms)
    assert np.abs(off[..., 0] - expect_u).max() < 0.03 * scale
    assert np.abs(off[..., 1] - expect_v).max() < 0.03 * scale


def test_write_gif_writes_every_frame(tmp_path):
    from PIL import Image

    frames = [np.full((8, 12, 3), k * 40, np.uint8) for k in range(4)]
    path = write_gif(tmp_path / "a.gif", frames, fps=10)
    with Image.open(path) as im:
        assert im.n_frames == 4
        im.seek(2)
        assert abs(int(np.asarray(im.convert("L"))[0, 0]) - 80) <= 2


RUN_WORKTREE = """
import importlib.util, sys
root = sys.argv[1]
sys.path.insert(0, root)
spec = importlib.util.spec_from_file_location("lowcam_blender", root + "/__init__.py",
                                              submodule_search_locations=[root])
mod = importlib.util.module_from_spec(spec); sys.modules["lowcam_blender"] = mod; spec.loader.exec_module(mod)
from lowcam.cli import main
sys.exit(main(sys.argv[2:]))
"""


@needs_data
@pytest.mark.blender
@pytest.mark.slow   # 35 s alone, 2 min with the plate estimate on a busy 2-core machine
def test_footage_demo_end_to_end_keeps_the_object_fixed_in_the_world(tmp_path):
    """Four frames: the inserted objects move in the image as the gyro-turned camera says (fixed in the world)."""
    from lowcam.io import read_image

    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-c", RUN_WORKTREE, str(ROOT), "demo", "--footage", str(DATA),
                        "--footage-frames", "4", "-o", str(out)], capture_output=True, text=True, timeout=600,
                       env=dict(os.environ))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "[5/5]" in r.stdout and "profile estimated from 4 frames of the plate" in r.stdout and (out / "side_by_side.png").is_file()
    from PIL import Image

    with Image.open(out / "side_by_side.gif") as im:
        assert im.n_frames == 4
    side = read_image(out / "side_by_side.png")
    assert side.shape == (628, 1608, 3)
    lowcam_frame, plain = read_image(out / "lowcam.png"), read_image(out / "plain.png")
    clip = read_footage_clip(DATA, 99, 4)
    plate = cv2.cvtColor(cv2.imread(str(clip.frames[2])), cv2.COLOR_BGR2RGB)
    changed = np.abs(plain.astype(int) - plate).max(-1) > 40
    assert 2000 < changed.sum() < 60000                  # the objects, nothing else
    assert (np.abs(lowcam_frame.astype(int) - plain).max(-1) > 8).mean() < 0.2   # the same plate, degraded objects
    # the sphere's centre, fixed in the world, projected through the gyro's camera for the middle frame (2): the
    # centroid of its silhouette sits there (a static camera would put it where frame 0 had it, SHIFT px away)
    rots = camera_rotations(clip)

    def project(rot):
        p = rot.T @ np.array([-6.5, -5.0, 26.0])
        return np.array([PHONE_K[0, 0] * p[0] / p[2] + PHONE_K[0, 2], PHONE_K[1, 1] * p[1] / p[2] + PHONE_K[1, 2]])

    centre = project(rots[2])
    _, labels = cv2.connectedComponents(changed.astype(np.uint8))
    blob = labels == labels[int(round(centre[1])), int(round(centre[0]))]
    assert labels[int(round(centre[1])), int(round(centre[0]))] != 0 and 3000 < blob.sum() < 12000
    ys, xs = np.nonzero(blob)
    found = np.array([xs.mean(), ys.mean()])
    shift = np.linalg.norm(project(rots[2]) - project(rots[0]))
    assert shift > 3.0
    assert np.linalg.norm(found - centre) < 0.5 * shift, (found, centre, shift)
