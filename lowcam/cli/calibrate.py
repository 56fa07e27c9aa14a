"""The commands that measure a camera: ``lowcam chart`` (the printable chart) and ``lowcam calibrate`` (every
calibration of :data:`lowcam.calibrate.CALIBRATIONS`, one at a time or from a manifest).

Contents
--------
- :func:`cmd_chart`: ``lowcam chart``: the printable calibration chart and its layout
- :func:`cmd_calibrate`: ``lowcam calibrate``, through :data:`lowcam.calibrate.CALIBRATIONS`
- :func:`add_commands`: add this module's commands to the ``lowcam`` sub-parsers
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from .. import calibrate as cal
from ..arguments import Reads, Writes, bounded_int
from ..boundary import Named
from ..calibrate import CALIBRATIONS
from ..chart import write_chart
from ..errors import LowcamError
from ..outputs import atomic_write_bytes, check_output, check_output_folder
from ..profile import load_profile
from ..reports import json_value
from .common import PROFILE


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
        atomic_write_bytes(args.json, json.dumps(doc, indent=1, default=json_value).encode())
    return 0


def _default_plots(output) -> Path:
    """``calibrate``'s plots folder without ``--plots``: ``<output>-plots`` beside the profile."""
    return Path(output).parent / f"{Path(output).stem}-plots"


def _calibrate_also_writes(args):
    if args.plots or not args.output:
        return []
    return [Named(str(_default_plots(args.output)), "-o (its plots folder)", "plots", "folder")]


def add_commands(sub) -> None:
    """Add this module's commands to ``sub`` (the ``lowcam`` sub-parsers)."""
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

