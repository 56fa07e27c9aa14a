"""The ``lowcam`` command line. Every user-facing problem is one line on stderr and exit status 2; ``--debug``
shows its traceback.

Every option declares what it is (:mod:`lowcam.arguments`: the files it reads or writes, a number's range), so
:func:`main` refuses an output that is one of the command's inputs before any work (:mod:`lowcam.boundary`).

Other packages add commands through the ``lowcam.commands`` entry-point group: the Blender side adds ``demo``,
``render``, ``motion`` and ``node-asset`` (``addon/commands.py``); the engine knows none of them by name.

Contents
--------
- :class:`Parser`: an argument parser whose errors are one line
- :data:`FPS`, :data:`EXPOSURE_S`, :data:`METRES_PER_UNIT`, :data:`PROFILE`, :data:`LAYER`, :data:`FRAMES`: declared
  arguments several commands share; :data:`IMAGE_SUFFIXES`: the images Lowcam writes (:mod:`lowcam.io`'s)
- :func:`cmd_apply`: ``lowcam apply``: simulate the camera on one render
- :func:`save_stages`: write each stage's picture as PNG (the working image premultiplied over black)
- :func:`cmd_stages`: ``lowcam stages``: every stage's intermediate output as an image
- :func:`cmd_profiles`: ``lowcam profiles [NAME]``: list the profiles, or one profile's provenance
- :func:`cmd_batch`: ``lowcam batch``: run the camera over a shot, resumable, optionally on Dask
- :func:`cmd_chart`: ``lowcam chart``: the printable calibration chart and its layout
- :func:`cmd_calibrate`: ``lowcam calibrate``, through :data:`lowcam.calibrate.CALIBRATIONS`
- :func:`cmd_compare`: ``lowcam compare``: the model against measured frames, or (``--plate-only``) against footage
- :func:`cmd_diagnose`: ``lowcam diagnose``: rank the effects the profile may lack
- :func:`cmd_synth`: ``lowcam synth``: a measurement set from bundled scenes, with hidden effects
- :func:`cmd_profile_from_lensfun`: ``lowcam profile from-lensfun``: a base profile with a lensfun database lens
- :func:`cmd_profile_search`: ``lowcam profile search TEXT``: lenses of the lensfun database that match
- :func:`cmd_profile_from_dng`: ``lowcam profile from-dng``: a profile's sensor from a DNG file's metadata
- :func:`add_plugin_commands`: commands other packages add through the ``lowcam.commands`` entry points
- :func:`build_parser`: the argument parser of every sub-command
- :func:`main`: the entry point: one line on stderr and exit status 2 for a :class:`~lowcam.errors.LowcamError`
"""
from __future__ import annotations

import argparse
import json
import os
import select
import shutil
import sys
import tempfile
import time
import warnings
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np

from . import calibrate as cal
from .arguments import Number, Reads, Text, Writes, angular_velocity, bounded_int, defocus, frame_number, seed
from .batch import Shot, check_shot_outputs, parse_frames, run_shot, summary
from .boundary import Named, check_declared_files, command_name
from .calibrate import CALIBRATIONS
from .chart import write_chart
from .dng import profile_from_dng
from .effects import effect_class, trust_plugins, trusted_modules
from .errors import LowcamError, UntrustedPlugin
from .io import read_plate, read_render
from .lensdb import lens_entries, nearest_names, profile_from_lensfun, require_lensfunpy, search_lenses
from .measure.compare import compare
from .measure.diagnose import (RENAMED_CANDIDATES, candidates, diagnose, explain, removal_candidates,
                               save_candidate_profile)
from .measure.plate import plate_probes, read_footage
from .measure.plate_compare import compare_plate, write_plate_report
from .measure.report import history_figure, read_history, record_history, write_compare_report
from .measure.sets import load_set
from .measure.synth import parse_change, synthesise
from .motion import gyro_to_motion, read_gyro_csv, read_motion_json
from .outputs import (IMAGE_SUFFIXES, atomic_write_bytes, check_image_output, check_output, check_output_folder,
                      make_output_folder, write_image, write_png)
from .passes import needed_passes, read_render_and_passes
from .pipeline import run
from .profile import list_profiles, load_profile
from .sample import sample_plate, sample_render

#: Declared ranges shared by several commands.
FPS = Number(0, 1000, low_open=True, what="frames per second")
EXPOSURE_S = Number(0, 10, low_open=True, what="exposure time in s")
METRES_PER_UNIT = Number(0, 1e5, low_open=True, what="metres per scene unit")
PROFILE = Reads("profile")
LAYER = Text(what="view layer")


def _check_frames(spec: str) -> None:
    parse_frames(spec)


#: A frame list, ``1-240``, ``1-10,15``, ``1-240x2`` (:func:`lowcam.batch.parse_frames`).
FRAMES = Text(what="frames", check=_check_frames)


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


