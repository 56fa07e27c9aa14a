"""The shape of the code: effects describe themselves, dependencies run one way.

- The engine (``lowcam/``) imports nothing of the Blender side (``addon/``, ``nodes/``, ``bpy``), directly or by
  name.
- Every import, at module level or inside a function, runs down the layers of :data:`LAYERS` or within one layer,
  and no import circle closes, even through an import made at call time; the Blender side likewise
  (:data:`BLENDER_LAYERS`). No module hides an edge behind ``importlib`` with a name of its own package.
- Inside a function the engine imports only the packages of :data:`LAZY`, each for a reason given there.
- Chain order, node stages and diagnosis candidates are derived from the effects' declarations, so a plug-in
  effect written outside the package shows up in the pipeline, the node bake and diagnosis without a table
  being edited (the claim of ``docs/adding-an-effect.md``).
"""
import ast
import fnmatch
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lowcam
from lowcam.effects import EFFECTS, canonical_order

ENGINE = Path(lowcam.__file__).resolve().parent
ROOT = ENGINE.parent  # the repository: also the Blender extension's package (lowcam_blender)

#: The engine's layers, bottom to top (fnmatch patterns of module names; a package is its ``__init__``). A module
#: imports modules of its own layer or of the layers below, never above. The effects simulate and fit on arrays;
#: a fit that needs the whole chain receives it (``Context.simulate``, ``film``) from the layer that runs it.
LAYERS = (
    ("helpers", ("lowcam.errors", "lowcam.geometry", "lowcam.parallel", "lowcam.window", "lowcam.schema",
                 "lowcam.uncompressed_exr",
                 "lowcam.io", "lowcam.outputs", "lowcam.registration", "lowcam.reports", "lowcam.captures",
                 "lowcam.motion", "lowcam.gyro_logs", "lowcam.passes", "lowcam.chart", "lowcam.plate_estimate",
                 "lowcam.arguments", "lowcam.node_images", "lowcam.render_spaces", "lowcam.colour_checker", "lowcam.video")),
    ("effects", ("lowcam.effects", "lowcam.effects.*")),
    ("profile", ("lowcam.profile", "lowcam.dng", "lowcam.lensdb", "lowcam.gyroflow")),
    ("pipeline", ("lowcam", "lowcam.pipeline", "lowcam.node_maps", "lowcam.sample", "lowcam.scene",
                  "lowcam.batch")),
    ("measure", ("lowcam.measure.*", "lowcam.gyro_footage")),
    ("calibrate", ("lowcam.calibrate", "lowcam.calibrate.*")),
    ("cli", ("lowcam.cli", "lowcam.cli.*", "lowcam.boundary")),
)

#: The Blender side's layers, bottom to top, above the whole engine: what differs between Blender versions, the
#: compositor nodes, and the add-on with the extension's entry point (the repository root, ``lowcam_blender``,
#: whose ``submodule`` the add-on's commands use).
BLENDER_LAYERS = (
    ("compat", ("lowcam_blender.blender_compat",)),
    ("nodes", ("lowcam_blender.nodes", "lowcam_blender.nodes.*")),
    ("addon", ("lowcam_blender", "lowcam_blender.addon", "lowcam_blender.addon.*")),
)

#: The only packages the engine imports inside a function, and why (everything else is imported at the top of the
#: module, so that a module's imports say what it stands on). The Blender extension carries the engine's run-time
#: dependencies (``scripts/build_extension.py``: ``RUNTIME``); the heavy ones wait until a fit or a figure needs them,
#: so that enabling the add-on stays quick.
LAZY = {
    "OpenEXR": "never loaded beside an older libOpenEXRCore (Debian's Blender): lowcam.io then reads in a child",
    "PIL": "optional (pillow is no dependency): lowcam.gyro_footage's GIFs",
    "dask": "optional extra 'farm': lowcam batch --workers / --scheduler",
    "distributed": "optional extra 'farm'",
    "lensfunpy": "optional extra 'lensfun': lowcam profile from-lensfun",
    "matplotlib": "heavy (1-2 s to import): report figures, the chart's PDF",
    "scipy": "heavy (scipy.optimize, scipy.stats: 0.5-2 s): fits only",
    "colour": "heavy (colour-science: about 1 s to import): ColorChecker targets only",
    "colour_checker_detection": "heavy (imports colour-science): ColorChecker targets only",
    "av": "heavy (PyAV: about 0.6 s to import): a clip's frame rate, for --gyro CLIP only (lowcam.gyro_logs)",
    "telemetry_parser": "absent under Python 3.13 (no wheel; Blender 5.1's extension lacks it): --gyro CLIP only",
}


