"""The error boundary's file check: no command writes over a file it reads.

Before a command runs, :func:`check_declared_files` gathers every file it reads and every path it writes from its
declared arguments (:mod:`lowcam.arguments`), expanded to what is actually read: the files a measurement set's
``set.toml`` or a calibration manifest names, the frames a glob or a ``#`` pattern matches, a profile given by name
resolved to its file. It refuses, as one line naming the option and both files, a written path that is the same
file as a read one (same real path, a symbolic link, a hard link: same inode), an output folder that holds a file
the command reads, and two outputs that are the same file. Inputs are what a command reads, not everything in a
folder: a report written into a set's folder is no input of the next run. A file that is not there yet, or an
argument the command itself will refuse (a bad pattern, an unknown profile), is left to the command.

Contents
--------
- :data:`FRAME_SUFFIXES`: the image files a folder of frames is read for
- :class:`Named`: one path of a command, with the option that named it
- :func:`chosen_actions`: the argparse actions of the sub-commands ``args`` was parsed with
- :func:`command_name`: the command ``args`` was parsed for (``lowcam profile from-dng``)
- :func:`read_files`: the files one read argument names, expanded by its kind
- :func:`written_paths`: the paths one written argument names, expanded by its kind
- :func:`check_declared_files`: refuse a command whose output is one of its inputs, before any work
"""
from __future__ import annotations

import argparse
import functools
import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

from .batch import expand_pattern, parse_frames
from .calibrate import CALIBRATIONS
from .errors import LowcamError
from .profile import find_profile
from .schema import read_toml

#: Image files a folder of frames is read for (a folder's other files are no input).
FRAME_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr"}


@dataclass(frozen=True)
class Named:
    """One path of a command: ``path`` as the user (or a manifest) named it, ``option`` the argument that named it
    (``--json``, ``SET``), ``dest`` that argument's ``dest``, ``kind`` the declared kind."""

    path: str
    option: str
    dest: str
    kind: str = "file"