def _load_inputs(args, profile):
    render = read_render(args.render, args.layer)
    plate = None
    if args.plate:
        c = profile.camera
        plate = read_plate(args.plate, c.width, c.height, channels=None if profile.is_raw else 3)
    return render, plate


def _pass_effects(args) -> tuple:
    """The effects ``--object-motion`` and ``--defocus`` add to the profile, as ``(name, ((key, value), ...))``."""
    effects = []
    if args.object_motion:
        effects.append(("object_motion", ()))
    if args.defocus:
        effects.append(("depth_of_field", (("focus_distance_m", args.defocus[0]), ("aperture_mm", args.defocus[1]))))
    return tuple(effects)


def _pass_options(p, fps: bool) -> None:
    """``--object-motion``, ``--defocus`` and the units of the render passes they read (apply and batch)."""
    p.add_argument("--object-motion", action="store_true",
                   help="blur moving objects along the render's Vector pass (a Blender multilayer EXR)")
    p.add_argument("--defocus", type=defocus, metavar="FOCUS_M,APERTURE_MM",
                   help="defocus from the render's Depth (Z) pass: focus distance (m), aperture diameter (mm)")
    if fps:
        p.add_argument("--fps", type=FPS, default=24.0,
                       help="frame rate of the render's Vector pass (pixels per frame; default 24)")
    p.add_argument("--metres-per-unit", type=METRES_PER_UNIT, default=1.0,
                   help="the Depth pass's unit in metres (Blender's Unit Scale; default 1)")


def cmd_apply(args) -> int:
    check_image_output(args.output)
    profile = load_profile(args.profile)
    for name, values in _pass_effects(args):
        profile = profile.with_effect(name, **dict(values))
    render, passes = read_render_and_passes(args.render, args.layer, needed_passes(profile), args.fps,
                                            args.metres_per_unit)
    c = profile.camera
    plate = read_plate(args.plate, c.width, c.height, channels=None if profile.is_raw else 3) if args.plate else None
    t0 = time.perf_counter()
    result = run(render, profile, plate, args.angular_velocity, args.exposure_s, args.seed, args.frame,
                 passes=passes)
    write_image(args.output, result.frame)
    print(f"{args.output}: {profile.name}, {result.frame.shape[1]}x{result.frame.shape[0]}, "
          f"{100 * result.footprint.mean():.1f} % of pixels from the render, {1e3 * (time.perf_counter() - t0):.0f} ms")
    return 0


def save_stages(stages, folder: Path) -> list[Path]:
    """Write each stage's picture as PNG (the working image as premultiplied-over-black RGB)."""
    make_output_folder(folder)
    paths = []
    for name, img in stages.items():
        if img.dtype != np.uint8:
            img = np.clip(img[..., :3] * 255.0 + 0.5, 0, 255).astype(np.uint8)
        paths.append(write_png(folder / f"{name}.png", img))
    return paths


def cmd_stages(args) -> int:
    check_output_folder(args.output, force=args.force)
    profile = load_profile(args.profile)
    if args.render:
        render, plate = _load_inputs(args, profile)
    else:
        render, plate = sample_render(profile, 1600), sample_plate(profile)
    result = run(render, profile, plate, args.angular_velocity, args.exposure_s, args.seed, args.frame,
                 keep_stages=True)
    paths = save_stages(result.stages, Path(args.output))
    print(f"{args.output}: {len(paths)} stage images ({', '.join(p.stem for p in paths)})")
    return 0


def cmd_profiles(args) -> int:
    if args.name:
        p = load_profile(args.name)
        print(f"{p.name}: {p.camera.name} ({p.source})")
        print(f"  {'camera':22s} {p.provenance.get('camera', '(not stated)')}")
        for e in p.effects:
            print(f"  {e.name:22s} {p.provenance_of(e.name) or '(not stated)'}")
            for key, source in p.provenance.items():
                if key.startswith(f"{e.name}."):
                    print(f"    {key.partition('.')[2]:20s} {source}")
        return 0
    for name, path in list_profiles():
        try:
            p = load_profile(path)
            stated = sum(1 for e in p.effects if p.provenance_of(e.name))
            desc = (f"{p.camera.name}: {p.camera.width}x{p.camera.height}, {len(p.effects)} effects, "
                    f"provenance stated for {stated}")
        except UntrustedPlugin as e:  # nothing was imported
            desc = f"NEEDS PLUG-IN {e.effect_type}: {e.how_to_allow}"
        except LowcamError as e:
            desc = f"INVALID: {e}"
        print(f"{name:12s} {desc}  ({path})")
    return 0


