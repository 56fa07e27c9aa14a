"""Local tone mapping of a camera's image processor: contrast-limited adaptive histogram equalisation of the luma
(not in the paper).

Phones, action cameras, drones and webcams raise local contrast before they deliver a frame: shadows are lifted
and flat, dim regions get their detail stretched, tile by tile. The classic form is contrast-limited adaptive
histogram equalisation (CLAHE) [Pizer1987, Zuiderveld1994]: the frame is cut into ``tiles`` x ``tiles`` regions;
each region's luma histogram (256 bins) is clipped at ``clip_limit`` times its mean bin count, the excess spread
over all bins, and its cumulative sum taken as that region's tone curve; each pixel's new luma is the bilinear
interpolation of the curves of the four regions around it (their centres). The clip bounds each curve's slope, so
noise in flat regions is amplified at most ``clip_limit`` times.

The stage equalises the delivered frame's full-range BT.601 luma Y (:mod:`~lowcam.effects.delivered_frame`) with
OpenCV's ``cv2.createCLAHE`` (``clipLimit`` = ``clip_limit``, ``tileGridSize`` = (``tiles``, ``tiles``)), which
reads 8-bit values: Y is rounded, equalised, and the change mixed back by ``strength``:

    Y' = Y + strength (CLAHE(round(Y)) - round(Y))

the change added to R, G and B alike (chroma kept). A strength of 0 leaves the frame as it is.

Where it acts: a tone mapper's regions are large (a frame of 640 px in 8 tiles has regions of 80 px), and each
region's curve depends on every pixel of it, so the stage equalises the whole composite frame (plate and graphics
together, as the camera's processor saw the scene) and keeps the result only where the graphics reach; the plate's
own pixels, which the real camera tone-mapped already, keep their bytes. The graphics thus get the curves the
composite's regions have, an approximation where the graphics change a region's histogram much.

Contents
--------
- :func:`equalise_luma`: a luma plane equalised by OpenCV's CLAHE and mixed back
- :func:`tone_map_frame`: an RGB frame with its luma equalised
- :func:`fit_local_tone_mapping`: diagnosis's fit: the clip limit, tile count and strength whose tone-mapped noisy
  model frames best match the measured frames (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`LocalToneMapping`: the stage

It has no compositor node: Blender's compositor has no histogram of a region, so no node could build the regions'
curves from the frame; ``lowcam.node_maps.bake`` refuses a profile with it, and the render handler, which runs the
engine, simulates it.

It has no plate probe (``calibrate plate``): a region's curve is made from the region's own histogram, so footage
alone cannot tell a scene of high local contrast filmed plainly from a flat one equalised; a measurement set of
known scenes shows it to diagnosis.

References
----------
- [Pizer1987] S. M. Pizer, E. P. Amburn, J. D. Austin, R. Cromartie, A. Geselowitz, T. Greer, B. ter Haar Romeny,
  J. B. Zimmerman and K. Zuiderveld, "Adaptive histogram equalization and its variations", Computer Vision,
  Graphics, and Image Processing 39(3), 355-368, 1987.
- [Zuiderveld1994] K. Zuiderveld, "Contrast Limited Adaptive Histogram Equalization", in P. S. Heckbert (ed.),
  Graphics Gems IV, Academic Press 1994, 474-485 (OpenCV's createCLAHE follows it).
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 luma).
"""
from __future__ import annotations

import cv2
import numpy as np

from .base import Effect, Param, Search
from .delivered_frame import BT601_TO_YCC, fit_delivered_stage, processed_by, to_uint8, within_footprint


def equalise_luma(luma: np.ndarray, clip_limit: float, tiles: int, strength: float) -> np.ndarray:
    """``luma`` (H, W) float32 (DN) with OpenCV's CLAHE at ``clip_limit`` (times a region's mean bin count) over
    ``tiles`` x ``tiles`` regions, its change mixed in by ``strength`` (0..1; the module's formula), float32."""
    luma = np.asarray(luma, np.float32)
    if strength <= 0:
        return luma
    q = np.clip(np.rint(luma), 0, 255).astype(np.uint8)
    clahe = cv2.createCLAHE(clipLimit=float(clip_limit), tileGridSize=(int(tiles), int(tiles)))
    return luma + np.float32(strength) * (clahe.apply(np.ascontiguousarray(q)).astype(np.float32) - q)


def tone_map_frame(frame: np.ndarray, clip_limit: float, tiles: int, strength: float) -> np.ndarray:
    """An (H, W, 3) uint8 RGB frame with its full-range BT.601 luma equalised (:func:`equalise_luma`); the luma's
    change is added to R, G and B alike (the chroma kept), rounded (uint8)."""
    f = np.asarray(frame, np.float32)
    if strength <= 0:
        return np.asarray(frame, np.uint8)
    y = f @ BT601_TO_YCC[0]
    change = equalise_luma(y, clip_limit, tiles, strength) - y
    return to_uint8(f + change[..., None])


