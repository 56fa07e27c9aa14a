"""The ``lowcam`` command line. Every user-facing problem is one line on stderr and exit status 2; ``--debug``
shows its traceback.

Every option declares what it is (:mod:`lowcam.arguments`: the files it reads or writes, a number's range), so
:func:`main` refuses an output that is one of the command's inputs before any work (:mod:`lowcam.boundary`).

Other packages add commands through the ``lowcam.commands`` entry-point group: the Blender side adds ``demo``,
``render``, ``motion`` and ``node-asset`` (``addon/commands.py``); the engine knows none of them by name.

The commands live by what they do: :mod:`.frames` (apply, stages, batch), :mod:`.calibrate` (chart, calibrate),
:mod:`.measure` (compare, diagnose, synth), :mod:`.profiles` (profiles, profile ...); :mod:`.common` holds what they
share (the one-line :class:`~lowcam.cli.common.Parser`, the declared arguments several take).

Contents
--------
- :func:`add_plugin_commands`: commands other packages add through the ``lowcam.commands`` entry points
- :func:`build_parser`: the argument parser of every sub-command
- :func:`main`: the entry point: one line on stderr and exit status 2 for a :class:`~lowcam.errors.LowcamError`
- :class:`~lowcam.cli.common.Parser`, :data:`FPS`, :data:`EXPOSURE_S`, :data:`METRES_PER_UNIT`, :data:`PROFILE`,
  :data:`LAYER`, :data:`FRAMES` (from :mod:`.common`) and :data:`IMAGE_SUFFIXES` (:mod:`lowcam.outputs`'s): the
  declared arguments other packages' commands take too
"""
from __future__ import annotations

import argparse
import os
import select
import sys
import warnings
from importlib.metadata import entry_points

from ..arguments import Text
from ..boundary import check_declared_files, command_name
from ..effects import trust_plugins
from ..errors import LowcamError
from ..outputs import IMAGE_SUFFIXES
from . import calibrate, frames, measure, profiles
from .common import EXPOSURE_S, FPS, FRAMES, LAYER, METRES_PER_UNIT, PROFILE, Parser, end_progress_lines


#: What other packages' commands (the Blender side's) take from here.
__all__ = ["main", "build_parser", "add_plugin_commands", "Parser", "FPS", "EXPOSURE_S", "METRES_PER_UNIT", "PROFILE",
           "LAYER", "FRAMES", "IMAGE_SUFFIXES"]


def add_plugin_commands(sub) -> None:
    """Commands other packages add through the ``lowcam.commands`` entry-point group: each entry is a function
    that takes the sub-parsers and adds its own (the Blender side adds ``demo``, ``render``, ``motion`` and
    ``node-asset``; see ``addon/commands.py``). The engine knows none of them by name."""
    for entry in entry_points(group="lowcam.commands"):
        try:
            add = entry.load()
        except ImportError as e:
            p = sub.add_parser(entry.name, help=f"unavailable: {e}")
            p.set_defaults(func=lambda args, e=e, name=entry.name: _unavailable(name, e))
            continue
        add(sub)


def _unavailable(name: str, problem: Exception) -> int:
    raise LowcamError(f"'{name}' commands cannot be loaded ({problem}); reinstall Lowcam with pip install -e .")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every sub-command: the engine's, grouped by module (:mod:`.frames`,
    :mod:`.calibrate`, :mod:`.measure`, :mod:`.profiles`), then those other packages add."""
    parser = Parser(prog="lowcam", description="Simulate a low-cost camera on CG renders (Klein & Murray 2010).")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (for a bug report)")
    parser.add_argument("--plugin", type=Text(what="MODULE"), action="append", dest="plugins", default=[],
                        metavar="MODULE",
                        help="trust this plug-in module: profiles may name its effects ('MODULE:Class'); "
                             "repeatable; LOWCAM_PLUGINS lists more (no other module is ever imported)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    for group in (frames, calibrate, measure, profiles):
        group.add_commands(sub)
    add_plugin_commands(sub)
    for command in set(sub.choices.values()):  # lowcam apply --debug as well as lowcam --debug apply
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        if "--plugin" not in command._option_string_actions:  # lowcam apply --plugin M too (diagnose has its own)
            command.add_argument("--plugin", type=Text(what="MODULE"), action="append", dest="plugins_after",
                                 default=argparse.SUPPRESS, metavar="MODULE", help=argparse.SUPPRESS)
    return parser


def main(argv=None) -> int:
    """The entry point: the one error boundary of every command. Before the command runs, the files it reads and
    writes (declared by its arguments, :mod:`lowcam.arguments`) are checked: an output that is one of its inputs
    is refused (:func:`lowcam.boundary.check_declared_files`). A :class:`~lowcam.errors.LowcamError`, an operating-system error (a full disk, a folder
    that cannot be written) or running out of memory is one line on stderr and exit status 2; Ctrl-C is one line
    and 130. Anything else is a bug and keeps its traceback. ``--debug`` (or ``LOWCAM_DEBUG=1``) shows the
    traceback of every error; without it, library warnings stay off the terminal."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)   # a value out of its declared range is refused here, naming the option
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    debug = args.debug or os.environ.get("LOWCAM_DEBUG", "") not in ("", "0")
    with warnings.catch_warnings():
        if not debug:
            warnings.simplefilter("ignore")

        command = command_name(parser, args)
        try:
            _trust_plugins(args)
            check_declared_files(parser, args)   # no output is an input, before any work
            return args.func(args)
        except (LowcamError, OSError, MemoryError) as e:
            end_progress_lines()
            if isinstance(e, BrokenPipeError) and _reader_gone(sys.stdout):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # `lowcam ... | head`: done
                return 0
            if debug:
                raise
            print(f"{command}: error: {_one_line(e)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            end_progress_lines()
            print(f"{command}: interrupted", file=sys.stderr)
            return 130


def _reader_gone(stream) -> bool:
    """Whether ``stream`` is a pipe whose reader has closed it (``lowcam profile search Canon | head -1``): poll
    reports an error on a pipe's writing end once no reader is left."""
    try:
        poll = select.poll()
        poll.register(stream.fileno(), select.POLLOUT)
        return any(event & select.POLLERR for _, event in poll.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _trust_plugins(args) -> None:
    """Trust the modules ``--plugin`` names (before or after the command; ``diagnose --plugin MODULE:CLASS`` too)."""
    named = list(args.plugins) + list(getattr(args, "plugins_after", []))
    if args.command == "diagnose":
        named += [p.partition(":")[0] for p in args.plugin]
    trust_plugins(*named, option="--plugin")


def _one_line(error: BaseException) -> str:
    if isinstance(error, MemoryError):
        return "out of memory" + (f" ({error})" if str(error) else "") + "; try a smaller frame or fewer workers"
    if isinstance(error, OSError):
        where = f"{error.filename}: " if error.filename else ""
        return f"{where}{error.strerror or error}"
    return " ".join(str(error).split("\n"))
