"""What the image-processor stages that act on the delivered 8-bit frame share: luma and chroma, where they act,
and their diagnosis fit (noise reduction, :mod:`~lowcam.effects.noise_reduction`; local tone mapping,
:mod:`~lowcam.effects.local_tone_mapping`; edge enhancement, :mod:`~lowcam.effects.edge_enhancement`).

A camera's image processor filters the frame in a luma-chroma space after demosaicing [Ramanath2005]. These stages
act after the blend (and after the chroma subsampling), on the frame as delivered, before any encoder: the
processed composite replaces the frame only where the graphics reach (the footprint), so the plate's own pixels,
which the real camera processed already, keep their bytes.

Contents
--------
- :data:`BT601_TO_YCC`, :data:`BT601_FROM_YCC`: full-range BT.601 RGB -> (Y, Cb, Cr) and back (as JFIF, [T871])
- :func:`to_ycc`: a frame's luma and chroma planes (float32, DN; chroma centred on 0)
- :func:`ycc_change_to_rgb`: an RGB change (float32, DN) from a change of luma and chroma
- :func:`to_uint8`: a float frame rounded (half to even) and limited to 0-255, as 8 bits
- :func:`within_footprint`: a frame processed by a function of its pixels, kept where the graphics reach
- :func:`frame_score`: how far model frames stand from measured ones: the mean and variance families of a
  comparison (:mod:`lowcam.measure.compare`), over a crop
- :func:`beyond_spread`: a noise family's log ratio less the two model sequences' own (frames not independent)
- :func:`row_log_ratios`: the row noise family's log ratios, measured over model (the fit's and the comparison's)
- :func:`processed_by`: the ``process`` of :func:`fit_delivered_stage` for a stage class with ``process_frame``
- :func:`fit_delivered_stage`: diagnosis's fit of such a stage: a coordinate search over its parameters, each
  trial processing the model's noisy frames again

References
----------
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 YCbCr).
- [Ramanath2005] R. Ramanath, W. E. Snyder, Y. Yoo and M. S. Drew, "Color image processing pipeline", IEEE Signal
  Processing Magazine 22(1), 34-43, 2005 (where noise reduction and sharpening sit in a camera's chain).
"""
from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict

import numpy as np

from .fixed_pattern import row_noise_variance

#: Full-range BT.601 RGB -> (Y, Cb, Cr), chroma centred on 0 [T871].
BT601_TO_YCC = np.array([[0.299, 0.587, 0.114],
                         [-0.168736, -0.331264, 0.5],
                         [0.5, -0.418688, -0.081312]], np.float32)
#: (Y, Cb, Cr) -> RGB, the inverse of :data:`BT601_TO_YCC`.
BT601_FROM_YCC = np.linalg.inv(BT601_TO_YCC.astype(np.float64)).astype(np.float32)

_CROP = (160, 224)  # rows, columns of the centre crop a fit scores (filters are local: a margin makes it exact)
_MARGIN = 24        # px around the crop that the filters read
_SHARES: OrderedDict = OrderedDict()  # (stage, frames' digest, values) -> one capture's share of a trial's score
_SHARES_KEPT = 20000                  # shares kept (a few numbers each), least recently made out first
_LOCK = threading.Lock()              # diagnosis fits candidates in threads
_PLAIN: OrderedDict = OrderedDict()   # (capture's id, profile, count, crop) -> (capture's weakref, model frames)
_PLAIN_BYTES = 64 << 20               # model frames kept for the other folds' fits, least recently used out first


