"""Video files, read with FFmpeg's own libraries (PyAV): each frame converted with the stream's own colour tags,
frame-accurate by presentation time.

A video frame is coded as Y'CbCr. Turning it into the R'G'B' values Lowcam works on needs four facts the stream
carries in its tags (ITU-T H.273): the matrix (the luma weights Kr, Kb), the range (limited: Y' 16-235, C 16-240
at 8 bits, scaled by 2^(n-8) at n bits; full: 0 to 2^n - 1), the bit depth n, and the transfer function. A
reader that assumes one matrix (OpenCV decodes every clip with BT.601's) shifts the colours of every BT.709 clip
by up to 20 DN. Here the tags decide, and a file whose tags lie is read as ``--plate-colour`` says.

What comes out: 8-bit R'G'B' (DN 0-255), the decoded code values rounded, as a display shows an SDR clip. SDR
clips (transfer BT.709, BT.601, sRGB, BT.2020 10/12-bit, gamma 2.2/2.8, or untagged) are not re-encoded: their
code values are the plate's, as every player and compositor shows them on an sRGB display; the primaries are
not converted (a BT.2020 SDR clip stays in its own primaries). HDR clips (HLG, PQ) are refused in one line naming
the transfer: their code values are not display values, and a tone map is a creative choice Lowcam does not make
for the user (convert the clip to SDR first, or declare it SDR with ``--plate-colour ...,sdr`` to take its code
values as they are).

Untagged streams: the matrix is BT.709 for HD frames (wider than 1024 px or taller than 576 px) and BT.601
otherwise (what players assume); the range is limited, full for FFmpeg's JPEG formats (``yuvj*``, MJPEG); the
transfer is SDR. Streams that are already RGB (Cinepak, PNG-in-MOV) need no matrix.

Seeking: when a clip is opened its packets are listed (no decoding) and their presentation times sorted: frame i
is the i-th presentation time. Reading frame i seeks to the key frame before that time and decodes forward to the
frame whose time is exactly it, so long groups of pictures with B-frames give every frame its own picture on
every worker. Reading frames in order decodes without seeking.

Contents
--------
- :data:`VIDEO_SUFFIXES`: file suffixes read as video
- :func:`is_video`: whether a path names a video file (by its suffix)
- :data:`MATRICES`: the Y'CbCr matrices, name -> (Kr, Kb)
- :class:`PlateColour`: a clip's matrix, range and transfer
- :func:`parse_plate_colour`: the ``--plate-colour`` option's text -> the fields it sets
- :func:`ycbcr_matrix`: the affine map from Y'CbCr code values to R'G'B' in [0, 1] (ITU-T H.273)
- :func:`ycbcr_to_rgb`: Y'CbCr code values -> R'G'B' in [0, 1]
- :class:`VideoReader`: one open video: frame ``i`` as uint8 RGB, in order or by seeking
- :func:`to_rgb`: one decoded frame -> uint8 RGB with a clip's :class:`PlateColour`
- :func:`open_video`: the :class:`VideoReader` of a file, kept open per process
- :func:`read_video_frame`: frame ``index`` of a video file, the file kept open per process
- :func:`close_videos`: close the videos :func:`read_video_frame` keeps open
- :func:`av_log_capture`: FFmpeg's warnings and errors while a block runs, kept off the terminal
- :func:`initialised_heap`: memory the C heap hands out while a block runs holds a fixed byte (x264 reproducible)
- :func:`stream_facts`: the codec, profile, GOP structure, frame types and bitrate read from the bitstream
- :data:`VIDEO_OUTPUTS`: the video files a shot can be written as
- :class:`VideoCoding`: how a shot is coded (encoder, bit depth, colour tags, GOP, B-frames, rate)
- :func:`coding_of_plate`: the coding of a plate video, read from its bitstream
- :func:`rgb_to_ycbcr`: uint8 R'G'B' -> 4:2:0 Y'CbCr code values (the inverse of :func:`ycbcr_matrix`)
- :func:`write_video`: frames coded into a video file, tagged, written atomically
- :func:`write_shot_video`: a shot's frame files coded as its plate video was (``batch -o shot.mp4``, the
  add-on's Video Output)

References
----------
- ITU-T H.273 (2021), Coding-independent code points for video signal type identification, eq. 23-41.
- ITU-R BT.601-7, BT.709-6, BT.2020-2 (the matrices), BT.2100-2 (HLG, PQ).
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import re
import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from .errors import LowcamError
from .io import read_image
from .outputs import atomic_write_with, remove_stale_temporaries

VIDEO_SUFFIXES = frozenset({".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv", ".3gp",
                            ".mts", ".m2ts", ".ts"})


def is_video(path) -> bool:
    """Whether ``path`` names a video file, by its suffix (:data:`VIDEO_SUFFIXES`)."""
    return bool(path) and Path(str(path)).suffix.lower() in VIDEO_SUFFIXES


#: Luma weights (Kr, Kb) of each matrix; Kg = 1 - Kr - Kb (BT.601-7 sec. 2.5.1, BT.709-6 item 3.2, BT.2020-2
#: table 4, non-constant luminance).
MATRICES = {"bt601": (0.299, 0.114), "bt709": (0.2126, 0.0722), "bt2020": (0.2627, 0.0593)}
RANGES = ("limited", "full")
TRANSFERS = ("sdr", "hlg", "pq")

#: H.273 MatrixCoefficients code points -> matrix (1 BT.709, 5 BT.470BG, 6 SMPTE 170M, 9 BT.2020 NCL); 2 is
#: "unspecified", 0 is RGB (identity); the others (FCC, SMPTE 240M, YCgCo, BT.2020 CL, ICtCp, ...) are refused.
_MATRIX_TAGS = {1: "bt709", 5: "bt601", 6: "bt601", 9: "bt2020"}
#: H.273 TransferCharacteristics code points -> transfer; 2 is "unspecified".
_TRANSFER_TAGS = {1: "sdr", 4: "sdr", 5: "sdr", 6: "sdr", 13: "sdr", 14: "sdr", 15: "sdr", 16: "pq", 18: "hlg"}
_TRANSFER_NAMES = {16: "PQ (SMPTE ST 2084)", 18: "HLG (ARIB STD-B67)"}


@dataclass(frozen=True)
class PlateColour:
    """How a clip's Y'CbCr becomes R'G'B': ``matrix`` (a key of :data:`MATRICES`), ``range`` (``limited`` or
    ``full``), ``transfer`` (``sdr``, ``hlg`` or ``pq``); ``source`` says where each came from."""

    matrix: str
    range: str
    transfer: str
    source: str = "the stream's tags"

    def __str__(self) -> str:
        return f"{self.matrix},{self.range},{self.transfer}"


def parse_plate_colour(text: str | None) -> dict:
    """``--plate-colour`` text -> the fields it sets, e.g. ``"bt709,limited"`` -> ``{"matrix": "bt709", "range":
    "limited"}``: comma-separated words, each a matrix (bt601, bt709, bt2020), a range (limited, full) or a
    transfer (sdr, hlg, pq), in any order; what it leaves out comes from the stream's tags."""
    if not text:
        return {}
    out: dict = {}
    for word in (w.strip().lower() for w in str(text).split(",")):
        field = ("matrix" if word in MATRICES else "range" if word in RANGES else "transfer" if word in TRANSFERS
                 else None)
        if field is None:
            raise LowcamError(f"--plate-colour {text}: '{word}' is none of {', '.join(MATRICES)}, "
                              f"{', '.join(RANGES)}, {', '.join(TRANSFERS)}")
        if field in out:
            raise LowcamError(f"--plate-colour {text}: two values for the {field} ({out[field]}, {word})")
        out[field] = word
    return out


