"""A generative fuzz suite: every option of every ``lowcam`` command, bad and borderline values made by what the
option declares (:mod:`lowcam.arguments`), with Hypothesis.

The commands and options come from ``lowcam.cli.build_parser()`` itself (through
:func:`lowcam.arguments.declared`), the Blender side's included, so a command is covered the day it is added:
:func:`test_every_command_and_option_has_a_strategy` fails for a command without a baseline
(``fuzz_baselines.py``) or an option whose declaration no strategy knows. For each option, values are drawn by its
declaration:

- :class:`~lowcam.arguments.Reads` (by kind): a missing path, a folder where a file is wanted and a file where a
  folder is, a FIFO, ``/dev/null``, endless devices, a dangling symlink; the valid input emptied, truncated,
  replaced by binary garbage or by another format, bytes flipped, valid but extreme; a set or manifest naming
  missing files; a glob matching nothing; a profile name nobody has;
- :class:`~lowcam.arguments.Writes`: the command's inputs themselves (as typed, through a symlink, a hard link),
  an existing folder, a FIFO, a parent that is a file, a location nobody can write (``/proc``), an existing
  folder Lowcam did not make, a wrong suffix, another output of the same command; and valid ones (new nested
  folders, an existing file of one's own, an upper-case suffix);
- :class:`~lowcam.arguments.Number` and :class:`~lowcam.arguments.Numbers`: 0, negatives, NaN, infinities, huge,
  just outside the declared range, the bounds themselves, text that is no number, Hypothesis's own floats;
- :class:`~lowcam.arguments.Text`: each choice, near misses, empty, long, multi-line and non-ASCII text.

Each value runs the command with every other argument from the command's cheap valid baseline, in a folder of its
own holding copies of the inputs. The contract (``docs/refusals.md``): exit status 2 and exactly one line on
stderr naming the fuzzed option or its value (a value inside its declared range may instead run: exit 0, having
written its outputs); never a traceback; no input's bytes changed, FIFOs still FIFOs; no ``.lowcam-*.part``
temporary and, after a refusal, no new file or folder anywhere. A refusal that comes after work may follow
Lowcam's own progress lines (``[2/6] fitting ...``; stderr is no terminal here). Runs happen in-process
(``lowcam.cli.main`` under ``capfd``, the address space capped) except Blender-side commands and endless devices,
which run as a process with a timeout and a memory limit.

Tiers: :func:`test_fuzz_fast` is a seeded slice (Hypothesis ``derandomize``, two values an option, no run of a
slow command with a value it accepts, Blender-side commands parsed only) in the fast tier: about 25 s on a busy
2-core machine. :func:`test_fuzz_full` draws 3 to 16 values an option by its command's cost, runs everything
(accepted values of runs over :data:`NEVER_RUN_S` only parsed) and is marked slow (and blender where it runs
Blender): 2 to 3.5 minutes there. Both are seeded: a failure is the same failure on every run.
``LOWCAM_FUZZ_EXAMPLES`` raises the full run's most values an option; ``LOWCAM_FUZZ_LOG=FILE`` logs every run.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import re
import resource
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pytest
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

import fuzz_baselines as fb
from lowcam.arguments import Number, Numbers, Reads, Text, Writes, declared
from lowcam.cli import build_parser
from test_fuzz_cli import run_in_process, run_subprocess, snapshot, traceback_summary

PARSER = build_parser()
#: accepted values of a command whose whole run costs more than this (s) are left to the slow tier
FAST_RUN_S = 1.0
#: accepted values of a command whose whole run costs more than this (s) are only parsed, in every tier
NEVER_RUN_S = 10.0
FAST = settings(max_examples=2, derandomize=True, deadline=None, database=None, print_blob=False,
                suppress_health_check=list(HealthCheck))
#: the full run's examples of an option: about FULL_BUDGET_S of runs of its command's cost, within FULL_EXAMPLES
FULL_EXAMPLES = (3, int(os.environ.get("LOWCAM_FUZZ_EXAMPLES", "16")))
FULL_BUDGET_S = 4.0
#: a value's run in-process may use this much more address space (GiB) before MemoryError
MEMORY_GIB = 6.0


# --- the options, from the parser ----------------------------------------------------------------------------------

def _is_help(action) -> bool:
    return isinstance(action, argparse._HelpAction) or action.dest == "debug"


def _leaves(parser=PARSER, path=()):
    """(command path, its parser) of every command that runs (no sub-commands below it)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    seen = set()
    for name, sub in subs[0].choices.items():
        if id(sub) not in seen:
            seen.add(id(sub))
            yield from _leaves(sub, path + (name,))


COMMANDS = dict(_leaves())


@dataclass(frozen=True)
class Option:
    """One option of one command: its path (``("calibrate", "plate")``), argparse action and declaration."""

    command: tuple[str, ...]
    action: argparse.Action
    decl: object

    @property
    def flag(self) -> bool:
        return self.action.nargs == 0

    @property
    def name(self) -> str:
        return (self.action.option_strings or [self.action.dest])[-1]

    def __str__(self) -> str:
        return " ".join(self.command + (self.name,))


def all_options() -> list[Option]:
    """Every option (flags included, help and --debug not) of every command that runs."""
    return [Option(path, action, decl) for path, action, decl in declared(PARSER)
            if path in COMMANDS and not _is_help(action)]


# --- values ---------------------------------------------------------------------------------------------------------

REFUSE, EITHER, PARSE = "refuse", "either", "parse"


@dataclass(frozen=True)
class Value:
    """A value for one option. ``make(example)`` writes what it needs into the example's ``fuzz/`` folder and
    returns the option's value (a list of text; ``True`` for a flag). ``expect``: ``refuse`` (exit 2 naming the
    option or file), ``either`` (exit 0, or a refusal naming it) or ``parse`` (valid but too costly to run here:
    the parser must take it). ``at_parse``: refused by parsing alone (checked without a run for Blender-side
    commands in the fast tier). ``costly``: slow tier only. ``process``: run as a process (an endless device).
    ``in_process``: no process can be given it (a NUL character). ``needs_file``: made from the option's valid
    input file (a profile given by name is given as its file for it)."""

    label: str
    make: Callable
    expect: str = REFUSE
    at_parse: bool = False
    costly: bool = False
    process: bool = False
    in_process: bool = False
    needs_file: bool = False

    def __repr__(self) -> str:
        return self.label


