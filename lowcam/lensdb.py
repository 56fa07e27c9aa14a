"""Lenses from the lensfun database: a profile's lens distortion, lateral colour and vignetting; the search.

Lensfun (https://lensfun.github.io) holds thousands of measured lenses. Through lensfunpy (the optional extra
``pip install lowcam[lensfun]``) this module finds a lens and takes, at one focal length, aperture and focus
distance, lensfun's own interpolation of its three calibrations (``Lens.interpolate_distortion``,
``interpolate_tca``, ``interpolate_vignetting``): nothing of the database lookup or interpolation is redone here.
The terms go into Lowcam's effects unchanged, in lensfun's own models and normalisation:

- distortion (poly3, poly5, ptlens) -> ``lens_distortion`` with the same model, on the lens's projection (its
  lensfun lens type: rectilinear, or a fisheye: equidistant, equisolid, stereographic, orthographic, Thoby; as
  ``lensfun_geometry``) (:class:`~lowcam.effects.lens_models.LensfunLens`); a fisheye's focal length is the one
  lensfun's geometry conversion takes (its real focal length where the database has one);
- transverse chromatic aberration (linear, poly3) -> ``chromatic_aberration`` with ``model = "lensfun"``
  (:func:`~lowcam.effects.chromatic_aberration.lensfun_tca_offsets`);
- vignetting (pa) -> ``vignetting`` with ``model = "lensfun_pa"``
  (:func:`~lowcam.effects.vignetting.lensfun_vignetting`).

Every number written gets a ``[provenance]`` entry naming the lens, the setting and the database.

``lowcam profile search`` (:func:`search`) looks through the database's lenses and camera bodies and, in a folder
the user names, Gyroflow's lens profiles (:mod:`lowcam.gyroflow`), allowing mistyped words (rapidfuzz's
optimal string alignment distance, [RapidFuzz]).

Contents
--------
- :func:`require_lensfunpy`: import lensfunpy, or a one-line error saying how to install it
- :class:`LensEntry`: one database lens: maker, model, type, mount, focal range and which calibrations it has
- :func:`lens_entries`: every lens of the database as :class:`LensEntry`
- :class:`CameraEntry`: one database camera body: maker, model, mount, crop factor, and its lens if it has a fixed one
- :func:`camera_entries`: every camera of the database as :class:`CameraEntry`
- :data:`GYROFLOW_ENV`: the environment variable naming a folder of Gyroflow lens profiles
- :class:`GyroflowEntry`: one Gyroflow lens profile of a folder: camera, lens, mode, frame size, lens model
- :func:`gyroflow_entries`: the Gyroflow lens profiles of a folder that Lowcam reads
- :func:`gyroflow_folder`: the folder of Gyroflow lens profiles given (option or environment), checked
- :func:`name_words`: the words of a name or a search (letters of any script, digits)
- :data:`TYPO_SIMILARITY`: how similar (rapidfuzz, 0-100) a mistyped word must be to a word of a name
- :data:`TYPO_LETTERS`: how long a word must be to be taken as mistyped
- :class:`Match`: one row of a search: the entry, its score and the mistyped words it was found by
- :func:`search`: lenses, cameras and Gyroflow profiles matching a text, typos allowed, best first, filtered
- :func:`nearest_maker`: the maker a mistyped maker stands for
- :func:`makers`: the makers of the lenses, cameras and Gyroflow profiles
- :func:`is_of_type`: whether a lens type is the type asked for, or one of its kinds
- :func:`lens_types`: the lens types of the database
- :func:`nearest_names`: the names closest to a text (difflib), quoted, for an error
- :func:`find_lens`: one lens by maker and model (a one-line error with the nearest names otherwise)
- :func:`camera_crop_factor`: a camera's crop factor from the database
- :func:`calibration_aspect_ratio`: the lens entry's ``aspect-ratio`` from lensfun's XML (lensfunpy lacks it)
- :func:`real_focal_length`: the lens entry's real focal length from lensfun's XML (lensfunpy lacks it)
- :class:`LensSetting`: the lensfun terms of one lens at one setting, and the effects' values they give
- :func:`lens_setting`: the lens's calibrations interpolated by lensfun at focal length, aperture and distance
- :func:`profile_from_lensfun`: a profile: the base with the lens's distortion, TCA and vignetting

References
----------
- [Lensfun] A. Zabolotny et al., lensfun 0.3.4 (the version lensfunpy 1.x bundles), https://github.com/lensfun/lensfun;
  its database format: https://lensfun.github.io/manual/latest/dbformat.html.
- [RapidFuzz] M. Bachmann, RapidFuzz, https://github.com/rapidfuzz/RapidFuzz (``distance.OSA``: the optimal string
  alignment distance, Levenshtein's with adjacent transpositions; ``fuzz.ratio``: the normalised Indel similarity).
"""
from __future__ import annotations