def ycbcr_matrix(matrix: str, bits: int, full: bool) -> np.ndarray:
    """The (3, 4) affine map from Y'CbCr code values (``bits`` per sample) to R'G'B' in [0, 1]: rows R, G, B,
    columns Y, Cb, Cr, offset.

    Limited range (H.273 eq. 23-25 inverted): E'Y = (Y - 16 * 2^(n-8)) / (219 * 2^(n-8)),
    E'C = (C - 128 * 2^(n-8)) / (224 * 2^(n-8)); full range: E'Y = Y / (2^n - 1), E'C = (C - 2^(n-1)) / (2^n - 1).
    Then R' = Y' + 2 (1 - Kr) Cr, B' = Y' + 2 (1 - Kb) Cb, G' = (Y' - Kr R' - Kb B') / (1 - Kr - Kb)."""
    kr, kb = MATRICES[matrix]
    kg = 1 - kr - kb
    scale = 2.0 ** (bits - 8)
    if full:
        top = 2.0 ** bits - 1
        offsets, gains = np.array([0.0, 2.0 ** (bits - 1), 2.0 ** (bits - 1)]), np.full(3, 1 / top)
    else:
        offsets = np.array([16.0, 128.0, 128.0]) * scale
        gains = 1 / (np.array([219.0, 224.0, 224.0]) * scale)
    mix = np.array([[1.0, 0.0, 2 * (1 - kr)],                                  # E'Y, E'Cb, E'Cr -> R'
                    [1.0, -2 * kb * (1 - kb) / kg, -2 * kr * (1 - kr) / kg],     # -> G'
                    [1.0, 2 * (1 - kb), 0.0]])                                  # -> B'
    linear = mix * gains
    return np.column_stack([linear, -linear @ offsets])


def ycbcr_to_rgb(y: np.ndarray, cb: np.ndarray, cr: np.ndarray, bits: int, matrix: str, full: bool) -> np.ndarray:
    """Y'CbCr code values (any integer dtype, ``bits`` per sample, planes of one size) -> R'G'B' float32
    (H, W, 3), not clipped (:func:`ycbcr_matrix`)."""
    m = ycbcr_matrix(matrix, bits, full).astype(np.float32)
    ycc = np.stack([y, cb, cr], axis=-1).astype(np.float32)
    return ycc @ m[:, :3].T + m[:, 3]


def _tag_value(value) -> int:
    return int(getattr(value, "value", value) or 0)