def fixed(label: str, values, expect=REFUSE, **kw) -> Value:
    """A value that needs no file: ``values`` (text or a list of text) as given."""
    items = [values] if isinstance(values, str) else list(values)
    return Value(label, lambda ex: items, expect, **kw)


@dataclass
class Example:
    """One run's folder: ``in/`` (copies of the baseline's inputs), ``out/`` (the baseline's outputs), ``fuzz/``
    (what the value makes). ``args``: the baseline's arguments with ``{in}``/``{out}`` filled in; ``made``: the
    fuzzed option's value."""

    folder: Path
    option: Option
    baseline: fb.Baseline
    args: dict = field(default_factory=dict)
    made: list = field(default_factory=list)

    @property
    def inp(self) -> Path:
        return self.folder / "in"

    @property
    def out(self) -> Path:
        return self.folder / "out"

    @property
    def fuzz(self) -> Path:
        return self.folder / "fuzz"

    def valid(self) -> list[str]:
        """The option's valid value in the baseline (``[]`` if it has none)."""
        v = self.args.get(self.option.action.dest)
        return list(v) if isinstance(v, list) else []

    def valid_file(self) -> Path | None:
        """The first existing file the option's valid value names (a glob expanded; a folder's first file)."""
        for text in self.valid():
            pattern = Path(re.sub("#+", "*", text))
            for p in sorted(pattern.parent.glob(pattern.name)) if "*" in pattern.name else [Path(text)]:
                if p.is_file():
                    return p
                if p.is_dir():
                    files = sorted(q for q in p.rglob("*") if q.is_file())
                    if files:
                        return files[0]
        return None

    def inputs(self) -> list[Path]:
        """The files the baseline reads, as typed: every file its reads-options name (a set's set.toml and what
        it names, a profile by name, a glob's matches, a pattern's frames, a manifest)."""
        found = []
        parser = COMMANDS[self.option.command]
        for action in parser._actions:
            decl = getattr(action.type, "role", None) and action.type
            values = self.args.get(action.dest)
            if not isinstance(decl, Reads) or not isinstance(values, list):
                continue
            for text in values:
                found += _files_named(text, decl.kind, self)
        return list(dict.fromkeys(found))

    def outputs(self) -> dict[str, str]:
        """dest -> the baseline's value of each writes-option other than the fuzzed one."""
        parser = COMMANDS[self.option.command]
        return {a.dest: self.args[a.dest][0] for a in parser._actions
                if isinstance(getattr(a.type, "role", None) and a.type, Writes) and isinstance(self.args.get(a.dest),
                                                                                                list)
                and self.args[a.dest] and a.dest != self.option.action.dest}

    def path(self, name: str) -> Path:
        self.fuzz.mkdir(parents=True, exist_ok=True)
        return self.fuzz / name


def _files_named(text: str, kind: str, ex: Example) -> list[Path]:
    """The files a reads-value names (for "the output is an input" values)."""
    if kind == "profile" and not text.endswith(".toml") and "/" not in text:
        p = ex.inp / "profiles" / f"{text}.toml"
        return [p] if p.is_file() else []
    p = Path(text)
    if "#" in text:
        return sorted(p.parent.glob(re.sub("#+", "*", p.name)))
    if "*" in text:
        return sorted(p.parent.glob(p.name))
    if p.is_file():
        if kind == "manifest":
            return [p] + sorted(q for q in p.parent.rglob("*") if q.is_file() and q != p)
        return [p]
    if p.is_dir():
        if (p / "set.toml").is_file():
            return [p / "set.toml"] + sorted(q for q in p.rglob("*") if q.is_file() and q.name != "set.toml"
                                             and q.name != "history.json")
        return sorted(q for q in p.rglob("*") if q.is_file())
    return []


# --- strategies by declaration --------------------------------------------------------------------------------------

def _num_text(x) -> str:
    return repr(x) if isinstance(x, float) else str(x)


def _parse_ok(decl: Number, text: str):
    """The reference reading of ``text`` by a :class:`Number`: the value, or None when it must be refused."""
    try:
        value = int(text.strip()) if decl.integer else float(text)
    except (TypeError, ValueError):
        return None
    if not decl.integer and not math.isfinite(value):
        return None
    try:
        decl.check(value)
    except argparse.ArgumentTypeError:
        return None
    return value


def number_value(decl: Number, text: str, cap=None, label: str = "") -> Value:
    value = _parse_ok(decl, text)
    label = label or f"{text!r}"
    if value is None:
        return fixed(label, text, REFUSE, at_parse=True)
    if cap is not None and value > cap:
        return fixed(label, text, PARSE)
    return fixed(label, text, EITHER)


def number_strategy(decl: Number, cap=None) -> st.SearchStrategy:
    """Bad and borderline numbers for a :class:`Number`, each classified by the declared range."""
    texts = ["nan", "0", "-1", "inf", "-inf", "1e308", "-1e308", "1e309", "", "abc", "1,5", "0x10", " 3 ", "1e3",
             "+5", "1_000", "\u0663", "NaN", "Infinity", str(2 ** 64), str(-2 ** 63), str(10 ** 30), "2.5"]
    edges = []
    for bound, side in ((decl.low, -1), (decl.high, +1)):
        if bound is None:
            continue
        edges.append(_num_text(bound))
        if decl.integer:
            edges += [str(bound + side), str(bound - side)]
        else:
            out, inside = math.nextafter(bound, side * math.inf), math.nextafter(bound, -side * math.inf)
            edges += [_num_text(out), _num_text(inside), _num_text(bound + side * max(1.0, abs(bound)) * 1e-6)]
    fixed_values = [number_value(decl, t, cap) for t in dict.fromkeys(texts + edges)]
    generated = (st.integers(min_value=-2 ** 70, max_value=2 ** 70).map(str) if decl.integer else
                 st.floats(allow_nan=True, allow_infinity=True).map(_num_text))
    near = [st.floats(min_value=b - 1.0, max_value=b + 1.0).map(_num_text) for b in (decl.low, decl.high)
            if b is not None and not decl.integer]
    return st.one_of(st.sampled_from(fixed_values),
                     st.one_of(generated, *near).map(lambda t: number_value(decl, t, cap, f"drawn {t}")))


