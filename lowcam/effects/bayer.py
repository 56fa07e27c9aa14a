"""Bayer sampling and demosaicing (Klein & Murray 2010, sec. 4.4.1, 5.2 steps 5 and 8, sec. 7).

Sensel planes are (4, rows, cols) in R, Gr, Gb, B order (:data:`lowcam.geometry.CFA_CHANNELS`), with borders, in
8-bit DN. The Fire-i's 2x2-block demosaicing (sec. 4.4.1, Fig. 5) makes red and blue nearest-neighbour blocks
and green the mean of the Gr and Gb blocks; the camera's method is identified from the correlations of its
temporal noise in 4x4 blocks (the paper's Fig. 4).

A lens calibration, a plate and a tracked feature are all measured on the frames the camera delivers, after its
demosaicing. The Fire-i's blocks move the picture by half a pixel left and half a pixel down (every sensel fills
the block that has it in its top-right corner): a feature a sensel sees at pixel (u, v) is delivered at (u - 1/2,
v + 1/2). So the sensel of pixel (u, v) sees the light the lens puts at (u, v) moved by its profile's
:func:`sensel_shift_px` (the lens stage lays the working grid out so), and the lens's calibration holds on the
delivered frame.

Contents
--------
- :class:`BayerSampling`: samples the working image at every sensel of R, Gr, Gb and B (sec. 5.2 step 5)
- :data:`DEMOSAIC_SHIFT_PX`: how far each demosaicing method moves the picture, (right, down) output px
- :func:`sensel_shift_px`: where in the delivered frame a profile's sensels look, from their own pixels
- :data:`WARPS_KEPT`: how many sets of Bayer sampling warps the process keeps
- :func:`demosaic_block`: 2x2-block demosaicing of the Fire-i (sec. 4.4.1, Fig. 5)
- :func:`mosaic`: interleave the four sensel planes (borders dropped) into one (H, W) Bayer frame
- :func:`unmosaic`: split a Bayer (or mosaic-sampled RGB) frame into four planes with replicated borders
- :func:`demosaic_bilinear`: bilinear demosaicing (the raw-Bayer pipeline, sec. 7); returns (H, W, 3)
- :func:`demosaic_gradient_corrected`: Malvar-He-Cutler gradient-corrected bilinear demosaicing; returns (H, W, 3)
- :func:`demosaic_edge_aware`: OpenCV's edge-aware demosaicing of the planes; returns (H, W, 3)
- :func:`demosaic_monochrome`: a sensor without colour filters: each pixel its own sensel; returns (H, W, 3)
- :data:`DEMOSAICERS`: method name -> demosaicing function, the ``method`` choices of :class:`Demosaic`
- :class:`Demosaic`: full-colour premultiplied RGB and per-channel alpha from the planes (sec. 5.2 step 8)
- :data:`DEMOSAIC_METHODS`: the methods identification compares: block, bilinear and OpenCV's edge-aware
- :func:`block_correlations`: 16x16 noise correlations between the pixels of 4x4 blocks (Fig. 4)
- :func:`predicted_correlations`: the 4x4-block correlations independent sensel noise gives through a method
- :func:`identify_demosaic`: score each method against the measured correlations; the lowest error wins

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Malvar2004] H. S. Malvar, L.-W. He and R. Cutler, "High-Quality Linear Interpolation for Demosaicing of
  Bayer-Patterned Color Images", Proc. IEEE ICASSP 2004, vol. 3, 485-488 (the 5x5 filters of Fig. 2).
- [OpenCV-EA] OpenCV ``cv::demosaicing`` with ``COLOR_Bayer*2RGB_EA``: edge-aware demosaicing (imgproc,
  ``demosaicing.cpp``), interpolating green along the smaller of the horizontal and vertical gradients.
"""
from __future__ import annotations

import threading

import cv2
import numpy as np

from ..errors import LowcamError
from ..geometry import BAYER_BORDER, CFA_CHANNELS, COLOUR_INDEX, sample_texture
from ..node_images import mosaic_shape, planes_to_mosaic, stmap
from ..parallel import thread_map
from ..window import WindowedRemap
from .base import Effect, NodeStage, Param, Search

