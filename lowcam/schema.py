"""Schemas at every edge: the checks every value Lowcam reads from a user's file goes through.

Profiles, chromatic-aberration grids, motion.json, gyro logs, measurement sets and chart layouts all read their
files and check their values with these helpers, so a bad value is refused the same way everywhere: a one-line
:class:`~lowcam.errors.LowcamError` (or the ``error`` class the reader passes, such as
:class:`~lowcam.errors.ProfileError`) that starts with ``where`` (the file, then the table or row) and names the
key, e.g. ``x.toml: effect 'blur': 'sigma' must be a finite number in [0.0, 10.0], got inf``. Numbers are always
finite; booleans are never taken for numbers.

Contents
--------
- :func:`shown`: a short, one-line repr of a refused value (or key) for a message
- :func:`number`: a finite float, optionally within [low, high]
- :func:`integer`: a whole number (an int, or a float with no fraction), optionally within [low, high]
- :func:`boolean`: true or false
- :func:`string`: a string, optionally non-empty or one of ``choices``
- :func:`table`: a TOML table / JSON object, optionally with only ``known`` keys and all ``required`` ones
- :func:`array_of`: a list, optionally of a given length, each entry checked by a helper
- :func:`numbers`: a list of finite numbers (a vector), each within [low, high]
- :func:`existing_file`: the file a string names, relative to a folder; it must exist
- :data:`MAX_TEXT_BYTES`: the largest text file a reader takes
- :func:`read_text`: a UTF-8 text file (missing, a folder, a device, unreadable, too large or not UTF-8: refused)
- :func:`read_toml`: a TOML file as a table
- :func:`read_json`: a JSON file (NaN, Infinity and numbers that overflow, such as ``1e400``, refused)
- :func:`read_number_csv`: a CSV of finite numbers under a header naming its columns, and each row's line number
"""
from __future__ import annotations

import json
import math
import numbers as _numbers
import stat
import tomllib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .errors import LowcamError

#: Largest text file a reader takes (bytes): a gyro log of an hour at 1 kHz is about 150 MB.
MAX_TEXT_BYTES = 512 * 2**20


def shown(value: Any) -> str:
    """A short, one-line repr of a refused value."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 60 else text[:57] + "..."


def _range(low, high) -> str:
    return f"[{'-inf' if low is None else low}, {'inf' if high is None else high}]"


def number(value: Any, where: str, key: str, low: float | None = None, high: float | None = None, unit: str = "",
           error: type[LowcamError] = LowcamError) -> float:
    """``value`` as a finite float within [low, high] (either bound may be None); ``unit`` is named on a miss."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, _numbers.Real):
        raise error(f"{where}: '{key}' must be a number, got {shown(value)}")
    try:
        x = float(value)
    except OverflowError:  # an int too large for a float
        x = math.inf
    if not math.isfinite(x):
        bounds = f" in {_range(low, high)}" if low is not None or high is not None else ""
        raise error(f"{where}: '{key}' must be a finite number{bounds}, got {shown(value)}")
    if (low is not None and x < low) or (high is not None and x > high):
        unit = f" {unit}" if unit else ""
        raise error(f"{where}: '{key}' = {shown(value)}{unit} is out of range {_range(low, high)}")
    return x


def integer(value: Any, where: str, key: str, low: int | None = None, high: int | None = None, unit: str = "",
            error: type[LowcamError] = LowcamError) -> int:
    """``value`` as an int within [low, high]: an int, or a float with no fraction (``24.0``)."""
    x = number(value, where, key, low, high, unit, error=error)
    if x != int(x):
        raise error(f"{where}: '{key}' must be a whole number, got {shown(value)}")
    return int(x)


def boolean(value: Any, where: str, key: str, error: type[LowcamError] = LowcamError) -> bool:
    """``value`` if it is true or false (not 0 or 1)."""
    if not isinstance(value, bool):
        raise error(f"{where}: '{key}' must be true or false, got {shown(value)}")
    return value


def string(value: Any, where: str, key: str, choices=None, nonempty: bool = False,
           error: type[LowcamError] = LowcamError) -> str:
    """``value`` if it is a string (non-empty with ``nonempty``; one of ``choices`` when given)."""
    if not isinstance(value, str):
        raise error(f"{where}: '{key}' must be a string, got {shown(value)}")
    if nonempty and not value.strip():
        raise error(f"{where}: '{key}' must not be empty")
    if choices and value not in choices:
        raise error(f"{where}: '{key}' must be one of {', '.join(choices)}, got {shown(value)}")
    return value


def table(value: Any, where: str, key: str | None = None, known=None, required=(),
          error: type[LowcamError] = LowcamError) -> dict:
    """``value`` if it is a table (dict) holding only ``known`` keys (when given) and every ``required`` one.
    Without ``key``, the messages speak of ``where`` itself (a whole file, one entry of an array)."""
    name = f"'{key}' " if key else ""
    if not isinstance(value, dict):
        raise error(f"{where}: {name}must be a table, got {shown(value)}")
    if known is not None:
        unknown = sorted(str(k) for k in value if k not in known)
        if unknown:
            inside = f" in '{key}'" if key else ""
            raise error(f"{where}: unknown key {shown(unknown[0])}{inside} (known: {', '.join(sorted(known))})")
    missing = [k for k in required if k not in value]
    if missing:
        raise error(f"{where}: {name}needs '{missing[0]}'")
    return value


def array_of(value: Any, where: str, key: str, check: Callable | None = None, length: int | None = None,
             min_length: int = 0, error: type[LowcamError] = LowcamError) -> list:
    """``value`` if it is a list (``length`` long, or at least ``min_length``), each entry passed through
    ``check(entry, where, "key[i]")`` (its result kept)."""
    if not isinstance(value, (list, tuple)):
        raise error(f"{where}: '{key}' must be a list, got {shown(value)}")
    if length is not None and len(value) != length:
        raise error(f"{where}: '{key}' must have {length} entries, got {len(value)}")
    if len(value) < min_length:
        raise error(f"{where}: '{key}' must have at least {min_length} entries, got {len(value)}")
    return [check(v, where, f"{key}[{i}]") if check else v for i, v in enumerate(value)]


def numbers(value: Any, where: str, key: str, length: int | None = None, low: float | None = None,
            high: float | None = None, unit: str = "", whole: bool = False,
            error: type[LowcamError] = LowcamError) -> list:
    """``value`` as a list of finite floats (ints with ``whole``), ``length`` long, each within [low, high]."""
    def entry(v, w, k):
        return (integer if whole else number)(v, w, k, low, high, unit, error=error)

    return array_of(value, where, key, entry, length, error=error)


def existing_file(value: Any, where: str, key: str, base: Path | None = None,
                  error: type[LowcamError] = LowcamError) -> Path:
    """The file a string ``value`` names (relative to ``base`` when given and not absolute); it must exist."""
    path = Path(string(value, where, key, nonempty=True, error=error))
    path = base / path if base is not None and not path.is_absolute() else path
    try:
        found = path.is_file()
    except (OSError, ValueError):  # a name too long for the file system
        found = False
    if not found:
        raise error(f"{where}: '{key}' names a file that does not exist: {path}")
    return path


def read_text(path, what: str = "file", error: type[LowcamError] = LowcamError) -> str:
    """The text of a UTF-8 file (a byte-order mark is dropped); a missing file, a folder, a device, an unreadable,
    too large or not-UTF-8 file is refused."""
    path = Path(path)
    try:
        mode = path.stat()
        if stat.S_ISDIR(mode.st_mode):
            raise error(f"{path}: is a folder, not a {what}")
        if stat.S_ISCHR(mode.st_mode) or stat.S_ISBLK(mode.st_mode):
            raise error(f"{path}: is a device, not a {what}")
        with open(path, "rb") as f:  # a pipe (``<(...)``) is read too, up to the limit
            data = f.read(MAX_TEXT_BYTES + 1)
        if len(data) > MAX_TEXT_BYTES:
            raise error(f"{path}: the {what} is larger than {MAX_TEXT_BYTES // 2**20} MiB")
        return data.decode("utf-8-sig")
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except UnicodeDecodeError as e:
        raise error(f"{path}: the {what} is not UTF-8 text (byte {e.start})") from None
    except (OSError, ValueError) as e:  # permission, a name too long, a NUL in the name
        raise error(f"{path}: cannot read the {what} ({getattr(e, 'strerror', None) or e})") from None