import difflib
import functools
import os
import re
import shlex
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rapidfuzz import fuzz, process
from rapidfuzz.distance import OSA

from .effects.lens_models import LENSFUN_GEOMETRIES
from .errors import LowcamError
from .gyroflow import lens_in_frame, read_gyroflow_lens
from .profile import inherited_provenance
from .schema import read_json

_INSTALL = "pip install lowcam[lensfun]"


def require_lensfunpy():
    """Import lensfunpy, or raise a one-line :class:`LowcamError` saying how to install it."""
    try:
        import lensfunpy
    except ImportError:
        raise LowcamError(f"the lensfun database needs lensfunpy, which is not installed: {_INSTALL}") from None
    return lensfunpy


@functools.lru_cache(maxsize=1)
def _database():
    return require_lensfunpy().Database()


def _f32(x) -> float:
    """A lensfun number (float32) as the shortest decimal that reads back as the same float32 ("6.118", not
    "6.118000030517578")."""
    return float(np.format_float_positional(np.float32(x), unique=True, trim="-"))  # not str(): print options vary


def _model_name(calibration) -> str:
    return calibration.model.name.lower()


@dataclass(frozen=True)
class LensEntry:
    """One database lens: maker, model, mounts, focal range (mm), lensfun's crop factor and which calibrations it
    has (distortion model, TCA model, number of vignetting measurements)."""

    maker: str
    model: str
    mounts: tuple[str, ...]
    focal_range: tuple[float, float]
    crop_factor: float
    lens_type: str
    distortion: str
    tca: str
    vignetting: int
    lens: object = field(repr=False, compare=False)

    @property
    def name(self) -> str:
        """Maker and model, the maker once (lensfun's models often begin with it)."""
        return self.model if self.model.lower().startswith(self.maker.lower()) else f"{self.maker} {self.model}"

    def row(self) -> str:
        """One line of ``lowcam profile search``."""
        lo, hi = self.focal_range
        focal = f"{lo:g} mm" if lo == hi else f"{lo:g}-{hi:g} mm"
        vig = f"vignetting ({self.vignetting})" if self.vignetting else "-"
        return (f"{self.maker} | {self.model} | {self.lens_type.replace('_', ' ')} | {', '.join(self.mounts)} | "
                f"{focal} | crop {self.crop_factor:.3g} | distortion {self.distortion or '-'}, TCA {self.tca or '-'}, "
                f"{vig}")


def _entry(lens) -> LensEntry:
    kinds = lambda cals: "/".join(sorted({_model_name(c) for c in cals}))  # noqa: E731
    return LensEntry(lens.maker, lens.model, tuple(lens.mounts), (_f32(lens.min_focal or 0.0),
                     _f32(lens.max_focal or lens.min_focal or 0.0)), _f32(lens.crop_factor),
                     lens.type.name.lower(), kinds(lens.calib_distortion), kinds(lens.calib_tca),
                     len(lens.calib_vignetting), lens)


@functools.lru_cache(maxsize=1)
def lens_entries() -> tuple[LensEntry, ...]:
    """Every lens of the database (lensfunpy's bundled copy), as :class:`LensEntry`."""
    return tuple(_entry(lens) for lens in _database().lenses)


@dataclass(frozen=True)
class CameraEntry:
    """One database camera body: maker, model, lensfun's ``variant`` (a sensor mode such as ``16:9``, or another
    model of the same body; empty if none), lens mount and crop factor (35 mm film's diagonal over the sensor's);
    ``lens``: the one (rectilinear) lens of that mount when the camera has a fixed lens (compacts, phones), else
    None; ``by_name``: whether ``--camera-maker``/``--camera-model`` find this entry (no other variant of the model
    has another crop factor)."""

    maker: str
    model: str
    variant: str
    mount: str
    crop_factor: float
    lens: LensEntry | None = field(default=None, compare=False)
    by_name: bool = True

    @property
    def name(self) -> str:
        """Maker, model and variant, the maker once."""
        name = self.model if self.model.lower().startswith(self.maker.lower()) else f"{self.maker} {self.model}"
        return f"{name} ({self.variant})" if self.variant else name

    def command(self) -> str:
        """The ``lowcam profile from-lensfun`` command that puts a lens on this camera's sensor size: its own lens
        (at the shortest focal length) for a fixed-lens camera, else ``LENS-MAKER``/``LENS-MODEL`` to fill in."""
        if self.lens is not None:
            lens = (f"--maker {shlex.quote(self.lens.maker)} --model {shlex.quote(self.lens.model)} "
                    f"--focal-mm {self.lens.focal_range[0]:g}")
        else:
            lens = "--maker LENS-MAKER --model LENS-MODEL --focal-mm MM"
        camera = (f"--camera-maker {shlex.quote(self.maker)} --camera-model {shlex.quote(self.model)}"
                  if self.by_name else f"--crop-factor {self.crop_factor:.4g}")
        return f"lowcam profile from-lensfun {camera} {lens} --base fire-i -o mycam.toml"

    def row(self) -> str:
        """One line of ``lowcam profile search``."""
        model = f"{self.model} ({self.variant})" if self.variant else self.model
        return f"{self.maker} | {model} | camera | {self.mount} | crop {self.crop_factor:.3g} | {self.command()}"


