"""Benchmark: reading a render, by how it was written (OpenEXR codec and depth) and by OpenEXR's decoding threads.

The sample 3000x2250 RGBA render is written once per codec (as Blender offers them) in 32-bit and half float; each
file is read with :func:`lowcam.io.read_render` (the reading a shot does: decode, group, check). Prints the file
size and the median read time (wall and CPU), and each against the 32-bit ZIP file that Blender writes by default,
measured in the same run. ``NO*`` is the uncompressed file read by the OpenEXR binding, as before Lowcam read such
files itself (:mod:`lowcam.uncompressed_exr`). Half float keeps 11 significant bits, under the 6-bit quantisation at the chain's end by far; lossy codecs
(DWAA, DWAB, B44, PXR24) are listed for their speed, not recommended for linear data.

    .venv/bin/python benchmarks/bench_exr.py [--repeats 7]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    import OpenEXR

    import lowcam.io
    from lowcam.io import read_render

    uncompressed = lowcam.io.read_uncompressed_exr
    from lowcam.sample import sample_render

    render = sample_render("fire-i", 3000)
    tmp = Path(tempfile.mkdtemp())
    cases = [(codec, depth) for codec in ("ZIP", "ZIPS", "PIZ", "RLE", "NO", "NO*", "DWAA", "PXR24")
             for depth in ("float", "half")]
    rows = []
    for codec, depth in cases:
        path = tmp / f"{codec.rstrip('*')}-{depth}.exr"
        pixels = render.astype(np.float16 if depth == "half" else np.float32)
        header = {"compression": getattr(OpenEXR, f"{codec.rstrip('*')}_COMPRESSION"), "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGBA": pixels}).write(str(path))
        # NO*: the uncompressed file read by the OpenEXR binding, as before Lowcam read such files itself
        lowcam.io.read_uncompressed_exr = (lambda *a, **k: None) if codec == "NO*" else uncompressed
        read_render(path)  # warm the page cache
        times = []
        for _ in range(args.repeats):
            t, c = time.perf_counter(), time.process_time()
            read_render(path)
            times.append((time.perf_counter() - t, time.process_time() - c))
        wall, cpu = np.median(times, axis=0) * 1e3
        rows.append((codec, depth, path.stat().st_size / 1e6, float(wall), float(cpu)))
        print(f"{codec:6s} {depth:5s} {rows[-1][2]:7.1f} MB  {wall:7.1f} ms  CPU {cpu:7.1f} ms", flush=True)
    lowcam.io.read_uncompressed_exr = uncompressed
    base = next(r for r in rows if r[:2] == ("ZIP", "float"))
    print("\nagainst 32-bit ZIP (Blender's default):")
    for codec, depth, mb, ms, cpu in sorted(rows, key=lambda r: r[3]):
        print(f"  {codec:6s} {depth:5s} {mb / base[2]:5.2f}x the size, {ms / base[3]:5.2f}x the read time, "
              f"{cpu / base[4]:5.2f}x its CPU")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