def cmd_batch(args) -> int:
    frames = parse_frames(args.frames)
    check_shot_outputs(args.output, args.renders, args.plates, frames)
    load_profile(args.profile)  # fail early on a bad profile
    motion, require = {}, False
    if args.motion:
        motion, require = read_motion_json(args.motion), True
    elif args.gyro:
        if not args.fps or args.exposure_s is None:
            raise LowcamError(f"{args.gyro}: a gyro log needs --fps and --exposure-s")
        motion = gyro_to_motion(read_gyro_csv(args.gyro), frames, args.fps, args.exposure_s, args.gyro_t0,
                                args.gyro_first_frame, source=args.gyro)
        require = True
    shot = Shot(args.profile, args.renders, args.output, args.plates, motion, require, args.seed,
                args.video_first_frame, args.layer, args.motion or args.gyro or "the motion file",
                _pass_effects(args), args.fps or 24.0, args.metres_per_unit, tuple(sorted(trusted_modules())))
    shot.load_profile()  # a bad --defocus value fails here, once
    t = time.perf_counter()
    results = run_shot(shot, frames, args.force, args.workers, args.scheduler, args.quiet)
    done = sum(r.status == "written" for r in results)
    elapsed = time.perf_counter() - t
    rate = f" ({done / elapsed:.2f} frames/s written)" if done else ""
    failed = any(r.status == "failed" for r in results)
    print(f"{summary(results)}\n{len(frames)} frames in {elapsed:.1f} s{rate}",
          file=sys.stderr if failed else sys.stdout)
    return 1 if failed else 0


def cmd_chart(args) -> int:
    if Path(args.output).suffix.lower() not in (".pdf", ".png"):
        raise LowcamError(f"{args.output}: the chart is written as .pdf or .png")
    check_output(args.output)
    layout = Path(args.output).with_suffix(".json")
    check_output(layout, option="the layout beside -o")
    if layout.exists() and b'"lowcam-chart"' not in layout.read_bytes()[:200]:
        raise LowcamError(f"{layout}: exists and is not a chart layout; the chart's layout would replace it")
    chart, layout = write_chart(args.output, args.size, args.dpi)
    print(f"{chart}: {args.size.upper()} calibration chart at {args.dpi} dpi; layout in {layout}")
    return 0


def cmd_calibrate(args) -> int:
    if args.what == "list":
        for name, effects in cal.calibration_listing().items():
            c = cal.CALIBRATIONS.get(name)
            about = (c.help + (f" (also: {', '.join(c.aliases)})" if c.aliases else "")) if c else "no such calibration"
            print(f"{name:22s} {', '.join(effects) or '-':24s} {about}")
        return 0
    out = Path(check_output(args.output))
    if out.suffix.lower() != ".toml":
        raise LowcamError(f"{out}: a profile is written as .toml")
    plots = Path(args.plots) if args.plots else _default_plots(out)
    check_output_folder(plots, "--plots")
    if args.report:
        check_output_folder(args.report, "--report")
    if args.json:
        check_output(args.json, [out], "--json")
    base = load_profile(args.profile or (out if out.is_file() else "fire-i"))
    new_plots = not plots.exists()
    try:
        if args.what == "all":
            base_from_manifest, results = cal.run_manifest(args.manifest, plots)
            if not args.profile:
                base = base_from_manifest
        else:
            results = [cal.CALIBRATIONS[args.calibration].from_args(args, base, plots)]
        for r in results:
            print(r.summary)
            for note in r.notes + (r.numbers.get("skipped", []) if isinstance(r.numbers, dict) else []):
                print(f"  {note}")
        saved = cal.apply_to_profile(base, results, out).save(out)
    except BaseException:  # a refused fit (or Ctrl-C) leaves no plots folder of a profile never written
        if new_plots:
            shutil.rmtree(plots, ignore_errors=True)
        raise
    figures = [f for r in results for f in r.figures]
    print(f"{saved}: profile written" + (f"; plots in {plots}" if figures else ""))
    if args.report:
        print(f"{cal.write_report(results, args.report)}: report")
    if args.json:
        doc = {"profile": str(saved), "calibrations": [{"what": r.what, "summary": r.summary, "notes": r.notes,
                                                        "provenance": r.provenance, "numbers": r.numbers}
                                                       for r in results]}
        atomic_write_bytes(args.json, json.dumps(doc, indent=1, default=_plain).encode())
    return 0


def _plain(value):
    """A number array or scalar as JSON takes it (a list, a float); anything else as text."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def _default_plots(output) -> Path:
    """``calibrate``'s plots folder without ``--plots``: ``<output>-plots`` beside the profile."""
    return Path(output).parent / f"{Path(output).stem}-plots"


def _calibrate_also_writes(args):
    if args.plots or not args.output:
        return []
    return [Named(str(_default_plots(args.output)), "-o (its plots folder)", "plots", "folder")]


def _steps_folder(output) -> Path:
    """``diagnose --until-explained``'s folder of step profiles beside ``-o``."""
    return Path(output).parent / f"{Path(output).stem}-steps"


def _diagnose_also_writes(args):
    if not (args.until_explained and args.output):
        return []
    return [Named(str(_steps_folder(args.output)), "-o (its steps folder)", "steps", "folder")]


def _check_report_outputs(args) -> None:
    """Check the ``--json`` file and the ``--report`` folder of compare and diagnose before any work."""
    if args.json:
        check_output(args.json, option="--json")
    if args.report:
        check_output_folder(args.report, "--report")


_open_line = False  # a progress line without its newline is on stderr


def _progress_line(i, n, name):
    global _open_line
    _open_line = sys.stderr.isatty()
    print(f"{chr(13) if _open_line else ''}[{i + 1}/{n}] fitting {name:<24s}", end="" if _open_line else "\n",
          file=sys.stderr, flush=True)


def _end_progress_lines() -> None:
    """End an open progress line, and close any progress bar, so that what follows starts on its own line."""
    global _open_line
    tqdm = sys.modules.get("tqdm")
    for bar in list(getattr(getattr(tqdm, "tqdm", None), "_instances", ()) or ()):
        bar.close()
    if _open_line:
        print(file=sys.stderr, flush=True)
        _open_line = False


def _compare_plate_only(args, profile) -> int:
    """``lowcam compare --plate-only FOOTAGE``: the plate probes' statistics, profile against footage."""
    probes = plate_probes()
    if args.probes:
        names = [n.strip() for n in args.probes.split(",") if n.strip()]
        known = {p.name: p for p in plate_probes()}
        unknown = [n for n in names if n not in known]
        if unknown:
            raise LowcamError(f"--probes: no plate probe {', '.join(unknown)} (there are: {', '.join(known)})")
        probes = [known[n] for n in names]
    footage = read_footage(args.plate_only)
    cmp = compare_plate(footage, profile, probes)
    worst = cmp.where["worst"]
    print(f"{args.plate_only}: error {cmp.error:.3f} (noise floor 1.0): {cmp.verdict}; " +
          ", ".join(f"{k} {v:.3f}" for k, v in cmp.families.items()))
    print(f"where: {worst['probe']} ({worst['effect']}), error {worst['error']:.2f}: {worst['worst_statistic']} "
          f"footage {worst['footage']:.4g}, model {worst['model']:.4g}")
    for name, why in cmp.skipped.items():
        print(f"  {name}: skipped ({why})")
    if args.json:
        doc = {"error": cmp.error, "noise_floor": cmp.noise_floor, "verdict": cmp.verdict, "families": cmp.families,
               "where": cmp.where, "skipped": cmp.skipped, "statistics": [s.as_dict() for s in cmp.statistics]}
        atomic_write_bytes(args.json, json.dumps(doc, indent=1).encode())
    if args.report:
        page = write_plate_report(cmp, args.report, f"{profile.name} against the plate {args.plate_only}")
        print(f"{page}: report")
    return 0


def cmd_compare(args) -> int:
    if (args.set is None) == (args.plate_only is None):
        raise LowcamError("compare: give a measurement set or --plate-only FOOTAGE (one of the two)")
    if args.probes and not args.plate_only:
        raise LowcamError("compare: --probes goes with --plate-only")
    _check_report_outputs(args)
    profile = load_profile(args.profile)
    if args.plate_only:
        return _compare_plate_only(args, profile)
    mset = load_set(args.set, profile)
    read_history(mset.path)  # a damaged history fails before the work
    print(f"comparing {len(mset.captures)} captures with {profile.name} ...", file=sys.stderr, flush=True)
    cmp = compare(mset, profile)
    history = record_history(mset.path, str(profile.path or profile.name), cmp)
    print(f"{mset.path}: error {cmp.error:.3f} (noise floor 1.0): {cmp.verdict}; " +
          ", ".join(f"{k} {v:.3f}" for k, v in cmp.families.items()))
    if args.json:
        doc = {"error": cmp.error, "noise_floor": cmp.noise_floor, "verdict": cmp.verdict, "families": cmp.families,
               "where": cmp.where}
        atomic_write_bytes(args.json, json.dumps(doc, indent=1).encode())
    if args.report:
        page = write_compare_report(cmp, args.report, f"{profile.name} against {mset.path}", history)
        print(f"{page}: report")
    return 0