def _resolve_colour(path, stream, override: dict) -> PlateColour:
    """The stream's matrix, range and transfer from its tags (the untagged defaults of the module's text), each
    field ``override`` sets replacing the tag."""
    cc = stream.codec_context
    fmt = cc.format
    rgb = fmt is not None and (fmt.is_rgb or not fmt.name.startswith(("yuv", "nv", "p0", "p2", "y2", "uyvy",
                                                                         "yuyv", "gray")))
    sources = []
    m_tag = _tag_value(cc.colorspace)
    if rgb:   # coded as R'G'B' (Cinepak, PNG, ...): no matrix, no range to undo
        return PlateColour("rgb", "full", "sdr", "the stream is coded as RGB")
    if "matrix" in override:
        matrix = override["matrix"]
        sources.append("matrix from --plate-colour")
    elif m_tag in _MATRIX_TAGS:
        matrix = _MATRIX_TAGS[m_tag]
    elif m_tag == 2:
        matrix = "bt709" if (cc.width > 1024 or cc.height > 576) else "bt601"
    else:
        raise LowcamError(f"{path}: matrix tag {m_tag} ({_enum_name(cc.colorspace)}) is not BT.601, BT.709 or "
                          "BT.2020; declare the matrix with --plate-colour (e.g. --plate-colour bt709,limited)")
    r_tag = _tag_value(cc.color_range)
    if "range" in override:
        rng = override["range"]
        sources.append("range from --plate-colour")
    elif r_tag == 2 or (r_tag == 0 and fmt is not None and fmt.name.startswith("yuvj")):
        rng = "full"
    else:
        rng = "limited"
    t_tag = _tag_value(cc.color_trc)
    if "transfer" in override:
        transfer = override["transfer"]
        sources.append("transfer from --plate-colour")
    elif t_tag in _TRANSFER_TAGS:
        transfer = _TRANSFER_TAGS[t_tag]
    elif t_tag in (0, 2):
        transfer = "sdr"
    else:
        raise LowcamError(f"{path}: transfer tag {t_tag} ({_enum_name(cc.color_trc)}) is not one Lowcam reads "
                          "(SDR, HLG or PQ); declare it with --plate-colour (e.g. --plate-colour bt709,limited,sdr)")
    if transfer in ("hlg", "pq"):
        name = _TRANSFER_NAMES[18 if transfer == "hlg" else 16]
        raise LowcamError(f"{path}: an HDR clip (transfer {name}); Lowcam reads SDR footage only: convert it to "
                          "SDR first, or take its code values as SDR with --plate-colour ...,sdr")
    return PlateColour(matrix, rng, transfer, "; ".join(sources) or "the stream's tags")


def _enum_name(value) -> str:
    return getattr(value, "name", None) or str(value)


@contextlib.contextmanager
def av_log_capture():
    """FFmpeg's warnings and errors while the block runs (every thread's), kept off the terminal: yields a list
    that holds them, one ``"name: message"`` string each, once the block ends."""
    said: list[str] = []
    close_videos()   # the kept readers' decoding threads would call the Python callback too
    level = av.logging.get_level()
    av.logging.set_level(av.logging.WARNING)
    try:
        with av.logging.Capture(local=False) as logs:
            yield said
    finally:
        av.logging.set_level(level)
        said.extend(f"{name}: {message.strip()}" for _, name, message in logs)


_M_PERTURB = -6          # glibc's mallopt parameter: fill what malloc hands out and what free takes back
_PERTURB_BYTE = 0xA5
_HEAP = {"users": 0, "lock": threading.Lock(), "mallopt": None}


def _mallopt():
    if _HEAP["mallopt"] is None:
        try:
            libc = ctypes.CDLL(None)
            _HEAP["mallopt"] = libc.mallopt if hasattr(libc, "gnu_get_libc_version") else False
        except (OSError, AttributeError):
            _HEAP["mallopt"] = False
    return _HEAP["mallopt"]


@contextlib.contextmanager
def initialised_heap():
    """While the block runs (in any thread), the C heap's new blocks hold a fixed byte rather than what was
    freed there before (glibc's ``M_PERTURB``; elsewhere nothing changes).

    x264's lookahead reads memory it has not written: the same frames coded twice in one process came out
    differently 11-25 times in 25 where x265 had run in between (its freed buffers are what x264 was handed
    next), at 96x80 px and, rarely, at 368x304. With the heap initialised x264 codes them the same in every
    process. Blocks nest, across threads: the heap is initialised while any runs. glibc's per-thread cache
    (tcache, blocks up to about 1 KiB) hands such small blocks back as they were freed, and cannot be turned off
    once a process runs (``GLIBC_TUNABLES=glibc.malloc.tcache_count=0`` before it starts does): x264's coding is
    reproducible in the tests without that."""
    mallopt = _mallopt()
    if not mallopt:
        yield
        return
    with _HEAP["lock"]:
        if _HEAP["users"] == 0:
            mallopt(_M_PERTURB, _PERTURB_BYTE)
        _HEAP["users"] += 1
    try:
        yield
    finally:
        with _HEAP["lock"]:
            _HEAP["users"] -= 1
            if _HEAP["users"] == 0:
                mallopt(_M_PERTURB, 0)


def _open(path):
    """The container and its first video stream; one line naming the file for every failure."""
    path = str(path)
    if not Path(path).is_file():
        raise LowcamError(f"{path}: no such file")
    try:
        container = av.open(path, metadata_errors="ignore")
    except (av.FFmpegError, UnicodeDecodeError, ValueError, OSError) as e:
        raise LowcamError(f"{path}: not a video FFmpeg can read ({_first_line(e)})") from None
    if not container.streams.video:
        container.close()
        raise LowcamError(f"{path}: the file holds no video stream")
    stream = container.streams.video[0]
    if stream.codec_context is None or stream.codec_context.width <= 0:
        container.close()
        raise LowcamError(f"{path}: the video stream has no decoder or no frame size")
    return container, stream


def _first_line(e) -> str:
    return (str(e).splitlines() or [type(e).__name__])[0]


class VideoReader:
    """One open video: :meth:`frame` ``(i)`` is frame i (0-based, presentation order) as uint8 RGB (H, W, 3).

    ``colour``: ``--plate-colour`` text (or the dict :func:`parse_plate_colour` makes) overriding the stream's
    tags. Each frame is turned as the stream's display matrix says (a phone's upright video), as players and
    Blender 4.5's Movie Clip show it; ``turned=False``: as coded (Blender 4.2 shows it so). Attributes:
    ``path``, ``count`` (frames), ``fps`` (frames/s, or None), ``colour`` (:class:`PlateColour`), ``width``,
    ``height`` (px, as shown), ``turns`` (quarter turns counter-clockwise applied to each decoded picture),
    ``pict_types`` (``{index: "I"|"P"|"B"}`` of the frames decoded so far)."""

    def __init__(self, path, colour=None, turned: bool = True):
        self.path = str(path)
        override = colour if isinstance(colour, dict) else parse_plate_colour(colour)
        self.container, self.stream = _open(self.path)
        try:
            # FFmpeg's decoding threads call PyAV's Python log callback while one is installed (av_log_capture),
            # which can deadlock against the thread waiting for them: threads only where none is
            self.stream.thread_type = "AUTO" if av.logging.get_level() is None else "NONE"
            self.colour = _resolve_colour(self.path, self.stream, override)
            self.times = self._presentation_times()
            self.turns = self._display_turns() if turned else 0
        except BaseException:
            self.container.close()
            raise
        cc = self.stream.codec_context
        self.width, self.height = (cc.height, cc.width) if self.turns % 2 else (cc.width, cc.height)
        rate = self.stream.average_rate or self.stream.guessed_rate
        self.fps = float(rate) if rate and 0 < float(rate) < 1000 else None
        self.count = len(self.times) if self.times is not None else int(self.stream.frames or 0)
        self.pict_types: dict[int, str] = {}
        self.corrupt: list[int] = []
        self.decode_error: str | None = None   # what the decoder said where it gave up
        self._index = {t: i for i, t in enumerate(self.times)} if self.times is not None else {}
        self._frames = None     # the decoding generator
        self._next = 0          # the index the generator gives next

    def _presentation_times(self):
        """Every frame's presentation time (stream time base), sorted: the packets listed, nothing decoded. None
        where a packet has no time (frames are then counted as they decode, and read by decoding from the
        start)."""
        times = []
        try:
            for packet in self.container.demux(self.stream):
                if packet.size == 0:   # a flush packet, or an AVI's dropped frame: no picture of its own
                    continue
                t = packet.pts if packet.pts is not None else packet.dts
                if t is None:
                    return None
                times.append(int(t))
        except av.FFmpegError as e:
            raise LowcamError(f"{self.path}: the container cannot be read ({_first_line(e)})") from None
        finally:
            self.container.seek(0)
        if not times:
            raise LowcamError(f"{self.path}: the video stream holds no frames")
        times.sort()
        return None if len(set(times)) != len(times) else times

    def _display_turns(self) -> int:
        """Quarter turns counter-clockwise that the stream's display matrix asks of each decoded picture (a phone
        held upright records its sensor's landscape frames and says so there), read off the first frame: 0 where
        it has none or cannot be decoded (the frame's read then says why)."""
        try:
            degrees = float(next(self.container.decode(self.stream)).rotation or 0.0)
        except (av.FFmpegError, StopIteration):
            return 0
        finally:
            self.container.seek(0)
        turns = round(degrees / 90.0)
        if abs(degrees - 90.0 * turns) > 1.0:
            raise LowcamError(f"{self.path}: its display matrix turns the picture by {degrees:g} degrees; Lowcam "
                              "reads turns of 0, 90, 180 and 270 degrees only")
        return turns % 4

    def close(self) -> None:
        self._frames = None
        self.container.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _decode(self):
        try:
            for frame in self.container.decode(self.stream):
                yield frame
        except av.FFmpegError as e:
            self.decode_error = _first_line(e)
            raise LowcamError(f"{self.path}: the video cannot be decoded ({self.decode_error})") from None

    def _start(self, index: int) -> None:
        """Position the decoder so that its next frame is ``index``: seek by presentation time to the key frame
        at or before it (from the start where the stream has no times)."""
        if self.times is None or index == 0:
            self.container.seek(0)
            self._frames, self._next = self._decode(), 0
            return
        self.container.seek(self.times[index], stream=self.stream, backward=True, any_frame=False)
        self._frames, self._next = self._decode(), None   # where it landed: told by the first frame's time

    def _converted(self, frame) -> np.ndarray:
        rgb = to_rgb(frame, self.colour, self.path)
        return np.ascontiguousarray(np.rot90(rgb, self.turns)) if self.turns else rgb

    def frame(self, index: int) -> np.ndarray:
        """Frame ``index`` (0-based, presentation order) as uint8 RGB (H, W, 3)."""
        if index < 0 or (self.count and index >= self.count):
            raise LowcamError(f"{self.path}: the video has {self.count} frames, frame {index} (0-based) does not "
                              "exist")
        if self._frames is None or self._next is None or index < self._next or (
                self.times is not None and index > self._next + 2 * _GOP_GUESS):
            self._start(index)
        target = None if self.times is None else self.times[index]
        for i, frame in self._decoded():
            if i == index:
                return self._converted(frame)
            if target is not None and frame.pts is not None and frame.pts > target:
                break
        self._frames = None
        raise LowcamError(f"{self.path}: frame {index} (0-based) cannot be decoded")

    def _decoded(self):
        """The decoding generator's frames, each (index, frame), noted as they come."""
        for frame in self._frames:
            i = self._frame_index(frame)
            if i is None:
                continue
            self._next = i + 1
            self._note(i, frame)
            yield i, frame

    def _frame_index(self, frame):
        if self.times is None:
            return self._next
        return self._index.get(frame.pts if frame.pts is not None else frame.dts)

    def _note(self, i: int, frame) -> None:
        kind = _PICT_TYPES.get(_tag_value(frame.pict_type))
        self.pict_types[i] = kind or ("I" if frame.key_frame else "?")   # codecs that state no type: key frames
        if frame.is_corrupt:
            self.corrupt.append(i)

    def note_frame_types(self, max_frames: int, limit: int) -> None:
        """Decode the first ``max_frames`` frames, without converting them, so that :attr:`pict_types` holds their
        types (the GOP structure :func:`stream_facts` reads); on, up to ``limit`` frames, until a second key frame
        shows (a long GOP)."""
        self._start(0)
        keys = 0
        for i, _ in self._decoded():
            keys += self.pict_types.get(i) == "I"
            if self._next >= limit or (self._next >= max_frames and keys >= 2):
                break
        self._frames = None

    def frames(self, max_frames: int | None = None):
        """Frames in order from the first, each (index, uint8 RGB), at most ``max_frames``."""
        self._start(0)
        for i, frame in self._decoded():
            yield i, self._converted(frame)
            if max_frames is not None and self._next >= max_frames:
                return