#: The sensel planes (R, Gr, Gb, B) each colour reads: R, then both greens, then B.
_COLOUR_PLANES = (slice(0, 1), slice(1, 3), slice(3, 4))


#: How many sets of Bayer sampling warps are kept, shared by every profile in the process (a fit varies
#: profiles by the dozen; a shot's frames reuse one set while the camera's motion is steady).
WARPS_KEPT = 4
_KEPT_WARPS: list = []     # (geometry, (ca_grid, sampling_offset, motion_taps) copies, (taps, warps))
_KEPT_LOCK = threading.Lock()


#: How far each demosaicing method moves the picture, (right, down) in output px: where a feature one sensel sees
#: at its own pixel lies in the delivered frame, on average over the 2x2 cell. The blocks (sec. 4.4.1, Fig. 5):
#: every sensel fills the 2x2 block that has it in its top-right corner, whose centre is half a pixel left of it
#: and half a pixel below. The interpolating methods weigh each pixel's neighbours symmetrically: none.
DEMOSAIC_SHIFT_PX = {"block": (-0.5, 0.5), "bilinear": (0.0, 0.0), "gradient_corrected": (0.0, 0.0),
                     "edge_aware": (0.0, 0.0), "monochrome": (0.0, 0.0)}


def sensel_shift_px(profile) -> tuple[float, float]:
    """Where in the delivered frame ``profile``'s sensels look, (right, down) output px from their own pixels: its
    demosaicing's :data:`DEMOSAIC_SHIFT_PX`. The sensel of pixel ``s`` sees the light the lens puts at ``s + d``,
    and the delivered pixel ``s + d`` shows it: every ray lands where the lens puts it in the delivered frame.
    None without a demosaicing stage (e.g. a raw-Bayer camera's plate)."""
    demosaic = profile.effect("demosaic")
    if demosaic is None or not demosaic.enabled:
        return 0.0, 0.0
    return DEMOSAIC_SHIFT_PX[demosaic.method]


def _same(a, b) -> bool:
    return a is None and b is None or a is not None and b is not None and a.shape == b.shape and np.array_equal(a, b)


