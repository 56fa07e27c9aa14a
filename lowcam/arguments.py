"""Declared command-line arguments: argparse ``type=`` callables that carry what they are.

Every option of every ``lowcam`` command that takes a value has one of these as its ``type``: what it reads
(:class:`Reads`), what it writes (:class:`Writes`), a number and its physical range (:class:`Number`,
:class:`Numbers`) or free text (:class:`Text`). The declaration is an attribute of the callable, so the one error
boundary (``lowcam.cli.main``) knows every file a command reads and writes before it runs, and a test can find an
option nobody declared (:func:`declared`). Parsing refuses NaN, infinities and values out of range with the range
in the message; argparse then names the option (``argument --fps: 0 is out of range (0, 1000]``).

Kinds of file a command reads (:data:`READ_KINDS`): ``file`` (one file), ``folder`` (a folder of inputs),
``glob`` (a file name or glob pattern), ``footage`` (a video file, a folder of frames or a glob of frames),
``profile`` (a profile name, resolved on the search path, or a TOML file), ``set`` (a measurement-set folder: the
files its ``set.toml`` names), ``files`` (one of several file names, globs or folders of frames given with ``nargs``),
``pattern`` (a frame pattern, ``#`` for the frame digits, or one video file), ``manifest`` (a calibration
manifest: the files and the profile it names). Kinds written (:data:`WRITE_KINDS`): ``file``,
``folder`` (a whole output written into it), ``pattern`` (a ``#`` frame pattern, or a folder for one).

Contents
--------
- :data:`READ_KINDS`: the kinds of input :class:`Reads` knows
- :data:`WRITE_KINDS`: the kinds of output :class:`Writes` knows
- :class:`Reads`: argparse type of an argument naming what a command reads
- :class:`Writes`: argparse type of an argument naming what a command writes
- :class:`Number`: argparse type of a finite number in a declared range
- :class:`Numbers`: argparse type of a comma-separated list of numbers, each in its declared range
- :class:`Text`: argparse type of free text (a name, a spec), optionally one of ``choices`` or checked
- :func:`bounded_int`: an integer in [low, high] (a :class:`Number`)
- :data:`seed`: a noise seed, 0 <= seed < 2**64 (every bit counts: no two seeds alias)
- :data:`frame_number`: a frame number in [-2**31, 2**31)
- :data:`angular_velocity`: ``wx,wy,wz`` in rad/s, each within +-1000 (gyros saturate near 35)
- :data:`defocus`: ``FOCUS_M,APERTURE_MM``: the depth-of-field effect's focus distance and aperture
- :func:`declaration`: the declaration of one argparse action (None for a flag)
- :func:`declared`: (command path, action, declaration) for every option of every sub-command
- :func:`undeclared`: the options that take a value and declare nothing
"""
from __future__ import annotations

import argparse
import math
import os

from .errors import LowcamError

#: The kinds of input :class:`Reads` knows (see the module's docstring).
READ_KINDS = ("file", "folder", "glob", "footage", "profile", "set", "files", "pattern", "manifest")
#: The kinds of output :class:`Writes` knows.
WRITE_KINDS = ("file", "folder", "pattern")


class Reads:
    """An argument naming something the command reads, of ``kind`` (:data:`READ_KINDS`). Parsing returns the
    text as given (``str``); the error boundary expands it to the files it names."""

    role = "reads"

    def __init__(self, kind: str, what: str = ""):
        if kind not in READ_KINDS:
            raise ValueError(f"Reads: unknown kind {kind!r} (known: {', '.join(READ_KINDS)})")
        self.kind, self.what = kind, what
        self.__name__ = f"reads {kind}"

    def __call__(self, text) -> str:
        text = str(text)
        if text == "":
            raise argparse.ArgumentTypeError("an empty path")
        if "\0" in text:
            raise argparse.ArgumentTypeError("a path with a NUL character")
        return text

    def __repr__(self) -> str:
        return f"Reads({self.kind!r})"


