"""Uncompressed scan-line OpenEXR files read straight from their bytes: a part is read when one of its channels is
first taken and each channel is a strided view of those bytes, so reading a render costs only the parts a caller
takes (a shot takes the Combined and Vector passes and leaves the overlay layer unread), and no library decodes
anything.

The layout read here is OpenEXR's own ("OpenEXR File Layout", openexr.com): the magic number and version field;
the header (a multi-part file: one per part, and an empty one after them), a list of attributes each written as
its name and type (null-terminated), its size (int32) and its value, ended by a null byte; one offset table per
part (a uint64 file offset per chunk, in increasing y); then the chunks: a multi-part file's begin with the part's
number (int32), then the line's y (int32), the data size (int32) and, uncompressed (one line a chunk), the line's
channels one after another in the header's order, ``width`` little-endian samples each (UINT 4 bytes, HALF 2,
FLOAT 4).

Only the common case is read: every part scan-line and uncompressed, no subsampled channel, the chunks of a part
evenly spaced in increasing y (as the OpenEXR library and Blender write them) and all within the file. For
anything else :func:`read_uncompressed_exr` returns None and the caller reads the file with the OpenEXR library,
which gives the same channels grouped the same way (:func:`group_names`) and its own refusals (a truncated or
damaged file, a group of mixed pixel types). The file is read, not mapped into memory: a render cut short or
replaced by another process while it is read (a frame rendered again) is a one-line error, where a mapping would
end the process.

Contents
--------
- :func:`read_uncompressed_exr`: the parts' channels (read when taken) and the first part's colour tags, or None
- :func:`group_names`: channel names grouped as the OpenEXR Python binding groups them (``RGBA``, ``layer.pass``)
- :class:`LazyChannels`: a part's channels by the binding's names, its bytes read from the file when one is taken,
  or a float32 layer read strip by strip into an array (:meth:`LazyChannels.read_in_strips`)
"""
from __future__ import annotations

import os
import struct
import threading
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np

from .errors import LowcamError
from .parallel import thread_map

_MAGIC = 20000630
_TILED, _DEEP, _MULTIPART = 0x200, 0x800, 0x1000
#: OpenEXR pixel types: UINT, HALF, FLOAT.
_PIXEL_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
#: The colour channels the binding groups into one (H, W, 3 or 4) array, in its order.
_GROUPED = ("R", "G", "B", "A")
#: The first bytes read for the headers and offset tables (more when they are longer).
_HEAD_BYTES = 1 << 20
#: About how many bytes of a part :meth:`LazyChannels.read_in_strips` reads at a time: a strip stays in cache
#: while it is interleaved and looked at.
_STRIP_BYTES = 4 << 20
_strip_buffers = threading.local()    # each thread's buffer for a strip's bytes, kept from call to call


class _Unread(Exception):
    """The file is not the common case read here: the OpenEXR library reads it instead."""


class _Short(Exception):
    """The headers and offset tables go on past the bytes read so far."""


def _string(buffer: bytes, at: int) -> tuple[str, int]:
    end = buffer.find(b"\0", at)
    if end < 0:
        raise _Short
    return buffer[at:end].decode("utf-8", "replace"), end + 1


def _channel_list(value: bytes) -> list[tuple[str, np.dtype]]:
    """A ``chlist`` attribute: (name, dtype) per channel; a subsampled channel or an unknown type is not read."""
    channels, at = [], 0
    while at < len(value) and value[at] != 0:
        try:
            name, at = _string(value, at)
        except _Short:                  # within one attribute: a damaged list
            raise _Unread from None
        pixel_type, _linear, x_sampling, y_sampling = struct.unpack_from("<iB3xii", value, at)
        at += 16
        if pixel_type not in _PIXEL_TYPES or (x_sampling, y_sampling) != (1, 1):
            raise _Unread
        channels.append((name, _PIXEL_TYPES[pixel_type]))
    return channels