class BayerSampling(Effect):
    """Samples the working image at every sensel of R, Gr, Gb and B (sec. 5.2 step 5).

    Each channel reads its own colour component (and alpha) at its sensels' positions, moved by the
    chromatic-aberration grid and averaged over the motion-blur taps when those stages ran. Values are scaled to
    8-bit digital numbers (DN): a render value of ``render_white`` gives 255 DN. A sensor without colour filters
    (``colour_filters = false``) has every sensel read the same mix ``grey_weights`` of the colour components.
    """

    name = "bayer_sampling"
    section = "5.2 step 5"
    writes = "bayer"
    order = 110
    node = NodeStage("Bayer Sampling", "image", "bayer_sampling")
    always_runs = True
    params = {"render_white": Param(1.0, low=1e-6, high=1e6, doc="render value that gives 255 DN"),
              "colour_filters": Param(True, bool, doc="false: a monochrome sensor, every sensel unfiltered"),
              "grey_weights": Param([0.2126, 0.7152, 0.0722], "vector", length=3, low=0.0, high=1.0,
                                    doc="an unfiltered sensel's response to the render's R, G, B (BT.709 luma)")}

    def implausible(self) -> list[str]:
        total = sum(self.grey_weights)
        return [] if self.colour_filters or abs(total - 1.0) <= 0.05 else [f"grey weights summing to {total:.3f}"]

    def bake_node(self, state, bake) -> None:
        """Each mosaic pixel reads its own sensel's positions, aberration and motion taps included: one Map UV
        per tap (``bayer_uv_T``), with the tap count, the render's white and the CFA offsets."""
        g = bake.geometry
        hw, ww = g.working_shape
        sx, sy = self.sample_positions(state)     # (4, taps, hb, wb)
        for t in range(sx.shape[1]):
            bake.images[f"bayer_uv_{t}"] = stmap(planes_to_mosaic(sx[:, t], g), planes_to_mosaic(sy[:, t], g), ww, hw)
        bake.values["bayer_taps"] = sx.shape[1]
        bake.values["render_white"] = self.render_white
        bake.values["cfa"] = {name: g.cfa[name] for name in CFA_CHANNELS}

    def sample_positions(self, state) -> tuple[np.ndarray, np.ndarray]:
        """x and y, each (4, taps, rows, cols) float32: working-grid coordinates each sensel averages over.

        Motion taps vary smoothly (24x18-cell grid), so they are looked up once per 2x2 cell for all four channels.
        """
        g = state.geometry
        pos = g.sensel_positions.astype(np.float32)
        su, sv = pos[..., 0].copy(), pos[..., 1].copy()
        if state.ca_grid is not None:  # R and B only (green is the reference): the lookup is per point
            ca = sample_texture(state.ca_grid, g.frame_extent, pos[0::3, ..., 0], pos[0::3, ..., 1])
            for i, (k, c) in enumerate(((0, 0), (3, 2))):
                su[k] += ca[i, ..., c]
                sv[k] += ca[i, ..., c + 1]
        if state.sampling_offset is not None:  # e.g. rolling shutter
            off = sample_texture(state.sampling_offset, g.working_extent, pos[..., 0], pos[..., 1])
            su, sv = su + off[..., 0], sv + off[..., 1]
        x, y = g.output_to_working(su, sv)
        x, y = x.astype(np.float32)[:, None], y.astype(np.float32)[:, None]
        if state.motion_taps is None:
            return x, y
        centre = pos.mean(axis=0)
        taps = sample_texture(state.motion_taps, g.working_extent, centre[..., 0], centre[..., 1])
        # (rows * cols, taps * 2) -> (taps * 2, rows * cols): cv2.transpose is far faster than a strided copy
        taps = cv2.transpose(taps.reshape(-1, taps.shape[-1])).reshape((-1,) + centre.shape[:2])
        sx, sy = g.working_scale
        tx = np.multiply(taps[0::2], np.float32(sx))
        ty = np.multiply(taps[1::2], np.float32(sy))
        return x + tx[None], y + ty[None]

    def warps(self, state) -> tuple[int, list[WindowedRemap]]:
        """The number of taps and, per colour (R, G, B), the warp of :meth:`sample_positions` (one block per
        sensel plane and tap). Kept (:data:`WARPS_KEPT`) for the next frame while the geometry and the aberration,
        offset and motion-tap grids are the same (a steady camera motion)."""
        inputs = (state.ca_grid, state.sampling_offset, state.motion_taps)
        with _KEPT_LOCK:
            for i, (geometry, kept, result) in enumerate(_KEPT_WARPS):
                if geometry == state.geometry and all(_same(a, b) for a, b in zip(kept, inputs)):
                    _KEPT_WARPS.append(_KEPT_WARPS.pop(i))    # most recently used last
                    return result
        hb, wb = state.geometry.bayer_shape
        x, y = self.sample_positions(state)
        n = x.shape[1]
        warps = [WindowedRemap(x[ks].reshape(-1, hb, wb), y[ks].reshape(-1, hb, wb), tile=8) for ks in _COLOUR_PLANES]
        with _KEPT_LOCK:
            _KEPT_WARPS.append((state.geometry, tuple(None if a is None else a.copy() for a in inputs), (n, warps)))
            del _KEPT_WARPS[:-WARPS_KEPT]
        return n, warps

    def apply(self, state):
        g = state.geometry
        hb, wb = g.bayer_shape
        n, warps = self.warps(state)
        window = state.window("working")
        # Each colour is sampled from a 2-channel (colour, alpha) image: half the memory traffic of RGBA.
        h, w = state.working.shape[:2]
        pairs = [np.empty((h, w, 2), np.float32) for _ in range(3)]
        if self.colour_filters:
            cv2.mixChannels([state.working], pairs, [0, 0, 3, 1, 1, 2, 3, 3, 2, 4, 3, 5])
        else:  # every sensel sees the same mix of the light
            grey = cv2.transform(state.working, np.array([list(self.grey_weights) + [0.0]], np.float32))
            for pair in pairs:
                cv2.merge([grey, state.working[..., 3]], pair)
        state.bayer = np.empty((4, hb, wb), np.float32)
        state.bayer_alpha = np.empty((4, hb, wb), np.float32)
        # every colour's strips of rows side by side (each one's taps added in order, as alone)
        sampled = [np.zeros((warps[c].blocks // n, hb, wb, 2), np.float32) for c in range(3)]
        thread_map(lambda job: job(), [job for c in range(3) for job in warps[c].mean_jobs(pairs[c], window, n,
                                                                                           sampled[c])])
        for c in range(3):
            state.bayer[_COLOUR_PLANES[c]] = sampled[c][..., 0]
            state.bayer_alpha[_COLOUR_PLANES[c]] = sampled[c][..., 1]
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


def _sensor_mosaic(planes: np.ndarray, geometry) -> tuple[np.ndarray, dict]:
    """The four planes interleaved with their borders into one (2 rows, 2 cols) float32 mosaic, and the masks of
    its R, Gr, Gb and B sensels. The output frame is ``[2 by : 2 by + H, 2 bx : 2 bx + W]`` of it
    (:func:`_crop`), so 5x5 filters at the frame's edge read real border sensels."""
    hb, wb = planes.shape[1:]
    out = np.empty((2 * hb, 2 * wb), np.float32)
    masks = {}
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        out[dy::2, dx::2] = planes[k]
        masks[name] = np.zeros(out.shape, bool)
        masks[name][dy::2, dx::2] = True
    return out, masks


def _crop(full: np.ndarray, geometry) -> np.ndarray:
    by, bx = BAYER_BORDER
    return np.ascontiguousarray(full[2 * by:2 * by + geometry.height, 2 * bx:2 * bx + geometry.width])


# [Malvar2004] Fig. 2, times 8: green at red/blue sensels; red (blue) at green sensels whose row holds red (blue),
# at green sensels whose column holds it, and at blue (red) sensels.
_MHC_GREEN = np.array([[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]])
_MHC_ROW = np.array([[0, 0, .5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, .5, 0, 0]])
_MHC_COLUMN = _MHC_ROW.T
_MHC_DIAGONAL = np.array([[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0],
                          [0, 0, -1.5, 0, 0]])


def demosaic_gradient_corrected(planes: np.ndarray, geometry) -> np.ndarray:
    """Gradient-corrected bilinear demosaicing [Malvar2004]: each missing colour is the bilinear estimate
    corrected by the Laplacian of the sensel's own colour (the four 5x5 filters of Fig. 2, gains 1/2, 5/8, 3/4).
    ``planes`` is (4, rows, cols) in R, Gr, Gb, B order; returns (H, W, 3). Linear: noise keeps its mean."""
    frame, m = _sensor_mosaic(planes, geometry)

    def filtered(kernel):
        return cv2.filter2D(frame, -1, (kernel / 8.0).astype(np.float32), borderType=cv2.BORDER_REFLECT_101)

    green, row, column, diagonal = (filtered(k) for k in (_MHC_GREEN, _MHC_ROW, _MHC_COLUMN, _MHC_DIAGONAL))
    out = np.empty(frame.shape + (3,), np.float32)
    # red: known at R; from the row at Gr (green in a red row), the column at Gb, the diagonal at B
    out[..., 0] = np.select([m["R"], m["Gr"], m["Gb"]], [frame, row, column], diagonal)
    out[..., 1] = np.where(m["Gr"] | m["Gb"], frame, green)
    out[..., 2] = np.select([m["B"], m["Gb"], m["Gr"]], [frame, row, column], diagonal)
    return _crop(out, geometry)


def demosaic_edge_aware(planes: np.ndarray, geometry) -> np.ndarray:
    """OpenCV's edge-aware demosaicing [OpenCV-EA] of the four sensel planes; returns (H, W, 3).

    OpenCV takes integers: the frame is mapped linearly onto 16 bits (1000-61000) and back, which keeps 1/240 of
    its range per step. Its Bayer code is the one that reads our red sensels as red."""
    frame, _ = _sensor_mosaic(planes, geometry)
    lo, hi = float(frame.min()), float(frame.max())
    scale = 60000.0 / max(hi - lo, 1e-9)
    u16 = np.round((frame - lo) * scale + 1000).astype(np.uint16)
    out = _crop(cv2.cvtColor(u16, _bayer_code(geometry, "_EA")), geometry).astype(np.float32)
    return (out - np.float32(1000)) / np.float32(scale) + np.float32(lo)


def demosaic_monochrome(planes: np.ndarray, geometry) -> np.ndarray:
    """A sensor without colour filters: each output pixel is its own sensel (:func:`mosaic`), in every channel;
    returns (H, W, 3). With the crosstalk's rows all equal, every sensel has seen the same mix of the light."""
    frame = mosaic(planes, geometry).astype(np.float32)
    return np.ascontiguousarray(np.repeat(frame[..., None], 3, axis=2))


#: Method name -> demosaicing function ``fn(planes, geometry) -> (H, W, 3)``: the ``method`` choices of
#: :class:`Demosaic`.
DEMOSAICERS = {"block": demosaic_block, "bilinear": demosaic_bilinear,
               "gradient_corrected": demosaic_gradient_corrected, "edge_aware": demosaic_edge_aware,
               "monochrome": demosaic_monochrome}


class Demosaic(Effect):
    """Reconstructs full-colour premultiplied RGB and per-channel alpha from the sensel planes.

    ``method = "block"``: the Fire-i's 2x2-block scheme (sec. 4.4.1); ``"bilinear"``: bilinear interpolation
    (sec. 7, and the assumption of the paper's earlier version); ``"gradient_corrected"``: Malvar-He-Cutler
    [Malvar2004]; ``"edge_aware"``: OpenCV's edge-aware method [OpenCV-EA]; ``"monochrome"``: no colour filters,
    each pixel its own sensel (with the crosstalk's rows equal, a grey sensor). Alpha travels with colour, so each
    output channel carries its own alpha (sec. 5.2 step 8).
    """

    name = "demosaic"
    section = "4.4.1, 5.2 step 8, 7"
    writes = "rgb"
    order = 200
    calibration = "demosaic"
    node = NodeStage("Demosaic", "mosaic", "demosaic")
    searches = (Search("bilinear_demosaic", "fine detail and noise correlations follow bilinear demosaicing",
                       fixed={"method": "bilinear"}, requires="demosaic"),
                Search("gradient_corrected_demosaic", "colour edges follow gradient-corrected (Malvar-He-Cutler) "
                       "demosaicing", fixed={"method": "gradient_corrected"}, requires="demosaic"),
                Search("edge_aware_demosaic", "colour edges follow edge-aware demosaicing",
                       fixed={"method": "edge_aware"}, requires="demosaic"))
    always_runs = True
    params = {"method": Param("block", str, choices=tuple(DEMOSAICERS))}

    def bake_node(self, state, bake) -> None:
        """2x2-block demosaicing as Map UVs (``demosaic_uv_R`` ...): each output pixel reads the mosaic pixel of
        its block's sensel of that colour. The node group has no other method."""
        if self.method != "block":
            raise LowcamError(f"{bake.profile.source}: the node group demosaics 2x2 blocks only, not {self.method!r}")
        g = bake.geometry
        by, bx = BAYER_BORDER
        hm, wm = mosaic_shape(g)
        yo, xo = np.mgrid[0:g.height, 0:g.width]
        for name in CFA_CHANNELS:
            dy, dx = g.cfa[name]
            i = (2 * by - dy + yo) // 2
            j = (2 * bx - dx + 1 + xo) // 2
            bake.images[f"demosaic_uv_{name}"] = stmap(2 * j + dx, 2 * i + dy, wm, hm)

    def apply(self, state):
        fn = DEMOSAICERS[self.method]
        # colour and alpha side by side (numpy and OpenCV release the GIL)
        state.rgb, state.rgb_alpha = thread_map(lambda planes: fn(planes, state.geometry),
                                                (state.bayer, state.bayer_alpha))


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


_BAYER_CODES: dict = {}


def _bayer_code(geometry, kind: str):
    """The OpenCV Bayer conversion code (``kind`` "_EA", "_VNG" or "") that reads our red sensels as red, found
    by test so that OpenCV's pattern naming cannot be misread; cached per pattern."""
    key = (tuple(sorted(geometry.cfa.items())), kind)
    if key not in _BAYER_CODES:
        _BAYER_CODES[key] = _find_bayer_code(geometry, kind)
    return _BAYER_CODES[key]


def _find_bayer_code(geometry, kind: str):
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
    fn = DEMOSAICERS[method]
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
