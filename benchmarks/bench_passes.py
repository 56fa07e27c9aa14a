"""Benchmark: what object motion (velocity pass) and defocus from depth (depth pass) add to the Fire-i chain.

A 1600x1200 render of the sample objects (the size ``lowcam demo`` renders at twice its default width), the
objects moving 1500 px/s to the right (50 px over the 33 ms exposure) and standing at 1 m with the focus at 2 m
and a 2 mm aperture. Prints the median ms per frame of the chain alone, with each effect and with both, and the
ratios to the chain alone, all measured in this run, the cases taking turns frame by frame (this machine's load
changes by the second). The same with the camera turning at (0.05, 0.8, 0.1) rad/s, the velocity pass holding the
rotation's image velocity plus the objects' own (float32 sums, so the paths left after taking the rotation out
differ by rounding). Beside them, object motion as it was at ``--before`` (a commit; the module read with
``git show``), and whether both give the same frames.

    .venv/bin/python benchmarks/bench_passes.py [--repeats 9] [--before ef6190f]
"""
from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

MODULE = "lowcam/effects/object_motion.py"


@contextmanager
def object_motion_at(commit: str):
    """Object motion's ``apply`` as it was at ``commit`` (``git show`` of its module) while inside."""
    from lowcam.effects.object_motion import ObjectMotion

    source = subprocess.run(["git", "show", f"{commit}:{MODULE}"], capture_output=True, text=True, check=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout
    spec = importlib.util.spec_from_loader("lowcam.effects._object_motion_before", loader=None)
    before = importlib.util.module_from_spec(spec)
    before.__package__ = "lowcam.effects"
    exec(compile(source, f"{commit}:{MODULE}", "exec"), before.__dict__)
    now = ObjectMotion.apply
    ObjectMotion.apply = before.ObjectMotion.apply
    try:
        yield
    finally:
        ObjectMotion.apply = now


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--before", default="ef6190f", help="the commit whose object motion to compare against")
    args = parser.parse_args()

    import lowcam
    from lowcam.effects.object_motion import rotation_velocity
    from lowcam.passes import RenderPasses
    from lowcam.pipeline import render_focal_px
    from lowcam.sample import sample_plate, sample_render

    profile = lowcam.load_profile("fire-i")
    render, plate = sample_render(profile, 1600), sample_plate(profile)
    covered = render[..., 3] > 0
    velocity = np.zeros(render.shape[:2] + (2,), np.float32)
    velocity[covered, 0] = 1500.0
    depth = np.where(covered, 1.0, np.inf).astype(np.float32)
    passes = RenderPasses(velocity, depth)
    motion = profile.with_effect("object_motion")
    dof = {"focus_distance_m": 2.0, "aperture_mm": 2.0}
    before = f"+ object_motion at {args.before}"
    turning = (0.05, 0.8, 0.1)
    turning_velocity = rotation_velocity(turning, render_focal_px(profile, *render.shape[1::-1]), render.shape[:2])
    turning_velocity[covered, 0] += 1500.0
    turning_passes = RenderPasses(turning_velocity, depth)
    cases = {"chain alone": profile, "+ object_motion": motion, before: motion,
             "+ depth_of_field": profile.with_effect("depth_of_field", **dof),
             "+ both": motion.with_effect("depth_of_field", **dof),
             "turning: chain alone": profile, "turning: + object_motion": motion}

    def frame_of(name, p, frame):
        w, frame_passes = (turning, turning_passes) if name.startswith("turning") else ((0, 0, 0), passes)
        if name != before:
            return lowcam.run(render, p, plate, w, passes=frame_passes, frame=frame).frame
        with object_motion_at(args.before):
            return lowcam.run(render, p, plate, passes=passes, frame=frame).frame

    times = {name: [] for name in cases}
    frames = {name: frame_of(name, p, 0) for name, p in cases.items()}      # warm-up (lens maps)
    for frame in range(args.repeats):
        for name, p in cases.items():
            t = time.perf_counter()
            frame_of(name, p, frame)
            times[name].append(1e3 * (time.perf_counter() - t))
    print(f"1600x1200 render, {covered.mean():.0%} covered, median of {args.repeats}:")
    for name, ts in times.items():
        median = statistics.median(ts)
        base = statistics.median(times["turning: chain alone" if name.startswith("turning") else "chain alone"])
        print(f"  {name:34s} {median:7.1f} ms   {median / base:5.2f}x")
    now, then = frames["+ object_motion"].astype(int), frames[before].astype(int)
    print(f"object motion now / at {args.before}: "
          f"{statistics.median(times['+ object_motion']) / statistics.median(times[before]):.2f}x the time; "
          f"frames differ at {np.count_nonzero(now != then)} of {now.size} values, by at most "
          f"{np.abs(now - then).max()} (8-bit)")

if __name__ == "__main__":
    main()
