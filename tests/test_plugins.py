"""Plug-in effects run only by consent: a profile that names ``module:Class`` imports nothing unless the user
trusted the module (``--plugin``, ``LOWCAM_PLUGINS``, :func:`lowcam.trust_plugins`).

The plug-in here is the harmful kind made harmless: importing it writes a marker file beside it (as ``antigravity``
opens a web browser), so a test sees whether its import-time code ran. Each case runs ``lowcam`` as a real process
with the plug-in's folder on ``PYTHONPATH`` and the profile on ``LOWCAM_PROFILE_PATH``.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import lowcam
from lowcam.effects import effect_class
from lowcam.errors import UntrustedPlugin

PLUGIN = '''
from pathlib import Path
Path(__file__).with_name("IMPORTED").write_text("the plug-in's import-time code ran")

from lowcam.effects import Effect, Param


class Veil(Effect):
    """A veil of light (a user's own effect)."""
    name = "veil"
    writes = "rgb"
    params = {"level": Param(0.0, low=0.0, high=1.0)}

    def apply(self, state):
        state.rgb += self.level
'''

PROFILE = '''[camera]
name = "A camera with a plug-in"
width = 640
height = 480

[[effect]]
type = "lens_distortion"

[[effect]]
type = "half_sampling"

[[effect]]
type = "bayer_sampling"

[[effect]]
type = "demosaic"

[[effect]]
type = "yuv_blend"

[[effect]]
type = "{type}"
'''


@pytest.fixture
def gravity(tmp_path):
    """A plug-in module ``gravity_fx`` that leaves a marker when imported, and a profile ``gravity`` naming it."""
    code = tmp_path / "code"
    code.mkdir()
    (code / "gravity_fx.py").write_text(PLUGIN)
    (code / "exits_fx.py").write_text("import sys\nsys.exit(0)\n")
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    (profiles / "gravity.toml").write_text(PROFILE.format(type="gravity_fx:Veil"))
    (profiles / "exits.toml").write_text(PROFILE.format(type="exits_fx:Veil"))
    return tmp_path


def lowcam_cli(folder: Path, *argv, env=None):
    environ = {k: v for k, v in os.environ.items() if k != "LOWCAM_PLUGINS"}
    path = os.pathsep.join(p for p in (str(folder / "code"), os.environ.get("PYTHONPATH", "")) if p)
    environ.update(PYTHONPATH=path, LOWCAM_PROFILE_PATH=str(folder / "profiles"), **(env or {}))
    return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, argv)], capture_output=True, text=True,
                          env=environ, cwd=folder, timeout=120)


def imported(folder: Path) -> bool:
    return (folder / "code" / "IMPORTED").exists()


def one_line(r) -> str:
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def test_listing_and_validating_a_profile_import_nothing_and_say_how_to_allow_it(gravity):
    r = lowcam_cli(gravity, "profiles")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("gravity "))
    assert "NEEDS PLUG-IN gravity_fx:Veil: allow it with --plugin gravity_fx or LOWCAM_PLUGINS=gravity_fx" in line
    assert any(x.startswith("fire-i ") and "INVALID" not in x for x in r.stdout.splitlines())
    r = lowcam_cli(gravity, "profiles", "gravity")
    assert r.returncode == 2
    message = one_line(r)
    assert message.startswith(f"lowcam profiles: error: {gravity / 'profiles' / 'gravity.toml'}: ")
    assert "names plug-in effect 'gravity_fx:Veil'" in message and "--plugin gravity_fx" in message
    r = lowcam_cli(gravity, "stages", "--profile", "gravity", "-o", gravity / "stages")
    assert r.returncode == 2 and "LOWCAM_PLUGINS=gravity_fx" in one_line(r)
    assert not imported(gravity) and not (gravity / "stages").exists()


@pytest.mark.parametrize("consent", [["--plugin", "gravity_fx", "profiles"], ["profiles", "--plugin", "gravity_fx"],
                                     ["--plugin", "studio", "--plugin", "gravity_fx", "profiles"]],
                         ids=["before", "after", "repeated"])
def test_plugin_option_gives_consent(gravity, consent):
    r = lowcam_cli(gravity, *consent)
    assert r.returncode == 0, r.stderr
    assert imported(gravity)
    line = next(x for x in r.stdout.splitlines() if x.startswith("gravity "))
    assert "A camera with a plug-in: 640x480, 6 effects" in line


@pytest.mark.parametrize("value", ["gravity_fx", f"studio,gravity_fx", f"studio{os.pathsep}gravity_fx",
                                   " gravity_fx , "], ids=["one", "comma", "pathsep", "spaces"])
def test_the_environment_variable_gives_consent(gravity, value):
    r = lowcam_cli(gravity, "profiles", "gravity", env={"LOWCAM_PLUGINS": value})
    assert r.returncode == 0, r.stderr
    assert imported(gravity) and "veil" in r.stdout


def test_a_package_trusts_its_modules_and_another_module_stays_untrusted(gravity):
    r = lowcam_cli(gravity, "--plugin", "gravity", "profiles", "gravity")  # a prefix of the name, not its package
    assert r.returncode == 2 and "--plugin gravity_fx" in one_line(r) and not imported(gravity)


@pytest.mark.parametrize("argv, option", [(["--plugin", "gravity-fx", "profiles"], "--plugin 'gravity-fx'"),
                                          (["profiles", "--plugin", "a..b"], "--plugin 'a..b'")])
def test_a_plugin_name_that_is_no_module_name_is_refused(gravity, argv, option):
    r = lowcam_cli(gravity, *argv)
    assert r.returncode == 2 and option in one_line(r) and "not a Python module name" in r.stderr


def test_a_bad_environment_variable_is_one_line(gravity):
    r = lowcam_cli(gravity, "profiles", "gravity", env={"LOWCAM_PLUGINS": "gravity_fx;rm -rf"})
    assert r.returncode == 2 and "LOWCAM_PLUGINS 'gravity_fx;rm -rf'" in one_line(r) and not imported(gravity)


def test_a_plugin_that_exits_on_import_does_not_end_diagnose_with_success(gravity):
    report = gravity / "d.json"
    r = lowcam_cli(gravity, "diagnose", gravity / "no-set", "--profile", "exits", "--json", report,
                   env={"LOWCAM_PLUGINS": "exits_fx"})
    assert r.returncode == 2
    assert "exits on import (sys.exit(0))" in one_line(r) and "exits_fx:Veil" in r.stderr
    assert not report.exists()
    # diagnose's own --plugin MODULE:CLASS is consent too, and loads the class before any work
    r = lowcam_cli(gravity, "diagnose", gravity / "no-set", "--plugin", "exits_fx:Veil", "--json", report)
    assert r.returncode == 2 and "exits on import" in one_line(r) and not report.exists()


def test_python_callers_trust_a_module_before_its_effects_load(gravity, monkeypatch):
    monkeypatch.syspath_prepend(str(gravity / "code"))
    monkeypatch.delenv("LOWCAM_PLUGINS", raising=False)
    monkeypatch.setattr(lowcam.effects, "TRUSTED", set())
    monkeypatch.setattr(lowcam.effects, "PLUGINS", {})
    profile = gravity / "profiles" / "gravity.toml"
    with pytest.raises(UntrustedPlugin) as e:
        lowcam.load_profile(profile)
    assert (e.value.effect_type, e.value.module) == ("gravity_fx:Veil", "gravity_fx")
    with pytest.raises(UntrustedPlugin):
        effect_class("gravity_fx:Veil")
    assert "gravity_fx" not in sys.modules and not imported(gravity)
    lowcam.trust_plugins("gravity_fx")
    try:
        assert lowcam.load_profile(profile).effects[-1].name == "veil" and imported(gravity)
    finally:
        sys.modules.pop("gravity_fx", None)


@pytest.mark.blender
def test_blender_preference_trusts_only_while_the_blend_may_run_scripts(gravity, monkeypatch):
    """The add-on's Trusted Plug-ins preference (real bpy): no import for a .blend opened without permission to run
    scripts (its script blocked, or Auto Run Python Scripts off); the import once the file may run scripts."""
    bpy = pytest.importorskip("bpy")
    from lowcam_blender import submodule

    preferences = submodule("addon.preferences")
    monkeypatch.syspath_prepend(str(gravity / "code"))
    monkeypatch.delenv("LOWCAM_PLUGINS", raising=False)
    monkeypatch.setattr(lowcam.effects, "TRUSTED", set())
    profile = gravity / "profiles" / "gravity.toml"
    blend = gravity / "with_script.blend"
    auto_run = bpy.context.preferences.filepaths.use_scripts_auto_execute
    try:
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)   # the preferences stay
        addons = bpy.context.preferences.addons
        entry = addons.get(preferences.ADDON_MODULE) or addons.new()   # the add-on as enabled in Preferences
        entry.module = preferences.ADDON_MODULE
        entry.preferences.trusted_plugins = "studio.effects, gravity_fx"
        script = bpy.data.texts.new("startup.py")
        script.write("print('a script of the .blend')\n")
        script.use_module = True                       # a script Blender asks about before running
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        bpy.context.preferences.filepaths.use_scripts_auto_execute = False
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        assert bpy.app.autoexec_fail
        with pytest.raises(UntrustedPlugin, match="Trusted Plug-ins preference"):
            lowcam.load_profile(profile)
        bpy.data.texts.remove(bpy.data.texts["startup.py"])
        bpy.ops.wm.save_mainfile()
        bpy.ops.wm.open_mainfile(filepath=str(blend))   # no script to block, but still no permission
        assert not bpy.app.autoexec_fail and preferences.blend_may_run_scripts() is not None
        with pytest.raises(UntrustedPlugin):
            lowcam.load_profile(profile)
        assert not imported(gravity) and "gravity_fx" not in sys.modules
        bpy.context.preferences.filepaths.use_scripts_auto_execute = True
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        assert preferences.blend_may_run_scripts() is None
        assert lowcam.load_profile(profile).effects[-1].name == "veil" and imported(gravity)
    finally:
        bpy.context.preferences.filepaths.use_scripts_auto_execute = auto_run
        addons = bpy.context.preferences.addons
        if addons.get(preferences.ADDON_MODULE) is not None:
            addons.remove(addons[preferences.ADDON_MODULE])
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        sys.modules.pop("gravity_fx", None)
        lowcam.effects.PLUGINS.pop("gravity_fx:Veil", None)
