"""The arrays the compositor node group needs, computed by the engine's own effect objects (no bpy here).

The node group reproduces :func:`lowcam.pipeline.run` stage by stage on the same grids:

- the supersampled working grid (lens distortion: a Map UV into the render),
- the working grid (half-sampling, crosstalk, spatial blur),
- the sensel mosaic, ``(2 rows, 2 cols)`` of the engine's sensel planes, borders included (Bayer sampling with
  chromatic aberration and motion taps, vignetting, noise, horizontal blur, sharpening, quantisation),
- the output frame (demosaicing, saturation, YUV blending, 4:1:1 chroma).

Everything that depends on the lens, the colour filter array or the camera motion is baked into images: Map UV
"STMaps" (normalised, origin bottom-left, third component 1), gain maps and convolution kernels
(:mod:`lowcam.node_images`). Images are returned top row first, as numpy holds them; :mod:`nodes.build` flips them
for Blender.

Which effects have a node, and how it is built, each effect declares (``Effect.node``,
:class:`lowcam.effects.NodeStage`), and each bakes what its node reads itself (``Effect.bake_node``): the generic
recipes (``kernel``, ``gain``, ``matrix``) from the effect's own ``kernel()``, ``gain_planes()`` and
``total_matrix()``, so a plug-in effect that declares one gets a node without changes here. Pure numpy: testable
without Blender.

Contents
--------
- :func:`node_stages`: effect name -> :class:`~lowcam.effects.NodeStage` of every effect with a node, in chain order
- :class:`CameraBake`: everything the node group reads, for one profile, render size and camera motion
- :func:`bake`: the images and values of every stage of a profile for a render of ``render_shape`` (rows, cols)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effects import known_effects
from .effects.base import plugin_failures
from .errors import LowcamError
from .pipeline import run
from .profile import load_profile


def node_stages() -> dict:
    """Effect name -> :class:`~lowcam.effects.NodeStage` of every known effect that has a compositor node, in
    chain order."""
    return {cls.name: cls.node for cls in known_effects() if cls.node is not None}


@dataclass
class CameraBake:
    """Everything the node group reads, for one profile, render size and camera motion."""

    profile: object
    render_shape: tuple[int, int]
    images: dict = field(default_factory=dict)      # name -> (rows, cols, 4) or (rows, cols) float32, top row first
    values: dict = field(default_factory=dict)      # name -> float or list of floats
    stages: list = field(default_factory=list)      # effect names the group contains, in order

    @property
    def geometry(self):
        return self.profile.geometry


def bake(profile="fire-i", render_shape=(1200, 1600), angular_velocity=(0.0, 0.0, 0.0),
         exposure_s: float | None = None) -> CameraBake:
    """Compute the images and values of every stage of ``profile`` for a render of ``render_shape`` (rows, cols).

    >>> b = bake("fire-i", (600, 800))
    >>> b.images["lens_uv"].shape, b.images["demosaic_uv_R"].shape
    ((1536, 2016, 4), (480, 640, 4))
    """
    profile = load_profile(profile)
    needs_passes = [e.name for e in profile.effects if e.enabled and e.needs_pass]
    if needs_passes:  # object motion, defocus from depth: the render handler's (Blender's Vector Blur, Defocus)
        profile = profile.without(*needs_passes)
    if profile.is_raw:
        raise LowcamError(f"{profile.source}: the compositor node group simulates YUV cameras; "
                          "use the engine (the add-on's render handler) for raw Bayer profiles")
    stages = [e.name for e in profile.effects if e.enabled or e.always_runs]
    declared = node_stages()
    unknown = [s for s in stages if s not in declared]
    if unknown:
        raise LowcamError(f"{profile.source}: the compositor node group has no node for {', '.join(unknown)}; "
                          "use the engine (the add-on's render handler) for this profile")
    dummy = np.zeros(tuple(render_shape) + (4,), np.float32)
    before = stages[stages.index("bayer_sampling") - 1]
    state = run(dummy, profile, None, angular_velocity, exposure_s, stop_after=before).state
    out = CameraBake(profile, tuple(render_shape), stages=stages)
    for name in stages:
        with plugin_failures(profile.effect(name)):
            profile.effect(name).bake_node(state, out)
    return out
