"""The repository root is a Blender extension: Blender's own validator (shipped in the bpy wheel) accepts it."""
import subprocess
import sys
from pathlib import Path

import bpy
import pytest

pytestmark = pytest.mark.blender  # real bpy: the Blender tier

ROOT = Path(__file__).resolve().parent.parent


def blender_ext_cli() -> Path:
    site = Path(bpy.__file__).resolve().parents[4]  # .../bpy/5.0/scripts/modules/bpy/__init__.py -> .../bpy
    return site / "5.0" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"


def test_manifest_passes_blenders_validator():
    r = subprocess.run([sys.executable, str(blender_ext_cli()), "validate", str(ROOT)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr


INSTALL_SCRIPT = r'''
import sys, addon_utils, bpy
zip_path = sys.argv[-1]
module = "bl_ext.user_default.lowcam"
bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
assert module in {m.__name__ for m in addon_utils.modules()}, "not installed"
def registered():
    return (hasattr(bpy.types.Scene, "lowcam"), bpy.types.Node.bl_rna_get_subclass_py("LowcamCameraNode") is not None,
            hasattr(bpy.types, "LOWCAM_OT_apply"), any(h.__name__ == "on_render_write"
                                                       for h in bpy.app.handlers.render_write))
assert registered() == (True,) * 4, registered()
import lowcam
assert "site-packages" in lowcam.__file__ and "extensions" in lowcam.__file__, lowcam.__file__
for _ in range(2):
    addon_utils.disable(module)
    assert registered() == (False,) * 4, ("leftovers", registered())
    addon_utils.enable(module)
    assert registered() == (True,) * 4, registered()
scene = bpy.context.scene
scene.lowcam.profile = "ueye"
assert abs(scene.lowcam.exposure_s - __import__("lowcam").load_profile("ueye").camera.exposure_s) < 1e-6
tree = bpy.data.node_groups.new("C", "CompositorNodeTree")
node = tree.nodes.new("LowcamSharpeningNode")
assert node.node_tree is not None and node.sharpness == 80.0 and node.taps == 7
def kernel():
    image = next(n.image for n in node.node_tree.nodes if n.bl_idname == "CompositorNodeImage")
    return [round(x, 6) for x in image.pixels[:]]
before = kernel()
node.sharpness = 25.0                   # rebakes the kernel from the engine: a weaker centre tap
after = kernel()
assert len(after) == len(before) and after != before and max(after) < max(before), (before, after)
addon_utils.disable(module)
print("EXTENSION-OK")
'''


def test_extension_builds_installs_and_registers_twice(tmp_path):
    """The zip Blender's builder makes (with wheels) installs as a user installs it, enables, and registers and
    unregisters twice without leftovers; the engine comes from the bundled wheel."""
    import os

    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"), str(tmp_path / "dist")],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    zip_path = next((tmp_path / "dist").glob("lowcam-*.zip"))
    assert (tmp_path / "dist" / "lowcam-camera-fire-i.blend").stat().st_size > 1e6     # the node-group asset
    import zipfile

    names = zipfile.ZipFile(zip_path).namelist()
    assert any(n.startswith("wheels/lowcam-") for n in names) and any("opencv" in n for n in names)
    assert "addon/__init__.py" in names and "profiles/fire-i.toml" in names and not any(
        n.startswith("lowcam/") for n in names)
    script = tmp_path / "install.py"
    script.write_text(f"import bpy\nexec(compile({INSTALL_SCRIPT!r}, 'install', 'exec'))\n")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    env.pop("LOWCAM_PROFILE_PATH", None)
    # run from an empty folder, with the checkout off sys.path, so only the installed extension can be found
    r = subprocess.run([sys.executable, "-I", str(script), str(zip_path)], capture_output=True, text=True,
                       timeout=600, env=env, cwd=tmp_path)
    assert "EXTENSION-OK" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]
