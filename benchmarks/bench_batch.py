"""Benchmark: shot throughput in frames/s, serial and on a 2-worker Dask LocalCluster, at the paper's sizes.

Renders are 3000x2250 RGBA float32 OpenEXR files (ZIP-compressed, as Blender writes them; half float with
``--depth 16``), plates 640x480 PNG,
outputs 640x480 PNG: the whole job per frame, reading and writing included. Prints frames/s, each frame's median
read / simulate / write split, the floor (reading the same renders and plates alone, one after another), the
serial run with one frame at a time (no reading ahead or writing behind) as the baseline, the scaling ratio
(target >= 1.7x on 2 cores) and the peak memory per worker.

Then the targets, as ratios measured in the same run (``--targets`` alone skips the runs above): on renders in the
compression the add-on writes (:data:`RENDER_CODEC`), a serial shot's CPU per frame against the engine's own (the
simulation of the same frames from memory; target <= 1.25x) and the render reading's share of that frame CPU (target
<= 15 %; read as the shot reads them, into arrays reused from frame to frame); on ZIP renders, a serial shot's wall
time per frame against the code of 2026-11-25 (commit 7f593e9, run from ``git archive`` in a child Python on the
same files, the two taking turns; target <= 0.55x). CPU times are the process's (every thread's,
``time.process_time``): on the shared development machine they are far steadier than wall times.

    .venv/bin/python benchmarks/bench_batch.py [--frames 16] [--depth 16] [--targets] [--turns 3]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


ROOT = Path(__file__).resolve().parent.parent
#: The compression the add-on writes renders in by default (addon/properties.py, Render Compression).
RENDER_CODEC = "NO"
#: The code the ZIP target is measured against (2026-11-25).
BASELINE_COMMIT = "7f593e9"

#: A serial shot in a child Python, on whichever lowcam its sys.path finds first: argv = renders, plates, output,
#: frames; prints its wall and CPU seconds and the lowcam it ran as JSON.
_CHILD_SHOT = """
import json, sys, time
import numpy as np
import lowcam
from lowcam.batch import Shot, run_shot
from lowcam.motion import FrameMotion
renders, plates, output, n = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
frames = list(range(1, n + 1))
motion = {f: FrameMotion((0.05, 0.8 * np.sin(f / 5), 0.1)) for f in frames}
shot = Shot("fire-i", renders, output, plates, motion, True)
run_shot(shot, frames[:2], force=True, quiet=True)
t, c = time.perf_counter(), time.process_time()
results = run_shot(shot, frames, force=True, quiet=True)
wall, cpu = time.perf_counter() - t, time.process_time() - c
assert all(r.status == "written" for r in results)
print(json.dumps({"wall": wall, "cpu": cpu, "lowcam": lowcam.__file__}))
"""


def write_renders(folder: Path, render: np.ndarray, frames, codec: str, half: bool = False) -> None:
    """The shot's renders: ``render`` moved 8 px a frame, single-part RGBA OpenEXR in ``codec``."""
    import OpenEXR

    folder.mkdir(parents=True, exist_ok=True)
    for f in frames:
        pixels = np.roll(render, 8 * f, axis=1).astype(np.float16 if half else np.float32)
        header = {"compression": getattr(OpenEXR, f"{codec}_COMPRESSION"), "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGBA": pixels}).write(str(folder / f"{f:04d}.exr"))


