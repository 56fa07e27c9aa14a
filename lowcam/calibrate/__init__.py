"""Calibration from measurements (Klein & Murray 2010, sec. 4): captures in, profile parameters and plots out.

Each calibration, one module each (``lowcam.calibrate.lens``, ``.vignetting``, ``.chromatic_aberration``, ``.noise``,
``.demosaic``, ``.blur``, ``.sharpening``, ``.colour``, ``.plate``), reads the camera's frames
(:mod:`lowcam.captures`) after the shared checks (:mod:`.checks`), fits the parameters of one effect with that
effect's own fitting code (``lowcam.effects.*``), and returns a :class:`Calibration` (:mod:`.outcome`): written
into a profile (textures beside it), a one-line summary and a plot (:mod:`lowcam.reports`). :func:`write_report`
gathers the plots and numbers into an HTML page. This module is the registry and the manifest.

:data:`CALIBRATIONS` is the one table of calibrations: the ``lowcam calibrate`` sub-commands and the manifest's
sections (:func:`run_manifest`) are made from it. Effects name the calibration that measures them
(``Effect.calibration``); :func:`calibration_listing` gathers those declarations.

Contents
--------
- :class:`Texture`: a fitted texture for an effect's path parameter, written beside the profile
- :class:`Calibration`: one calibration's outcome: summary, fitted values, textures, numbers and figures
- :func:`calibrate_lens`: FOV, Brown-Conrady or fisheye lenses from chessboard or ChArUco views (sec. 4.1)
- :func:`calibrate_vignetting`: the vignetting texture from flat fields (sec. 4.1)
- :func:`calibrate_chromatic_aberration`: the lateral-colour grid from frames of the noise field (sec. 4.1)
- :func:`calibrate_noise`: both noise laws from a stack of frames of a static scene (sec. 4.3)
- :func:`calibrate_demosaic`: which demosaicing, from noise covariances of a static stack (sec. 4.4.1)
- :func:`calibrate_blur`: horizontal and vertical blur from slanted edges (sec. 4.3)
- :func:`calibrate_sharpening`: sharpening from captures at sharpness 0 and at a setting (sec. 4.4.3)
- :func:`calibrate_colour`: crosstalk from patch colours, the saturation setting divided out (sec. 4.2, 4.4.2)
- :func:`calibrate_plate`: a profile from the footage itself, no chart, no ideal (:mod:`lowcam.measure.plate`)
- :func:`apply_to_profile`: a copy of a profile with every calibration's values, textures written beside it
- :func:`write_report`: an HTML page with every calibration's summary, numbers and plots
- :class:`Option`: one input of a calibration: a manifest key and a ``lowcam calibrate`` argument
- :class:`Calibrator`: one calibration, as ``lowcam calibrate <name>`` and a manifest's ``[name]`` section run it
- :data:`CALIBRATIONS`: every calibration by name, in the order a manifest runs them
- :func:`calibrator`: the calibration called ``name`` (or one of its aliases, e.g. ``"ca"``)
- :func:`calibration_listing`: each calibration with the effects that declare it
- :func:`run_manifest`: run every calibration a manifest lists; returns (base profile, calibrations)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..arguments import Number, Reads, Text
from ..captures import chart_patch_colours, expand_paths, load_frames, parse_target, read_patches_csv
from ..colour_checker import read_colour_checker, reference_colours
from ..effects import known_effects
from ..errors import LowcamError
from ..measure.targets import patch_fall_off
from ..outputs import make_output_folder
from ..profile import load_profile
from ..schema import read_toml
from ..video import parse_plate_colour
from .blur import calibrate_blur
from .checks import source_name
from .chromatic_aberration import calibrate_chromatic_aberration
from .colour import calibrate_colour
from .demosaic import calibrate_demosaic
from .lens import calibrate_lens
from .noise import calibrate_noise
from .outcome import Calibration, Texture, apply_to_profile, write_report
from .plate import calibrate_plate
from .sharpening import calibrate_sharpening
from .vignetting import calibrate_vignetting

#: The calibrations' outcome and functions, importable from the package as from their modules.
__all__ = ["Texture", "Calibration", "apply_to_profile", "write_report", "calibrate_lens", "calibrate_vignetting",
           "calibrate_chromatic_aberration", "calibrate_noise", "calibrate_demosaic", "calibrate_blur",
           "calibrate_sharpening", "calibrate_colour", "calibrate_plate", "Option", "Calibrator", "CALIBRATIONS",
           "calibrator", "calibration_listing", "run_manifest"]


# --- the table of calibrations ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Option:
    """One input of a calibration: a key of its manifest section and an argument of its ``lowcam calibrate``
    sub-command (``--key``, or a positional argument).

    ``kind``: ``"frames"`` (file names or glob patterns; at least one if ``required``), ``"path"`` (one file),
    ``str``, or a declared number (:class:`lowcam.arguments.Number`: its range holds on the command line and in a
    manifest alike). In a manifest, frames and paths are relative to the manifest and a key left
    out takes ``default`` (an error if it has none and is ``required``); on the command line a ``required`` option
    must be given.
    """

    key: str
    kind: Any = str
    default: Any = None
    required: bool = False
    positional: bool = False
    choices: tuple[str, ...] | None = None
    help: str | None = None

    def add_argument(self, parser) -> None:
        if self.kind == "frames":
            nargs = "+" if self.required else "*"
            if self.positional:
                parser.add_argument(self.key, nargs=nargs, type=Reads("files"), help=self.help)
            else:
                parser.add_argument(self.flag, dest=self.key, nargs=nargs, type=Reads("files"),
                                    required=self.required, help=self.help)
            return
        kw = {"help": self.help, "choices": self.choices}
        if self.kind == "path":
            kw["type"] = Reads("file")
        elif self.kind is str:
            kw["type"] = Text(self.choices, what=self.key)
        else:
            kw["type"] = self.kind
        if self.positional:
            parser.add_argument(self.key, **kw)
            return
        if self.required:
            kw["required"] = True
        elif self.default is not None:
            kw["default"] = self.default
        parser.add_argument(self.flag, dest=self.key, **kw)

    @property
    def flag(self) -> str:
        return "--" + self.key.replace("_", "-")

    def from_manifest(self, section: dict, where: str, folder: Path):
        """This option's value from a manifest section: types checked, and every frame pattern and path must
        name existing files (relative to ``folder``); each problem is one line naming ``where`` and the key."""
        value = section.get(self.key)
        if self.kind == "frames":
            if value is None or value == "" or value == []:
                if self.required:
                    raise LowcamError(f"{where} needs '{self.key}'")
                return []
            names = [value] if isinstance(value, str) else value
            if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
                raise LowcamError(f"{where}: '{self.key}' must be a file name or pattern, or a list of them, got "
                                  f"{value!r}")
            for name in names:
                if not any(p.is_file() for p in expand_paths([folder / name])):
                    raise LowcamError(f"{where}: '{self.key}' entry {name!r} matches no file in {folder}")
            return [str(folder / n) for n in names]
        if value is None:
            if self.default is None and self.required:
                raise LowcamError(f"{where} needs '{self.key}'")
            return self.default
        if self.kind in ("path", str) and not isinstance(value, str):
            raise LowcamError(f"{where}: '{self.key}' must be a string, got {value!r}")
        if self.kind == "path":
            if not (folder / value).is_file():
                raise LowcamError(f"{where}: '{self.key}' = {value!r}: no such file in {folder}")
            return str(folder / value)
        if self.choices and value not in self.choices:
            raise LowcamError(f"{where}: '{self.key}' must be one of {', '.join(self.choices)}, got {value!r}")
        if isinstance(value, (bool, list, dict)):  # float(True) would pass silently
            raise LowcamError(f"{where}: '{self.key}' must be a {self.kind.__name__}, got {value!r}")
        try:
            return self.kind(value)
        except (TypeError, ValueError):
            raise LowcamError(f"{where}: '{self.key}' must be a {self.kind.__name__}, got {value!r}") from None
        except argparse.ArgumentTypeError as e:  # a declared number out of its range
            raise LowcamError(f"{where}: '{self.key}': {e}") from None


@dataclass(frozen=True)
class Calibrator:
    """One calibration, as ``lowcam calibrate <name>`` and a manifest's ``[name]`` section run it.

    ``function`` fits the parameters; ``help`` is its line in ``lowcam calibrate -h``; ``options`` its inputs
    (:class:`Option`: the sub-command's arguments beside the common ones and the manifest keys it accepts); ``run(
    options, base, plot_dir)`` calls ``function`` with the options' values (a dict), the starting profile and the
    plot folder. ``aliases`` are further sub-command names. The effects it fits are those that declare
    ``calibration = name`` (:attr:`effects`, :func:`calibration_listing`).
    """

    name: str
    function: Callable[..., Calibration]
    help: str
    options: tuple[Option, ...]
    run: Callable[[dict, Any, Path | None], Calibration]
    aliases: tuple[str, ...] = ()

    @property
    def manifest_keys(self) -> tuple[str, ...]:
        return tuple(o.key for o in self.options)

    @property
    def effects(self) -> list[str]:
        """The known effects that declare this calibration (:func:`calibration_listing`)."""
        return calibration_listing().get(self.name, [])

    def add_arguments(self, parser) -> None:
        """This calibration's arguments on its ``lowcam calibrate`` sub-parser."""
        for option in self.options:
            option.add_argument(parser)

    def from_args(self, args, base, plot_dir: Path | None = None) -> Calibration:
        """Run it with parsed command-line ``args`` (from :meth:`add_arguments`)."""
        return self.run({o.key: getattr(args, o.key) for o in self.options}, base, plot_dir)

    def check_section(self, section, where: str) -> None:
        if not isinstance(section, dict):
            raise LowcamError(f"{where} must be a table of keys ({', '.join(self.manifest_keys)})")
        unknown = sorted(set(section) - set(self.manifest_keys))
        if unknown:
            raise LowcamError(f"{where}: unknown key '{unknown[0]}' (known: {', '.join(self.manifest_keys)})")

    def from_manifest(self, section: dict, where: str, folder: Path, base,
                      plot_dir: Path | None = None) -> Calibration:
        """Run it with a manifest's section (``where`` names it in messages; paths relative to ``folder``)."""
        return self.run(self.options_from_manifest(section, where, folder), base, plot_dir)

    def options_from_manifest(self, section: dict, where: str, folder: Path) -> dict:
        """The options' values from a manifest's section, checked (:meth:`Option.from_manifest`), without running."""
        self.check_section(section, where)
        return {o.key: o.from_manifest(section, where, Path(folder)) for o in self.options}