def numbers_strategy(decl: Numbers) -> st.SearchStrategy:
    """Comma-separated numbers: wrong counts, one bad component, each component's edges."""
    def value(parts) -> Value:
        text = ",".join(parts)
        ok = len(parts) == decl.count and all(_parse_ok(item, p) is not None for item, p in zip(decl.items, parts))
        return fixed(repr(text), text, EITHER if ok else REFUSE, at_parse=not ok)

    good = ["0"] * decl.count
    cases = [good, good[:-1], good + ["0"], [""] * decl.count, ["a"] * decl.count]
    for k, item in enumerate(decl.items):
        for bad in ("nan", "inf", "-inf", "1e308"):
            cases.append(good[:k] + [bad] + good[k + 1:])
        for bound, side in ((item.low, -1), (item.high, 1)):
            if bound is not None:
                cases.append(good[:k] + [_num_text(bound)] + good[k + 1:])
                cases.append(good[:k] + [_num_text(bound + side * max(1.0, abs(bound)))] + good[k + 1:])
    drawn = st.lists(st.floats(allow_nan=True, allow_infinity=True).map(_num_text), min_size=decl.count - 1,
                     max_size=decl.count + 1)
    return st.one_of(st.sampled_from([value(c) for c in cases]), drawn.map(value))


#: a NUL character: refused by parsing (no process can even be given it)
NUL = fixed("a NUL character", "a\0b", REFUSE, at_parse=True, in_process=True)
#: text that is no module name (so a --plugin value never imports a real module) and breaks naive parsing
_ODD_TEXTS = ["", " ", "\u2603" * 3, "a\nb", "x" * 5000, "-", "--", "\t", "../..", "%s%n{0}", "\u00e9\u2713 \u00fc",
              "\u2603:\u2603", "\u2603.\u2603:X"]


def text_strategy(decl: Text) -> st.SearchStrategy:
    if decl.choices:
        values = [fixed(repr(c), c, EITHER) for c in decl.choices]
        for c in decl.choices:
            for near in (c.upper(), c + " ", c[:-1], c + "x"):
                if near not in decl.choices:
                    values.append(fixed(repr(near), near, REFUSE, at_parse=True))
        values += [fixed("empty", "", REFUSE, at_parse=True), fixed("unknown", "\u2603nosuch", REFUSE, at_parse=True),
                   NUL]
        return st.sampled_from(values)
    values = [fixed(repr(t[:20]), t, EITHER) for t in _ODD_TEXTS] + [NUL]
    drawn = st.text(min_size=1, max_size=40).filter(lambda t: "\0" not in t).map(lambda t: "\u2603" + t)
    return st.one_of(st.sampled_from(values), drawn.map(lambda t: fixed(f"drawn {t!r}", t, EITHER)))


# --- paths ------------------------------------------------------------------------------------------------------------

def _suffix(ex: Example, default: str = ".dat") -> str:
    f = ex.valid_file()
    return f.suffix if f is not None else default


def _with_valid(ex: Example, replace_first: Callable[[Path], str]) -> list[str]:
    """The option's valid value with its first item replaced by ``replace_first(path)``: the folder it names, or
    its first file."""
    items = ex.valid()
    f = Path(items[0]) if items and Path(items[0]).is_dir() else ex.valid_file()
    assert f is not None, f"{ex.option}: the baseline gives it no valid file"
    return [replace_first(f)] + items[1:]


def _content(label: str, data: Callable[[bytes, Path], bytes], expect=REFUSE) -> Value:
    """The valid input's bytes changed by ``data(bytes, path)``, written into ``fuzz/`` under the same suffix."""
    def make(ex: Example):
        def write(f: Path) -> str:
            p = ex.path(f"{f.stem}-{label.split()[0]}{f.suffix}")
            p.write_bytes(data(f.read_bytes(), f))
            return str(p)
        return _replace_in_value(ex, write)
    return Value(label, make, expect, needs_file=True)


def _replace_in_value(ex: Example, write: Callable[[Path], str]) -> list[str]:
    """Replace the valid file inside the option's value: the value itself for a file, the file inside a folder
    (copied into ``fuzz/``, the copy's path returned) for folders, sets and footage."""
    f = ex.valid_file()
    assert f is not None, f"{ex.option}: the baseline gives it no valid file"
    items = ex.valid()
    first = Path(items[0]) if "*" not in items[0] and "#" not in items[0] else None
    if first is not None and first.is_dir():
        copy = ex.path(first.name)
        shutil.copytree(first, copy)
        target = copy / f.relative_to(first)
        changed = Path(write(f))
        target.unlink()
        shutil.move(changed, target)
        return [str(copy)] + items[1:]
    if first is None:  # a glob or pattern: the bad file joins the valid ones, as a careless user's extra file does
        return [write(f)] + items if ex.option.action.nargs in ("+", "*") else [write(f)]
    return [write(f)] + items[1:]


def _fifo(ex: Example, name: str) -> str:
    p = ex.path(name)
    os.mkfifo(p)
    return str(p)


def _garbage(seed_bytes: bytes) -> Callable[[bytes, Path], bytes]:
    return lambda data, f: b"\xff\xfe\x00" + seed_bytes


def _truncate(fraction: float) -> Callable[[bytes, Path], bytes]:
    return lambda data, f: data[:max(1, min(len(data) - 1, int(len(data) * fraction)))]


def _flip(positions: list[int]) -> Callable[[bytes, Path], bytes]:
    def change(data: bytes, f: Path) -> bytes:
        b = bytearray(data)
        for p in positions:
            b[p % len(b)] ^= 0xFF
        return bytes(b)
    return change


_TEXT_SUFFIXES = {".toml", ".json", ".csv", ".txt"}


def _other_format(data: bytes, f: Path) -> bytes:
    """Bytes of another format than ``f``'s: a PNG for text files, TOML for binary ones."""
    if f.suffix.lower() in _TEXT_SUFFIXES:
        return next((fb.ROOT / "lowcam" / "data").glob("*.png")).read_bytes()[:4096]
    return (fb.ROOT / "profiles" / "fire-i.toml").read_bytes()


def _extreme(data: bytes, f: Path) -> bytes:
    """A valid file of the same kind with extreme content: a tiny image, text padded with a million blanks."""
    s = f.suffix.lower()
    if s in (".png", ".jpg", ".jpeg", ".tif", ".tiff"):
        import cv2
        import numpy as np

        return cv2.imencode(s if s != ".jpeg" else ".jpg", np.full((2, 2, 3), 255, np.uint8))[1].tobytes()
    if s == ".exr":
        import numpy as np

        from lowcam.outputs import write_exr

        tmp = f.parent / f".fuzz-tiny-{os.getpid()}.exr"
        write_exr(tmp, np.full((2, 2, 4), 6e4, np.float32))
        try:
            return tmp.read_bytes()
        finally:
            tmp.unlink()
    if s in _TEXT_SUFFIXES:
        pad = {".toml": b"#", ".csv": b"#", ".json": b" "}.get(s, b" ")
        return data + b"\n" + (pad + b" " * 99 + b"\n") * 10000
    return data + bytes(1 << 20)


