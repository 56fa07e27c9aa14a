"""Blender extension entry point. Blender imports this package; everything Blender-specific lives in ``addon/``.

The engine (``lowcam/``) is plain Python; this file only forwards ``register``/``unregister`` and imports nothing
from Blender at import time, so pytest and pip never trip over it. Outside Blender the same folder is the
package ``lowcam_blender`` (pyproject.toml), which the Blender-driving commands (``addon/commands.py``), the tests
and the scripts use through :func:`submodule`.
"""
import importlib

_registered = False


def submodule(name: str):
    """The module ``name`` of this package (``"addon.render"``, ``"nodes.asset"``), with the add-on registered
    with Blender once per process (outside Blender, where nothing else registers it)."""
    global _registered
    if not _registered:
        register()
        _registered = True
    return importlib.import_module(f"{__name__}.{name}")


def register():
    from .addon import register as _register

    _register()


def unregister():
    from .addon import unregister as _unregister

    _unregister()