def _lens_models(model: str) -> tuple[str, ...]:
    return ("fov", "opencv") if model == "both" else (model,)


def _run_colour(o: dict, base, plot_dir: Path | None) -> Calibration:
    notes, noise, tone, usable = None, None, None, None
    if o["patches"]:
        source = str(o["patches"])
        ideal, measured = read_patches_csv(o["patches"])
    elif o["frames"] and o["target"]:
        if parse_target(o["target"], "--target")[0] != "colorchecker":  # an unknown name is refused there
            raise LowcamError(f"--target {o['target']}: the colour calibration reads a colorchecker target")
        source = source_name(o["frames"])
        frames, names = load_frames(o["frames"], 1, "colour calibration")
        reading = read_colour_checker(frames, names, what="colour calibration")
        # each patch's light as the profile's fall-off leaves it (diagnosis simulates the same), so the matrix fits
        # the colours, not the vignetting across the chart
        ideal = reference_colours() * 255.0 * patch_fall_off(base, reading)[:, None]
        measured, noise, usable = reading.mean, reading.noise, ~reading.clipped
        curve = base.effect("tone_curve")
        if curve is not None and curve.enabled:  # fitted along, its black and white levels kept
            tone = {k: getattr(curve, k) for k in ("gamma", "toe_break", "black_dn", "white_dn")}
    elif o["frames"] and o["chart"]:
        source = source_name(o["frames"])
        ideal, measured, notes = chart_patch_colours(o["frames"], o["chart"])
    else:
        raise LowcamError("colour calibration needs --patches CSV, frames of the chart with --chart chart.json, or "
                          "frames of a ColorChecker with --target colorchecker (in a manifest: patches, or frames "
                          "and chart or target)")
    cal = calibrate_colour(ideal, measured, o["saturation"], plot_dir, source, noise, tone, usable)
    if notes is not None:
        cal.numbers["skipped"] = notes
    return cal


