"""Blender glue: properties, operators, panels, handlers. It calls the engine in ``lowcam``; it reimplements
nothing. (The full add-on is the Blender issue; this registers cleanly so the extension installs.)"""

_classes = ()


def register():
    import bpy

    for cls in _classes:
        bpy.utils.register_class(cls)


def unregister():
    import bpy

    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
