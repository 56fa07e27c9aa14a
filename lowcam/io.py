"""What Lowcam reads: renders (OpenEXR, via the ``OpenEXR`` package), plates and textures (PNG, JPEG, TIFF, via
OpenCV), each checked.

Every problem is a one-line :class:`~lowcam.errors.LowcamError` naming the file. Inputs are told by their bytes,
not their names. What Lowcam writes is in :mod:`lowcam.outputs`.

Contents
--------
- :func:`quiet_stderr`: keep C libraries' messages off the terminal for a while
- :func:`read_exr`: all channels of an OpenEXR file as ``{name: float32 array}``, layers grouped as (H, W, C)
- :func:`read_exr_tagged`: :func:`read_exr` and its header's colour tags
- :func:`render_space_of`: the space a render is in: the one stated, else its header's, else linear Rec.709
- :data:`OVERLAY_LAYER`: the add-on's view layer of excluded objects, never taken for the render
- :func:`read_render`: read a render as premultiplied linear Rec.709 RGBA float32 (H, W, 4)
- :func:`read_checked_render`: :func:`read_render` with its window, which the pipeline then need not find again
- :func:`exr_render`: :func:`read_checked_render` of an OpenEXR file's channels already read
- :func:`reusing_render_buffers`: renders read into the same few arrays, frame after frame, while it is on
- :data:`RENDER_MAX`: the largest render value accepted
- :func:`check_render`: validate an in-memory render: (H, W, 4), finite, in range, alpha in [0, 1]
- :func:`check_render_window`: :func:`check_render`, and the window around the render's non-zero pixels
- :class:`CheckedRender`: what :func:`check_render_window` returns; :func:`lowcam.simulate` takes it unchecked
- :func:`read_image`: read a PNG/JPEG/TIFF as RGB (H, W, 3) or greyscale (H, W), keeping its dtype
- :func:`read_plate`: read the video frame (PNG/JPEG) as uint8 and check its size against the camera's frame
- :func:`check_plate`: validate an in-memory plate: uint8, the camera's size, RGB (or one channel for raw Bayer)
- :func:`read_gain_map`: a greyscale PNG gain texture, scaled so the brightest texel is 1
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
from collections import ChainMap
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from .errors import LowcamError
from .parallel import thread_map, threads
from .render_spaces import LINEAR_REC709, header_space, render_space, to_camera_space
from .uncompressed_exr import LazyChannels, read_uncompressed_exr
from .window import nonzero_window, window_union


def _check_finite(path, image: np.ndarray) -> None:
    bad = ~np.isfinite(image)
    if bad.any():
        y, x = np.argwhere(bad)[0][:2]
        raise LowcamError(f"{path}: {int(bad.any(axis=-1).sum())} pixels hold NaN or Inf (first at x={x}, y={y})")


def _exists(path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise LowcamError(f"{path}: no such file")
    return path


@contextlib.contextmanager
def quiet_stderr(stdout: bool = False):
    """Keep C libraries' messages (libpng, libjpeg, ffmpeg; Blender's with ``stdout``) off the terminal: file
    descriptor 2 (and 1) goes to a temporary file for the duration. Yields a dict whose ``"text"`` holds what
    they said, once the block ends. The descriptors are the process's: whatever another thread writes to them
    meanwhile is kept off the terminal too (a shot's progress bar writes to its own copy of stderr)."""
    said = {"text": ""}
    fds = (1, 2) if stdout else (2,)
    sys.stdout.flush()
    sys.stderr.flush()
    with _QUIET:
        try:
            saved = [os.dup(fd) for fd in fds]
        except OSError:  # no such descriptor (a detached process): nothing to keep quiet
            yield said
            return
        with tempfile.TemporaryFile() as capture:
            try:
                for fd in fds:
                    os.dup2(capture.fileno(), fd)
                yield said
            finally:
                for fd, old in zip(fds, saved):
                    os.dup2(old, fd)
                    os.close(old)
                capture.seek(0)
                said["text"] = capture.read(4096).decode(errors="replace")


#: One thread at a time moves descriptors 1 and 2 (a shot reads its next frame while it simulates this one).
_QUIET = threading.RLock()


#: File signatures: the format is told by the bytes, not the name (an EXR named .png is still an EXR).
_MAGIC = {b"\x76\x2f\x31\x01": "exr", b"\x89PNG": "png", b"\xff\xd8\xff": "jpeg", b"II*\x00": "tiff",
          b"MM\x00*": "tiff"}


def _format(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as e:
        raise LowcamError(f"{path}: cannot read ({e.strerror or e})") from None
    if not head:
        raise LowcamError(f"{path}: the file is empty")
    return next((kind for magic, kind in _MAGIC.items() if head.startswith(magic)), "other")


#: A libOpenEXRCore older than 3.2 (soname 30) already in the process: its unversioned ``exr_*`` functions would
#: serve the OpenEXR wheel's module, which then crashes reading a file (Debian's Blender 4.3 links the system's 3.1).
_EXR_CORE_SONAME = re.compile(rb"libOpenEXRCore[-0-9_]*\.so\.(\d+)")


def _exr_core_too_old() -> bool:
    try:
        with open("/proc/self/maps", "rb") as f:
            return any(int(n) < 31 for n in _EXR_CORE_SONAME.findall(f.read()))
    except OSError:
        return False


_CHILD_READ = ("import sys, json, numpy as np\nfrom lowcam.errors import LowcamError\n"
               "from lowcam.io import read_exr_tagged\n"
               "try:\n    channels, tags = read_exr_tagged(sys.argv[1])\n"
               "    np.savez(sys.argv[2], **channels, **{_TAGS: np.array(json.dumps(tags))})\n"
               "except LowcamError as e:\n    sys.exit(str(e))\n").replace("_TAGS", repr("lowcam:colour tags"))
#: The header attributes that name a render's colour space.
_COLOUR_TAGS = ("colorInteropID", "chromaticities")


def _read_exr_in_child(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """:func:`read_exr_tagged` in a child Python on the same ``sys.path`` (the process's own libOpenEXRCore is
    too old for the OpenEXR wheel); the channels and tags come back through a temporary ``.npz``."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    with tempfile.TemporaryDirectory(prefix="lowcam-exr-") as folder:
        out = Path(folder) / "channels.npz"
        r = subprocess.run([sys.executable, "-c", _CHILD_READ, str(path), str(out)], env=env, capture_output=True,
                           text=True)
        if r.returncode != 0:
            lines = r.stderr.strip().splitlines()
            last = lines[-1] if lines else f"exit status {r.returncode}"
            raise LowcamError(last if last.startswith(str(path)) else
                              f"{path}: reading it in a child Python failed ({last})")
        with np.load(out) as z:
            channels = {k: z[k] for k in z.files}
        return channels, json.loads(str(channels.pop("lowcam:colour tags")))


def _float32(pixels: np.ndarray) -> np.ndarray:
    """A channel's pixels as float32; half floats through OpenCV (exact, and 4x numpy's conversion)."""
    if pixels.dtype == np.float16 and pixels.ndim <= 3 and pixels.size:
        return cv2.convertFp16(np.ascontiguousarray(pixels).view(np.int16)).reshape(pixels.shape)
    return np.asarray(pixels, np.float32)


def read_exr(path) -> Mapping[str, np.ndarray]:
    """All channels of an OpenEXR file as ``{name: float32 array}`` (grouped layers such as ``'RGBA'`` or
    ``'ViewLayer.Combined'`` come as (H, W, C) arrays). In a process that holds an older libOpenEXRCore (Debian's
    Blender) the file is read in a child Python."""
    return read_exr_tagged(path)[0]


def render_space_of(path, stated=None, tags=None):
    """The colour space of the render at ``path``: ``stated`` (a name, :func:`lowcam.render_spaces.render_space`)
    when given, else the one its header's colour ``tags`` name (:func:`read_exr_tagged`,
    :func:`lowcam.render_spaces.header_space`), else linear Rec.709. A stated space overrides a header Lowcam
    cannot read."""
    if stated:
        return render_space(stated)
    return header_space(tags or {}, path) or LINEAR_REC709


def read_exr_tagged(path) -> tuple[Mapping[str, np.ndarray], dict]:
    """:func:`read_exr` and the first part's colour tags (``colorInteropID``, ``chromaticities`` as a list), for
    :func:`render_space_of`. An uncompressed scan-line file (the add-on's renders) is read by Lowcam itself, each
    part when one of its channels is taken (:mod:`lowcam.uncompressed_exr`); any other file by the OpenEXR library:
    the same channels, grouped the same way."""
    path = _exists(path)
    direct = read_uncompressed_exr(path, _float32)
    if direct is not None:
        parts, tags = direct
        return _merged_parts(path, parts), tags
    if _exr_core_too_old():
        return _read_exr_in_child(path)
    import OpenEXR

    # OpenEXR raises bare RuntimeErrors for some corrupt files; of others (a truncated one) its C core only
    # complains on file descriptors 1 and 2 and hands back no channels: that complaint is the reason, kept off the
    # terminal
    decoders = threads() if threads() > 1 else 0   # the engine's threads; 0: in the calling thread (the default)
    if OpenEXR.global_thread_count() != decoders:
        OpenEXR.set_global_thread_count(decoders)
    with quiet_stderr(stdout=True) as said:
        try:
            with OpenEXR.File(str(path)) as f:  # every part: Blender writes one part per view layer
                parts = [(part.name(), {n: _float32(c.pixels) for n, c in part.channels.items()})
                         for part in f.parts]
                header = f.parts[0].header if f.parts else {}
                tags = {k: header[k] for k in _COLOUR_TAGS if header.get(k) is not None}
        except Exception as e:
            parts, reason = None, (str(e).splitlines()[0] if str(e) else type(e).__name__)
    complaint = sorted(said["text"].strip().splitlines(), key=lambda line: "EXR_ERR" not in line)
    if parts is None or (complaint and not any(channels for _, channels in parts)):
        if complaint:
            reason = complaint[0].removeprefix(f"{path}: ").strip()
        raise LowcamError(f"{path}: not a readable OpenEXR file ({reason})")
    if complaint and "EXR_ERR" in complaint[0]:
        _refuse_damaged_parts(path, parts, complaint[0].removeprefix(f"{path}: ").strip())
    if "chromaticities" in tags:
        tags["chromaticities"] = [float(v) for v in np.ravel(np.asarray(tags["chromaticities"], float))]
    if isinstance(tags.get("colorInteropID"), bytes):
        tags["colorInteropID"] = tags["colorInteropID"].decode(errors="replace")
    return _merged_parts(path, parts), tags


def _merged_parts(path: Path, parts) -> ChainMap:
    """Every part's channels in one mapping, in the parts' order (Blender writes one part per view layer, the
    layer in the channel names), each read only when it is taken where the part reads lazily. A channel two parts
    hold is refused."""
    seen: set = set()
    for part_name, part_channels in parts:
        twice = sorted(seen & set(part_channels))
        if twice:
            raise LowcamError(f"{path}: part '{part_name}' holds channel '{twice[0]}' again; write one part per "
                              "view layer, with the layer in the channel names")
        seen |= set(part_channels)
    return ChainMap(*reversed([part_channels for _, part_channels in parts]))  # iterates in the parts' order


def _refuse_damaged_parts(path: Path, parts: list, reason: str) -> None:
    """Refuse a file whose C core complained while the binding handed back some parts: a part it dropped or cut
    short (a file truncated in its last pass) is named with its channels, instead of a pass said to be absent."""
    import OpenEXR

    try:
        with quiet_stderr(stdout=True), OpenEXR.File(str(path), header_only=True) as f:
            declared = [(part.name(), [c.name for c in part.header.get("channels", [])]) for part in f.parts]
    except Exception:
        raise LowcamError(f"{path}: not a readable OpenEXR file ({reason})") from None
    read = dict(parts)
    for name, names in declared:
        got = set()
        for key, pixels in read.get(name, {}).items():   # grouped layers ("RGBA", "L.Combined") by their channels
            prefix = "" if key in ("RGB", "RGBA") else f"{key}."
            got |= {prefix + c for c in "RGBA"[:pixels.shape[2]]} if pixels.ndim == 3 else {key}
        lost = [n for n in names if n not in got]
        if lost:
            raise LowcamError(f"{path}: not a readable OpenEXR file: layer '{name}' (channels {', '.join(lost)}) is "
                              f"truncated or damaged ({reason})")


#: The view layer of excluded objects that the add-on adds ("Lowcam Overlay"); never taken for the render.
OVERLAY_LAYER = "Lowcam Overlay"


def _combined_layers(path, channels: Mapping, layer: str | None) -> list[str]:
    """The entries that may hold the render: the ``RGBA`` layer, the one ``*.Combined`` layer (Lowcam's overlay
    layer aside) or view layer ``layer``'s; several candidates without ``layer`` are refused."""
    candidates = [k for k in channels if k == "RGBA" or k.endswith(".Combined") or k == "Combined"]
    if layer is not None:
        chosen = [k for k in candidates if k in (layer, f"{layer}.Combined")]
        if not chosen:
            raise LowcamError(f"{path}: no layer '{layer}' (layers: {', '.join(candidates) or 'none'})")
        return chosen
    if len(candidates) > 1:
        candidates = [k for k in candidates if k != f"{OVERLAY_LAYER}.Combined"]
        if len(candidates) > 1:
            raise LowcamError(f"{path}: {len(candidates)} render layers ({', '.join(candidates)}); "
                              "choose one with --layer")
    return candidates


def _rgba_from_exr(path, channels: dict[str, np.ndarray], layer: str | None = None) -> np.ndarray:
    """The render's RGBA from an EXR's channels: the first of :func:`_combined_layers` with four channels, or
    R, G, B and A channels of their own."""
    for key in _combined_layers(path, channels, layer):
        arr = channels[key]
        if arr.ndim == 3 and arr.shape[2] == 4:
            return arr
        if arr.ndim == 3 and arr.shape[2] == 3:
            raise LowcamError(f"{path}: layer '{key}' has no alpha channel (render with a transparent film)")
    names = {k.split(".")[-1]: k for k in channels if channels[k].ndim == 2}
    if all(c in names for c in "RGB"):
        if "A" not in names:
            raise LowcamError(f"{path}: no alpha channel (render with a transparent film)")
        return np.stack([channels[names[c]] for c in "RGBA"], -1)
    if any(channels[k].ndim == 3 and channels[k].shape[2] == 3 for k in channels):
        raise LowcamError(f"{path}: no alpha channel (render with a transparent film)")
    raise LowcamError(f"{path}: no RGBA layer found (channels: {', '.join(sorted(channels))})")


def read_render(path, layer: str | None = None, render_space: str | None = None) -> np.ndarray:
    """Read a render as premultiplied linear Rec.709 RGBA float32 (H, W, 4): :func:`read_checked_render`'s array."""
    return read_checked_render(path, layer, render_space).rgba


def read_checked_render(path, layer: str | None = None, render_space: str | None = None) -> CheckedRender:
    """Read a render as premultiplied linear Rec.709 RGBA float32 (H, W, 4), checked, with the window around its
    non-zero pixels (:class:`CheckedRender`).

    OpenEXR (single-layer ``RGBA``, a Blender multilayer file's one ``*.Combined`` layer, or view layer ``layer``)
    is taken as premultiplied, as Blender writes it. PNG and TIFF are straight alpha (as Blender writes them) and
    are premultiplied here; 8- and 16-bit code values are scaled to 0..1, float TIFF values are used as they are.
    The format is told by the file's first bytes, not its name. A render in another colour space (``render_space``
    when given, else the one an OpenEXR header names: :func:`render_space_of`) is converted to linear Rec.709.
    """
    path = _exists(path)
    if _format(path) == "exr":
        return exr_render(path, *read_exr_tagged(path), layer, render_space)
    img = _decode(path)
    if img.ndim != 3 or img.shape[2] != 4:
        raise LowcamError(f"{path}: no alpha channel (a render needs RGBA)")
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(img.dtype, 1.0)
    rgba = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA).astype(np.float32) / np.float32(scale)
    rgba[..., :3] *= rgba[..., 3:]
    return check_render_window(to_camera_space(rgba, render_space_of(path, render_space)), path)


def exr_render(path, channels: dict, tags: dict, layer: str | None = None,
               render_space: str | None = None) -> CheckedRender:
    """:func:`read_checked_render` of an OpenEXR file whose channels and colour tags are read
    (:func:`read_exr_tagged`). A linear Rec.709 render in an uncompressed file is checked strip by strip as it is
    read (:func:`_checked_in_strips`)."""
    space = render_space_of(path, render_space, tags)
    checked = _checked_in_strips(path, channels, layer) if space is None or space == LINEAR_REC709 else None
    if checked is not None:
        return checked
    return check_render_window(to_camera_space(_rgba_from_exr(path, channels, layer), space), path)


def _references(arrays: list, i: int) -> int:
    return sys.getrefcount(arrays[i])


#: What :func:`_references` counts for an array that no one but its list refers to, measured rather than assumed
#: (what ``sys.getrefcount`` counts besides the holders differs between Python versions).
_HELD_BY_LIST_ALONE = _references([np.empty(0)], 0)


class _RenderBuffers:
    """Render-sized arrays kept while :func:`reusing_render_buffers` is on, so that a shot reads its renders into
    the same memory frame after frame instead of fresh pages, which the system must first zero. An array is given
    again only once nothing else refers to it."""

    def __init__(self):
        self._lock = threading.Lock()
        self._kept: list[np.ndarray] = []
        self._users = self._count = 0

    def take(self, shape: tuple, dtype) -> np.ndarray:
        with self._lock:
            kept = self._kept
            for i in range(len(kept)):      # no loop variable: it would hold a reference
                if kept[i].shape == shape and kept[i].dtype == dtype and _references(kept, i) == _HELD_BY_LIST_ALONE:
                    return kept[i]
            array = np.empty(shape, dtype)
            if self._users and self._count:
                self._kept = [*self._kept, array][-self._count:]
            return array

    @contextlib.contextmanager
    def reusing(self, count: int):
        with self._lock:
            self._users += 1
            self._count = max(self._count, count)
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if not self._users:
                    self._kept, self._count = [], 0


_render_buffers = _RenderBuffers()


def reusing_render_buffers(count: int):
    """While on (a context manager), renders read from uncompressed files go into at most ``count`` arrays kept and
    reused once no one refers to them (a shot's frames in flight), instead of fresh memory for every frame."""
    return _render_buffers.reusing(count)


def _checked_in_strips(path, channels: Mapping, layer: str | None) -> CheckedRender | None:
    """:func:`check_render_window` of the render's RGBA where an uncompressed part holds it as float32
    (:meth:`~lowcam.uncompressed_exr.LazyChannels.read_in_strips`): each strip of lines is checked and its window
    found while it is in cache, instead of reading the part, then the array, then the array again; the array is
    one of :func:`reusing_render_buffers`'s while that is on. The same array, window and refusals; None where the
    render is not held that way, or its part holds other entries too (Blender writes one part per pass)."""
    keys = _combined_layers(path, channels, layer)
    part = next((m for m in getattr(channels, "maps", [channels]) if keys and keys[0] in m), None)
    if not isinstance(part, LazyChannels) or len(part) > 1:   # passes beside it: one read of the part serves all
        return None

    def visit(top: int, lines: np.ndarray):
        window = nonzero_window(lines)                    # NaN counts; None: -0.0 alone
        if window is None:
            return None
        inside = lines[window]
        return top, window, cv2.countNonZero(cv2.inRange(inside, *_RENDER_BOUNDS)) == inside[..., 0].size

    read = part.read_in_strips(keys[0], 4, visit, _render_buffers.take)
    if read is None:
        return None
    rgba, found = read
    _check_render_shape(rgba.shape, path)
    if not all(passed for _, _, passed in found):
        return check_render_window(rgba, path)           # refuses it with the exact reason
    return CheckedRender(rgba, window_union([(top, window) for top, window, _ in found]))


#: The largest render value accepted: half-float's maximum (no real render is brighter; larger finite values
#: overflow the chain's float32 arithmetic).
RENDER_MAX = 65504.0


def _float32_within(lo: float, hi: float) -> tuple[float, float]:
    """The least and greatest float32 values inside [lo, hi] (open at a bound of RENDER_MAX, as cv2.checkRange)."""
    a, b = np.float32(lo), np.float32(hi)
    if float(a) < lo or float(a) == -RENDER_MAX:
        a = np.nextafter(a, np.float32(np.inf))
    if float(b) > hi or float(b) == RENDER_MAX:
        b = np.nextafter(b, np.float32(-np.inf))
    return float(a), float(b)


_COLOUR_BOUNDS, _ALPHA_BOUNDS = _float32_within(-RENDER_MAX, RENDER_MAX), _float32_within(-1e-4, 1 + 1e-4)
#: cv2.inRange's lower and upper bounds for (R, G, B, A): every float32 inside passes all of check_render's tests.
_RENDER_BOUNDS = tuple((c, c, c, a) for c, a in zip(_COLOUR_BOUNDS, _ALPHA_BOUNDS))


class CheckedRender(NamedTuple):
    """A render that :func:`check_render_window` has passed, and its window. :func:`lowcam.simulate` takes it in
    place of the array and does not check it again (a shot reads and checks each render on its reading thread)."""

    rgba: np.ndarray
    window: tuple[slice, slice] | None


def check_render(rgba: np.ndarray, name="render") -> np.ndarray:
    """Validate an in-memory render: (H, W, 4), finite, within +-:data:`RENDER_MAX`, alpha in [0, 1]. Returns it
    as float32."""
    return check_render_window(rgba, name)[0]


def _check_render_shape(shape: tuple, name) -> None:
    if len(shape) != 3 or shape[2] != 4:
        raise LowcamError(f"{name}: a render must be RGBA of shape (H, W, 4), got {shape}")
    if shape[0] < 16 or shape[1] < 16:
        raise LowcamError(f"{name}: a render of {shape[1]}x{shape[0]} is too small")


def check_render_window(rgba: np.ndarray, name="render") -> CheckedRender:
    """:func:`check_render`, and the :func:`~lowcam.window.nonzero_window` around the render's non-zero pixels
    (None: all zero). The zero margins are valid by construction, so only the window is checked in full."""
    rgba = np.asarray(rgba)
    _check_render_shape(rgba.shape, name)
    if rgba.dtype.kind not in "fiu":
        raise LowcamError(f"{name}: a render must hold numbers, got {rgba.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        rgba = np.ascontiguousarray(rgba, np.float32)
    window = nonzero_window(rgba)  # NaN counts as non-zero
    if window is None:
        return CheckedRender(rgba, None)
    # One pass over the window: cv2.inRange fails NaN and Inf too, and its bounds (float32 values inside the
    # limits below) make it at least as strict; only a render it refuses is checked again for the exact error.
    # Strips of about 3 MB, shared out among the threads, keep each mask in cache until it is counted.
    inside = rgba[window]
    step = int(np.clip((3 << 20) // max(1, inside.shape[1] * 16), 16, 256))
    passed = thread_map(lambda rows: cv2.countNonZero(cv2.inRange(inside[rows], *_RENDER_BOUNDS)),
                        [slice(top, top + step) for top in range(0, inside.shape[0], step)])
    if sum(passed) == inside.shape[0] * inside.shape[1]:
        return CheckedRender(rgba, window)
    if not cv2.checkRange(rgba, True, -RENDER_MAX, RENDER_MAX)[0]:  # one pass finds NaN, Inf and range at once
        _check_finite(name, rgba)
        lo, hi = float(rgba.min()), float(rgba.max())
        raise LowcamError(f"{name}: values up to {max(-lo, hi):.3g} are beyond a render's range "
                          f"(+-{RENDER_MAX:g}); is it in the right units?")
    lo, hi, _, _ = cv2.minMaxLoc(cv2.extractChannel(rgba, 3))
    if lo < -1e-4 or hi > 1 + 1e-4:
        raise LowcamError(f"{name}: alpha must lie in [0, 1], found {lo:.3g}..{hi:.3g}")
    return CheckedRender(rgba, window)


#: What libjpeg and libpng say of a damaged file that they still decode (partly grey).
_DAMAGE = re.compile(r"premature end|corrupt|incomplete|crc error|truncat|invalid", re.IGNORECASE)


def _decode(path: Path) -> np.ndarray:
    """Decode a PNG, JPEG or TIFF with OpenCV, its codecs' chatter kept off the terminal. A truncated or damaged
    file is an error, not a partly grey picture; bytes after the image's end (as phones append) are fine."""
    kind = _format(path)
    if kind == "exr":
        raise LowcamError(f"{path}: an OpenEXR file where a PNG, JPEG or TIFF image was expected")
    with quiet_stderr() as codec:
        try:
            img = cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            img = None
    complaint = next((line for line in codec["text"].splitlines() if _DAMAGE.search(line)), None)
    if img is None or complaint:
        raise LowcamError(f"{path}: " + (f"the image is truncated or corrupt ({complaint.strip()})" if complaint
                                         else "not a readable image (PNG, JPEG or TIFF), or truncated"))
    return img


def read_image(path) -> np.ndarray:
    """Read a PNG/JPEG/TIFF as RGB (H, W, 3) or greyscale (H, W), keeping its dtype (uint8 or uint16)."""
    img = _decode(_exists(path))
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def read_plate(path, width: int, height: int, channels: int | None = 3) -> np.ndarray:
    """Read the video frame (PNG/JPEG) as uint8 and check its size against the camera's frame.

    ``channels`` 3 wants RGB (a greyscale frame is an error); ``None`` accepts RGB or a one-channel raw frame.
    """
    img = read_image(path)
    if img.dtype == np.uint16:
        img = np.round(img / 257.0).astype(np.uint8)
    if img.dtype != np.uint8:
        raise LowcamError(f"{path}: the plate holds {img.dtype} values; a video frame is 8- or 16-bit")
    if img.shape[:2] != (height, width):
        raise LowcamError(f"{path}: the plate is {img.shape[1]}x{img.shape[0]}, the camera delivers {width}x{height}")
    if channels == 3 and img.ndim != 3:
        raise LowcamError(f"{path}: the plate is greyscale, this profile needs an RGB video frame")
    return img


def check_plate(plate: np.ndarray, width: int, height: int, name="plate", raw: bool = False) -> np.ndarray:
    """Validate an in-memory plate: uint8, the camera's size, RGB (or one channel for a raw-Bayer camera)."""
    plate = np.asarray(plate)
    if plate.shape[:2] != (height, width):
        raise LowcamError(f"{name}: the plate is {plate.shape[1] if plate.ndim > 1 else '?'}x{plate.shape[0]}, "
                          f"the camera delivers {width}x{height}")
    if not (plate.ndim == 3 and plate.shape[2] == 3) and not (raw and plate.ndim == 2):
        raise LowcamError(f"{name}: the plate must be RGB (H, W, 3){' or a raw Bayer frame (H, W)' if raw else ''}, "
                          f"got shape {plate.shape}")
    if plate.dtype != np.uint8:
        raise LowcamError(f"{name}: the plate must be 8-bit (uint8), got {plate.dtype}")
    return plate


def read_gain_map(path) -> np.ndarray:
    """A greyscale PNG gain texture, scaled so the brightest texel is 1."""
    img = read_image(path)
    if img.ndim != 2:
        img = img.mean(axis=2)
    img = img.astype(np.float32)
    _check_finite(path, img)
    if img.min() < 0:
        raise LowcamError(f"{path}: the gain map holds negative values (down to {img.min():.3g})")
    if img.max() <= 0:
        raise LowcamError(f"{path}: the gain map is all zero")
    return img / img.max()
