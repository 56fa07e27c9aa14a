"""Blender extension entry point. Blender imports this package; everything Blender-specific lives in ``addon/``.

The engine (``lowcam/``) is plain Python; this file only forwards ``register``/``unregister`` and imports nothing
from Blender at import time, so pytest and pip never trip over it.
"""


def register():
    from .addon import register as _register

    _register()


def unregister():
    from .addon import unregister as _unregister

    _unregister()
