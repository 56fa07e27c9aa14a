"""The images a compositor node group reads, as arrays (no bpy here): below the effects, which bake their own.

STMaps read pixel (x, y) (top-left origin, centres at integers) at ``u = (x + 0.5) / width``,
``v = 1 - (y + 0.5) / height``, mask 1. In the sensel mosaic, plane (i, j) of a channel with CFA offset (dy, dx)
sits at mosaic pixel (2 i + dy, 2 j + dx); a plane's row filter becomes a mosaic filter with zeros between its taps.
Images are top row first, as numpy holds them; :mod:`nodes.build` flips them for Blender.

Contents
--------
- :func:`stmap`: a Map UV image that reads pixel (x, y) of a ``width`` x ``height`` image
- :func:`mosaic_shape`: (rows, cols) of the sensel mosaic, borders included
- :func:`planes_to_mosaic`: interleave (4, hb, wb, ...) sensel planes into the (2 hb, 2 wb, ...) mosaic
- :func:`mosaic_kernel`: a row filter over one sensel plane as a (1, 2 taps - 1) filter over the mosaic
- :func:`gaussian_blur_kernel`: the 2-D kernel ``cv2.GaussianBlur(image, (0, 0), sigma)`` uses on float32 images
"""
from __future__ import annotations

import cv2
import numpy as np

from .geometry import CFA_CHANNELS


def stmap(x: np.ndarray, y: np.ndarray, width: int, height: int) -> np.ndarray:
    """An (rows, cols, 4) Map UV image that reads pixel (x, y) (top-left origin, centres at integers) of a
    ``width`` x ``height`` image: ``u = (x + 0.5) / width``, ``v = 1 - (y + 0.5) / height``, mask 1."""
    out = np.ones(np.shape(x) + (4,), np.float32)
    out[..., 0] = (np.asarray(x, np.float64) + 0.5) / width
    out[..., 1] = 1.0 - (np.asarray(y, np.float64) + 0.5) / height
    return out


def mosaic_shape(geometry) -> tuple[int, int]:
    hb, wb = geometry.bayer_shape
    return 2 * hb, 2 * wb


def planes_to_mosaic(planes: np.ndarray, geometry) -> np.ndarray:
    """Interleave (4, hb, wb, ...) sensel planes into the (2 hb, 2 wb, ...) mosaic, borders included: plane
    (i, j) of a channel with CFA offset (dy, dx) sits at mosaic pixel (2 i + dy, 2 j + dx)."""
    hm, wm = mosaic_shape(geometry)
    out = np.zeros((hm, wm) + planes.shape[3:], planes.dtype)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        out[dy::2, dx::2] = planes[k]
    return out


def mosaic_kernel(kernel: np.ndarray) -> np.ndarray:
    """A row filter over one sensel plane as a (1, 2 taps - 1) filter over the mosaic (zeros between)."""
    out = np.zeros(2 * len(kernel) - 1, np.float32)
    out[::2] = kernel
    return out[None]


def gaussian_blur_kernel(sigma: float) -> np.ndarray:
    """The 2-D kernel ``cv2.GaussianBlur(image, (0, 0), sigma)`` uses on float32 images."""
    size = int(round(sigma * 8 + 1)) | 1
    k = cv2.getGaussianKernel(size, sigma, cv2.CV_32F)
    return (k @ k.T).astype(np.float32)