def common_path_values() -> list[Value]:
    """Path values that name nothing usable, for any input."""
    return [
        Value("missing", lambda ex: [str(ex.path("missing" + _suffix(ex)))]),
        Value("dangling symlink", lambda ex: [_symlink(ex.path("dangling" + _suffix(ex)), ex.path("nowhere"))]),
        Value("FIFO", lambda ex: [_fifo(ex, "pipe" + _suffix(ex))]),
        fixed("/dev/null", "/dev/null"),
        fixed("empty path", "", at_parse=True),
        NUL,
        Value("symlink to the valid input", lambda ex: _with_valid(
            ex, lambda f: _symlink(ex.path("link" + f.suffix), f)), EITHER, needs_file=True),
        Value("a name with spaces and accents", lambda ex: _with_valid(
            ex, lambda f: _copy(f, ex.path("my caf\u00e9 " + f.name))), EITHER, needs_file=True),
        Value("/dev/zero", lambda ex: ["/dev/zero"], process=True, costly=True),
        Value("/dev/urandom", lambda ex: ["/dev/urandom"], process=True, costly=True),
    ]


def _copy(src: Path, dst: Path) -> str:
    (shutil.copytree if src.is_dir() else shutil.copyfile)(src, dst)
    return str(dst)


def _symlink(link: Path, target: Path) -> str:
    link.symlink_to(target)
    return str(link)


def content_values() -> list[Value]:
    """The valid input's bytes, damaged."""
    return [
        _content("empty", lambda data, f: b""),
        _content("truncated to half", _truncate(0.5), EITHER),
        _content("truncated to 7 bytes", lambda data, f: data[:7]),
        _content("another format", _other_format),
        _content("valid but extreme", _extreme, EITHER),
    ]


def content_strategy() -> st.SearchStrategy:
    garbage = st.binary(min_size=0, max_size=2048).map(
        lambda b: _content(f"garbage {len(b) + 3} bytes", _garbage(b)))
    cut = st.floats(min_value=0.0, max_value=1.0).map(
        lambda x: _content(f"truncated to {x:.3f}", _truncate(x), EITHER))
    flips = st.lists(st.integers(min_value=0, max_value=2 ** 20), min_size=1, max_size=8).map(
        lambda ps: _content(f"flipped bytes at {ps}", _flip(ps), EITHER))
    return st.one_of(garbage, cut, flips)


def folder_values() -> list[Value]:
    """Values for an input that is a folder (a set, footage, a folder of frames)."""
    def trailing_slash(ex):
        return [ex.valid()[0].rstrip("/") + "/"] + ex.valid()[1:]

    return [Value("a file, not a folder", lambda ex: [_plain_file(ex)]),
            Value("an empty folder", lambda ex: [_folder(ex, "empty")]),
            Value("a folder of other files", lambda ex: [_folder(ex, "holiday", {"notes.txt": "mine\n"})]),
            Value("the valid folder with a trailing slash", trailing_slash, EITHER)]


def set_values() -> list[Value]:
    """A measurement set whose ``set.toml`` is broken or names what is not there."""
    def changed_set(label, change, expect=REFUSE):
        def make(ex):
            src = Path(ex.valid()[0])
            copy = ex.path("myset")
            shutil.copytree(src, copy)
            change(copy)
            return [str(copy)]
        return Value(label, make, expect)

    def no_set_toml(p):
        (p / "set.toml").unlink()

    def missing_frame(p):
        for f in (p / "frames").glob("*"):
            f.unlink()

    def missing_ideal(p):
        for f in (p / "ideal").glob("*"):
            f.unlink()

    def foreign_file(p):
        (p / "notes.txt").write_text("my notes\n")

    def outside(p):
        """set.toml naming a frame outside the set's folder (allowed: it is read, never written)."""
        text = (p / "set.toml").read_text()
        frame = next((p / "frames").glob("*"))
        moved = p.parent / ("outside-" + frame.name)
        shutil.move(frame, moved)
        (p / "set.toml").write_text(text.replace('"frames/a-*.png"', f'"{moved}"'))

    return [changed_set("set.toml missing", no_set_toml), changed_set("set.toml empty",
                                                                      lambda p: (p / "set.toml").write_text("")),
            changed_set("set.toml garbage", lambda p: (p / "set.toml").write_bytes(b"\xff\xfe\x00[[[")),
            changed_set("a frame missing", missing_frame), changed_set("the ideal missing", missing_ideal),
            changed_set("a foreign file in the set", foreign_file, EITHER),
            changed_set("a frame outside the set folder", outside, EITHER)]


def glob_values() -> list[Value]:
    def nothing(ex):
        return [str(ex.path("nothing") / "*.png")]

    def plus_missing(ex):
        return ex.valid() + [str(ex.path("missing.png"))]

    def plus_folder(ex):
        p = ex.path("a-folder")
        p.mkdir()
        return ex.valid() + [str(p)]

    def plus_empty(ex):
        p = ex.path("empty.png")
        p.write_bytes(b"")
        return ex.valid() + [str(p)]

    return [Value("a glob matching nothing", nothing), Value("one more, missing", plus_missing),
            Value("one more, an empty folder", plus_folder), Value("one more, an empty file", plus_empty)]


def pattern_values() -> list[Value]:
    def no_hash(ex):
        return [re.sub("#+", "0001", ex.valid()[0])]

    def no_frames(ex):
        return [str(ex.path("none") / "####.exr")]

    def frame_empty(ex):
        src = Path(ex.valid()[0])
        copy = ex.path("frames")
        shutil.copytree(src.parent, copy)
        for f in copy.iterdir():
            f.write_bytes(b"")
        return [str(copy / src.name)]

    return [Value("a frame pattern without #", no_hash, EITHER), Value("a pattern matching no frame", no_frames),
            Value("every frame empty", frame_empty)]


def profile_values() -> list[Value]:
    return [fixed("an unknown profile name", "\u2603nosuchcam"), fixed("a bundled profile", "fire-i", EITHER),
            fixed("the name in capitals", "FUZZCAM", EITHER),
            Value("the profile as a path", lambda ex: [str(ex.inp / "profiles" / "fuzzcam.toml")], EITHER)]


