"""The UI, seen: screenshots of the add-on in Debian trixie's Blender 4.3 under Xvfb, written to docs/.

    python scripts/screenshots.py [OUT_DIR] [--match-only]      (as root; default docs/)

It builds the linux-x64 extension zip, installs it into a fresh user folder inside the trixie root
(``scripts/trixie-blender.sh`` builds the root once), builds the sample scene with the installed add-on, and runs
``scripts/screenshots_blender.py`` in the real binary under ``xvfb-run`` twice per shot: with the add-on and with it
disabled. Each picture is cropped with OpenCV to what the add-on adds (the panel, the nodes, the menu) and written
as ``lowcam-panel.png``, ``lowcam-compositor.png``, ``lowcam-group.png`` and ``lowcam-add-menu.png``. Then the
Match loop runs in the same Blender on a measurement set with a hidden tone curve (:func:`match_pictures`):
``lowcam-match-before.png``, ``lowcam-match-diagnosed.png`` and ``lowcam-match-added.png``.

The helpers here (:class:`Trixie`, :func:`build_zip`, :func:`install`, :func:`build_scene`, :func:`take`,
:func:`match_pictures`) are also what ``tests/test_blender_binary.py`` drives the root with.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
MODULE = "bl_ext.user_default.lowcam"
#: shot -> (X screen width, height): the Properties editor as tall and narrow as a sidebar, the compositor wide.
GEOMETRY = {"panel": (720, 1500), "compositor": (1600, 1000), "menu": (1600, 1000)}
#: the pictures each shot makes -> the docs/ file name
DOCS = {"panel": "lowcam-panel.png", "compositor": "lowcam-compositor.png", "group": "lowcam-group.png",
        "menu": "lowcam-add-menu.png"}
TIMES: dict[str, float] = {}
#: The Match loop's pictures -> the docs/ file name; its X screen (the Properties editor with the Match panel alone).
MATCH_DOCS = {"match-before": "lowcam-match-before.png", "match-diagnosed": "lowcam-match-diagnosed.png",
              "match-added": "lowcam-match-added.png"}
MATCH_GEOMETRY = (760, 2400)


class Unavailable(Exception):
    """The trixie root cannot be had here (not root, no mmdebstrap, no network): the reason, one line."""


class Trixie:
    """The Debian trixie root with Blender 4.3 (``scripts/trixie-blender.sh``): set up, run commands inside."""

    def __init__(self, root: Path | None = None):
        self.root = Path(root or os.environ.get("LOWCAM_TRIXIE_ROOT") or REPO / ".cache" / "trixie-root")

    def script(self, *args, timeout=1800, **kw) -> subprocess.CompletedProcess:
        env = dict(os.environ, LOWCAM_TRIXIE_ROOT=str(self.root))
        return subprocess.run(["bash", str(REPO / "scripts" / "trixie-blender.sh"), *args], env=env,
                              capture_output=True, text=True, timeout=timeout, **kw)

    def setup(self) -> str:
        """Build the root once (idempotent); returns Blender's version line or raises :class:`Unavailable`."""
        t0 = time.monotonic()
        r = self.script("--setup")
        TIMES.setdefault("setup_s", time.monotonic() - t0)
        if r.returncode == 77:
            raise Unavailable(r.stderr.strip().splitlines()[-1])
        if r.returncode != 0:
            raise RuntimeError(f"trixie-blender.sh --setup failed:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
        return r.stdout.strip()

    def run(self, *cmd, env: dict | None = None, timeout=900) -> subprocess.CompletedProcess:
        """``cmd`` inside the root (proc mounted), with a clean environment plus ``env``."""
        pairs = [f"{k}={v}" for k, v in (env or {}).items()]
        return self.script("--run", "env", *pairs, *cmd, timeout=timeout)

    def workdir(self) -> tuple[Path, str]:
        """A fresh folder inside the root: (its path here, its path inside the root)."""
        (self.root / "tmp").mkdir(exist_ok=True)
        host = Path(tempfile.mkdtemp(prefix="lowcam-", dir=self.root / "tmp"))
        return host, "/" + str(host.relative_to(self.root))

    def inside(self, path: Path) -> str:
        return "/" + str(Path(path).relative_to(self.root))


def build_zip(out_dir: Path, python: str = sys.executable) -> Path:
    """The linux-x64 extension zip, built by ``scripts/build_extension.py`` into ``out_dir``."""
    t0 = time.monotonic()
    r = subprocess.run([python, str(REPO / "scripts" / "build_extension.py"), str(out_dir), "--platform",
                        "linux-x64"], capture_output=True, text=True, timeout=1800, cwd=REPO)
    TIMES["build_zip_s"] = time.monotonic() - t0
    zips = sorted(Path(out_dir).glob("lowcam-*linux*x64*.zip")) or sorted(Path(out_dir).glob("lowcam-*.zip"))
    if not zips:            # the asset .blend built after the zips may fail on its own; the zip is what counts
        raise RuntimeError(f"build_extension.py made no zip:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
    return zips[-1]


INSTALL = """
import sys, addon_utils, bpy
bpy.ops.extensions.package_install_files(filepath=sys.argv[-1], repo="user_default", enable_on_install=True)
assert hasattr(bpy.types.Scene, "lowcam"), "the add-on did not register"
import lowcam
assert "extensions" in lowcam.__file__, lowcam.__file__
bpy.ops.wm.save_userpref()
print("INSTALLED", bpy.app.version_string, sys.version.split()[0], lowcam.__file__)
"""

SCENE = """
import sys
from bl_ext.user_default.lowcam.addon.sample import build_sample_scene
print("SCENE", build_sample_scene(sys.argv[-2], render_width=int(sys.argv[-1]), samples=8, frames=3))
"""


def blender(trixie: Trixie, user: str, *args, timeout=900) -> subprocess.CompletedProcess:
    return trixie.run("blender", *args, env={"BLENDER_USER_RESOURCES": user}, timeout=timeout)


def install(trixie: Trixie, work: Path, zip_path: Path) -> str:
    """Install ``zip_path`` with ``package_install_files`` into ``work``/user (saved user preferences, so every
    later Blender run with that folder has the add-on enabled); returns the user folder inside the root."""
    shutil.copy2(zip_path, work / zip_path.name)
    (work / "install.py").write_text(INSTALL)
    user = trixie.inside(work / "user")
    t0 = time.monotonic()
    r = blender(trixie, user, "-b", "--factory-startup", "--python", trixie.inside(work / "install.py"), "--",
                trixie.inside(work / zip_path.name))
    TIMES["install_s"] = time.monotonic() - t0
    if "INSTALLED" not in r.stdout:
        raise RuntimeError(f"installing {zip_path.name} in Blender failed:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
    return user


def build_scene(trixie: Trixie, work: Path, user: str, render_width: int = 400) -> Path:
    """The sample scene built by the installed add-on in the real binary; returns the .blend (path here)."""
    (work / "scene.py").write_text(SCENE)
    t0 = time.monotonic()
    r = blender(trixie, user, "-b", "--python", trixie.inside(work / "scene.py"), "--", trixie.inside(work / "scene"),
                str(render_width))
    TIMES["scene_s"] = time.monotonic() - t0
    blend = work / "scene" / "sample_scene.blend"
    if not blend.is_file():
        raise RuntimeError(f"building the sample scene failed:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
    return blend


def take(trixie: Trixie, work: Path, user: str, blend: Path, shot: str, addon: bool = True, extra=(),
         timeout: int = 300) -> dict[str, Path]:
    """Run ``shot`` in the real binary under Xvfb (``extra`` arguments after it); returns {picture name: PNG path
    here}."""
    out = work / f"shots-{shot}-{'on' if addon else 'off'}"
    script = work / "screenshots_blender.py"
    shutil.copy2(REPO / "scripts" / "screenshots_blender.py", script)
    w, h = MATCH_GEOMETRY if shot == "match" else GEOMETRY[shot]
    args = ["xvfb-run", "-a", "-s", f"-screen 0 {w}x{h}x24", "blender", "-p", "0", "0", str(w), str(h),
            trixie.inside(blend), "--python", trixie.inside(script), "--", trixie.inside(out), shot, *extra]
    t0 = time.monotonic()
    r = trixie.run(*args, *([] if addon else ["--no-addon"]), env={"BLENDER_USER_RESOURCES": user},
                   timeout=timeout)
    TIMES[f"shot_{shot}_{'on' if addon else 'off'}_s"] = time.monotonic() - t0
    if (out / "error.txt").exists():
        raise RuntimeError(f"screenshot {shot}: {(out / 'error.txt').read_text()}")
    pictures = {p.stem: p for p in out.glob("*.png")}
    if not pictures:
        raise RuntimeError(f"screenshot {shot} wrote nothing:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
    return pictures


def match_pictures(trixie: Trixie, work: Path, user: str, blend: Path) -> tuple[dict[str, Path], dict]:
    """The Match loop run in the real binary under Xvfb on a measurement set with a hidden tone curve (made here
    by ``lowcam synth``): ({picture name: PNG path here}, the numbers of ``match.json``)."""
    import json

    folder = work / "match-set"
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "lowcam.cli", "synth", "--add", "tone_curve:gamma=2.0", "--frames", "2",
                    "--width", "64", "-o", str(folder), "--force"], check=True, capture_output=True, timeout=600)
    TIMES["match_set_s"] = time.monotonic() - t0
    pictures = take(trixie, work, user, blend, "match", extra=[trixie.inside(folder)], timeout=900)
    return pictures, json.loads((work / "shots-match-on" / "match.json").read_text())


def changed_box(with_addon: np.ndarray, without: np.ndarray, threshold: int = 24):
    """(x0, y0, x1, y1) around the pixels that differ by more than ``threshold`` in some channel, or None."""
    diff = (np.abs(with_addon.astype(np.int16) - without.astype(np.int16)).max(axis=2) > threshold)
    ys, xs = np.nonzero(diff)
    if len(xs) == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def content_box(image: np.ndarray, header_px: int = 40, threshold: int = 24):
    """(x0, y0, x1, y1) around what differs from the editor's background colour (the most common one) below the
    header."""
    body = image[header_px:]
    colours, counts = np.unique(body.reshape(-1, 3), axis=0, return_counts=True)
    background = colours[counts.argmax()].astype(np.int16)
    ys, xs = np.nonzero(np.abs(body.astype(np.int16) - background).max(axis=2) > threshold)
    return int(xs.min()), int(ys.min()) + header_px, int(xs.max()) + 1, int(ys.max()) + 1 + header_px


def crop_for_docs(name: str, with_addon: np.ndarray, without: np.ndarray, margin: int = 30) -> np.ndarray:
    """The part of a screenshot the docs show: the panel with the window's top (its header and the Output tab's
    panels above it), or the nodes / menu with a margin; at most 1200 px wide."""
    import cv2

    h, w = with_addon.shape[:2]
    if name == "panel":
        box = changed_box(with_addon, without)
        crop = with_addon[:min(h, box[3] + margin)]
    elif name.startswith("match"):              # the Match panel alone: the window's top to the panel's end
        crop = with_addon[:min(h, content_box(with_addon)[3] + margin)]
    else:
        x0, y0, x1, y1 = content_box(with_addon)
        crop = with_addon[max(0, y0 - margin):min(h, y1 + margin), max(0, x0 - margin):min(w, x1 + margin)]
    if crop.shape[1] > 1200:
        scale = 1200 / crop.shape[1]
        crop = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return crop


def make_all(trixie: Trixie, work: Path, zip_path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every picture with and without the add-on: {name: (with, without)} as BGR arrays."""
    import cv2

    user = install(trixie, work, zip_path)
    blend = build_scene(trixie, work, user)
    pictures = {}
    for shot in GEOMETRY:
        on, off = take(trixie, work, user, blend, shot), take(trixie, work, user, blend, shot, addon=False)
        for name in on:
            pictures[name] = (cv2.imread(str(on[name])), cv2.imread(str(off[name])))
    return pictures


def main(argv=None) -> int:
    import cv2

    args = list(sys.argv[1:] if argv is None else argv)
    match_only = "--match-only" in args             # only the Match loop's pictures
    args = [a for a in args if a != "--match-only"]
    out = Path((args or [REPO / "docs"])[0])
    trixie = Trixie()
    try:
        print(trixie.setup())
    except Unavailable as e:
        print(f"screenshots: {e}", file=sys.stderr)
        return 77
    work, _ = trixie.workdir()
    try:
        zip_path = build_zip(work / "dist")
        if match_only:
            pictures = {}
            user = install(trixie, work, zip_path)
            blend = build_scene(trixie, work, user)
        else:
            pictures = make_all(trixie, work, zip_path)
            user, blend = trixie.inside(work / "user"), work / "scene" / "sample_scene.blend"
        match, numbers = match_pictures(trixie, work, user, blend)
        print(f"match: {numbers}")
        for name, path in match.items():
            image = cv2.imread(str(path))
            pictures[name] = (image, image)
        for name, (on, off) in pictures.items():
            path = out / {**DOCS, **MATCH_DOCS}[name]
            ok, data = cv2.imencode(".png", crop_for_docs(name, on, off), [cv2.IMWRITE_PNG_COMPRESSION, 9])
            tmp = path.with_suffix(".png.part")
            tmp.write_bytes(data.tobytes())
            os.replace(tmp, path)
            print(f"{path} ({len(data) // 1024} KB)")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(", ".join(f"{k} {v:.0f}" for k, v in TIMES.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