def _module_name(path: Path, top: Path, package: str) -> str:
    parts = (package,) + path.relative_to(top).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources(which: str) -> dict[str, Path]:
    """Module name -> file, for the engine (``"engine"``) or the Blender side (``"blender"``)."""
    if which == "engine":
        return {_module_name(p, ENGINE, "lowcam"): p for p in sorted(ENGINE.rglob("*.py"))}
    files = [*sorted(ROOT.glob("*.py")), *(p for d in ("addon", "nodes") for p in sorted((ROOT / d).rglob("*.py")))]
    return {_module_name(p, ROOT, "lowcam_blender"): p for p in files}


def _known() -> set[str]:
    return set(_sources("engine")) | set(_sources("blender"))


def _inside_function(tree: ast.AST) -> set[ast.AST]:
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            inside.update(n for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
    return inside


def module_imports(which: str = "engine"):
    """(module, imported module, line, inside a function) for every import statement of one side, relative ones
    resolved; ``from package import name`` is an edge to ``package.name`` where that is a module."""
    known = _known()
    for module, path in _sources(which).items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        tree = ast.parse(path.read_text())
        lazy = _inside_function(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    yield module, alias.name, node.lineno, node in lazy
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module
                targets = [f"{source}.{a.name}" for a in node.names if f"{source}.{a.name}" in known]
                for target in targets or [source]:
                    yield module, target, node.lineno, node in lazy


def engine_imports():
    """(module file, imported name) for every import statement in lowcam/, relative ones resolved."""
    files = _sources("engine")
    for module, target, _, _ in module_imports("engine"):
        yield files[module], target


def _layer(module: str, layers) -> int | None:
    found = [i for i, (_, patterns) in enumerate(layers) for pattern in patterns if fnmatch.fnmatchcase(module,
                                                                                                         pattern)]
    return found[0] if len(set(found)) == 1 else None


def _edges(which: str) -> dict[str, set[str]]:
    """Module -> the modules of the same side it imports (module level and inside functions)."""
    sources = _sources(which)
    out = {m: set() for m in sources}
    for module, target, _, _ in module_imports(which):
        if target in sources and target != module:
            out[module].add(target)
    return out


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph) + 100))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.mark.parametrize("which, layers", [("engine", LAYERS), ("blender", BLENDER_LAYERS)])
def test_every_module_has_one_layer(which, layers):
    unplaced = [m for m in _sources(which) if _layer(m, layers) is None]
    assert not unplaced, f"place these modules in exactly one layer of tests/test_architecture.py: {unplaced}"


@pytest.mark.parametrize("which, layers", [("engine", LAYERS), ("blender", BLENDER_LAYERS)])
def test_no_import_runs_up_a_layer(which, layers):
    """Module level or inside a function: an import made at call time is an edge all the same."""
    sources = _sources(which)
    up = sorted({f"{m} ({layers[_layer(m, layers)][0]}) -> {t} ({layers[_layer(t, layers)][0]}), line {line}"
                 f"{' inside a function' if lazy else ''}"
                 for m, t, line, lazy in module_imports(which)
                 if t in sources and _layer(m, layers) is not None and _layer(t, layers) is not None
                 and _layer(t, layers) > _layer(m, layers)})
    assert not up, "imports that run up a layer:\n" + "\n".join(up)


@pytest.mark.parametrize("which", ["engine", "blender"])
def test_no_import_circle_even_at_call_time(which):
    circles = _circles(_edges(which))
    assert not circles, "import circles (function-level imports included): " + "; ".join(
        " <-> ".join(c) for c in circles)


def test_the_engine_imports_inside_functions_only_what_must_load_late():
    late = sorted(f"{m}:{line}: {t}" for m, t, line, lazy in module_imports("engine")
                  if lazy and t.split(".")[0] not in LAZY)
    assert not late, (f"{len(late)} imports inside functions that belong at the top of their module (or, if it "
                      "must load late, in LAZY with the reason):\n" + "\n".join(late))


