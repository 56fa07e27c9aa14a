"""Blending in YUV and YUV 4:1:1 chroma (Klein & Murray 2010, sec. 5.2 steps 8-10)."""
from __future__ import annotations

import numpy as np

from .base import Effect, Param

#: Full-range BT.601 (JFIF) RGB -> YUV.
RGB_TO_YUV = np.array([[0.299, 0.587, 0.114],
                       [-0.168736, -0.331264, 0.5],
                       [0.5, -0.418688, -0.081312]], np.float64)
YUV_TO_RGB = np.linalg.inv(RGB_TO_YUV)


def rgb_to_yuv(rgb: np.ndarray) -> np.ndarray:
    return (rgb @ RGB_TO_YUV.T.astype(np.float32)).astype(np.float32)


def yuv_to_rgb(yuv: np.ndarray) -> np.ndarray:
    return (yuv @ YUV_TO_RGB.T.astype(np.float32)).astype(np.float32)


class YuvBlend(Effect):
    """Blends the rendered light into the video frame in YUV, each channel with its own alpha (step 8).

    The composite is ``video + delta`` with ``delta = rgb - alpha * video`` (premultiplied over), held in YUV.
    Arranging it as a difference keeps video pixels that no graphics touch bit-for-bit unchanged, which is the
    paper's stated aim for its rearranged blending.
    """

    name = "yuv_blend"
    section = "5.2 step 8"
    writes = "output"
    always_runs = True
    params = {}

    def apply(self, state):
        state.delta_yuv = rgb_to_yuv(state.rgb - state.rgb_alpha * state.plate)


class ChromaSubsampling(Effect):
    """YUV 4:1:1: U and V are box-averaged over groups of ``group`` horizontal pixels and recombined with the
    full-resolution Y without interpolation (steps 9-10).

    Only the graphics' contribution is squashed: the video already carries the camera's own 4:1:1 chroma.
    """

    name = "chroma_subsampling"
    section = "5.2 steps 9-10"
    writes = "output"
    params = {"group": Param(4, int, low=1, high=64)}

    def apply(self, state):
        d = state.delta_yuv
        h, w, _ = d.shape
        n = self.group
        pad = (-w) % n
        uv = np.pad(d[..., 1:], ((0, 0), (0, pad), (0, 0)), mode="edge") if pad else d[..., 1:]
        mean = uv.reshape(h, -1, n, 2).mean(axis=2)
        d[..., 1:] = np.repeat(mean, n, axis=1)[:, :w]
        state.chroma_group = n
