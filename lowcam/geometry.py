"""Pixel grids of the simulation and the Bayer colour-filter layout.

Coordinates are in **output pixels** (the camera's frame, e.g. 640x480), x right and y down, with pixel centres on
integers (Klein & Murray 2010, sec. 5.2; PTAM's convention). The *working grid* covers the output frame plus a
margin of ``margin_px`` on every side, at ``oversample`` working pixels per output pixel (the paper's 1024x768 image,
step 2); the lens stage renders into twice that resolution (the paper's 2048x1536, step 1). Each Bayer channel's
sensel plane has half the frame's rows and columns plus borders (326x242 for 640x480, step 5); the default
pattern is the Fire-i's GBRG (sec. 4.2).

Contents
--------
- :data:`CFA_CHANNELS`: the Bayer channels in sensel-plane order: R, Gr, Gb, B
- :data:`COLOUR_INDEX`: the RGB component of each of :data:`CFA_CHANNELS`
- :data:`BAYER_BORDER`: border sensels kept around each plane: 1 row, 3 columns
- :func:`cfa_offsets`: row/column offset of each of R, Gr, Gb, B in the 2x2 cell of a pattern such as ``"GBRG"``
- :class:`FrameGeometry`: output frame size, working-grid margin and oversampling, and Bayer layout
- :func:`sample_texture`: bilinear lookup of a texture over ``extent`` = (u0, v0, u1, v1), texels at cell centres
- :func:`grid_points`: output-pixel centres of a ``cells`` = (columns, rows) partition of ``extent``

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [Klein2007] G. Klein and D. Murray, "Parallel Tracking and Mapping for Small AR Workspaces", ISMAR 2007 (PTAM;
  its camera's pixel convention).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

#: Bayer channels in the order used for sensel planes. ``COLOUR_INDEX`` maps each to its RGB component.
CFA_CHANNELS = ("R", "Gr", "Gb", "B")
COLOUR_INDEX = (0, 1, 1, 2)
#: Border sensels kept around each 320x240 plane: 1 row, 3 columns (the paper's 326x242, step 5).
BAYER_BORDER = (1, 3)


def cfa_offsets(pattern: str) -> dict[str, tuple[int, int]]:
    """Row/column offset of each of R, Gr, Gb, B inside the 2x2 cell of a Bayer ``pattern`` such as ``"GBRG"``.

    The pattern lists the cell in scan order (top-left, top-right, bottom-left, bottom-right). Gr is the green
    sensel on the red row, Gb the one on the blue row.

    >>> cfa_offsets("GBRG")
    {'R': (1, 0), 'Gr': (1, 1), 'Gb': (0, 0), 'B': (0, 1)}
    """
    pattern = pattern.upper()
    if sorted(pattern) != ["B", "G", "G", "R"]:
        raise ValueError(f"Bayer pattern must be a permutation of RGGB, got {pattern!r}")
    cells = {(i // 2, i % 2): c for i, c in enumerate(pattern)}
    red_row = next(pos[0] for pos, c in cells.items() if c == "R")
    out = {}
    for pos, c in cells.items():
        key = c if c != "G" else ("Gr" if pos[0] == red_row else "Gb")
        out[key] = pos
    return {k: out[k] for k in CFA_CHANNELS}


@dataclass(frozen=True)
class FrameGeometry:
    """Output frame size, working-grid margin and oversampling, and Bayer layout."""

    width: int
    height: int
    margin_px: float = 16.0
    oversample: float = 1.6
    bayer_pattern: str = "GBRG"

    def __deepcopy__(self, memo):
        """Itself: a geometry never changes, so the copies of a profile share it and the arrays it keeps
        (:attr:`sensel_positions`, read-only), as diagnosis copies profiles by the hundred."""
        return self

    @cached_property
    def working_shape(self) -> tuple[int, int]:
        """(rows, columns) of the working grid; even, so the 2x2 half-sampling is exact."""
        w = int(round((self.width + 2 * self.margin_px) * self.oversample))
        h = int(round((self.height + 2 * self.margin_px) * self.oversample))
        return h, w

    @cached_property
    def working_scale(self) -> tuple[float, float]:
        """Working pixels per output pixel along (x, y)."""
        h, w = self.working_shape
        return w / (self.width + 2 * self.margin_px), h / (self.height + 2 * self.margin_px)

    def output_to_working(self, u, v, factor: int = 1):
        """Map output-pixel coordinates to working-grid pixel coordinates (``factor`` 2: the supersampled grid)."""
        sx, sy = self.working_scale
        return ((u + self.margin_px + 0.5) * sx * factor - 0.5, (v + self.margin_px + 0.5) * sy * factor - 0.5)

    def working_to_output(self, x, y, factor: int = 1):
        sx, sy = self.working_scale
        return ((x + 0.5) / (sx * factor) - self.margin_px - 0.5, (y + 0.5) / (sy * factor) - self.margin_px - 0.5)

    def working_pixel_centres(self, factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Output-pixel coordinates (u, v) of every working pixel centre, as 2-D float64 arrays."""
        h, w = self.working_shape
        x = np.arange(w * factor, dtype=np.float64)
        y = np.arange(h * factor, dtype=np.float64)
        u, _ = self.working_to_output(x, 0.0, factor)
        _, v = self.working_to_output(0.0, y, factor)
        return np.meshgrid(u, v)

    @property
    def working_extent(self) -> tuple[float, float, float, float]:
        """(u0, v0, u1, v1): outer edges of the working grid in output pixels."""
        m = self.margin_px
        return (-m - 0.5, -m - 0.5, self.width + m - 0.5, self.height + m - 0.5)

    @property
    def frame_extent(self) -> tuple[float, float, float, float]:
        """(u0, v0, u1, v1): outer edges of the output frame."""
        return (-0.5, -0.5, self.width - 0.5, self.height - 0.5)

    @cached_property
    def cfa(self) -> dict[str, tuple[int, int]]:
        return cfa_offsets(self.bayer_pattern)

    @cached_property
    def bayer_shape(self) -> tuple[int, int]:
        """(rows, columns) of each sensel plane, borders included (326x242 for a 640x480 frame)."""
        by, bx = BAYER_BORDER
        return self.height // 2 + 2 * by, self.width // 2 + 2 * bx

    @cached_property
    def sensel_positions(self) -> np.ndarray:
        """(4, rows, cols, 2) output-pixel positions (u, v) of the sensels of R, Gr, Gb, B."""
        by, bx = BAYER_BORDER
        hb, wb = self.bayer_shape
        i = np.arange(hb) - by
        j = np.arange(wb) - bx
        out = np.empty((4, hb, wb, 2), np.float64)
        for k, name in enumerate(CFA_CHANNELS):
            dy, dx = self.cfa[name]
            jj, ii = np.meshgrid(2 * j + dx, 2 * i + dy)
            out[k, ..., 0] = jj
            out[k, ..., 1] = ii
        out.flags.writeable = False     # shared by every copy of the profile
        return out