@functools.lru_cache(maxsize=1)
def camera_entries() -> tuple[CameraEntry, ...]:
    """Every camera body of the database, as :class:`CameraEntry`; a camera gets its lens where exactly one lens
    of the database has the camera's mount (a fixed lens)."""
    by_mount: dict[str, list[LensEntry]] = {}
    for e in lens_entries():
        for mount in e.mounts:
            by_mount.setdefault(mount, []).append(e)
    cameras = _database().cameras
    crops: dict[tuple[str, str], set[float]] = {}
    for c in cameras:
        crops.setdefault((c.maker, c.model), set()).add(_f32(c.crop_factor))
    out = []
    for c in cameras:
        lenses = by_mount.get(c.mount, [])
        fixed = lenses[0] if len({e.name for e in lenses}) == 1 and lenses[0].lens_type == "rectilinear" else None
        out.append(CameraEntry(c.maker, c.model, c.variant or "", c.mount, _f32(c.crop_factor), fixed,
                               len(crops[(c.maker, c.model)]) == 1))
    return tuple(out)


#: The environment variable naming a folder of Gyroflow lens profiles (a copy of
#: https://github.com/gyroflow/lens_profiles) for ``lowcam profile search``.
GYROFLOW_ENV = "LOWCAM_GYROFLOW_PROFILES"


@dataclass(frozen=True)
class GyroflowEntry:
    """One Gyroflow lens profile of a folder: the file, the camera's brand and model, the lens, the video mode
    (``camera_setting``, else what the file name adds to brand, model and lens), the recorded frame (w, h px),
    the frame rate (0: not given) and the lens model (``opencv_fisheye`` or ``opencv_standard``)."""

    path: Path
    maker: str
    model: str
    lens_name: str
    mode: str
    size: tuple[int, int]
    fps: float
    distortion: str

    @property
    def name(self) -> str:
        """Brand, model, lens and mode."""
        return " ".join(w for w in (self.maker, self.model, self.lens_name, self.mode) if w)

    @property
    def lens_type(self) -> str:
        """``fisheye`` for OpenCV's fisheye model, ``rectilinear`` for its standard one (for ``--type``)."""
        return "fisheye" if self.distortion == "opencv_fisheye" else "rectilinear"

    def row(self) -> str:
        """One line of ``lowcam profile search``."""
        rate = f" at {self.fps:.4g} fps" if self.fps else ""
        return (f"{self.maker or '-'} | {self.model or '-'} | Gyroflow {self.distortion.removeprefix('opencv_')} | "
                f"lens {self.lens_name or '-'} | mode {self.mode or '-'} | {self.size[0]}x{self.size[1]}{rate} | "
                f"lowcam profile from-gyroflow {shlex.quote(str(self.path))} -o mycam.toml")


def _gyroflow_entry(path: Path) -> GyroflowEntry:
    doc = read_json(path, "Gyroflow lens profile")
    lens = read_gyroflow_lens(path, doc)       # a file Lowcam cannot make a profile of raises here, not listed
    lens_in_frame(lens)                        # ... and one whose lens folds over inside its frame
    maker, model, lens_name, setting = (str(doc.get(key) or "").strip() for key in
                                        ("camera_brand", "camera_model", "lens_model", "camera_setting"))
    if not setting:  # the mode is in the file name: GoPro_HERO11 Black_Wide_NO-EIS_1440p_4by3_1920x1440-59.94fps
        known = {w.lower() for w in (maker, model, lens_name)}
        setting = " ".join(part for part in path.stem.split("_") if part.strip().lower() not in known)
    return GyroflowEntry(path, maker, model, lens_name, setting, lens.frame, lens.fps, lens.model)


