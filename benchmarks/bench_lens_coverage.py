"""Coverage: how many of the Gyroflow and lensfun calibrations ``lowcam profile from-gyroflow`` / ``from-lensfun``
import, and why the rest are refused.

Every ``.json`` file of Gyroflow's lens-profile database (a folder, or the ``.tar.xz`` of
https://github.com/gyroflow/lens_profiles; CC0) goes through :func:`lowcam.gyroflow.profile_from_gyroflow` with the
README's default base (``fire-i``), and every lens of lensfun's database (lensfunpy's bundled copy) through
:func:`lowcam.lensdb.profile_from_lensfun` at each focal length it has a calibration for (distortion, TCA or
vignetting). A refusal's reason is its message with the file, the lens and the numbers taken out. Prints one
table per database: imported, refused by reason, and the share of the files (lenses at a focal length) that hold a
calibration.

    .venv/bin/python benchmarks/bench_lens_coverage.py [DATABASE] [--base fire-i] [--only gyroflow|lensfun]

``DATABASE`` defaults to ``../shared/data/gyroflow-lens-profiles/lens_profiles.tar.xz`` beside the repository.
"""
from __future__ import annotations

import argparse
import collections
import json
import re
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATABASE = ROOT.parent / "shared" / "data" / "gyroflow-lens-profiles" / "lens_profiles.tar.xz"


def reason(message: str, where: str) -> str:
    """The refusal's reason: ``message`` without the file or lens it names and without its numbers."""
    text = message.replace(where, "FILE")
    text = re.sub(r"^FILE: ", "", text)
    text = re.sub(r"'[^']*\.json'|\S+\.json", "FILE", text)
    text = re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "#", text)
    return text[:110]


def holds_calibration(path: Path) -> bool:
    """Whether a Gyroflow file holds a calibration: JSON with a calibration frame and a camera matrix whose focal
    lengths are not zero."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    if not isinstance(doc, dict) or not isinstance(doc.get("calib_dimension"), dict):
        return False
    for p in (doc.get(k) for k in ("fisheye_params", "calib_params")):
        try:
            if float(p["camera_matrix"][0][0]) != 0 and float(p["camera_matrix"][1][1]) != 0:
                return True
        except (KeyError, IndexError, TypeError, ValueError):
            pass
    return False


def table(title: str, counts: collections.Counter, total: int, calibrated: int, seconds: float) -> None:
    ok = counts.pop("imported", 0)
    print(f"\n{title}: {total} tried, {calibrated} hold a calibration, {seconds:.0f} s")
    print(f"  {ok:6d}  imported ({100 * ok / max(calibrated, 1):.2f} % of those with a calibration)")
    for text, n in counts.most_common():
        print(f"  {n:6d}  refused: {text}")


def gyroflow(database: Path, base) -> None:
    from lowcam.errors import LowcamError
    from lowcam.gyroflow import profile_from_gyroflow

    with tempfile.TemporaryDirectory() as tmp:
        if database.is_file():
            with tarfile.open(database) as tar:
                tar.extractall(tmp, filter="data")
            folder = Path(tmp)
        else:
            folder = database
        files = sorted(folder.rglob("*.json"))
        counts, calibrated, start = collections.Counter(), 0, time.perf_counter()
        for path in files:
            has = holds_calibration(path)
            calibrated += has
            try:
                profile_from_gyroflow(path, base)
                counts["imported"] += 1
            except LowcamError as e:
                counts[reason(str(e), str(path)) + ("" if has else " [no calibration]")] += 1
        table(f"Gyroflow ({database})", counts, len(files), calibrated, time.perf_counter() - start)


def lensfun(base) -> None:
    from lowcam.errors import LowcamError
    from lowcam.lensdb import lens_entries, profile_from_lensfun

    counts, tried, start = collections.Counter(), 0, time.perf_counter()
    for entry in lens_entries():
        lens = entry.lens
        focals = sorted({float(c.focal) for cals in (lens.calib_distortion, lens.calib_tca, lens.calib_vignetting)
                         for c in cals})
        for focal in focals:
            tried += 1
            try:
                profile_from_lensfun(base, entry.maker, entry.model, focal, crop_factor=entry.crop_factor)
                counts["imported"] += 1
            except LowcamError as e:
                counts[reason(str(e), entry.name)] += 1
    table("lensfun (lenses at each calibrated focal length)", counts, tried, tried, time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("database", nargs="?", type=Path, default=DATABASE)
    parser.add_argument("--base", default="fire-i")
    parser.add_argument("--only", choices=("gyroflow", "lensfun"))
    args = parser.parse_args()

    from lowcam.profile import load_profile

    base = load_profile(args.base)
    if args.only != "lensfun":
        gyroflow(args.database, base)
    if args.only != "gyroflow":
        lensfun(base)


if __name__ == "__main__":
    main()
