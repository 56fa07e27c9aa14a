"""JPEG compression of the delivered frame (a phone's or webcam's MJPEG stream; not in the paper).

The frame is encoded with OpenCV's libjpeg and decoded again. The quantisation tables are the standard ones of
[T.81] Annex K scaled by the IJG quality rule (``quality`` 50: the tables as printed; below 50: ``5000 / quality``
percent; above: ``200 - 2 quality`` percent; libjpeg's ``jpeg_quality_scaling``). The chroma planes are kept at
full resolution (4:4:4), halved across (4:2:2) or halved both ways (4:2:0) before the DCT [T.81, A.1.1]. The
whole frame is recompressed, so no pixel keeps the plate's exact bytes. An encoder's own tables (``luma_table``,
``chroma_table``), which OpenCV cannot write, are coded in numpy with libjpeg's rounding; diagnosis reads them off
the frames: decoded blocks' DCT coefficients sit on the multiples of each frequency's step.

Contents
--------
- :data:`SUBSAMPLINGS`: the chroma subsamplings the encoder offers, as the J:a:b names JPEG writers use
- :func:`jpeg_roundtrip`: one 8-bit RGB frame encoded as JPEG and decoded again
- :func:`jpeg_roundtrip_tables`: the same coding with an encoder's own tables, in numpy with libjpeg's rounding
- :func:`quantisation_step`: one frequency's quantisation step from the DCT coefficients of decoded blocks
- :func:`read_tables`: the luma and chroma steps decoded JPEG frames show
- :func:`ijg_quality`: the IJG quality whose scaled standard table holds the steps read
- :func:`standard_tables`: the IJG-scaled Annex K tables at a quality
- :func:`fit_jpeg`: diagnosis's fit: the subsampling, quality and chroma quality whose coded noisy model frames
  best match the measured means (coarse grid, then finer steps; only the coding is repeated), then the tables
  read off the frames
- :class:`Jpeg`: encodes the final 8-bit frame as JPEG (``quality``, ``chroma_quality``, ``subsampling``, or an
  encoder's own tables) and decodes it again
- :data:`LUMA_WEIGHTS`, :func:`bt601_luma`: JPEG's luma (full-range BT.601) of RGB frames
- :data:`PLATE_QUALITIES`: the qualities at which :func:`jpeg_quality_from_plate` calibrates blockiness
- :func:`block_difference_profile`: mean absolute neighbour difference at each phase of a period (the 8x8 grid)
- :func:`jpeg_blockiness`: blockiness per axis, the grid's phase and the tile evidence that the grid is there
- :func:`jpeg_blockiness_statistic`: the no-reference statistic ``block_step_h``, ``block_step_v`` of a stack (DN)
- :func:`jpeg_quality_from_plate`: the JPEG quality the footage's blockiness implies (a plate estimate)

Blockiness from the footage alone
---------------------------------
JPEG quantises each 8x8 block's DCT on its own, so the luma steps across block boundaries exceed those inside
blocks [Wang2000]. Per axis, ``D[p]`` is the mean absolute difference between neighbours ``p`` and ``p + 1``
(modulo 8) and the blockiness is ``D[p*]`` over the median of ``D[p* + 2]``, ``D[p* + 4]``, ``D[p* + 6]`` at the
grid's phase ``p*`` (7 when the grid starts at the frame's corner): 1.0 without a grid. The reference is the phases
of ``p*``'s parity, not all the others: a demosaiced Bayer mosaic repeats every 2 px and raises every second phase
alike, which the median of all the others would read as a grid. The quality is found by
coding the footage's own frame again, shifted by half a block so its old grid falls inside the new blocks, at
:data:`PLATE_QUALITIES` (:func:`jpeg_roundtrip`), and inverting that curve of the block step in DN
(``D[p*] - median(D[others])``: the frame coded again shares any such structure) against quality, corrected for
the frame being coded already (a second recoding extrapolates back to one coding). The confidence is earned from
the tiles (64 px): that the grid is there (its log ratio per tile, mean over standard error: a t statistic, on
both axes) and how narrow a range of qualities the block step's scatter over the tiles leaves. A frame too flat
for coding it again to tell qualities apart is not measurable, whatever its grid.

References
----------
- [T.81] ITU-T Recommendation T.81 | ISO/IEC 10918-1, "Digital compression and coding of continuous-tone still
  images" (JPEG), 1992 (Annex K: the example quantisation tables).
- [IJG] Independent JPEG Group, libjpeg 6b, ``jcparam.c``: ``jpeg_quality_scaling`` (the quality -> table
  percentage rule that OpenCV, Pillow and most cameras' encoders use).
- [Wang2000] Z. Wang, A. C. Bovik and B. L. Evans, "Blind measurement of blocking artifacts in images", Proc. IEEE
  ICIP 2000, vol. 3, 981-984 (blockiness as the excess of the block-boundary differences).
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import LowcamError
from ..plate_estimate import PlateEstimate, PlateProbe
from .base import Effect, Param, Search

#: The chroma subsamplings the encoder offers (J:a:b): full, halved across, halved across and down.
SUBSAMPLINGS = ("4:4:4", "4:2:2", "4:2:0")

#: Coarse quality grid of :func:`fit_jpeg`, then the steps around the best.
_COARSE_QUALITY = (20, 40, 60, 75, 90)


def _encode_decode(frame: np.ndarray, quality: int, subsampling: str) -> np.ndarray:
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

    luma = cv2.cvtColor(_encode_decode(frame, quality, subsampling), cv2.COLOR_RGB2YCrCb)
    chroma = cv2.cvtColor(_encode_decode(frame, chroma_quality, subsampling), cv2.COLOR_RGB2YCrCb)
    chroma[..., 0] = luma[..., 0]
    return cv2.cvtColor(chroma, cv2.COLOR_YCrCb2RGB)


#: (rows, cols) halving of the chroma planes per subsampling.
_CHROMA_STEP = {"4:4:4": (1, 1), "4:2:2": (1, 2), "4:2:0": (2, 2)}


def _dct_matrix() -> np.ndarray:
    """The orthonormal 8-point DCT-II matrix C: a block's JPEG DCT is ``C b C^T`` [T.81, A.3.3]."""
    k = np.arange(8)
    c = np.sqrt(2 / 8) * np.cos((2 * k[None, :] + 1) * k[:, None] * np.pi / 16)
    c[0] /= np.sqrt(2)
    return c


