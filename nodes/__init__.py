"""Compositor node groups built from Blender's built-in nodes only, from the same profiles as the engine.

Python-defined nodes crash the compositor at render time (see ../shared/notes/blender-5.md), so every pixel
operation is a built-in node; the maps and kernels come from :mod:`lowcam.node_maps`.

Contents
--------
- :mod:`nodes.build`: the "Lowcam Camera" node group, one node group per stage
- :mod:`nodes.custom`: the nodes in the compositor's Add menu (containers of built-in nodes)
- :mod:`nodes.asset`: the node group as an asset .blend
- :mod:`nodes.parity`: the node group against the engine, stage by stage
"""
