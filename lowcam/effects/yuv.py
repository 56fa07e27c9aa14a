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
- :data:`SUBSAMPLING_FACTORS`: J:a:b name -> (horizontal, vertical) chroma subsampling factors
- :func:`chroma_spectrum_ratio`: per 1-D frequency, the chroma power relative to the luma power along an axis
- :func:`chroma_bandwidth_statistic`: the no-reference statistic of a stack: replication and JPEG chroma steps
- :func:`chroma_detail`: how much detail the chroma holds (mean neighbour step of Cb and Cr, DN)
- :func:`chroma_subsampling_evidence`: per axis, the three cues to the chroma subsampling factor (see below)
- :func:`chroma_subsampling_from_plate`: the chroma subsampling the footage shows (a plate estimate)

Chroma bandwidth from the footage alone
---------------------------------------
Chroma subsampled by ``k`` along an axis carries little power above ``0.5 / k`` cycles/px. Three cues, per axis,
each relative to the luma of the same frames so that the scene's own colour detail cancels in part:

- *replication*: an upsampler that repeats samples (libjpeg's 4:1:1, :class:`ChromaSubsampling`) leaves chroma
  steps only every ``k`` px: ``log10`` of the mean neighbour-difference power at the ``k - 1`` weakest phases
  (modulo ``k``, leaving out JPEG's block steps) over the strongest (0: none; below -0.8: replicated);
- *JPEG grid*: JPEG codes the chroma in 8x8 blocks of the subsampled plane, so its block steps come every
  ``8 k`` px: the log step excess at odd multiples of 8 px (``g8``, present only at full chroma) over that at
  multiples of 32 px (``g32``); ``g8 / g32`` is about 1 at 4:4:4 and under 0.6 when halved (read where
  ``g32 > 0.3``, i.e. quality up to about 95);
- *spectrum* (no grid, no replication; a weak cue, the scene's colour detail confounds it): ``chroma_drop``,
  ``log10`` of the chroma/luma power ratio in 0.28-0.5 cycles/px over that in 0.02-0.12; below -0.45: halved
  (confidence at most 0.35, so it is reported, not applied).

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [ITU-R BT.601] ITU-R Recommendation BT.601, "Studio encoding parameters of digital television for standard 4:3 and
  wide-screen 16:9 aspect ratios" (the Y'CbCr luma and colour-difference weights).
- [T.81] ITU-T Recommendation T.81, "Digital compression and coding of continuous-tone still images" (JPEG),
  1992, A.1.1 (sampling factors: chroma blocks are 8x8 samples of the subsampled plane).
"""
from __future__ import annotations

import cv2
import numpy as np

from ..node_images import stmap
from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, NodeStage, Param, Search
from .jpeg import _GRID_T, SUBSAMPLINGS, block_difference_profile, jpeg_blockiness

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

    def bake_node(self, state, bake) -> None:
        """The mean of each group of ``group`` pixels (``chroma_kernel``, a row filter over pixels x .. x + n - 1)
        and the Map UV that reads it at the group's first pixel (``chroma_uv``)."""
        g, n = bake.geometry, self.group
        kernel = np.zeros((1, 2 * n - 1), np.float32)
        kernel[0, n - 1:] = 1.0 / n
        bake.images["chroma_kernel"] = kernel
        yo, xo = np.mgrid[0:g.height, 0:g.width]
        bake.images["chroma_uv"] = stmap(n * (xo // n), yo, g.width, g.height)

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


#: J:a:b name -> (horizontal, vertical) chroma subsampling factors.
SUBSAMPLING_FACTORS = {"4:4:4": (1, 1), "4:2:2": (2, 1), "4:2:0": (2, 2), "4:1:1": (4, 1), "4:4:0": (1, 2),
                       "4:1:0": (4, 2)}

_REPLICATED_BELOW = -0.8   # replication cue: log10 weak/strong phase power below this means repeated samples
_GRID_HALVED_BELOW = 0.6  # JPEG grid cue: g8 / g32 below this means halved chroma
_GRID_VISIBLE = 0.3        # JPEG grid cue: g32 (log step excess) needed to read the cue at all
_DROP_HALVED_BELOW = -0.45 # spectrum cue: chroma_drop below this suggests halved chroma
_SPECTRUM_CONFIDENCE = 0.35  # the spectrum cue alone never gives more (the scene's colour detail confounds it)
_STEP_VISIBLE_DN = 0.05    # JPEG grid cue: the chroma's 32 px step (DN) needed besides g32 (flat chroma has none)
_CHROMA_DETAIL_DN = 0.05   # mean |neighbour difference| of Cb and Cr (DN) below which chroma shows nothing


def _yuv_stack(frames: np.ndarray) -> np.ndarray:
    f = np.asarray(frames, np.float32)
    return (f.reshape(-1, 3) @ RGB_TO_YUV.T.astype(np.float32)).reshape(f.shape)


def chroma_spectrum_ratio(frames: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies in cycles/px, chroma power / luma power) along ``axis`` (-1: horizontal, -2: vertical) of a
    (T, H, W, 3) or (H, W, 3) RGB stack: the Hann-windowed 1-D power spectra of Cb + Cr and of Y, averaged over
    the lines and frames."""
    y = _yuv_stack(frames)
    if y.ndim == 3:
        y = y[None]
    y = np.transpose(y, (0, 1, 3, 2) if axis == -1 else (0, 2, 3, 1))  # (T, lines, 3, n): the axis last
    n = y.shape[-1]
    x = (y - y.mean(axis=-1, keepdims=True)) * np.hanning(n).astype(np.float32)
    p = (np.abs(np.fft.rfft(x, axis=-1)) ** 2).mean(axis=(0, 1))  # (3, n/2+1)
    return np.fft.rfftfreq(n), (p[1] + p[2]) / np.maximum(p[0], 1e-12)


def _drop(freq, ratio) -> float:
    hi = ratio[(freq >= 0.28) & (freq <= 0.5)].mean()
    lo = ratio[(freq >= 0.02) & (freq <= 0.12)].mean()
    return float(np.log10(max(hi, 1e-12) / max(lo, 1e-12)))


def chroma_bandwidth_statistic(frames: np.ndarray) -> dict:
    """The no-reference statistic of a (T, H, W, 3) stack (DN), per axis ``h`` / ``v``: the structural cues of
    :func:`chroma_subsampling_evidence` that depend little on the scene: ``replication_2`` and ``replication_4``
    (log10 power ratios), and the chroma's JPEG steps in DN, ``step8`` at odd multiples of 8 px and ``step32`` at
    multiples of 32 px (mean absolute step less the median over the 32 px phases; ``step8`` near 0 while
    ``step32`` is not: halved chroma). ``{}`` (not measurable) for frames under 64 px or chroma without detail
    (:func:`chroma_detail` under :data:`_CHROMA_DETAIL_DN`)."""
    f = np.asarray(frames)
    if min(f.shape[-3:-1]) < 64 or chroma_detail(f) < _CHROMA_DETAIL_DN:
        return {}
    ev = chroma_subsampling_evidence(f, spectrum=False)
    return {f"{k}_{a}": ev[a][k] for a in ("h", "v") for k in ("replication_2", "replication_4", "step8", "step32")}


def chroma_detail(frames: np.ndarray) -> float:
    """The mean absolute step (DN) between neighbouring pixels of Cb and Cr, across and down, of an RGB stack:
    about 0 where the chroma holds nothing a subsampling could change (a grey or flat scene, or a codec that
    flattened it)."""
    yuv = _yuv_stack(frames)
    return float(np.mean([np.abs(np.diff(yuv[..., c], axis=a)).mean() for c in (1, 2) for a in (-1, -2)]))


def _phase_power(plane: np.ndarray, axis: int, period: int) -> np.ndarray:
    """Mean squared neighbour difference at each phase modulo ``period`` (2 or 4), leaving out the steps across
    JPEG's 8 px block boundaries (index 7 modulo 8), which would otherwise mimic replication."""
    d = np.moveaxis(np.diff(plane, axis=axis) ** 2, axis, -1)
    n = d.shape[-1] // 8 * 8
    d = d[..., :n].reshape(-1, n // 8, 8)[..., :7].mean(axis=(0, 1))  # phases 0..6 of the 8 px block
    return np.array([d[p::period].mean() for p in range(period)])


def chroma_subsampling_evidence(frames: np.ndarray, spectrum: bool = True) -> dict:
    """Per axis (``h``, ``v``): the three cues of the module docstring: ``replication_2`` / ``replication_4``
    (chroma less luma; luma's own is subtracted so a sharp scene's structure cancels), ``g8`` and ``g32`` (the
    chroma's JPEG step excess, as a log ratio to the median step, at odd multiples of 8 px and at multiples of
    32 px, mean over Cb and Cr, the grid starting at the frame's corner), the same as differences in DN
    (``step8``, ``step32``) and, with ``spectrum``, ``chroma_drop``."""
    y = _yuv_stack(frames)
    if y.ndim == 3:
        y = y[None]
    out = {}
    for axis, name in ((-1, "h"), (-2, "v")):
        e = {}
        for k in (2, 4):
            rep = []
            for c in range(3):
                p = np.sort(_phase_power(y[..., c], axis, k))
                rep.append(np.log10(max(p[:-1].mean(), 1e-9) / max(p[-1], 1e-9)))
            e[f"replication_{k}"] = float(min(rep[1], rep[2]) - rep[0])
        g8, g32, s8, s32 = [], [], [], []
        for c in (1, 2):
            d = block_difference_profile(y[..., c], axis, 32)
            med = max(np.median(d), 1e-9)
            g8.append(np.log(max((d[7] + d[23]) / 2, 1e-9) / med))
            g32.append(np.log(max(d[31], 1e-9) / med))
            s8.append((d[7] + d[23]) / 2 - med)
            s32.append(d[31] - med)
        e["g8"], e["g32"] = float(np.mean(g8)), float(np.mean(g32))
        e["step8"], e["step32"] = float(np.mean(s8)), float(np.mean(s32))
        if spectrum:
            e["chroma_drop"] = _drop(*chroma_spectrum_ratio(frames, axis))
        out[name] = e
    return out


def _axis_factor(e: dict) -> tuple[int, float, str]:
    """(factor, confidence, cue) for one axis from :func:`chroma_subsampling_evidence`'s cues."""
    for k in (4, 2):
        r = e[f"replication_{k}"]
        if r < _REPLICATED_BELOW:
            return k, float(np.clip((_REPLICATED_BELOW - r) / 0.5 + 0.5, 0, 1)), f"repeated samples ({r:.2f})"
    if e["g32"] > _GRID_VISIBLE and e["step32"] >= _STEP_VISIBLE_DN:
        ratio = e["g8"] / e["g32"]
        visible = float(np.clip(e["g32"] / (2 * _GRID_VISIBLE), 0, 1))
        margin = float(np.clip(abs(ratio - _GRID_HALVED_BELOW) / 0.25, 0, 1))
        return (2 if ratio < _GRID_HALVED_BELOW else 1), visible * margin, f"JPEG chroma grid (g8/g32 {ratio:.2f})"
    d = e["chroma_drop"]
    conf = _SPECTRUM_CONFIDENCE * float(np.clip(abs(d - _DROP_HALVED_BELOW) / 0.4, 0, 1))
    return (2 if d < _DROP_HALVED_BELOW else 1), conf, f"chroma spectrum (drop {d:.2f})"


def chroma_subsampling_from_plate(footage, base=None, film=None):
    """The chroma subsampling the footage shows, as a :class:`lowcam.plate_estimate.PlateEstimate`.

    Per axis the factor comes from the first cue that speaks (replication, then the JPEG grid, then the
    spectrum; module docstring), the confidence is the weaker axis's. Where one axis shows repeated samples
    and the other shows neither repetition nor a JPEG grid, the other is taken as full (the same upsampler
    would have repeated there), with the confidence of its repetition cue. A JPEG-style result (4:4:4, 4:2:2,
    4:2:0) on footage with a JPEG grid sets the ``jpeg`` effect's ``subsampling`` (where ``base``, the profile
    being refined, has one: the JPEG probe runs first and adds it when it measures the quality) and turns
    :class:`ChromaSubsampling` off (``"chroma_subsampling.enabled": False``: the codec's subsampling is the
    camera's only one, not a second one on top of the base's); otherwise the horizontal factor sets
    :class:`ChromaSubsampling`'s ``group`` (the engine's chroma subsampling is horizontal only; a vertical factor
    is reported). Chroma with no detail (mean neighbour step of Cb and Cr under :data:`_CHROMA_DETAIL_DN`, a grey
    or flat scene): not measurable."""
    frames = footage.stack(max_frames=6)
    detail = chroma_detail(frames)
    if detail < _CHROMA_DETAIL_DN:
        return PlateEstimate.not_measurable(
            "chroma_bandwidth", "chroma_subsampling", {"chroma_detail_dn": round(detail, 4)},
            f"the chroma holds no detail (mean step {detail:.3f} DN between neighbours): any subsampling looks alike")
    ev = chroma_subsampling_evidence(frames)
    (fh, ch, why_h), (fv, cv, why_v) = _axis_factor(ev["h"]), _axis_factor(ev["v"])
    # an upsampler that repeats samples along one axis would repeat them along the other too if it subsampled
    # there: no repetition there (and no JPEG grid to read) is then evidence of full chroma along it
    for rep, other, axis in ((why_h, why_v, "v"), (why_v, why_h, "h")):
        if rep.startswith("repeated") and other.startswith("chroma spectrum"):
            r = ev[axis]["replication_2"]
            conf = float(np.clip((r - _REPLICATED_BELOW) / 0.5, 0, 1))
            note = f"no repeated samples ({r:.2f}) where the other axis has them"
            if axis == "v":
                fv, cv, why_v = 1, conf, note
            else:
                fh, ch, why_h = 1, conf, note
    name = next((k for k, v in SUBSAMPLING_FACTORS.items() if v == (fh, fv)), f"{fh}x{fv}")
    measured = {"subsampling": name, "factors": [fh, fv],
                **{f"{a}_{k}": round(v, 4) for a in ("h", "v") for k, v in ev[a].items()}}
    confidence = round(min(ch, cv), 3)
    reason = f"across: {why_h}; down: {why_v}"
    grid = jpeg_blockiness(frames)
    if name in SUBSAMPLINGS and min(grid["t_h"], grid["t_v"]) >= _GRID_T[0]:
        jpeg = base.effect("jpeg") if base is not None else None
        if jpeg is None or not jpeg.enabled:
            return PlateEstimate("chroma_bandwidth", "jpeg", measured, {}, confidence,
                                 f"{reason}; JPEG {name}, reported only: the profile has no JPEG effect and its "
                                 "quality was not measured (a JPEG at an assumed quality is not written)")
        # the JPEG's subsampling is the camera's only one: the base's own chroma subsampling goes
        return PlateEstimate("chroma_bandwidth", "jpeg", measured,
                             {"subsampling": name, "chroma_subsampling.enabled": False}, confidence, reason)
    if fv > 1:
        reason += "; the vertical halving is reported only (the engine's chroma subsampling is horizontal)"
    return PlateEstimate("chroma_bandwidth", "chroma_subsampling", measured, {"group": fh}, confidence, reason)


#: Declared after its estimator and statistic, which the module defines below the class.
ChromaSubsampling.plate_probe = PlateProbe(
    "chroma_bandwidth", chroma_subsampling_from_plate, chroma_bandwidth_statistic, order=30,
    about="chroma against luma detail: repeated samples, the JPEG chroma grid, the spectrum")
