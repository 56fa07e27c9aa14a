"""Load the Blender side of Lowcam (``addon/``, ``nodes/``) from a source checkout, the way Blender loads the
extension: the repository root as one package (here ``lowcam_extension``). Imports no bpy itself."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from .errors import LowcamError

ROOT = Path(__file__).resolve().parent.parent
NAME = "lowcam_extension"


def load_extension():
    """The extension package (``.addon``, ``.nodes``), registered with Blender once per process."""
    if NAME in sys.modules:
        return sys.modules[NAME]
    if not (ROOT / "addon" / "__init__.py").is_file():
        raise LowcamError(f"{ROOT}: no addon/ here; Blender rendering needs a source checkout of Lowcam "
                          "(pip install -e .) or the Blender extension")
    spec = importlib.util.spec_from_file_location(NAME, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[NAME] = module
    spec.loader.exec_module(module)
    module.register()
    return module


def submodule(name: str):
    """``addon.render`` etc. of the loaded extension."""
    import importlib

    load_extension()
    return importlib.import_module(f"{NAME}.{name}")