def chosen_actions(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[argparse.Action]:
    """The actions of ``parser`` and of each sub-command ``args`` was parsed with (``calibrate``, then ``plate``)."""
    return [a for p in _chosen_parsers(parser, args) for a in p._actions
            if not isinstance(a, argparse._SubParsersAction)]


def _chosen_parsers(parser, args):
    while parser is not None:
        yield parser
        sub = None
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                sub = action.choices.get(getattr(args, action.dest, None) or "")
        parser = sub


def command_name(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The command ``args`` was parsed for, as its parser names it (``lowcam profile from-dng``)."""
    return list(_chosen_parsers(parser, args))[-1].prog


def _option(action: argparse.Action) -> str:
    return action.option_strings[0] if action.option_strings else action.metavar or action.dest.upper()


def _glob(pattern: str) -> list[str]:
    if glob.has_magic(pattern):
        return sorted(glob.glob(pattern))
    return [pattern]


def _frames_in(folder: Path) -> list[str]:
    try:
        return sorted(str(p) for p in folder.iterdir() if p.suffix.lower() in FRAME_SUFFIXES and p.is_file())
    except OSError:
        return []


def _toml(path: Path) -> dict:
    try:
        return read_toml(path)
    except LowcamError:
        return {}


def _set_files(value: str) -> list[str]:
    """set.toml and the frames, ideals, plates and masks it names (relative to the set's folder)."""
    folder = Path(value)
    toml_path = folder / "set.toml" if folder.is_dir() else folder
    folder = toml_path.parent
    out = [str(toml_path)]
    captures = _toml(toml_path).get("capture", [])
    for entry in captures if isinstance(captures, list) else []:
        if not isinstance(entry, dict):
            continue
        for key in ("ideal", "plate", "mask"):
            if isinstance(entry.get(key), str) and entry[key]:
                out.append(str(folder / entry[key]))
        frames = entry.get("frames", [])
        for pattern in [frames] if isinstance(frames, str) else frames if isinstance(frames, list) else []:
            if isinstance(pattern, str) and pattern:
                out.extend(sorted(glob.glob(str(folder / pattern))))
    return out


def _manifest_files(value: str) -> list[tuple[str, str]]:
    """(path, dest) of a calibration manifest and every file it names; its ``profile`` counts as ``--profile``."""
    path = Path(value)
    doc = _toml(path)
    out = [(str(path), "manifest")]
    if isinstance(doc.get("profile"), str) and doc["profile"]:
        out.extend((p, "profile") for p in _profile_file(doc["profile"]))
    for name, calibrator in CALIBRATIONS.items():
        section = doc.get(name)
        if not isinstance(section, dict):
            continue
        for option in calibrator.options:
            entry = section.get(option.key)
            if option.kind not in ("frames", "path") or entry is None:
                continue
            for item in [entry] if isinstance(entry, str) else entry if isinstance(entry, list) else []:
                if isinstance(item, str) and item:
                    out.extend((p, "manifest") for p in _glob(str(path.parent / item)))
    return out


def _profile_file(name: str) -> list[str]:
    try:
        return [str(find_profile(name))]
    except LowcamError:
        return []


def _frame_set(args) -> frozenset[int] | None:
    spec = getattr(args, "frames", None)
    return _frames_of(spec) if isinstance(spec, str) else None


@functools.lru_cache(maxsize=4)
def _frames_of(spec: str) -> frozenset[int] | None:
    try:
        return frozenset(parse_frames(spec))
    except LowcamError:
        return None


#: The frame number of a pattern: its last run of ``#``, or a ``%d`` (``%04d``).
_FRAME_FIELD = re.compile(r"#+(?!.*#)|%0?\d*d")


def _pattern_paths(pattern: str, args, folder_default: bool) -> list[str]:
    """The files that exist of a ``#`` (or ``%d``) pattern filled in for each of ``args.frames`` (only a file that
    is there can be the same file as another); without a frame field, the pattern itself (a video), or with
    ``folder_default`` the folder's ``####.png`` (``render -o FOLDER``). The folder is listed once, not each of a
    shot's frames looked up."""
    if "#" not in pattern and "%" not in pattern:
        if not folder_default:
            return [pattern]
        pattern = str(Path(pattern) / "####.png")
    fields = list(_FRAME_FIELD.finditer(pattern))
    if not fields:
        return []
    m = fields[-1]
    head, tail = pattern[:m.start()], pattern[m.end():]
    there = glob.glob(glob.escape(head) + "*" + glob.escape(tail))
    frames = _frame_set(args) if there else None
    if frames is None:
        return []
    number = re.compile(re.escape(head) + r"(-?\d+)" + re.escape(tail) + r"\Z")
    out = []
    for path in there:
        found = number.match(path)
        if found is None or int(found.group(1)) not in frames:
            continue
        try:
            if expand_pattern(pattern, int(found.group(1))) == path:
                out.append(path)
        except LowcamError:
            return []
    return sorted(out)


def read_files(action: argparse.Action, value, args) -> list[Named]:
    """The files that ``value`` of the read argument ``action`` names, expanded by its kind (see the module)."""
    kind, option = action.type.kind, _option(action)
    out: list[Named] = []
    for item in value if isinstance(value, list) else [value]:
        if not isinstance(item, str) or not item:
            continue
        p = Path(item)
        if kind == "profile":
            paths = [(f, action.dest) for f in _profile_file(item)]
        elif kind == "set":
            paths = [(f, action.dest) for f in _set_files(item)]
        elif kind == "manifest":
            paths = _manifest_files(item)
        elif kind == "pattern":
            paths = [(f, action.dest) for f in _pattern_paths(item, args, folder_default=False)]
        elif p.is_dir() and kind in ("folder", "footage", "files", "glob"):
            paths = [(f, action.dest) for f in _frames_in(p)] if kind != "folder" else \
                [(str(f), action.dest) for f in sorted(p.iterdir()) if f.is_file()]
        elif kind in ("glob", "footage", "files"):
            paths = [(f, action.dest) for f in _glob(item)]
        else:
            paths = [(item, action.dest)]
        out.extend(Named(f, option, dest, kind) for f, dest in paths)
    return out


def written_paths(action: argparse.Action, value, args) -> list[Named]:
    """The paths that ``value`` of the written argument ``action`` names: the file, the folder, or a pattern's
    file for each of ``args.frames``."""
    if not isinstance(value, str) or not value:
        return []
    kind, option = action.type.kind, _option(action)
    if kind == "pattern":
        return [Named(f, option, action.dest) for f in _pattern_paths(value, args, folder_default=True)]
    return [Named(value, option, action.dest, kind)]


@functools.lru_cache(maxsize=4096)
def _real_folder(folder: str) -> str:
    return os.path.realpath(folder or ".")


def _real(path: str) -> str:
    """The real path of ``path``, its folder resolved once for many files (a pattern's frames share one)."""
    head, tail = os.path.split(path)
    return os.path.join(_real_folder(head), tail) if tail not in ("", ".", "..") else os.path.realpath(path)


def _identity(path: str):
    """The file ``path`` is: (device, inode) of what it points to, or its real path if it is not there. A path
    through a folder that does not exist yet and back out of it (``new/../clip.mp4``) is the file its real path
    names: writing it makes the folder, and then reaches that file."""
    for p in (path, _real(path)):
        try:
            st = os.stat(p)
            return ("inode", st.st_dev, st.st_ino)
        except (OSError, ValueError):
            continue
    return ("path", _real(path))


def _inside(path: str, folder: str) -> bool:
    real, top = _real(path), _real_folder(folder)
    return real != top and real.startswith(top.rstrip(os.sep) + os.sep)


def check_declared_files(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse, before any work, a command that would write over a file it reads (or write two outputs to one file):
    one :class:`~lowcam.errors.LowcamError` naming the output, its option and the input. Outputs come from every
    :class:`~lowcam.arguments.Writes` argument and from ``args.also_writes(args)`` (outputs a command derives,
    such as a chart's layout beside it); inputs from every :class:`~lowcam.arguments.Reads` argument. A written
    argument's ``replaces`` names inputs it may replace on purpose (``calibrate -o`` updating ``--profile``)."""
    _real_folder.cache_clear()  # folders may have changed since the last command of this process
    reads: list[Named] = []
    writes: list[tuple[Named, tuple[str, ...]]] = []
    for action in chosen_actions(parser, args):
        role = getattr(action.type, "role", None)
        value = getattr(args, action.dest, None)
        if role == "reads":
            reads.extend(read_files(action, value, args))
        elif role == "writes":
            writes.extend((n, action.type.replaces) for n in written_paths(action, value, args))
    derived = getattr(args, "also_writes", None)
    if callable(derived):
        writes.extend((n, ()) for n in derived(args))
    inputs: dict = {}
    for r in reads:
        if os.path.lexists(r.path):
            inputs.setdefault(_identity(r.path), r)
    outputs: dict = {}
    for w, replaces in writes:
        if w.kind == "folder":
            for r in reads:
                if _inside(r.path, w.path):
                    raise LowcamError(f"{w.path}: the {w.option} folder holds the input {r.path} ({r.option}); "
                                      f"choose another {w.option}")
        key = _identity(w.path)
        r = inputs.get(key)
        if r is not None and r.dest not in replaces:
            which = "this input" if os.path.abspath(r.path) == os.path.abspath(w.path) else \
                f"the input {r.path}" + (" (a link to it)" if os.path.islink(w.path) or os.path.islink(r.path)
                                         else "")
            raise LowcamError(f"{w.path}: {w.option} would replace {which} of {r.option}; choose another {w.option}")
        other = outputs.setdefault(key, w)
        if other is not w and other.option != w.option:
            raise LowcamError(f"{w.path}: {w.option} and {other.option} name the same file; give each its own")
