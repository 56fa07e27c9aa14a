"""ColorChecker captures: the chart found, its patches read with their noise, and a camera's colour matrix and tone
curve fitted from them (``lowcam calibrate colour --target colorchecker``, ``target = "colorchecker"`` captures).

The charts are rendered here: the 24 patches of colour-science's reference colours in the chart's layout (black
gaps and frame), warped in perspective, seen by hidden cameras whose colour matrices come from colour-science's
camera spectral sensitivities (integrated against the patches' reflectances under an illuminant, fitted as a
3x3 matrix from the working space, white balanced) and hidden tone curves from colour-science's transfer
functions. The real chart is Infinite-ISP's raw ColorChecker frame (``../shared/data/infinite-isp-raw``).
"""
from __future__ import annotations

import os
from pathlib import Path

import colour
import cv2
import numpy as np
import pytest

from lowcam.colour_checker import (COLUMNS, NEUTRALS, ROWS, find_chart, read_colour_checker, read_patches,
                                   reference_colours)
from lowcam.effects.saturation import colour_matrix_problems, saturation_matrix
from lowcam.errors import LowcamError

DATA = Path(os.environ.get("LOWCAM_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")
SHAPE = colour.SpectralShape(400, 700, 5)
ILLUMINANTS = ("D65", "D50", "A", "FL2", "FL11")


def camera_matrix(rng) -> tuple[np.ndarray, str]:
    """A camera's white-balanced colour matrix (rows sum to 1: linear Rec.709 -> camera RGB) and its description:
    colour-science's camera sensitivities (a random mix of the two cameras it holds, each channel shifted by up
    to 8 nm) integrated against the Ohta ColorChecker reflectances under a random illuminant, then the 3x3
    matrix fitted from the patches' reference colours."""
    names = list(colour.MSDS_CAMERA_SENSITIVITIES)
    mix = rng.uniform(0.0, 0.35)
    shifts = rng.uniform(-8, 8, 3)
    ill = ILLUMINANTS[rng.integers(len(ILLUMINANTS))]
    wl = SHAPE.wavelengths
    sens = np.zeros((len(wl), 3))
    for name, weight in zip(names, (1 - mix, mix)):
        msds = colour.MSDS_CAMERA_SENSITIVITIES[name].copy().align(SHAPE, extrapolator_kwargs={"method": "Constant",
                                                                                                "left": 0, "right": 0})
        for c in range(3):
            sens[:, c] += weight * np.interp(wl - shifts[c], wl, msds.values[:, c], left=0, right=0)
    refl = np.array([sd.copy().align(SHAPE).values for sd in colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()])
    light = colour.SDS_ILLUMINANTS[ill].copy().align(SHAPE).values
    rgb = (refl * light) @ sens
    m = np.linalg.lstsq(reference_colours(), rgb, rcond=None)[0].T
    return m / m.sum(axis=1, keepdims=True), f"{names[0]} + {mix:.2f} {names[1]}, shifts {np.round(shifts, 1)} nm, {ill}"


def render_chart(light: np.ndarray, size=(640, 480), corners=None, background=0.18, frame=0.03,
                 supersample: int = 4) -> np.ndarray:
    """(H, W, 3) float linear light: a ColorChecker (24 patches ``light`` (24, 3) in a 6 x 4 grid, each 0.86 of its
    cell, black gaps and a frame of ``frame``) on a grey ``background``, the grid's outer corners at ``corners``
    (pixels: top-left, top-right, bottom-right, bottom-left), edges anti-aliased."""
    w, h = size
    if corners is None:
        corners = np.array([[0.15 * w, 0.2 * h], [0.85 * w, 0.2 * h], [0.85 * w, 0.2 * h + 0.7 * w * 4 / 6],
                            [0.15 * w, 0.2 * h + 0.7 * w * 4 / 6]])
    cell = 64
    chart = np.full((ROWS * cell + cell // 2, COLUMNS * cell + cell // 2, 3), frame, np.float32)
    pad = cell // 4
    for k in range(24):
        y, x = pad + (k // COLUMNS) * cell, pad + (k % COLUMNS) * cell
        g = int(round(0.07 * cell))
        chart[y + g:y + cell - g, x + g:x + cell - g] = light[k]
    src = np.array([[pad, pad], [pad + COLUMNS * cell, pad], [pad + COLUMNS * cell, pad + ROWS * cell],
                    [pad, pad + ROWS * cell]], np.float32)
    s = supersample
    hom = cv2.getPerspectiveTransform(src - 0.5, (np.asarray(corners, np.float32) + 0.5) * s - 0.5)
    big = cv2.warpPerspective(chart, hom, (w * s, h * s), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=(np.nan, np.nan, np.nan))  # the cyan's red is below 0 in Rec.709
    big = np.where(np.isnan(big), np.float32(background), big)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


def jittered_corners(rng, size=(640, 480), jitter=0.04):
    w, h = size
    base = np.array([[0.15 * w, 0.18 * h], [0.85 * w, 0.18 * h], [0.85 * w, 0.18 * h + 0.7 * w * 4 / 6],
                     [0.15 * w, 0.18 * h + 0.7 * w * 4 / 6]])
    return base + rng.uniform(-jitter, jitter, base.shape) * w
