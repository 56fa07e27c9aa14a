"""Lenses from the lensfun database: a profile's lens distortion, lateral colour and vignetting.

Lensfun (https://lensfun.github.io) holds thousands of measured lenses. Through lensfunpy (the optional extra
``pip install lowcam[lensfun]``) this module finds a lens and takes, at one focal length, aperture and focus
distance, lensfun's own interpolation of its three calibrations (``Lens.interpolate_distortion``,
``interpolate_tca``, ``interpolate_vignetting``): nothing of the database lookup or interpolation is redone here.
The terms go into Lowcam's effects unchanged, in lensfun's own models and normalisation:

- distortion (poly3, poly5, ptlens) -> ``lens_distortion`` with the same model
  (:class:`~lowcam.effects.lens_models.LensfunLens`);
- transverse chromatic aberration (linear, poly3) -> ``chromatic_aberration`` with ``model = "lensfun"``
  (:func:`~lowcam.effects.chromatic_aberration.lensfun_tca_offsets`);
- vignetting (pa) -> ``vignetting`` with ``model = "lensfun_pa"``
  (:func:`~lowcam.effects.vignetting.lensfun_vignetting`).

Every number written gets a ``[provenance]`` entry naming the lens, the setting and the database.

Contents
--------
- :func:`require_lensfunpy`: import lensfunpy, or a one-line error saying how to install it
- :class:`LensEntry`: one database lens: maker, model, type, mount, focal range and which calibrations it has
- :func:`lens_entries`: every lens of the database as :class:`LensEntry`
- :func:`search_lenses`: the lenses whose maker and model contain every word of a text (of a type, at a focal length)
- :func:`corrected_search`: a search text with its mistyped words replaced by the nearest words of the database
- :func:`is_of_type`: whether a lens type is the type asked for, or one of its kinds
- :func:`lens_types`: the lens types of the database
- :func:`nearest_names`: the names closest to a text (difflib), quoted, for an error
- :func:`find_lens`: one lens by maker and model (a one-line error with the nearest names otherwise)
- :func:`camera_crop_factor`: a camera's crop factor from the database
- :func:`calibration_aspect_ratio`: the lens entry's ``aspect-ratio`` from lensfun's XML (lensfunpy lacks it)
- :class:`LensSetting`: the lensfun terms of one lens at one setting, and the effects' values they give
- :func:`lens_setting`: the lens's calibrations interpolated by lensfun at focal length, aperture and distance
- :func:`profile_from_lensfun`: a profile: the base with the lens's distortion, TCA and vignetting

References
----------
- [Lensfun] A. Zabolotny et al., lensfun 0.3.4 (the version lensfunpy 1.x bundles), https://github.com/lensfun/lensfun;
  its database format: https://lensfun.github.io/manual/latest/dbformat.html.
"""
from __future__ import annotations

import difflib
import functools
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import LowcamError
from .profile import inherited_provenance

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


def search_lenses(text: str, lens_type: str | None = None, focal_mm: float | None = None) -> list[LensEntry]:
    """The lenses whose maker and model together contain every word of ``text`` (case-insensitive), sorted; with
    ``lens_type``, only lenses of that type or its kinds (``"fisheye"`` takes ``fisheye_equisolid`` too); with
    ``focal_mm``, only lenses whose focal range holds it."""
    words = text.lower().split()
    found = [e for e in lens_entries() if all(w in e.name.lower() for w in words)
             and (lens_type is None or is_of_type(e.lens_type, lens_type))
             and (focal_mm is None or e.focal_range[0] - 1e-3 <= focal_mm <= e.focal_range[1] + 1e-3)]
    return sorted(found, key=lambda e: (e.maker.lower(), e.model.lower()))


@functools.lru_cache(maxsize=1)
def _vocabulary() -> tuple[str, ...]:
    return tuple(sorted({w for e in lens_entries() for w in re.findall(r"[a-z0-9]+", e.name.lower())}))


def corrected_search(text: str) -> str | None:
    """``text`` with each word that no lens's maker and model contain replaced by the nearest word of the
    database's makers and models (difflib, similarity at least 0.6: ``iphnoe`` -> ``iphone``); None when every
    word is found as typed, or one has no near word."""
    names = [e.name.lower() for e in lens_entries()]
    out, changed = [], False
    for word in text.lower().split():
        if any(word in name for name in names):
            out.append(word)
            continue
        close = difflib.get_close_matches(word, _vocabulary(), n=1, cutoff=0.6)
        if not close:
            return None
        out.append(close[0])
        changed = True
    return " ".join(out) if changed else None


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
def _aspect_ratios() -> dict:
    lensfunpy = require_lensfunpy()
    out: dict = {}
    for path in sorted(Path(lensfunpy.__path__[0], "db_files").glob("*.xml")):
        for el in ET.parse(path).getroot().iter("lens"):
            crop = el.findtext("cropfactor")
            key = (el.findtext("maker") or "", el.findtext("model") or "", round(float(crop or 1.0), 3))
            out.setdefault(key, el.findtext("aspect-ratio"))
    return out


def calibration_aspect_ratio(entry: LensEntry) -> float:
    """The lens entry's ``aspect-ratio`` (long / short side of the calibration sensor) from lensfun's XML files
    (lensfunpy does not expose it); lensfun's default 3:2 where the entry gives none."""
    text = _aspect_ratios().get((entry.maker, entry.model, round(entry.crop_factor, 3)))
    if not text:
        return 1.5
    a, _, b = text.partition(":")
    return float(a) / float(b) if b else float(a)


@dataclass
class LensSetting:
    """The lensfun terms of one lens at one setting (focal length mm, f-number, focus distance m) on a camera of
    crop factor ``crop_factor``, and the values of Lowcam's effects they give (:meth:`effects`)."""

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
        out = {"lens_distortion": {"model": model, "focal_length": self.focal_mm, **self._frame(),
                                   **dict(zip(keys[model], terms)), "render_hfov_deg": 0.0}}
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
        if self.distortion is None:
            out["lens_distortion"] = f"{db}: the database has no distortion calibration for this lens: a pinhole " \
                                     f"(poly3 k1 = 0) of focal length {self.focal_mm:g} mm {crop}"
        else:
            model, terms = self.distortion
            out["lens_distortion"] = f"{db} at {self.focal_mm:g} mm {crop}: {model} terms {fmt(terms)} " \
                                     "(lensfun's interpolation); focal_length is the nominal focal length"
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
        None if vig is None or _model_name(vig) != "pa" else [_f32(t) for t in vig.terms[:3]])


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
    if entry.lens_type != "rectilinear":
        raise LowcamError(f"{entry.name}: a {entry.lens_type.replace('_', ' ')} lens; Lowcam takes only "
                          "rectilinear lenses from lensfun so far")
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
