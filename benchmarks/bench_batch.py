"""Benchmark: shot throughput in frames/s, serial and on a 2-worker Dask LocalCluster, at the paper's sizes.

Renders are 3000x2250 RGBA float32 OpenEXR files (ZIP-compressed, as Blender writes them; half float with
``--depth 16``), plates 640x480 PNG,
outputs 640x480 PNG: the whole job per frame, reading and writing included. Prints frames/s, each frame's median
read / simulate / write split, the floor (reading the same renders and plates alone, one after another), the
serial run with one frame at a time (no reading ahead or writing behind) as the baseline, the scaling ratio
(target >= 1.7x on 2 cores) and the peak memory per worker.

    .venv/bin/python benchmarks/bench_batch.py [--frames 16] [--depth 16]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


def peak_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--depth", choices=("32", "16"), default="32",
                        help="the renders' float depth: 32-bit (Blender's default) or half float, both ZIP")
    args = parser.parse_args()

    from lowcam.batch import Shot, run_shot
    from lowcam.motion import FrameMotion
    from lowcam.outputs import write_exr
    from lowcam.sample import sample_plate, sample_render

    tmp = Path(tempfile.mkdtemp())
    frames = list(range(1, args.frames + 1))
    print(f"making a {len(frames)}-frame shot of 3000x2250 {args.depth}-bit EXR renders in {tmp} ...", flush=True)
    render = sample_render("fire-i", 3000)
    plate = cv2.cvtColor(sample_plate("fire-i"), cv2.COLOR_RGB2BGR)
    for f in frames:
        write_exr(tmp / "renders" / f"{f:04d}.exr", np.roll(render, 8 * f, axis=1), half=args.depth == "16")
        (tmp / "plates").mkdir(exist_ok=True)
        cv2.imwrite(str(tmp / "plates" / f"{f:04d}.png"), plate)
    motion = {f: FrameMotion((0.05, 0.8 * np.sin(f / 5), 0.1)) for f in frames}

    def shot(name):
        return Shot("fire-i", str(tmp / "renders/####.exr"), str(tmp / name / "####.png"),
                    str(tmp / "plates/####.png"), motion, True)

    from dask.distributed import Client

    from lowcam.batch import local_cluster

    from lowcam.batch import _read_inputs, process_frame

    s = shot("floor")
    profile = s.load_profile()
    _read_inputs(s, 1, profile)
    t = time.perf_counter()
    for f in frames:
        _read_inputs(s, f, profile)
    floor = len(frames) / (time.perf_counter() - t)
    print(f"{'reading alone':18s} {floor:6.2f} frames/s  (the floor: renders and plates, one after another)",
          flush=True)

    def one_at_a_time(s, frames, force=False, quiet=True):
        return [process_frame(s, f, force) for f in frames]

    rates = {}
    with local_cluster(2) as cluster:
        # A farm job starts its workers once: both sides are warmed up (imports, lens maps) on the first four
        # frames, then the whole shot is timed.
        for label, run, kwargs in (("one at a time", one_at_a_time, {}), ("serial 1 thread", run_shot, {}),
                                   ("serial", run_shot, {}),
                                   ("2 Dask workers", run_shot, {"scheduler": cluster.scheduler_address})):
            cv2.setNumThreads(1 if label == "serial 1 thread" else cv2.getNumberOfCPUs())
            s = shot(label.replace(" ", "-"))
            run(s, frames[:4], quiet=True, **kwargs)
            t = time.perf_counter()
            results = run(s, frames, force=True, quiet=True, **kwargs)
            elapsed = time.perf_counter() - t
            assert all(r.status == "written" for r in results)
            rates[label] = len(frames) / elapsed
            split = " / ".join(f"{np.median([getattr(r, k) for r in results]) * 1e3:.0f}"
                               for k in ("read_s", "simulate_s", "write_s"))
            print(f"{label:18s} {rates[label]:6.2f} frames/s  ({elapsed:5.1f} s wall; per frame, median ms: read / "
                  f"simulate / write {split})", flush=True)
        with Client(cluster) as client:
            peaks = client.run(peak_mb)
    print(f"serial: {rates['serial'] / rates['one at a time']:.2f}x one frame at a time, "
          f"{floor / rates['serial']:.2f}x the floor's time (target <= 1.3x)")
    ratio = rates["2 Dask workers"] / rates["serial"]
    print(f"scaling with 2 workers: {ratio:.2f}x over the serial run (target >= 1.7x on 2 cores), "
          f"{rates['2 Dask workers'] / rates['serial 1 thread']:.2f}x over a serial run on one core")
    print("peak memory per worker: " + ", ".join(f"{v:.0f} MB" for v in peaks.values()))
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
