"""Build the Blender extension, one zip per platform: ``python scripts/build_extension.py [OUT_DIR] [--platform P]``.

Each zip (``lowcam-<version>-<platform>.zip``, default OUT_DIR dist/) holds addon/, nodes/, blender_compat.py,
profiles/, the manifest and the wheels the add-on needs at run time for that platform and for every Python the
supported Blenders embed (3.11 for Blender 4.2-5.0, 3.13 for 5.1 and later): Lowcam's engine itself (built from
pyproject.toml, pure Python) and what it imports at run time that Blender lacks (:data:`RUNTIME`), with everything those
require on that platform and Python (read from their installed metadata, :func:`runtime_pins`), at the versions
installed in this environment. numpy comes with Blender and is not bundled. Blender's own builder (``blender_ext.py build
--split-platforms``, shipped in the bpy wheel) validates the manifest, keeps each platform's wheels and zips.

Downloaded wheels are kept in build/wheel-cache/ (git-ignored): a rebuild asks pip only for what is missing there.
Beside the zips it writes the compositor node group as an asset .blend (``lowcam-camera-fire-i.blend``).

Bad input is one line on stderr and exit status 2: an unknown platform, or a dependency with no wheel for a
platform and Python.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.tags import compatible_tags, cpython_tags, mac_platforms
from packaging.utils import canonicalize_name, parse_wheel_filename

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "build" / "wheel-cache"
#: What the engine imports at run time (the loop's fits, plots, progress and DNG tags included): their own
#: requirements are added by :func:`runtime_pins`.
RUNTIME = ("opencv-contrib-python-headless", "OpenEXR", "tomli-w", "scipy", "matplotlib", "tqdm", "tifffile",
           "rapidfuzz", "colour-science", "colour-checker-detection", "av")
#: Requirements another runtime wheel provides (the same ``cv2`` module): never bundled beside it.
PROVIDED = {"opencv-python": "opencv-contrib-python-headless"}
#: Every Blender embeds these: never bundled.
WITH_BLENDER = {"numpy"}
SHIPPED = ("__init__.py", "blender_compat.py", "blender_manifest.toml", "LICENSE", "README.md", "addon", "nodes",
           "profiles")
#: The Pythons the supported Blenders embed: 3.11 (4.2 LTS to 5.0) and 3.13 (5.1 and later).
PYTHONS = ((3, 11), (3, 13))
#: Blender platform -> the wheel platform tags that run there, best first. The oldest systems are Blender's own
#: minimums: glibc 2.28 (Linux), macOS 11 (4.2 LTS; OpenCV's current wheels need macOS 13).
PLATFORMS = {
    "windows-x64": ["win_amd64"],
    "macos-arm64": list(mac_platforms((14, 0), "arm64")),
    "macos-x64": list(mac_platforms((14, 0), "x86_64")),
    "linux-x64": [f"manylinux_2_{minor}_x86_64" for minor in range(28, 16, -1)] + ["manylinux2014_x86_64"],
}


class BuildError(Exception):
    """A one-line reason the build cannot go on."""


def supported_tags(platform: str, python: tuple[int, int]) -> set:
    """The wheel tags a CPython ``python`` on Blender platform ``platform`` installs."""
    if platform not in PLATFORMS:
        raise BuildError(f"unknown platform {platform!r}: choose from {', '.join(PLATFORMS)}")
    plats = PLATFORMS[platform]
    return set(cpython_tags(python, platforms=plats)) | set(compatible_tags(python, platforms=plats))


#: Blender platform -> the environment markers of its requirements (PEP 508) that differ between platforms.
MARKERS = {
    "windows-x64": {"sys_platform": "win32", "platform_system": "Windows", "os_name": "nt", "platform_machine": "AMD64"},
    "macos-arm64": {"sys_platform": "darwin", "platform_system": "Darwin", "os_name": "posix",
                    "platform_machine": "arm64"},
    "macos-x64": {"sys_platform": "darwin", "platform_system": "Darwin", "os_name": "posix",
                  "platform_machine": "x86_64"},
    "linux-x64": {"sys_platform": "linux", "platform_system": "Linux", "os_name": "posix", "platform_machine": "x86_64"},
}


def runtime_pins(platform: str, python: tuple[int, int]) -> list[tuple[str, str | None]]:
    """``(name, version)`` of :data:`RUNTIME` and everything it requires on ``platform`` under ``python``, extras
    left out and numpy left to Blender. The version is the one installed here; ``None`` for a requirement of another
    platform that this environment lacks (colorama on Windows), which then takes the newest wheel."""
    environment = default_environment() | MARKERS[platform] | {
        "python_version": f"{python[0]}.{python[1]}", "python_full_version": f"{python[0]}.{python[1]}.0",
        "implementation_name": "cpython", "platform_python_implementation": "CPython", "extra": ""}
    pins, todo = {}, list(RUNTIME)
    while todo:
        name = canonicalize_name(todo.pop())
        if name in pins or name in WITH_BLENDER or name in PROVIDED:
            continue
        try:
            pins[name], requires = metadata.version(name), metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            pins[name], requires = None, []
        for text in requires:
            requirement = Requirement(text)
            if requirement.marker is None or requirement.marker.evaluate(environment):
                todo.append(requirement.name)
    return sorted(pins.items())


def cached_wheel(name: str, version: str | None, platform: str, python: tuple[int, int]) -> Path | None:
    """A wheel of ``name==version`` (the newest when ``version`` is None) in the cache that installs on
    ``platform`` under ``python``."""
    want = supported_tags(platform, python)
    found = []
    for path in sorted(CACHE.glob("*.whl")):
        wheel_name, wheel_version, _, tags = parse_wheel_filename(path.name)
        if wheel_name == canonicalize_name(name) and version in (None, str(wheel_version)) and tags & want:
            found.append((wheel_version, path))
    return max(found)[1] if found else None


def fetch_wheel(name: str, version: str | None, platform: str, python: tuple[int, int]) -> Path:
    """The cached wheel of ``name==version`` for ``platform`` and ``python``, downloaded first if missing."""
    found = cached_wheel(name, version, platform, python)
    if found is not None:
        return found
    CACHE.mkdir(parents=True, exist_ok=True)
    py = f"{python[0]}.{python[1]}"
    plats = [arg for p in PLATFORMS[platform] for arg in ("--platform", p)]
    r = subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "download", "--no-deps",
                        "--only-binary=:all:", "--python-version", py, "--implementation", "cp", *plats,
                        "-d", str(CACHE), f"{name}=={version}" if version else name], capture_output=True, text=True)
    found = cached_wheel(name, version, platform, python)
    if r.returncode != 0 or found is None:
        raise BuildError(f"no wheel of {name}=={version or 'any version'} for {platform} and Python {py} (pip download failed; "
                         f"pin another version of {name} or leave the platform out with --platform)")
    return found


def blender_ext() -> Path:
    """Blender's extension command line (``blender_ext.py``) in the installed bpy wheel, whatever its version."""
    import bpy  # noqa: F401  (only to find the wheel's folder; the builder itself is plain Python)

    version_dir = next((p for p in Path(bpy.__file__).parents if re.fullmatch(r"\d+\.\d+", p.name)), None)
    path = version_dir / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py" if version_dir else None
    if path is None or not path.is_file():
        raise BuildError(f"Blender's extension builder not found beside {bpy.__file__}")
    return path


