"""Build the Blender extension zip: ``python scripts/build_extension.py [OUT_DIR]`` (default dist/).

The zip holds addon/, nodes/, profiles/, the manifest and the wheels the add-on needs at run time: Lowcam's
engine itself (built from pyproject.toml) and its imports that Blender lacks (OpenCV, OpenEXR, tomli-w), at the
versions installed in this environment. Blender's own builder (shipped in the bpy wheel) validates and zips it.
Beside the zip it writes the compositor node group as an asset .blend (``lowcam-camera-fire-i.blend``).
"""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RUNTIME = ("opencv-contrib-python-headless", "OpenEXR", "tomli-w")
SHIPPED = ("__init__.py", "blender_manifest.toml", "LICENSE", "README.md", "addon", "nodes", "profiles")


def blender_ext() -> Path:
    import bpy  # noqa: F401  (only to find the wheel's folder; the builder itself is plain Python)

    version_dir = next(p for p in Path(bpy.__file__).parents if p.name == "5.0")
    path = version_dir / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    if not path.is_file():
        sys.exit(f"build_extension: Blender's extension builder not found at {path}")
    return path


def pip(*args):
    subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", *args], check=True)


def build(out_dir: Path) -> Path:
    stage = Path(tempfile.mkdtemp(prefix="lowcam-extension-"))
    wheels = stage / "wheels"
    pip("wheel", "--no-deps", "-w", str(wheels), str(ROOT))
    pins = [f"{name}=={metadata.version(name)}" for name in RUNTIME]
    pip("download", "--no-deps", "--only-binary=:all:", "--python-version", "3.11", "--platform",
        "manylinux2014_x86_64", "--platform", "manylinux_2_17_x86_64", "--platform", "manylinux_2_28_x86_64",
        "-d", str(wheels), *pins)
    for name in SHIPPED:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, stage / name, ignore=shutil.ignore_patterns("__pycache__", "out"))
        elif src.exists():
            shutil.copy2(src, stage / name)
    listed = ", ".join(f'"./wheels/{w.name}"' for w in sorted(wheels.glob("*.whl")))
    manifest = (ROOT / "blender_manifest.toml").read_text()
    manifest = re.sub(r"(?m)^wheels\s*=.*$\n?", "", manifest)
    manifest = manifest.replace("\n[permissions]", f"\nwheels = [{listed}]\n\n[permissions]", 1)
    (stage / "blender_manifest.toml").write_text(manifest)
    out_dir.mkdir(parents=True, exist_ok=True)
    tool = blender_ext()
    subprocess.run([sys.executable, str(tool), "validate", str(stage)], check=True)
    subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(stage), "--output-dir", str(out_dir)],
                   check=True)
    shutil.rmtree(stage)
    zips = sorted(out_dir.glob("lowcam-*.zip"), key=lambda p: p.stat().st_mtime)
    return zips[-1]


def build_asset(out_dir: Path, profile: str = "fire-i") -> Path:
    """The node group as an asset .blend beside the zip (``lowcam node-asset`` with its defaults)."""
    sys.path.insert(0, str(ROOT))
    from lowcam_blender import submodule

    return submodule("nodes.asset").write_asset(out_dir / f"lowcam-camera-{profile}.blend", profile)


if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "dist").resolve()
    print(build(out))
    print(build_asset(out))