class Writes:
    """An argument naming something the command writes, of ``kind`` (:data:`WRITE_KINDS`); ``suffixes`` are the
    file suffixes it may have (any if empty); ``replaces``: the ``dest`` of an input it may replace on purpose
    (``calibrate -o`` updates its ``--profile``). Parsing returns the text as given (``str``)."""

    role = "writes"

    def __init__(self, kind: str, suffixes: tuple[str, ...] = (), replaces: tuple[str, ...] = ()):
        if kind not in WRITE_KINDS:
            raise ValueError(f"Writes: unknown kind {kind!r} (known: {', '.join(WRITE_KINDS)})")
        self.kind, self.suffixes, self.replaces = kind, tuple(suffixes), tuple(replaces)
        self.__name__ = f"writes {kind}"

    def __call__(self, text) -> str:
        text = str(text)
        if text == "":
            raise argparse.ArgumentTypeError(f"an empty output {'folder' if self.kind == 'folder' else 'path'}")
        if "\0" in text:
            raise argparse.ArgumentTypeError("an output path with a NUL character")
        if self.kind == "file" and text.endswith(("/", os.sep)):  # Path() would drop the slash: a file "new"
            raise argparse.ArgumentTypeError(f"{text}: ends with '/', a folder; give the file's name")
        return text

    def __repr__(self) -> str:
        return f"Writes({self.kind!r}, suffixes={self.suffixes!r})"


def _interval(low, high, low_open: bool, high_open: bool) -> str:
    left = "(" if low_open or low is None else "["
    right = ")" if high_open or high is None else "]"
    return f"{left}{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}{right}"


class Number:
    """A finite number in [``low``, ``high``] (either end open with ``low_open`` / ``high_open``, unbounded if
    None); ``integer`` for whole numbers. NaN, infinities and values out of range are refused with the range in the
    message. Called with a number (a manifest's value) as well as with text."""

    role = "number"

    def __init__(self, low=None, high=None, *, integer: bool = False, low_open: bool = False,
                 high_open: bool = False, what: str = ""):
        self.low, self.high, self.integer = low, high, integer
        self.low_open, self.high_open = low_open, high_open
        self.what = what or ("an integer" if integer else "a number")
        self.__name__ = "integer" if integer else "number"

    @property
    def range(self) -> str:
        """The range as an interval, ``(0, 1000]``."""
        return _interval(self.low, self.high, self.low_open, self.high_open)

    def __call__(self, text):
        if isinstance(text, bool):
            raise argparse.ArgumentTypeError(f"expected {self.what}, got {text!r}")
        try:
            if self.integer:
                value = text if isinstance(text, int) else int(str(text).strip())
            else:
                value = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected {self.what}, got {str(text)!r}") from None
        if not self.integer and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number in {self.range}, got {text}")
        self.check(value)
        return value

    def check(self, value) -> None:
        """Refuse ``value`` (a parsed number) outside the range, naming it."""
        low_bad = self.low is not None and (value <= self.low if self.low_open else value < self.low)
        high_bad = self.high is not None and (value >= self.high if self.high_open else value > self.high)
        if low_bad or high_bad:
            raise argparse.ArgumentTypeError(f"{value:g} is out of range {self.range}"
                                             + (f" ({self.what})" if self.what not in ("an integer", "a number")
                                                else ""))

    def __repr__(self) -> str:
        return f"Number({self.range}{', integer' if self.integer else ''})"


class Numbers:
    """``count`` comma-separated numbers (``wx,wy,wz``), each a :class:`Number` of ``items`` (one per position, or
    one for all); ``what`` names them in messages. Parsing returns a tuple of floats."""

    role = "numbers"

    def __init__(self, items, count: int, what: str):
        items = tuple(items) if isinstance(items, (tuple, list)) else (items,) * count
        if len(items) != count:
            raise ValueError("Numbers: one Number per position, or one for all")
        self.items, self.count, self.what = items, count, what
        self.__name__ = "numbers"

    def __call__(self, text) -> tuple:
        parts = str(text).split(",")
        if len(parts) != self.count:
            raise argparse.ArgumentTypeError(f"expected {self.count} numbers {self.what}, got {str(text)!r}")
        values = []
        for item, part in zip(self.items, parts):
            try:
                values.append(float(part))
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected {self.count} numbers {self.what}, got "
                                                 f"{str(text)!r}") from None
            if not math.isfinite(values[-1]):
                raise argparse.ArgumentTypeError(f"expected {self.count} finite numbers {self.what}, got "
                                                 f"{str(text)!r}")
            try:
                item.check(values[-1])
            except argparse.ArgumentTypeError as e:
                raise argparse.ArgumentTypeError(f"{e} in {self.what}, got {str(text)!r}") from None
        return tuple(values)

    def __repr__(self) -> str:
        return f"Numbers({self.count}, {self.what})"


