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
- :data:`EDGE_HALF_PX`, :data:`MIN_EDGES`, :data:`EDGE_FRAMES`: the edge profiles' half-length (px), the edges an
  estimate needs and the frames it measures
- :func:`edge_profile_statistic`: the mean edge profile across strong natural edges: 10-90 % width, overshoot
- :func:`model_edge_profiles`: that statistic of a profile filming ideal steps
- :func:`edge_profile_from_plate`: horizontal blur and sharpening from footage's natural edges (a PlateEstimate)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
- [ISO12233] ISO 12233:2017, "Photography - Electronic still picture imaging - Resolution and spatial frequency
  responses" (edge spread, 10-90 % rise).
"""
from __future__ import annotations

import cv2
import numpy as np

from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, NodeStage, Param, Search
from .blur import filter_rows, gaussian_taps


def sharpening_kernel(a: float, sigma: float, taps: int = 7, shift: float = 0.0, tail: float = 0.0,
                      dtype=np.float32) -> np.ndarray:
    """The row filter of ``F = I + a (I - L)``, ``L`` a ``taps``-tap Gaussian of ``sigma`` sensels centred
    ``shift`` sensels off the middle tap (sec. 4.4.3), convolved with a one-sided exponential tail whose taps fall
    by the factor ``|tail|`` per sensel (an analog RC low-pass sampled at the sensel pitch: ``exp(-1 / tau)``),
    towards higher taps when ``tail`` > 0, lower when < 0; truncated to the ``taps`` window."""
    x = np.arange(taps) - (taps - 1) / 2 - shift
    low = np.exp(-0.5 * (x / sigma) ** 2)
    if tail:
        decay = abs(tail) ** np.arange(taps)
        low = np.convolve(low, decay)[:taps] if tail > 0 else np.convolve(low[::-1], decay)[:taps][::-1]
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
                       "sharpening halos are lopsided: its low-pass (sigma {sigma:.2f}) sits {shift:+.2f} sensels off "
                       "centre with a tail falling {tail:+.2f} per sensel",
                       bounds={"shift": (-2.0, 2.0), "sigma": (0.3, 1.5), "tail": (-0.8, 0.8)}, fixed={"taps": 9},
                       captures="textured", requires="sharpening"),)
    params = {
        "sharpness": Param(80.0, low=0.0, high=255.0, doc="the camera's sharpness setting"),
        "gain_per_unit": Param(0.025, low=0.0, high=1.0),
        "sigma": Param(0.55, low=0.01, high=10.0, unit="sensels"),
        "taps": Param(7, int, low=3, high=31),
        "shift": Param(0.0, low=-3.0, high=3.0, unit="sensels",
                       doc="centre of L: non-zero makes the filter asymmetric, as the Fire-i's really is (Fig. 8)"),
        "tail": Param(0.0, low=-0.95, high=0.95,
                      doc="L's one-sided exponential tail: the fall per sensel (its sign is its side; 0: none)"),
    }

    def check(self):
        if self.taps % 2 == 0:
            raise self.error("'taps' must be odd")

    def kernel(self) -> np.ndarray:
        return sharpening_kernel(self.gain_per_unit * self.sharpness, self.sigma, self.taps, self.shift, self.tail)

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


#: Half-length (px) of the edge profiles measured across natural edges; the outer 2 px each side are the plateaus.
EDGE_HALF_PX = 8.0
#: An orientation needs this many strong straight edges for an estimate (fewer: too little texture).
MIN_EDGES = 20
#: Frames of the footage whose edges :func:`edge_profile_from_plate` measures (spread over the clip).
EDGE_FRAMES = 16
#: Near-horizontal edges wider than the base's frame of a step by more than this factor: a soft scene.
SOFT_SCENE = 1.15


def _find_edges(g: np.ndarray, contrast_dn: float) -> list[tuple[int, float]]:
    """``(row, x)`` of strong, near-vertical, straight edges of ``g``: gradient peaks along x (parabolic sub-pixel
    position) found on a copy blurred by 1 px, so that the noise at the sampled pixels does not choose which edges
    are kept (that would favour noise that steepens them)."""
    soft = cv2.GaussianBlur(g, (0, 0), 1.0)
    gx = cv2.Sobel(soft, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(soft, cv2.CV_32F, 0, 1, ksize=3)
    a = np.abs(gx)
    r = int(np.ceil(EDGE_HALF_PX)) + 1
    w = g.shape[1]
    peak = np.zeros_like(a, bool)
    peak[2:-2, r:-r] = ((a[2:-2, r:-r] >= a[2:-2, r - 1:-r - 1]) & (a[2:-2, r:-r] > a[2:-2, r + 1:w - r + 1])
                        & (a[2:-2, r:-r] > 4 * contrast_dn) & (np.abs(gy[2:-2, r:-r]) < 0.25 * a[2:-2, r:-r]))
    # straight-ish: the edge continues two rows above and below, with the same sign, within one pixel
    same = np.sign(gx)
    cont = np.zeros_like(peak)
    for dy in (-2, 2):
        near = np.zeros_like(peak)
        for dx in (-1, 0, 1):
            near |= (np.roll(np.roll(a, -dy, 0), -dx, 1) > 0.5 * a) & (np.roll(np.roll(same, -dy, 0), -dx, 1) == same)
        cont = near if dy == -2 else cont & near
    found = []
    for y, x in zip(*np.nonzero(peak & cont)):
        l, c, rr = a[y, x - 1], a[y, x], a[y, x + 1]
        den = l - 2 * c + rr
        found.append((int(y), float(x + (0.5 * (l - rr) / den if den < 0 else 0.0))))
    return found


def _gain_slope_field(rows: np.ndarray, at: np.ndarray, shape, offsets: np.ndarray) -> np.ndarray:
    """The local gain slope ``e`` (per px, along x) at each edge: a smooth cubic field of position fitted to every
    edge's plateaus.

    Vignetting or shading multiplies an edge by a gain that changes across the window (up to 10 % over 16 px near a
    frame's corner); it tilts each plateau in proportion to its level, ``c (1 + e x)``, and biases the edge's shape.
    One edge's plateaus are too short and noisy to give ``e``; the field, fitted by least squares over all edges
    (each weighted by its plateau levels), is not."""
    sides = (offsets <= -EDGE_HALF_PX + 2, offsets >= EDGE_HALF_PX - 2)
    slope = np.zeros(len(rows))
    weight = np.zeros(len(rows))
    for side in sides:  # per side: rows[side] ~ alpha + beta x with beta = e alpha
        x = offsets[side] - offsets[side].mean()
        alpha = rows[:, side].mean(1)
        beta = rows[:, side] @ x / (x @ x)
        slope += beta * alpha
        weight += alpha ** 2
    e = slope / np.maximum(weight, 1e-12)  # each edge's own (noisy) estimate, weight its precision
    h, w = shape
    u, v = 2 * at[:, 1] / w - 1, 2 * at[:, 0] / h - 1
    degree = 3 if len(rows) >= 60 else 1
    terms = np.stack([u ** i * v ** j for i in range(degree + 1) for j in range(degree + 1 - i)], 1)
    sw = np.sqrt(weight / max(weight.max(), 1e-12))
    coef = np.linalg.lstsq(terms * sw[:, None], e * sw, rcond=None)[0]
    return terms @ coef


def _edge_profiles(grey: np.ndarray, contrast_dn: float = 20.0, at=None, found=None):
    """(profiles, positions): normalised profiles (0 left plateau, 1 right plateau) along x across strong,
    near-vertical, straight edges of ``grey`` (:func:`_find_edges`), sampled every 0.25 px over
    +-:data:`EDGE_HALF_PX` about the edge, with the local gain slope divided out (:func:`_gain_slope_field`);
    edges with another edge in the window (uneven plateaus) are dropped. ``at``: sample at these ``(row, x)``
    positions instead of finding edges, dropping none (the model's fit samples the same edges at every step, so
    its statistic changes smoothly); ``found``: a list that receives the positions used."""
    g = np.asarray(grey, np.float32)
    offsets = np.arange(-EDGE_HALF_PX, EDGE_HALF_PX + 1e-9, 0.25)
    cols = np.arange(g.shape[1], dtype=np.float64)
    where = _find_edges(g, contrast_dn) if at is None else list(at)
    if not where:
        return [], []
    rows = np.stack([np.interp(x0 + offsets, cols, g[y]) for y, x0 in where])
    lmask, rmask = offsets <= -EDGE_HALF_PX + 2, offsets >= EDGE_HALF_PX - 2
    if at is None:
        step = rows[:, rmask].mean(1) - rows[:, lmask].mean(1)
        keep = ((np.abs(step) >= contrast_dn)
                & (np.maximum(rows[:, lmask].std(1), rows[:, rmask].std(1)) <= 0.1 * np.abs(step)))
        rows, where = rows[keep], [p for p, k in zip(where, keep) if k]
        if not where:
            return [], []
    pos = np.asarray(where, np.float64)
    rows = rows / np.maximum(1 + _gain_slope_field(rows, pos, g.shape, offsets)[:, None] * offsets, 0.5)
    left, step = rows[:, lmask].mean(1), rows[:, rmask].mean(1) - rows[:, lmask].mean(1)
    out = [(r - lo) / st if st != 0 else r * 0 for r, lo, st in zip(rows, left, step)]
    if found is not None:
        found += where
    return out, pos


def _profile_numbers(profiles: list[np.ndarray], positions: list[np.ndarray]) -> dict:
    """Mean profile, 10-90 % width (px) and overshoot (fraction of the step) of normalised edge profiles found at
    ``positions`` (arrays of ``(row, x)``)."""
    offsets = np.arange(-EDGE_HALF_PX, EDGE_HALF_PX + 1e-9, 0.25)
    if not profiles:
        return {}  # no edges: nothing to measure (not a count of 0 to compare)
    # the median within each phase on the 2x2 sensel pattern (x in quarter pixels, row parity), then the mean over
    # phases: a scene whose edges fall at uneven phases is compared fairly with the model's even ones
    stack = np.stack(profiles)
    pos = np.concatenate([p for p in positions if len(p)])
    phase = np.floor(np.mod(pos[:, 1], 2.0) * 4).astype(int) * 2 + np.mod(pos[:, 0], 2).astype(int)
    mean = np.mean([np.median(stack[phase == k], axis=0) for k in np.unique(phase)], axis=0)
    centre = len(offsets) // 2

    def crossing(level):
        # the crossing nearest the centre, searched outwards (a halo can cross the level again further out)
        above = mean >= level
        i = centre
        if above[i]:
            while i > 0 and above[i - 1]:
                i -= 1
            i -= 1
        else:
            while i < len(mean) - 1 and not above[i + 1]:
                i += 1
        i = int(np.clip(i, 0, len(mean) - 2))
        t = (level - mean[i]) / (mean[i + 1] - mean[i]) if mean[i + 1] != mean[i] else 0.5
        return offsets[i] + 0.25 * t

    over = float(max(mean[offsets > 0].max() - 1.0, 0.0))
    under = float(max(-mean[offsets < 0].min(), 0.0))
    return {"edges": len(profiles), "width_10_90_px": float(crossing(0.9) - crossing(0.1)),
            "overshoot": 0.5 * (over + under), "offsets_px": offsets.tolist(), "profile": mean.tolist()}


def edge_profile_statistic(frames, max_frames: int = 4, at=None, found=None,
                           across=("across_x", "across_y")) -> dict:
    """The mean edge profile across strong natural edges of a stack (T, H, W, 3) float32 DN (up to
    ``max_frames`` frames, the green channel), for edges near vertical (``"across_x"``: the profile along rows,
    which horizontal blur and sharpening shape) and near horizontal (``"across_y"``): each with the number of
    edges, the 10-90 % rise width (px) [ISO12233] and the overshoot (the mean of the bright side's overshoot and
    the dark side's undershoot, as a fraction of the step); ``{}`` for an orientation without edges (not
    measurable). ``at`` / ``found``: the edge positions to sample
    (``{"across_x": [...], "across_y": [...]}`` per frame index) instead of finding them, or a dict to fill with
    those found (see :func:`_edge_profiles`). ``across``: the orientations measured (the others are left out)."""
    x = np.asarray(frames, np.float32)
    if x.ndim == 3:
        x = x[None]
    idx = np.linspace(0, len(x) - 1, min(len(x), max_frames)).round().astype(int)
    collected = {key: ([], []) for key in across}
    for i in idx:
        grey = x[i][..., 1] if x.ndim == 4 else x[i]  # green: one linear chain (a grey mix of colour edges is not)
        for key, into in collected.items():
            image = grey if key == "across_x" else grey.T
            where = None if at is None else at[key][int(i)]
            kept = None if found is None else found.setdefault(key, {}).setdefault(int(i), [])
            profs, pos = _edge_profiles(image, at=where, found=kept)
            into[0].extend(profs)
            into[1].append(pos)
    return {key: _profile_numbers(*into) for key, into in collected.items()}


def _edge_scene(width: int, height: int, cell: int = 24, angle_deg: float = 4.0) -> np.ndarray:
    """An opaque ideal of grey squares on a lighter ground, rotated ``angle_deg`` so that edges fall at every
    phase of the pixel grid, area-sampled from 4x supersampling (exact steps)."""
    s = 4
    big_w, big_h = width * s, height * s
    yy, xx = np.mgrid[0:big_h, 0:big_w].astype(np.float32) / s
    t = np.radians(angle_deg)
    u = xx * np.cos(t) + yy * np.sin(t)
    v = -xx * np.sin(t) + yy * np.cos(t)
    squares = ((u // cell) % 2 == 0) & ((v // cell) % 2 == 0)
    img = np.where(squares, 0.25, 0.7).astype(np.float32)
    small = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    out = np.ones((height, width, 4), np.float32)
    out[..., :3] = small[..., None]
    return out


def model_edge_profiles(profile, values, film, at=None, found=None, across=("across_x", "across_y")) -> dict:
    """:func:`edge_profile_statistic` of ``profile`` (noise off, ``values`` set: ``{"effect.param": value}``)
    filming ideal steps rotated 4 degrees, so that edges fall at every phase of the pixel grid; ``at`` /
    ``found`` / ``across`` as there."""
    model = profile.without("noise") if profile.effect("noise") else profile
    for key, v in values.items():
        effect, param = key.split(".")
        model = model.with_effect(effect, **{param: v})
    frame = film(model, lambda w, h: _edge_scene(w, h, cell=max(12, w // 14)))
    return edge_profile_statistic(frame[None], at=at, found=found, across=across)


def edge_profile_from_plate(footage, base, film):
    """The horizontal blur and sharpening from footage's natural edges, as a
    :class:`lowcam.plate_estimate.PlateEstimate` whose params are ``horizontal_blur.sigma`` and
    ``sharpening.sharpness`` (the sharpening gain ``a`` over the profile's ``gain_per_unit``).

    The mean edge profile across near-vertical edges (:func:`edge_profile_statistic`, the footage scaled to the
    profile's frame) is matched by the base profile filming ideal steps (noise off), the two parameters fitted by least
    squares on the profile. The spatial blur is kept as the base has it (under a 2x2 demosaic it barely changes the
    edges); the near-horizontal edges' profile, which only it shapes, is reported for comparison. Natural edges are
    never sharper than the camera makes them, but may be softer (defocus, the scene itself): on real footage the
    blur is an upper bound. Fewer than :data:`MIN_EDGES` edges in either orientation: too little texture, not
    measurable. Confidence: ``0.9 min(1, edges / 100)``, halved where the fitted profile misses the measured one
    by 0.03 of the step or more (root mean square), halved again when the sharpness ends at its range's
    upper end (:class:`Sharpening`'s 255), and halved where the near-horizontal edges (which the row filters do
    not shape) are more than :data:`SOFT_SCENE` times as wide as the base makes a step: the scene is softer than
    steps, which the fit reads as more blur and less sharpening (a photograph filmed by the Fire-i: 0.94 and 43 for
    0.7 and 80), so the estimate is reported rather than applied. ``base``: the profile
    being refined; ``film(profile, make_ideal)``: its frame of an ideal (:func:`lowcam.measure.plate.film`)."""
    from scipy.optimize import least_squares

    frames = footage.stack(max_frames=EDGE_FRAMES)
    w, h = base.camera.width, base.camera.height
    if frames.shape[1:3] != (h, w):
        frames = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames])
    stat = edge_profile_statistic(frames, max_frames=len(frames))
    nx, ny = stat["across_x"].get("edges", 0), stat["across_y"].get("edges", 0)
    if min(nx, ny) < MIN_EDGES:
        return PlateEstimate.not_measurable(
            "edge_profile", "sharpening", stat, f"too little texture to estimate sharpening: {nx} near-vertical and "
            f"{ny} near-horizontal strong straight edges (at least {MIN_EDGES} of each needed)")
    sharp = base.effect("sharpening")
    keys = ("spatial_blur.antialias_sigma_px", "horizontal_blur.sigma", "sharpening.sharpness")
    gain = sharp.gain_per_unit if sharp is not None else 0.025
    start = [getattr(base.effect("spatial_blur"), "antialias_sigma_px", 0.3) or 0.3,
             getattr(base.effect("horizontal_blur"), "sigma", 0.7) or 0.7,
             (sharp.sharpness if sharp is not None else 40.0) * gain]
    tx = np.asarray(stat["across_x"]["profile"])

    at: dict = {}

    def model(aa, hs, a):  # the edges found at the start are sampled at every step
        m = model_edge_profiles(base, dict(zip(keys, (aa, hs, a / gain))), film, at or None, None if at else at)
        return [np.asarray(m[k]["profile"]) if m[k].get("edges") else None for k in ("across_x", "across_y")]

    # the spatial blur is kept: on natural edges under a 2x2 demosaic it is barely identifiable (0 and 0.2 px give
    # vertical profiles within 0.01 px of each other); the vertical profile is reported beside the model's
    aa = float(start[0])

    def residual(p):
        mx = model(aa, p[0], p[1])[0]
        return np.ones_like(tx) if mx is None else mx - tx

    a_max = Sharpening.params["sharpness"].high * gain  # the setting's own range bounds the gain
    start = np.clip(start, [0.0, 0.05, 0.0], [3.0, 3.0, 0.8 * a_max])
    sol = least_squares(residual, start[1:], bounds=([0.0, 0.0], [4.0, a_max]), diff_step=0.05,
                        x_scale=[0.3, 1.0], max_nfev=12)
    sol.x = np.concatenate([[aa], sol.x])
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    params = {keys[1]: float(sol.x[1]), keys[2]: float(sol.x[2] / gain)}
    stat["fit_rms"] = rms
    stat["sharpening_a"] = float(sol.x[2])
    at_bound = sol.x[2] >= 0.99 * a_max
    # the profile down the frame, which the row filters do not shape: wider than the base makes a step, the scene
    # is softer than steps, and the fit reads that softness as more blur and less sharpening
    down = model_edge_profiles(base, dict(zip(keys, (aa, sol.x[1], sol.x[2] / gain))), film, at)["across_y"]
    softer = (stat["across_y"]["width_10_90_px"] / down["width_10_90_px"]
              if down.get("edges") and down["width_10_90_px"] > 0 else 1.0)
    stat["softer_than_steps"] = softer
    soft = softer > SOFT_SCENE
    confidence = 0.9 * min(1.0, min(nx, ny) / 100) * (1.0 if rms < 0.03 else 0.5) * (0.5 if at_bound else 1.0) \
        * (0.5 if soft else 1.0)
    return PlateEstimate("edge_profile", "sharpening", stat, params, round(confidence, 3),
                         f"{nx} near-vertical and {ny} near-horizontal edges, profile fit rms {rms:.3f}"
                         + (f"; the sharpness is at its range's end ({params[keys[2]]:.0f}): the edges may be "
                            "sharper than this camera model can make them" if at_bound else "")
                         + (f"; the near-horizontal edges are {softer:.2f} times as wide as the base makes a step "
                            "(the scene is softer than steps): the blur may be less and the sharpening more" if soft
                            else ""))


#: Declared after its estimator and statistic, which the module defines below the class.
Sharpening.plate_probe = PlateProbe("edge_profile", edge_profile_from_plate, edge_profile_statistic, order=10,
                                     about="10-90 % edge width and overshoot across strong natural edges")
