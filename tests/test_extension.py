"""The repository root is a Blender extension: Blender's own validator (shipped in the bpy wheel) accepts it."""
import subprocess
import sys
from pathlib import Path

import bpy

ROOT = Path(__file__).resolve().parent.parent


def blender_ext_cli() -> Path:
    site = Path(bpy.__file__).resolve().parents[4]  # .../bpy/5.0/scripts/modules/bpy/__init__.py -> .../bpy
    return site / "5.0" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"


def test_manifest_passes_blenders_validator():
    r = subprocess.run([sys.executable, str(blender_ext_cli()), "validate", str(ROOT)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr
