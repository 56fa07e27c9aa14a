"""H.264 or HEVC coding of the delivered frames with a real encoder (a phone's, action camera's or webcam's video
stream; not in the paper).

The frames are coded with x264 [H.264] or x265 [H.265] through FFmpeg's libraries (PyAV) and decoded again with
FFmpeg's own decoders. Each frame's R'G'B' is converted to 8-bit 4:2:0 Y'CbCr (``yuv420p``) with the ``matrix``
(BT.601 or BT.709 luma weights) and ``range`` (limited: Y' 16-235, C 16-240; full: 0-255) the effect states, the
chroma the mean of each 2x2 block (:func:`lowcam.video.rgb_to_ycbcr`), and decoded back with the same matrix, each
chroma sample repeated over its 2x2 block (:func:`lowcam.video.to_rgb`, as plates are read). Odd sides are padded
by repeating the last row or column and cropped after decoding.

The rate is x264's or x265's constant rate factor ``crf`` (0-51; higher: coarser), or an average bitrate
``bitrate_kbps`` at ``fps`` when that is set. A group of pictures is ``gop_frames`` long: its first frame is an
I-frame (coded on its own), the others are P- or B-frames predicted from the frames before (and, for B-frames,
after) them, with at most ``b_frames`` B-frames in a row; scene cuts do not start a new group. A predicted block
whose residual quantises to zero is copied from its reference, so the noise of a still scene is held from frame to
frame: the temporal variance of a coded sequence falls below the sensor's, more so at high ``crf``, and jumps back
at each I-frame.

Frames in sequence and single frames
------------------------------------
A video codec codes the frames of a shot together, so the effect acts on sequences (``temporal``): where the
frames of one shot or one capture are made together (the ``count`` frames of a measurement capture, which
diagnosis and ``compare`` simulate), they are coded as one sequence, frame 0 an I-frame
(:meth:`VideoCodec.finish_frames`). A frame made on its own (``lowcam.simulate``, ``lowcam run``, and each frame
of ``lowcam batch`` written as image files, which the farm's workers make independently) is coded as one
I-frame (:meth:`VideoCodec.finish`): the same bytes whichever worker makes it. The whole frame is coded, and the
coded pixels are kept where the graphics reach (the footprint); the plate's pixels that they do not reach keep
their own bytes (the real camera coded them already), so only the inserted region carries this coding (in a shot
of image files, an I-frame's blocks and ringing; not the held noise of predicted frames, nor the coding's spill
from the graphics' blocks onto the plate around them). A shot written as a video (``lowcam batch -o shot.mp4``) is coded as a whole by the
writer (:func:`lowcam.video.write_video`), with the plate's own coding where it can be read.

The coding is deterministic: the encoders run on one thread (x264 ``threads=1``; x265 ``pools=none``,
``frame-threads=1``) on an initialised heap (:func:`lowcam.video.initialised_heap`: x264 reads memory it has not
written), so the same frames at the same settings give the same bytes.

Contents
--------
- :data:`CODECS`: the codecs, name -> (encoder, decoder)
- :data:`PRESETS`: the encoders' speed presets
- :func:`code_sequence`: a sequence of 8-bit RGB frames coded as H.264 or HEVC and decoded again
- :func:`i_frames`: where coded captures' noise is drawn afresh: their I-frames
- :func:`fit_video_codec`: diagnosis's fit: the GOP length read off the frames, then the codec, CRF and
  B-frames whose coded noisy model sequences best match the measured frames (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`)
- :class:`VideoCodec`: the stage

It has no compositor node: the node group refuses a profile with it (``lowcam.node_maps.bake``), and the render
handler, which runs the engine, simulates it.

References
----------
- [H.264] ITU-T Recommendation H.264 | ISO/IEC 14496-10, "Advanced video coding for generic audiovisual
  services" (I, P and B slices sec. 7.4.3; the quantisation parameter sec. 8.5.12).
- [H.265] ITU-T Recommendation H.265 | ISO/IEC 23008-2, "High efficiency video coding".
- [H.273] ITU-T Recommendation H.273, "Coding-independent code points for video signal type identification"
  (matrix and range, eq. 23-41).
- [x264] x264's ``--crf``, ``--keyint``, ``--bframes`` and ``--preset`` (x264 --fullhelp); x265's alike
  (x265 documentation, "Command Line Options").
"""
from __future__ import annotations

from fractions import Fraction

