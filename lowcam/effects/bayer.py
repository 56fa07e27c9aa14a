"""Bayer sampling and demosaicing (Klein & Murray 2010, sec. 4.4.1, 5.2 steps 5 and 8, sec. 7).

Sensel planes are (4, rows, cols) in R, Gr, Gb, B order (:data:`lowcam.geometry.CFA_CHANNELS`), with borders, in
8-bit DN. The Fire-i's 2x2-block demosaicing (sec. 4.4.1, Fig. 5) makes red and blue nearest-neighbour blocks
and green the mean of the Gr and Gb blocks; the camera's method is identified from the correlations of its
temporal noise in 4x4 blocks (the paper's Fig. 4).

Contents
--------
- :class:`BayerSampling`: samples the working image at every sensel of R, Gr, Gb and B (sec. 5.2 step 5)
- :func:`demosaic_block`: 2x2-block demosaicing of the Fire-i (sec. 4.4.1, Fig. 5)
- :func:`mosaic`: interleave the four sensel planes (borders dropped) into one (H, W) Bayer frame
- :func:`unmosaic`: split a Bayer (or mosaic-sampled RGB) frame into four planes with replicated borders
- :func:`demosaic_bilinear`: bilinear demosaicing (the raw-Bayer pipeline, sec. 7); returns (H, W, 3)
- :class:`Demosaic`: full-colour premultiplied RGB and per-channel alpha from the planes (sec. 5.2 step 8)
- :data:`DEMOSAIC_METHODS`: the methods identification compares: block, bilinear and OpenCV's edge-aware
- :func:`block_correlations`: 16x16 noise correlations between the pixels of 4x4 blocks (Fig. 4)
- :func:`predicted_correlations`: the 4x4-block correlations independent sensel noise gives through a method
- :func:`identify_demosaic`: score each method against the measured correlations; the lowest error wins

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import BAYER_BORDER, CFA_CHANNELS, COLOUR_INDEX, sample_texture
from .base import Effect, NodeStage, Param, Search


class BayerSampling(Effect):
    """Samples the working image at every sensel of R, Gr, Gb and B (sec. 5.2 step 5).

    Each channel reads its own colour component (and alpha) at its sensels' positions, moved by the
    chromatic-aberration grid and averaged over the motion-blur taps when those stages ran. Values are scaled to
    8-bit digital numbers (DN): a render value of ``render_white`` gives 255 DN.
    """

    name = "bayer_sampling"
    section = "5.2 step 5"
    writes = "bayer"
    order = 110
    node = NodeStage("Bayer Sampling", "image", "bayer_sampling")
    always_runs = True
    params = {"render_white": Param(1.0, low=1e-6, high=1e6, doc="render value that gives 255 DN")}

    def sample_positions(self, state) -> tuple[np.ndarray, np.ndarray]:
        """x and y, each (4, taps, rows, cols) float32: working-grid coordinates each sensel averages over.

        Motion taps vary smoothly (24x18-cell grid), so they are looked up once per 2x2 cell for all four channels.
        """
        g = state.geometry
        pos = g.sensel_positions.astype(np.float32)
        su, sv = pos[..., 0].copy(), pos[..., 1].copy()
        if state.ca_grid is not None:
            ca = sample_texture(state.ca_grid, g.frame_extent, pos[..., 0], pos[..., 1])
            for k, c in ((0, 0), (3, 2)):  # R and B; green is the reference
                su[k] += ca[k, ..., c]
                sv[k] += ca[k, ..., c + 1]
        if state.sampling_offset is not None:  # e.g. rolling shutter
            off = sample_texture(state.sampling_offset, g.working_extent, pos[..., 0], pos[..., 1])
            su, sv = su + off[..., 0], sv + off[..., 1]
        x, y = g.output_to_working(su, sv)
        x, y = x.astype(np.float32)[:, None], y.astype(np.float32)[:, None]
        if state.motion_taps is None:
            return x, y
        centre = pos.mean(axis=0)
        taps = sample_texture(state.motion_taps, g.working_extent, centre[..., 0], centre[..., 1])
        taps = taps.reshape(centre.shape[:2] + (-1, 2)).transpose(3, 2, 0, 1)  # (2, taps, rows, cols)
        sx, sy = g.working_scale
        tx = np.multiply(taps[0], np.float32(sx), order="C")
        ty = np.multiply(taps[1], np.float32(sy), order="C")
        return x + tx[None], y + ty[None]

    def apply(self, state):
        g = state.geometry
        hb, wb = g.bayer_shape
        x, y = self.sample_positions(state)
        n = x.shape[1]
        # Each colour is sampled from a 2-channel (colour, alpha) image: half the memory traffic of RGBA.
        h, w = state.working.shape[:2]
        pairs = [np.empty((h, w, 2), np.float32) for _ in range(3)]
        cv2.mixChannels([state.working], pairs, [0, 0, 3, 1, 1, 2, 3, 3, 2, 4, 3, 5])
        state.bayer = np.empty((4, hb, wb), np.float32)
        state.bayer_alpha = np.empty((4, hb, wb), np.float32)
        for src, ks in zip(pairs, (slice(0, 1), slice(1, 3), slice(3, 4))):
            count = ks.stop - ks.start
            rows = count * n * hb
            sampled = cv2.remap(src, x[ks].reshape(rows, wb), y[ks].reshape(rows, wb), cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            sampled = sampled.reshape(count, n, hb, wb, 2).mean(axis=1) if n > 1 else sampled.reshape(
                count, hb, wb, 2)
            state.bayer[ks] = sampled[..., 0]
            state.bayer_alpha[ks] = sampled[..., 1]
        state.bayer *= np.float32(255.0 / self.render_white)


def demosaic_block(planes: np.ndarray, geometry) -> np.ndarray:
    """2x2-block demosaicing of the Fire-i (sec. 4.4.1, Fig. 5): red and blue are nearest-neighbour blocks, green
    is the mean of the Gr and Gb blocks. ``planes`` is (4, rows, cols) in R, Gr, Gb, B order; returns (H, W, 3).

    Every sensel fills the 2x2 block that has it in its top-right corner (sec. 5.2 step 8), so output pixel
    (y, x) takes plane row ``floor((y - dy) / 2)`` and column ``floor((x - dx + 1) / 2)`` (plus borders).
    """
    by, bx = BAYER_BORDER
    h, w = geometry.height, geometry.width
    hb, wb = planes.shape[1:]
    up = cv2.resize(np.ascontiguousarray(planes.transpose(1, 2, 0)), (2 * wb, 2 * hb),
                    interpolation=cv2.INTER_NEAREST)
    blocks = []
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        y0, x0 = 2 * by - dy, 2 * bx - dx + 1
        blocks.append(up[y0:y0 + h, x0:x0 + w, k])
    return np.ascontiguousarray(np.stack([blocks[0], 0.5 * (blocks[1] + blocks[2]), blocks[3]], -1))


def mosaic(planes: np.ndarray, geometry) -> np.ndarray:
    """Interleave the four sensel planes (borders dropped) into one (H, W) Bayer frame."""
    by, bx = BAYER_BORDER
    h, w = geometry.height, geometry.width
    out = np.empty((h, w), planes.dtype)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        out[dy::2, dx::2] = planes[k, by:by + h // 2, bx:bx + w // 2]
    return out


def unmosaic(frame: np.ndarray, geometry) -> np.ndarray:
    """Split a Bayer frame (H, W), or an RGB frame (H, W, 3) sampled through the mosaic, into four planes with
    replicated borders."""
    by, bx = BAYER_BORDER
    planes = []
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        src = frame if frame.ndim == 2 else frame[..., COLOUR_INDEX[k]]
        planes.append(np.pad(src[dy::2, dx::2], ((by, by), (bx, bx)), mode="edge"))
    return np.stack(planes).astype(np.float32)


def demosaic_bilinear(planes: np.ndarray, geometry) -> np.ndarray:
    """Bilinear demosaicing of the four sensel planes (the raw-Bayer pipeline, sec. 7); returns (H, W, 3)."""
    frame = mosaic(planes, geometry).astype(np.float32)
    h, w = frame.shape
    out = np.empty((h, w, 3), np.float32)
    masks = np.zeros((3, h, w), np.float32)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        masks[COLOUR_INDEX[k], dy::2, dx::2] = 1
    k_rb = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], np.float32) / 4
    k_g = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], np.float32) / 4
    for c in range(3):
        kern = k_g if c == 1 else k_rb
        num = cv2.filter2D(frame * masks[c], -1, kern, borderType=cv2.BORDER_REFLECT_101)
        den = cv2.filter2D(masks[c], -1, kern, borderType=cv2.BORDER_REFLECT_101)
        out[..., c] = num / den
    return out


class Demosaic(Effect):
    """Reconstructs full-colour premultiplied RGB and per-channel alpha from the sensel planes.

    ``method = "block"``: the Fire-i's 2x2-block scheme (sec. 4.4.1); ``"bilinear"``: bilinear interpolation
    (sec. 7, and the assumption of the paper's earlier version). Alpha travels with colour, so each output
    channel carries its own alpha (sec. 5.2 step 8).
    """

    name = "demosaic"
    section = "4.4.1, 5.2 step 8, 7"
    writes = "rgb"
    order = 200
    calibration = "demosaic"
    node = NodeStage("Demosaic", "mosaic", "demosaic")
    searches = (Search("bilinear_demosaic", "fine detail and noise correlations follow bilinear demosaicing",
                       fixed={"method": "bilinear"}, requires="demosaic"),)
    always_runs = True
    params = {"method": Param("block", str, choices=("block", "bilinear"))}

    def apply(self, state):
        fn = demosaic_block if self.method == "block" else demosaic_bilinear
        state.rgb = fn(state.bayer, state.geometry)
        state.rgb_alpha = fn(state.bayer_alpha, state.geometry)


# --- demosaic identification (sec. 4.4.1, Fig. 4): noise covariances in 4x4 blocks --------------------------------

DEMOSAIC_METHODS = ("block", "bilinear", "edge_aware")


def block_correlations(frames: np.ndarray, channel: int) -> np.ndarray:
    """16x16 correlation between the pixels of aligned 4x4 blocks (the paper's Fig. 4), from the temporal noise
    of a stack (N, H, W, 3) of frames of a static scene, over all blocks and frames."""
    x = np.asarray(frames, np.float64)[..., channel]
    n, h, w = x.shape
    x = x - x.mean(axis=0, keepdims=True)
    blocks = x[:, : h // 4 * 4, : w // 4 * 4].reshape(n, h // 4, 4, w // 4, 4).transpose(0, 1, 3, 2, 4)
    with np.errstate(invalid="ignore", divide="ignore"):  # a noise-free stack has no correlations: NaN
        return np.corrcoef(blocks.reshape(-1, 16).T)


def _opencv_demosaic(planes: np.ndarray, geometry, code_kind: str) -> np.ndarray:
    """OpenCV's demosaicing of our planes (``code_kind`` "_EA": edge-aware, "_VNG"), with the Bayer code chosen
    by test so that OpenCV's pattern naming matches ours."""
    frame = mosaic(planes, geometry)
    lo, hi = float(frame.min()), float(frame.max())
    u16 = np.round((frame - lo) / max(hi - lo, 1e-9) * 60000 + 1000).astype(np.uint16)
    code = _bayer_code(geometry, code_kind)
    return cv2.cvtColor(u16, code).astype(np.float32)


def _bayer_code(geometry, kind: str):
    probe = np.zeros((4,) + geometry.bayer_shape, np.float32)
    probe[0] = 1.0  # red sensels only
    frame = np.round(mosaic(probe, geometry) * 1000).astype(np.uint16)
    for name in ("BG", "GB", "RG", "GR"):
        code = getattr(cv2, f"COLOR_Bayer{name}2RGB{kind}")
        out = cv2.cvtColor(frame, code).astype(np.float32)
        if out[4:-4, 4:-4, 0].mean() > 900 and out[4:-4, 4:-4, 2].mean() < 100:
            return code
    raise RuntimeError(f"no OpenCV Bayer code matches {geometry.bayer_pattern}")


def predicted_correlations(geometry, method: str, channel: int, frames: int = 40, seed: int = 99) -> np.ndarray:
    """The 4x4-block correlations that independent sensel noise produces through a demosaicing ``method``."""
    rng = np.random.default_rng(seed)
    shape = (4,) + geometry.bayer_shape
    if method == "block":
        fn = demosaic_block
    elif method == "bilinear":
        fn = demosaic_bilinear
    else:
        def fn(p, g):
            return _opencv_demosaic(p, g, "_EA")
    out = np.stack([fn(rng.standard_normal(shape).astype(np.float32), geometry) for _ in range(frames)])
    return block_correlations(out, channel)


def identify_demosaic(stack, geometry) -> dict:
    """Score each method of :data:`DEMOSAIC_METHODS` against the measured noise correlations of a stack of frames
    of a static scene; the lowest error (mean absolute difference of the off-diagonal correlations over the three
    channels) wins. Returns ``{"best", "errors", "measured", "predicted"}``."""
    off = ~np.eye(16, dtype=bool)
    measured = [block_correlations(stack, c) for c in range(3)]
    predicted, errors = {}, {}
    for method in DEMOSAIC_METHODS:
        predicted[method] = [predicted_correlations(geometry, method, c) for c in range(3)]
        errors[method] = float(np.mean([np.abs(m - p)[off].mean() for m, p in zip(measured, predicted[method])]))
    best = min(errors, key=errors.get)
    return {"best": best, "errors": errors, "measured": measured, "predicted": predicted}
