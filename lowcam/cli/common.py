"""What the ``lowcam`` commands share: the one-line argument parser, the declared arguments several take, the checks of
a report's outputs and the progress lines.

Contents
--------
- :class:`Parser`: an argument parser whose errors are one line
- :data:`FPS`, :data:`EXPOSURE_S`, :data:`METRES_PER_UNIT`, :data:`PROFILE`, :data:`LAYER`, :data:`FRAMES`,
  :data:`RENDER_SPACE`, :data:`PLATE_COLOUR`: declared arguments several commands share
- :func:`plate_colour_option`: ``--plate-colour``, on the commands that read video plates
- :func:`check_report_outputs`: check ``--json`` and ``--report`` of compare and diagnose before any work
- :func:`progress_line`: one fitting step's progress on stderr (rewritten in place on a terminal)
- :func:`end_progress_lines`: end an open progress line and close any progress bar
"""
from __future__ import annotations

import argparse
import sys

from ..arguments import Number, Reads, Text
from ..batch import parse_frames
from ..outputs import check_output, check_output_folder
from ..render_spaces import render_space
from ..video import parse_plate_colour


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``lowcam apply: error: ... (see lowcam apply --help)``)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def _get_values(self, action, arg_strings):
        # argparse drops a lone "--" given as an option's value (--maker=--) and hands on [], unconverted and
        # unchecked: it is the value "--"
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            return self._get_value(action, "--")
        return super()._get_values(action, arg_strings)


#: Declared ranges shared by several commands.
FPS = Number(0, 1000, low_open=True, what="frames per second")
EXPOSURE_S = Number(0, 10, low_open=True, what="exposure time in s")
METRES_PER_UNIT = Number(0, 1e5, low_open=True, what="metres per scene unit")
PROFILE = Reads("profile")
LAYER = Text(what="view layer")
#: A render's colour space (:func:`lowcam.render_spaces.render_space`: acescg, linear-rec2020, Blender's names).
RENDER_SPACE = Text(what="colour space", check=render_space)
#: A video plate's matrix, range and transfer, overriding its tags (:func:`lowcam.video.parse_plate_colour`).
PLATE_COLOUR = Text(what="matrix,range[,transfer]", check=parse_plate_colour)


def plate_colour_option(p) -> None:
    """``--plate-colour``: how a video plate's Y'CbCr is read, where its tags are missing or wrong."""
    p.add_argument("--plate-colour", type=PLATE_COLOUR, metavar="MATRIX,RANGE[,TRANSFER]",
                   help="read a video plate with this matrix (bt601, bt709, bt2020), range (limited, full) and "
                        "transfer (sdr) instead of its tags, e.g. bt709,limited (default: the video's own tags)")


def _check_frames(spec: str) -> None:
    parse_frames(spec)


#: A frame list, ``1-240``, ``1-10,15``, ``1-240x2`` (:func:`lowcam.batch.parse_frames`).
FRAMES = Text(what="frames", check=_check_frames)


def check_report_outputs(args) -> None:
    """Check the ``--json`` file and the ``--report`` folder of compare and diagnose before any work."""
    if args.json:
        check_output(args.json, option="--json")
    if args.report:
        check_output_folder(args.report, "--report")


_open_line = False  # a progress line without its newline is on stderr


def progress_line(i, n, name):
    global _open_line
    _open_line = sys.stderr.isatty()
    print(f"{chr(13) if _open_line else ''}[{i + 1}/{n}] fitting {name:<24s}", end="" if _open_line else "\n",
          file=sys.stderr, flush=True)


def end_progress_lines() -> None:
    """End an open progress line, and close any progress bar, so that what follows starts on its own line."""
    global _open_line
    tqdm = sys.modules.get("tqdm")
    for bar in list(getattr(getattr(tqdm, "tqdm", None), "_instances", ()) or ()):
        bar.close()
    if _open_line:
        print(file=sys.stderr, flush=True)
        _open_line = False