_FRAMES = Option("frames", "frames", required=True, positional=True)
#: A camera setting (sharpness, saturation: 0-255 on the cameras modelled; 0 is no setting to measure from).
_SETTING = Number(0, 255, low_open=True, what="a camera setting")

#: Every calibration by name, in the order a manifest runs them.
CALIBRATIONS: dict[str, Calibrator] = {c.name: c for c in (
    Calibrator("lens", calibrate_lens, "FOV and Brown-Conrady (or OpenCV's fisheye) from checkerboard or ChArUco "
               "frames",
               (_FRAMES, Option("target", str, "checkerboard:9x6:0.025",
                                help="checkerboard:COLSxROWS:SQUARE_M or charuco"),
                Option("model", str, "both", choices=("fov", "opencv", "both", "fisheye"),
                       help="the lens model fitted: both (FOV and Brown-Conrady, the closer one kept) or one; "
                            "fisheye: OpenCV's Kannala-Brandt model, by cv2.fisheye.calibrate")),
               lambda o, base, plots: calibrate_lens(o["frames"], o["target"], _lens_models(o["model"]), plots)),
    Calibrator("vignetting", calibrate_vignetting, "from flat-field frames", (_FRAMES,),
               lambda o, base, plots: calibrate_vignetting(o["frames"], plots)),
    Calibrator("chromatic_aberration", calibrate_chromatic_aberration,
               "chromatic aberration from frames of the noise field", (_FRAMES,),
               lambda o, base, plots: calibrate_chromatic_aberration(o["frames"], plots), aliases=("ca",)),
    Calibrator("noise", calibrate_noise, "both noise laws from a stack of frames of a static scene",
               (_FRAMES, Option("law", str, "sigma_linear", choices=("sigma_linear", "variance_linear"),
                                help="the law written into the profile (both are fitted and reported)"),
                Option("demosaic", str, "block", choices=("block", "bilinear"))),
               lambda o, base, plots: calibrate_noise(o["frames"], o["demosaic"], o["law"], plots, base)),
    Calibrator("demosaic", calibrate_demosaic, "identify the demosaicing from a static stack", (_FRAMES,),
               lambda o, base, plots: calibrate_demosaic(o["frames"], base.geometry, plots)),
    Calibrator("blur", calibrate_blur, "horizontal/vertical blur from slanted edges", (_FRAMES,),
               lambda o, base, plots: calibrate_blur(o["frames"], plots)),
    Calibrator("sharpening", calibrate_sharpening, "sharpening filter from captures at sharpness 0 and at a setting",
               (Option("soft", "frames", required=True), Option("sharp", "frames", required=True),
                Option("sharpness", _SETTING, 80.0, required=True, help="the camera setting of the --sharp captures")),
               lambda o, base, plots: calibrate_sharpening(o["soft"], o["sharp"], o["sharpness"], plots)),
    Calibrator("colour", calibrate_colour, "crosstalk from the chart's colour patches (or a table of patch colours)",
               (Option("frames", "frames", positional=True, help="frames showing the whole chart"),
                Option("chart", "path", help="the chart's layout JSON (written by lowcam chart)"),
                Option("target", str, help="instead of --chart: colorchecker (a ColorChecker Classic, 24 patches, "
                                           "found in the frames)"),
                Option("patches", "path",
                       help="instead: CSV ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b"),
                Option("saturation", _SETTING, 65.0, help="the camera's saturation setting")),
               _run_colour),
    Calibrator("plate", calibrate_plate, "a profile from the footage itself (no chart, no ideal): noise, edges, "
               "vignetting, gyro motion",
               (Option("footage", "frames", required=True, positional=True,
                       help="a video file, a folder of frames, or frame names or patterns"),
                Option("gyro", "path", help="gyro log: rows 'wx wy wz t' (framestamp.txt beside it), a gyro CSV, a "
                                            "Gyroflow .gcsv or .gyroflow, or a clip with its own gyro"),
                Option("fps", Number(0, 1000, low_open=True, what="frames per second"),
                       help="frames/s, 0 to 1000 (default: the video's, else 30)"),
                Option("min_confidence", Number(0, 1, what="a confidence"), 0.5,
                       help="estimates below this confidence (0 to 1) are reported, not applied"),
                Option("plate_colour", Text(what="matrix,range[,transfer]", check=parse_plate_colour),
                       help="read a video with this matrix (bt601, bt709, bt2020), range (limited, full) and "
                            "transfer (sdr) instead of its tags, e.g. bt709,limited")),
               lambda o, base, plots: calibrate_plate(o["footage"], base, o["gyro"], o["fps"], o["min_confidence"],
                                                      plots, plate_colour=o["plate_colour"])),
)}