def cmd_diagnose(args) -> int:
    _check_report_outputs(args)
    if (args.add_best or args.until_explained) and not args.output:
        raise LowcamError(f"{'--add-best' if args.add_best else '--until-explained'} needs -o NEW.toml")
    if args.output:
        check_output(args.output)
    profile = load_profile(args.profile)
    for plugin in args.plugin:  # a bare MODULE only trusts it (main)
        if ":" in plugin:
            effect_class(plugin, "--plugin")
    mset = load_set(args.set, profile)
    known = [*candidates(), *removal_candidates(profile)]       # without_EFFECT too: a row the Match panel adds
    only = [RENAMED_CANDIDATES.get(n, n) for n in args.only.split(",")] if args.only else None
    for name in only or []:
        if name not in known:
            raise LowcamError(f"--only {name}: unknown candidate (known: {', '.join(known)})")
    if args.until_explained:
        return _explain(args, mset, profile)
    d = diagnose(mset, profile, only, progress=_progress_line)
    _end_progress_lines()
    if args.add_best and d.best is None:  # refused before anything is written
        raise LowcamError(f"{mset.path}: no candidate could be fitted to this set; --add-best has none to add")
    doc = d.as_json()
    atomic_write_bytes(args.json, json.dumps(doc, indent=1).encode())
    print(f"{mset.path}: {d.summary()} ({d.seconds:.1f} s)")
    for c in d.candidates[:5]:
        held = "not held out" if c.held_out is None else f"held out {c.held_out:.3f}"
        flags = f" [{'; '.join(c.flags)}]" if c.flags else ""
        print(f"  {c.effect:28s} error {c.error_after:.3f} in sample, {held}{flags}  {c.evidence}")
    shown = d.not_fitted if only else {}  # asked for by name: say why each one that failed could not be fitted
    for name, why in shown.items():
        print(f"  {name:28s} not fitted: {why}")
    if args.report:
        page = write_compare_report(d.comparison, args.report, f"Diagnosis of {profile.name} against {mset.path}",
                                    extra={"candidates": doc["candidates"], "not_fitted": doc["not_fitted"],
                                           "measured": doc["measured"]})
        print(f"{page}: report")
    if args.add_best:
        saved = save_candidate_profile(d.best, args.output)
        added = [c.effect for c in d.added] + [d.best.effect]
        print(f"{saved}: {profile.name} with {' and '.join(dict.fromkeys(added))} added")
    return 0


def _explain(args, mset, profile) -> int:
    """``diagnose --until-explained``: add and refit until explained; every step's profile and the history."""
    out = Path(args.output)
    steps_dir = _steps_folder(out)
    check_output_folder(steps_dir, "-o (its steps folder)")
    with tempfile.TemporaryDirectory(prefix="lowcam-explain-") as work:
        steps = explain(mset, profile, work, args.max_steps, progress=_progress_line)
        _end_progress_lines()
        make_output_folder(steps_dir)
        history, doc = [], []
        for k, step in enumerate(steps):
            d = step.diagnosis
            history.append({"profile": "start" if k == 0 else f"+ {steps[k - 1].added.effect}", "error": d.error})
            entry = {"step": k, "error": round(d.error, 4), "verdict": d.verdict, "summary": d.summary(),
                     "measured": d.comparison.measured, "candidates": [c.as_json() for c in d.candidates[:8]],
                     "not_fitted": [{"effect": n, "reason": r} for n, r in d.not_fitted.items()]}
            if step.added is not None:
                path = save_candidate_profile(step.added, steps_dir / f"{k + 1:02d}-{step.added.effect}.toml",
                                              step.profile)
                entry.update(added=step.added.effect, profile=str(path))
            doc.append(entry)
            print(f"step {k}: {d.summary()}" + (f"; adding {step.added.effect}" if step.added else ""))
        final = steps[-1]
        saved = save_candidate_profile(final.diagnosis.best, out, final.profile) if len(steps) > 1 else \
            profile.save(out)
        figure = history_figure(history, steps_dir)
    atomic_write_bytes(args.json, json.dumps({"steps": doc, "error": doc[-1]["error"],
                                              "verdict": doc[-1]["verdict"]}, indent=1).encode())
    print(f"{saved}: the profile after {len(steps) - 1} added effect(s); each step's profile and {figure.name} "
          f"in {steps_dir}")
    if args.report:
        page = write_compare_report(final.diagnosis.comparison, args.report,
                                    f"{profile.name} made to explain {mset.path}", history,
                                    extra={"steps": doc})
        print(f"{page}: report")
    return 0


def cmd_synth(args) -> int:
    check_output_folder(args.output, force=args.force)
    profile = load_profile(args.profile)
    folder = synthesise(profile, args.output, [parse_change(a) for a in args.add or []], args.remove or [],
                        args.frames, args.width, args.seed)
    print(f"{folder}: measurement set of 6 captures x {args.frames} frames from {profile.name}"
          + (f" with {', '.join(args.add)}" if args.add else "")
          + (f" without {', '.join(args.remove)}" if args.remove else ""))
    return 0


