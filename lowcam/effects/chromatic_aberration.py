"""Lateral chromatic aberration: per-channel sampling offsets (Klein & Murray 2010, sec. 4.1, 5.2 step 5)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..errors import LowcamError
from ..geometry import grid_points
from .base import Effect, Param

CSV_COLUMNS = ["u", "v", "red_du", "red_dv", "blue_du", "blue_dv"]


def read_ca_grid(path: Path) -> np.ndarray:
    """Read a chromatic-aberration grid CSV.

    Format: a header ``u,v,red_du,red_dv,blue_du,blue_dv`` and one row per grid point. ``u, v`` are the point's
    output-pixel coordinates: the cell centres of a regular partition of the output frame (24x18 cells in the
    paper), rows in scan order. ``red_du, red_dv`` say where the red sensels sample the image relative to green,
    in output pixels (positive ``du``: to the right); likewise blue. Returns an array (rows, cols, 4).
    """
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise LowcamError(f"{path}: cannot read the chromatic-aberration grid: {e.strerror}") from None
    if not rows or [c.strip() for c in rows[0]] != CSV_COLUMNS:
        raise LowcamError(f"{path}: the chromatic-aberration grid must start with the header {','.join(CSV_COLUMNS)}")
    try:
        data = np.array([[float(c) for c in r] for r in rows[1:] if r], np.float64)
    except ValueError:
        raise LowcamError(f"{path}: the chromatic-aberration grid holds a value that is not a number") from None
    nu, nv = len(np.unique(data[:, 0])), len(np.unique(data[:, 1]))
    if data.shape != (nu * nv, 6) or not np.all(np.isfinite(data)):
        raise LowcamError(f"{path}: the chromatic-aberration grid is not a full {nu}x{nv} grid of finite numbers")
    order = np.lexsort((data[:, 0], data[:, 1]))
    return data[order, 2:].reshape(nv, nu, 4)


def write_ca_grid(path: Path, grid: np.ndarray, width: int, height: int) -> None:
    """Write ``grid`` (rows, cols, 4) for an output frame of ``width`` x ``height`` in :func:`read_ca_grid`'s format."""
    from ..io import atomic_write_bytes

    rows, cols = grid.shape[:2]
    u, v = grid_points((-0.5, -0.5, width - 0.5, height - 0.5), (cols, rows))
    lines = [",".join(CSV_COLUMNS)]
    for i in range(rows):
        for j in range(cols):
            lines.append(",".join(f"{x:.6g}" for x in (u[i, j], v[i, j], *grid[i, j])))
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())


def radial_ca_grid(width, height, red_px, blue_px, cells=(24, 18), cubic=0.0) -> np.ndarray:
    """A lateral-colour grid from a radial model: displacement ``s (rho + cubic rho^3) / (1 + cubic)`` outward,
    ``rho`` = radius / half-diagonal, ``s`` = ``red_px`` or ``blue_px`` (the displacement at the corner)."""
    u, v = grid_points((-0.5, -0.5, width - 0.5, height - 0.5), cells)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    half_diag = np.hypot(width, height) / 2
    du, dv = (u - cx) / half_diag, (v - cy) / half_diag
    rho = np.hypot(du, dv)
    gain = (1 + cubic * rho**2) / (1 + cubic)
    return np.stack([red_px * du * gain, red_px * dv * gain, blue_px * du * gain, blue_px * dv * gain], -1)


class ChromaticAberration(Effect):
    """Red and blue sensels sample the image through their own offset grids; green is the reference.

    Either ``texture`` (a CSV grid, see :func:`read_ca_grid`) or the radial model of :func:`radial_ca_grid`
    with ``red_corner_px``, ``blue_corner_px`` and ``cubic``.
    """

    name = "chromatic_aberration"
    section = "4.1, 5.2 step 5"
    writes = "sampling"
    params = {
        "texture": Param("", "path", doc="CSV grid; empty: use the radial model"),
        "red_corner_px": Param(0.0, low=-50.0, high=50.0, unit="px", doc="outward shift of red at the corner"),
        "blue_corner_px": Param(0.0, low=-50.0, high=50.0, unit="px", doc="outward shift of blue at the corner"),
        "cubic": Param(0.0, low=0.0, high=100.0, doc="weight of the rho^3 term of the radial model"),
    }

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._grid = read_ca_grid(self.texture) if self.texture else None

    def grid(self, width: int, height: int) -> np.ndarray:
        """(rows, cols, 4) offsets [red_du, red_dv, blue_du, blue_dv] over the output frame."""
        if self._grid is not None:
            return self._grid
        return radial_ca_grid(width, height, self.red_corner_px, self.blue_corner_px, cubic=self.cubic)

    def apply(self, state):
        g = state.geometry
        state.ca_grid = self.grid(g.width, g.height).astype(np.float32)