def manifest_with(manifest: str, platforms, wheels) -> str:
    """The manifest text with its ``platforms`` and ``wheels`` lists replaced."""
    manifest = re.sub(r"(?m)^(wheels|platforms)\s*=.*$\n?", "", manifest)
    listed = ", ".join(f'"./wheels/{w}"' for w in wheels)
    plats = ", ".join(f'"{p}"' for p in platforms)
    return manifest.replace("\n[permissions]", f'\nplatforms = [{plats}]\nwheels = [{listed}]\n\n[permissions]', 1)


def run(*args):
    """Run a command; its last output line becomes a :class:`BuildError` when it fails."""
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if r.returncode != 0:
        tail = (r.stdout + r.stderr).strip().splitlines()[-1:] or ["no output"]
        raise BuildError(f"{Path(str(args[1])).name} {args[2]} failed: {tail[0]}")
    return r.stdout


def build(out_dir: Path, platforms=tuple(PLATFORMS)) -> list[Path]:
    """Build one zip per Blender platform in ``platforms`` into ``out_dir``; return their paths."""
    for p in platforms:
        supported_tags(p, PYTHONS[0])                       # unknown platform: an error before any work
    wheels = {fetch_wheel(name, version, p, py) for p in platforms for py in PYTHONS
              for name, version in runtime_pins(p, py)}
    stage = Path(tempfile.mkdtemp(prefix="lowcam-extension-"))
    try:
        (stage / "wheels").mkdir()
        run(sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "wheel", "--no-deps", "-w",
            stage / "wheels", ROOT)
        for w in wheels:
            shutil.copy2(w, stage / "wheels" / w.name)
        for name in SHIPPED:
            src = ROOT / name
            if src.is_dir():
                shutil.copytree(src, stage / name, ignore=shutil.ignore_patterns("__pycache__", "out"))
            elif src.exists():
                shutil.copy2(src, stage / name)
        names = sorted(w.name for w in (stage / "wheels").glob("*.whl"))
        manifest = manifest_with((ROOT / "blender_manifest.toml").read_text(), platforms, names)
        (stage / "blender_manifest.toml").write_text(manifest)
        out_dir.mkdir(parents=True, exist_ok=True)
        tool = blender_ext()
        run(sys.executable, tool, "validate", stage)
        run(sys.executable, tool, "build", "--split-platforms", "--source-dir", stage, "--output-dir", out_dir)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    version = re.search(r'(?m)^version\s*=\s*"([^"]+)"', manifest).group(1)
    zips = [out_dir / f"lowcam-{version}-{p.replace('-', '_')}.zip" for p in platforms]
    missing = [z.name for z in zips if not z.is_file()]
    if missing:
        raise BuildError(f"Blender's builder did not write {', '.join(missing)} in {out_dir}")
    return zips


def build_asset(out_dir: Path, profile: str = "fire-i") -> Path:
    """The node group as an asset .blend beside the zips (``lowcam node-asset`` with its defaults)."""
    sys.path.insert(0, str(ROOT))
    from lowcam_blender import submodule

    return submodule("nodes.asset").write_asset(out_dir / f"lowcam-camera-{profile}.blend", profile)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default=str(ROOT / "dist"))
    ap.add_argument("--platform", action="append", dest="platforms",
                    help=f"build only this platform (repeatable): {', '.join(PLATFORMS)}")
    ap.add_argument("--no-asset", action="store_true", help="skip the node-group asset .blend")
    args = ap.parse_args(argv)
    out = Path(args.out_dir).resolve()
    try:
        for z in build(out, tuple(args.platforms or PLATFORMS)):
            print(z)
    except BuildError as e:
        print(f"build_extension: {e}", file=sys.stderr)
        return 2
    if not args.no_asset:
        print(build_asset(out))
    return 0


if __name__ == "__main__":
    status = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)            # the bpy 4.2 module can crash while the interpreter exits, after the work is done