def read_toml(path, what: str = "file", error: type[LowcamError] = LowcamError) -> dict:
    """A TOML file as a table."""
    text = read_text(path, what, error)
    try:
        return tomllib.loads(text)
    except (ValueError, RecursionError) as e:  # TOMLDecodeError, an integer of thousands of digits, deep nesting
        raise error(f"{path}: not valid TOML ({str(e).splitlines()[0] if str(e) else 'nested too deeply'})") from None


class _NotFinite(Exception):
    pass


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise _NotFinite(text)
    return x


def _no_constant(text: str):
    raise _NotFinite(text)


def read_json(path, what: str = "file", error: type[LowcamError] = LowcamError) -> Any:
    """A JSON file's value; ``NaN``, ``Infinity`` and numbers that overflow a float (``1e400``) are refused."""
    text = read_text(path, what, error)
    try:
        return json.loads(text, parse_float=_finite_float, parse_constant=_no_constant)
    except _NotFinite as e:
        raise error(f"{path}: the {what} holds {e}, which is not a finite number") from None
    except (ValueError, RecursionError) as e:  # JSONDecodeError, an integer of thousands of digits, deep nesting
        raise error(f"{path}: not valid JSON ({str(e).splitlines()[0] if str(e) else 'nested too deeply'})") from None


def read_number_csv(path, columns, what: str = "table", min_rows: int = 1, low=None, high=None,
                    error: type[LowcamError] = LowcamError) -> tuple[np.ndarray, np.ndarray]:
    """A CSV of finite numbers: a header naming ``columns`` (any order, any case), then one row per line.

    Values are separated by commas (or by whitespace when the header has no comma); blank lines and lines
    starting with ``#`` are skipped. ``low``/``high`` (scalars, or dicts column -> bound) bound the values.
    Returns (rows, len(columns)) float64 in the order of ``columns``, and each row's line number in the file.
    """
    columns = list(columns)
    lines = [(n, ln) for n, ln in enumerate(read_text(path, what, error).splitlines(), 1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise error(f"{path}: the {what} is empty (it needs the header {','.join(columns)})")
    comma = "," in lines[0][1]

    def split(line):
        return [c.strip() for c in line.split(",")] if comma else line.split()

    header = [h.lower() for h in split(lines[0][1])]
    if sorted(header) != sorted(columns):
        raise error(f"{path}: the {what} needs a header naming {','.join(columns)}; got {shown(lines[0][1])}")
    order = [header.index(c) for c in columns]
    if len(lines) - 1 < min_rows:
        raise error(f"{path}: the {what} has {len(lines) - 1} data row(s), at least {min_rows} needed")
    rows = []
    for n, line in lines[1:]:
        cells = split(line)
        if len(cells) != len(columns):
            raise error(f"{path}: line {n}: {len(cells)} values, the header names {len(columns)}")
        try:
            rows.append([float(cells[k]) for k in order])
        except ValueError:
            bad = next(c for c, k in enumerate(order) if not _parses(cells[k]))
            raise error(f"{path}: line {n}: '{columns[bad]}' must be a number, "
                        f"got {shown(cells[order[bad]])}") from None
    data = np.array(rows, np.float64).reshape(-1, len(columns))
    line_numbers = np.array([n for n, _ in lines[1:]])
    lows = np.array([_bound(low, c, -np.inf) for c in columns])
    highs = np.array([_bound(high, c, np.inf) for c in columns])
    bad = ~np.isfinite(data) | (data < lows) | (data > highs)
    if bad.any():  # the first bad cell, in file order, refused with its line and column
        r, c = np.argwhere(bad)[0]
        number(float(data[r, c]), f"{path}: line {line_numbers[r]}", columns[c], _bound(low, columns[c], None),
               _bound(high, columns[c], None), error=error)
    return data, line_numbers


def _parses(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _bound(bound, column: str, default):
    """A bound given for every column (a number) or per column (a dict), or ``default``."""
    value = bound.get(column) if isinstance(bound, dict) else bound
    return default if value is None else value
