"""Blending in YUV and YUV 4:1:1 chroma (Klein & Murray 2010, sec. 5.2 steps 8-10).

The composite is ``video + delta`` with ``delta = rgb - alpha * video`` held in YUV, so video pixels no graphics
touch stay bit-for-bit unchanged (step 8). The graphics' chroma is then box-averaged over groups of 4 horizontal
pixels and recombined with the full-resolution Y without interpolation (steps 9-10). YUV is full-range BT.601
(JFIF): ``Y = 0.299 R + 0.587 G + 0.114 B``.

Contents
--------
- :data:`RGB_TO_YUV`: the full-range BT.601 (JFIF) RGB -> YUV matrix
- :data:`YUV_TO_RGB`: its inverse
- :func:`rgb_to_yuv`: (..., 3) RGB to YUV with BT.601 luma weights
- :func:`yuv_to_rgb`: its inverse
- :class:`YuvBlend`: blends the rendered light into the video frame in YUV, each channel with its own alpha
- :class:`ChromaSubsampling`: YUV 4:1:1: U and V box-averaged over ``group`` horizontal pixels (steps 9-10)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [ITU-R BT.601] ITU-R Recommendation BT.601, "Studio encoding parameters of digital television for standard 4:3 and
  wide-screen 16:9 aspect ratios" (the Y'CbCr luma and colour-difference weights).
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, NodeStage, Param, Search

#: Full-range BT.601 (JFIF) RGB -> YUV.
RGB_TO_YUV = np.array([[0.299, 0.587, 0.114],
                       [-0.168736, -0.331264, 0.5],
                       [0.5, -0.418688, -0.081312]], np.float64)
YUV_TO_RGB = np.linalg.inv(RGB_TO_YUV)


def rgb_to_yuv(rgb: np.ndarray) -> np.ndarray:
    return cv2.transform(np.ascontiguousarray(rgb, np.float32), RGB_TO_YUV.astype(np.float32))


def yuv_to_rgb(yuv: np.ndarray) -> np.ndarray:
    return cv2.transform(np.ascontiguousarray(yuv, np.float32), YUV_TO_RGB.astype(np.float32))


class YuvBlend(Effect):
    """Blends the rendered light into the video frame in YUV, each channel with its own alpha (step 8).

    The composite is ``video + delta`` with ``delta = rgb - alpha * video`` (premultiplied over), held in YUV.
    Arranging it as a difference keeps video pixels that no graphics touch bit-for-bit unchanged, which is the
    paper's stated aim for its rearranged blending.

    When an in-camera colour matrix ``S`` (saturation) follows demosaicing, the video is ``S`` applied to the light
    behind it, so ``delta = rgb - S (alpha * S^+ video)``: without this, channels with different alphas (at
    chromatic-aberration edges) would be mixed wrongly and leave dark fringes.
    """

    name = "yuv_blend"
    section = "5.2 step 8"
    writes = "output"
    order = 260
    node = NodeStage("YUV Blend", "rgb", "yuv_blend")
    always_runs = True
    params = {}

    def apply(self, state):
        behind = state.plate
        if state.colour_matrix is not None:
            behind = cv2.transform(behind, np.linalg.pinv(state.colour_matrix).astype(np.float32))
        covered = state.rgb_alpha * behind
        if state.colour_matrix is not None:
            covered = cv2.transform(covered, state.colour_matrix.astype(np.float32))
        state.delta_yuv = rgb_to_yuv(state.rgb - covered)


class ChromaSubsampling(Effect):
    """YUV 4:1:1: U and V are box-averaged over groups of ``group`` horizontal pixels and recombined with the
    full-resolution Y without interpolation (steps 9-10).

    Only the graphics' contribution is squashed: the video already carries the camera's own 4:1:1 chroma.
    """

    name = "chroma_subsampling"
    section = "5.2 steps 9-10"
    writes = "output"
    order = 270
    node = NodeStage("Chroma Subsampling", "yuv", "chroma_subsampling")
    searches = (Search("chroma_subsampling", "colour is shared by groups of {group} pixels horizontally",
                       grid={"group": (2, 4, 8)}, requires="yuv_blend"),)
    params = {"group": Param(4, int, low=1, high=64)}

    def apply(self, state):
        d = state.delta_yuv
        h, w = d.shape[:2]
        n = self.group
        if w % n:
            raise self.error(f"the frame width {w} is not a multiple of the chroma group {n}")
        y, u, v = cv2.split(d)
        # an exact n:1 box mean, then each mean repeated n times
        u, v = (cv2.resize(cv2.resize(c, (w // n, h), interpolation=cv2.INTER_AREA), (w, h),
                           interpolation=cv2.INTER_NEAREST) for c in (u, v))
        state.delta_yuv = cv2.merge([y, u, v])

    def finish(self, state, frame, footprint):
        """The footprint grows to whole chroma groups: they share the graphics' colour."""
        h, w = footprint.shape
        n = self.group
        return frame, np.repeat(footprint.reshape(h, w // n, n).any(axis=2), n, axis=1)