@functools.lru_cache(maxsize=4)
def gyroflow_entries(folder: Path) -> tuple[tuple[GyroflowEntry, ...], int]:
    """``(entries, skipped)``: every Gyroflow lens profile (``*.json``, in sub-folders too) of ``folder`` that
    ``lowcam profile from-gyroflow`` makes a profile of, sorted by path, and how many ``.json`` files it cannot
    (not a lens profile, damaged, another of Gyroflow's lens models, a digital lens, a lens that folds over inside
    its frame)."""
    entries, skipped = [], 0
    for path in sorted(Path(folder).rglob("*.json")):
        try:
            entries.append(_gyroflow_entry(path))
        except (LowcamError, OSError):
            skipped += 1
    return tuple(entries), skipped


def gyroflow_folder(given: str | None) -> Path | None:
    """The folder of Gyroflow lens profiles to search: ``given`` (``--gyroflow``), else the one
    :data:`GYROFLOW_ENV` names, else None. One that is no folder, or holds no lens profile Lowcam reads, is a
    one-line :class:`LowcamError` naming where it came from."""
    where, text = ("--gyroflow", given) if given else (GYROFLOW_ENV, os.environ.get(GYROFLOW_ENV, ""))
    if not text:
        return None
    if not Path(text).is_dir():
        raise LowcamError(f"{where} {text}: not a folder (give a copy of https://github.com/gyroflow/lens_profiles)")
    entries, skipped = gyroflow_entries(Path(text))
    if not entries:
        raise LowcamError(f"{where} {text}: no Gyroflow lens profile Lowcam reads in it ({skipped} .json file"
                          f"{'s' * (skipped != 1)} of other kinds); give a copy of "
                          "https://github.com/gyroflow/lens_profiles")
    return Path(text)


def name_words(text: str) -> list[str]:
    """The words of a name or a search: runs of letters (of any script) and digits, lower case."""
    return re.findall(r"[^\W_]+", text.lower())


#: A word of the search matches a word of a name with the same digits at this similarity or more (0-100: 100 (1 -
#: d / n), d the letters inserted, dropped, changed or swapped with a neighbour (rapidfuzz's optimal string
#: alignment distance, ``OSA``), n the longer word's length): one typo in four letters (``snoy``), two in eight.
TYPO_SIMILARITY = 75.0
#: Only words of the search this long may be mistyped (``lx3`` is no typo of ``x3``).
TYPO_LETTERS = 4


@dataclass(frozen=True)
class Match:
    """One row of a search: the ``entry`` (:class:`LensEntry`, :class:`CameraEntry` or :class:`GyroflowEntry`),
    its ``score`` (0-100: 100 when every word of the search is a word of its name) and ``typos``: the words of the
    search it does not contain as typed, each with the word of the name it was taken for."""

    entry: object
    score: float
    typos: tuple[tuple[str, str], ...]

    @property
    def kind(self) -> str:
        """``lens``, ``camera`` or ``gyroflow``."""
        return {LensEntry: "lens", CameraEntry: "camera", GyroflowEntry: "gyroflow"}[type(self.entry)]


def _word_score(word: str, its_words: list[str], compact: str, near: dict[str, float]) -> tuple[float, str]:
    """How well one word of the search matches a name: 100 a word of it, 95 the start of one, 90 inside one or
    across words (``1835`` in ``18-35mm``), else the rapidfuzz similarity to its nearest word, at most 89."""
    if word not in compact:
        if not near:
            return 0.0, ""
        best = max(its_words, key=lambda w: near.get(w, 0.0), default="")
        return min(near.get(best, 0.0), 89.0), best
    if word in its_words:
        return 100.0, word
    return (95.0 if any(w.startswith(word) for w in its_words) else 90.0), word