def calibrator(name: str) -> Calibrator:
    """The calibration called ``name`` (or one of its aliases, e.g. ``"ca"``)."""
    for c in CALIBRATIONS.values():
        if name == c.name or name in c.aliases:
            return c
    raise LowcamError(f"unknown calibration '{name}' (known: {', '.join(CALIBRATIONS)})")


def calibration_listing() -> dict[str, list[str]]:
    """Which effects each calibration fits: every name of :data:`CALIBRATIONS` (in order) with the effects that
    declare it as their ``calibration`` (:func:`lowcam.effects.known_effects`, plug-ins loaded so far included).
    A name that effects declare but no calibration has comes after them.

    >>> calibration_listing()["lens"]
    ['lens_distortion']
    """
    listing: dict[str, list[str]] = {name: [] for name in CALIBRATIONS}
    for cls in known_effects():
        if cls.calibration:
            listing.setdefault(cls.calibration, []).append(cls.name)
    return listing


def run_manifest(path, plot_dir: Path | None = None):
    """Run every calibration that the manifest lists; returns (base profile, calibrations).

    Manifest (TOML; frame patterns relative to the manifest; sections and their keys from :data:`CALIBRATIONS`)::

        profile = "fire-i"                      # the profile the results are written into
        [lens]                 frames = ["chessboard/*.png"], target = "checkerboard:9x6:0.025", model = "both"
        [vignetting]           frames = ["flat/*.png"]
        [chromatic_aberration] frames = ["noise/*.png"]
        [noise]                frames = ["static/*.png"], law = "sigma_linear", demosaic = "block"
        [demosaic]             frames = ["static/*.png"]
        [blur]                 frames = ["edges/*.png"]
        [sharpening]           soft = ["soft/*.png"], sharp = ["sharp/*.png"], sharpness = 80
        [colour]               patches = "patches.csv", saturation = 90   # or frames = [...], chart = "chart.json"
                                                                  # or frames = [...], target = "colorchecker"
    """
    path = Path(path)
    doc = read_toml(path, "manifest")
    known = {"profile", *CALIBRATIONS}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise LowcamError(f"{path}: unknown manifest section '{unknown[0]}' (known: {', '.join(sorted(known))})")
    profile = doc.get("profile", "fire-i")
    if not isinstance(profile, str) or not profile:
        raise LowcamError(f"{path}: 'profile' must be a profile name or file, got {profile!r}")
    base = load_profile(profile)
    listed = [c for name, c in CALIBRATIONS.items() if name in doc]
    if not listed:
        raise LowcamError(f"{path}: the manifest lists no calibration")
    for c in listed:  # every section's keys before the first (slow) calibration runs
        c.check_section(doc[c.name], f"{path}: [{c.name}]")
    options = [c.options_from_manifest(doc[c.name], f"{path}: [{c.name}]", path.parent) for c in listed]
    if plot_dir is None:
        return base, [c.run(o, base, None) for c, o in zip(listed, options)]

    # plots go to a staging folder until every calibration has succeeded: a refusal leaves no plots behind
    with tempfile.TemporaryDirectory(prefix="lowcam-plots-") as staging:
        results = [c.run(o, base, Path(staging)) for c, o in zip(listed, options)]
        for cal in results:
            if cal.figures:
                make_output_folder(plot_dir)
            cal.figures = [Path(shutil.move(str(f), str(Path(plot_dir) / Path(f).name))) for f in cal.figures]
    return base, results
