"""Blender glue: properties, operators, panels, handlers and the compositor nodes; it reimplements nothing.

It calls the engine in ``lowcam``. The extension's root package holds ``addon/`` and ``nodes/``, and ships the
bundled ``profiles/``, which the engine finds through ``LOWCAM_PROFILE_PATH``.

Contents
--------
- :func:`register`: register the settings, operators, panels, render handlers and compositor nodes
- :func:`unregister`: unregister them, in reverse order

Modules: :mod:`.properties` (scene settings), :mod:`.preferences` (trusted plug-ins), :mod:`.operators`,
:mod:`.panels`, :mod:`.handlers` (render handlers), :mod:`.match` (the Match loop: estimate, compare, diagnose, add,
undo), :mod:`.jobs` (``lowcam`` commands in a child process, polled by a timer), :mod:`.frames` (scene to engine
inputs), :mod:`.motion` (camera motion), :mod:`.render` and :mod:`.commands` (command line), :mod:`.sample` (the
sample scene). What differs between Blender 4.2 LTS and 5.2 is the root's ``blender_compat``, below both ``addon/``
and ``nodes/``.
"""


def _modules():
    from . import handlers, match, operators, panels, preferences, properties
    from ..nodes import custom  # the extension's root package holds addon/ and nodes/

    return properties, operators, match, panels, handlers, custom, preferences


def _bundled_profiles():
    """The extension ships profiles/ beside addon/; the engine wheel finds them through LOWCAM_PROFILE_PATH."""
    import os
    from pathlib import Path

    folder = str(Path(__file__).resolve().parent.parent / "profiles")
    paths = [p for p in os.environ.get("LOWCAM_PROFILE_PATH", "").split(os.pathsep) if p]
    if folder not in paths and Path(folder).is_dir():
        os.environ["LOWCAM_PROFILE_PATH"] = os.pathsep.join(paths + [folder])


def register():
    import bpy

    _bundled_profiles()
    properties, operators, match, panels, handlers, custom, preferences = _modules()
    for cls in preferences.classes + properties.classes + operators.classes + match.classes + panels.classes:
        bpy.utils.register_class(cls)
    preferences.register()
    properties.register()
    match.register()
    handlers.register()
    custom.register()


def unregister():
    import bpy

    properties, operators, match, panels, handlers, custom, preferences = _modules()
    custom.unregister()
    handlers.unregister()
    match.unregister()
    properties.unregister()
    preferences.unregister()
    for cls in reversed(preferences.classes + properties.classes + operators.classes + match.classes
                        + panels.classes):
        bpy.utils.unregister_class(cls)
