"""Defocus from depth: each point spreads over the disc its distance from the focus plane gives it.

This goes beyond the paper, whose fixed-focus camera is sharp at its working distances (Fig. 15 lists depth of
field as a drawback). A thin lens with entrance pupil ``A`` focused at ``s`` images a point at depth ``z`` as a
disc subtending ``A |1/z - 1/s|`` radians, so its radius in render pixels is ``0.5 A |1/z - 1/s| f_px``.

Contents
--------
- :data:`RADIUS_LEVELS`: disc radii (render px) of the layers a varying blur is blended from
- :func:`blur_radius_px`: radius (px) of the blur disc of points at ``depth_m``: ``0.5 A |1/z - 1/s| f_px``
- :func:`scatter_discs`: spread each pixel of a premultiplied image over a disc of its own radius
- :class:`DepthOfField`: defocus blur that grows with the distance from the focus plane (needs a depth pass)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param
from .blur import level_weights
from .defocus import disc_kernel

#: Disc radii (render px) of the layers a varying blur is blended from.
RADIUS_LEVELS = [0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 11.0, 16.0, 22.0, 32.0, 45.0, 64.0]


def blur_radius_px(depth_m: np.ndarray, focus_distance_m: float, aperture_mm: float, focal_px: float):
    """Radius (px) of the blur disc of points at ``depth_m``: ``0.5 A |1/z - 1/s| f_px``."""
    return 0.5 * aperture_mm * 1e-3 * np.abs(1.0 / depth_m - 1.0 / focus_distance_m) * focal_px


def scatter_discs(image: np.ndarray, radius_px: np.ndarray) -> np.ndarray:
    """Spread each pixel of premultiplied ``image`` over a disc of its own ``radius_px`` (H, W).

    The radii are split between the two nearest of :data:`RADIUS_LEVELS` with linear weights; each layer is
    convolved with its disc and the layers are summed, so what a pixel gives away is conserved. Occlusion is
    not modelled: a blurred background spreads over a sharp foreground too.
    """
    radius = np.minimum(radius_px, RADIUS_LEVELS[-1]).astype(np.float32)
    weights = level_weights(radius, RADIUS_LEVELS)
    out = np.zeros_like(image)
    for r, w in zip(RADIUS_LEVELS, weights):
        if not w.any():
            continue
        layer = image * w[..., None]
        out += layer if r == 0 else cv2.filter2D(layer, -1, disc_kernel(r), borderType=cv2.BORDER_CONSTANT)
    return out


class DepthOfField(Effect):
    """Defocus blur that grows with the distance from the focus plane (needs a depth pass: Blender's Z pass
    through the add-on or ``lowcam render``)."""

    name = "depth_of_field"
    section = "beyond the paper (Fig. 15: depth of field)"
    writes = "render"
    order = 10
    needs_pass = "depth"
    params = {
        "focus_distance_m": Param(2.0, low=0.01, high=1e4, unit="m", doc="distance of the sharp plane"),
        "aperture_mm": Param(1.0, low=0.0, high=200.0, unit="mm",
                             doc="entrance pupil diameter: focal length / f-number"),
    }

    def apply(self, state):
        depth = state.render_pass(self)
        if self.aperture_mm > 0:
            radius = blur_radius_px(depth, self.focus_distance_m, self.aperture_mm, state.render_focal_px())
            state.render = scatter_discs(state.render, radius)