# --- profile from-dng ------------------------------------------------------------------------
def cmd_profile_from_lensfun(args) -> int:
    """``lowcam profile from-lensfun``: the base profile with a database lens at one setting, written to ``-o``."""
    out = Path(check_output(args.output))
    if out.suffix.lower() != ".toml":
        raise LowcamError(f"{out}: a profile is written as .toml")
    if (args.camera_maker is None) != (args.camera_model is None):
        raise LowcamError("--camera-maker and --camera-model go together")
    require_lensfunpy()
    base = load_profile(args.base)
    camera = (args.camera_maker, args.camera_model) if args.camera_maker is not None else None
    profile, setting = profile_from_lensfun(base, args.maker, args.model, args.focal_mm, args.aperture,
                                            args.distance_m, camera, args.crop_factor)
    if args.name:
        profile.camera.name = args.name
        profile.camera.description = f"{base.camera.name} with the lens {setting.entry.name} (lensfun)"
        profile.provenance["camera"] = (f"{base.provenance.get('camera', 'not stated')} (from base {base.name}); "
                                        "name and description given to profile from-lensfun")
    profile.save(out)
    have = [name for name in ("distortion", "tca", "vignetting") if getattr(setting, name) is not None]
    print(f"{out}: {setting.entry.name} at {setting.focal_mm:g} mm, f/{setting.aperture:g}, "
          f"{setting.distance_m:g} m, crop factor {setting.crop_factor:.4g}, on {base.name}: "
          f"{', '.join(have) or 'no calibration'} from lensfun")
    return 0


def cmd_profile_search(args) -> int:
    """``lowcam profile search TEXT``: the matching lenses, one a line (maker | model | mounts | focal range |
    crop factor | calibrations); none is a one-line error with the nearest names."""
    text = " ".join(args.text)
    found = search_lenses(text)
    if not found:
        names = sorted({e.name for e in lens_entries()})
        raise LowcamError(f"no lens of the lensfun database matches '{text}'; nearest: {nearest_names(text, names)}")
    for e in found:
        print(e.row())
    print(f"{len(found)} lens{'es' if len(found) > 1 else ''}")
    return 0


def cmd_profile_from_dng(args) -> int:
    if Path(check_output(args.output)).suffix.lower() != ".toml":
        raise LowcamError(f"{args.output}: a profile is written as .toml")
    profile, notes = profile_from_dng(args.dng, load_profile(args.base))
    for note in notes:
        print(f"note: {note}")
    path = profile.save(args.output)
    noise = profile.effect("noise")
    laws = "; ".join(f"{c} [{getattr(noise, c)[0]:.4g}, {getattr(noise, c)[1]:.4g}]" for c in ("red", "green", "blue"))
    print(f"{path}: {profile.camera.name}, Bayer {profile.camera.bayer_pattern}, noise variance_linear {laws} DN"
          if noise is not None and noise.law == "variance_linear" else f"{path}: {profile.camera.name}")
    return 0
