"""Benchmark: a full diagnosis of the standard ``lowcam synth`` set (its speed target: 10 s median).

Makes the standard set (Fire-i, every bundled scene, 5 frames, a tone curve of gamma 2.0 hidden), then diagnoses
it with every candidate ``--repeats`` times. Prints the median total, the median and range per candidate
(screening, fitting and error together) and the number of noise-free and noisy capture simulations; then, as the
baseline in the same run, the median total with the candidates fitted one at a time (``WORKERS = 1``); and the
command line's wall time and peak memory (``lowcam diagnose SET --json``, a fresh process each run, imports
included), its wall time beside the in-process figure.

    .venv/bin/python benchmarks/bench_diagnose.py [--repeats 3]

With ``--hidden-sets`` it times instead the diagnosis of each held-out case of ``tests/test_diagnose.py`` (the
standard set, 6 frames of every scene, with one candidate's effect hidden, every candidate ranked) and prints
each time and the median.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path


#: ``lowcam`` run as its command line, writing its peak memory (kB) to ``argv[1]`` as it exits. The process's own
#: ``VmHWM``: ``ru_maxrss`` would count the parent too (a child started by vfork records the parent's peak at exec).
CLI_WITH_PEAK = """
import atexit, re, runpy, sys
peak_file = sys.argv.pop(1)
def record():
    with open("/proc/self/status") as f, open(peak_file, "w") as out:
        out.write(re.search(r"VmHWM:\\s+(\\d+)", f.read()).group(1))
atexit.register(record)
sys.argv[0] = "lowcam"
runpy.run_module("lowcam.cli", run_name="__main__")
"""


def hidden_sets() -> None:
    """Each standard-set case of ``tests/test_diagnose.py``, diagnosed once: its time, the median of all."""
    import importlib.util

    import lowcam
    from lowcam.measure.diagnose import diagnose
    from lowcam.measure.sets import load_set
    from lowcam.measure.synth import synthesise

    spec = importlib.util.spec_from_file_location("cases", Path(__file__).resolve().parents[1] / "tests" /
                                                  "test_diagnose.py")
    cases = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cases)
    fire_i, times = lowcam.load_profile("fire-i"), []
    names = [c for c in cases.HIDDEN if c not in cases.NOT_ON_THE_STANDARD_SET]
    for k, name in enumerate(names):
        add, remove, diagnosed = cases.hidden_case(fire_i, name)
        with tempfile.TemporaryDirectory() as tmp:
            folder = synthesise(fire_i, Path(tmp) / "set", add=add, seed=100 + len(name), frames=6)
            profile = diagnosed or (fire_i.without(*remove) if remove else fire_i)
            mset = load_set(folder, profile)
            started = time.perf_counter()
            d = diagnose(mset, profile, workdir=Path(tmp) / "work")
            times.append(time.perf_counter() - started)
        print(f"[{k + 1}/{len(names)}] {name:32s} {times[-1]:6.1f} s  {d.summary()}", flush=True)
    print(f"\ndiagnoses of {len(times)} held-out sets: median {statistics.median(times):.1f} s (min {min(times):.1f}, "
          f"max {max(times):.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--hidden-sets", action="store_true",
                        help="time the diagnosis of each held-out case of tests/test_diagnose.py instead")
    args = parser.parse_args()
    if args.hidden_sets:
        hidden_sets()
        return

    import lowcam
    import lowcam.measure.diagnose as diagnosis
    import lowcam.measure.compare as comparison
    from lowcam.measure.diagnose import diagnose
    from lowcam.measure.sets import load_set
    from lowcam.measure.synth import synthesise

    counts = defaultdict(int)
    prepare, resume = comparison.prepare, comparison.resume  # the chain as diagnosis calls it

    def counted(name, fn):
        def wrapper(*a, **k):
            counts[name] += 1
            return fn(*a, **k)
        return wrapper

    comparison.prepare, comparison.resume = counted("chain fronts", prepare), counted("chain tails", resume)
    profile = lowcam.load_profile("fire-i")
    with tempfile.TemporaryDirectory() as tmp:
        folder = synthesise(profile, Path(tmp) / "set", add=[("tone_curve", {"gamma": 2.0})], frames=5)
        mset = load_set(folder, profile)
        totals, per = [], defaultdict(list)
        for k in range(args.repeats):
            counts.clear()
            started = time.perf_counter()
            d = diagnose(mset, profile)
            totals.append(time.perf_counter() - started)
            for c in d.candidates:
                per[c.effect].append(c.seconds)
            print(f"run {k + 1}: {totals[-1]:.1f} s, {d.summary()}; simulations: "
                  + ", ".join(f"{n} {v}" for n, v in counts.items()), flush=True)
        walls, peaks = [], []
        peak_file = Path(tmp) / "peak"
        for _ in range(args.repeats):
            started = time.perf_counter()
            subprocess.run([sys.executable, "-c", CLI_WITH_PEAK, str(peak_file), "diagnose", str(folder), "--profile",
                            "fire-i", "--json", str(Path(tmp) / "d.json")], check=True, capture_output=True)
            walls.append(time.perf_counter() - started)
            peaks.append(int(peak_file.read_text()) / 1024)
        workers, diagnosis.WORKERS = diagnosis.WORKERS, 1
        serial = []
        for _ in range(args.repeats):
            started = time.perf_counter()
            diagnose(mset, profile)
            serial.append(time.perf_counter() - started)
        diagnosis.WORKERS = workers
    print(f"\ndiagnosis of the standard synth set ({len(per)} candidates): median {statistics.median(totals):.1f} s "
          f"(min {min(totals):.1f}, max {max(totals):.1f}) over {len(totals)} runs, {workers} candidates at a time")
    ratio = statistics.median(totals) / statistics.median(serial)
    print(f"one candidate at a time, same run: median {statistics.median(serial):.1f} s "
          f"(min {min(serial):.1f}, max {max(serial):.1f}); ratio {ratio:.2f}")
    print(f"the command line (lowcam diagnose, imports included): median {statistics.median(walls):.1f} s wall "
          f"(min {min(walls):.1f}, max {max(walls):.1f}), peak memory {max(peaks):.0f} MB")
    print("per candidate (screening, fitting and error together): median (min-max) over the runs")
    for name, times in sorted(per.items(), key=lambda kv: -statistics.median(kv[1])):
        print(f"  {name:32s} {statistics.median(times):6.2f} s  ({min(times):.2f}-{max(times):.2f})")


if __name__ == "__main__":
    main()
