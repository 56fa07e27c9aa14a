"""The commands of the loop: ``lowcam compare`` (the model against measurements, or against footage alone), ``lowcam
diagnose`` (what the profile lacks) and ``lowcam synth`` (a measurement set with hidden effects).

Contents
--------
- :func:`cmd_compare`: ``lowcam compare``: the model against measured frames, or (``--plate-only``) against footage
- :func:`cmd_diagnose`: ``lowcam diagnose``: rank the effects the profile may lack
- :func:`cmd_synth`: ``lowcam synth``: a measurement set from bundled scenes, with hidden effects
- :func:`add_commands`: add this module's commands to the ``lowcam`` sub-parsers
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

from ..arguments import Reads, Text, Writes, bounded_int, seed
from ..boundary import Named
from ..effects import effect_class
from ..errors import LowcamError
from ..measure.compare import compare
from ..measure.comparison_report import history_figure, read_history, record_history, write_compare_report
from ..measure.diagnose import (RENAMED_CANDIDATES, candidates, diagnose, explain, removal_candidates,
                               save_candidate_profile)
from ..measure.plate import plate_probes, read_footage
from ..measure.plate_compare import compare_plate, write_plate_report
from ..measure.sets import load_set
from ..measure.synth import parse_change, synthesise
from ..outputs import atomic_write_bytes, check_output, check_output_folder, make_output_folder
from ..parallel import one_malloc_arena
from ..profile import load_profile
from ..video import is_video
from .common import PROFILE, check_report_outputs, end_progress_lines, plate_colour_option, progress_line


def _steps_folder(output) -> Path:
    """``diagnose --until-explained``'s folder of step profiles beside ``-o``."""
    return Path(output).parent / f"{Path(output).stem}-steps"


def _diagnose_also_writes(args):
    if not (args.until_explained and args.output):
        return []
    return [Named(str(_steps_folder(args.output)), "-o (its steps folder)", "steps", "folder")]


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
    if args.plate_colour and not is_video(args.plate_only):
        raise LowcamError(f"--plate-colour {args.plate_colour}: only a video has colour tags to override "
                          f"({args.plate_only} is not a video file)")
    footage = read_footage(args.plate_only, colour=args.plate_colour)
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
    if args.plate_colour and not args.plate_only:
        raise LowcamError("compare: --plate-colour goes with --plate-only (a video)")
    check_report_outputs(args)
    profile = load_profile(args.profile)
    if args.plate_only:
        return _compare_plate_only(args, profile)
    mset = load_set(args.set, profile)
    read_history(mset.path)  # a damaged history fails before the work
    print(f"comparing {len(mset.captures)} captures with {profile.name} ...", file=sys.stderr, flush=True)
    cmp = compare(mset, profile)
    history = record_history(mset.path, str(profile.path or profile.name), cmp)
    unmasked = cmp.error_unmasked
    print(f"{mset.path}: error {cmp.error:.3f} (noise floor 1.0): {cmp.verdict}; " +
          ", ".join(f"{k} {v:.3f}" for k, v in cmp.families.items()) +
          (f"; {unmasked:.3f} with the masked pixels compared too" if unmasked != cmp.error else ""))
    if args.json:
        doc = {"error": cmp.error, "error_unmasked": unmasked, "noise_floor": cmp.noise_floor,
               "verdict": cmp.verdict, "families": cmp.families, "where": cmp.where,
               "noise_texture": cmp.noise_texture}
        atomic_write_bytes(args.json, json.dumps(doc, indent=1).encode())
    if args.report:
        page = write_compare_report(cmp, args.report, f"{profile.name} against {mset.path}", history)
        print(f"{page}: report")
    return 0


def cmd_diagnose(args) -> int:
    one_malloc_arena()      # the candidates' threads share one arena: a lower peak, the same time
    check_report_outputs(args)
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
    only = None
    if args.only is not None:  # each candidate once, by its current name; none at all is refused
        only = list(dict.fromkeys(RENAMED_CANDIDATES.get(n, n) for n in (n.strip() for n in args.only.split(","))
                                  if n))
        if not only:
            raise LowcamError(f"--only {args.only!r}: names no candidate (known: {', '.join(known)})")
    for name in only or []:
        if name not in known:
            raise LowcamError(f"--only {name}: unknown candidate (known: {', '.join(known)})")
    if args.until_explained:
        return _explain(args, mset, profile, only)
    d = diagnose(mset, profile, only, progress=progress_line)
    end_progress_lines()
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


def _explain(args, mset, profile, only=None) -> int:
    """``diagnose --until-explained``: add and refit until explained; every step's profile and the history."""
    out = Path(args.output)
    steps_dir = _steps_folder(out)
    check_output_folder(steps_dir, "-o (its steps folder)")
    with tempfile.TemporaryDirectory(prefix="lowcam-explain-") as work:
        steps = explain(mset, profile, work, args.max_steps, progress=progress_line, only=only)
        end_progress_lines()
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


def add_commands(sub) -> None:
    """Add this module's commands to ``sub`` (the ``lowcam`` sub-parsers)."""
    p = sub.add_parser("compare", help="the model against measured frames: error, where it fails, probes")
    p.add_argument("set", nargs="?", type=Reads("set"), help="measurement-set folder (with set.toml)")
    p.add_argument("--plate-only", type=Reads("footage"), metavar="FOOTAGE",
                   help="no chart, no ideal: compare the plate probes' statistics of this video, folder or glob "
                        "of frames with the profile filming similar content")
    p.add_argument("--probes", type=Text(what="PROBE,..."), help="with --plate-only: comma-separated plate probes to compare (default: all)")
    plate_colour_option(p)
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