def search(text: str, maker: str | None = None, lens_type: str | None = None, focal_mm: float | None = None,
           gyroflow: Path | None = None, lensfun: bool = True) -> list[Match]:
    """The lenses and cameras of the lensfun database (with ``lensfun``) and the Gyroflow lens profiles of the
    folder ``gyroflow`` whose names match every word of ``text``, best first. A word matches a name that holds
    it or, mistyped, a word of the name at least :data:`TYPO_SIMILARITY` similar (rapidfuzz's ``OSA``); a row's
    score is the mean of its words' (:func:`_word_score`), ties going to the name nearest the whole text
    (``fuzz.ratio``), then lenses before cameras before Gyroflow profiles. ``maker``: only makers that contain it
    (case-blind); ``lens_type``: only lenses of that type or its kinds (cameras have none; Gyroflow's fisheye
    model is ``fisheye``, its standard one ``rectilinear``); ``focal_mm``: only lenses whose focal range holds it
    (mm; cameras and Gyroflow profiles have none)."""
    entries: list = []
    if lensfun:
        entries += list(lens_entries()) + list(camera_entries())
    if gyroflow is not None:
        entries += list(gyroflow_entries(Path(gyroflow))[0])
    if maker:
        entries = [e for e in entries if maker.strip().lower() in e.maker.lower()]
    if lens_type is not None:
        entries = [e for e in entries if not isinstance(e, CameraEntry) and is_of_type(e.lens_type, lens_type)]
    if focal_mm is not None:
        entries = [e for e in entries if isinstance(e, LensEntry) and
                   e.focal_range[0] - 1e-3 <= focal_mm <= e.focal_range[1] + 1e-3]
    words = name_words(text)
    if text.strip() and not words:             # punctuation only: nothing to look for, so nothing matches
        return []
    names = {id(e): name_words(f"{e.maker} {e.name}") for e in entries}
    vocabulary = sorted({w for ws in names.values() for w in ws})
    near = {}
    for word in words:  # each word of the search against every word of the names, once
        found = process.extract(word, vocabulary, scorer=OSA.normalized_similarity, limit=None,
                                score_cutoff=TYPO_SIMILARITY / 100) if len(word) >= TYPO_LETTERS else []
        digits = re.sub(r"\D", "", word)  # a typo is in the letters: g12 is no typo of g1, 24mm none of 28mm
        near[word] = {w: 100 * score for w, score, _ in found if re.sub(r"\D", "", w) == digits}
    whole = "".join(words)
    out = []
    for e in entries:
        its_words = names[id(e)]
        compact = "".join(its_words)
        scores = []
        for w in words:  # most names miss the first word: no need to score the rest
            scores.append(_word_score(w, its_words, compact, near[w]))
            if scores[-1][0] < TYPO_SIMILARITY:
                break
        else:
            out.append((Match(e, sum(s for s, _ in scores) / len(scores) if scores else 100.0,
                              tuple((w, m) for w, (s, m) in zip(words, scores) if s < 90)),
                        fuzz.ratio(whole, "".join(name_words(e.name)))))
    order = {LensEntry: 0, CameraEntry: 1, GyroflowEntry: 2}
    out.sort(key=lambda m: (-m[0].score, -m[1], order[type(m[0].entry)], m[0].entry.name.lower()))
    return [m for m, _ in out]


def nearest_maker(text: str, names) -> str | None:
    """The name of ``names`` (makers) that ``text`` is a typo of, case-blind, as :func:`search` takes a mistyped
    word (at least :data:`TYPO_SIMILARITY` similar, rapidfuzz's ``OSA``); None if there is none."""
    lowered = {name: name.lower() for name in names}
    best = process.extractOne(text.strip().lower(), lowered, scorer=OSA.normalized_similarity,
                              score_cutoff=TYPO_SIMILARITY / 100)
    return None if best is None else best[2]


def makers(gyroflow: Path | None = None, lensfun: bool = True) -> list[str]:
    """Every maker of the lensfun database's lenses and cameras (with ``lensfun``) and of the Gyroflow lens
    profiles in ``gyroflow``, sorted."""
    entries = (list(lens_entries()) + list(camera_entries()) if lensfun else []) + \
        (list(gyroflow_entries(Path(gyroflow))[0]) if gyroflow is not None else [])
    return sorted({e.maker for e in entries if e.maker}, key=str.lower)


def is_of_type(lens_type: str, asked: str) -> bool:
    """Whether a lens of ``lens_type`` is of the type ``asked``: the same, or one of its kinds (``fisheye`` asked:
    ``fisheye_equisolid`` too)."""
    return lens_type == asked or lens_type.startswith(f"{asked}_")


def lens_types() -> tuple[str, ...]:
    """The lens types of the database (lensfun's ``LensType`` names, lower case: ``rectilinear``, ``fisheye``,
    ``fisheye_equisolid``, ...)."""
    return tuple(sorted({e.lens_type for e in lens_entries()}))


def nearest_names(text: str, names, n: int = 3) -> str:
    """The ``n`` names closest to ``text`` (difflib; case-blind as a fallback), quoted and joined for an error."""
    close = difflib.get_close_matches(text, names, n=n, cutoff=0.3)
    if not close:
        lowered = {name.lower(): name for name in names}
        close = [lowered[c] for c in difflib.get_close_matches(text.lower(), list(lowered), n=n, cutoff=0.0)]
    return "; ".join(f"'{c}'" for c in close)


