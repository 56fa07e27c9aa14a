"""Benchmark: the render files between Blender and Lowcam, by EXR compression and by reader.

Blender renders the sample scene through the add-on (Cycles, 16 samples, the passes a shot needs: the graphics'
Combined and Vector passes and the "Lowcam Overlay" layer, one part each, 32-bit float, ZIP) at three sizes: the
sample's 800x600, a full frame of 3000x2250 and an HD render of 3840x2160 (the 1920x1080 Fire-i of
``bench_frames.py``). Each render is then written again with the OpenEXR binding in every lossless compression
Blender offers (none, RLE, ZIPS, ZIP, PIZ): same parts, headers and channel bytes, checked.

For each file it prints the size and the median CPU and wall time of decoding it, with 1 and 2 decoding threads:
the OpenEXR binding reading every part (what Lowcam did before), OpenImageIO reading every part and the two parts a
shot needs, and Lowcam's own reader (:func:`lowcam.passes.read_render_and_passes`: decode, group, check) as a shot
calls it. CPU time is the process's (every thread's), from ``time.process_time``: on a shared machine it is far
steadier than wall time. The configurations take turns within each repeat, so a burst of load hits them alike.

    .venv/bin/python benchmarks/bench_codecs.py [--repeats 9] [--renders FOLDER] [--cases sample,full,hd]
        [--threads 1,2] [--readers OpenEXR]

``--renders FOLDER`` keeps the Blender renders there (made once, reused by later runs).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CASES = {"sample": 800, "full": 3000, "hd": 3840}
CODECS = ("NO", "RLE", "ZIPS", "ZIP", "PIZ")


def make_renders(folder: Path, cases) -> None:
    """Blender's ZIP renders of the sample scene, ``folder/CASE-ZIP.exr``, those not there yet."""
    todo = [c for c in cases if not (folder / f"{c}-ZIP.exr").exists()]
    if not todo:
        return
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_frames import hd_profile

    from lowcam_blender import submodule

    blend = folder / "scene" / "sample_scene.blend"
    if not blend.exists():
        submodule("addon.sample").build_sample_scene(blend.parent, render_width=CASES["sample"])
    for case in todo:
        scene = submodule("addon.render").open_scene(blend)
        if case == "hd":
            scene.lowcam.profile_file = str(hd_profile(folder, ROOT / "profiles"))
        scene.lowcam.render_codec = "ZIP"
        submodule("addon.frames").setup_scene(scene, CASES[case])
        scene.render.filepath = str(folder / f"{case}-ZIP.exr")
        t = time.perf_counter()
        submodule("addon.render").render_still(scene)
        print(f"{case}: Blender rendered {scene.render.resolution_x}x{scene.render.resolution_y} in "
              f"{time.perf_counter() - t:.0f} s", flush=True)


def parts_of(path: Path):
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return [(p.name(), dict(p.header), {n: np.array(c.pixels) for n, c in p.channels.items()}) for p in f.parts]


def reencode(src: Path, dst: Path, codec: str) -> None:
    """``src`` written again in ``codec``: the same parts, headers and channel bytes (checked)."""
    import OpenEXR

    parts = parts_of(src)
    out = [OpenEXR.Part({**{k: v for k, v in h.items() if k not in ("channels", "chunkCount", "name")},
                         "compression": getattr(OpenEXR, f"{codec}_COMPRESSION")}, dict(ch), name)
           for name, h, ch in parts]
    OpenEXR.File(out).write(str(dst))
    for (n1, _, c1), (n2, h2, c2) in zip(parts, parts_of(dst), strict=True):
        assert n1 == n2 and str(h2["compression"]).endswith(f".{codec}_COMPRESSION"), (n1, n2, h2["compression"])
        assert c1.keys() == c2.keys() and all(c1[k].tobytes() == c2[k].tobytes() for k in c1), n1


def encode_ms(path: Path, repeats: int = 3) -> float:
    """The median CPU time of writing ``path``'s parts again in its compression with the OpenEXR binding on one
    thread (what Blender's writing costs, by the same library)."""
    import OpenEXR

    OpenEXR.set_global_thread_count(0)
    parts = parts_of(path)
    times = []
    with tempfile.TemporaryDirectory() as scratch:
        for _ in range(repeats):
            out = [OpenEXR.Part({k: v for k, v in h.items() if k not in ("channels", "chunkCount", "name")},
                                dict(ch), name) for name, h, ch in parts]
            c = time.process_time()
            OpenEXR.File(out).write(str(Path(scratch) / path.name))
            times.append(time.process_time() - c)
    return float(np.median(times)) * 1e3


