"""Spatial noise reduction of a camera's image processor: luma and chroma filtered apart (not in the paper).

Today's phones, action cameras and webcams smooth the frame before they deliver it: white sensor noise becomes
blotchy, low-pass noise, and fine texture of low contrast is wiped while edges stay. The stage filters the
delivered frame's full-range BT.601 luma with ``luma_strength_dn`` and its chroma with ``chroma_strength_dn``
(:mod:`~lowcam.effects.delivered_frame`), with one of two edge-preserving filter families, both OpenCV's:

- ``bilateral`` [Tomasi1998]: ``cv2.bilateralFilter``, range sigma = the strength (DN), spatial sigma =
  ``scale_px``, over a window of ``2 ceil(2 scale_px) + 1`` px;
- ``nl_means`` [Buades2005]: ``cv2.fastNlMeansDenoising``, filter parameter ``h`` = the strength (DN), 7x7
  patches compared over a search window of ``2 round(scale_px) + 1`` px (chroma: both planes as one
  two-channel image).

A strength of 0 leaves that part of the frame as it is. The processed frame replaces the delivered one only where
the graphics reach (the plate already went through the camera's filter).

Contents
--------
- :data:`METHODS`: the filter families
- :func:`denoise_plane`: one plane (or a two-channel stack) filtered by a family at a strength and scale
- :func:`denoise_frame`: an RGB frame's luma and chroma filtered apart
- :func:`fit_noise_reduction`: diagnosis's fit: the family, strengths and scale whose filtered noisy model frames
  best match the measured frames' means and noise (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`NoiseReduction`: the stage

It has no compositor node: Blender's compositor has no non-local-means filter, and its Bilateral Blur node
(iterated 3x3 passes with a determinator image) is not OpenCV's bilateral filter, so the node group could not
give the engine's frame; ``lowcam.node_maps.bake`` refuses a profile with it, and the render handler, which runs
the engine, simulates it.

References
----------
- [Tomasi1998] C. Tomasi and R. Manduchi, "Bilateral filtering for gray and color images", Proc. ICCV 1998,
  839-846.
- [Buades2005] A. Buades, B. Coll and J.-M. Morel, "A non-local algorithm for image denoising", Proc. CVPR 2005,
  vol. 2, 60-65 (OpenCV's fastNlMeansDenoising: the same with integral images over the search window).
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 YCbCr).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .base import Effect, Param, Search
from .delivered_frame import fit_delivered_stage, processed_by, to_ycc, within_footprint, ycc_change_to_rgb

#: The filter families: OpenCV's bilateral filter and its fast non-local means.
METHODS = ("bilateral", "nl_means")


def _window(method: str, scale_px: float) -> int:
    """The filter's window (px, odd): the bilateral's kernel, the non-local means' search window."""
    if method == "bilateral":
        return 2 * math.ceil(2 * scale_px) + 1
    return 2 * max(int(round(scale_px)), 1) + 1


def denoise_plane(plane: np.ndarray, method: str, strength_dn: float, scale_px: float) -> np.ndarray:
    """``plane`` (H, W) or (H, W, 2) float32 (DN; chroma centred on 0) filtered by ``method`` at ``strength_dn``
    (the bilateral's range sigma, the non-local means' ``h``) and ``scale_px`` (see the module's docstring),
    float32. The non-local means reads 8-bit values: the plane is rounded (chroma offset by 128) and the filter's
    change added to it."""
    plane = np.asarray(plane, np.float32)
    if strength_dn <= 0:
        return plane
    window = _window(method, scale_px)
    if method == "bilateral":
        if plane.ndim == 3:
            return np.dstack([cv2.bilateralFilter(np.ascontiguousarray(plane[..., k]), window, strength_dn,
                                                  scale_px, borderType=cv2.BORDER_REFLECT_101)
                              for k in range(plane.shape[2])])
        return cv2.bilateralFilter(plane, window, strength_dn, scale_px, borderType=cv2.BORDER_REFLECT_101)
    offset = 0.0 if plane.ndim == 2 else 128.0
    q = np.clip(np.rint(plane + offset), 0, 255).astype(np.uint8)
    out = cv2.fastNlMeansDenoising(np.ascontiguousarray(q), None, float(strength_dn), 7, window)
    return plane + (out.astype(np.float32) - q)


