"""What the image-processor stages that act on the delivered 8-bit frame share: luma and chroma, where they act,
and their diagnosis fit (noise reduction, :mod:`~lowcam.effects.noise_reduction`; edge enhancement,
:mod:`~lowcam.effects.edge_enhancement`).

A camera's image processor filters the frame in a luma-chroma space after demosaicing [Ramanath2005]. These stages
act after the blend (and after the chroma subsampling), on the frame as delivered, before any encoder: the
processed composite replaces the frame only where the graphics reach (the footprint), so the plate's own pixels,
which the real camera processed already, keep their bytes.

Contents
--------
- :data:`BT601_TO_YCC`, :data:`BT601_FROM_YCC`: full-range BT.601 RGB -> (Y, Cb, Cr) and back (as JFIF, [T871])
- :func:`to_ycc`: a frame's luma and chroma planes (float32, DN; chroma centred on 0)
- :func:`ycc_change_to_rgb`: an RGB change (float32, DN) from a change of luma and chroma
- :func:`within_footprint`: a frame processed by a function of its pixels, kept where the graphics reach
- :func:`frame_score`: how far model frames stand from measured ones: the mean and variance families of a
  comparison (:mod:`lowcam.measure.compare`), over a crop
- :func:`fit_delivered_stage`: diagnosis's fit of such a stage: a coordinate search over its parameters, each
  trial processing the model's noisy frames again

References
----------
- [T871] ITU-T Recommendation T.871, "JPEG File Interchange Format", 2011 (full-range BT.601 YCbCr).
- [Ramanath2005] R. Ramanath, W. E. Snyder, Y. Yoo and M. S. Drew, "Color image processing pipeline", IEEE Signal
  Processing Magazine 22(1), 34-43, 2005 (where noise reduction and sharpening sit in a camera's chain).
"""
from __future__ import annotations

import numpy as np

#: Full-range BT.601 RGB -> (Y, Cb, Cr), chroma centred on 0 [T871].
BT601_TO_YCC = np.array([[0.299, 0.587, 0.114],
                         [-0.168736, -0.331264, 0.5],
                         [0.5, -0.418688, -0.081312]], np.float32)
#: (Y, Cb, Cr) -> RGB, the inverse of :data:`BT601_TO_YCC`.
BT601_FROM_YCC = np.linalg.inv(BT601_TO_YCC.astype(np.float64)).astype(np.float32)

_CROP = (192, 256)  # rows, columns of the centre crop a fit scores (filters are local: a margin makes it exact)
_MARGIN = 24        # px around the crop that the filters read


