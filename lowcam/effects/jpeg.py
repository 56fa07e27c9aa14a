"""JPEG compression of the delivered frame (a phone's or webcam's MJPEG stream; not in the paper).

The frame is encoded with OpenCV's libjpeg and decoded again. The quantisation tables are the standard ones of
[T.81] Annex K scaled by the IJG quality rule (``quality`` 50: the tables as printed; below 50: ``5000 / quality``
percent; above: ``200 - 2 quality`` percent; libjpeg's ``jpeg_quality_scaling``). The chroma planes are kept at
full resolution (4:4:4), halved across (4:2:2) or halved both ways (4:2:0) before the DCT [T.81, A.1.1]. The
whole frame is recompressed, so no pixel keeps the plate's exact bytes.

Contents
--------
- :data:`SUBSAMPLINGS`: the chroma subsamplings the encoder offers, as the J:a:b names JPEG writers use
- :func:`jpeg_roundtrip`: one 8-bit RGB frame encoded as JPEG and decoded again
- :func:`fit_jpeg`: diagnosis's fit: the subsampling, quality and chroma quality whose coded noisy model frames
  best match the measured means (coarse grid, then finer steps; only the coding is repeated)
- :class:`Jpeg`: encodes the final 8-bit frame as JPEG (``quality``, ``chroma_quality``, ``subsampling``) and
  decodes it again

References
----------
- [T.81] ITU-T Recommendation T.81 | ISO/IEC 10918-1, "Digital compression and coding of continuous-tone still
  images" (JPEG), 1992 (Annex K: the example quantisation tables).
- [IJG] Independent JPEG Group, libjpeg 6b, ``jcparam.c``: ``jpeg_quality_scaling`` (the quality -> table
  percentage rule that OpenCV, Pillow and most cameras' encoders use).
"""
from __future__ import annotations

import numpy as np

from .base import Effect, Param, Search

#: The chroma subsamplings the encoder offers (J:a:b): full, halved across, halved across and down.
SUBSAMPLINGS = ("4:4:4", "4:2:2", "4:2:0")

#: Coarse quality grid of :func:`fit_jpeg`, then the steps around the best.
_COARSE_QUALITY = (20, 40, 60, 75, 90)


def _encode_decode(frame: np.ndarray, quality: int, subsampling: str) -> np.ndarray:
    import cv2

    from ..errors import LowcamError

    factor = {"4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444, "4:2:2": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
              "4:2:0": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420}[subsampling]
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, int(quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR, factor])
    if not ok:
        raise LowcamError(f"JPEG encoding of a {frame.shape[1]}x{frame.shape[0]} frame failed")
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def jpeg_roundtrip(frame: np.ndarray, quality: int, subsampling: str = "4:2:0", chroma_quality: int = 0) -> np.ndarray:
    """One 8-bit RGB frame (H, W, 3) encoded as baseline JPEG (OpenCV's libjpeg, IJG-scaled standard tables at
    ``quality`` 1-100, chroma ``subsampling`` one of :data:`SUBSAMPLINGS`) and decoded again.

    ``chroma_quality`` (0: as ``quality``) scales the chroma table on its own. libjpeg codes Y, Cb and Cr
    independently, but OpenCV drops the subsampling when the two qualities differ, so the frame is then coded
    twice and the luma of the first joined with the chroma of the second (full-range BT.601, as JFIF); the
    extra rounding (under 1 DN) is dithered away by the camera's noise."""
    if not chroma_quality or int(chroma_quality) == int(quality):
        return _encode_decode(frame, quality, subsampling)
    import cv2

    luma = cv2.cvtColor(_encode_decode(frame, quality, subsampling), cv2.COLOR_RGB2YCrCb)
    chroma = cv2.cvtColor(_encode_decode(frame, chroma_quality, subsampling), cv2.COLOR_RGB2YCrCb)
    chroma[..., 0] = luma[..., 0]
    return cv2.cvtColor(chroma, cv2.COLOR_YCrCb2RGB)


