"""Blender glue: properties, operators, panels, handlers and the compositor nodes. It calls the engine in
``lowcam``; it reimplements nothing."""


def _modules():
    from . import handlers, operators, panels, properties
    from ..nodes import custom  # the extension's root package holds addon/ and nodes/ (lowcam.extension)

    return properties, operators, panels, handlers, custom


def register():
    import bpy

    properties, operators, panels, handlers, custom = _modules()
    for cls in properties.classes + operators.classes + panels.classes:
        bpy.utils.register_class(cls)
    properties.register()
    handlers.register()
    custom.register()


def unregister():
    import bpy

    properties, operators, panels, handlers, custom = _modules()
    custom.unregister()
    handlers.unregister()
    properties.unregister()
    for cls in reversed(properties.classes + operators.classes + panels.classes):
        bpy.utils.unregister_class(cls)
