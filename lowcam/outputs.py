"""What Lowcam writes, and the checks before it writes: frames (PNG, JPEG, OpenEXR), profiles, reports, folders.

Every write is atomic: the data goes to a temporary file in the same folder, is fsynced, and is renamed over the
target, so a crash never leaves a half-written frame under the final name. Outputs are checked before the work
that makes them: never a folder, a FIFO or one of the inputs. Every problem is a one-line
:class:`~lowcam.errors.LowcamError` naming the file; a full disk is a :class:`~lowcam.errors.DiskFull`.

Contents
--------
- :data:`FULL_ERRNOS`: the OS errors of a full disk, a quota or a file-size limit (:class:`~lowcam.errors.DiskFull`)
- :func:`atomic_write_with`: a file a library writes, through a temporary file renamed into place
- :func:`atomic_write_bytes`: write bytes through a temporary file, fsync, an atomic rename and a folder fsync
- :func:`remove_stale_temporaries`: remove the temporaries of killed runs, never a live run's or a user's file
- :func:`check_output`: check before any work that an output file can be written and is none of the inputs
- :data:`FOLDER_MARKER`: the file that marks a folder Lowcam wrote
- :func:`check_output_folder`: check before any work that a folder may receive a whole output
- :func:`output_folder`: check and make an output folder for a block of work; an error removes what it made
- :func:`make_output_folder`: create an output folder and mark it as Lowcam's
- :func:`encode_png`: PNG bytes of an RGB(A) or greyscale uint8/uint16 image
- :func:`write_png`: write an RGB(A) or greyscale uint8/uint16 image as PNG, atomically
- :func:`write_exr`: write float RGB(A) as a single-layer OpenEXR file, atomically
- :data:`IMAGE_SUFFIXES`: the output formats, by suffix
- :data:`JPEG_QUALITY`: the quality of JPEG outputs
- :func:`check_image_output`: :func:`check_output` for an image, its suffix one of :data:`IMAGE_SUFFIXES`
- :func:`write_image`: write by suffix: PNG, JPEG or OpenEXR (8-bit frames as code values over 255)
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from .errors import DiskFull, LowcamError


_umask = os.umask(0)
os.umask(_umask)
_FILE_MODE = 0o666 & ~_umask


#: Temporaries are named ``.lowcam-<host>-<pid>-<random>.<name>.part`` so that a run can tell its own, another
#: live run's and a killed run's apart, and so that no user file matches.
_PART = re.compile(r"^\.lowcam-(?P<host>[^-]+)-(?P<pid>\d+)-[A-Za-z0-9_]+\..+\.part$")


_HOST = socket.gethostname().split(".")[0].replace("-", "_")[:32] or "host"


def _part_prefix() -> str:
    return f".lowcam-{_HOST}-{os.getpid()}-"


def _fsync_folder(folder: Path) -> None:
    if os.name != "posix":
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


#: The OS errors of a full disk, an exhausted quota or a file-size limit: every later write would fail alike, so
#: they are a :class:`~lowcam.errors.DiskFull` (a shot stops there), not a bad frame.
FULL_ERRNOS = frozenset(code for code in (errno.ENOSPC, getattr(errno, "EDQUOT", None), errno.EFBIG) if code)


def _cannot_write(path, e: OSError) -> LowcamError:
    kind = DiskFull if e.errno in FULL_ERRNOS else LowcamError
    return kind(f"{path}: cannot write ({e.strerror or e})")


def _write_through_temporary(path, write) -> Path:
    """Call ``write(temporary_path)``, fsync it, rename it over ``path`` and fsync the folder. An OS error is a
    one-line :class:`LowcamError` naming ``path`` (:class:`~lowcam.errors.DiskFull` for :data:`FULL_ERRNOS`); the
    temporary never survives a failure."""
    path = Path(path)
    check_output(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=_part_prefix(), suffix=f".{path.name[:100]}.part", dir=path.parent)
    except OSError as e:
        raise _cannot_write(path, e) from None
    try:
        os.close(fd)
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
        _fsync_folder(path.parent)
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        raise _cannot_write(path, e) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_with(path, write) -> Path:
    """Call ``write(temporary_path)`` and rename the temporary over ``path`` (fsynced): for outputs a library
    writes itself (a video); nothing is left at ``path`` if ``write`` fails."""
    return _write_through_temporary(path, write)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file, fsync, an atomic rename and an fsync of the folder."""
    return _write_through_temporary(path, lambda tmp: Path(tmp).write_bytes(data))