#: Frames decoded forward rather than seeking: about a short group of pictures.
_GOP_GUESS = 12
#: AVPictureType -> letter.
_PICT_TYPES = {1: "I", 2: "P", 3: "B", 4: "S", 5: "SI", 6: "SP", 7: "BI"}


def _planes(frame, fmt_name: str):
    """(Y, Cb, Cr) planes of a planar Y'CbCr frame, each (h, w) at its own resolution, and the bit depth."""
    fmt = frame.format
    bits = fmt.components[0].bits
    dtype = np.dtype("<u2") if bits > 8 else np.dtype(np.uint8)
    out = []
    for plane in frame.planes[:3]:
        a = np.frombuffer(plane, dtype)
        out.append(a.reshape(plane.height, plane.line_size // dtype.itemsize)[:, :plane.width])
    return out, bits


_DIRECT = re.compile(r"yuvj?4[24][024]p(9|10|12|14|16)?(le)?$")


def to_rgb(frame, colour: PlateColour, path: str = "video") -> np.ndarray:
    """A decoded PyAV frame -> uint8 RGB (H, W, 3) with ``colour``'s matrix and range (:func:`ycbcr_to_rgb`);
    each chroma sample repeated over the luma samples it covers (4:2:0: 2x2), as FFmpeg's own conversion and
    Blender's Movie Clip do. RGB frames are repacked, no matrix."""
    name = frame.format.name
    if frame.format.is_rgb or name.startswith(("pal8", "gbr", "rgb", "bgr", "argb", "abgr", "rgba", "bgra")):
        return frame.to_ndarray(format="rgb24")
    if name.startswith("gray"):
        frame = frame.reformat(format="yuv444p16le" if frame.format.components[0].bits > 8 else "yuv444p")
    elif not _DIRECT.match(name):   # packed or semi-planar Y'CbCr (nv12, p010, yuyv422, ...): planar first
        deep = frame.format.components[0].bits > 8
        frame = frame.reformat(format="yuv444p16le" if deep else "yuv444p")
    (y, cb, cr), bits = _planes(frame, name)
    h, w = y.shape
    if cb.shape != y.shape:   # each chroma sample over the luma samples it was taken from
        fy, fx = -(-h // cb.shape[0]), -(-w // cb.shape[1])
        cb = cv2.resize(cb, None, fx=fx, fy=fy, interpolation=cv2.INTER_NEAREST)[:h, :w]
        cr = cv2.resize(cr, None, fx=fx, fy=fy, interpolation=cv2.INTER_NEAREST)[:h, :w]
    # one affine map per pixel, rounded and saturated to 0-255 by OpenCV (the same map as ycbcr_to_rgb)
    m = 255.0 * ycbcr_matrix(colour.matrix, bits, colour.range == "full")
    rgb = cv2.transform(cv2.merge([y, cb, cr]), m)
    return rgb if rgb.dtype == np.uint8 else np.minimum(rgb, 255).astype(np.uint8)


#: Open videos, (real path, mtime ns, size, colour override) -> :class:`VideoReader`: a shot's video is opened
#: once per process, not once per frame; a file changed on disk is opened afresh. At most
#: :data:`OPEN_VIDEOS_MAX` stay open.
_OPEN_VIDEOS: dict = {}
OPEN_VIDEOS_MAX = 2


def open_video(path, colour: str | None = None, turned: bool = True) -> VideoReader:
    """The :class:`VideoReader` of ``path`` kept open in this process (a new one if the file changed)."""
    path = str(path)
    if not Path(path).is_file():
        raise LowcamError(f"{path}: no such file")
    st = os.stat(path)
    key = (os.path.realpath(path), st.st_mtime_ns, st.st_size, colour or "", turned)
    video = _OPEN_VIDEOS.pop(key, None)
    if video is None:
        video = VideoReader(path, colour, turned)
        while len(_OPEN_VIDEOS) >= OPEN_VIDEOS_MAX:                 # the least recently used goes
            _OPEN_VIDEOS.pop(next(iter(_OPEN_VIDEOS))).close()
    _OPEN_VIDEOS[key] = video                                       # most recently used last
    return video


def close_videos() -> None:
    """Close every video :func:`read_video_frame` keeps open."""
    while _OPEN_VIDEOS:
        _OPEN_VIDEOS.popitem()[1].close()


def read_video_frame(path, index: int, colour: str | None = None, turned: bool = True) -> np.ndarray:
    """Frame ``index`` (0-based) of a video file as uint8 RGB, converted with the stream's tags (``colour``:
    ``--plate-colour`` text overriding them), turned as its display matrix says unless ``turned`` is False. The
    file is opened once per process and kept open (keyed by path, modification time, size, ``colour`` and
    ``turned``), so a shot's frames are read in sequence without reopening."""
    return open_video(path, colour, turned).frame(index)


def stream_facts(video: VideoReader) -> dict:
    """What the bitstream says of how the clip was coded: codec, profile, pixel format, bit depth, colour, GOP
    structure (key-frame interval, B-frames) and frame types of the frames decoded so far, bitrate (from the
    packets' sizes over the clip's duration) and the encoder's own rate control where it wrote it (x264's and
    x265's settings in their SEI message: crf, qp, bitrate)."""
    s, cc = video.stream, video.stream.codec_context
    types = [video.pict_types[i] for i in sorted(video.pict_types)]
    keys = [i for i in sorted(video.pict_types) if video.pict_types[i] == "I"]
    facts = {"codec": cc.name, "codec_profile": s.profile or "none",
             "pixel_format": cc.format.name if cc.format else "unknown",
             "bit_depth": int(cc.format.components[0].bits) if cc.format else 8, "colour": str(video.colour),
             "colour_from": video.colour.source, "frames": video.count}
    if video.turns:
        facts["display_turned_deg"] = 90 * video.turns   # counter-clockwise, as the display matrix asks
    if video.fps:
        facts["fps"] = round(video.fps, 6)
    pattern = "".join(types)
    if keys:
        nxt = keys[1] if len(keys) > 1 else len(types)
        facts["gop_frame_types"] = pattern[keys[0]:nxt][:120]     # the first group of pictures, in display order
    if len(keys) >= 2:
        facts["gop_length"] = int(np.median(np.diff(keys)))
    facts["key_frames"] = len(keys)
    facts["b_frames"] = "B" in types
    facts["max_consecutive_b_frames"] = max((len(m.group()) for m in re.finditer("B+", pattern)), default=0)
    facts["frame_types"] = ", ".join(f"{t} {types.count(t)}" for t in sorted(set(types)))
    size, first, last, settings = 0, None, None, ""
    container = av.open(video.path, metadata_errors="ignore")
    try:
        stream = container.streams.video[0]
        for k, packet in enumerate(container.demux(stream)):
            if packet.size == 0:
                continue
            size += packet.size
            if packet.pts is not None:
                first = packet.pts if first is None else min(first, packet.pts)
                last = packet.pts if last is None else max(last, packet.pts)
            if k < 2 and not settings:
                settings = _encoder_settings(bytes(packet))
        if not settings and stream.codec_context.extradata:
            settings = _encoder_settings(bytes(stream.codec_context.extradata))
        tb = stream.time_base
    finally:
        container.close()
    if first is not None and last is not None and tb and last > first and video.fps:
        duration = float((last - first) * Fraction(tb)) + 1 / video.fps
        facts["bitrate_bps"] = round(8 * size / duration)
    if settings:
        facts["encoder"] = settings.split(" - ")[0].strip()[:80]
        for key in ("rc", "crf", "qp", "bitrate", "keyint", "bframes"):
            m = re.search(rf"(?:^|\s){key}=([^\s:]+)", settings)
            if m:
                facts[f"encoder_{key}"] = m.group(1)
    return facts


def _encoder_settings(data: bytes) -> str:
    """x264's or x265's settings line, which they write into an SEI message of the first access unit."""
    m = re.search(rb"(x26[45] \(build|x264 - core|x265 \(build)[\x20-\x7e]{0,4000}", data)
    return m.group().decode("ascii", "replace") if m else ""


# --- writing a shot as a video --------------------------------------------------------------------------------------

#: The video files ``lowcam batch -o`` writes: suffix -> FFmpeg's container.
VIDEO_OUTPUTS = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}
#: The decoder's name -> the encoder that codes a shot as that camera did (others: libx264).
_ENCODERS = {"h264": "libx264", "hevc": "libx265"}
_MATRIX_CODE = {"bt601": 6, "bt709": 1, "bt2020": 9}


@dataclass(frozen=True)
class VideoCoding:
    """How a shot is coded: ``encoder`` (libx264, libx265), ``pixel_format`` (yuv420p, yuv420p10le), the colour
    tags (``matrix``, ``range``; ``transfer_tag``, ``primaries_tag``: H.273 code points), ``gop`` (frames from
    one key frame to the next), ``b_frames`` (at most in a row), the rate (``crf``, else ``bitrate_bps``),
    ``fps`` and ``source`` (where these came from)."""

    encoder: str = "libx264"
    pixel_format: str = "yuv420p"
    matrix: str = "bt709"
    range: str = "limited"
    transfer_tag: int = 1
    primaries_tag: int = 1
    gop: int = 48
    b_frames: int = 2
    crf: float | None = 18.0
    bitrate_bps: int | None = None
    fps: float = 24.0
    source: str = "Lowcam's default (H.264, CRF 18, BT.709 limited range)"


#: The frames of a plate video whose types give the GOP structure a shot's video is coded with, and how far the
#: decoding goes on to find a second key frame.
CODING_FRAMES, CODING_FRAMES_MAX = 250, 1000


def _whole(text) -> int | None:
    """A positive whole number written in an encoder's settings, else None."""
    return int(text) if isinstance(text, str) and text.isdigit() and int(text) > 0 else None


def coding_of_plate(path, colour: str | None = None, fps: float | None = None) -> VideoCoding:
    """The coding of the plate video ``path`` (``colour``: ``--plate-colour``): its codec (H.264, HEVC; others
    coded as H.264), bit depth, colour tags, GOP length, B-frames and rate (x264's or x265's CRF where the stream
    states it, else its bitrate), as :func:`stream_facts` reads them from its first :data:`CODING_FRAMES` frames,
    or more until a second key frame (decoded here: the same whatever frames a run read before). A GOP that no two
    key frames show is the encoder's own ``keyint`` where the stream states it, else two seconds."""
    with VideoReader(path, colour) as video:
        video.note_frame_types(CODING_FRAMES, CODING_FRAMES_MAX)
        facts = stream_facts(video)
        cc = video.stream.codec_context
        rgb = video.colour.matrix not in MATRICES
        crf = facts.get("encoder_crf")
        try:
            crf = float(crf) if crf is not None and facts.get("encoder_rc") == "crf" else None
        except ValueError:
            crf = None
        return VideoCoding(
            encoder=_ENCODERS.get(facts["codec"], "libx264"),
            pixel_format="yuv420p10le" if facts["bit_depth"] > 8 else "yuv420p",
            matrix="bt709" if rgb else video.colour.matrix, range="limited" if rgb else video.colour.range,
            transfer_tag=_tag_value(cc.color_trc) or 1, primaries_tag=_tag_value(cc.color_primaries) or 1,
            gop=int(facts.get("gop_length") or _whole(facts.get("encoder_keyint"))
                    or max(1, round(2 * (video.fps or 24)))),
            b_frames=int(facts["max_consecutive_b_frames"]), crf=crf,
            bitrate_bps=None if crf is not None else facts.get("bitrate_bps"),
            fps=float(fps or video.fps or 24.0), source=f"the plate {video.path} ({facts['codec']})")


def rgb_to_ycbcr(rgb: np.ndarray, bits: int, matrix: str, full: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """uint8 R'G'B' (H, W, 3), H and W even -> 4:2:0 Y'CbCr code values (Y (H, W), Cb and Cr (H/2, W/2), uint8 or
    uint16 for ``bits`` > 8): the inverse of :func:`ycbcr_matrix`, chroma averaged over each 2x2 block."""
    m = ycbcr_matrix(matrix, bits, full)
    inverse = np.linalg.inv(m[:, :3])
    forward = np.column_stack([inverse / 255.0, -inverse @ m[:, 3]])   # R'G'B' DN -> code values
    ycc = cv2.transform(rgb.astype(np.float32), forward.astype(np.float32))
    h, w = rgb.shape[:2]
    chroma = cv2.resize(ycc[..., 1:], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    top = 2 ** bits - 1
    dtype = np.uint8 if bits == 8 else np.dtype("<u2")
    planes = (ycc[..., 0], chroma[..., 0], chroma[..., 1])
    return tuple(np.clip(np.rint(p), 0, top).astype(dtype) for p in planes)


def write_video(path, frames, coding: VideoCoding) -> Path:
    """Code ``frames`` (an iterable of uint8 RGB (H, W, 3), H and W even) into the video file ``path``
    (:data:`VIDEO_OUTPUTS`) as ``coding`` says, tagged with its matrix, range, transfer and primaries; written
    through a temporary file and renamed into place (nothing is left at ``path`` on failure)."""
    path = Path(path)
    container_format = VIDEO_OUTPUTS.get(path.suffix.lower())
    if container_format is None:
        raise LowcamError(f"{path}: unknown video format '{path.suffix}' (write {', '.join(VIDEO_OUTPUTS)})")
    bits = 10 if "10" in coding.pixel_format else 8
    full = coding.range == "full"

    def write(tmp):
        with av.open(str(tmp), "w", format=container_format) as out:
            stream = None
            for i, rgb in enumerate(frames):
                h, w = rgb.shape[:2]
                if stream is None:
                    if h % 2 or w % 2:
                        raise LowcamError(f"{path}: frames of {w}x{h} px; 4:2:0 video needs an even width and "
                                          "height")
                    stream = _video_stream(out, coding, w, h)
                frame = av.VideoFrame(w, h, coding.pixel_format)
                for plane, data in zip(frame.planes, rgb_to_ycbcr(rgb, bits, coding.matrix, full)):
                    buf = np.zeros((plane.height, plane.line_size // data.itemsize), data.dtype)
                    buf[:, :data.shape[1]] = data
                    plane.update(buf.tobytes())
                frame.pts = i
                frame.colorspace, frame.color_range = _MATRIX_CODE[coding.matrix], 2 if full else 1
                for packet in stream.encode(frame):
                    out.mux(packet)
            if stream is None:
                raise LowcamError(f"{path}: no frames to write")
            for packet in stream.encode():
                out.mux(packet)

    try:
        with initialised_heap():
            return atomic_write_with(path, write)
    except av.FFmpegError as e:
        raise LowcamError(f"{path}: the encoder {coding.encoder} refused ({_first_line(e)})") from None


def write_shot_video(path, frame_files, fps: float | None = None, plate=None, plate_colour: str | None = None) -> str:
    """A shot's frames (image files, in frame order) coded into the video ``path`` as the ``plate`` video was coded
    (:func:`coding_of_plate`: its codec, bit depth, colour tags, GOP, B-frames and rate), else as
    :class:`VideoCoding`'s default at ``fps`` (24 when None). Returns one line saying how it was coded. Used by
    ``lowcam batch -o shot.mp4`` and the add-on's Video Output."""
    if plate is not None and is_video(plate):
        coding = coding_of_plate(plate, plate_colour, fps)
    else:
        coding = VideoCoding(fps=fps or 24.0)
    frame_files = list(frame_files)
    remove_stale_temporaries(Path(path).parent)   # a killed run's, left beside the video
    t = time.perf_counter()

    def rgb(file):
        img = read_image(file)
        return np.dstack([img] * 3) if img.ndim == 2 else img[..., :3]

    write_video(path, (rgb(f) for f in frame_files), coding)
    rate = f"CRF {coding.crf:g}" if coding.crf is not None else f"{coding.bitrate_bps} bit/s"
    return (f"{path}: {len(frame_files)} frames coded by {coding.encoder} ({rate}, GOP {coding.gop}, "
            f"{coding.b_frames} B-frames, {coding.matrix} {coding.range}) as {coding.source} in "
            f"{time.perf_counter() - t:.1f} s")


def _video_stream(out, coding: VideoCoding, width: int, height: int):
    stream = out.add_stream(coding.encoder, rate=Fraction(coding.fps).limit_denominator(1001))
    stream.width, stream.height, stream.pix_fmt = width, height, coding.pixel_format
    cc = stream.codec_context
    cc.colorspace, cc.color_range = _MATRIX_CODE[coding.matrix], 2 if coding.range == "full" else 1
    cc.color_trc, cc.color_primaries = coding.transfer_tag, coding.primaries_tag
    gop = f"keyint={coding.gop}:min-keyint={coding.gop}:scenecut=0:bframes={coding.b_frames}"
    options = {}
    if coding.crf is not None:
        options["crf"] = f"{coding.crf:g}"
    else:
        stream.bit_rate = int(coding.bitrate_bps)
    if coding.encoder == "libx265":
        options["x265-params"] = gop + ":log-level=error"
    else:
        options["x264-params"] = gop
    stream.options = options
    return stream