def find_lens(maker: str, model: str, crop_factor: float | None = None) -> LensEntry:
    """The database lens of ``maker`` and ``model``: an exact (case-insensitive) match of both, else the only lens
    whose maker and model contain the given texts; among several entries of one name (a lens measured on two
    sensors), the one whose crop factor is nearest ``crop_factor``. A one-line :class:`LowcamError` naming the
    nearest names (difflib) otherwise."""
    entries = lens_entries()
    mk, md = maker.strip().lower(), model.strip().lower()
    exact = [e for e in entries if e.maker.lower() == mk and e.model.lower() == md]
    if not exact:
        exact = [e for e in entries if mk in e.maker.lower() and md in e.model.lower()]
        if len({e.name for e in exact}) > 1:
            names = sorted({e.name for e in exact})
            raise LowcamError(f"lens '{maker} {model}' matches {len(names)} lenses of the lensfun database: "
                              f"{'; '.join(names[:6])}{' ...' if len(names) > 6 else ''} (give the full model)")
    if not exact:
        same_maker = [e for e in entries if e.maker.lower() == mk]
        if same_maker:  # the maker is right: the nearest models of that maker
            names = sorted({e.model for e in same_maker})
            near = nearest_names(model, names)
        else:
            makers = sorted({e.maker for e in entries})
            near = "makers " + nearest_names(maker, makers)
        raise LowcamError(f"--maker '{maker}' --model '{model}': the lens is not in the lensfun database; nearest: "
                          f"{near} (lowcam profile search TEXT lists lenses)")
    if crop_factor is not None:
        exact.sort(key=lambda e: abs(e.crop_factor - crop_factor))
    return exact[0]


def camera_crop_factor(maker: str, model: str) -> tuple[float, str]:
    """(crop factor, "maker model") of a camera of the database, by lensfun's own camera search; a one-line
    :class:`LowcamError` with the nearest names if there is none."""
    db = _database()
    cameras = db.find_cameras(maker, model)
    if not cameras:  # lensfun's camera models often repeat the maker ("Canon PowerShot G12")
        mk, md = maker.strip().lower(), model.strip().lower()
        cameras = [c for c in db.cameras if c.maker.lower() == mk and md in (c.model.lower(),
                   c.model.lower().removeprefix(mk).strip())]
    if not cameras:
        names = sorted({f"{c.maker} {c.model}" for c in _database().cameras})
        raise LowcamError(f"--camera-maker '{maker}' --camera-model '{model}': the camera is not in the lensfun "
                          f"database; nearest: "
                          f"{nearest_names(f'{maker} {model}', names)}")
    return _f32(cameras[0].crop_factor), f"{cameras[0].maker} {cameras[0].model}"


@functools.lru_cache(maxsize=1)
def _xml_lenses() -> dict:
    """(maker, model, crop factor to 3 decimals) -> the lens's first element in lensfun's XML files."""
    lensfunpy = require_lensfunpy()
    out: dict = {}
    for path in sorted(Path(lensfunpy.__path__[0], "db_files").glob("*.xml")):
        for el in ET.parse(path).getroot().iter("lens"):
            crop = el.findtext("cropfactor")
            key = (el.findtext("maker") or "", el.findtext("model") or "", round(float(crop or 1.0), 3))
            out.setdefault(key, el)
    return out


def _xml_lens(entry: LensEntry):
    return _xml_lenses().get((entry.maker, entry.model, round(entry.crop_factor, 3)))


def calibration_aspect_ratio(entry: LensEntry) -> float:
    """The lens entry's ``aspect-ratio`` (long / short side of the calibration sensor) from lensfun's XML files
    (lensfunpy does not expose it); lensfun's default 3:2 where the entry gives none."""
    el = _xml_lens(entry)
    text = None if el is None else el.findtext("aspect-ratio")
    if not text:
        return 1.5
    a, _, b = text.partition(":")
    return float(a) / float(b) if b else float(a)


def real_focal_length(entry: LensEntry, focal_mm: float) -> float | None:
    """The lens's real focal length (mm) at ``focal_mm`` from its ``real-focal-length`` calibrations in lensfun's
    XML (lensfunpy does not expose them), linear between calibrated focal lengths; None where it has none.
    Lensfun's geometry conversion uses it (``lfModifier::GetRealFocalLength``)."""
    el = _xml_lens(entry)
    found = sorted((float(c.get("focal")), float(c.get("real-focal"))) for c in ([] if el is None else
                   el.iter("real-focal-length")) if c.get("focal") and c.get("real-focal"))
    if not found:
        return None
    return _f32(np.interp(focal_mm, [f for f, _ in found], [r for _, r in found]))


