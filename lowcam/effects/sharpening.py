"""In-camera sharpening: horizontal unsharp masking and its calibration (Klein & Murray 2010, sec. 4.4.3).

The camera sharpens each colour channel's 320x240 image horizontally (sec. 5.2 step 7). The paper measures a
long, asymmetric 101-tap filter and simulates it with the symmetric 7-tap ``F = I + a (I - L)``, ``L`` a Gaussian
of sigma 0.55 sensels. The relation between ``a`` and the sharpness setting was lost from the text; here
``a = gain_per_unit * sharpness`` (a profile parameter; see :class:`Sharpening`).

Contents
--------
- :func:`sharpening_kernel`: the row filter of ``F = I + a (I - L)``, ``L`` a Gaussian, optionally off centre
- :class:`Sharpening`: horizontal unsharp masking ``F = I + a (I - L)`` on each sensel plane
- :func:`fit_row_filter`: the free FIR filter mapping soft rows onto sharp rows (the paper's 101-tap estimate)
- :func:`frequency_response`: |H(f)| of a centred FIR kernel from 0 to Nyquist (cycles/sample)
- :func:`fit_sharpening_to_images`: (a, sigma) of ``F = I + a (I - L_sigma)`` fitted to the images themselves
- :func:`edge_profile_statistic`: the mean edge profile across strong natural edges: 10-90 % width, overshoot
- :func:`edge_profile_from_plate`: horizontal blur and sharpening from footage's natural edges (a PlateEstimate)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import numpy as np

from .base import Effect, NodeStage, Param, Search
from .blur import filter_rows, gaussian_taps


def sharpening_kernel(a: float, sigma: float, taps: int = 7, shift: float = 0.0, dtype=np.float32) -> np.ndarray:
    """The row filter of ``F = I + a (I - L)``, ``L`` a ``taps``-tap Gaussian of ``sigma`` sensels centred
    ``shift`` sensels off the middle tap (sec. 4.4.3)."""
    x = np.arange(taps) - (taps - 1) / 2 - shift
    low = np.exp(-0.5 * (x / sigma) ** 2)
    return ((1 + a) * gaussian_taps(0.0, taps, np.float64) - a * low / low.sum()).astype(dtype)


class Sharpening(Effect):
    """Horizontal unsharp masking ``F = I + a (I - L)`` on each sensel plane, ``L`` a ``taps``-tap Gaussian.

    The paper sets ``a`` from the camera's sharpness control; the constant that relates them was lost in the
    text extraction. We use ``a = gain_per_unit * sharpness`` with ``gain_per_unit = 0.025``, so the Fire-i's
    default 80 gives ``a = 2`` (about 2x gain at the sensel Nyquist frequency with sigma 0.55) and PTAM's
    recommended 25 gives ``a = 0.6``. Both numbers are profile parameters.
    """

    name = "sharpening"
    section = "4.4.3, 5.2 step 7"
    writes = "bayer"
    order = 170
    calibration = "sharpening"
    node = NodeStage("Sharpening", "mosaic", "kernel")
    searches = (Search("asymmetric_sharpening",
                       "sharpening halos are lopsided: its low-pass sits {shift:+.2f} sensels off centre",
                       bounds={"shift": (-2.0, 2.0)}, captures="textured", requires="sharpening"),)
    params = {
        "sharpness": Param(80.0, low=0.0, high=255.0, doc="the camera's sharpness setting"),
        "gain_per_unit": Param(0.025, low=0.0, high=1.0),
        "sigma": Param(0.55, low=0.01, high=10.0, unit="sensels"),
        "taps": Param(7, int, low=3, high=31),
        "shift": Param(0.0, low=-3.0, high=3.0, unit="sensels",
                       doc="centre of L: non-zero makes the filter asymmetric, as the Fire-i's really is (Fig. 8)"),
    }

    def check(self):
        if self.taps % 2 == 0:
            raise self.error("'taps' must be odd")

    def kernel(self) -> np.ndarray:
        return sharpening_kernel(self.gain_per_unit * self.sharpness, self.sigma, self.taps, self.shift)

    def apply(self, state):
        filter_rows(state, self.kernel())


def fit_row_filter(soft: np.ndarray, sharp: np.ndarray, taps: int = 101) -> np.ndarray:
    """The ``taps``-tap FIR filter h with ``sharp[row] = soft[row] * h`` in the least-squares sense over every
    row of two 2-D images of the same static scene (the paper's 101-tap estimate, sec. 4.4.3)."""
    soft = np.asarray(soft, np.float64)
    sharp = np.asarray(sharp, np.float64)
    half = taps // 2
    rows, cols = soft.shape
    ata = np.zeros((taps, taps))
    atb = np.zeros(taps)
    for r in range(rows):
        x = soft[r]
        a = np.lib.stride_tricks.sliding_window_view(x, taps)[:, ::-1]  # a[i, k] = x[i + half - (k - half)]
        b = sharp[r, half:cols - half]
        ata += a.T @ a
        atb += a.T @ b
    return np.linalg.solve(ata + 1e-9 * np.trace(ata) / taps * np.eye(taps), atb)


def frequency_response(kernel: np.ndarray, n: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """|H(f)| of a symmetric-centred FIR kernel at ``n`` frequencies from 0 to Nyquist (cycles/sample)."""
    f = np.linspace(0, 0.5, n)
    k = np.arange(len(kernel)) - (len(kernel) - 1) / 2
    return f, np.abs(np.exp(-2j * np.pi * np.outer(f, k)) @ kernel)


def fit_sharpening_to_images(soft: np.ndarray, sharp: np.ndarray, taps: int = 7) -> tuple[float, float]:
    """(a, sigma) of ``F = I + a (I - L_sigma)`` that best maps the rows of ``soft`` onto ``sharp`` (least
    squares in the image, so only frequencies the scene actually contains decide the fit). Pixels clipped at 0
    or 255 in ``sharp`` are left out: their overshoot is lost."""
    from scipy.optimize import least_squares

    soft = np.asarray(soft, np.float64)
    sharp = np.asarray(sharp, np.float64)
    half = taps // 2
    windows = np.lib.stride_tricks.sliding_window_view(soft, taps, axis=1)
    target = sharp[:, half:soft.shape[1] - half]
    valid = (target > 0.5) & (target < 254.5)

    def residual(p):
        return (windows @ sharpening_kernel(*p, taps, dtype=np.float64)[::-1] - target)[valid]

    sol = least_squares(residual, [1.0, 0.6], bounds=([0.0, 0.2], [20.0, 3.0]))
    return float(sol.x[0]), float(sol.x[1])


def edge_profile_statistic(frames) -> dict:
    """The mean edge profile across strong natural edges of a stack (T, H, W, 3) float32 DN."""
    raise NotImplementedError


def edge_profile_from_plate(footage, base=None):
    """Horizontal blur sigma and sharpening gain from footage's natural edges, as a PlateEstimate."""
    raise NotImplementedError
