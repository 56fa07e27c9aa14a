"""Reading renders and plates, writing frames: OpenEXR (via the ``OpenEXR`` package), PNG and JPEG (via OpenCV).

Every problem is a one-line :class:`~lowcam.errors.LowcamError` naming the file. Every write is atomic: the data
goes to a temporary file in the same folder, which is then renamed over the target, so a crash never leaves a
half-written frame under the final name.

Contents
--------
- :func:`atomic_write_bytes`: write bytes to a path through a temporary file and an atomic rename
- :func:`read_toml`: a TOML file as a dict; a missing or malformed file is a one-line error naming it
- :func:`read_exr`: all channels of an OpenEXR file as ``{name: float32 array}``, layers grouped as (H, W, C)
- :func:`read_render`: read a render as premultiplied linear RGBA float32 (H, W, 4)
- :func:`check_render`: validate an in-memory render: (H, W, 4), finite, alpha in [0, 1]
- :func:`read_image`: read a PNG/JPEG as RGB (H, W, 3) or greyscale (H, W), keeping its dtype (uint8 or uint16)
- :func:`read_plate`: read the video frame (PNG/JPEG) as uint8 and check its size against the camera's frame
- :func:`check_plate`: validate an in-memory plate: uint8, the camera's size, RGB (or one channel for raw Bayer)
- :func:`read_gain_map`: a greyscale PNG gain texture, scaled so the brightest texel is 1
- :func:`encode_png`: PNG bytes of an RGB(A) or greyscale uint8/uint16 image
- :func:`write_png`: write an RGB(A) or greyscale uint8/uint16 image as PNG, atomically
- :func:`write_exr`: write float RGBA (H, W, 4) as a single-layer OpenEXR file, atomically
- :func:`write_image`: write by extension: ``.exr`` takes float RGBA, anything else is PNG
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .errors import LowcamError


_umask = os.umask(0)
os.umask(_umask)
_FILE_MODE = 0o666 & ~_umask


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _check_finite(path, image: np.ndarray) -> None:
    if np.isfinite(image).all():
        return
    bad = ~np.isfinite(image)
    if bad.any():
        y, x = np.argwhere(bad)[0][:2]
        raise LowcamError(f"{path}: {int(bad.any(axis=-1).sum())} pixels hold NaN or Inf (first at x={x}, y={y})")


def _exists(path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise LowcamError(f"{path}: no such file")
    return path


def read_toml(path, what: str = "file") -> dict:
    """A TOML file as a dict; a missing or malformed file is a one-line error naming it."""
    import tomllib

    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise LowcamError(f"{path}: no such {what}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise LowcamError(f"{path}: not valid TOML ({e})") from None


def read_exr(path) -> dict[str, np.ndarray]:
    """All channels of an OpenEXR file as ``{name: float32 array}`` (grouped layers such as ``'RGBA'`` or
    ``'ViewLayer.Combined'`` come as (H, W, C) arrays)."""
    import OpenEXR

    path = _exists(path)
    try:
        with OpenEXR.File(str(path)) as f:  # every part: Blender writes one part per view layer
            return {name: np.asarray(ch.pixels, np.float32) for part in f.parts for name, ch in part.channels.items()}
    except Exception as e:  # OpenEXR raises bare RuntimeErrors for corrupt files
        raise LowcamError(f"{path}: not a readable OpenEXR file ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


def _rgba_from_exr(path, channels: dict[str, np.ndarray]) -> np.ndarray:
    candidates = [k for k in channels if k == "RGBA" or k.endswith(".Combined") or k == "Combined"]
    for key in candidates:
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


def read_render(path) -> np.ndarray:
    """Read a render as premultiplied linear RGBA float32 (H, W, 4).

    OpenEXR (single-layer ``RGBA`` or a Blender multilayer ``*.Combined`` layer) is taken as premultiplied, as
    Blender writes it. PNG is straight alpha (as Blender writes it) and is premultiplied here; its code values are
    scaled to 0..1 and used as they are.
    """
    path = _exists(path)
    if path.suffix.lower() == ".exr":
        rgba = _rgba_from_exr(path, read_exr(path))
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise LowcamError(f"{path}: not a readable image")
        if img.ndim != 3 or img.shape[2] != 4:
            raise LowcamError(f"{path}: no alpha channel (a render needs RGBA)")
        scale = 65535.0 if img.dtype == np.uint16 else 255.0
        rgba = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA).astype(np.float32) / scale
        rgba[..., :3] *= rgba[..., 3:]
    return check_render(rgba, path)


def check_render(rgba: np.ndarray, name="render") -> np.ndarray:
    """Validate an in-memory render: (H, W, 4), finite, alpha in [0, 1]. Returns it as float32."""
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4:
        raise LowcamError(f"{name}: a render must be RGBA of shape (H, W, 4), got {rgba.shape}")
    if rgba.shape[0] < 16 or rgba.shape[1] < 16:
        raise LowcamError(f"{name}: a render of {rgba.shape[1]}x{rgba.shape[0]} is too small")
    rgba = np.ascontiguousarray(rgba, np.float32)
    _check_finite(name, rgba)
    lo, hi, _, _ = cv2.minMaxLoc(cv2.extractChannel(rgba, 3))
    if lo < -1e-4 or hi > 1 + 1e-4:
        raise LowcamError(f"{name}: alpha must lie in [0, 1], found {lo:.3g}..{hi:.3g}")
    return rgba


def read_image(path) -> np.ndarray:
    """Read a PNG/JPEG as RGB (H, W, 3) or greyscale (H, W), keeping its dtype (uint8 or uint16)."""
    path = _exists(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise LowcamError(f"{path}: not a readable image")
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
    if img.max() <= 0:
        raise LowcamError(f"{path}: the gain map is all zero")
    return img / img.max()


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB(A) or greyscale uint8/uint16 image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    ok, data = cv2.imencode(".png", img)
    if not ok:
        raise LowcamError("could not encode PNG")
    return data.tobytes()


def write_png(path, image: np.ndarray) -> Path:
    """Write an RGB(A) or greyscale uint8/uint16 image as PNG, atomically."""
    atomic_write_bytes(path, encode_png(image))
    return Path(path)


def write_exr(path, rgba: np.ndarray) -> Path:
    """Write float RGBA (H, W, 4) as a single-layer OpenEXR file, atomically."""
    import OpenEXR

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part.exr", dir=path.parent)
    os.close(fd)
    try:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGBA": np.ascontiguousarray(rgba, np.float32)}).write(tmp)
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_image(path, image: np.ndarray) -> Path:
    """Write by extension: ``.exr`` takes float RGBA, anything else is PNG."""
    if Path(path).suffix.lower() == ".exr":
        return write_exr(path, image)
    return write_png(path, image)
