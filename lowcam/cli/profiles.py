"""The commands about profiles: ``lowcam profiles`` (the list, or one profile's provenance) and ``lowcam profile
from-lensfun | search | from-gyroflow | from-dng`` (profiles from outside data).

Contents
--------
- :func:`cmd_profiles`: ``lowcam profiles [NAME]``: list the profiles, or one profile's provenance
- :func:`cmd_profile_from_lensfun`: ``lowcam profile from-lensfun``: a base profile with a lensfun database lens
- :data:`SEARCH_LIMIT`: the rows ``lowcam profile search`` shows by default
- :func:`cmd_profile_search`: ``lowcam profile search TEXT``: lenses, cameras and Gyroflow profiles that match
- :func:`cmd_profile_from_gyroflow`: ``lowcam profile from-gyroflow``: a profile's lens from a Gyroflow lens profile
- :func:`cmd_profile_from_dng`: ``lowcam profile from-dng``: a profile's sensor from a DNG file's metadata
- :func:`add_commands`: add this module's commands to the ``lowcam`` sub-parsers
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..arguments import Number, Numbers, Reads, Text, Writes, bounded_int
from ..dng import profile_from_dng
from ..errors import LowcamError, UntrustedPlugin
from ..gyroflow import profile_from_gyroflow
from ..lensdb import (GYROFLOW_ENV, gyroflow_entries, gyroflow_folder, is_of_type, lens_types, makers, name_words,
                      nearest_maker, nearest_names, profile_from_lensfun, require_lensfunpy, search)
from ..outputs import check_output
from ..profile import list_profiles, load_profile
from .common import PROFILE, Parser


#: ``--size WIDTH,HEIGHT``: the frame a profile from outside data delivers (px; the camera table's range).
FRAME_SIZE = Numbers((Number(16, 16384, integer=True, what="a width in px"),
                      Number(16, 16384, integer=True, what="a height in px")), 2, "WIDTH,HEIGHT in px")


def _frame_size(size) -> tuple[int, int] | None:
    """``--size`` as whole pixels, None if not given; a frame the camera cannot deliver is a one-line error."""
    if size is None:
        return None
    w, h = (int(round(x)) for x in size)
    if w % 4 or h % 2:
        raise LowcamError(f"--size {w},{h}: the frame must be a multiple of 4 wide and 2 high")
    return w, h


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
    size = _frame_size(args.size)
    if size is not None:
        base = base.with_frame(*size, "--size")
    profile, setting = profile_from_lensfun(base, args.maker, args.model, args.focal_mm, args.aperture,
                                            args.distance_m, camera, args.crop_factor)
    # the camera is now the base's sensor with another lens: named after the lens unless --name says otherwise
    profile.camera.name = args.name or f"{setting.entry.name} at {setting.focal_mm:g} mm"
    profile.camera.description = f"{base.camera.name} with the lens {setting.entry.name} (lensfun)"
    profile.provenance["camera"] = (f"{base.provenance.get('camera', 'not stated')} (from base {base.name}); name "
                                    f"{'given to' if args.name else 'from the lens by'} profile from-lensfun")
    profile.save(out)
    have = [name for name in ("distortion", "tca", "vignetting") if getattr(setting, name) is not None]
    print(f"{out}: {setting.entry.name} at {setting.focal_mm:g} mm, f/{setting.aperture:g}, "
          f"{setting.distance_m:g} m, crop factor {setting.crop_factor:.4g}, on {base.name}: "
          f"{', '.join(have) or 'no calibration'} from lensfun")
    return 0


#: Rows ``lowcam profile search`` shows unless ``--limit`` says otherwise.
SEARCH_LIMIT = 20


def _counted(found) -> str:
    """``"3 lenses, 1 camera, 2 Gyroflow profiles"``: the kinds of the matches, counted."""
    kinds = [m.kind for m in found]
    words = (("lens", "lenses"), ("camera", "cameras"), ("gyroflow", None))
    out = []
    for kind, plural in words:
        n = kinds.count(kind)
        if n and kind == "gyroflow":
            out.append(f"{n} Gyroflow profile{'s' if n > 1 else ''}")
        elif n:
            out.append(f"{n} {kind if n == 1 else plural}")
    return ", ".join(out)


def _search_maker(maker: str | None, folder, lensfun: bool) -> str | None:
    """The ``--maker`` to filter by: as given where a maker contains it, else the nearest maker
    (:func:`~lowcam.lensdb.nearest_maker`, said on stderr), else a one-line error with the nearest makers."""
    if not maker:
        return maker
    known = makers(folder, lensfun)
    if any(maker.strip().lower() in m.lower() for m in known):
        return maker
    best = nearest_maker(maker, known)
    if best is None:
        raise LowcamError(f"--maker {maker}: no lens, camera or Gyroflow profile of that maker; nearest: "
                          f"{nearest_names(maker, known)}")
    print(f"no maker is '{maker}'; showing '{best}'", file=sys.stderr)
    return best


def cmd_profile_search(args) -> int:
    """``lowcam profile search TEXT``: the lenses and cameras of the lensfun database and the Gyroflow lens
    profiles of a folder (``--gyroflow`` or ``LOWCAM_GYROFLOW_PROFILES``) that match, best first, one a line
    (lenses: maker | model | type | mounts | focal range | crop factor | calibrations; cameras: maker | model |
    camera | mount | crop factor | command; Gyroflow: brand | model | Gyroflow model | lens | mode | frame |
    command), filtered by ``--maker``, ``--type`` and ``--focal-mm``; at most ``--limit`` rows, then a line saying
    how many more. Mistyped words are matched by rapidfuzz, said on stderr; no match at all is a one-line error
    with the nearest names."""
    text = " ".join(args.text)
    if not text.strip() and not args.maker:
        raise LowcamError("text: give words of the name to look for, or --maker")
    folder = gyroflow_folder(args.gyroflow)
    lensfun = True
    try:
        require_lensfunpy()
    except LowcamError:
        if folder is None:
            raise
        lensfun = False
        print("lensfun's database needs lensfunpy (pip install lowcam[lensfun]): searching the Gyroflow profiles "
              "only", file=sys.stderr)
    if args.type is not None:
        types = sorted(set(lens_types() if lensfun else ()) | {"fisheye", "rectilinear"})
        if not any(is_of_type(t, args.type) for t in types):
            raise LowcamError(f"--type {args.type}: no such lens type; the database has {', '.join(types)}")
    maker = _search_maker(args.maker, folder, lensfun)
    found = search(text, maker, args.type, args.focal_mm, folder, lensfun)
    if folder is not None and gyroflow_entries(folder)[1]:
        print(f"{folder}: {gyroflow_entries(folder)[1]} .json files are not listed: Lowcam makes no profile of "
              "them (not a lens profile or damaged, a digital lens, or a lens that folds over inside its frame; "
              "lowcam profile from-gyroflow FILE says why)", file=sys.stderr)
    where = "the lensfun database" + (f" or {folder}" if folder is not None else "") if lensfun else str(folder)
    if not found:
        if (maker or args.type or args.focal_mm) and search(text, gyroflow=folder, lensfun=lensfun):
            raise LowcamError(f"nothing matching '{text}' is of the maker, type and focal length asked for "
                              "(without --maker, --type and --focal-mm: lowcam profile search TEXT)")
        if not name_words(text):
            raise LowcamError(f"nothing in {where} matches '{text}' (it holds no letters or digits to look for)")
        names = sorted({m.entry.name for m in search("", gyroflow=folder, lensfun=lensfun)})
        raise LowcamError(f"nothing in {where} matches '{text}'; nearest: {nearest_names(text, names)}")
    if found[0].typos:
        print(f"no name holds {', '.join(repr(w) for w, _ in found[0].typos)} as typed; showing "
              f"{', '.join(repr(near) for _, near in found[0].typos)}", file=sys.stderr)
    shown = found[:args.limit] if args.limit else found
    for m in shown:
        print(m.entry.row())
    if len(shown) < len(found):
        print(f"{len(shown)} of {len(found)} shown ({_counted(found)}); --limit 0 shows all, or narrow with more "
              "words, --maker, --type or --focal-mm")
    else:
        print(_counted(found))
    sys.stdout.flush()  # a reader that left (| head -1) is seen here, inside the command's error boundary
    return 0


def cmd_profile_from_gyroflow(args) -> int:
    """``lowcam profile from-gyroflow FILE.json``: the base profile with a Gyroflow lens profile's lens, rolling
    shutter and exposure limit."""
    if Path(check_output(args.output)).suffix.lower() != ".toml":
        raise LowcamError(f"{args.output}: a profile is written as .toml")
    profile, notes = profile_from_gyroflow(args.lens_profile, load_profile(args.base), _frame_size(args.size))
    path = profile.save(args.output)
    print(f"{path}: {profile.camera.name}; " + "; ".join(notes))
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


def add_commands(sub) -> None:
    """Add this module's commands to ``sub`` (the ``lowcam`` sub-parsers)."""
    p = sub.add_parser("profiles", help="list the profiles; with a name, where each of its numbers came from")
    p.add_argument("name", nargs="?", type=PROFILE, help="a profile name or file: show its provenance, effect by effect")
    p.set_defaults(func=cmd_profiles)

    # --- lowcam profile: profiles from outside data: a lens database, DNG metadata ---
    p = sub.add_parser("profile", help="make a profile from outside data: a lens database, a Gyroflow lens "
                       "profile, DNG metadata")
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
    q.add_argument("--size", type=FRAME_SIZE, default=None, metavar="WIDTH,HEIGHT",
                   help="the frame in px (default: the base's); lensfun's calibrations hold at any frame size")
    q.add_argument("--name", type=Text(what="camera name"), default=None,
                   help="the new camera's name (default: the lens and focal length)")
    q.add_argument("-o", "--output", type=Writes("file", (".toml",)), required=True, help="the new profile (.toml)")
    q.set_defaults(func=cmd_profile_from_lensfun)
    q = psub.add_parser("search", help="find lenses and cameras of the lensfun database, and Gyroflow lens profiles "
                        "(--gyroflow), by maker and model; mistyped words are allowed")
    q.add_argument("text", nargs="*", type=Text(what="TEXT"), help="words of the maker and model")
    q.add_argument("--maker", type=Text(what="maker"), default=None,
                   help="only lenses, cameras and Gyroflow profiles of this maker (or brand)")
    q.add_argument("--type", type=Text(what="lens type"),
                   help="only lenses of this type: rectilinear, fisheye (any fisheye projection), fisheye_equisolid, "
                        "... (no cameras)")
    q.add_argument("--focal-mm", type=Number(0, 5000, low_open=True, what="focal length in mm"),
                   help="only lensfun lenses whose focal range holds this focal length (mm)")
    q.add_argument("--gyroflow", type=Reads("folder"), default=None, metavar="FOLDER",
                   help="a copy of Gyroflow's lens profiles (https://github.com/gyroflow/lens_profiles) to search "
                        f"too (default: the folder ${GYROFLOW_ENV} names, if any)")
    q.add_argument("--limit", type=bounded_int(0, 10 ** 6, "a number of rows"), default=SEARCH_LIMIT,
                   help=f"show at most this many rows, best first (default {SEARCH_LIMIT}; 0: all)")
    q.set_defaults(func=cmd_profile_search)
    q = psub.add_parser("from-gyroflow", help="the lens (OpenCV fisheye or standard), rolling shutter and frame rate "
                        "of a Gyroflow lens profile (.json) on a base profile")
    q.add_argument("lens_profile", type=Reads("file"), help="a Gyroflow lens profile (JSON)")
    q.add_argument("--base", type=PROFILE, default="fire-i",
                   help="profile whose sensor and processing are kept (any frame shape)")
    q.add_argument("--size", type=FRAME_SIZE, default=None, metavar="WIDTH,HEIGHT",
                   help="the frame in px, of any shape, made from the recorded one as the camera does (scaled to "
                        "cover it, cut around the centre); default: the recorded frame")
    q.add_argument("-o", "--output", type=Writes("file", (".toml",)), required=True, help="profile TOML to write")
    q.set_defaults(func=cmd_profile_from_gyroflow)
    q = psub.add_parser("from-dng", help="the sensor (noise, colour, levels, CFA) from a DNG file's metadata")
    q.add_argument("dng", type=Reads("file"), help="a DNG file (a phone's or camera's raw)")
    q.add_argument("--base", type=PROFILE, default="fire-i", help="profile whose frame, optics and processing are kept")
    q.add_argument("-o", "--output", type=Writes("file", (".toml",)), required=True, help="profile TOML to write")
    q.set_defaults(func=cmd_profile_from_dng)
    for q in psub.choices.values():
        q.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)