def remove_stale_temporaries(folder) -> int:
    """Remove the temporaries that killed Lowcam runs left in ``folder``: those of this host whose process is
    gone, and any older than a day. Temporaries of live runs (a farm's other tasks) and user files stay.
    Returns how many were removed."""
    removed = 0
    for p in Path(folder).glob(".lowcam-*.part"):
        m = _PART.match(p.name)
        if not m:
            continue
        try:
            old = time.time() - p.stat().st_mtime > 86400
        except FileNotFoundError:
            continue
        if old or (m["host"] == _HOST and not _process_alive(int(m["pid"]))):
            p.unlink(missing_ok=True)
            removed += 1
    return removed


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # alive, but another user's
        return True
    try:  # a killed process that nobody reaped (a container whose init does not) is a zombie: gone
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rpartition(b")")[2].split()[0] not in (b"Z", b"X")
    except (OSError, IndexError):
        return True


def check_output(path, inputs=(), option: str = "-o") -> Path:
    """Check, before any work, that ``path`` can be written as a regular file and is none of ``inputs``.

    Refused, each as a one-line :class:`LowcamError`: an empty path, a folder or a non-regular file (FIFO, device)
    at ``path``, a parent that is a file, a name too long for the file system, a folder that cannot be written, and
    a path that is (by real path or inode) one of ``inputs``."""
    if path is None or str(path) == "":
        raise LowcamError(f"{option}: an empty output path")
    path = Path(path)
    if path.is_dir():
        raise LowcamError(f"{path}: is a folder; {option} names the file to write")
    if path.exists() and not path.is_file():
        raise LowcamError(f"{path}: is not a regular file (a FIFO or device); Lowcam writes only regular files")
    for source in inputs:
        if source and _same_file(path, source):
            raise LowcamError(f"{path}: the output is the input {source}; choose another {option}")
    if len(path.name.encode()) > 255:
        raise LowcamError(f"{path.name[:40]}...: the file name is {len(path.name.encode())} bytes long, "
                          f"longer than file systems allow (255)")
    _check_writable_folder(path.parent, path)
    return path


def _same_file(a, b) -> bool:
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        return False
    return os.path.realpath(a) == os.path.realpath(b)