def manifest_values() -> list[Value]:
    def naming_missing(ex):
        src = Path(ex.valid()[0])
        p = ex.path("manifest.toml")
        p.write_text(src.read_text().replace("flat/*.png", "nothing/*.png"))
        return [str(p)]

    def unknown_section(ex):
        p = ex.path("manifest.toml")
        p.write_text(Path(ex.valid()[0]).read_text() + "\n[nosuch]\nframes = ['x.png']\n")
        return [str(p)]

    return [Value("a manifest naming no file", naming_missing), Value("a manifest with an unknown section",
                                                                      unknown_section)]


def _profile_file(ex: Example) -> None:
    """For a profile option: make its valid value the profile's file, so that content damage has a file."""
    if ex.valid() and not ex.valid()[0].endswith(".toml"):
        ex.args[ex.option.action.dest] = [str(ex.inp / "profiles" / f"{ex.valid()[0]}.toml")]


def reads_strategy(decl: Reads) -> st.SearchStrategy | None:
    kinds = {"file": [], "folder": folder_values(), "set": folder_values() + set_values(),
             "footage": folder_values(), "glob": glob_values(), "files": glob_values(), "pattern": pattern_values(),
             "profile": profile_values(), "manifest": manifest_values()}
    if decl.kind not in kinds:
        return None
    return st.one_of(st.sampled_from(common_path_values() + kinds[decl.kind] + content_values()), content_strategy())


# --- outputs --------------------------------------------------------------------------------------------------------

def _an_input(ex: Example, k: int) -> Path | None:
    found = ex.inputs()
    return found[k % len(found)] if found else None


def writes_values(decl: Writes) -> list[Value]:
    suffix = decl.suffixes[0] if decl.suffixes else ""
    name = {"file": f"result{suffix}", "folder": "results", "pattern": f"####{suffix or '.png'}"}[decl.kind]

    def onto_input(how: str):
        def make(ex: Example, k: int = 0):
            target = _an_input(ex, k)
            if target is None:  # a command that reads nothing
                reject()
            if decl.kind == "folder":
                target = target.parent
            if how == "symlink":
                return [_symlink(ex.path("link-" + target.name), target)]
            if how == "hard link":
                link = ex.path("hard-" + target.name)
                os.link(target, link)
                return [str(link)]
            if decl.kind == "pattern":
                return [str(target.parent / re.sub(r"\d{4}", "####", target.name))]
            return [str(target)]
        return make

    def existing_folder(ex):
        return [_folder(ex, "a-folder" + (suffix if decl.kind == "file" else ""), {"keep.txt": "mine\n"})]

    def parent_is_a_file(ex):
        return [str(Path(_plain_file(ex)) / name)]

    def nested(ex):
        return [str(ex.path("new") / "nested" / "folders" / name)]

    def own_file(ex):
        p = ex.path(name.replace("####", "0001"))
        p.write_bytes(b"an earlier result of mine\n")
        return [str(p if decl.kind == "file" else p.parent / name)]

    def another_output(ex):
        others = ex.outputs()
        if not others:
            reject()
        return [next(iter(others.values()))]

    def inputs_pattern(ex):
        patterns = [v[0] for k, v in ex.args.items() if isinstance(v, list) and v and "#" in v[0]
                    and k != ex.option.action.dest]
        if not patterns:
            reject()
        return [patterns[0]]

    values = [
        Value("the command's input", onto_input("as typed")),
        Value("a symlink to an input", onto_input("symlink")),
        Value("a FIFO", lambda ex: [_fifo(ex, "pipe" + suffix)], EITHER),
        Value("a parent that is a file", parent_is_a_file),
        fixed("a folder nobody can write", f"/proc/lowcam-fuzz/{name}"),
        Value("new nested folders", nested, EITHER),
        fixed("empty path", "", at_parse=True),
        NUL,
    ]
    if decl.kind == "file":
        values += [Value("a hard link to an input", onto_input("hard link")),
                   Value("an existing folder", existing_folder),
                   Value("an existing file of one's own", own_file, EITHER),
                   Value("a trailing slash", lambda ex: [str(ex.path("new")) + "/"]),
                   Value("another output of the command", another_output)]
        for s in decl.suffixes[:1]:
            values += [Value("a wrong suffix", lambda ex: [str(ex.path("result.wrong"))]),
                       Value("an upper-case suffix", lambda ex, s=s: [str(ex.path("result" + s.upper()))], EITHER)]
    elif decl.kind == "folder":
        values += [Value("an existing folder Lowcam did not make", existing_folder),
                   Value("an existing empty folder", lambda ex: [_folder(ex, "empty")], EITHER),
                   Value("a folder Lowcam made before", lambda ex: [_folder(ex, "earlier", {".lowcam-output": ""})],
                         EITHER),
                   Value("a file, not a folder", lambda ex: [_plain_file(ex)]),
                   Value("the folder of the inputs", lambda ex: [str(ex.inp)])]
    else:
        values += [Value("a pattern without #", lambda ex: [str(ex.path("one.png"))], EITHER),
                   Value("the inputs' own pattern", inputs_pattern)]
    return values


def _plain_file(ex: Example) -> str:
    f = ex.path("plain.txt")
    f.write_text("a file\n")
    return str(f)


def _folder(ex: Example, name: str, files: dict | None = None) -> str:
    """A folder ``fuzz/name`` holding ``files`` (name -> text)."""
    p = ex.path(name)
    p.mkdir()
    for file, text in (files or {}).items():
        (p / file).write_text(text)
    return str(p)


def writes_strategy(decl: Writes) -> st.SearchStrategy:
    values = writes_values(decl)
    pick = st.integers(min_value=0, max_value=50).map(
        lambda k: Value(f"input #{k} as the output", lambda ex: _onto_input_k(ex, decl, k)))
    return st.one_of(st.sampled_from(values), pick)


def _onto_input_k(ex: Example, decl: Writes, k: int) -> list[str]:
    target = _an_input(ex, k)
    if target is None:
        reject()
    return [str(target.parent if decl.kind == "folder" else target)]


# --- choosing a strategy ----------------------------------------------------------------------------------------------

FLAG = st.just(Value("set", lambda ex: True, EITHER))


