"""The add-on's preferences: the plug-in modules the user trusts in Blender.

A profile may name a plug-in effect (``"my_effects:Haze"``); importing its module runs code, and profiles travel
with .blend files. Blender asks before it runs a .blend's scripts, and the trusted plug-ins follow that answer: they
are trusted while no saved .blend is open, or while the open one may run scripts (Preferences > Save & Load > Auto
Run Python Scripts on, the file not in its excluded paths, and Blender did not block the file's scripts). Otherwise
a profile naming a plug-in is refused in one line and nothing is imported (:mod:`lowcam.effects`).

Contents
--------
- :data:`ADDON_MODULE`: the add-on's module name, the preferences' ``bl_idname``
- :class:`LowcamPreferences`: the Trusted Plug-ins preference
- :func:`blend_may_run_scripts`: why the open .blend may not run scripts, or None when it may
- :func:`trusted_by_preference`: the modules the preference trusts now (none while the .blend may not run scripts)
- :data:`classes`: the preference class, for registration
- :func:`register`: let the engine ask :func:`trusted_by_preference`
- :func:`unregister`: stop it asking
"""
from __future__ import annotations

import fnmatch

import bpy
from bpy.props import StringProperty

#: The add-on's module name (``bl_ext.user_default.lowcam``, or ``lowcam_blender`` outside Blender's add-on list).
ADDON_MODULE = __package__.rpartition(".")[0]


class LowcamPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_MODULE

    trusted_plugins: StringProperty(
        name="Trusted Plug-ins", default="",
        description="Python modules whose effects profiles may use, separated by commas (e.g. my_effects, "
                    "studio.effects). They are imported only for .blend files Blender allows to run scripts")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "trusted_plugins")
        why = blend_may_run_scripts()
        if why and self.trusted_plugins.strip():
            layout.label(text=f"Not used now: {why}", icon="ERROR")


def blend_may_run_scripts() -> str | None:
    """Why the open .blend may not run scripts (then no plug-in is trusted by preference), or None when it may."""
    if bpy.app.autoexec_fail:
        return "Blender blocked this .blend's scripts"
    path = bpy.data.filepath
    if not path:
        return None   # a new, unsaved file: nothing came from outside
    prefs = bpy.context.preferences
    if not prefs.filepaths.use_scripts_auto_execute:
        return "this .blend was opened without permission to run scripts (Auto Run Python Scripts is off)"
    for entry in prefs.autoexec_paths:   # the excluded paths, matched as Blender matches them
        pattern = bpy.path.abspath(entry.path) if entry.path else ""
        if pattern and (fnmatch.fnmatch(path.lower(), pattern.lower()) if entry.use_glob else
                        path.startswith(pattern)):
            return f"this .blend lies in an excluded path of Auto Run Python Scripts ({entry.path})"
    return None


def trusted_by_preference() -> list[str]:
    """The modules the Trusted Plug-ins preference names, while the open .blend may run scripts; else none."""
    entry = bpy.context.preferences.addons.get(ADDON_MODULE)
    prefs = getattr(entry, "preferences", None) if entry is not None else None
    if prefs is None or blend_may_run_scripts() is not None:
        return []
    return [name.strip() for name in prefs.trusted_plugins.replace(";", ",").split(",") if name.strip()]


classes = (LowcamPreferences,)


def register():
    from lowcam.effects import TRUST_PROVIDERS

    if trusted_by_preference not in TRUST_PROVIDERS:
        TRUST_PROVIDERS.append(trusted_by_preference)


def unregister():
    from lowcam.effects import TRUST_PROVIDERS

    while trusted_by_preference in TRUST_PROVIDERS:
        TRUST_PROVIDERS.remove(trusted_by_preference)