def _headers(buffer: bytes, multipart: bool) -> tuple[list[dict], int]:
    """The parts' headers ({attribute name: (type, raw value)}) and where the offset tables begin."""
    headers, at = [], 8
    while True:
        header: dict = {}
        while _byte(buffer, at) != 0:
            name, at = _string(buffer, at)
            kind, at = _string(buffer, at)
            (size,) = struct.unpack_from("<i", _within(buffer, at + 4), at)
            at += 4
            if size < 0:
                raise _Unread
            header[name] = (kind, _within(buffer, at + size)[at:at + size])
            at += size
        at += 1
        headers.append(header)
        if not multipart or _byte(buffer, at) == 0:
            return headers, at + (1 if multipart else 0)


def _within(buffer: bytes, end: int) -> bytes:
    if end > len(buffer):
        raise _Short
    return buffer


def _byte(buffer: bytes, at: int) -> int:
    return _within(buffer, at + 1)[at]


def group_names(names: list[str]) -> list[tuple[str, list[str]]]:
    """(key, channel names) in the order the OpenEXR Python binding gives a part's channels: ``R``, ``G``, ``B``
    (and ``A``) of one prefix become one entry, keyed ``RGB``/``RGBA`` without a prefix and by the prefix
    (``ViewLayer.Combined``) with one, placed where its first channel comes in ``names`` (the header's
    alphabetical order); every other channel is its own entry."""
    members: dict[str, dict[str, str]] = {}
    for name in names:
        prefix, _, last = name.rpartition(".")
        if last in _GROUPED:
            members.setdefault(prefix, {})[last] = name
    groups = {prefix: [found[c] for c in _GROUPED if c in found] for prefix, found in members.items()
              if all(c in found for c in "RGB")}
    out, placed = [], set()
    for name in names:
        prefix, _, last = name.rpartition(".")
        if prefix in groups and last in _GROUPED:
            if prefix not in placed:
                placed.add(prefix)
                key = prefix or "".join(_GROUPED[:len(groups[prefix])])
                out.append((key, groups[prefix]))
        else:
            out.append((name, [name]))
    return out