def fit_local_tone_mapping(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): the tile count and clip limit together on a coarse grid at full
    strength, then the strength; then clip limit and strength together finer, the tile count by one or two either
    side, clip limit and strength twice more as broadly (other regions want another clip), and finer again
    (:func:`~lowcam.effects.delivered_frame.fit_delivered_stage`).
    The crop is larger than any frame: each trial tone-maps the whole model frames (a region's curve depends on all
    of it) and is scored on all of them (on a centre crop, which leaves the border regions out, a fit to
    scikit-image's CLAHE held out worse: 1.247 against 1.214). While diagnosis screens: a coarser grid of 4 tile
    counts and clips and 2 strengths only."""
    def together(steps_clip, steps_strength):  # a higher clip at a lower strength looks alike
        return lambda v: [(min(max(v["clip_limit"] * a, 1.0), 40.0), min(max(v["strength"] * b, 0.0), 1.0))
                          for a in steps_clip for b in steps_strength]

    coarse = [(("tiles", "clip_limit"), [(t, c) for t in (2, 4, 8, 16) for c in (1.5, 2.5, 4.0, 8.0)]),
              ("strength", (0.25, 0.5, 0.75, 1.0))]
    if getattr(ctx, "screening", False):  # screening shows whether it helps at all: 6 trials, not 20
        coarse = [(("tiles", "clip_limit"), [(t, c) for t in (4, 8) for c in (2.5, 6.0)]), ("strength", (0.5, 1.0))]
    broad = together((0.7, 0.85, 1.0, 1.18, 1.4), (0.8, 0.9, 1.0, 1.1, 1.25))
    plan = [(("clip_limit", "strength"), broad),
            ("tiles", lambda v: sorted({min(max(v["tiles"] + k, 1), 32) for k in (-2, -1, 0, 1, 2)})),
            (("clip_limit", "strength"), broad),  # other regions, another clip: searched broadly again
            (("clip_limit", "strength"), broad),
            (("clip_limit", "strength"), together((0.9, 0.95, 1.0, 1.05, 1.1), (0.93, 1.0, 1.07))),
            (("clip_limit", "strength"), together((0.97, 1.0, 1.03), (0.97, 1.0, 1.03)))]
    start = {"clip_limit": 2.5, "tiles": 8, "strength": 1.0}
    whole = (1 << 16, 1 << 16)  # a crop larger than any frame: processed and scored whole, no margin
    return fit_delivered_stage(ctx, effect, processed_by(LocalToneMapping), [(start, plan, coarse)], crop=whole)


class LocalToneMapping(Effect):
    """Local tone mapping of the delivered frame: its luma equalised by contrast-limited adaptive histogram
    equalisation over ``tiles`` x ``tiles`` regions, each region's histogram clipped at ``clip_limit`` times its
    mean bin count, mixed in by ``strength`` (OpenCV's ``createCLAHE``; see the module's docstring)."""

    name = "local_tone_mapping"
    section = "not in the paper"
    writes = "output"
    order = 273  # after noise reduction (a processor equalises denoised luma), before edge enhancement
    searches = (Search("local_tone_mapping", "local contrast raised: luma equalised in {tiles}x{tiles} regions, "
                       "histograms clipped at {clip_limit:.2f}x, mixed in at {strength:.2f}",
                       fit=fit_local_tone_mapping, changes_noise=True),)
    params = {
        "clip_limit": Param(2.5, low=1.0, high=40.0,
                            doc="each region's histogram is clipped at this many times its mean bin count "
                                "(256 bins): the largest slope of its tone curve; 1: no change"),
        "tiles": Param(8, int, low=1, high=32, doc="the frame is cut into tiles x tiles regions, each with its "
                                                    "own tone curve"),
        "strength": Param(1.0, low=0.0, high=1.0, doc="the share of the equalised luma mixed in (0: the frame "
                                                      "untouched, 1: the equalised luma)"),
    }

    def process_frame(self, frame: np.ndarray) -> np.ndarray:
        """The whole (H, W, 3) uint8 frame tone-mapped (:func:`tone_map_frame`)."""
        return tone_map_frame(frame, self.clip_limit, self.tiles, self.strength)

    def apply(self, state):
        """Nothing before the blend: the tone mapping acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        if frame.ndim != 3:
            raise self.error("acts on an RGB frame; a raw camera delivers a colour-filter mosaic")
        # the regions' curves read the whole frame: equalised whole, kept where the graphics reach
        return within_footprint(frame, footprint, self.process_frame, max(frame.shape[:2])), footprint


fit_local_tone_mapping.refines = True  # diagnosis calls it again, in full, for a promising candidate