# --- end profile from-dng ---------------------------------------------------------------------------------------


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
    parser = Parser(prog="lowcam", description="Simulate a low-cost camera on CG renders (Klein & Murray 2010).")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (for a bug report)")
    parser.add_argument("--plugin", type=Text(what="MODULE"), action="append", dest="plugins", default=[],
                        metavar="MODULE",
                        help="trust this plug-in module: profiles may name its effects ('MODULE:Class'); "
                             "repeatable; LOWCAM_PLUGINS lists more (no other module is ever imported)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    def frame_options(p, render_required=True):
        p.add_argument("--profile", type=PROFILE, default="fire-i", help="profile name or TOML path (default fire-i)")
        p.add_argument("--render", type=Reads("file"), required=render_required,
                       help="premultiplied RGBA render (EXR or PNG)")
        p.add_argument("--layer", type=LAYER, help="the view layer to take from a multilayer EXR with several")
        p.add_argument("--plate", type=Reads("file"), help="the video frame (PNG/JPEG) at the camera's size")
        p.add_argument("--angular-velocity", type=angular_velocity, default=(0.0, 0.0, 0.0), metavar="WX,WY,WZ",
                       help="camera rotation in rad/s, camera frame: x right, y down, z forward")
        p.add_argument("--exposure-s", type=EXPOSURE_S, default=None, help="exposure time (s); default: the profile's")
        p.add_argument("--seed", type=seed, default=0, help="noise seed, 0 <= seed < 2^64")
        p.add_argument("--frame", type=frame_number, default=0, help="frame number (noise differs per frame)")

    p = sub.add_parser("apply", help="simulate the camera on one render")
    frame_options(p)
    _pass_options(p, fps=True)
    p.add_argument("-o", "--output", type=Writes("file", IMAGE_SUFFIXES), required=True,
                   help="output frame: .png, .jpg or .exr (code values / 255)")
    p.set_defaults(func=cmd_apply)

    p = sub.add_parser("stages", help="write every stage's intermediate output as an image")
    frame_options(p, render_required=False)
    p.add_argument("-o", "--output", type=Writes("folder"), required=True,
                   help="folder for the stage images (new, empty or Lowcam's)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files")
    p.set_defaults(func=cmd_stages)

    p = sub.add_parser("batch", help="run the camera over a shot (frame sequence), resumable, optionally on Dask")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--renders", type=Reads("pattern"), required=True, help="render pattern, '#' for frame digits: renders/####.exr")
    p.add_argument("--layer", type=LAYER, help="the view layer to take from multilayer EXRs with several")
    p.add_argument("--plates", type=Reads("pattern"), help="plate pattern (plate/####.png) or one video file")
    p.add_argument("--video-first-frame", type=frame_number, default=1,
                   help="shot frame shown by the video's first frame")
    p.add_argument("--motion", type=Reads("file"), help="motion.json: per-frame angular velocity and exposure")
    p.add_argument("--gyro", type=Reads("file"), help="gyro CSV (t, wx, wy, wz) integrated over each frame's exposure")
    p.add_argument("--fps", type=FPS, help="frame rate, for --gyro and the renders' Vector pass (default 24)")
    p.add_argument("--exposure-s", type=EXPOSURE_S, help="exposure time, for --gyro")
    p.add_argument("--gyro-t0", type=Number(-1e9, 1e9, what="gyro time in s"), default=0.0, help="gyro time (s) at which --gyro-first-frame starts")
    p.add_argument("--gyro-first-frame", type=frame_number, default=1)
    p.add_argument("--frames", type=FRAMES, required=True, help="e.g. 1-240, 1-10,15, 1-240x2")
    p.add_argument("-o", "--output", type=Writes("pattern", IMAGE_SUFFIXES), required=True,
                   help="output pattern: out/####.png")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--force", action="store_true", help="redo frames whose output exists")
    p.add_argument("--workers", type=bounded_int(0, 1024), default=0,
                   help="run on a Dask LocalCluster of N processes")
    p.add_argument("--scheduler", type=Text(what="tcp://HOST:PORT"), help="run on an existing Dask cluster: tcp://host:port")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _pass_options(p, fps=False)
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("chart", help="write the printable calibration chart and its layout")
    p.add_argument("-o", "--output", type=Writes("file", (".pdf", ".png")), required=True,
                   help="chart.pdf or chart.png")
    p.add_argument("--dpi", type=bounded_int(72, 1200), default=300)
    p.add_argument("--size", choices=("a4", "a3"), default="a4")
    p.set_defaults(func=cmd_chart)

    p = sub.add_parser("calibrate", help="measure a camera: fit effects to captures and write a profile")
    csub = p.add_subparsers(dest="what", required=True)

    def common(q):
        q.add_argument("-o", "--output", type=Writes("file", (".toml",), replaces=("profile",)), required=True,
                       help="profile TOML to write (textures go beside it)")
        q.add_argument("--profile", "--base", type=PROFILE,
                       help="profile to start from (default: the output if it exists, else fire-i)")
        q.add_argument("--report", type=Writes("folder"), help="folder for an HTML report with every plot and number")
        q.add_argument("--plots", type=Writes("folder"), help="folder for the plots (default: <output>-plots beside the profile)")
        q.add_argument("--json", type=Writes("file"),
                       help="write the profile's path and each calibration's summary as JSON")
        q.set_defaults(func=cmd_calibrate, also_writes=_calibrate_also_writes)


    for name, calibrator in CALIBRATIONS.items():
        q = csub.add_parser(name, aliases=list(calibrator.aliases), help=calibrator.help)
        calibrator.add_arguments(q)
        common(q)
        q.set_defaults(calibration=name)
    q = csub.add_parser("all", help="every calibration a manifest lists, into one profile")
    q.add_argument("manifest", type=Reads("manifest"), help="the calibration manifest (TOML)")
    common(q)
    q = csub.add_parser("list", help="every calibration and the effects it fits")
    q.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("compare", help="the model against measured frames: error, where it fails, probes")
    p.add_argument("set", nargs="?", type=Reads("set"), help="measurement-set folder (with set.toml)")
    p.add_argument("--plate-only", type=Reads("footage"), metavar="FOOTAGE",
                   help="no chart, no ideal: compare the plate probes' statistics of this video, folder or glob "
                        "of frames with the profile filming similar content")
    p.add_argument("--probes", type=Text(what="PROBE,..."), help="with --plate-only: comma-separated plate probes to compare (default: all)")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--report", type=Writes("folder"), help="folder for the HTML report and its pictures")
    p.add_argument("--json", type=Writes("file"), help="write the numbers as JSON")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("diagnose", help="rank the effects the profile may lack, fitted to the measurements")
    p.add_argument("set", type=Reads("set"), help="measurement-set folder (with set.toml)")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--json", type=Writes("file"), required=True, help="the ranked candidates as JSON")
    p.add_argument("--report", type=Writes("folder"), help="folder for an HTML report")
    p.add_argument("--only", type=Text(what="CANDIDATE,..."), help="comma-separated candidates to try (default: all)")
    p.add_argument("--plugin", type=Text(what="MODULE[:CLASS]"), action="append", default=[],
                   metavar="MODULE[:CLASS]",
                   help="trust this plug-in module and also try the effect's declared searches (repeatable)")
    p.add_argument("--add-best", action="store_true", help="write the profile with the best candidate added")
    p.add_argument("--until-explained", action="store_true",
                   help="add the best candidate and refit, step by step, until the error reaches the noise floor "
                        "or no candidate helps; writes each step's profile and the error history beside -o")
    p.add_argument("--max-steps", type=bounded_int(1, 20), default=6, help="effects --until-explained may add")
    p.add_argument("-o", "--output", type=Writes("file"), help="profile to write with --add-best or --until-explained")
    p.set_defaults(func=cmd_diagnose, also_writes=_diagnose_also_writes)

    p = sub.add_parser("synth", help="make a measurement set from bundled scenes, with hidden effects")
    p.add_argument("--profile", type=PROFILE, default="fire-i")
    p.add_argument("--add", type=Text(what="EFFECT[:k=v,...]"), action="append", metavar="EFFECT[:k=v,...]",
                   help="hide an effect (or change one)")
    p.add_argument("--remove", type=Text(what="EFFECT"), action="append", metavar="EFFECT", help="switch one of the profile's effects off")
    p.add_argument("--frames", type=bounded_int(1, 1000), default=5)
    p.add_argument("--width", type=bounded_int(64, 8192), default=640, help="render width of the ideal scenes")
    p.add_argument("--seed", type=seed, default=7)
    p.add_argument("-o", "--output", type=Writes("folder"), required=True,
                   help="folder for the set (new, empty or Lowcam's)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files")
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("profiles", help="list the profiles; with a name, where each of its numbers came from")
    p.add_argument("name", nargs="?", type=PROFILE, help="a profile name or file: show its provenance, effect by effect")
    p.set_defaults(func=cmd_profiles)

    # --- lowcam profile: profiles from outside data: a lens database, DNG metadata ---
    p = sub.add_parser("profile", help="make a profile from outside data: a lens database, DNG metadata")
    psub = p.add_subparsers(dest="what", required=True, parser_class=Parser)

    # profile from-lensfun / profile search (lowcam.lensdb)
    q = psub.add_parser("from-lensfun", help="a lens of the lensfun database (distortion, TCA, vignetting) on a "
                        "base profile (needs pip install lowcam[lensfun])")
    q.add_argument("--maker", type=Text(what="lens maker"), required=True,
                   help="lens maker, as 'lowcam profile search' lists it")
    q.add_argument("--model", type=Text(what="lens model"), required=True,
                   help="lens model (or a unique part of it)")
    q.add_argument("--focal-mm", type=Number(0, 5000, low_open=True, what="focal length in mm"), required=True,
                   help="focal length (mm) within the lens's range")
    q.add_argument("--aperture", type=Number(0.5, 64, what="f-number"), default=None,
                   help="f-number for the vignetting, 0.5 to 64 (default: widest)")
    q.add_argument("--distance-m", type=Number(0.01, 1e6, what="focus distance in m"), default=1000.0,
                   help="focus distance (m) for the vignetting, 0.01 to 1e6")
    q.add_argument("--camera-maker", type=Text(what="camera maker"), default=None,
                   help="the camera, for its crop factor (with --camera-model)")
    q.add_argument("--camera-model", type=Text(what="camera model"), default=None)
    q.add_argument("--crop-factor", type=Number(0.1, 100, what="crop factor"), default=None,
                   help="the camera's crop factor (default: the one the lens was calibrated on)")
    q.add_argument("--base", type=PROFILE, required=True, help="profile for everything else (name or file)")
    q.add_argument("--name", type=Text(what="camera name"), default=None,
                   help="the new camera's name (default: the base's)")
    q.add_argument("-o", "--output", type=Writes("file", (".toml",)), required=True, help="the new profile (.toml)")
    q.set_defaults(func=cmd_profile_from_lensfun)
    q = psub.add_parser("search", help="list lenses of the lensfun database whose maker and model contain TEXT")
    q.add_argument("text", nargs="+", type=Text(what="TEXT"), help="words of the lens's maker and model")
    q.set_defaults(func=cmd_profile_search)
    q = psub.add_parser("from-dng", help="the sensor (noise, colour, levels, CFA) from a DNG file's metadata")
    q.add_argument("dng", type=Reads("file"), help="a DNG file (a phone's or camera's raw)")
    q.add_argument("--base", type=PROFILE, default="fire-i", help="profile whose frame, optics and processing are kept")
    q.add_argument("-o", "--output", type=Writes("file", (".toml",)), required=True, help="profile TOML to write")
    q.set_defaults(func=cmd_profile_from_dng)
    for q in psub.choices.values():
        q.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)

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
            _end_progress_lines()
            if isinstance(e, BrokenPipeError) and _reader_gone(sys.stdout):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # `lowcam ... | head`: done
                return 0
            if debug:
                raise
            print(f"{command}: error: {_one_line(e)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            _end_progress_lines()
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


if __name__ == "__main__":
    sys.exit(main())
