"""Benchmark: reading a render, by how it was written (OpenEXR codec and depth) and by OpenEXR's decoding threads.

The sample 3000x2250 RGBA render is written once per codec (as Blender offers them) in 32-bit and half float; each
file is read with :func:`lowcam.io.read_render` (the reading a shot does: decode, group, check). Prints the file
size and the median read time, and each against the 32-bit ZIP file that Blender writes by default, measured in the
same run. Half float keeps 11 significant bits, under the 6-bit quantisation at the chain's end by far; lossy codecs
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

    from lowcam.io import read_render
    from lowcam.sample import sample_render

    render = sample_render("fire-i", 3000)
    tmp = Path(tempfile.mkdtemp())
    cases = [(codec, depth) for codec in ("ZIP", "ZIPS", "PIZ", "RLE", "NO", "DWAA", "PXR24")
             for depth in ("float", "half")]
    rows = []
    for codec, depth in cases:
        path = tmp / f"{codec}-{depth}.exr"
        pixels = render.astype(np.float16 if depth == "half" else np.float32)
        header = {"compression": getattr(OpenEXR, f"{codec}_COMPRESSION"), "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGBA": pixels}).write(str(path))
        read_render(path)  # warm the page cache
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            read_render(path)
            times.append(time.perf_counter() - t)
        rows.append((codec, depth, path.stat().st_size / 1e6, float(np.median(times)) * 1e3))
        print(f"{codec:6s} {depth:5s} {rows[-1][2]:7.1f} MB  {rows[-1][3]:7.1f} ms", flush=True)
    base = next(r for r in rows if r[:2] == ("ZIP", "float"))
    print("\nagainst 32-bit ZIP (Blender's default):")
    for codec, depth, mb, ms in sorted(rows, key=lambda r: r[3]):
        print(f"  {codec:6s} {depth:5s} {mb / base[2]:5.2f}x the size, {ms / base[3]:5.2f}x the read time")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
