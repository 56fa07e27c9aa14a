"""Test scenes: exact, analytic renders; measurement sets whose hidden effect a test makes."""
import numpy as np

import lowcam

from lowcam.pipeline import render_field_of_view


def flat_render(value: float, width: int = 400, height: int = 300, alpha: float = 1.0) -> np.ndarray:
    """A uniform premultiplied render."""
    out = np.empty((height, width, 4), np.float32)
    out[..., :3] = value * alpha
    out[..., 3] = alpha
    return out


def disk_render(profile, radius: float = 0.2, centre=(0.0, 0.0), colour=(1.0, 1.0, 1.0), width: int = 1200):
    """An opaque disk with exact anti-aliased coverage; radius and centre in camera-plane units (tan angles)."""
    half_x, _ = render_field_of_view(profile)
    height = width * profile.camera.height // profile.camera.width
    focal = width / (2 * half_x)
    x = (np.arange(width) - width / 2 + 0.5) / focal
    y = (np.arange(height) - height / 2 + 0.5) / focal
    xx, yy = np.meshgrid(x, y)
    d = np.hypot(xx - centre[0], yy - centre[1])
    alpha = np.clip((radius - d) * focal + 0.5, 0, 1).astype(np.float32)
    out = np.zeros((height, width, 4), np.float32)
    out[..., :3] = alpha[..., None] * np.asarray(colour, np.float32)
    out[..., 3] = alpha
    return out


def opaque(grey: np.ndarray) -> np.ndarray:
    """An opaque render from a greyscale (H, W) or colour (H, W, 3) image in 0..1."""
    out = np.ones(grey.shape[:2] + (4,), np.float32)
    out[..., :3] = grey[..., None] if grey.ndim == 2 else grey
    return out


def noise_field(width=1600, height=1200, cells=(400, 300), seed=0, crisp=False) -> np.ndarray:
    """A grey white-noise field as an opaque render: smooth (cubic) in 0.2..0.8, or ``crisp`` square cells in
    0..1 like the printed chart's."""
    import cv2

    rng = np.random.default_rng(seed)
    how = cv2.INTER_NEAREST if crisp else cv2.INTER_CUBIC
    tex = cv2.resize(rng.random(cells[::-1]).astype(np.float32), (width, height), interpolation=how)
    return opaque(tex if crisp else np.clip(0.2 + 0.6 * tex, 0, 1))


def slanted_squares(width=1600, height=1200, supersample=4) -> np.ndarray:
    """Dark squares rotated 5 degrees on light grey, anti-aliased by supersampling."""
    import cv2

    img = np.full((height * supersample, width * supersample), 0.8, np.float32)
    for cx, cy in [(0.25, 0.3), (0.5, 0.5), (0.75, 0.7), (0.3, 0.72), (0.72, 0.28)]:
        pts = cv2.boxPoints(((cx * width * supersample, cy * height * supersample),
                             (0.12 * width * supersample, 0.12 * width * supersample), 5.0))
        cv2.fillPoly(img, [np.round(pts).astype(np.int32)], 0.15)
    return opaque(cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA))


def chessboard_view(profile, rvec, tvec, width=1600):
    """A pinhole render of a printed 9x6 chessboard (25 mm squares) at pose (rvec, tvec), on a light wall."""
    from lowcam.measure.targets import render_board_view

    board = render_board_view(profile, rvec, tvec, width=width)
    out = board.copy()
    out[..., :3] += 0.9 * (1 - board[..., 3:])
    out[..., 3] = 1.0
    return out


def quiet_fire_i():
    """Fire-i with RGB output (no 4:1:1 chroma) and saturation at identity: its output frame is its demosaiced
    frame, so an offset added to the output is an offset at the sensor's pixels."""
    p = lowcam.load_profile("fire-i").without("chroma_subsampling")
    p.effect("saturation").saturation = 65.0
    return p