def strategy_for(option: Option, tier: str = "full") -> st.SearchStrategy | None:
    """The strategy of ``option``'s values, by its declaration (None: no strategy knows it). ``tier`` "fast"
    leaves out costly values, and accepted values of slow or Blender-side commands."""
    decl = option.decl
    base = fb.baseline_for(option.command, option.action.dest)
    cap = base.caps.get(option.action.dest) if base else None
    role = getattr(decl, "role", None)  # the declared role picks the strategy
    if option.flag:
        s = FLAG
    elif role == "number":
        s = number_strategy(decl, cap)
    elif role == "numbers":
        s = numbers_strategy(decl)
    elif role == "text":
        s = text_strategy(decl)
    elif role == "reads":
        s = reads_strategy(decl)
    elif role == "writes":
        s = writes_strategy(decl) if decl.kind in ("file", "folder", "pattern") else None
    else:
        s = None
    if s is None or base is None:
        return s
    if base.bpy and tier == "full":  # run as a process
        s = s.filter(lambda v: not v.in_process)
    if base.cost(option.action.dest) > NEVER_RUN_S:  # accepted values only parsed
        s = s.map(lambda v: dataclasses.replace(v, expect=PARSE) if v.expect == EITHER else v)
    if tier == "full":
        return s
    slow = base.bpy or base.cost(option.action.dest) > FAST_RUN_S
    return s.filter(lambda v: not v.costly and not (slow and v.expect == EITHER) and not (base.bpy and not v.at_parse))


def in_fast_tier(option: Option) -> bool:
    """Whether the fast tier has a value for ``option``: a flag of a slow or Blender-side command has none (only
    refusals run there, and a flag is never refused)."""
    base = fb.baseline_for(option.command, option.action.dest)
    slow = base.bpy or base.cost(option.action.dest) > FAST_RUN_S
    return not (option.flag and slow)


# --- running a value ------------------------------------------------------------------------------------------------

def _fill(value, ex: Example):
    if isinstance(value, list):
        return [v.replace("{in}", str(ex.inp)).replace("{out}", str(ex.out)) for v in value]
    return value


def assemble(command: tuple[str, ...], args: dict) -> list[str]:
    """The argv of ``command`` with ``args`` (dest -> values or True): options as ``--name=value``, positionals
    last."""
    argv, positionals = list(command), []
    for action in COMMANDS[command]._actions:
        v = args.get(action.dest)
        if v is None or v is False or _is_help(action):
            continue
        if v is True:
            argv.append(action.option_strings[-1])
        elif not action.option_strings:
            positionals += v
        elif action.nargs in ("+", "*"):
            argv += [action.option_strings[-1], *v]
        elif isinstance(action, argparse._AppendAction):
            argv += [f"{action.option_strings[-1]}={x}" for x in v]
        else:
            argv.append(f"{action.option_strings[-1]}={v[0]}")
    return argv + positionals


def tree_state(root: Path) -> dict[Path, str]:
    """Every path under ``root``: files by content hash and special files by type (``test_fuzz_cli.snapshot``),
    and every folder and link (by its target), so that a half-made empty folder shows. Never opens a special
    file."""
    out = snapshot(root)
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            if p.is_symlink():
                out[p] = f"link {os.readlink(p)}"
            elif name in dirnames:
                out[p] = "dir"
    return out


