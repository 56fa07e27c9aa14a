"""A video plate is opened once per shot, not once per frame: ``lowcam batch`` and the add-on's Movie Clip plates.

The video is written with OpenCV (MJPEG) and read with :mod:`lowcam.video`; opens are counted by wrapping
``lowcam.video.VideoReader``, and the frames are checked against OpenCV's own decode.
"""
import os

import cv2
import numpy as np
import pytest

from lowcam import video as lowcam_video
from lowcam.batch import Shot, read_video_frame, run_shot
from lowcam.outputs import write_exr

FRAMES = 6


def _write_video(path, frames=FRAMES, shift=0):
    """An MJPEG .avi at the Fire-i's size whose frame i has its own brightness and a bar at column 40 i."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 24.0, (640, 480))
    assert writer.isOpened()
    for i in range(frames):
        img = np.full((480, 640, 3), 30 + 30 * i + shift, np.uint8)
        img[:, 40 * i:40 * i + 40] = 250
        writer.write(img)
    writer.release()
    return path


def _frames_as_opencv_reads_them(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    cap.release()
    return out


def _frames_as_lowcam_reads_them(path):
    with lowcam_video.VideoReader(path) as video:
        return [rgb for _, rgb in video.frames()]


@pytest.fixture
def count_opens(monkeypatch):
    """The number of ``lowcam.video.VideoReader`` objects made, per path, from now on (cached ones closed
    first)."""
    lowcam_video.close_videos()
    opens: dict = {}
    real = lowcam_video.VideoReader

    class Counting(real):
        def __init__(self, path, *args):
            opens[os.path.basename(str(path))] = opens.get(os.path.basename(str(path)), 0) + 1
            super().__init__(path, *args)

    monkeypatch.setattr(lowcam_video, "VideoReader", Counting)
    yield opens
    lowcam_video.close_videos()


def test_a_shot_opens_its_video_once_and_reads_every_frame_right(tmp_path, count_opens):
    video = _write_video(tmp_path / "plate.avi")
    opencv = _frames_as_opencv_reads_them(video)
    truth = _frames_as_lowcam_reads_them(video)
    assert len(truth) == FRAMES and count_opens == {"plate.avi": 1}
    for ours, theirs in zip(truth, opencv):                          # MJPEG: full-range BT.601 both ways
        assert np.abs(ours.astype(int) - theirs).mean() < 1.5
    count_opens.clear()
    for f in range(1, FRAMES + 1):                                   # transparent renders: the output is the plate
        write_exr(tmp_path / "renders" / f"{f:04d}.exr", np.zeros((150, 200, 4), np.float32))
    shot = Shot("fire-i", str(tmp_path / "renders" / "####.exr"), str(tmp_path / "out" / "####.png"), str(video))
    results = run_shot(shot, list(range(1, FRAMES + 1)), quiet=True)
    assert [r.status for r in results] == ["written"] * FRAMES
    assert count_opens == {"plate.avi": 1}                           # not once per frame (it was 7)
    for f in range(1, FRAMES + 1):
        out = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / f"{f:04d}.png")), cv2.COLOR_BGR2RGB)
        assert np.array_equal(out, truth[f - 1])                     # the right frame, in order
    assert np.array_equal(read_video_frame(str(video), 2), truth[2])  # a jump back reads the right frame too
    assert np.array_equal(read_video_frame(str(video), 5), truth[5])
    assert count_opens == {"plate.avi": 1}


def test_a_video_changed_on_disk_is_opened_afresh(tmp_path, count_opens):
    video = _write_video(tmp_path / "plate.avi")
    before = read_video_frame(str(video), 1)
    _write_video(tmp_path / "new.avi", shift=7)
    os.replace(tmp_path / "new.avi", video)
    os.utime(video, ns=(os.stat(video).st_atime_ns, os.stat(video).st_mtime_ns + 10**9))
    after = read_video_frame(str(video), 1)
    assert count_opens == {"plate.avi": 2}                           # the new file, not the old one cached
    assert np.abs(after.astype(int) - before.astype(int)).mean() > 4


@pytest.mark.blender
def test_a_movie_clip_plate_is_opened_once_per_render_of_many_frames(tmp_path, count_opens):
    """The add-on's Movie Clip plate over a three-frame ``lowcam render``: one open of the video, and each
    composite shows its own video frame."""
    from lowcam_blender import submodule

    import bpy

    render = submodule("addon.render")                              # registers the add-on
    video = _write_video(tmp_path / "plate.avi")
    truth = _frames_as_lowcam_reads_them(video)
    count_opens.clear()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.device, scene.cycles.use_denoising = 1, "CPU", False
    scene.render.resolution_x, scene.render.resolution_y = 160, 120     # the render the engine takes: 160 wide
    scene.frame_start, scene.frame_end = 1, 3
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    clip = bpy.data.movieclips.load(str(video))
    s = scene.lowcam
    s.enabled, s.plate_source, s.plate_clip, s.motion_source = True, "CLIP", clip, "NONE"
    blend = tmp_path / "clip.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    written = render.render(blend, [1, 2, 3], str(tmp_path / "out" / "####.png"))
    assert count_opens.get("plate.avi") == 1
    for f, path in zip((1, 2, 3), written):
        out = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        assert np.array_equal(out, truth[f - 1])                     # nothing rendered: the plate, frame f