def child_shot(pythonpath: str, renders: str, plates: str, output: str, frames: int) -> dict:
    env = {**os.environ, "PYTHONPATH": pythonpath}
    r = subprocess.run([sys.executable, "-c", _CHILD_SHOT, renders, plates, output, str(frames)], env=env,
                       capture_output=True, text=True, cwd=pythonpath)
    if r.returncode:
        raise SystemExit(f"the child shot failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def targets(tmp: Path, render: np.ndarray, frames: list[int], turns: int) -> None:
    """The issue's targets as ratios, measured in this run (see the module's docstring)."""
    from lowcam.batch import READ_AHEAD, Shot, _read_inputs, _simulate_inputs, run_shot
    from lowcam.io import reusing_render_buffers
    from lowcam.motion import FrameMotion
    from lowcam.passes import read_render_and_passes

    motion = {f: FrameMotion((0.05, 0.8 * np.sin(f / 5), 0.1)) for f in frames}
    for codec in (RENDER_CODEC, "ZIP"):
        write_renders(tmp / f"renders-{codec}", render, frames, codec)

    # 1. renders in the add-on's compression (and in ZIP, its compression before): the shot's CPU per frame
    # against the engine's and the reading's
    for codec in (RENDER_CODEC, "ZIP"):
        shot = Shot("fire-i", str(tmp / f"renders-{codec}/####.exr"), str(tmp / "targets/####.png"),
                    str(tmp / "plates/####.png"), motion, True)
        profile = shot.load_profile()
        run_shot(shot, frames[:2], force=True, quiet=True)
        shot_cpu, engine_cpu, read_cpu = [], [], []
        for _ in range(turns):
            c = time.process_time()
            results = run_shot(shot, frames, force=True, quiet=True)
            shot_cpu.append((time.process_time() - c) / len(frames))
            assert all(r.status == "written" for r in results)
            engine = 0.0
            for f in frames:   # the engine alone: each frame's inputs read first, untimed
                inputs = _read_inputs(shot, f, profile)
                c = time.process_time()
                _simulate_inputs(shot, f, profile, motion[f], inputs)
                engine += time.process_time() - c
            engine_cpu.append(engine / len(frames))
            c = time.process_time()
            with reusing_render_buffers(READ_AHEAD + 2):    # as the shot reads them
                for f in frames:
                    read_render_and_passes(tmp / f"renders-{codec}/{f:04d}.exr", None, (), 24.0)
            read_cpu.append((time.process_time() - c) / len(frames))
        shot_ms, engine_ms, read_ms = (float(np.median(v)) * 1e3 for v in (shot_cpu, engine_cpu, read_cpu))
        print(f"\ntargets, renders in {codec}{' (the add-on' + chr(39) + 's default)' if codec == RENDER_CODEC else ''}, "
              f"medians of {turns} turns of {len(frames)} frames, CPU ms per frame: shot {shot_ms:.0f}, engine alone "
              f"{engine_ms:.0f}, reading the render {read_ms:.0f}")
        print(f"  serial shot / engine CPU per frame: {shot_ms / engine_ms:.2f}x (target <= 1.25x)")
        print(f"  reading the render: {read_ms / shot_ms:.0%} of the shot's CPU per frame (target <= 15 %)")

    # 2. ZIP renders: this code's serial shot against the code of BASELINE_COMMIT, taking turns
    old = tmp / "baseline-code"
    old.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", BASELINE_COMMIT], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
    walls = {"now": [], "old": []}
    cpus = {"now": [], "old": []}
    for _ in range(turns):
        for label, path in (("now", str(ROOT)), ("old", str(old))):
            got = child_shot(path, str(tmp / "renders-ZIP/####.exr"), str(tmp / "plates/####.png"),
                             str(tmp / f"zip-{label}/####.png"), len(frames))
            assert Path(got["lowcam"]).resolve().is_relative_to(Path(path).resolve()), got["lowcam"]
            walls[label].append(got["wall"] / len(frames))
            cpus[label].append(got["cpu"] / len(frames))
    now, was = (float(np.median(walls[k])) * 1e3 for k in ("now", "old"))
    now_c, was_c = (float(np.median(cpus[k])) * 1e3 for k in ("now", "old"))
    print(f"\ntargets, ZIP renders, medians of {turns} turns of {len(frames)} frames per frame: wall {now:.0f} ms "
          f"(CPU {now_c:.0f}) now, {was:.0f} ms (CPU {was_c:.0f}) at {BASELINE_COMMIT}")
    print(f"  serial shot wall per frame: {now / was:.2f}x the code of 2026-11-25 (target <= 0.55x); "
          f"CPU {now_c / was_c:.2f}x")


def peak_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--depth", choices=("32", "16"), default="32",
                        help="the renders' float depth: 32-bit (Blender's default) or half float, both ZIP")
    parser.add_argument("--targets", action="store_true", help="only the targets' ratios")
    parser.add_argument("--turns", type=int, default=3, help="turns of each run for the targets' ratios")
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

    if args.targets:
        targets(tmp, render, frames, args.turns)
        shutil.rmtree(tmp)
        return

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
    targets(tmp, render, frames, args.turns)
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