class LazyChannels(Mapping):
    """A part's channels by the binding's names (:func:`group_names`): the part's bytes are read from the file
    when one of them is first taken, and each channel taken is its own array (H, W) or (H, W, C) of the file's
    pixel type, as the OpenEXR binding gives it, passed through ``convert``. ``layout``: the part's place in the
    file, (its first chunk's offset, the chunks' stride, their count, the lead before each line's channels, the
    width, a line's bytes) and each channel's (dtype, offset in a line); ``identity``: the file's (device, inode, size, modification time),
    which must not change before the part is read. The part's bytes are kept until every entry is taken."""

    def __init__(self, path: Path, identity: tuple, layout: tuple, channels: dict, groups: list, convert=None):
        self._path, self._identity, self._layout, self._channels = path, identity, layout, channels
        self._groups = dict(groups)
        self._convert = convert or (lambda pixels: pixels)
        self._taken: dict[str, np.ndarray] = {}
        self._data: np.ndarray | None = None          # the part's bytes, once read
        self._lock = threading.Lock()                 # one read of the part, whichever thread takes first

    def _read_part(self) -> np.ndarray:
        """The part's bytes, from its first chunk to the end of its last, checked whole."""
        first, stride, count, lead, _, line = self._layout
        data = np.empty(stride * (count - 1) + lead + line, np.uint8)
        self._read_at(data, first)
        return data

    def _read_at(self, buffer: np.ndarray, offset: int) -> None:
        """Fill ``buffer`` (bytes) from the file at ``offset``; a file that is not the one whose headers were read,
        or ends early, is refused in one line. Each call opens the file itself, so threads read side by side."""
        again = "(rendered again?); read it again once it is written"
        try:
            with open(self._path, "rb", buffering=0) as f:
                if _identity(f) != self._identity:
                    raise LowcamError(f"{self._path}: the file changed while it was read {again}")
                f.seek(offset)
                view, done = memoryview(buffer), 0
                while done < len(view):           # one call reads at most about 2 GB
                    got = f.readinto(view[done:])
                    if not got:
                        raise LowcamError(f"{self._path}: the file was cut short while it was read {again}")
                    done += got
        except OSError as e:
            raise LowcamError(f"{self._path}: cannot read it any more ({e.strerror or e}) {again}") from None

    def _mergeable(self, names) -> bool:
        """Whether ``cv2.merge`` takes these channels' views: a type it holds (not UINT) and every sample on its
        type's grid in every line."""
        dtype = self._channels[names[0]][0]
        _, stride, _, lead, _, _ = self._layout
        return dtype != np.uint32 and not stride % dtype.itemsize and \
            not any((lead + self._channels[n][1]) % dtype.itemsize for n in names)

    def read_in_strips(self, key: str, depth: int, visit, allocate=np.empty) -> tuple[np.ndarray, list] | None:
        """Entry ``key``, a group of ``depth`` float32 channels, read into an array ``allocate((H, W, depth),
        float32)`` a strip of lines at a time (about :data:`_STRIP_BYTES`, the strips shared out among the engine's
        threads), so the part never lies in memory whole and each strip is looked at while it is in cache: a strip
        whose channels are all zero bytes is zeroed, any other is interleaved and ``visit(first line, its lines)``
        called on it. Returns (the array, the visits' results other than None, in order), the array's bits those
        ``self[key]`` gives; None where the entry is no such group or its lines are not aligned for float32
        (``self[key]`` reads it)."""
        names = self._groups.get(key, ())
        if len(names) != depth:
            return None
        if any(self._channels[n][0] != np.float32 for n in names) or not self._mergeable(names):
            return None
        first, stride, count, lead, width, _ = self._layout
        starts = [lead + self._channels[n][1] for n in names]
        out = allocate((count, width, depth), np.float32)
        rows = max(1, _STRIP_BYTES // stride)
        end = max(starts) + 4 * width                     # a strip's bytes end there in its last line

        def strip(top: int):
            n = min(rows, count - top)
            try:
                buffer = getattr(_strip_buffers, "bytes", None)
                if buffer is None or buffer.nbytes < rows * stride:
                    buffer = _strip_buffers.bytes = np.empty(rows * stride, np.uint8)
                self._read_at(buffer[:(n - 1) * stride + end], first + top * stride)
                planes = [np.ndarray((n, width), np.float32, buffer, start, (stride, 4)) for start in starts]
                lines = out[top:top + n]
                if not any(cv2.countNonZero(plane.view(np.int32)) for plane in planes):  # -0.0: not zero bytes
                    lines.fill(0)
                    return None
                cv2.merge(planes, lines)
                return visit(top, lines)
            except Exception as e:      # raised once every strip is done: none writes into an array given up
                return e

        found = thread_map(strip, range(0, count, rows))
        for result in found:
            if isinstance(result, Exception):
                raise result
        return out, [result for result in found if result is not None]

    def __getitem__(self, key: str) -> np.ndarray:
        with self._lock:
            if key not in self._taken:
                names = self._groups[key]               # KeyError for a channel the part does not hold
                if self._data is None:
                    self._data = self._read_part()
                _, stride, count, lead, width, _ = self._layout
                views = [np.ndarray((count, width), self._channels[n][0], self._data, lead + self._channels[n][1],
                                    (stride, self._channels[n][0].itemsize)) for n in names]
                if len(views) == 1:
                    pixels = np.array(views[0])
                elif not self._mergeable(names):
                    pixels = np.stack(views, -1)        # a type or a line alignment OpenCV does not take
                else:
                    pixels = cv2.merge(views)           # interleaved, about 2.5x np.stack's speed
                self._taken[key] = self._convert(pixels)
                if len(self._taken) == len(self._groups):
                    self._data = None                   # every entry is its own array now
            return self._taken[key]

    def __contains__(self, key) -> bool:
        return key in self._groups                      # without reading anything

    def __iter__(self):
        return iter(self._groups)

    def __len__(self) -> int:
        return len(self._groups)


def _identity(f) -> tuple:
    st = os.fstat(f.fileno())
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _colour_tags(header: dict) -> dict:
    tags = {}
    if header.get("chromaticities", ("",))[0] == "chromaticities" and len(header["chromaticities"][1]) == 32:
        tags["chromaticities"] = [float(v) for v in struct.unpack("<8f", header["chromaticities"][1])]
    if header.get("colorInteropID", ("",))[0] == "string":
        tags["colorInteropID"] = header["colorInteropID"][1].decode("utf-8", "replace")
    return tags


def read_uncompressed_exr(path, convert=None) -> tuple[list[tuple[str, LazyChannels]], dict] | None:
    """``([(part name, its channels), ...], the first part's colour tags)`` of an uncompressed scan-line OpenEXR
    file, each part read from the file when one of its channels is taken (:class:`LazyChannels`, arrays passed
    through ``convert``); the tags ``chromaticities`` (8 floats) and ``colorInteropID`` where the header has them.
    None where the file is not that common case (module docstring): the caller reads it with the OpenEXR
    library."""
    path = Path(path).absolute()
    try:
        with open(path, "rb") as f:
            identity, wanted = _identity(f), _HEAD_BYTES
            while True:
                f.seek(0)
                head = f.read(wanted)
                try:
                    found = _read(f, head, identity[2])
                    break
                except _Short:
                    if len(head) < wanted:          # the whole file is read: it ends inside its headers
                        return None
                    wanted *= 4
    except (OSError, _Unread, struct.error, LookupError, ValueError):   # LookupError: a missing attribute
        return None
    return [(name, LazyChannels(path, identity, layout, channels, groups, convert))
            for name, layout, channels, groups in found[0]], found[1]


def _read(f, head: bytes, file_size: int):
    """The parts' (name, layout, channels, groups) and the colour tags, from ``head`` (the file's first bytes)
    and, for the first and last chunks' own fields, ``f``."""
    magic, version = struct.unpack_from("<ii", _within(head, 8), 0)
    if magic != _MAGIC or version & 0xFF != 2 or version & (_TILED | _DEEP):
        raise _Unread
    multipart = bool(version & _MULTIPART)
    headers, at = _headers(head, multipart)
    parts = []
    for number, header in enumerate(headers):
        if header.get("compression", ("", b"\1"))[1] != b"\0" or \
                header.get("type", ("", b"scanlineimage"))[1] != b"scanlineimage":
            raise _Unread
        x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
        width, height = x1 - x0 + 1, y1 - y0 + 1
        chunks = struct.unpack("<i", header["chunkCount"][1])[0] if multipart else height
        if width < 1 or height < 1 or chunks != height or at + 8 * chunks > file_size:
            raise _Unread
        offsets = np.frombuffer(_within(head, at + 8 * chunks), "<u8", chunks, at).astype(np.int64)
        at += 8 * chunks
        channel_list = _channel_list(header["channels"][1])
        line = sum(width * dtype.itemsize for _, dtype in channel_list)
        lead = 12 if multipart else 8                     # (part number,) y, data size
        stride = int(offsets[1] - offsets[0]) if chunks > 1 else lead + line
        if stride < lead + line or np.any(np.diff(offsets) != stride) or offsets[0] < at or \
                int(offsets[-1]) + lead + line > file_size:
            raise _Unread
        for k in (0, chunks - 1):                         # the first and last chunks say what they are
            f.seek(int(offsets[k]))
            fields = struct.unpack("<iii" if multipart else "<ii", f.read(lead))
            if fields[:-2] != ((number,) if multipart else ()) or fields[-2:] != (y0 + k, line):
                raise _Unread
        channels, start = {}, 0
        for name, dtype in channel_list:
            channels[name] = (dtype, start)
            start += width * dtype.itemsize
        groups = group_names([name for name, _ in channel_list])
        if len({key for key, _ in groups}) < len(groups) or any(name.startswith(".") for name, _ in channel_list):
            raise _Unread                                # a channel named as a group, or an empty prefix
        for _key, names in groups:
            if len({channels[n][0] for n in names}) > 1:     # the binding refuses a group of mixed types
                raise _Unread
        name = header["name"][1].decode("utf-8", "replace") if "name" in header else ""
        parts.append((name, (int(offsets[0]), stride, chunks, lead, width, line), channels, groups))
    return parts, _colour_tags(headers[0])