import av
import numpy as np

from ..errors import LowcamError
from ..video import PlateColour, initialised_heap, rgb_to_ycbcr, to_rgb
from .base import Effect, Param, Search
from .delivered_frame import fit_delivered_stage

#: The codecs: name -> (FFmpeg's encoder, its decoder).
CODECS = {"h264": ("libx264", "h264"), "hevc": ("libx265", "hevc")}
#: The speed presets x264 and x265 share (slower: more search, fewer bits at the same quality).
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")
#: The matrices the frames are coded with (H.273 MatrixCoefficients 6 and 1).
MATRICES = ("bt601", "bt709")
_MATRIX_CODE = {"bt601": 6, "bt709": 1}


def _encoder(codec: str, width: int, height: int, crf: float, gop_frames: int, b_frames: int, preset: str,
             matrix: str, full: bool, bitrate_kbps: float, fps: float):
    encoder = CODECS[codec][0]
    cc = av.CodecContext.create(encoder, "w")
    cc.width, cc.height, cc.pix_fmt = width, height, "yuv420p"
    rate = Fraction(fps).limit_denominator(1001)
    cc.time_base, cc.framerate = 1 / rate, rate
    cc.colorspace, cc.color_range = _MATRIX_CODE[matrix], 2 if full else 1
    cc.thread_count = 1
    gop = f"keyint={gop_frames}:min-keyint={gop_frames}:scenecut=0:bframes={b_frames}"
    options = {"preset": preset}
    if bitrate_kbps > 0:
        cc.bit_rate = int(bitrate_kbps * 1000)
    else:
        options["crf"] = f"{crf:g}"
    if encoder == "libx265":
        options["x265-params"] = gop + ":pools=none:frame-threads=1:log-level=error"
    else:
        options["x264-params"] = gop + ":threads=1:lookahead-threads=1"
    cc.options = options
    return cc


