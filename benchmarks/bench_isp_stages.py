"""Benchmark: the image-processor stages on a 640x480 frame, and the Fire-i frame with them off and on.

Prints, per stage, the median ms to process one delivered 640x480 frame whose graphics cover it all (the stage's
``finish``; temporal noise reduction's ``finish_after``, given the frame before), and the Fire-i chain's frame (a 1280x960 render of the sample scene over the sample plate) as the
bundled profile has it (the stages absent), with the stages present but switched off, and with each one on (the
four in turn, repeat by repeat).

    .venv/bin/python benchmarks/bench_isp_stages.py [--repeats 9]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

STAGES = (
    ("noise_reduction", {"method": "bilateral", "luma_strength_dn": 12.0, "chroma_strength_dn": 0.0, "scale_px": 2.0},
     "bilateral, luma, scale 2 px"),
    ("noise_reduction", {"method": "bilateral", "luma_strength_dn": 12.0, "chroma_strength_dn": 12.0,
                         "scale_px": 2.0}, "bilateral, luma and chroma, scale 2 px"),
    ("noise_reduction", {"method": "nl_means", "luma_strength_dn": 8.0, "chroma_strength_dn": 0.0, "scale_px": 5.0},
     "non-local means, luma, 11 px search"),
    ("noise_reduction", {"method": "nl_means", "luma_strength_dn": 8.0, "chroma_strength_dn": 8.0, "scale_px": 10.0},
     "non-local means, luma and chroma, 21 px search"),
    ("edge_enhancement", {"gain": 1.2, "radius_px": 1.2, "coring_dn": 2.0}, "luma, radius 1.2 px, soft coring"),
    ("edge_enhancement", {"gain": 1.2, "radius_px": 1.2, "coring_dn": 2.0, "coring": "hard", "channels": "rgb"},
     "R, G, B, radius 1.2 px, hard coring"),
)


def median_ms(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t))
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()

    import lowcam
    from lowcam.sample import sample_plate, sample_render

    rng = np.random.default_rng(0)
    frame = np.clip(rng.normal(120, 20, (480, 640, 3)), 0, 255).astype(np.uint8)
    footprint = np.ones((480, 640), bool)
    print("one delivered 640x480 frame, graphics over all of it (2 CPU threads)")
    print(f"{'stage':18s}{'settings':48s}{'median ms':>10s}")
    for name, values, about in STAGES:
        effect = lowcam.effects.effect_class(name)(**values)
        ms = median_ms(lambda: effect.finish(None, frame, footprint), args.repeats)
        print(f"{name:18s}{about:48s}{ms:10.1f}")
    # a shot's frame after the one before it (the recursive filter's step)
    before = np.clip(frame.astype(np.int16) + rng.integers(-6, 7, frame.shape), 0, 255).astype(np.uint8)
    effect = lowcam.effects.effect_class("temporal_noise_reduction")(strength=0.6, motion_threshold_dn=16.0)
    ms = median_ms(lambda: effect.finish_after(before, frame, footprint), args.repeats)
    print(f"{'temporal_nr':18s}{'strength 0.6, threshold 16 DN, after the frame before':48s}{ms:10.1f}")

    profile = lowcam.load_profile("fire-i")
    render, plate = sample_render(profile, 1280), sample_plate(profile)
    off = profile.with_effect("noise_reduction").with_effect("edge_enhancement")
    for e in ("noise_reduction", "edge_enhancement"):
        off.effect(e).enabled = False
    print("\nthe Fire-i frame, 1280x960 sample render -> 640x480 over the sample plate")
    rows = [("fire-i as bundled (the stages absent)", profile), ("the stages present, switched off", off),
            ("with noise_reduction (bilateral) on", profile.with_effect("noise_reduction", **STAGES[1][1])),
            ("with edge_enhancement on", profile.with_effect("edge_enhancement", **STAGES[4][1]))]
    times: dict = {about: [] for about, _ in rows}
    for about, p in rows:  # warm-up
        lowcam.simulate(render, p, plate, seed=0, frame=1)
    for _ in range(args.repeats):  # in turn, so that a busy machine slows every row alike
        for about, p in rows:
            t = time.perf_counter()
            lowcam.simulate(render, p, plate, seed=0, frame=1)
            times[about].append(1e3 * (time.perf_counter() - t))
    for about, _ in rows:
        print(f"{about:48s}{statistics.median(times[about]):10.1f}")
    with open("/proc/loadavg") as f:
        print(f"load average during the run: {f.read().split()[0]} (on {os.cpu_count()} cores)")

if __name__ == "__main__":
    main()