class Text:
    """Free text: a name, a spec, a list of names. ``choices``: the values it may take (refused otherwise);
    ``check``: a function that raises :class:`~lowcam.errors.LowcamError` (or ValueError) on a bad value (its
    message becomes the refusal); ``what`` says what the text is (``"frames"``, ``"MODULE:CLASS"``)."""

    role = "text"

    def __init__(self, choices=None, *, what: str = "", check=None):
        self.choices = tuple(choices) if choices is not None else None
        self.what, self.check = what, check
        self.__name__ = what or "text"

    def __call__(self, text) -> str:
        text = str(text)
        if "\0" in text:
            raise argparse.ArgumentTypeError("text with a NUL character")
        if self.choices is not None and text not in self.choices:
            raise argparse.ArgumentTypeError(f"{text!r} is not one of {', '.join(self.choices)}")
        if self.check is not None:
            try:
                self.check(text)
            except (LowcamError, ValueError) as e:
                raise argparse.ArgumentTypeError(str(e).split("\n")[0]) from None
        return text

    def __repr__(self) -> str:
        return f"Text({self.what or self.choices!r})"


def bounded_int(low: int, high: int, what: str = "an integer") -> Number:
    """An integer in [low, high] (a :class:`Number`)."""
    return Number(low, high, integer=True, what=what)


#: A noise seed, 0 <= seed < 2**64 (``lowcam.effects.noise.SEED_RANGE``; every bit counts).
seed = Number(0, 2 ** 64 - 1, integer=True, what="an integer seed")
#: A frame number in [-2**31, 2**31) (``lowcam.effects.noise.FRAME_RANGE``).
frame_number = Number(-2 ** 31, 2 ** 31 - 1, integer=True, what="an integer frame number")
#: The camera's angular velocity ``wx,wy,wz`` in rad/s (``lowcam.motion.MAX_RATE`` bounds each).
angular_velocity = Numbers(Number(-1000.0, 1000.0), 3, "wx,wy,wz in rad/s")
#: ``FOCUS_M,APERTURE_MM``: the depth-of-field effect's focus distance (m) and aperture diameter (mm), within the
#: effect's parameter ranges.
defocus = Numbers((Number(0.01, 1e4, what="focus distance in m"), Number(0.0, 200.0, what="aperture in mm")), 2,
                  "FOCUS_M,APERTURE_MM")

#: The action classes that take no value.
_NO_VALUE = (argparse._HelpAction, argparse._StoreTrueAction, argparse._StoreFalseAction,
             argparse._StoreConstAction, argparse._AppendConstAction, argparse._CountAction,
             argparse._VersionAction)


def declaration(action: argparse.Action):
    """What ``action`` declares: its type's declaration (:class:`Reads`, :class:`Writes`, :class:`Number`,
    :class:`Numbers`, :class:`Text`); for an option with ``choices`` only, a :class:`Text` of them; None for a flag
    (store_true, help) or an option that declares nothing."""
    if getattr(action.type, "role", None) is not None:
        return action.type
    if isinstance(action, _NO_VALUE) or action.nargs == 0:
        return None
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        return Text(tuple(action.choices))
    return None


def _sub_parsers(parser: argparse.ArgumentParser):
    """(name, parser) of each sub-command of ``parser`` (an alias once, under its first name)."""
    seen = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if id(sub) not in seen:
                    seen.add(id(sub))
                    yield name, sub


def declared(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """``(command path, action, declaration)`` for every option of every sub-command below ``parser``, e.g.
    ``(("profile", "from-dng"), <-o action>, Writes("file"))``; flags and help give None (:func:`declaration`).
    Sub-commands of sub-commands (``calibrate plate``) are walked too; the sub-command actions themselves are not
    yielded."""
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            yield path, action, declaration(action)
    for name, sub in _sub_parsers(parser):
        yield from declared(sub, path + (name,))


def undeclared(parser: argparse.ArgumentParser) -> list[str]:
    """``"calibrate plate --fps"`` for each option that takes a value and declares nothing."""
    out = []
    for path, action, decl in declared(parser):
        takes_value = not isinstance(action, _NO_VALUE) and action.nargs != 0
        if takes_value and decl is None:
            out.append(" ".join(path + ((action.option_strings or [action.dest])[-1],)))
    return out