def make_set(profile, folder, scenes, frames=4, seed=7, post=None, pre=None, mask=None):
    """A measurement set of bundled scenes through ``profile``; ``pre(ideal)`` changes the render before the
    camera (optical), ``post(frame)`` each delivered 8-bit frame (after everything); ``mask`` (H, W) bool: the
    pixels compared in every capture."""
    from lowcam.measure.sets import write_set
    from lowcam.measure.synth import scenes as bundled
    from lowcam.pipeline import simulate

    every = bundled(profile, 640)
    captures = []
    for i, name in enumerate(scenes):
        ideal, omega = every[name]
        render = pre(ideal) if pre else ideal
        # each capture its own noise: with one seed, frame k's noise would repeat in every capture, a fixed
        # pattern across captures that per-pixel maps would take for DSNU
        shots = [simulate(render, profile, None, omega, None, seed + 1000 * i, k) for k in range(frames)]
        captures.append({"name": name, "ideal": ideal, "frames": [post(s) if post else s for s in shots],
                         "angular_velocity": omega, "mask": mask})
    return write_set(folder, captures)


def diagnose_set(tmp_path, profile, only, rounds=2, **kw):
    from lowcam.measure.diagnose import diagnose
    from lowcam.measure.sets import load_set

    folder = make_set(profile, tmp_path / "set", **kw)
    return diagnose(load_set(folder, profile), profile, only=only, workdir=tmp_path / "work", rounds=rounds)


def film_through_mapping(folder, profile, mapping, margin, focal_px, hfov, seed, frames, fine, scene_names):
    """A measurement set whose frames look through a lens given by ``mapping`` ((rows, cols, 2): for each output
    pixel of the frame and a ``margin`` around it, the pinhole pixel of the same ray, centred, focal ``focal_px``).
    Each ideal render of ``scene_names`` (for ``profile``, a pinhole of that focal, its render ``hfov`` deg wide) is
    warped at ``fine`` times its resolution: fine render pixel -> output pixel of the pinhole profile -> the pinhole
    pixel of that ray -> render pixel; then filmed through ``profile``."""
    import cv2

    from lowcam.measure.sets import write_set
    from lowcam.measure.synth import scenes
    from lowcam.pipeline import simulate

    geo = profile.geometry
    cx, cy = (geo.width - 1) / 2, (geo.height - 1) / 2
    captures = []
    for name, (ideal, omega) in scenes(profile).items():
        if name not in scene_names:
            continue
        hr, wr = ideal.shape[:2]
        f_render = wr / (2 * np.tan(np.radians(hfov) / 2))
        yy, xx = np.mgrid[0:hr * fine, 0:wr * fine].astype(np.float64)
        u = cx + focal_px * ((xx + 0.5) / fine - 0.5 - wr / 2 + 0.5) / f_render + margin
        v = cy + focal_px * ((yy + 0.5) / fine - 0.5 - hr / 2 + 0.5) / f_render + margin
        mu, mv = (cv2.remap(mapping[..., c].astype(np.float32), u.astype(np.float32), v.astype(np.float32),
                            cv2.INTER_LINEAR) for c in (0, 1))
        sx = f_render * (mu - cx) / focal_px + wr / 2 - 0.5
        sy = f_render * (mv - cy) / focal_px + hr / 2 - 0.5
        warped = cv2.remap(ideal, sx.astype(np.float32), sy.astype(np.float32), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        shots = [simulate(warped, profile, None, omega, None, seed, n) for n in range(frames)]
        captures.append({"name": name, "ideal": ideal, "frames": shots, "angular_velocity": omega})
    return write_set(folder, captures)


def drawn(seed, **ranges):
    """Seeded parameters for an independent implementation: a list is drawn from, a (low, high) pair drawn uniformly
    within."""
    rng = np.random.default_rng(seed)
    return {k: v[int(rng.integers(len(v)))] if isinstance(v, list) else float(rng.uniform(*v))
            for k, v in ranges.items()}


def check_named_first(d, expected, bound=1.25):
    """The diagnosis ``d`` of a set hiding ``expected``: the hidden stage shows (the profile without it is not
    explained), comes first with a held-out error at most ``bound``, and a verdict that names an effect names it.
    Returns the candidate."""
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    best = d.candidates[0]
    assert d.error > 1.2, ranking
    assert best.effect == expected, ranking
    assert best.score <= bound, ranking  # held out
    assert d.verdict != "missing-effect" or d.best.effect == expected, d.summary()
    print(f"{expected}: error {d.error:.2f} -> {best.score:.3f} held out ({best.params}); {d.verdict}")
    return best