def to_ycc(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: luma Y and chroma Cb, Cr (DN, chroma centred on 0) of an (H, W, 3) RGB frame."""
    f = np.asarray(frame, np.float32)
    return (f.reshape(-1, 3) @ BT601_TO_YCC.T).reshape(f.shape)


def ycc_change_to_rgb(change: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: the RGB change (DN) that changes luma and chroma by ``change`` (H, W, 3)."""
    c = np.asarray(change, np.float32)
    return (c.reshape(-1, 3) @ BT601_FROM_YCC.T).reshape(c.shape)


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


def _crop(shape) -> tuple[slice, slice, slice, slice]:
    """(rows, cols) of the centre crop with its margin, and the crop within that."""
    h, w = shape
    ch, cw = min(_CROP[0], h), min(_CROP[1], w)
    r0, c0 = (h - ch) // 2, (w - cw) // 2
    mr0, mc0 = max(r0 - _MARGIN, 0), max(c0 - _MARGIN, 0)
    mr1, mc1 = min(r0 + ch + _MARGIN, h), min(c0 + cw + _MARGIN, w)
    return (slice(mr0, mr1), slice(mc0, mc1), slice(r0 - mr0, r0 - mr0 + ch), slice(c0 - mc0, c0 - mc0 + cw))


def frame_score(measured: list, simulated: list, masks: list) -> float:
    """``e_mean^2 + e_var^2`` of model frames against measured ones, as :mod:`lowcam.measure.compare` defines them:
    ``e_mean^2 = sum R^2 / sum(var_F / n + var_G / K)`` of the temporal means' residual ``R``, and
    ``e_var = exp(rms |ln ratio|)`` of the temporal variances per channel and brightness bin (16 bins of 16 DN, bins
    of at least 100 pixels). ``measured``, ``simulated``: per capture (n, h, w, 3) and (K, h, w, 3) frames;
    ``masks``: per capture (h, w) bool or None. A capture of one frame adds to the mean family only, with the
    model's variance for both."""
    num = den = 0.0
    logs = []
    for f, g, m in zip(measured, simulated, masks):
        f, g = np.asarray(f, np.float32), np.asarray(g, np.float32)
        mf, mg = f.mean(0), g.mean(0)
        vg = g.var(0, ddof=1)
        vf = f.var(0, ddof=1) if len(f) > 1 else vg
        keep = np.ones(mf.shape[:2], bool) if m is None else m
        num += float(np.square(mf - mg)[keep].sum())
        den += float((vf / len(f) + vg / len(g))[keep].sum())
        if len(f) > 1:
            level = np.clip((mg // 16).astype(int), 0, 15)
            for c in range(3):
                lv, a, b = level[..., c][keep], vf[..., c][keep], vg[..., c][keep]
                counts = np.bincount(lv, minlength=16)
                sa, sb = np.bincount(lv, a, 16), np.bincount(lv, b, 16)
                ok = (counts >= 100) & (sa > 0) & (sb > 0)
                logs.extend(np.log(sa[ok] / sb[ok]))
    e_mean2 = num / max(den, 1e-12)
    e_var = float(np.exp(np.sqrt(np.mean(np.square(logs))))) if logs else 1.0
    return e_mean2 + e_var ** 2


def fit_delivered_stage(ctx, effect: str, process, searches):
    """Diagnosis's fit (a :class:`~lowcam.effects.Search` ``fit``) of a stage that acts on the delivered frame:
    (profile with it, values, values shown).

    The model keeps its noise: these filters are not linear (a bilateral or non-local-means filter smooths noise
    and keeps edges; coring passes small details through unchanged), so the model's frames must carry the noise
    the camera filtered. When the stage is the chain's last, the model's noisy frames of the context's few captures
    (the flattest and the most textured, ``ctx.quick``) are simulated once without it and each trial only processes them again; otherwise each trial
    re-simulates the chain (``ctx.simulate``). Trials are scored by :func:`frame_score` on a centre crop
    (:data:`_CROP` with a :data:`_MARGIN` the filters read). ``process(values, frames) -> frames`` processes a
    stack of uint8 frames with the stage at ``values``. ``searches``: ``(start, plan, screening_plan)`` triples
    (one per form of the stage, e.g. a filter family), whose best result is returned: ``start`` the values before
    the search, ``plan`` the steps of a coordinate search, each ``(key, options)`` where ``options`` is a list of
    values or a function of the current values returning one (every option is tried and the best kept), and
    ``screening_plan`` the steps while diagnosis screens (``ctx.screening``)."""
    p = ctx.profile
    caps, idx = ctx.mset.captures, ctx.quick
    rows, cols, ir, ic = _crop(ctx.means[0].shape[:2])
    measured = [caps[i].frames[:, rows, cols][:, ir, ic] for i in idx]
    masks = [None if ctx.inputs[i].mask is None else ctx.inputs[i].mask[rows, cols][ir, ic] for i in idx]
    count = lambda i: max(min(len(caps[i].frames), 6), 4)  # noqa: E731
    with_it = p.with_effect(effect, **searches[0][0])
    names = [e.name for e in with_it.effects if e.enabled or e.always_runs]
    shortcut = names[-1] == effect
    if shortcut:
        have = p.effect(effect)
        base = p.without(effect) if have is not None and have.enabled else p
        plain = [ctx.simulate(base, i, count(i))[:, rows, cols] for i in idx]
    scores: dict = {}

    def score(values):
        key = tuple(sorted(values.items()))
        if key not in scores:
            if shortcut:
                sims = [process(values, f)[:, ir, ic] for f in plain]
            else:
                model = p.with_effect(effect, **values)
                sims = [ctx.simulate(model, i, count(i))[:, rows, cols][:, ir, ic] for i in idx]
            scores[key] = frame_score(measured, sims, masks)
        return scores[key]

    best = None
    for start, plan, screening_plan in searches:
        values = dict(start)
        for key, options in (screening_plan if getattr(ctx, "screening", False) else plan):
            opts = options(values) if callable(options) else options
            values[key] = min(dict.fromkeys(opts), key=lambda v: score(dict(values, **{key: v})))
        if best is None or score(values) < score(best):
            best = values
    return p.with_effect(effect, **best), dict(best), dict(best)
