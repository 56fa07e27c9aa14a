"""The shape of the code: effects describe themselves, dependencies run one way (issue 13).

- The engine (``lowcam/``) imports nothing of the Blender side (``addon/``, ``nodes/``, ``bpy``), directly or by
  name, and has no import circle.
- Chain order, node stages and diagnosis candidates are derived from the effects' declarations, so a plug-in
  effect written outside the package shows up in the pipeline, the node bake and diagnosis without a table
  being edited (the claim of ``docs/adding-an-effect.md``).
"""
import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lowcam
from lowcam.effects import EFFECTS, canonical_order

ENGINE = Path(lowcam.__file__).resolve().parent


def engine_imports():
    """(module file, imported name) for every import statement in lowcam/, relative ones resolved."""
    for path in sorted(ENGINE.rglob("*.py")):
        package = ".".join(("lowcam",) + path.relative_to(ENGINE).parent.parts)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                yield from ((path, a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
                yield path, ".".join(base + ([node.module] if node.module else []))


def test_the_engine_never_imports_the_blender_side():
    bad = [(p.name, m) for p, m in engine_imports()
           if m.split(".")[0] in ("bpy", "addon", "nodes", "lowcam_blender", "bl_ext")]
    assert not bad, bad
    text = "\n".join(p.read_text() for p in ENGINE.rglob("*.py"))
    for name in ('"addon.', '"nodes.', "'addon.", "'nodes.", "lowcam_blender", "spec_from_file_location"):
        assert name not in text, f"lowcam/ names the Blender side: {name}"


def test_importing_the_engine_loads_no_blender_module():
    code = ("import sys, lowcam, lowcam.cli, lowcam.node_maps, lowcam.measure.diagnose; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('bpy', 'addon', 'nodes', 'lowcam_blender')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_effects_import_neither_the_pipeline_nor_the_profile():
    """The lens once asked the pipeline, which asked the profile, which asked the lens: a circle."""
    bad = [(p.name, m) for p, m in engine_imports()
           if p.parent.name == "effects" and m in ("lowcam.pipeline", "lowcam.profile")]
    assert not bad, bad


def test_every_bundled_effect_declares_its_place_and_the_order_is_derived():
    assert all(cls.order is not None for cls in EFFECTS.values())
    orders = [cls.order for cls in EFFECTS.values()]  # bundled ones: a test's plug-in may sit at any place
    assert len(set(orders)) == len(orders), "two effects share a place in the chain"
    order = canonical_order()
    # the paper's chain (sec. 5.2) in its order
    paper = ["lens_distortion", "crosstalk", "motion_blur", "chromatic_aberration", "spatial_blur",
             "bayer_sampling", "vignetting", "noise", "horizontal_blur", "sharpening", "quantisation", "demosaic",
             "saturation", "yuv_blend", "chroma_subsampling"]
    assert [n for n in order if n in paper] == paper
    for profile in ("fire-i", "ueye"):  # the bundled profiles list their effects in that order
        names = [e.name for e in lowcam.load_profile(profile).effects]
        assert names == sorted(names, key=order.index)


PLUGIN = '''
import numpy as np
from lowcam.effects import Effect, NodeStage, Param, Search


class Haze(Effect):
    """A uniform veil over the sensels: ``value + veil_dn * alpha`` (a user's own effect)."""

    name = "haze"
    writes = "bayer"
    order = 125                                   # after vignetting, before noise
    node = NodeStage("Haze", "mosaic", "kernel")  # built like a row filter
    searches = (Search("haze", "a veil of {veil_dn:.1f} DN", bounds={"veil_dn": (0.0, 40.0)}),)
    params = {"veil_dn": Param(0.0, low=0.0, high=255.0, unit="DN")}

    def kernel(self):
        return np.array([0.0, 1.0, 0.0], np.float32)

    def apply(self, state):
        state.bayer += np.float32(self.veil_dn) * state.bayer_alpha
'''


@pytest.fixture
def haze(tmp_path, monkeypatch):
    (tmp_path / "user_haze.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "user_haze")  # the user's consent
    yield "user_haze:Haze"
    sys.modules.pop("user_haze", None)
    lowcam.effects.PLUGINS.pop("user_haze:Haze", None)


def test_a_plugin_effect_goes_to_its_declared_place_and_runs(fire_i, haze):
    from helpers import flat_render

    profile = fire_i.with_effect(haze, veil_dn=20.0)
    names = [e.name for e in profile.effects]
    assert names.index("vignetting") + 1 == names.index("haze") == names.index("noise") - 1
    quiet = profile.without("noise")
    veiled = lowcam.run(flat_render(0.3, 800, 600), quiet, stop_after="haze").state.bayer
    clean = lowcam.run(flat_render(0.3, 800, 600), quiet.without("haze"), stop_after="vignetting").state.bayer
    inside = (slice(None), slice(40, -40), slice(40, -40))
    assert np.allclose(veiled[inside] - clean[inside], 20.0, atol=1e-3)


def test_a_plugin_effect_gets_a_node_stage_and_its_kernel_is_baked(fire_i, haze):
    from lowcam.node_maps import bake, node_stages

    b = bake(fire_i.with_effect(haze, veil_dn=5.0), (600, 800))
    assert node_stages()["haze"].label == "Haze" and "haze" in b.stages
    assert np.array_equal(b.images["haze_kernel"], np.array([[0, 0, 1, 0, 0]], np.float32))


def test_a_plugin_effect_is_a_diagnosis_candidate_and_is_found(tmp_path, fire_i, haze):
    from lowcam.effects import effect_class
    from lowcam.measure.diagnose import candidates, diagnose
    from lowcam.measure.sets import load_set
    from lowcam.measure.synth import synthesise

    effect_class(haze)
    assert "haze" in candidates()
    folder = synthesise(fire_i, tmp_path / "set", add=[(haze, {"veil_dn": 12.0})], frames=4,
                        only_scenes=("flat-dark", "photo"))
    d = diagnose(load_set(folder, fire_i), fire_i, only=["haze", "dsnu", "tone_curve"], workdir=tmp_path / "w")
    assert d.candidates[0].effect == "haze", [(c.effect, c.score) for c in d.candidates]
    assert abs(d.candidates[0].params["veil_dn"] - 12.0) < 1.0 and d.candidates[0].error_after <= 1.1


def test_every_engine_module_says_what_it_holds_and_effects_cite_the_paper():
    for path in sorted(ENGINE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        doc = ast.get_docstring(tree) or ""
        public = [n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))
                  and not n.name.startswith("_")]
        assert doc, f"{path} has no module docstring"
        missing = [n for n in public if f"`{n}`" not in doc]
        assert not missing, f"{path.name}'s docstring does not list {missing}"
        if path.parent.name == "effects" and path.name not in ("__init__.py", "base.py"):
            assert "[Klein2010]" in doc or "References" in doc, f"{path.name} cites nothing"