def test_no_module_hides_an_import_behind_importlib():
    """``importlib.import_module("lowcam....")`` (or ``__import__``) would be an edge no reading of the imports
    sees; plug-ins named by the user (``module:Class``) are imported so, never the engine's own modules."""
    hidden = []
    for which in ("engine", "blender"):
        for module, path in _sources(which).items():
            for node in ast.walk(ast.parse(path.read_text())):
                if not (isinstance(node, ast.Call) and node.args):
                    continue
                name = getattr(node.func, "attr", getattr(node.func, "id", ""))
                if name not in ("import_module", "__import__", "spec_from_file_location"):
                    continue
                arg = node.args[0]
                text = arg.value if isinstance(arg, ast.Constant) else (
                    arg.values[0].value if isinstance(arg, ast.JoinedStr) and arg.values
                    and isinstance(arg.values[0], ast.Constant) else "")
                if isinstance(text, str) and text.split(".")[0] in ("lowcam", "addon", "nodes", "lowcam_blender"):
                    hidden.append(f"{module}:{node.lineno}: {name}({text!r}...)")
    assert not hidden, hidden


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
from lowcam.plate_estimate import PlateEstimate, PlateProbe


def darkest(frames):
    return {"darkest_dn": float(np.percentile(frames, 0.5))}


def veil_from_plate(footage, base=None, film=None):
    low = darkest(np.stack([footage.frame(i) for i in range(len(footage))]))["darkest_dn"]
    return PlateEstimate("dark_floor", "haze", {"darkest_dn": low}, {"veil_dn": low}, 0.9,
                         f"the darkest pixels sit at {low:.1f} DN")


def fit_veil(ctx, effect):
    veil = max(float(np.median(np.stack(ctx.means) - np.stack(ctx.clean(ctx.profile)))), 0.0)
    return ctx.profile.with_effect(effect, veil_dn=veil), {"veil_dn": veil}, {"veil_dn": veil}


class Haze(Effect):
    """A uniform veil over the sensels: ``value + veil_dn * alpha`` (a user's own effect)."""

    name = "haze"
    writes = "bayer"
    order = 125                                   # after vignetting, before noise
    node = NodeStage("Haze", "mosaic", "kernel")  # built like a row filter
    searches = (Search("haze", "a veil of {veil_dn:.1f} DN", bounds={"veil_dn": (0.0, 40.0)}),
                Search("haze_closed_form", "a veil of {veil_dn:.1f} DN, the median offset", fit=fit_veil))
    plate_probe = PlateProbe("dark_floor", veil_from_plate, darkest, order=45, about="the darkest pixels")
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
    d = diagnose(load_set(folder, fire_i), fire_i, only=["haze", "haze_closed_form", "dsnu", "tone_curve"],
                 workdir=tmp_path / "w")
    assert d.candidates[0].effect in ("haze", "haze_closed_form"), [(c.effect, c.score) for c in d.candidates]
    assert abs(d.candidates[0].params["veil_dn"] - 12.0) < 1.0 and d.candidates[0].error_after <= 1.1
    closed = next(c for c in d.candidates if c.effect == "haze_closed_form")    # its own fit, from outside
    assert abs(closed.params["veil_dn"] - 12.0) < 1.5 and closed.error_after <= 1.1, closed


def test_a_plugin_effects_plate_probe_runs_in_its_place(fire_i, haze):
    """The plug-in's plate probe is found among the bundled ones, at its declared place (after the noise, before
    the fall-off), and the plate estimate applies what it measures to the plug-in effect."""
    from lowcam.effects import effect_class
    from lowcam.measure.plate import Footage, estimate_profile, plate_probes

    effect_class(haze)
    names = [p.name for p in plate_probes()]
    assert names.index("noise_level_function") + 1 == names.index("dark_floor") == names.index("radial_falloff") - 1
    frames = np.random.default_rng(1).normal(40.0, 2.0, (3, 48, 64, 3)).clip(0, 255).astype(np.float32)
    probe = next(p for p in plate_probes() if p.name == "dark_floor")
    assert probe.effect == "haze"
    profile, (estimate,) = estimate_profile(Footage(frames), fire_i, progress=False, probes=[probe])
    assert estimate.applied and abs(profile.effect("haze").veil_dn - np.percentile(frames, 0.5)) < 1e-3


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