def sample_texture(texture: np.ndarray, extent, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a texture that covers ``extent`` = (u0, v0, u1, v1) with texel centres at cell centres.

    Lookups beyond the outermost texel centres clamp to the edge (the paper's grids and the 80x60 vignetting map
    are used this way). ``u`` and ``v`` are arrays of any (equal) shape; the result has that shape plus the
    texture's channels.
    """
    tex = np.ascontiguousarray(texture, dtype=np.float32)
    th, tw = tex.shape[:2]
    u0, v0, u1, v1 = extent
    shape = np.shape(u)
    tu = ((np.asarray(u) - u0) * (tw / (u1 - u0)) - 0.5).astype(np.float32).reshape(-1, 1)
    tv = ((np.asarray(v) - v0) * (th / (v1 - v0)) - 0.5).astype(np.float32).reshape(-1, 1)
    # cv2.remap wants maps of at most 32767 rows: fold the points into a 2-D block.
    n = tu.shape[0]
    cols = 1024 if n > 1024 else n
    rows = -(-n // cols)
    pad = rows * cols - n
    if pad:
        tu = np.concatenate([tu, np.zeros((pad, 1), np.float32)])
        tv = np.concatenate([tv, np.zeros((pad, 1), np.float32)])
    out = cv2.remap(tex, tu.reshape(rows, cols), tv.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    channels = tex.shape[2:]
    return out.reshape((rows * cols,) + channels)[:n].reshape(shape + channels)


def grid_points(extent, cells=(24, 18)) -> tuple[np.ndarray, np.ndarray]:
    """Output-pixel coordinates of the centres of a ``cells`` = (columns, rows) partition of ``extent``.

    The paper evaluates blur and motion on a 24x18-cell grid (sec. 5.2, steps 3-4; after Watson and Hodges).
    """
    u0, v0, u1, v1 = extent
    nx, ny = cells
    u = u0 + (np.arange(nx) + 0.5) * (u1 - u0) / nx
    v = v0 + (np.arange(ny) + 0.5) * (v1 - v0) / ny
    return np.meshgrid(u, v)