def code_sequence(frames: np.ndarray, codec: str = "h264", crf: float = 23.0, gop_frames: int = 30,
                  b_frames: int = 0, preset: str = "medium", matrix: str = "bt601", range: str = "limited",
                  bitrate_kbps: float = 0.0, fps: float = 30.0) -> np.ndarray:
    """``frames`` (T, H, W, 3) uint8 R'G'B' coded in order as one H.264 or HEVC sequence (``codec`` a key of
    :data:`CODECS`) and decoded again: (T, H, W, 3) uint8. Frame 0 is an I-frame, then one every ``gop_frames``;
    at most ``b_frames`` B-frames in a row; the rate a constant rate factor ``crf``, or ``bitrate_kbps`` (kbit/s)
    at ``fps`` when above 0. Colour in 4:2:0 with ``matrix`` and ``range`` (see the module's docstring)."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise LowcamError(f"video coding takes (T, H, W, 3) uint8 frames, got {frames.dtype} {frames.shape}")
    t, h, w = frames.shape[:3]
    padded = np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge") if (h % 2 or w % 2) else frames
    hh, ww = padded.shape[1:3]
    full = range == "full"
    colour = PlateColour(matrix, range, "sdr", "the video codec effect")
    with initialised_heap():  # x264 reads memory it has not written
        try:
            enc = _encoder(codec, ww, hh, crf, gop_frames, b_frames, preset, matrix, full, bitrate_kbps, fps)
            dec = av.CodecContext.create(CODECS[codec][1], "r")
            dec.thread_count = 1
            out = []

            def decode(packets):
                for packet in packets:
                    for picture in dec.decode(packet):
                        out.append(to_rgb(picture, colour)[:h, :w])

            for i, rgb in enumerate(padded):
                picture = av.VideoFrame(ww, hh, "yuv420p")
                for plane, data in zip(picture.planes, rgb_to_ycbcr(rgb, 8, matrix, full)):
                    buf = np.zeros((plane.height, plane.line_size), np.uint8)
                    buf[:, :data.shape[1]] = data
                    plane.update(buf.tobytes())
                picture.pts = i
                picture.colorspace, picture.color_range = _MATRIX_CODE[matrix], 2 if full else 1
                decode(enc.encode(picture))
            decode(enc.encode(None))
            for picture in dec.decode(None):
                out.append(to_rgb(picture, colour)[:h, :w])
        except av.FFmpegError as e:
            raise LowcamError(f"{CODECS[codec][0]} refused {ww}x{hh} frames: {str(e).splitlines()[0]}") from None
    if len(out) != t:
        raise LowcamError(f"{CODECS[codec][0]}: {t} frames coded, {len(out)} decoded")
    return np.stack(out)


#: Coarse plan of :func:`fit_video_codec`: CRF, then B-frames.
_COARSE_CRF = (18, 24, 28, 32, 36, 42)
_COARSE_B = (0, 2, 3)
#: The CRF grid while diagnosis screens (each codec).
_SCREENING_CRF = (22, 28, 34, 40)
#: Rows, columns of the centre a trial codes: a 640x480 frame whole (the encoder's rate control weighs each block
#: against its whole frame: fitted on a quarter of the frame, a flat capture read CRFs 3-7 too high).
_CROP = (480, 640)
#: The centre crop while diagnosis screens (and scores, less a margin): a quarter of a 640x480 frame.
_SCREENING_CROP = (256, 320)
#: A frame is an I-frame when its mean squared change from the frame before is this many times the median change,
#: at least half the largest, and above :data:`_MIN_CHANGE` (DN^2).
_I_FRAME_JUMP = 10.0
_MIN_CHANGE = 0.01


def _process(values, frames):
    return code_sequence(frames, values["codec"], values["crf"], values["gop_frames"], values["b_frames"],
                         values["preset"], values["matrix"], values["range"])


def i_frames(captures) -> list[int]:
    """The frame indices (after frame 0) at which coded captures' noise is drawn afresh: the I-frames. A predicted
    frame holds the noise of the frame before, an I-frame codes its own, so the mean squared change from the frame
    before, summed over the ``captures`` ((T, H, W, 3) stacks of one length), jumps there: frames whose change is
    at least :data:`_I_FRAME_JUMP` times the median change and half the largest (B- and P-frames change a little
    too). [] when no frame jumps."""
    changes = sum(np.square(np.diff(np.asarray(f, np.float32), axis=0)).mean(axis=(1, 2, 3)) for f in captures)
    changes = np.atleast_1d(changes)
    if len(changes) < 2:
        return []
    top = float(changes.max())
    jump = (changes >= _I_FRAME_JUMP * np.median(changes)) & (changes >= 0.5 * top) & (changes > _MIN_CHANGE)
    return [int(k) + 1 for k in np.nonzero(jump)[0]]


def fit_video_codec(ctx, effect):
    """Diagnosis's fit (a :class:`Search` ``fit``): the GOP length read off the frames, then the codec (H.264 or
    HEVC), CRF and B-frames whose coded noisy model sequences best match the measured frames' temporal means and
    variances (:func:`lowcam.effects.delivered_frame.fit_delivered_stage`,
    :func:`~lowcam.effects.delivered_frame.frame_score`, with its rows family).

    The GOP: the first I-frame after frame 0 (:func:`i_frames`) over the captures with the most frames; when none
    shows, the GOP is at least as long as the captures (their frame count is taken). The model keeps its noise,
    and as many frames as the captures have (at least 4): a predicted frame holds the noise of the frame it is
    predicted from, so what the coding does to the frames' variance depends on the GOP and on the noise itself.
    The model's noisy frames are simulated once without the codec and each trial codes them again: two sequences
    of independent noise, whose means' difference measures the noise of the mean (the frames' temporal variance no
    longer does), on whole frames up to :data:`_CROP` px (their centre). Per codec a coarse CRF grid
    (:data:`_COARSE_CRF`), then the B-frames (:data:`_COARSE_B`) and the CRF in steps of 2; for the better codec
    the CRF in steps of 1, the B-frames from 0 to 3 and the CRF again. While diagnosis screens, each codec on
    :data:`_SCREENING_CRF` only, on a centre crop of :data:`_SCREENING_CROP` px and a margin. The matrix, range
    and preset stay the profile's (or the defaults)."""
    p = ctx.profile
    have = p.effect(effect)
    fixed = {k: getattr(have, k) if have is not None else VideoCodec.params[k].default
             for k in ("preset", "matrix", "range")}
    caps = ctx.mset.captures
    count = max(4, max(len(caps[i].frames) for i in ctx.quick))
    longest = max(len(c.frames) for c in caps)
    jumps = i_frames([c.frames for c in caps if len(c.frames) == longest]) if longest > 2 else []
    gop = int(jumps[0]) if jumps else max(longest, 1)

    def near(steps):
        return lambda v: sorted({int(min(51, max(0, v["crf"] + d))) for d in steps})

    coarse = [("crf", list(_COARSE_CRF)), ("b_frames", list(_COARSE_B)), ("crf", near((-2, 0, 2)))]
    crop = _CROP
    if getattr(ctx, "screening", False):  # screening: both codecs on a coarser CRF grid, no B-frames, a crop
        coarse, crop = [("crf", list(_SCREENING_CRF))], _SCREENING_CROP
    plan = [("crf", near((-1, 0, 1))), ("b_frames", [0, 1, 2, 3]), ("crf", near((-1, 0, 1)))]
    searches = [(dict(fixed, codec=codec, crf=28, gop_frames=gop, b_frames=0), plan, coarse) for codec in CODECS]
    out, values, shown = fit_delivered_stage(ctx, effect, _process, searches, crop=crop, count=count,
                                             frozen_noise=True, screened_forms=len(CODECS))
    shown["gop_frames"] = f"{gop}" if jumps else f"at least {gop}"
    return out, values, shown