def denoise_frame(frame: np.ndarray, method: str, luma_strength_dn: float, chroma_strength_dn: float,
                  scale_px: float) -> np.ndarray:
    """An (H, W, 3) uint8 RGB frame with its luma filtered at ``luma_strength_dn`` and its chroma (Cb, Cr) at
    ``chroma_strength_dn`` (:func:`denoise_plane`), the changes taken back to RGB, rounded (uint8)."""
    ycc = to_ycc(frame)
    change = np.zeros_like(ycc)
    if luma_strength_dn > 0:
        change[..., 0] = denoise_plane(ycc[..., 0], method, luma_strength_dn, scale_px) - ycc[..., 0]
    if chroma_strength_dn > 0:
        change[..., 1:] = denoise_plane(ycc[..., 1:], method, chroma_strength_dn, scale_px) - ycc[..., 1:]
    out = frame.astype(np.float32) + ycc_change_to_rgb(change)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def fit_noise_reduction(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): for each family, the luma strength on a coarse grid at the
    family's usual scale, no chroma; for the family that fits best, the luma strength finer, the scale, the chroma
    strength and each finer again (:func:`~lowcam.effects.delivered_frame.fit_delivered_stage`). While diagnosis
    screens: the bilateral family's coarse grid only (it shows whether smoothing helps; the non-local means costs
    5-10 times as much)."""
    finer = lambda key, f: (lambda v: [min(max(v[key] * k, 0.0), 60.0) for k in f])  # noqa: E731
    searches = []
    for method in METHODS:
        scales = (1.0, 1.5, 2.0, 3.0) if method == "bilateral" else (3.0, 5.0, 10.0)
        coarse = [("luma_strength_dn", (3.0, 8.0, 20.0, 45.0))]
        plan = [("luma_strength_dn", finer("luma_strength_dn", (0.6, 0.78, 1.0, 1.28, 1.65))),
                ("scale_px", scales),
                ("luma_strength_dn", finer("luma_strength_dn", (0.85, 0.93, 1.0, 1.08, 1.17))),
                ("chroma_strength_dn", (0.0, 5.0, 12.0, 30.0)),
                ("chroma_strength_dn", finer("chroma_strength_dn", (0.7, 1.0, 1.4))),
                ("scale_px", lambda v: [min(max(v["scale_px"] * k, 0.5), 12.0) for k in (0.85, 1.0, 1.18)]),
                ("luma_strength_dn", finer("luma_strength_dn", (0.95, 1.0, 1.05)))]
        usual = 2.0 if method == "bilateral" else 5.0
        start = {"method": method, "luma_strength_dn": 8.0, "chroma_strength_dn": 0.0, "scale_px": usual}
        searches.append((start, plan, coarse))
    return fit_delivered_stage(ctx, effect, processed_by(NoiseReduction), searches)


class NoiseReduction(Effect):
    """Spatial noise reduction of the delivered frame: its luma filtered at ``luma_strength_dn`` and its chroma at
    ``chroma_strength_dn`` by an edge-preserving filter of the family ``method`` and spatial ``scale_px``
    (OpenCV's ``bilateralFilter`` or ``fastNlMeansDenoising``; see the module's docstring)."""

    name = "noise_reduction"
    section = "not in the paper"
    writes = "output"
    order = 272
    searches = (Search("noise_reduction", "noise smoothed and fine texture wiped: {method} filter, luma strength "
                       "{luma_strength_dn:.1f} DN, chroma {chroma_strength_dn:.1f} DN, scale {scale_px:.1f} px",
                       fit=fit_noise_reduction, changes_noise=True),)
    params = {
        "method": Param("bilateral", str, choices=METHODS, doc="the filter family: bilateral or non-local means"),
        "luma_strength_dn": Param(8.0, low=0.0, high=60.0, unit="DN",
                                  doc="the luma filter's strength: the bilateral's range sigma, the non-local "
                                      "means' h; 0: luma untouched"),
        "chroma_strength_dn": Param(0.0, low=0.0, high=60.0, unit="DN",
                                    doc="the chroma filter's strength (Cb, Cr), as luma_strength_dn"),
        "scale_px": Param(2.0, low=0.5, high=12.0, unit="px",
                          doc="the bilateral's spatial sigma; the non-local means' search radius"),
    }

    def process_frame(self, frame: np.ndarray) -> np.ndarray:
        """The whole (H, W, 3) uint8 frame filtered (:func:`denoise_frame`)."""
        return denoise_frame(frame, self.method, self.luma_strength_dn, self.chroma_strength_dn, self.scale_px)

    def apply(self, state):
        """Nothing before the blend: the filter acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        if frame.ndim != 3:
            raise self.error("acts on an RGB frame; a raw camera delivers a colour-filter mosaic")
        reach = _window(self.method, self.scale_px) // 2 + 3
        return within_footprint(frame, footprint, self.process_frame, reach), footprint


fit_noise_reduction.refines = True  # diagnosis calls it again, in full, for a promising candidate