def to_ycc(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: luma Y and chroma Cb, Cr (DN, chroma centred on 0) of an (H, W, 3) RGB frame."""
    f = np.asarray(frame, np.float32)
    return (f.reshape(-1, 3) @ BT601_TO_YCC.T).reshape(f.shape)


def ycc_change_to_rgb(change: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: the RGB change (DN) that changes luma and chroma by ``change`` (H, W, 3)."""
    c = np.asarray(change, np.float32)
    return (c.reshape(-1, 3) @ BT601_FROM_YCC.T).reshape(c.shape)


def to_uint8(frame: np.ndarray) -> np.ndarray:
    """``np.clip(np.rint(frame), 0, 255).astype(np.uint8)`` of a float ``frame``, rounded and limited in place
    (``frame`` is overwritten): the same bytes at half the cost of a frame-sized clip."""
    np.rint(frame, out=frame)
    return np.minimum(np.maximum(frame, 0, out=frame), 255, out=frame).astype(np.uint8)


def within_footprint(frame: np.ndarray, footprint: np.ndarray, process, reach: int) -> np.ndarray:
    """``frame`` (H, W, 3) uint8 with ``process(crop) -> crop`` (uint8) applied where ``footprint`` (H, W) bool is
    set; the crop holds the footprint's bounding box and ``reach`` px around it (what the filter reads). Pixels
    outside the footprint keep their bytes."""
    rows, cols = np.nonzero(footprint.any(axis=1))[0], np.nonzero(footprint.any(axis=0))[0]
    if not len(rows):
        return frame
    h, w = footprint.shape
    r0, r1 = max(rows[0] - reach, 0), min(rows[-1] + 1 + reach, h)
    c0, c1 = max(cols[0] - reach, 0), min(cols[-1] + 1 + reach, w)
    done = process(np.ascontiguousarray(frame[r0:r1, c0:c1]))
    out = frame.copy()
    inside = footprint[r0:r1, c0:c1]
    out[r0:r1, c0:c1][inside] = done[inside]
    return out


def _crop(shape, crop) -> tuple[slice, slice, slice, slice]:
    """(rows, cols) of the centre ``crop`` (rows, columns) with its margin, and the crop within that."""
    h, w = shape
    ch, cw = min(crop[0], h), min(crop[1], w)
    r0, c0 = (h - ch) // 2, (w - cw) // 2
    mr0, mc0 = max(r0 - _MARGIN, 0), max(c0 - _MARGIN, 0)
    mr1, mc1 = min(r0 + ch + _MARGIN, h), min(c0 + cw + _MARGIN, w)
    return (slice(mr0, mr1), slice(mc0, mc1), slice(r0 - mr0, r0 - mr0 + ch), slice(c0 - mc0, c0 - mc0 + cw))


def _moments(frames) -> tuple[np.ndarray, np.ndarray, int]:
    f = np.asarray(frames, np.float32)
    return f.mean(0), (f.var(0, ddof=1) if len(f) > 1 else None), len(f)


def _partial(measured, simulated, mask, again=None) -> tuple[float, float, list]:
    """One capture's share of :func:`frame_score`: the mean family's numerator and denominator and the variance
    family's log ratios; ``measured`` as :func:`_moments` gives it. ``again``: a second model sequence (other
    noise) of a stage that holds noise from frame to frame (a video encoder): the mean family's denominator is
    then ``sum (mean(simulated) - mean(again))^2`` (at least the independent frames'), and each pixel's variance
    at least 1/12 DN^2 (the rounding's), as :func:`lowcam.measure.compare.capture_stats` has them."""
    mf, vf, n = measured[:3]
    mg, vg, k = _moments(simulated)

    def kept(a):  # the compared pixels, in order (a sum over them is the same as over the unmasked array)
        return a if mask is None else a[mask]

    num = float(kept(np.square(mf - mg)).sum())
    den = float(kept((vg if vf is None else vf) / n + vg / k).sum())
    va, rows = None, None
    if again is not None:
        ma, va, _ = _moments(again)
        vf, vg, va = (None if vf is None else np.maximum(vf, 1 / 12)), np.maximum(vg, 1 / 12), np.maximum(va, 1 / 12)
        den = max(den, float(kept(np.square(mg - ma)).sum()))
        if len(measured) > 3 and vf is not None:  # the row family, beyond the model sequences' own spread
            rows = row_log_ratios(measured[3], row_noise_variance(np.asarray(simulated), mask),
                                  row_noise_variance(np.asarray(again), mask))
    logs = []
    if vf is not None:
        level = np.minimum(mg * np.float32(1 / 16), 15).astype(np.intp)  # mg >= 0: the cast floors, as // 16
        for c in range(3):
            lv, a, b = (kept(x[..., c]).ravel() for x in (level, vf, vg))
            counts = np.bincount(lv, minlength=16)
            sa, sb = np.bincount(lv, a, 16), np.bincount(lv, b, 16)
            ok = (counts >= 100) & (sa > 0) & (sb > 0)
            if va is None:
                logs.extend(np.log(sa[ok] / sb[ok]).tolist())
            else:
                sc = np.bincount(lv, kept(va[..., c]).ravel(), 16)
                logs.extend(beyond_spread(x, y) for x, y in zip(np.log(sa[ok] / sb[ok]), np.log(sc[ok] / sb[ok])))
    return num, den, logs, rows


def beyond_spread(log_ratio: float, spread: float) -> float:
    """A noise family's log ratio, measured over model, less what two model sequences of other noise differ by
    (``spread``, their log ratio): ``sign(r) max(|r| - |spread|, 0)``. Where frames are not independent (a video
    encoder holds the noise of one frame in the next), a noise statistic of a few frames scatters from one noise
    draw to the next by a factor of 2 or more; what the model's own draws show of that is not counted (here and in
    :func:`lowcam.measure.compare.capture_stats`)."""
    return float(np.sign(log_ratio) * max(abs(log_ratio) - abs(spread), 0.0))


def row_log_ratios(measured, model, again=None) -> list[float]:
    """Per channel, the log ratio of the measured frames' row noise variance (the variance of the per-frame row
    means, :func:`~lowcam.effects.fixed_pattern.row_noise_variance`) over the model's; with a second model sequence
    ``again``, less the two sequences' own (:func:`beyond_spread`). A channel where either does not vary is left
    out (clipped, or a coded sequence that holds its noise entirely)."""
    return [float(np.log(a / b)) if again is None else beyond_spread(np.log(a / b), np.log(max(c, 1e-9) / b))
            for a, b, c in zip(measured, model, model if again is None else again) if a > 1e-9 and b > 1e-9]


def _combined(parts) -> float:
    num, den = sum(p[0] for p in parts), sum(p[1] for p in parts)
    logs = [x for p in parts for x in p[2]]
    e_var = float(np.exp(np.sqrt(np.mean(np.square(logs))))) if logs else 1.0
    rows = [x for p in parts if p[3] is not None for x in p[3]]  # scored only with a second sequence
    scored = any(p[3] is not None for p in parts)
    e_rows = float(np.exp(np.sqrt(np.mean(np.square(rows))))) if rows else float(scored)
    return num / max(den, 1e-12) + e_var ** 2 + e_rows ** 2


def frame_score(measured: list, simulated: list, masks: list) -> float:
    """``e_mean^2 + e_var^2`` of model frames against measured ones, as :mod:`lowcam.measure.compare` defines them:
    ``e_mean^2 = sum R^2 / sum(var_F / n + var_G / K)`` of the temporal means' residual ``R``, and
    ``e_var = exp(rms |ln ratio|)`` of the temporal variances per channel and brightness bin (16 bins of 16 DN, bins
    of at least 100 pixels). ``measured``, ``simulated``: per capture (n, h, w, 3) and (K, h, w, 3) frames;
    ``masks``: per capture (h, w) bool or None. A capture of one frame adds to the mean family only, with the
    model's variance for both."""
    return _combined([_partial(_moments(f), g, m) for f, g, m in zip(measured, simulated, masks)])


def processed_by(stage_class):
    """``process(values, frames) -> frames`` for :func:`fit_delivered_stage`: each uint8 frame of the stack through
    ``stage_class(**values).process_frame``."""
    def process(values, frames):
        stage = stage_class(**values)
        return np.stack([stage.process_frame(f) for f in frames])
    return process


def _plain_frames(ctx, profile, i: int, count: int, rows: slice, cols: slice, second: bool = False) -> np.ndarray:
    """``ctx.simulate(profile, i, count, second)`` within ``rows``, ``cols``, kept (up to :data:`_PLAIN_BYTES`) for
    the other folds' fits, which see the same capture (a temporal stage's fit asks for dozens of frames)."""
    capture = ctx.mset.captures[i]
    key = (id(capture), repr((profile.camera.values(), [(e.name, e.enabled, e.values()) for e in profile.effects])),
           count, second, rows.start, rows.stop, cols.start, cols.stop)
    with _LOCK:
        kept = _PLAIN.get(key)
        if kept is not None and kept[0]() is capture:
            _PLAIN.move_to_end(key)
            return kept[1]
    frames = np.ascontiguousarray(ctx.simulate(profile, i, count, second)[:, rows, cols])
    frames.flags.writeable = False  # shared by the folds' threads
    if frames.nbytes <= _PLAIN_BYTES:
        with _LOCK:
            for dead in [k for k, (ref, _) in _PLAIN.items() if ref() is None]:
                del _PLAIN[dead]
            _PLAIN[key] = (weakref.ref(capture), frames)
            while sum(f.nbytes for _, f in _PLAIN.values()) > _PLAIN_BYTES:
                _PLAIN.popitem(last=False)
    return frames


def fit_delivered_stage(ctx, effect: str, process, searches, crop: tuple[int, int] = _CROP, count: int = 3,
                        frozen_noise: bool = False, screened_forms: int = 1, lead: int = 0):
    """Diagnosis's fit (a :class:`~lowcam.effects.Search` ``fit``) of a stage that acts on the delivered frame:
    (profile with it, values, values shown).

    The model keeps its noise: these filters are not linear (a bilateral or non-local-means filter smooths noise
    and keeps edges; coring passes small details through unchanged), so the model's frames must carry the noise
    the camera filtered. When the stage is the chain's last, the model's noisy frames of the context's few
    captures (the flattest and the most textured, ``ctx.quick``) are simulated once without it and each trial only
    processes them again; otherwise each trial re-simulates the chain (``ctx.simulate``). Trials are scored by
    :func:`frame_score` on a centre ``crop`` (rows, columns; :data:`_CROP` unless given) with a :data:`_MARGIN` the
    filters read; a capture's share of a trial's score depends on its measured and model frames alone, so it is
    kept (by their digest) for the fits on the other folds.

    ``process(values, frames) -> frames`` processes a stack of uint8 frames with the stage at ``values``.
    ``searches``: ``(start, plan, coarse_plan)`` triples, one per form of the stage (a filter family): each form is
    searched from ``start`` by the steps of ``coarse_plan``, and the best form then by those of ``plan``; while
    diagnosis screens (``ctx.screening``), the first form on its coarse steps only (screening is for every
    candidate of every diagnosis: it only needs to show whether the stage helps). A step is ``(key, options)``,
    ``options`` a list of values or a function of the current values returning one: every option is tried and the
    best kept (a coordinate search); ``key`` may be a tuple of keys, each option then a tuple of their values,
    searched together. ``count``: model frames per capture (3; a stage that acts across frames, a video encoder,
    asks for as many as the captures have). ``frozen_noise``: the stage holds noise from frame to frame (a video
    encoder's predicted frames), so the frames' temporal variance no longer measures the noise of their mean: each
    trial processes a second sequence of ``count`` frames of other noise too, the one the comparison draws (the
    noise is coded differently in each draw, so a fit on a draw of its own chose settings that only its draw
    favoured), and the mean family's noise is measured from the two (:func:`_partial`'s ``again``), as the
    comparison does; the noise families count only what lies beyond the two sequences' own difference, and the
    rows family (the variance of per-frame row means, :func:`~lowcam.effects.fixed_pattern.row_noise_variance`) is
    scored too. ``screened_forms``: how many forms screening tries (the first; a video encoder's two codecs code
    noise too differently for one to stand for the other). ``lead``: frames before each sequence that settle a
    recursive filter: ``process`` is handed ``lead + count`` frames and returns the last ``count``."""
    p = ctx.profile
    caps, idx = ctx.mset.captures, ctx.quick
    rows, cols, ir, ic = _crop(ctx.means[0].shape[:2], crop)
    measured = [_moments(caps[i].frames[:, rows, cols][:, ir, ic]) for i in idx]
    masks = [None if ctx.inputs[i].mask is None else ctx.inputs[i].mask[rows, cols][ir, ic] for i in idx]
    if frozen_noise:  # the row family too: a coded sequence's row means show where the noise is held
        measured = [m + (row_noise_variance(caps[i].frames[:, rows, cols][:, ir, ic], k),)
                    for m, i, k in zip(measured, idx, masks)]
    # ``count`` model frames per capture: the same noise in every trial, so trials compare fairly
    with_it = p.with_effect(effect, **searches[0][0])
    names = [e.name for e in with_it.effects if e.enabled or e.always_runs]
    shortcut = names[-1] == effect
    if shortcut:
        have = p.effect(effect)
        base = p.without(effect) if have is not None and have.enabled else p
        per = count + lead
        # per capture, its model sequence and, where noise is held, the comparison's own second one
        plain = [(_plain_frames(ctx, base, i, per, rows, cols),
                  _plain_frames(ctx, base, i, per, rows, cols, second=True) if frozen_noise else None) for i in idx]
        # a capture's share of a trial depends on its frames alone: kept for the other folds' fits
        digests = [hashlib.blake2b(np.ascontiguousarray(caps[i].frames[:, rows, cols][:, ir, ic]).tobytes()
                                   + f.tobytes() + (b"" if g is None else g.tobytes())
                                   + (b"" if m is None else np.packbits(m).tobytes()),
                                   digest_size=16).digest() for i, (f, g), m in zip(idx, plain, masks)]

    scores: dict = {}

    def share(j, values):
        key = (effect, digests[j], tuple(sorted(values.items())))
        with _LOCK:
            got = _SHARES.get(key)
        if got is None:
            first, second = plain[j]
            if frozen_noise:  # two sequences of independent noise: the noise of the mean from their difference
                got = _partial(measured[j], process(values, first)[:, ir, ic], masks[j],
                               process(values, second)[:, ir, ic])
            else:
                got = _partial(measured[j], process(values, first)[:, ir, ic], masks[j])
            with _LOCK:
                _SHARES[key] = got
                while len(_SHARES) > _SHARES_KEPT:
                    _SHARES.popitem(last=False)
        return got

    def score(values):
        key = tuple(sorted(values.items()))
        if key not in scores:
            if shortcut:
                parts = [share(j, values) for j in range(len(idx))]
            else:
                model = p.with_effect(effect, **values)  # the chain makes its own lead frames (resume_sequence)
                parts = [_partial(measured[j], ctx.simulate(model, i, count)[:, rows, cols][:, ir, ic], masks[j],
                                  ctx.simulate(model, i, count, second=True)[:, rows, cols][:, ir, ic]
                                  if frozen_noise else None)
                         for j, i in enumerate(idx)]
            scores[key] = _combined(parts)
        return scores[key]

    def snap(o):  # options on a lattice of 3 significant digits: folds share their trials
        return float(f"{o:.3g}") if isinstance(o, float) else o

    def step(values, key, options):  # a key, or a tuple of keys whose options are tuples (searched together)
        keys = key if isinstance(key, tuple) else (key,)
        opts = options(values) if callable(options) else options
        opts = [tuple(map(snap, o)) if isinstance(key, tuple) else (snap(o),) for o in opts]
        values.update(zip(keys, min(dict.fromkeys(opts), key=lambda o: score(dict(values, **dict(zip(keys, o)))))))

    screening = getattr(ctx, "screening", False)
    coarse = []
    for start, plan, coarse_plan in searches[:screened_forms] if screening else searches:  # each on its coarse steps
        values = dict(start)
        for key, options in coarse_plan:
            step(values, key, options)
        coarse.append((values, plan))
    best, plan = min(coarse, key=lambda c: score(c[0]))
    if not screening:  # the best form on its finer steps
        for key, options in plan:
            step(best, key, options)
    return p.with_effect(effect, **best), dict(best), dict(best)