def decoders(path: Path, threads: int):
    """The decodes compared, each a function of no arguments."""
    import OpenEXR
    import OpenImageIO as oiio

    from lowcam.passes import read_render_and_passes

    def openexr_all():
        OpenEXR.set_global_thread_count(threads if threads > 1 else 0)
        with OpenEXR.File(str(path)) as f:
            return [c.pixels for part in f.parts for c in part.channels.values()]

    def oiio_parts(names):
        def read():
            oiio.attribute("threads", threads)
            inp = oiio.ImageInput.open(str(path))
            out, i = [], 0
            while inp.seek_subimage(i, 0):
                if names is None or inp.spec().get_string_attribute("oiio:subimagename") in names:
                    out.append(inp.read_image(i, 0, 0, inp.spec().nchannels, oiio.UNKNOWN))
                i += 1
            inp.close()
            return out
        return read

    def lowcam_shot():
        from lowcam import parallel
        import cv2

        cv2.setNumThreads(threads)
        assert parallel.threads() == threads
        return read_render_and_passes(path, None, ("Vector",), 24.0)

    def openexr_cold():
        """Every part from the disk: the file's pages are dropped from the page cache first."""
        fd = os.open(path, os.O_RDONLY)
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        os.close(fd)
        return openexr_all()

    runs = {"OpenEXR, every part": openexr_all, "OpenEXR, from disk": openexr_cold,
            "OpenImageIO, every part": oiio_parts(None),
            "OpenImageIO, Combined + Vector": oiio_parts({"ViewLayer.Combined", "ViewLayer.Vector"}),
            "lowcam read (shot)": lowcam_shot}
    return {k: v for k, v in runs.items() if oiio is not None or "OpenImageIO" not in k}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--renders", type=Path, default=None)
    parser.add_argument("--cases", default="sample,full,hd")
    parser.add_argument("--codecs", default=",".join(CODECS))
    parser.add_argument("--threads", default="1,2", help="decoding threads to run, e.g. 1")
    parser.add_argument("--readers", default="", help="only the readers whose name holds this text, e.g. OpenEXR")
    args = parser.parse_args()
    cases = args.cases.split(",")
    folder = args.renders or Path(tempfile.mkdtemp(prefix="lowcam-codecs-"))
    folder.mkdir(parents=True, exist_ok=True)
    make_renders(folder, cases)
    import cv2

    for case in cases:
        files = {}
        for codec in args.codecs.split(","):
            path = folder / f"{case}-{codec}.exr"
            if not path.exists():
                reencode(folder / f"{case}-ZIP.exr", path, codec)
            files[codec] = path
        counts = [int(n) for n in args.threads.split(",")]
        runs = {(codec, threads, name): fn for codec, path in files.items() for threads in counts
                for name, fn in decoders(path, threads).items() if args.readers in name}
        cpu = {k: [] for k in runs}
        wall = {k: [] for k in runs}
        for fn in runs.values():
            fn()   # warm: page cache, lens-free imports
        for _ in range(args.repeats):
            for key, fn in runs.items():
                t, c = time.perf_counter(), time.process_time()
                fn()
                wall[key].append(time.perf_counter() - t)
                cpu[key].append(time.process_time() - c)
        cv2.setNumThreads(cv2.getNumberOfCPUs())
        print(f"\n{case} ({folder / f'{case}-ZIP.exr'}), medians of {args.repeats}: size MB; CPU / wall ms with "
              f"{' and '.join(map(str, counts))} decoding threads")
        print("| codec | MB | reader | " + " | ".join(f"CPU {n} | wall {n}" for n in counts) + " |")
        print("|---|---|---|" + "---|---|" * len(counts))
        for codec, path in files.items():
            print(f"| {codec} | {path.stat().st_size / 1e6:.1f} | writing (OpenEXR, 1 thread) | "
                  f"{encode_ms(path):.0f} |" + " |" * (2 * len(counts) - 1))
            for name in (n for n in decoders(path, 1) if args.readers in n):
                cells = " | ".join(f"{np.median(cpu[(codec, n, name)]) * 1e3:.0f} | "
                                   f"{np.median(wall[(codec, n, name)]) * 1e3:.0f}" for n in counts)
                print(f"| {codec} | {path.stat().st_size / 1e6:.1f} | {name} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
