"""Rolling shutter: rows exposed at different times while the camera turns (paper sec. 3, not simulated there).

Row ``v`` is exposed ``(v / H - 1/2) readout_s`` after the frame's middle row, so with the camera turning at
``w`` it sees the scene rotated by ``w t(v)``: the image skews and stretches (``readout_s``: the time from the
first row to the last; negative where the bottom row is read first, as Gyroflow writes a read-out from the bottom
up [Gyroflow]). The effect adds sampling offsets on the 24x18-cell grid to every sensel's position; for a
lens rendered through a fisheye, the rays are unit directions (at 90 deg and beyond too).

Contents
--------
- :class:`RollingShutter`: each row sees the scene rotated as at its own exposure time (``readout_s``)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Gyroflow] a negative ``frame_readout_time`` is a read-out from the bottom row up (``ReadoutDirection::BottomToTop``,
  ``src/core/gyro_source/mod.rs``), https://github.com/gyroflow/gyroflow.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import grid_points
from .base import Effect, Param, Search
from .motion_blur import direction_pixels, ray_directions


class RollingShutter(Effect):
    """Row ``v`` is exposed ``(v / H - 1/2) readout_s`` after the frame's middle row, so with the camera turning at
    ``w`` it sees the scene rotated by ``w t(v)``: the image skews and stretches. Implemented as extra sampling
    offsets on the 24x18-cell grid, added to every sensel's position."""

    name = "rolling_shutter"
    section = "3 (CMOS rolling shutter; not simulated in the paper)"
    writes = "sampling"
    order = 60
    searches = (Search("rolling_shutter", "moving captures skew as with a {readout_s:.4f} s row read-out",
                       bounds={"readout_s": (0.0, 0.1)}, captures="moving"),)
    params = {"readout_s": Param(0.0, low=-1.0, high=1.0, unit="s",
                                 doc="time from the first row to the last; negative: the bottom row is read first")}

    def apply(self, state):
        w = np.asarray(state.angular_velocity, np.float64)
        if not np.any(w) or self.readout_s == 0:
            return

        g = state.geometry
        u, v = grid_points(g.working_extent)
        t = (v / g.height - 0.5) * self.readout_s
        rot = np.stack([cv2.Rodrigues(w * tt)[0] for tt in t.ravel()]).reshape(t.shape + (3, 3))
        if state.profile.effect("lens_distortion").projection(g) != "pinhole":   # rays at 90 deg and beyond too
            u2, v2 = direction_pixels(state.lens, np.einsum("...ij,...j->...i", rot, ray_directions(state.lens, u, v)))
        else:
            x, y = state.lens.undistort(u, v)
            d = np.stack([x, y, np.ones_like(x)], -1)
            d2 = np.einsum("...ij,...j->...i", rot, d)
            u2, v2 = state.lens.distort(d2[..., 0] / d2[..., 2], d2[..., 1] / d2[..., 2])
        offset = np.stack([u2 - u, v2 - v], -1).astype(np.float32)
        state.sampling_offset = offset if state.sampling_offset is None else state.sampling_offset + offset