fit_video_codec.refines = True  # diagnosis calls it again, in full, for a promising candidate
fit_video_codec.honours_masks = True  # scored where the capture's mask is (fit_delivered_stage): tiles can be held out


class VideoCodec(Effect):
    """H.264 or HEVC coding of the delivered frames (x264, x265) and decoding again: a sequence of frames as one
    coded video (:meth:`finish_frames`), a frame on its own as an I-frame (:meth:`finish`), kept where the graphics
    reach; see the module's docstring."""

    name = "video_codec"
    section = "not in the paper"
    writes = "output"
    order = 290
    temporal = True
    searches = (Search("video_codec", "{codec} video at CRF {crf:g}, a GOP of {gop_frames} frames, up to "
                       "{b_frames} B-frames", fit=fit_video_codec, changes_noise=True, held_noise=True,
                       determined_by="textured"),)
    params = {
        "codec": Param("h264", str, choices=tuple(CODECS), doc="h264: x264 (ITU-T H.264); hevc: x265 (ITU-T "
                                                                 "H.265)"),
        "crf": Param(23.0, low=0.0, high=51.0, doc="the encoder's constant rate factor: higher codes coarser"),
        "gop_frames": Param(30, int, low=1, high=600, unit="frames", doc="frames from one I-frame to the next"),
        "b_frames": Param(0, int, low=0, high=16, unit="frames", doc="at most this many B-frames in a row"),
        "preset": Param("medium", str, choices=PRESETS, doc="the encoder's speed preset"),
        "matrix": Param("bt601", str, choices=MATRICES, doc="the Y'CbCr matrix the frames are coded with "
                                                            "(ITU-T H.273)"),
        "range": Param("limited", str, choices=("limited", "full"), doc="limited: Y' 16-235; full: 0-255"),
        "bitrate_kbps": Param(0.0, low=0.0, high=1e6, unit="kbit/s", doc="an average bitrate instead of the CRF; "
                                                                         "0: the CRF"),
        "fps": Param(30.0, low=1.0, high=240.0, unit="frames/s", doc="the frame rate a bitrate is spread over"),
    }

    def apply(self, state):
        """Nothing before the blend: the coding acts on the delivered frames (:meth:`finish`,
        :meth:`finish_frames`)."""

    def _code(self, frames: np.ndarray) -> np.ndarray:
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise self.error("acts on RGB frames; a raw camera delivers a colour-filter mosaic")
        try:
            return code_sequence(frames, self.codec, self.crf, self.gop_frames, self.b_frames, self.preset,
                                 self.matrix, self.range, self.bitrate_kbps, self.fps)
        except LowcamError as e:
            raise LowcamError(f"{self.source}: effect '{self.name}': {e}") from None

    def finish(self, state, frame, footprint):
        """One frame on its own, coded as an I-frame; kept where the graphics reach (``footprint``), the plate's
        own bytes elsewhere."""
        coded = self._code(frame[None])[0]
        return np.where(footprint[..., None], coded, frame), footprint

    def finish_frames(self, frames, footprints):
        """The frames (T, H, W, 3) uint8 coded in order as one sequence, frame 0 an I-frame; kept where the
        graphics reach (``footprints`` (T, H, W)), the plate's own bytes elsewhere."""
        frames = np.asarray(frames)
        coded = self._code(frames)
        return np.where(footprints[..., None], coded, frames), footprints