@dataclass
class LensSetting:
    """The lensfun terms of one lens at one setting (focal length mm, f-number, focus distance m) on a camera of
    crop factor ``crop_factor``, and the values of Lowcam's effects they give (:meth:`effects`). ``geometry``: the
    lens's projection (lensfun's lens type); ``real_focal_mm``: its real focal length where the database has one
    (lensfun's geometry conversion of a fisheye uses it)."""

    entry: LensEntry
    focal_mm: float
    aperture: float
    distance_m: float
    crop_factor: float
    crop_source: str
    aspect_ratio: float
    distortion: tuple[str, list[float]] | None
    tca: tuple[str, list[float]] | None
    vignetting: list[float] | None
    geometry: str = "rectilinear"
    real_focal_mm: float | None = None

    def projection_focal_mm(self) -> float:
        """The focal length (mm) of the undistorted coordinates, LensDistortion's ``focal_length``: the nominal one,
        but for a fisheye with a real focal length that over Hugin's correction ``1 - k1`` or ``1 - a - b - c``
        (lensfun 0.3.4 ``lfModifier::Initialize``: ``GetRealFocalLength / get_hugin_focal_correction``)."""
        if self.geometry == "rectilinear" or self.real_focal_mm is None:
            return self.focal_mm
        model, terms = self.distortion or ("poly3", [0.0])
        hugin = {"poly3": 1.0 - terms[0], "ptlens": 1.0 - sum(terms)}.get(model, 1.0)
        return self.real_focal_mm / hugin

    def _frame(self) -> dict:
        lens = self.entry.lens
        return {"crop_factor": self.crop_factor, "calibration_crop_factor": self.entry.crop_factor,
                "calibration_aspect_ratio": self.aspect_ratio,
                "lensfun_center": [_f32(lens.center_x), _f32(lens.center_y)]}

    def effects(self) -> dict[str, dict]:
        """``{effect: values}`` for ``lens_distortion``, ``chromatic_aberration`` and ``vignetting`` (the last two
        only where the database has the calibration)."""
        keys = {"poly3": ("lensfun_k1",), "poly5": ("lensfun_k1", "lensfun_k2"),
                "ptlens": ("lensfun_a", "lensfun_b", "lensfun_c")}
        model, terms = self.distortion or ("poly3", [0.0])
        out = {"lens_distortion": {"model": model, "focal_length": self.projection_focal_mm(), **self._frame(),
                                   **dict(zip(keys[model], terms)), "render_hfov_deg": 0.0}}
        if self.geometry != "rectilinear":  # the default stays unwritten
            out["lens_distortion"]["lensfun_geometry"] = self.geometry
        if self.tca is not None:
            tmodel, t = self.tca
            red, blue = ([t[0], 0.0, 0.0], [t[1], 0.0, 0.0]) if tmodel == "linear" else ([t[0], t[2], t[4]],
                                                                                          [t[1], t[3], t[5]])
            out["chromatic_aberration"] = {"model": "lensfun", "lensfun_red": red, "lensfun_blue": blue,
                                           **self._frame()}
        if self.vignetting is not None:
            out["vignetting"] = {"model": "lensfun_pa", "lensfun_terms": list(self.vignetting), **self._frame()}
        return out

    def provenance(self) -> dict[str, str]:
        """``[provenance]`` entries for every effect :meth:`effects` sets."""
        lensfunpy = require_lensfunpy()
        db = f"lensfun {'.'.join(str(x) for x in lensfunpy.lensfun_version[:3])} database (lensfunpy " \
             f"{lensfunpy.__version__}), {self.entry.name} (calibrated at crop factor {self.entry.crop_factor:.4g}, " \
             f"aspect {self.aspect_ratio:.4g})"
        crop = f"on a camera of crop factor {self.crop_factor:.4g} ({self.crop_source})"
        fmt = lambda xs: ", ".join(f"{x:.6g}" for x in xs)  # noqa: E731
        out = {}
        kind = self.geometry.replace("_", " ")
        if self.geometry == "rectilinear":
            focal = "focal_length is the nominal focal length"
        elif self.real_focal_mm is None:
            focal = f"a {kind} lens (lensfun's lens type); focal_length is the nominal focal length"
        else:
            focal = f"a {kind} lens (lensfun's lens type); focal_length is the database's real focal length " \
                    f"{self.real_focal_mm:g} mm over Hugin's correction (1 - k1 or 1 - a - b - c), as lensfun's " \
                    "geometry conversion takes it"
        if self.distortion is None:
            ideal = "a pinhole" if self.geometry == "rectilinear" else f"an ideal {kind} projection"
            out["lens_distortion"] = f"{db}: the database has no distortion calibration for this lens: {ideal} " \
                                     f"(poly3 k1 = 0) of focal length {self.projection_focal_mm():g} mm {crop}"
        else:
            model, terms = self.distortion
            out["lens_distortion"] = f"{db} at {self.focal_mm:g} mm {crop}: {model} terms {fmt(terms)} " \
                                     f"(lensfun's interpolation); {focal}"
        if self.tca is not None:
            model, terms = self.tca
            out["chromatic_aberration"] = f"{db} at {self.focal_mm:g} mm {crop}: TCA {model} terms " \
                                          f"{fmt(terms)} (lensfun's interpolation)"
        if self.vignetting is not None:
            out["vignetting"] = f"{db} at {self.focal_mm:g} mm, f/{self.aperture:g}, {self.distance_m:g} m {crop}: " \
                                f"pa terms {fmt(self.vignetting)} (lensfun's interpolation)"
        return out


