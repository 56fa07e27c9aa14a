"""Benchmark: what object motion (velocity pass) and defocus from depth (depth pass) add to the Fire-i chain.

A 1600x1200 render of the sample objects (the size ``lowcam demo`` renders at twice its default width), the
objects moving 1500 px/s to the right (50 px over the 33 ms exposure) and standing at 1 m with the focus at 2 m
and a 2 mm aperture. Prints the median ms per frame of the chain alone, with each effect and with both, and the
ratios to the chain alone, all measured in this run.

    .venv/bin/python benchmarks/bench_passes.py [--repeats 9]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()

    import lowcam
    from lowcam.passes import RenderPasses
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
    cases = {"chain alone": profile, "+ object_motion": motion,
             "+ depth_of_field": profile.with_effect("depth_of_field", **dof),
             "+ both": motion.with_effect("depth_of_field", **dof)}
    print(f"1600x1200 render, {covered.mean():.0%} covered, median of {args.repeats}:")
    base = None
    for name, p in cases.items():
        lowcam.run(render, p, plate, passes=passes)             # warm-up (lens maps)
        times = []
        for frame in range(args.repeats):
            t = time.perf_counter()
            lowcam.run(render, p, plate, passes=passes, frame=frame)
            times.append(1e3 * (time.perf_counter() - t))
        median = statistics.median(times)
        base = base or median
        print(f"  {name:18s} {median:7.1f} ms   {median / base:5.2f}x")


if __name__ == "__main__":
    main()
