"""Measurement sets: what an ideal camera saw, and what the real camera delivered (several frames each).

A folder holds ``set.toml``::

    [[capture]]
    name = "chart-a"
    ideal = "ideal/chart-a.exr"         # premultiplied linear RGBA, as for `lowcam apply --render`
    frames = ["frames/chart-a-*.png"]   # 8-bit RGB at the profile's output size; several frames of a static scene
                                        # (one frame works too: its noise is then taken from the model)
    plate = "plates/chart-a.png"        # optional: the real background where the ideal is transparent
    mask = "masks/chart-a.png"          # optional: greyscale, black where the frames are not to be compared (a
                                        # hand, a reflection); white elsewhere
    angular_velocity = [0.0, 0.0, 0.0]  # optional, rad/s in the camera frame
    exposure_s = 0.033                  # optional, s

Instead of ``ideal``, ``target = "checkerboard:9x6:0.025"`` makes Lowcam find the board in the frames, estimate
its pose with the profile's lens, and render the board's ideal view itself (its white and black are taken from
the frames); everything off the board is compared against the frames' own mean. ``target = "colorchecker"`` (a
ColorChecker Classic) compares the inner half of its 24 patches against their reference colours times an
exposure fitted on the neutral patches (:func:`lowcam.measure.targets.colour_checker_view`).

Contents
--------
- :data:`CAPTURE_KEYS`: the keys a ``[[capture]]`` table may hold
- :class:`Capture`: one capture: its frames, ideal or target, plate and motion
- :class:`MeasurementSet`: the captures of a set.toml
- :func:`load_set`: read and validate a measurement set; errors name the file, the capture and the key
- :func:`write_set`: write a measurement set
"""
from __future__ import annotations

import glob
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomli_w

from .. import schema
from ..captures import load_frames, parse_target
from ..errors import LowcamError
from ..io import read_image, read_plate, read_render
from ..motion import MAX_RATE
from ..outputs import atomic_write_bytes, write_exr, write_png

CAPTURE_KEYS = {"name", "ideal", "target", "frames", "plate", "mask", "angular_velocity", "exposure_s"}


@dataclass
class Capture:
    name: str
    frames: np.ndarray  # (n, H, W, 3) uint8
    ideal: np.ndarray | None = None  # (h, w, 4) premultiplied RGBA
    target: str | None = None
    plate: np.ndarray | None = None
    mask: np.ndarray | None = None  # (H, W) bool: the pixels compared (None: all)
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    exposure_s: float | None = None
    frame_names: list[str] = field(default_factory=list)
    source: str = ""  # the set.toml that lists it ("" for a capture made in code)

    @property
    def mean(self) -> np.ndarray:
        return self.frames.astype(np.float64).mean(axis=0)

    @property
    def where(self) -> str:
        """The capture in messages: its set file and name, and its frames (``set.toml: capture board (frames
        f-000.png ... f-004.png)``)."""
        names = [Path(n).name for n in self.frame_names]
        frames = "" if not names else f" (frames {names[0]}" + (f" ... {names[-1]})" if len(names) > 1 else ")")
        return (f"{self.source}: " if self.source else "") + f"capture {self.name}{frames}"


@dataclass
class MeasurementSet:
    path: Path
    captures: list[Capture]

    @property
    def name(self) -> str:
        return self.path.name