def lens_setting(entry: LensEntry, focal_mm: float, aperture: float | None = None, distance_m: float = 1000.0,
                 crop_factor: float | None = None, crop_source: str = "") -> LensSetting:
    """The lens's calibrations at ``focal_mm``, f-number ``aperture`` (default: the lens's widest) and focus
    distance ``distance_m``, each interpolated by lensfun itself (``Lens.interpolate_*``). A focal length outside
    the lens's range, or an aperture wider than its widest, is a one-line :class:`LowcamError`."""
    lens = entry.lens
    lo, hi = entry.focal_range
    if lo and not lo * 0.999 <= focal_mm <= hi * 1.001:
        raise LowcamError(f"--focal-mm {focal_mm:g}: outside the lens's range {lo:g}-{hi:g} mm ({entry.name})")
    widest = _f32(lens.min_aperture or 0.0)
    if aperture is None:
        aperture = widest or 2.8
    elif widest and aperture < widest * 0.999:
        raise LowcamError(f"{entry.name}: f/{aperture:g} is wider than the lens's widest aperture f/{widest:g}")
    if distance_m <= 0:
        raise LowcamError(f"{entry.name}: the focus distance must be positive, got {distance_m:g} m")
    if crop_factor is None:
        crop_factor, crop_source = entry.crop_factor, "the lens's calibration crop factor"
    dist = lens.interpolate_distortion(focal_mm) if lens.calib_distortion else None
    tca = lens.interpolate_tca(focal_mm) if lens.calib_tca else None
    vig = lens.interpolate_vignetting(focal_mm, aperture, distance_m) if lens.calib_vignetting else None
    return LensSetting(
        entry, float(focal_mm), float(aperture), float(distance_m), float(crop_factor), crop_source,
        calibration_aspect_ratio(entry),
        None if dist is None or _model_name(dist) == "none" else (_model_name(dist), [_f32(t) for t in
                                                                  dist.terms[:{"poly3": 1, "poly5": 2}.get(
                                                                      _model_name(dist), 3)]]),
        None if tca is None or _model_name(tca) == "none" else (_model_name(tca), [_f32(t) for t in tca.terms]),
        None if vig is None or _model_name(vig) != "pa" else [_f32(t) for t in vig.terms[:3]],
        entry.lens_type, real_focal_length(entry, focal_mm))


def profile_from_lensfun(base, maker: str, model: str, focal_mm: float, aperture: float | None = None,
                         distance_m: float = 1000.0, camera: tuple[str, str] | None = None,
                         crop_factor: float | None = None):
    """``(profile, setting)``: the ``base`` profile (a :class:`~lowcam.profile.Profile`) with the lens's
    distortion, TCA and vignetting at that setting (:func:`lens_setting`) and their provenance; the camera's crop
    factor from ``camera`` (maker, model) in the database, else ``crop_factor``, else the lens's own. Effects the
    database has no calibration for keep the base's values and provenance."""
    if camera is not None and crop_factor is not None:
        raise LowcamError("give either a camera (--camera-maker/--camera-model) or --crop-factor, not both")
    source = ""
    if camera is not None:
        crop_factor, name = camera_crop_factor(*camera)
        source = f"camera {name} in the lensfun database"
    elif crop_factor is not None:
        if not 0.1 <= crop_factor <= 100:
            raise LowcamError(f"--crop-factor {crop_factor:g} is outside 0.1..100")
        source = "given"
    entry = find_lens(maker, model, crop_factor)
    if entry.lens_type not in LENSFUN_GEOMETRIES:
        raise LowcamError(f"{entry.name}: a {entry.lens_type.replace('_', ' ')} lens; Lowcam takes rectilinear and "
                          f"fisheye lenses from lensfun ({', '.join(g.replace('_', ' ') for g in LENSFUN_GEOMETRIES)})")
    setting = lens_setting(entry, focal_mm, aperture, distance_m, crop_factor, source)
    # the new effects' errors (a lens that folds over) name the lens and the setting, not the base's file
    source = (f"{entry.name} at {setting.focal_mm:g} mm, crop factor {setting.crop_factor:.3g}, on {base.name}'s "
              f"{base.camera.width}x{base.camera.height} frame")
    profile = base
    for name, values in setting.effects().items():
        profile = profile.with_effect(name, replace=True, source=source, **values)
    provenance = inherited_provenance(base, setting.effects())
    provenance.update(setting.provenance())
    profile.provenance = provenance
    return profile, setting
