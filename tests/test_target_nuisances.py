"""A target capture's own nuisances (paper margin, white, black, lighting) are fitted before the camera is blamed.

The frames are made here, outside the engine's board renderer: a chessboard drawn analytically on a plane (white
paper with a known margin on a dark table, a known linear light gradient), warped with cv2.warpPerspective into
the ideal pinhole view at a known pose, and put through the Fire-i profile (with its noise) as the measured frames.
"""
import cv2
import numpy as np
import pytest

import lowcam
from lowcam.io import write_png
from lowcam.measure.compare import compare
from lowcam.measure.sets import load_set
from lowcam.measure.targets import fit_target, ideal_from_target

INNER, SQUARE = (9, 6), 0.025
WHITE, BLACK, TABLE, WALL = 0.8, 0.07, 0.15, 0.5
MARGINS = (0.6, 0.45, 0.8, 0.55)  # white paper beyond the squares: left, top, right, bottom (squares)
LIGHT = (0.15, -0.10)  # L = 1 + 0.15 s - 0.10 t, s and t -1..1 across the squares
POSE = (np.array([0.2, -0.25, 0.05]), np.array([-0.105, -0.07, 0.36]))
PX = 80  # texture pixels per square, drawn with 4x4 supersampling


def _plane_texture(pad: float = 4.0):
    """The board's plane: squares, paper margin, table; lit. Returns (texture, position of (u, v) = (0, 0))."""
    cols, rows = INNER[0] + 1, INNER[1] + 1
    ss = 4
    n_u, n_v = int((cols + 2 * pad) * PX), int((rows + 2 * pad) * PX)
    u = (np.arange(n_u * ss) + 0.5) / (PX * ss) - pad - 1
    v = (np.arange(n_v * ss) + 0.5) / (PX * ss) - pad - 1
    uu, vv = np.meshgrid(u, v)
    left, top, right, bottom = MARGINS
    paper = (uu > -1 - left) & (uu < INNER[0] + right) & (vv > -1 - top) & (vv < INNER[1] + bottom)
    squares = (uu > -1) & (uu < INNER[0]) & (vv > -1) & (vv < INNER[1])
    dark = squares & ((np.floor(uu) + np.floor(vv)) % 2 == 0)
    s, t = (uu - (INNER[0] - 1) / 2) / (cols / 2), (vv - (INNER[1] - 1) / 2) / (rows / 2)
    light = 1 + LIGHT[0] * s + LIGHT[1] * t
    tex = np.where(paper, np.where(dark, BLACK, WHITE), TABLE) * light
    tex = tex.reshape(n_v, ss, n_u, ss).mean(axis=(1, 3)).astype(np.float32)
    return tex, (pad + 1) * PX


def _ideal_view(profile, width=1600):
    """The analytic board warped into the ideal pinhole camera at POSE, a light wall beyond the table."""
    from lowcam.pipeline import render_field_of_view

    half_x, _ = render_field_of_view(profile)
    height = width * profile.camera.height // profile.camera.width
    f = width / (2 * half_x)
    k = np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1]])
    tex, origin = _plane_texture()
    s = SQUARE / PX
    to_m = np.array([[s, 0, -origin * s + 0.5 * s], [0, s, -origin * s + 0.5 * s], [0, 0, 1]])
    r = cv2.Rodrigues(POSE[0])[0]
    h = k @ np.column_stack([r[:, 0], r[:, 1], POSE[1]]) @ to_m
    grey = cv2.warpPerspective(tex, h, (width, height), flags=cv2.INTER_LINEAR, borderValue=WALL)
    out = np.ones((height, width, 4), np.float32)
    out[..., :3] = grey[..., None]
    return out


@pytest.fixture(scope="module")
def board_set(tmp_path_factory):
    profile = lowcam.load_profile("fire-i")
    folder = tmp_path_factory.mktemp("board")
    ideal = _ideal_view(profile)
    for k in range(4):
        write_png(folder / "frames" / f"board-{k:03d}.png", lowcam.simulate(ideal, profile, seed=7, frame=k))
    (folder / "set.toml").write_text('[[capture]]\nname = "board"\ntarget = "checkerboard:9x6:0.025"\n'
                                     'frames = ["frames/board-*.png"]\n')
    return profile, load_set(folder, profile)


def test_board_nuisances_fitted_from_the_frames(board_set):
    profile, mset = board_set
    _, rvec, tvec, fit = fit_target(profile, mset.captures[0])
    assert np.allclose(rvec, POSE[0], atol=0.01) and np.allclose(tvec, POSE[1], atol=0.002), (rvec, tvec)
    assert not fit.flipped
    assert fit.white == pytest.approx(WHITE, rel=0.03)
    assert fit.black == pytest.approx(BLACK, rel=0.05)
    assert fit.illumination[0] == pytest.approx(LIGHT[0], abs=0.01)
    assert fit.illumination[1] == pytest.approx(LIGHT[1], abs=0.01)
    assert abs(fit.illumination[2]) < 0.01
    assert np.allclose(fit.margins, MARGINS, atol=0.04), fit.margins


def test_compare_reaches_the_noise_floor_only_with_the_nuisances_fitted(board_set):
    profile, mset = board_set
    fitted = compare(mset, profile)
    fixed = compare(mset, profile, inputs=[ideal_from_target(profile, mset.captures[0], nuisances=False)])
    # the mean family: the nuisances' residual in noise units. (The variance and rows families of a target
    # capture with several frames are off for another reason: the plate around the paper carries no model noise.)
    assert fitted.families["mean"] <= 2.0, fitted.families
    assert fixed.families["mean"] > 10.0, fixed.families