def load_set(folder, profile=None) -> MeasurementSet:
    """Read and validate a measurement set; errors name the file, the capture and the key."""
    folder = Path(folder)
    toml_path = folder / "set.toml" if folder.is_dir() else folder
    folder, src = toml_path.parent, str(toml_path)
    doc = schema.read_toml(toml_path, "measurement set (a folder with set.toml)")
    schema.table(doc, src, known={"capture"})
    entries = schema.array_of(doc.get("capture", []), src, "capture")
    if not entries:
        raise LowcamError(f"{toml_path}: no [[capture]] entries")
    captures = []
    for i, entry in enumerate(entries):
        where = f"{toml_path}: capture {i + 1}"
        schema.table(entry, where, known=CAPTURE_KEYS, required=("frames",))
        name = schema.string(entry.get("name", f"capture-{i + 1}"), where, "name", nonempty=True)
        where = f"{toml_path}: capture {schema.shown(name)}"
        if any(c.name == name for c in captures):
            raise LowcamError(f"{where}: a second capture of that name")
        if ("ideal" in entry) == ("target" in entry):
            raise LowcamError(f"{where}: give exactly one of 'ideal' and 'target'")
        files = {k: schema.existing_file(entry[k], where, k, folder) for k in ("ideal", "plate", "mask") if k in entry}
        target = entry.get("target")
        if target is not None and parse_target(target, f"{where}: 'target'")[0] not in ("checkerboard", "colorchecker"):
            raise LowcamError(f"{where}: 'target': only checkerboard targets and colorchecker can be rendered so far")
        w = schema.numbers(entry.get("angular_velocity", [0.0, 0.0, 0.0]), where, "angular_velocity", 3,
                           -MAX_RATE, MAX_RATE, "rad/s")
        exposure_s = entry.get("exposure_s")
        if exposure_s is not None:
            exposure_s = schema.number(exposure_s, where, "exposure_s", 0.0, 10.0, "s")
        patterns = entry["frames"]
        patterns = [patterns] if isinstance(patterns, str) else patterns
        patterns = schema.array_of(patterns, where, "frames", _nonempty, min_length=1)
        # the set's folder is a path, not a pattern (a name with [ or *); a name without a wildcard must be there
        names = set()
        for pat in patterns:
            if not glob.has_magic(pat):
                if not (folder / pat).is_file():
                    raise LowcamError(f"{where}: 'frames': {folder / pat}: no such file")
                names.add(str(folder / pat))
            else:
                names.update(glob.glob(pat if os.path.isabs(pat) else glob.escape(str(folder)) + os.sep + pat))
        names = sorted(names)
        if not names:
            raise LowcamError(f"{where}: 'frames': no file matches {', '.join(str(folder / p) for p in patterns)}")
        frames, _ = load_frames(names, 1, where)
        frames = np.stack(frames)
        if profile is not None and frames.shape[1:3] != (profile.camera.height, profile.camera.width):
            raise LowcamError(f"{names[0]}: the frames are {frames.shape[2]}x{frames.shape[1]}, the profile's camera "
                              f"delivers {profile.camera.width}x{profile.camera.height}")
        cap = Capture(name, frames, target=target, angular_velocity=tuple(w), exposure_s=exposure_s,
                      frame_names=names, source=str(toml_path))
        if "ideal" in files:
            cap.ideal = read_render(files["ideal"])
        if "plate" in files:
            cap.plate = read_plate(files["plate"], frames.shape[2], frames.shape[1])
        if "mask" in files:
            cap.mask = _read_mask(files["mask"], frames.shape[2], frames.shape[1])
        captures.append(cap)
    return MeasurementSet(folder, captures)


def _read_mask(path, width: int, height: int) -> np.ndarray:
    """A capture's mask image as (H, W) bool, True where the frames are compared (grey above half)."""
    raw = read_image(path)
    img = raw.astype(np.float64)
    img = img.mean(axis=2) if img.ndim == 3 else img
    if img.shape != (height, width):
        raise LowcamError(f"{path}: the mask is {img.shape[1]}x{img.shape[0]}, the frames are {width}x{height}")
    mask = img > (0.5 if raw.dtype.kind == "f" else np.iinfo(raw.dtype).max / 2)   # a float image: 0-1
    if not mask.any():
        raise LowcamError(f"{path}: the mask leaves no pixel to compare (white marks the pixels compared)")
    return mask


def _nonempty(value, where: str, key: str) -> str:
    return schema.string(value, where, key, nonempty=True)


def write_set(folder, captures: list[dict]) -> Path:
    """Write a measurement set. Each dict: ``name``, ``ideal`` (RGBA array), ``frames`` (list of uint8 RGB),
    optional ``plate``, ``mask`` ((H, W) bool: the pixels compared), ``angular_velocity``, ``exposure_s``."""
    folder = Path(folder)
    entries = []
    for c in captures:
        name = c["name"]
        write_exr(folder / "ideal" / f"{name}.exr", c["ideal"])
        for k, f in enumerate(c["frames"]):
            write_png(folder / "frames" / f"{name}-{k:03d}.png", f)
        entry = {"name": name, "ideal": f"ideal/{name}.exr", "frames": [f"frames/{name}-*.png"]}
        if c.get("plate") is not None:
            write_png(folder / "plates" / f"{name}.png", c["plate"])
            entry["plate"] = f"plates/{name}.png"
        if c.get("mask") is not None:
            write_png(folder / "masks" / f"{name}.png", np.where(np.asarray(c["mask"], bool), 255, 0).astype(np.uint8))
            entry["mask"] = f"masks/{name}.png"
        if c.get("angular_velocity") is not None:
            entry["angular_velocity"] = [float(v) for v in c["angular_velocity"]]
        if c.get("exposure_s") is not None:
            entry["exposure_s"] = float(c["exposure_s"])
        entries.append(entry)
    atomic_write_bytes(folder / "set.toml", tomli_w.dumps({"capture": entries}).encode())
    return folder