_DCT = _dct_matrix()


def _blocks(plane: np.ndarray) -> np.ndarray:
    """(rows/8, cols/8, 8, 8) view of a plane whose sides are multiples of 8."""
    h, w = plane.shape
    return plane.reshape(h // 8, 8, w // 8, 8).swapaxes(1, 2)


def _pad(plane: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The plane with its last row and column repeated to multiples of ``rows`` and ``cols`` (as libjpeg fills
    partial blocks)."""
    h, w = plane.shape
    return np.pad(plane, ((0, -h % rows), (0, -w % cols)), mode="edge")


def _code_plane(plane: np.ndarray, table) -> np.ndarray:
    """One plane (sides multiples of 8, values 0-255) through the DCT, quantisation by ``table`` (natural order;
    rounding half away from zero, as libjpeg) and back, rounded and limited to 0-255 as a decoder stores it."""
    q = np.asarray(table, np.float64).reshape(8, 8)
    coefficients = _DCT @ _blocks(plane - 128.0) @ _DCT.T
    levels = np.sign(coefficients) * np.floor(np.abs(coefficients) / q + 0.5)
    out = (_DCT.T @ (levels * q) @ _DCT).swapaxes(1, 2).reshape(plane.shape)
    return np.clip(np.floor(out + 128.5), 0, 255)


def _downsample(plane: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Box means of ``rows`` x ``cols`` pixels with libjpeg's alternating rounding bias (jcsample.c: 1, 2 for
    2x2 boxes; 0, 1 for pairs)."""
    if rows * cols == 1:
        return plane
    h, w = plane.shape
    total = plane.reshape(h // rows, rows, w // cols, cols).sum(axis=(1, 3))
    n = rows * cols
    bias = np.where(np.arange(w // cols) % 2 == 0, n // 4, n // 2)
    return np.floor((total + bias) / n)


def _fancy_upsample(plane: np.ndarray, rows: int) -> np.ndarray:
    """libjpeg's "fancy" (triangle) chroma upsampling, doubling the columns (and the rows when ``rows`` is 2):
    each new pixel weighs its own sample 3/4 and the nearer neighbour 1/4 per axis, integer-rounded as
    jdsample.c does."""
    def shifted(a, axis, step):
        edge = np.take(a, [0 if step < 0 else -1], axis=axis)
        body = np.take(a, range(0, a.shape[axis] - 1) if step < 0 else range(1, a.shape[axis]), axis=axis)
        return np.concatenate([edge, body] if step < 0 else [body, edge], axis=axis)

    if rows == 1:
        out = np.empty((plane.shape[0], 2 * plane.shape[1]))
        out[:, 0::2] = np.floor((3 * plane + shifted(plane, 1, -1) + 1) / 4)
        out[:, 1::2] = np.floor((3 * plane + shifted(plane, 1, 1) + 2) / 4)
        out[:, 0], out[:, -1] = plane[:, 0], plane[:, -1]
        return out
    out = np.empty((2 * plane.shape[0], 2 * plane.shape[1]))
    for first, step in ((0, -1), (1, 1)):
        column = 3 * plane + shifted(plane, 0, step)  # 4x the vertical triangle's value
        half = out[first::2]
        half[:, 0::2] = np.floor((3 * column + shifted(column, 1, -1) + 8) / 16)
        half[:, 1::2] = np.floor((3 * column + shifted(column, 1, 1) + 7) / 16)
        half[:, 0] = np.floor((4 * column[:, 0] + 8) / 16)
        half[:, -1] = np.floor((4 * column[:, -1] + 7) / 16)
    return out


def _rgb_to_ycc(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full-range BT.601 Y, Cb, Cr (JFIF) of an RGB frame, float64, unrounded."""
    r, g, b = (frame[..., k].astype(np.float64) for k in range(3))
    return (0.299 * r + 0.587 * g + 0.114 * b, -0.168735892 * r - 0.331264108 * g + 0.5 * b + 128.0,
            0.5 * r - 0.418687589 * g - 0.081312411 * b + 128.0)


def jpeg_roundtrip_tables(frame: np.ndarray, luma_table, chroma_table, subsampling: str = "4:2:0") -> np.ndarray:
    """One 8-bit RGB frame (H, W, 3) coded as baseline JPEG with the quantisation tables ``luma_table`` and
    ``chroma_table`` (64 entries each, natural row-major order) and decoded again, in numpy, with libjpeg's
    arithmetic where it shows: JFIF colour conversion rounded to 8 bits, box chroma downsampling with its
    alternating bias, 8x8 DCT [T.81, A.3.3], quantisation rounded half away from zero, decoded samples rounded
    and limited to 0-255, fancy (triangle) chroma upsampling. For an encoder's own tables, which OpenCV cannot
    write; libjpeg's integer DCT rounds a few coefficients on the other side (about 95 % of pixels equal Pillow's
    decoded frame, 0.6-0.8 DN RMS apart)."""
    rows, cols = _CHROMA_STEP[subsampling]
    y, cb, cr = _rgb_to_ycc(frame)
    h, w = y.shape
    luma = _code_plane(_pad(np.floor(y + 0.5), 8 * rows, 8 * cols), luma_table)[:h, :w]
    chroma = []
    for c in (cb, cr):
        small = _downsample(_pad(np.floor(c + 0.5 - 2.0 ** -16), 8 * rows, 8 * cols), rows, cols)
        coded = _code_plane(small, chroma_table)[:-(-h // rows), :-(-w // cols)]
        if cols == 2:
            coded = _fancy_upsample(coded, rows)
        chroma.append(coded[:h, :w] - 128.0)
    cb, cr = chroma
    rgb = np.stack([luma + np.floor(1.402 * cr + 0.5), luma + np.floor(-0.344136286 * cb - 0.714136286 * cr + 0.5),
                    luma + np.floor(1.772 * cb + 0.5)], axis=-1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _unfancy(plane: np.ndarray, axis: int) -> np.ndarray:
    """The samples fancy upsampling doubled along ``axis``, recovered from the means of its output pairs:
    ``(3/4) c[i] + (1/8) (c[i-1] + c[i+1])`` (edges repeated), solved as a tridiagonal system."""
    from scipy.linalg import solve_banded

    a = np.moveaxis(plane, axis, 0)
    pairs = 0.5 * (a[0::2] + a[1::2])
    n = pairs.shape[0]
    band = np.zeros((3, n))
    band[0, 1:], band[1], band[2, :-1] = 0.125, 0.75, 0.125
    band[1, 0] += 0.125
    band[1, -1] += 0.125
    return np.moveaxis(solve_banded((1, 1), band, pairs.reshape(n, -1)).reshape(pairs.shape), 0, axis)


def _dct_of_frames(frames: np.ndarray, subsampling: str) -> tuple[np.ndarray, np.ndarray]:
    """The 8x8 DCT coefficients, (N, 64) natural order, of the luma and chroma blocks a JPEG decoder held for
    the decoded (T, H, W, 3) ``frames``: their colour converted back, the chroma's upsampling undone."""
    rows, cols = _CHROMA_STEP[subsampling]
    luma, chroma = [], []
    for frame in frames:
        y, cb, cr = _rgb_to_ycc(frame)
        h8, w8 = y.shape[0] // 8 * 8, y.shape[1] // 8 * 8
        luma.append((_DCT @ _blocks(y[:h8, :w8] - 128.0) @ _DCT.T).reshape(-1, 64))
        for c in (cb, cr):
            c = c[:c.shape[0] // (8 * rows) * 8 * rows, :c.shape[1] // (8 * cols) * 8 * cols]
            if cols == 2:
                c = _unfancy(c, 1)
            if rows == 2:
                c = _unfancy(c, 0)
            chroma.append((_DCT @ _blocks(c - 128.0) @ _DCT.T).reshape(-1, 64))
    return np.concatenate(luma), np.concatenate(chroma)


#: Coefficients of one frequency that :func:`quantisation_step` needs away from 0 to name its step.
_MIN_SUPPORT = 30


def quantisation_step(coefficients: np.ndarray, noise: float) -> int | None:
    """The quantisation step (1-255) of one frequency from the DCT coefficients of decoded blocks, which lie on
    its multiples plus the decoder's rounding (``noise``: how far from 0 a coefficient of a zero level reaches).

    Each step ``q`` is scored by ``mean(cos(2 pi c / q))`` over the coefficients beyond ``q / 2`` (those it
    codes as non-zero; at least :data:`_MIN_SUPPORT` of them), for ``q`` up to the largest coefficient (beyond,
    every score tends to 1); the best wins, or a multiple of it scoring as well (a divisor of the true step fits as
    well but for its noise), and is settled to the median of each coefficient over its multiple. None when fewer than :data:`_MIN_SUPPORT` coefficients lie beyond ``noise`` or no step scores
    0.5 (the step is not shown, or too fine for the noise)."""
    away = np.abs(coefficients[np.abs(coefficients) > noise])
    if away.size < _MIN_SUPPORT:
        return None
    steps = np.arange(2, int(min(255, away.max() + 2)) + 1)
    phases = np.cos(2 * np.pi * away[None, :] / steps[:, None])
    coded = away[None, :] > steps[:, None] / 2
    support = coded.sum(axis=1)
    scores = np.where(support >= _MIN_SUPPORT, (phases * coded).sum(axis=1) / np.maximum(support, 1), -1.0)
    i = int(np.argmax(scores))
    if scores[i] < 0.5:
        return None
    # a divisor of the step scores about as well (a little lower, for its noise): take the multiple that does
    multiples = [j for j in range(len(steps)) if steps[j] % steps[i] == 0 and j > i
                 and scores[j] >= scores[i] - 0.01 * (1 - scores[i]) - 1e-3]
    q = int(steps[multiples[-1] if multiples else i])
    # where the coefficients sit on the first few multiples only, neighbouring steps score alike: the lattice's
    # spacing, from each coefficient over its multiple, settles it
    coded = away[away > q / 2]
    return int(np.rint(np.median(coded / np.rint(coded / q))))


def read_tables(frames: np.ndarray, subsampling: str) -> tuple[list, list]:
    """The luma and chroma quantisation steps (natural order) of decoded JPEG ``frames`` (T, H, W, 3), read off
    the lattice of their blocks' DCT coefficients (:func:`quantisation_step`): 64 each, None where the frames do
    not show the step."""
    luma, chroma = _dct_of_frames(np.asarray(frames), subsampling)
    # undoing the upsampling amplifies the decoder's rounding by up to 2 per halved axis, most at high frequencies
    rows, cols = _CHROMA_STEP[subsampling]
    gain = 1 / (0.75 + 0.25 * np.cos(np.pi * np.arange(8) / 8))
    chroma_noise = 4.0 * np.outer(gain if rows == 2 else np.ones(8), gain if cols == 2 else np.ones(8)).ravel()
    return ([quantisation_step(luma[:, k], 3.0) for k in range(64)],
            [quantisation_step(chroma[:, k], chroma_noise[k]) for k in range(64)])


def ijg_quality(steps: list, chroma: bool = False, near: int = 50) -> int | None:
    """The IJG quality (1-100) whose scaled Annex K luma (``chroma``: chroma) table the steps read (None: not
    shown) are, judged on the lowest frequencies (row + column <= 4, where the coefficients are many): at least
    80 % of those read equal, none more than one step off (clipped coefficients read a little low); the most
    equal, then the nearest ``near``. None when no quality is, or none of those steps was read."""
    read = [(x, k) for k, x in enumerate(steps) if x is not None and k // 8 + k % 8 <= 4]
    best = None
    for q in range(1, 101):
        table = standard_tables(q)[1 if chroma else 0]
        if read and all(abs(x - table[k]) <= 1 for x, k in read):
            equal = sum(x == table[k] for x, k in read)
            if equal >= 0.8 * len(read) and (best is None or (equal, -abs(q - near)) > best[0]):
                best = ((equal, -abs(q - near)), q)
    return None if best is None else best[1]


def standard_tables(quality: int, chroma_quality: int = 0) -> tuple[list, list]:
    """The IJG-scaled [T.81] Annex K tables (natural order) at ``quality`` (chroma at ``chroma_quality``, 0:
    ``quality``): the tables OpenCV's encoder writes."""
    def scaled(base, q):
        q = int(min(100, max(1, q)))
        percent = 5000 // q if q < 50 else 200 - 2 * q
        return [int(min(255, max(1, (b * percent + 50) // 100))) for b in base]

    return scaled(_ANNEX_K_LUMA, quality), scaled(_ANNEX_K_CHROMA, chroma_quality or quality)


#: [T.81] Annex K, tables K.1 and K.2 (natural order): quality 50's luma and chroma tables.
_ANNEX_K_LUMA = (16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99)
_ANNEX_K_CHROMA = (17, 18, 24, 47, 99, 99, 99, 99, 18, 21, 26, 66, 99, 99, 99, 99, 24, 26, 56, 99, 99, 99, 99, 99,
                   47, 66, 99, 99, 99, 99, 99, 99) + (99,) * 32


def fit_jpeg(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): the subsampling, quality and chroma quality whose coded
    frames' temporal means best match the measured means (squared residual summed over the context's few
    :attr:`~lowcam.measure.diagnose.Context.quick` captures).

    The model's frames keep their noise: JPEG is not linear, so the mean of coded noisy frames is not the coding
    of the clean frame (quantisation of noisy coefficients shrinks them less), and a noise-free fit picks too
    low a quality. When JPEG is the chain's last stage, the model's noisy frames are simulated once without it
    and each trial only codes them again (the frames :func:`lowcam.measure.compare.compare` makes); otherwise
    each trial re-simulates the chain (``ctx.simulate``: the effects do not run the pipeline themselves). Every
    subsampling is tried on a coarse quality grid; for the best, the quality is refined, then the chroma quality
    on its own (an encoder's tables rarely have the standard luma/chroma balance), then the quality again. While
    diagnosis screens (``ctx.screening``), only the coarse grid at 4:2:0.
    """
    p = ctx.profile
    caps, idx = ctx.mset.captures, ctx.quick  # a few captures: the flattest and the most textured
    means = [ctx.means[i] for i in idx]
    with_it = p.with_effect(effect)
    names = [e.name for e in with_it.effects if e.enabled or e.always_runs]
    shortcut = names[-1] == effect
    if shortcut:
        have = p.effect(effect)
        base = p.without(effect) if have is not None and have.enabled else p
        uncoded = [ctx.simulate(base, i, max(len(caps[i].frames), 4)) for i in idx]
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
                frames = [ctx.simulate(p.with_effect(effect, quality=q, subsampling=s, chroma_quality=key[2],
                                                     **_SCALED), i, max(len(caps[i].frames), 4)) for i in idx]
                scores[key] = float(sum(((m - g.mean(axis=0)) ** 2).sum() for m, g in zip(means, frames)))
        return scores[key]

    def refine(best, steps, score):
        return int(min(100, max(1, min((best + d for d in steps), key=score))))

    if getattr(ctx, "screening", False):  # screening: the usual subsampling on the coarse grid only
        q = min(_COARSE_QUALITY, key=lambda v: sse(v, "4:2:0"))
        return p.with_effect(effect, quality=q, subsampling="4:2:0", **_SCALED), \
            {"quality": q, "subsampling": "4:2:0"}, {"quality": q, "subsampling": "4:2:0", "chroma_quality": q,
                                                     "tables": "IJG-scaled"}
    q, s = min(((q, s) for s in SUBSAMPLINGS for q in _COARSE_QUALITY), key=lambda qs: sse(*qs))
    for steps in ((-12, -6, 0, 6, 12), (-3, 0, 3), (-1, 0, 1)):
        q = refine(q, steps, lambda v: sse(v, s))
    qc = q
    for steps in ((-40, -20, 0, 20, 40), (-10, 0, 10), (-5, 0, 5), (-2, 0, 2), (-1, 0, 1)):
        qc = refine(qc, steps, lambda v: sse(q, s, v))
    for steps in ((-2, 0, 2), (-1, 0, 1)):
        q = refine(q, steps, lambda v: sse(v, s, qc))
    values = {"quality": q, "subsampling": s, "chroma_quality": 0 if qc == q else qc}
    shown = dict(values, chroma_quality=qc, tables="IJG-scaled")
    values.update(_SCALED)
    # the tables, read off the measured frames' DCT lattice: IJG's at some quality (libjpeg codes those exactly),
    # or an encoder's own, where they fit better than the qualities fitted
    luma, chroma = read_tables(np.concatenate([caps[i].frames for i in idx]), s)
    read = sum(x is not None for x in luma + chroma)
    ql = ijg_quality(luma, near=q) if read else None
    qc_read = ijg_quality(chroma, chroma=True, near=qc) if any(x is not None for x in chroma) else ql
    if ql is not None and qc_read is not None:
        if (ql, qc_read) != (q, qc) and sse(ql, s, qc_read) < sse(q, s, qc):
            q, qc = ql, qc_read
            values.update(quality=q, chroma_quality=0 if qc == q else qc)
            shown.update(quality=q, chroma_quality=qc, tables=f"IJG-scaled ({read} of the 128 steps read off "
                                                             "the frames)")
    elif read:
        standard = standard_tables(q, qc)
        luma, chroma = ([x if x is not None else t for x, t in zip(steps, table)]
                        for steps, table in zip((luma, chroma), standard))
        own = {"subsampling": s, "luma_table": luma, "chroma_table": chroma}
        if shortcut:
            score = float(sum(((m - np.mean([jpeg_roundtrip_tables(f, luma, chroma, s) for f in g], axis=0)) ** 2
                               ).sum() for m, g in zip(means, uncoded)))
        else:
            frames = [ctx.simulate(p.with_effect(effect, **own), i, max(len(caps[i].frames), 4)) for i in idx]
            score = float(sum(((m - g.mean(axis=0)) ** 2).sum() for m, g in zip(means, frames)))
        if score < sse(q, s, qc):
            values = dict(values, **own)
            shown = dict(shown, tables=f"the encoder's own ({read} of the 128 steps read off the frames)")
    return p.with_effect(effect, **values), values, shown


#: The values that make a JPEG effect code with the IJG-scaled tables (no own tables).
_SCALED = {"luma_table": [], "chroma_table": []}

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
                       "chroma {subsampling}, tables {tables}",
                       fit=fit_jpeg),)
    params = {"quality": Param(90, int, low=1, high=100, doc="IJG quality: the standard tables' scaling"),
              "subsampling": Param("4:2:0", str, choices=SUBSAMPLINGS, doc="chroma subsampling (J:a:b)"),
              "chroma_quality": Param(0, int, low=0, high=100, doc="IJG quality of the chroma table; 0: quality"),
              "luma_table": Param([], "vector", low=1, high=255, whole=True,
                                  doc="an encoder's own luma table, 64 steps in natural order; [] the IJG-scaled"),
              "chroma_table": Param([], "vector", low=1, high=255, whole=True,
                                    doc="an encoder's own chroma table, 64 steps in natural order; [] with luma_table: "
                                        "as luma_table")}

    def check(self):
        if len(self.luma_table) not in (0, 64) or len(self.chroma_table) not in (0, 64):
            raise self.error("'luma_table' and 'chroma_table' hold 64 steps each (natural order), or none")
        if self.chroma_table and not self.luma_table:
            raise self.error("'chroma_table' needs 'luma_table'")

    def apply(self, state):
        """Nothing before the blend: the encode acts on the delivered frame (:meth:`finish`)."""

    def finish(self, state, frame, footprint):
        try:
            if self.luma_table:
                out = jpeg_roundtrip_tables(frame, self.luma_table, self.chroma_table or self.luma_table,
                                            self.subsampling)
            else:
                out = jpeg_roundtrip(frame, self.quality, self.subsampling, self.chroma_quality)
        except LowcamError as e:
            raise LowcamError(f"{self.source}: {e}") from None
        return out, np.ones_like(footprint)


#: The qualities at which :func:`jpeg_quality_from_plate` codes the footage's frame again to calibrate.
PLATE_QUALITIES = (5, 10, 15, 20, 25, 30, 40, 50, 60, 70, 80, 85, 90, 95)

_TILE_PX = 64  # tile side (px) of the grid evidence
_GRID_T = (3.0, 4.5)  # tile t statistic of the grid: none below the first, certain from the second


#: Full-range BT.601 luma weights of red, green and blue (JFIF, ITU-T T.871): JPEG's Y.
LUMA_WEIGHTS = (0.299, 0.587, 0.114)


def bt601_luma(frames: np.ndarray) -> np.ndarray:
    """Full-range BT.601 luma (DN) of a (..., 3) RGB array (:data:`LUMA_WEIGHTS`), float32 (NaN where a channel
    is NaN)."""
    f = np.asarray(frames, np.float32)
    return LUMA_WEIGHTS[0] * f[..., 0] + LUMA_WEIGHTS[1] * f[..., 1] + LUMA_WEIGHTS[2] * f[..., 2]


def block_difference_profile(plane: np.ndarray, axis: int, period: int = 8) -> np.ndarray:
    """``D[p]`` (DN), p = 0..period-1: the mean absolute difference between neighbours ``p`` and ``p + 1``
    (modulo ``period``) along ``axis`` (-1: across, horizontal steps; -2: down) of a (..., H, W) plane."""
    d = np.abs(np.diff(np.asarray(plane, np.float32), axis=axis))
    d = np.moveaxis(d, axis, -1)
    n = d.shape[-1] // period * period
    if n == 0:
        return np.zeros(period)
    return d[..., :n].reshape(-1, n // period, period).mean(axis=(0, 1)).astype(np.float64)


def _same_parity(profile: np.ndarray) -> np.ndarray:
    """Per phase ``p`` (the last axis): the median of ``D[p + 2]``, ``D[p + 4]``, ``D[p + 6]``, the other phases a
    structure of period 2 px (a demosaiced Bayer mosaic) raises with ``p``."""
    return np.median(np.stack([np.roll(profile, -k, axis=-1) for k in (2, 4, 6)]), axis=0)


def _ratio(profile: np.ndarray, phase: int) -> float:
    return float(profile[phase] / max(_same_parity(profile)[phase], 1e-9))


def jpeg_blockiness(frames: np.ndarray, phases: tuple[int, int] | None = None) -> dict:
    """Blockiness of a (T, H, W, 3) or (H, W, 3) RGB stack (DN) per axis [Wang2000].

    Returns ``blockiness_h`` / ``blockiness_v`` (``D[p*]`` over the median of ``D[p* + 2, 4, 6]``, 1.0: no grid),
    the grid phases ``phase_h`` / ``phase_v`` (``p*``: 7 when blocks start at the frame's corner; ``phases`` fixes
    them), and per axis the tile evidence ``t_h`` / ``t_v``: over 64 px tiles, the mean of the tile's log ratio at
    ``p*`` over its standard error (a t statistic; about 0-3 without a grid). ``p*`` is the phase of the largest
    mean log ratio over the tiles (a grid's smear into the next phase, which a phone's deblocking leaves, and the
    flat insides of strongly coded blocks do not move it there)."""
    y = bt601_luma(frames)
    if y.ndim == 2:
        y = y[None]
    out = {}
    h, w = y.shape[1:]
    for k, (axis, name) in enumerate(((-1, "h"), (-2, "v"))):
        prof = block_difference_profile(y, axis)
        tiles = [block_difference_profile(y[:, i:i + _TILE_PX, j:j + _TILE_PX], axis)
                 for i in range(0, h - _TILE_PX + 1, _TILE_PX) for j in range(0, w - _TILE_PX + 1, _TILE_PX)]
        tiles = np.array([tp for tp in tiles if tp.min() > 0]).reshape(-1, 8)
        t, mean = np.zeros(8), prof / np.maximum(_same_parity(prof), 1e-9) - 1
        if len(tiles) >= 4:  # every phase's tile log ratio: its mean and t statistic
            logs = np.log(tiles / _same_parity(tiles))
            mean = logs.mean(0)
            t = mean / np.maximum(logs.std(0, ddof=1) / np.sqrt(len(logs)), 1e-9)
        p = int(np.argmax(mean)) if phases is None else int(phases[k])
        out[f"blockiness_{name}"] = _ratio(prof, p)
        out[f"phase_{name}"] = p
        out[f"t_{name}"] = float(t[p])
    return out


def _block_step(frames: np.ndarray, phases: tuple[int, int] = (7, 7)) -> dict:
    """``D[p*] - median(D[others])`` (DN) per axis at the grid phases (``block_step_h``, ``block_step_v``)."""
    y = bt601_luma(frames)
    out = {}
    for k, (axis, name) in enumerate(((-1, "h"), (-2, "v"))):
        prof = block_difference_profile(y, axis)
        out[f"block_step_{name}"] = float(prof[phases[k]] - np.median(np.delete(prof, phases[k])))
    return out


def jpeg_blockiness_statistic(frames: np.ndarray) -> dict:
    """The no-reference statistic of a (T, H, W, 3) stack (DN) that ``compare --plate-only`` compares:
    ``block_step_h`` and ``block_step_v``, the luma step across the standard grid (blocks from the frame's
    corner, as a camera codes its frames) less the median step inside blocks, ``D[7] - median(D[0..6])`` in DN.
    The difference depends less on how soft the scene is than the ratio does (the model films a softened copy
    of the footage). ``{}`` for frames under 16 px."""
    f = np.asarray(frames)
    if min(f.shape[-3:-1]) < 16:
        return {}
    return _block_step(f)


def _step_level(frames, phases=(7, 7)) -> float:
    b = _block_step(frames, phases)
    return (b["block_step_h"] + b["block_step_v"]) / 2


def _quality_curve(frame: np.ndarray, phases: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The block step (DN) that coding at each of :data:`PLATE_QUALITIES` gives ``frame``'s scene, corrected for
    the frame being coded already: ``2 s(coded once more) - s(coded twice more)``, each new grid moved off the
    earlier ones (by 4 px, then 2 px), the linear extrapolation back to one coding."""
    top, left = (phases[1] + 1 + 4) % 8, (phases[0] + 1 + 4) % 8  # the old grid lands mid-block
    f = np.ascontiguousarray(np.clip(np.rint(frame[top:, left:]), 0, 255).astype(np.uint8))
    out = []
    for q in PLATE_QUALITIES:
        once = jpeg_roundtrip(f, q)
        twice = jpeg_roundtrip(np.ascontiguousarray(once[2:, 2:]), q)
        out.append(2 * _step_level(once) - _step_level(twice))
    return np.array(PLATE_QUALITIES, float), np.array(out)


def _tile_levels(frames: np.ndarray, phases: tuple[int, int]) -> np.ndarray:
    """The block step level (:func:`_step_level`, DN) of each :data:`_TILE_PX` tile of a stack."""
    h, w = frames.shape[1:3]
    return np.array([_step_level(frames[:, i:i + _TILE_PX, j:j + _TILE_PX], phases)
                     for i in range(0, h - _TILE_PX + 1, _TILE_PX) for j in range(0, w - _TILE_PX + 1, _TILE_PX)])


def jpeg_quality_from_plate(footage, base=None, film=None):
    """The IJG quality the footage's JPEG blockiness implies, as a :class:`lowcam.plate_estimate.PlateEstimate`
    for the ``jpeg`` effect (see "Blockiness from the footage alone" above).

    The grid is found on up to 8 frames by the blockiness ratio; the quality from the block step in DN
    (``D[p*] - median(D[others])``, which depends less on the scene's softness): the calibration codes the
    middle frame again at :data:`PLATE_QUALITIES` (bias-corrected, :func:`_quality_curve`) and interpolates the
    quality whose step matches (the curve made monotone). Measured: within 9 of the true quality on Pillow's
    and the engine's JPEGs at 20, 50 and 80 (three scenes).

    The confidence is earned from two pieces of evidence: that the grid is there, ``(t - 3) / 1.5`` of the weaker
    axis's tile t statistic clipped to 0..1 (without an 8x8 grid, in uncompressed or high-quality frames or a grid
    a scaler smeared, it is near 0), times the precision of the quality, ``1 - w / 40`` clipped to 0..1, ``w`` the
    width of the qualities whose steps lie within two standard errors of the measured one (the step's scatter
    over 64 px tiles). Not measurable: frames too flat for coding them again to tell qualities apart (the
    calibration's steps span under 1 DN or ten standard errors from quality 5 to 95), or a step above quality
    5's. A step below quality 95's gives quality 95 ("at least")."""
    name, effect = "jpeg_blockiness", "jpeg"
    frames = footage.stack(max_frames=8)
    b = jpeg_blockiness(frames)
    t = min(b["t_h"], b["t_v"])
    grid = float(np.clip((t - _GRID_T[0]) / (_GRID_T[1] - _GRID_T[0]), 0, 1))
    measured = {k: round(v, 4) if isinstance(v, float) else v for k, v in b.items()}
    phases = (b["phase_h"], b["phase_v"])
    qs, curve = _quality_curve(frames[len(frames) // 2], phases)
    curve = np.minimum.accumulate(curve)  # the step falls as the quality rises
    level = _step_level(frames, phases)
    tiles = _tile_levels(frames, phases)
    if len(tiles) < 4:
        return PlateEstimate.not_measurable(name, effect, measured, f"{len(tiles)} tiles of {_TILE_PX} px: frames "
                                            "too small to tell the block step's scatter")
    se = float(tiles.std(ddof=1) / np.sqrt(len(tiles)))
    span = float(curve[0] - curve[-1])
    measured.update(block_step_dn=round(level, 4), block_step_se_dn=round(se, 4),
                    calibration={"quality": [int(v) for v in qs], "block_step_dn": [round(float(v), 4) for v in curve]})
    if not span >= max(1.0, 10 * se):
        return PlateEstimate.not_measurable(
            name, effect, measured, f"too flat: coding the frame again at qualities 5 to 95 changes its block step "
            f"by {span:.2f} DN (at least {max(1.0, 10 * se):.2f} needed to tell qualities apart)")
    if t < _GRID_T[0]:
        return PlateEstimate(name, effect, measured, {}, 0.0,
                             f"no 8x8 grid (tile t statistic {t:.1f} < {_GRID_T[0]:.0f}): uncompressed, or coded at a "
                             "high quality")
    if level >= curve[0]:
        return PlateEstimate.not_measurable(
            name, effect, measured, f"block step {level:.3f} DN above quality {int(qs[0])}'s ({curve[0]:.3f}): no "
            "IJG quality codes this scene so")

    def quality(step):
        return float(qs[-1]) if step <= curve[-1] else float(qs[0]) if step >= curve[0] else \
            float(np.interp(-step, -curve, qs))

    q = int(round(quality(level)))
    lo, hi = quality(level + 2 * se), quality(level - 2 * se)
    precision = float(np.clip(1 - (hi - lo) / 40.0, 0, 1))
    note = f"; block step {level:.3f} DN at or below quality {int(qs[-1])}'s: at least {q}" if level <= curve[-1] \
        else ""
    aligned = b["phase_h"] == 7 and b["phase_v"] == 7
    reason = (f"8x8 grid on both axes (tile t statistic {t:.1f}); quality {lo:.0f}-{hi:.0f} within two standard "
              f"errors of the block step" + ("" if aligned else
              f"; the grid is offset ({(b['phase_h'] + 1) % 8}, {(b['phase_v'] + 1) % 8}) px: cropped or "
              "shifted after coding") + note)
    measured["quality_range"] = [round(lo), round(hi)]
    return PlateEstimate(name, effect, measured, {"quality": q}, round(grid * precision, 3), reason)


#: Declared after its estimator and statistic, which the module defines below the class.
Jpeg.plate_probe = PlateProbe("jpeg_blockiness", jpeg_quality_from_plate, jpeg_blockiness_statistic, order=20,
                               about="luma steps across the 8x8 grid over those inside blocks; the quality that "
                                     "codes the frame so")