@contextlib.contextmanager
def fifo_guard(folder: Path):
    """Keep the FIFOs under ``folder`` from blocking a run: a reader waiting for a writer gets end-of-file; a
    writer waiting for a reader gets one that drains it."""
    fifos = [p for p in folder.rglob("*") if p.is_fifo()]
    stop = threading.Event()

    def guard(p: Path):
        while not stop.is_set():
            try:
                fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
            except OSError:
                return
            try:
                quiet_until = time.monotonic() + 0.02
                while time.monotonic() < quiet_until:
                    try:
                        if os.read(fd, 1 << 16):
                            quiet_until = time.monotonic() + 0.2
                        else:
                            break
                    except BlockingIOError:
                        time.sleep(0.002)
            finally:
                os.close(fd)
            try:
                os.close(os.open(p, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
            time.sleep(0.01)

    threads = [threading.Thread(target=guard, args=(p,), daemon=True) for p in fifos]
    for t in threads:
        t.start()
    try:
        yield
    finally:
        stop.set()
        for t in threads:
            t.join(2)


@contextlib.contextmanager
def memory_cap(gib: float):
    """Limit this process's address space to what it uses now plus ``gib`` (a MemoryError, not the machine's
    memory, for a value that asks for too much)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    size = int(re.search(r"VmSize:\s+(\d+)", Path("/proc/self/status").read_text())[1]) * 1024
    limit = size + int(gib * 2 ** 30)
    resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY else min(limit, hard), hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


_REPO_PROFILES = fb.ROOT / "profiles"


def _repo_profiles_state() -> dict:
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in _REPO_PROFILES.rglob("*") if p.is_file()}


#: Lowcam's progress lines on stderr (``[2/6] fitting vignetting``, ``comparing 6 captures with fire-i ...``)
PROGRESS = re.compile(r"^(\[\d+/\d+\] \S|(comparing|simulating) .* \.\.\.$)")


def _lines(text: str) -> list[str]:
    """The lines a terminal shows (a new line at LF or CR only)."""
    return [ln for ln in re.split("[\r\n]", text) if ln.strip()]


class Runner:
    """Runs values: each in a numbered folder under ``root`` (removed when it passes)."""

    def __init__(self, workspace: fb.Workspace, root: Path):
        self.workspace, self.root, self.count = workspace, root, 0
        self.repo_profiles = _repo_profiles_state()

    def prepare(self, option: Option, value: Value, parse_only: bool) -> tuple[Example, list[str]]:
        """The example's folder with copies of the inputs (none for a value parsing refuses, when only parsed),
        and the argv."""
        base = fb.baseline_for(option.command, option.action.dest)
        self.count += 1
        ex = Example(self.root / f"{self.count:05d}", option, base)
        self.workspace.copy_into(() if parse_only and value.at_parse else base.inputs, ex.inp)
        ex.out.mkdir()
        ex.args = {k: _fill(v, ex) for k, v in base.args.items()}
        if isinstance(option.decl, Writes) and not ex.valid():
            ex.args[option.action.dest] = [str(ex.out / option.action.dest)]
        if isinstance(option.decl, Reads) and option.decl.kind == "profile" and value.needs_file:
            _profile_file(ex)
        made = value.make(ex)
        if made == [] and option.action.nargs not in ("*", "?"):
            reject()  # the value does not apply here (nothing of its kind in this baseline)
        ex.made = made if isinstance(made, list) else []
        args = dict(ex.args)
        args[option.action.dest] = made
        return ex, assemble(option.command, args)

    def run(self, option: Option, value: Value, capfd, tier: str) -> None:
        parse_only = value.expect == PARSE or (tier == "fast" and fb.baseline_for(option.command,
                                                                                  option.action.dest).bpy)
        ex, argv = self.prepare(option, value, parse_only)
        shown = f"lowcam {' '.join(argv)}"
        if parse_only:
            self._check_parse(ex, value, argv, capfd, shown)
            self._done(ex)
            return
        before = tree_state(ex.folder)
        t0 = time.perf_counter()
        old_cwd, old_path = os.getcwd(), os.environ.get("LOWCAM_PROFILE_PATH")
        os.environ["LOWCAM_PROFILE_PATH"] = str(ex.inp / "profiles")
        os.chdir(ex.folder)
        try:
            with fifo_guard(ex.folder):
                if ex.baseline.bpy or value.process:
                    timeout = 600 if ex.baseline.bpy else 60
                    rc, out, err = run_subprocess(argv, ex.folder, timeout, None if ex.baseline.bpy else 3.0)
                else:
                    with memory_cap(MEMORY_GIB):
                        rc, out, err = run_in_process(argv, capfd)
        finally:
            os.chdir(old_cwd)
            if old_path is None:
                os.environ.pop("LOWCAM_PROFILE_PATH", None)
            else:
                os.environ["LOWCAM_PROFILE_PATH"] = old_path
        _log(option, value, rc, err, time.perf_counter() - t0)
        check_contract(ex, value, argv, rc, out, err, before, tree_state(ex.folder), shown)
        assert _repo_profiles_state() == self.repo_profiles, f"{shown}: the repository's profiles/ changed"
        self._done(ex)

    def _check_parse(self, ex: Example, value: Value, argv: list[str], capfd, shown: str) -> None:
        """A value only parsed: a valid one is taken, a bad one refused in one line naming the option."""
        option = ex.option
        capfd.readouterr()
        try:
            build_parser().parse_args(argv)
            code = 0
        except SystemExit as e:
            code = e.code
        err = capfd.readouterr().err
        if value.expect == PARSE:
            assert code == 0, f"{shown}: a valid value ({value.label}) is refused by the parser: {err.strip()}"
            return
        lines = _lines(err)
        assert code == 2 and len(lines) == 1, f"{shown}: exit {code}, stderr:\n{err}"
        assert _names_it(lines[0], option, ex.made), f"{shown}: the refusal names neither option nor value: " \
                                                          f"{lines[0]!r}"

    def _done(self, ex: Example) -> None:
        shutil.rmtree(ex.folder, ignore_errors=True)


def _log(option: Option, value: Value, rc: int, err: str, seconds: float) -> None:
    """With ``LOWCAM_FUZZ_LOG=FILE``: one line a run (option, value, exit status, seconds, last stderr line)."""
    path = os.environ.get("LOWCAM_FUZZ_LOG")
    if path:
        with open(path, "a") as f:
            last = (_lines(err) or [""])[-1][:160]
            f.write(f"{option}\t{value.label[:60]!r}\t{value.expect}\t{rc}\t{seconds:.2f}\t{last}\n")


def _names_it(line: str, option: Option, made: list[str], also=()) -> bool:
    """Whether the refusal ``line`` names the option, its value ``made`` (as given, its file's name, a link's
    target) or one of ``also``."""
    names = set(option.action.option_strings) | {option.action.metavar or option.action.dest} | set(also)
    for text in made:
        names |= {text, Path(text).name} | ({str(Path(text).parent)} if "#" in text else set())  # a pattern's folder
        if os.path.islink(text):
            names |= {os.path.realpath(text), Path(os.path.realpath(text)).name}
    names.discard("")
    return any(n in line for n in names)


def check_contract(ex: Example, value: Value, argv: list[str], rc: int, out: str, err: str, before: dict,
                   after: dict, shown: str) -> None:
    """The promise of ``docs/refusals.md`` for one run."""
    lines = _lines(err)
    assert "Traceback" not in err, f"{shown}: exit {rc}, a traceback: {traceback_summary(err)}"
    allowed = {0, 2} | ({ex.baseline.partial_rc} if ex.baseline.partial_rc else set())
    assert rc in allowed, f"{shown}: exit {rc}; stderr:\n" + "\n".join(lines[-6:])
    if value.expect == REFUSE:
        assert rc != 0, f"{shown}: exit 0 for a bad value ({value.label}); stdout:\n{out[-600:]}"
    option = ex.option
    # the value's own files, the option's valid input, the inputs the value is aimed at: what a refusal may name
    names = [str(p) for p in ex.inputs()] + [p.name for p in ex.inputs()]
    if rc == 2:
        # a refusal after work may follow Lowcam's own progress lines (stderr is no terminal here): the error is
        # the one last line
        lines = [ln for ln in lines if not PROGRESS.match(ln)] if lines and PROGRESS.match(lines[0]) else lines
        assert len(lines) == 1, f"{shown}: {len(lines)} lines on stderr, expected 1:\n" + "\n".join(lines[:8])
        strict = value.expect == REFUSE and not isinstance(option.decl, Writes)
        assert _names_it(lines[0], option, ex.made, () if strict else names), \
            f"{shown}: the refusal names neither the option nor the file: {lines[0]!r}"
    elif rc and rc == ex.baseline.partial_rc:
        assert len(lines) <= 3, f"{shown}: exit {rc} with {len(lines)} lines:\n" + "\n".join(lines[:8])
        assert any(_names_it(ln, option, ex.made, names) for ln in lines), \
            f"{shown}: no line names the option or the file:\n" + "\n".join(lines)
    else:
        errors = [ln for ln in lines if "error:" in ln]
        assert not errors, f"{shown}: exit 0 with an error on stderr: {errors[0]}"
    # nothing destroyed: inputs keep their bytes, FIFOs stay FIFOs, a refusal writes nothing at all
    outputs = [Path(a) for a in _values_of_writes(ex, argv)]
    may_change = {ex.folder / m for m in ex.baseline.may_change}

    def is_output(p: Path) -> bool:
        return p in may_change or p.is_relative_to(ex.out) or any(p == o or p.is_relative_to(o) for o in outputs
                                                                  if not p.is_relative_to(ex.inp))
    changed = [p for p, h in before.items() if after.get(p) != h and not (rc == 0 and is_output(p)
                                                                          and not h.startswith("type"))]
    assert not changed, f"{shown}: exit {rc}, changed or removed: " + ", ".join(
        f"{p.relative_to(ex.folder)} ({before[p][:16]} -> {str(after.get(p, 'missing'))[:16]})" for p in changed[:6])
    parts = [p for p in after if p.name.startswith(".lowcam-") and p.name.endswith(".part")]
    assert not parts, f"{shown}: temporaries left behind: " + ", ".join(str(p.relative_to(ex.folder))
                                                                       for p in parts)
    if rc != 0:
        new = sorted(p for p in after if p not in before)
        assert not new, f"{shown}: exit {rc} left behind: " + ", ".join(str(p.relative_to(ex.folder))
                                                                      for p in new[:8])
    elif value.expect != PARSE:
        for o in outputs:  # exit 0 made what it was asked for
            if not (o.is_relative_to(Path("/proc")) or str(o) in ("/dev/null",) or o.is_fifo()):
                target = o.parent if "#" in o.name else o
                assert target.exists(), f"{shown}: exit 0 but {o} was not written"


def _values_of_writes(ex: Example, argv: list[str]) -> list[str]:
    """The paths given to the command's writes-options in ``argv``."""
    found = []
    for action in COMMANDS[ex.option.command]._actions:
        if isinstance(getattr(action.type, "role", None) and action.type, Writes):
            for k, a in enumerate(argv):
                for s in action.option_strings:
                    if a.startswith(s + "="):
                        found.append(a[len(s) + 1:])
    return [f for f in found if f]


# --- the tests ------------------------------------------------------------------------------------------------------

OPTIONS = all_options()


def _params(tier: str):
    for option in OPTIONS if tier == "full" else filter(in_fast_tier, OPTIONS):
        base = fb.BASELINES.get(option.command)
        marks = []
        if tier == "full":
            marks.append(pytest.mark.slow)
            if base is not None and (base.bpy or fb.baseline_for(option.command, option.action.dest).bpy):
                marks.append(pytest.mark.blender)
        yield pytest.param(option, id=str(option), marks=marks)


@pytest.fixture(scope="session")
def workspace(tmp_path_factory):
    return fb.Workspace(tmp_path_factory.mktemp("fuzz-inputs"))


@pytest.fixture(scope="session")
def runner(workspace, tmp_path_factory):
    return Runner(workspace, tmp_path_factory.mktemp("fuzz-examples"))


def coverage_gaps(parser) -> list[str]:
    """What this suite could not fuzz in ``parser``, one line each: a command without a baseline (or a baseline
    lacking a required argument, or setting one the command has not), an option that declares nothing or whose
    declaration no strategy knows, an input option without a valid value to damage."""
    commands = dict(_leaves(parser))
    options = [Option(path, action, decl) for path, action, decl in declared(parser)
               if path in commands and not _is_help(action)]
    gaps = [f"{' '.join(c)}: no baseline in fuzz_baselines.py" for c in commands if c not in fb.BASELINES]
    for command, sub in commands.items():
        base = fb.BASELINES.get(command)
        if base is not None:
            gaps += [f"{' '.join(command)}: the baseline lacks the required {a.dest}" for a in sub._actions
                     if a.required and a.dest not in base.args]
            gaps += [f"{' '.join(command)}: the baseline sets {d}, which the command does not have"
                     for d in sorted(set(base.args) - {a.dest for a in sub._actions})]
    for o in options:
        if not o.flag and o.decl is None:
            gaps.append(f"{o}: declares nothing (lowcam.arguments)")
        elif strategy_for(o) is None:
            gaps.append(f"{o}: no strategy knows {o.decl!r}")
        elif isinstance(o.decl, Reads) and o.command in fb.BASELINES and \
                not fb.baseline_for(o.command, o.action.dest).args.get(o.action.dest):
            gaps.append(f"{o}: no valid value in its baseline or the baseline's companions")
    return gaps


def test_every_command_and_option_has_a_strategy():
    """A command without a baseline, or an option whose declaration no strategy knows, fails here: a new command
    is fuzzed the day it is added."""
    gaps = coverage_gaps(PARSER)
    assert not gaps, "the fuzz suite cannot cover:\n" + "\n".join(gaps)
    stale = sorted(" ".join(c) for c in fb.BASELINES if c not in COMMANDS)
    assert not stale, f"baselines of commands the parser does not have: {stale}"


def test_a_new_command_or_option_is_a_coverage_gap():
    """The coverage test sees a command added without a baseline, an option declaring nothing and a declaration
    no strategy knows."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    new = sub.add_parser("frobnicate")
    new.add_argument("-o", "--output", type=Writes("file"), required=True)
    apply = sub.choices["apply"]
    apply.add_argument("--gamma", type=float)
    apply.add_argument("--lut", type=Reads("file"))

    class Colour(Text):  # a declaration of a kind no strategy knows
        role = "colour"
    apply.add_argument("--tint", type=Colour())
    gaps = coverage_gaps(parser)
    assert "frobnicate: no baseline in fuzz_baselines.py" in gaps
    assert "apply --gamma: declares nothing (lowcam.arguments)" in gaps
    assert any(g.startswith("apply --tint: no strategy knows") for g in gaps)
    assert "apply --lut: no valid value in its baseline or the baseline's companions" in gaps
    assert not coverage_gaps(build_parser())


@pytest.mark.parametrize("option", list(_params("fast")))
@FAST
@given(data=st.data())
def test_fuzz_fast(option, data, runner, capfd):
    """The seeded slice: a few values an option, in the fast tier."""
    value = data.draw(strategy_for(option, "fast"), label="value")
    runner.run(option, value, capfd, "fast")


def full_examples(option: Option) -> int:
    """How many values the full run tries for ``option``: more for a cheap command, fewer for a slow one."""
    base = fb.baseline_for(option.command, option.action.dest)
    return max(FULL_EXAMPLES[0], min(FULL_EXAMPLES[1], round(FULL_BUDGET_S / base.cost(option.action.dest))))


@pytest.mark.parametrize("option", list(_params("full")))
def test_fuzz_full(option, runner, capfd):
    """Every option with more values, every value run (Blender-side commands as processes)."""
    base = fb.baseline_for(option.command, option.action.dest)
    if base.bpy and fb.needs_bpy():
        pytest.skip(fb.needs_bpy())

    @settings(FAST, max_examples=full_examples(option))
    @given(data=st.data())
    def values(data):
        runner.run(option, data.draw(strategy_for(option, "full"), label="value"), capfd, "full")

    values()
