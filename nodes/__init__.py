"""Compositor node groups built from Blender's built-in nodes only, from the same profiles as the engine
(Python-defined nodes crash the compositor at render time; see ../shared/notes/blender-5.md)."""