def fit_jpeg(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): the subsampling, quality and chroma quality whose coded
    frames' temporal means best match the measured means (squared residual summed over the context's few
    :attr:`~lowcam.measure.diagnose.Context.quick` captures).

    The model's frames keep their noise: JPEG is not linear, so the mean of coded noisy frames is not the coding
    of the clean frame (quantisation of noisy coefficients shrinks them less), and a noise-free fit picks too
    low a quality. When JPEG is the chain's last stage, the model's noisy frames are simulated once without it
    and each trial only codes them again (the frames :func:`lowcam.measure.compare.compare` makes); otherwise
    each trial re-simulates the chain. Every subsampling is tried on a coarse quality grid; for the best, the
    quality is refined, then the chroma quality on its own (an encoder's tables rarely have the standard
    luma/chroma balance), then the quality again. While diagnosis screens (``ctx.screening``), only the coarse
    grid at 4:2:0.
    """
    from ..measure.compare import simulate_capture

    p = ctx.profile
    caps, idx = ctx.mset.captures, ctx.quick  # a few captures: the flattest and the most textured
    means = [ctx.means[i] for i in idx]
    with_it = p.with_effect(effect)
    names = [e.name for e in with_it.effects if e.enabled or e.always_runs]
    shortcut = names[-1] == effect
    if shortcut:
        have = p.effect(effect)
        base = p.without(effect) if have is not None and have.enabled else p
        uncoded = [simulate_capture(base, caps[i], max(len(caps[i].frames), 4), inputs=ctx.inputs[i],
                                    cache=ctx.cache) for i in idx]
    scores: dict = {}

    def sse(q, s, qc=None):  # the residual of the temporal means, model frames with their noise
        q = int(min(100, max(1, q)))
        qc = q if qc is None else int(min(100, max(1, qc)))
        key = (q, s, 0 if qc == q else qc)
        if key not in scores:
            if shortcut:
                scores[key] = float(sum(((m - np.mean([jpeg_roundtrip(f, *key) for f in g], axis=0)) ** 2).sum()
                                        for m, g in zip(means, uncoded)))
            else:
                frames = [simulate_capture(p.with_effect(effect, quality=q, subsampling=s, chroma_quality=key[2]),
                                           caps[i], max(len(caps[i].frames), 4), inputs=ctx.inputs[i],
                                           cache=ctx.cache) for i in idx]
                scores[key] = float(sum(((m - g.mean(axis=0)) ** 2).sum() for m, g in zip(means, frames)))
        return scores[key]

    def refine(best, steps, score):
        return int(min(100, max(1, min((best + d for d in steps), key=score))))

    if getattr(ctx, "screening", False):  # screening: the usual subsampling on the coarse grid only
        q = min(_COARSE_QUALITY, key=lambda v: sse(v, "4:2:0"))
        return p.with_effect(effect, quality=q, subsampling="4:2:0"), {"quality": q, "subsampling": "4:2:0"}, \
            {"quality": q, "subsampling": "4:2:0", "chroma_quality": q}
    q, s = min(((q, s) for s in SUBSAMPLINGS for q in _COARSE_QUALITY), key=lambda qs: sse(*qs))
    for steps in ((-12, -6, 0, 6, 12), (-3, 0, 3), (-1, 0, 1)):
        q = refine(q, steps, lambda v: sse(v, s))
    qc = q
    for steps in ((-40, -20, 0, 20, 40), (-10, 0, 10), (-5, 0, 5), (-2, 0, 2), (-1, 0, 1)):
        qc = refine(qc, steps, lambda v: sse(q, s, v))
    for steps in ((-2, 0, 2), (-1, 0, 1)):
        q = refine(q, steps, lambda v: sse(v, s, qc))
    values = {"quality": q, "subsampling": s, "chroma_quality": 0 if qc == q else qc}
    return p.with_effect(effect, **values), values, dict(values, chroma_quality=qc)


fit_jpeg.refines = True  # diagnosis calls it again, in full, for a promising candidate


class Jpeg(Effect):
    """Encodes the final 8-bit frame as JPEG at ``quality`` (IJG scaling of the standard tables; the chroma table
    at ``chroma_quality`` when set) with chroma ``subsampling`` and decodes it again (OpenCV's libjpeg). The whole
    frame is recompressed, so no pixel keeps
    the plate's exact bytes."""

    name = "jpeg"
    section = "not in the paper"
    writes = "output"
    order = 280
    searches = (Search("jpeg", "8x8 block artefacts as from JPEG quality {quality} (chroma {chroma_quality}), "
                       "chroma {subsampling}",
                       fit=fit_jpeg),)
    params = {"quality": Param(90, int, low=1, high=100, doc="IJG quality: the standard tables' scaling"),
              "subsampling": Param("4:2:0", str, choices=SUBSAMPLINGS, doc="chroma subsampling (J:a:b)"),
              "chroma_quality": Param(0, int, low=0, high=100, doc="IJG quality of the chroma table; 0: quality")}

    def apply(self, state):
        """Nothing before the blend: the encode acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        from ..errors import LowcamError

        try:
            out = jpeg_roundtrip(frame, self.quality, self.subsampling, self.chroma_quality)
        except LowcamError as e:
            raise LowcamError(f"{self.source}: {e}") from None
        return out, np.ones_like(footprint)
