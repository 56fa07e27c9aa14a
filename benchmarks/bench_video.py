"""Benchmark: decoding a video plate, Lowcam's reader (PyAV, the stream's own matrix) against OpenCV's VideoCapture.

A 1920x1080 H.264 clip like a phone's (BT.709, limited range, CRF 23, key frame every 60 frames, 3 B-frames, a
textured picture moving 4 px a frame) is written once with PyAV's libx264. Prints the median cost per frame of
reading it in order (decode and conversion to uint8 RGB) with :class:`lowcam.video.VideoReader` and with OpenCV
(``read`` and BGR->RGB), and of reading single frames in a seeded random order (seek and decode forward), as a Dask
worker does, and of coding the frames again as the plate was coded (``lowcam batch -o shot.mp4``: libx264 at
the plate's CRF, GOP and B-frames; the encoder's own preset, slower than the clip's). Each figure is the median of ``--repeats`` runs in the same process.

    .venv/bin/python benchmarks/bench_video.py [--frames 120] [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import av
import cv2
import numpy as np


def _write_clip(path: Path, frames: int) -> None:
    rng = np.random.default_rng(1)
    base = cv2.GaussianBlur(rng.integers(0, 256, (1080, 1920 + 4 * frames, 3)).astype(np.uint8), (0, 0), 3)
    with av.open(str(path), "w") as out:
        s = out.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 1920, 1080, "yuv420p"
        s.codec_context.colorspace, s.codec_context.color_range = 1, 1
        s.options = {"crf": "23", "preset": "veryfast", "x264-params": "keyint=60:bframes=3"}
        for i in range(frames):
            f = av.VideoFrame.from_ndarray(np.ascontiguousarray(base[:, 4 * i:4 * i + 1920]), "rgb24")
            f = f.reformat(format="yuv420p", dst_colorspace="itu709", dst_color_range="MPEG")
            f.pts = i
            for p in s.encode(f):
                out.mux(p)
        for p in s.encode():
            out.mux(p)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    from lowcam.video import VideoReader, coding_of_plate, write_video

    with tempfile.TemporaryDirectory() as tmp:
        clip = Path(tmp) / "phone.mp4"
        _write_clip(clip, args.frames)

        def lowcam_in_order():
            with VideoReader(clip) as video:
                return sum(1 for _ in video.frames())

        def opencv_in_order():
            cap = cv2.VideoCapture(str(clip))
            n = 0
            while True:
                ok, bgr = cap.read()
                if not ok:
                    break
                cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                n += 1
            cap.release()
            return n

        order = [int(i) for i in np.random.default_rng(3).permutation(args.frames)[:20]]

        def lowcam_random():
            with VideoReader(clip) as video:
                for i in order:
                    video.frame(i)
            return len(order)

        def opencv_random():
            cap = cv2.VideoCapture(str(clip))
            for i in order:
                cap.set(cv2.CAP_PROP_POS_FRAMES, i)
                cv2.cvtColor(cap.read()[1], cv2.COLOR_BGR2RGB)
            cap.release()
            return len(order)

        with VideoReader(clip) as video:
            rgb_frames = [rgb for _, rgb in video.frames()]
        coding = coding_of_plate(clip)

        def lowcam_encode():   # a shot coded as the plate was (lowcam batch -o shot.mp4)
            write_video(Path(tmp) / "shot.mp4", iter(rgb_frames), coding)
            return len(rgb_frames)

        for name, fn in (("lowcam.video in order", lowcam_in_order), ("OpenCV in order", opencv_in_order),
                         ("lowcam.video random frames", lowcam_random), ("OpenCV random frames", opencv_random),
                         ("coding a shot as the plate", lowcam_encode)):
            times = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                n = fn()
                times.append((time.perf_counter() - t) / n)
            print(f"{name:28s} {1000 * statistics.median(times):7.1f} ms/frame ({n} frames, median of "
                  f"{args.repeats})")


if __name__ == "__main__":
    main()
