"""Benchmark: the Fire-i chain on three kinds of frame, this checkout beside an earlier commit, in the same run.

Cases (RGBA float32 renders, w = (0.05, 0.8, 0.1) rad/s so motion blur does real work):

- ``sparse``: the sample render (graphics over about a fifth of the frame), 3000x2250 -> 640x480
- ``full``: the same render over an opaque background, every pixel opaque (a virtual set, full CG)
- ``hd``: the Fire-i chain at 1920x1080 (same lens, square pixels), a full-frame 3840x2160 render

Each side (``new``: this checkout; ``old``: ``--base``, default the merge base with ``main``, unpacked with
``git archive``) runs in its own long-lived process; the frames alternate between them (old, new, then new,
old, ...), so a shared, noisy machine slows both alike. Prints per case the median ms/frame of each side and
their ratio, the median CPU time of a frame (all its threads), the per-stage medians (``_start``, every effect's ``apply``, ``_finish``), and whether the two
sides' frames are the same bytes.

    .venv/bin/python benchmarks/bench_frames.py [--frames 9] [--cases sparse full hd] [--base REF]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OMEGA = (0.05, 0.8, 0.1)  # rad/s: a moderate hand-held pan
CASES = {"sparse": ("fire-i", 3000, 2250), "full": ("fire-i", 3000, 2250), "hd": ("hd", 3840, 2160)}
BACKGROUND = (0.3, 0.4, 0.5, 1.0)  # premultiplied linear RGBA behind the full-frame renders


def hd_profile(folder: Path, profiles: Path) -> Path:
    """A Fire-i profile at 1920x1080 in ``folder``: the bundled TOML with the frame enlarged, fy scaled for
    square pixels at 16:9, and its textures read from ``profiles`` (stretched over the wider frame)."""
    text = (profiles / "fire-i.toml").read_text()
    for old, new in (("width = 640", "width = 1920"), ("height = 480", "height = 1080"),
                     ("fy = 0.76", f"fy = {0.57 * 1920 / 1080:.6f}"),
                     ('texture = "fire-i/', f'texture = "{profiles.as_posix()}/fire-i/')):
        assert old in text, old
        text = text.replace(old, new)
    path = folder / "fire-i-hd.toml"
    path.write_text(text)
    return path


def child(case: str, folder: str) -> None:
    """Serve frames of ``case`` on stdin/stdout: each line ``K`` runs frame K and answers one JSON line."""
    import cv2
    import numpy as np

    import lowcam
    from lowcam.pipeline import _finish, _start
    from lowcam.profile import load_profile
    from lowcam.sample import sample_plate, sample_render

    name, width, height = CASES[case]
    profiles = Path(lowcam.__file__).resolve().parent.parent / "profiles"
    profile = load_profile(hd_profile(Path(tempfile.mkdtemp(dir=folder)), profiles) if name == "hd" else name)
    cache = Path(folder) / f"{case}.npz"  # render and plate made once, before either side starts
    if not cache.exists():
        render = sample_render(profile, width, height)
        if case != "sparse":
            render = render + np.float32(BACKGROUND) * (1 - render[..., 3:])
        np.savez(cache, render=render, plate=sample_plate(profile))
        return
    data = np.load(cache)
    render, plate = data["render"], data["plate"]
    print(json.dumps({"lowcam": lowcam.__file__, "threads": cv2.getNumThreads()}), flush=True)
    for line in sys.stdin:
        frame = int(line)
        c0 = time.process_time()
        t0 = time.perf_counter()
        state, plate_u8 = _start(render, profile, plate, OMEGA, None, 0, frame, None)
        stages = {"_start": time.perf_counter() - t0}
        cpu = {"_start": time.process_time() - c0}
        for effect in state.profile.effects:  # as lowcam.pipeline._walk
            if not effect.enabled and not effect.always_runs:
                continue
            t, c = time.perf_counter(), time.process_time()
            effect.apply(state)
            state.applied.append(effect)
            stages[effect.name] = time.perf_counter() - t
            cpu[effect.name] = time.process_time() - c
        t, c = time.perf_counter(), time.process_time()
        out, _ = _finish(state, plate_u8)
        stages["_finish"] = time.perf_counter() - t
        cpu["_finish"] = time.process_time() - c
        total = time.perf_counter() - t0
        print(json.dumps({"total_ms": 1e3 * total, "cpu_ms": 1e3 * (time.process_time() - c0), "stages": {k: 1e3 * v for k, v in stages.items()},
                          "stage_cpu": {k: 1e3 * v for k, v in cpu.items()},
                          "sha256": hashlib.sha256(np.ascontiguousarray(out).tobytes()).hexdigest()}), flush=True)


def unpack(ref: str, folder: Path) -> Path:
    """``ref``'s engine and profiles, unpacked under ``folder``."""
    dest = folder / "old"
    dest.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "lowcam", "profiles"], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def start(code: Path, case: str, folder: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(code))
    proc = subprocess.Popen([sys.executable, __file__, "--child", case, str(folder)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env, cwd=str(folder))
    hello = json.loads(proc.stdout.readline())
    assert Path(hello["lowcam"]).resolve().is_relative_to(code.resolve()), (hello, code)
    return proc


def ask(proc: subprocess.Popen, frame: int) -> dict:
    proc.stdin.write(f"{frame}\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=9, help="timed frames per side and case")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--base", help="the commit to compare with (default: the merge base with main)")
    parser.add_argument("--child", nargs=2, metavar=("CASE", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child)
        return
    base = args.base or subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], capture_output=True,
                                       text=True, check=True).stdout.strip()
    folder = Path(tempfile.mkdtemp(prefix="lowcam-bench-"))
    sides = {"old": unpack(base, folder), "new": ROOT}
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()
    print(f"Fire-i chain, old = {base[:9]}, new = {head} (+ working tree), w = {OMEGA} rad/s, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}", flush=True)
    results = {}
    for case in args.cases:
        subprocess.run([sys.executable, __file__, "--child", case, str(folder)], check=True,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=str(folder))  # the render and plate
        procs = {side: start(code, case, folder) for side, code in sides.items()}
        runs = {side: [] for side in procs}
        for frame in range(args.frames + 1):
            order = ("old", "new") if frame % 2 == 0 else ("new", "old")
            for side in order:
                answer = ask(procs[side], frame)
                if frame:  # frame 0 warms up: builds and keeps the warps
                    runs[side].append(answer)
        for proc in procs.values():
            proc.stdin.close()
            proc.wait()
        med = {side: statistics.median(r["total_ms"] for r in runs[side]) for side in runs}
        same = all(a["sha256"] == b["sha256"] for a, b in zip(runs["old"], runs["new"]))
        name, width, height = CASES[case]
        print(f"\n{case}: {width}x{height} render -> {'1920x1080' if name == 'hd' else '640x480'}, "
              f"{args.frames} frames per side; same bytes: {'yes' if same else 'NO'}")
        print(f"  {'stage':22s}{'old ms':>10s}{'new ms':>10s}{'new/old':>9s}{'old CPU':>10s}{'new CPU':>10s}")
        for stage in runs["new"][0]["stages"]:
            o, n, oc, nc = (statistics.median(r[key].get(stage, 0.0) for r in runs[side])
                            for key in ("stages", "stage_cpu") for side in ("old", "new"))
            if max(o, n) >= 0.5:
                print(f"  {stage:22s}{o:10.1f}{n:10.1f}{n / o if o else float('nan'):9.2f}{oc:10.1f}{nc:10.1f}")
        cpu = {side: statistics.median(r["cpu_ms"] for r in runs[side]) for side in runs}
        print(f"  {'frame (median)':22s}{med['old']:10.1f}{med['new']:10.1f}{med['new'] / med['old']:9.2f}")
        print(f"  {'CPU time, all threads':22s}{cpu['old']:10.1f}{cpu['new']:10.1f}{cpu['new'] / cpu['old']:9.2f}",
              flush=True)
        results[case] = {"old_ms": med["old"], "new_ms": med["new"], "ratio": med["new"] / med["old"],
                         "old_cpu_ms": cpu["old"], "new_cpu_ms": cpu["new"],
                         "same_bytes": same, "runs": runs}
    out = ROOT / "benchmarks" / "results"
    out.mkdir(exist_ok=True)
    (out / "frames.json").write_text(json.dumps({"base": base, "head": head, "results": results}, indent=1))


if __name__ == "__main__":
    main()