def _check_writable_folder(folder: Path, target: Path) -> None:
    existing = folder if str(folder) else Path(".")
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise LowcamError(f"{target}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise LowcamError(f"{target}: cannot write into {existing} (permission denied)")


#: The marker Lowcam leaves in every folder it writes a whole output into (reports, stage images, sets).
FOLDER_MARKER = ".lowcam-output"


def check_output_folder(folder, option: str = "-o", force: bool = False) -> Path:
    """Check, before any work, that ``folder`` may receive a whole output (a report, stage images, a measurement
    set): it is new, empty, written by Lowcam before (it holds :data:`FOLDER_MARKER`), or ``force``."""
    if folder is None or str(folder) == "":
        raise LowcamError(f"{option}: an empty output folder")
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise LowcamError(f"{folder}: is a file; {option} names a folder to write into")
    if folder.is_dir() and not force and not (folder / FOLDER_MARKER).exists():
        try:
            foreign = next(folder.iterdir(), None)
        except OSError as e:
            raise LowcamError(f"{folder}: cannot read the folder ({e.strerror})") from None
        if foreign is not None:
            raise LowcamError(f"{folder}: the folder holds files Lowcam did not write (e.g. {foreign.name}); "
                              f"choose a new or empty folder for {option}")
    _check_writable_folder(folder, folder)
    return folder


@contextlib.contextmanager
def output_folder(folder, option: str = "-o", force: bool = False):
    """:func:`check_output_folder`, then :func:`make_output_folder` for a block of work: a refusal or an error
    inside the block removes the folders it made, so no half-made output is left."""
    folder = check_output_folder(folder, option, force)
    new = next((p for p in reversed([folder, *folder.parents]) if not p.exists()), None)  # the topmost to be made
    made = make_output_folder(folder)
    try:
        yield made
    except BaseException:
        if new is not None:
            shutil.rmtree(new, ignore_errors=True)
        raise


def make_output_folder(folder) -> Path:
    """Create ``folder`` (checked by :func:`check_output_folder`) and mark it as Lowcam's."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / FOLDER_MARKER).touch()
    except OSError as e:
        raise LowcamError(f"{folder}: cannot write ({e.strerror or e})") from None
    return folder


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB(A) or greyscale uint8/uint16 image."""
    return _encode(image, ".png")


def _encode(image: np.ndarray, suffix: str, params=()) -> bytes:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    ok, data = cv2.imencode(suffix, img, list(params))
    if not ok:
        raise LowcamError(f"could not encode a {img.shape} {img.dtype} image as {suffix}")
    return data.tobytes()


def write_png(path, image: np.ndarray) -> Path:
    """Write an RGB(A) or greyscale uint8/uint16 image as PNG, atomically."""
    return atomic_write_bytes(path, encode_png(image))


def write_exr(path, rgba: np.ndarray, half: bool = False) -> Path:
    """Write a float (H, W, 4) RGBA or (H, W, 3) RGB image as a single-layer ZIP OpenEXR file, atomically: 32-bit
    float, or half float with ``half``."""
    import OpenEXR

    pixels = np.ascontiguousarray(rgba, np.float16 if half else np.float32)
    name = {4: "RGBA", 3: "RGB"}.get(pixels.shape[-1] if pixels.ndim == 3 else 0)
    if name is None:
        raise LowcamError(f"{path}: an OpenEXR image must be (H, W, 3) or (H, W, 4), got {pixels.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp):
        try:
            OpenEXR.File(header, {name: pixels}).write(tmp)
        except RuntimeError as e:  # OpenEXR names the OS error in its message only
            message = str(e)
            code = next((c for c in (*FULL_ERRNOS, errno.EACCES, errno.EROFS, errno.EIO)
                         if os.strerror(c) in message), errno.EIO)
            raise OSError(code, os.strerror(code) if os.strerror(code) in message else message.splitlines()[0],
                          tmp) from None

    return _write_through_temporary(path, write)


#: Output formats by file suffix.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")

#: JPEG quality of ``.jpg`` outputs (OpenCV's scale, 0-100).
JPEG_QUALITY = 95


def check_image_output(path, inputs=(), option: str = "-o") -> Path:
    """:func:`check_output` for an image, whose suffix must be one of :data:`IMAGE_SUFFIXES`."""
    if path and Path(path).suffix.lower() not in IMAGE_SUFFIXES:
        raise LowcamError(f"{path}: unknown image format '{Path(path).suffix}' (write {', '.join(IMAGE_SUFFIXES)})")
    return check_output(path, inputs, option)


def write_image(path, image: np.ndarray) -> Path:
    """Write by suffix: ``.png`` (lossless), ``.jpg``/``.jpeg`` (quality :data:`JPEG_QUALITY`) or ``.exr``.

    An 8-bit frame goes to OpenEXR as its code values over 255 (0-1, the camera's encoding, not linearised); a
    float image as it is."""
    suffix = Path(path).suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise LowcamError(f"{path}: unknown image format '{suffix}' (write {', '.join(IMAGE_SUFFIXES)})")
    image = np.asarray(image)
    if suffix == ".exr":
        if image.dtype == np.uint8:
            image = image.astype(np.float32) / 255.0
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        return write_exr(path, image)
    if suffix == ".png":
        return write_png(path, image)
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    return atomic_write_bytes(path, _encode(image, ".jpg", (cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY)))
