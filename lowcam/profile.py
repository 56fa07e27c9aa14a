"""Camera profiles: TOML files that list the camera's frame and its ordered chain of effects.

Layout (see ``profiles/fire-i.toml`` for a complete, commented example)::

    [camera]
    name = "Unibrain Fire-i, 2.1 mm lens"
    width = 640
    height = 480
    bayer_pattern = "GBRG"
    exposure_s = 0.033

    [[effect]]
    type = "lens_distortion"      # a bundled effect, or "package.module:Class" for a plug-in
    enabled = true                # optional; a disabled effect is skipped (or takes its neutral form)
    model = "fov"
    ...

    [provenance]                  # optional: where the numbers came from
    camera = "..."                # the [camera] table
    lens_distortion = "lensfun database: Canon PowerShot G12 at 6.1 mm"   # a whole effect
    "noise.read_noise_dn" = "DNG NoiseProfile of IMG_0001.dng"           # one parameter
    video = "the bitstream of clip.mp4"

    [video]                       # optional: how the footage a profile was estimated from was coded
    codec = "h264"                # (lowcam calibrate plate reads it from the bitstream; nothing simulates it)
    gop_length = 30

Everything is validated on load: an unknown key, a wrong type or a value out of range is a one-line
:class:`~lowcam.errors.ProfileError` naming the file and the key.

Contents
--------
- :data:`BUNDLED_PROFILES`: the repository's ``profiles/`` folder
- :class:`CameraSpec`: the ``[camera]`` table: the delivered frame and global settings
- :class:`Profile`: a validated camera profile: :class:`CameraSpec` plus an ordered list of effects
- :func:`profile_search_path`: folders searched for profiles by name: ``$LOWCAM_PROFILE_PATH``, then the bundled
- :func:`list_profiles`: (name, path) of every profile on the search path
- :func:`find_profile`: the file of a profile name or path (a clear error naming the known ones)
- :func:`load_profile`: load and validate a profile by name (``"fire-i"``) or path (``"my-camera.toml"``)
- :func:`profile_from_dict`: a validated :class:`Profile` from parsed TOML
- :func:`inherited_provenance`: the base's provenance for a profile made from it, its replaced effects left out
- :func:`check_video`: validate a ``[video]`` table (the coding of the footage a profile was estimated from)
- :func:`check_provenance`: validate a ``[provenance]`` table against a profile's camera and effects

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010 (the bundled Fire-i profile's values).
"""
from __future__ import annotations

import copy
import math
import os
from functools import cached_property
from pathlib import Path

import tomli_w

from . import schema
from .effects import Effect, Param, ParamSet, effect_class
from .errors import ProfileError
from .geometry import FrameGeometry
from .outputs import atomic_write_bytes

#: Bundled profiles: the repository's ``profiles/`` folder.
BUNDLED_PROFILES = Path(__file__).resolve().parent.parent / "profiles"


class CameraSpec(ParamSet):
    """The ``[camera]`` table: the delivered frame and global settings."""

    name = "camera"
    params = {
        "name": Param("", str),
        "description": Param("", str),
        "width": Param(640, int, low=16, high=16384, unit="px"),
        "height": Param(480, int, low=16, high=16384, unit="px"),
        "bayer_pattern": Param("GBRG", str, choices=("GBRG", "GRBG", "RGGB", "BGGR")),
        "exposure_s": Param(0.033, low=0.0, high=10.0, unit="s"),
        "margin_px": Param(16.0, low=0.0, high=1024.0, unit="px", doc="working-grid margin around the frame"),
        "oversample": Param(1.6, low=0.5, high=8.0, doc="working pixels per output pixel"),
    }

    def check(self):
        if self.width % 4 or self.height % 2:
            raise self.error(f"the frame must be a multiple of 4 wide and 2 high, got {self.width}x{self.height}")


class Profile:
    """A validated camera profile: :class:`CameraSpec` plus an ordered list of :class:`~lowcam.effects.Effect`."""

    def __init__(self, camera: CameraSpec, effects: list[Effect], path: Path | None = None,
                 provenance: dict[str, str] | None = None):
        self.camera = camera
        self.effects = list(effects)
        self.path = Path(path) if path else None
        #: Where the numbers came from: ``{"camera" | "EFFECT" | "EFFECT.PARAM": source}`` (:func:`check_provenance`)
        self.provenance = dict(provenance or {})
        #: How the footage the profile was estimated from was coded (``[video]``: codec, profile, GOP, bitrate,
        #: ...), as read from its bitstream; a record, not simulated.
        self.video: dict = {}
        names = [e.name for e in self.effects]
        for needed in ("lens_distortion", "half_sampling", "bayer_sampling", "demosaic"):
            if needed not in names:
                raise ProfileError(f"{self.source}: the chain needs a '{needed}' effect")
        if "yuv_blend" not in names and "raw_blend" not in names:
            raise ProfileError(f"{self.source}: the chain needs a 'yuv_blend' or a 'raw_blend' effect")

    @property
    def source(self) -> str:
        return str(self.path) if self.path else "<profile>"

    @property
    def name(self) -> str:
        return self.path.stem if self.path else (self.camera.name or "profile")

    @property
    def is_raw(self) -> bool:
        """True for a raw-Bayer camera (sec. 7): the plate is the camera's Bayer frame."""
        return self.effect("raw_blend") is not None

    def effect(self, name: str) -> Effect | None:
        """The first effect of type ``name``, or None."""
        return next((e for e in self.effects if e.name == name), None)

    @cached_property
    def geometry(self) -> FrameGeometry:
        c = self.camera
        return FrameGeometry(c.width, c.height, c.margin_px, c.oversample, c.bayer_pattern)

    def provenance_of(self, effect: str, param: str | None = None) -> str:
        """Where ``effect`` (or its ``param``) came from: the most specific ``[provenance]`` entry, or ``""``."""
        if param and f"{effect}.{param}" in self.provenance:
            return self.provenance[f"{effect}.{param}"]
        return self.provenance.get(effect, "")

    @property
    def lens(self):
        """The lens model of the output frame (a pinhole if the lens-distortion stage is disabled)."""
        return self.effect("lens_distortion").lens_model(self.geometry)

    def copy(self) -> "Profile":
        """A deep copy whose effects can be changed without touching this profile."""
        return copy.deepcopy(self)

    def with_frame(self, width: int, height: int, source: str | None = None) -> "Profile":
        """A copy that delivers ``width`` x ``height`` px frames, its other camera settings and its effects kept
        (a lens's intrinsics are the caller's to set); a size the ``[camera]`` table refuses is a one-line
        :class:`ProfileError` naming ``source``."""
        out = self.copy()
        c = out.camera
        values = {key: getattr(c, key) for key in type(c).params}
        out.camera = type(c)(source or self.source, c.base_dir, **dict(values, width=width, height=height))
        out.__dict__.pop("geometry", None)          # the cached frame geometry is the old frame's
        return out

    def with_effect(self, name: str, replace: bool = False, source: str | None = None, base_dir=None,
                    after: str | None = None, **values) -> "Profile":
        """A copy with effect ``name`` set to ``values`` (merged into the existing effect's, or all new with
        ``replace``), enabled; an effect the chain lacks is inserted at its place (``Effect.order``: before the
        first effect of the chain that comes after it). Plug-ins without an order go to the end.

        ``after`` names an effect of the chain: the effect set is then the one standing right after it (e.g. a
        second vertical blur after ``"sharpening"``, where a scaler or codec blurs the output), inserted there
        new (from its defaults and ``values``) unless the effect right after it is already of type ``name``."""
        out = self.copy()
        cls = effect_class(name, source or self.source)
        if after is None:
            old = out.effect(cls.name)
        else:
            anchor = out.effect(effect_class(after, self.source).name)
            if anchor is None:
                raise ProfileError(f"{self.source}: no effect '{after}' to place '{cls.name}' after (the chain: "
                                   f"{', '.join(e.name for e in out.effects)})")
            at = out.effects.index(anchor) + 1
            old = out.effects[at] if at < len(out.effects) and out.effects[at].name == cls.name else None
        merged = {} if old is None or replace else old.values()
        merged.update(values)
        src = source or (old.source if old is not None else self.source)
        bdir = base_dir if base_dir is not None else (old.base_dir if old is not None else None)
        new = cls(True, src, bdir, **merged)
        if old is not None:
            out.effects[out.effects.index(old)] = new
        elif after is not None:
            out.effects.insert(at, new)
        else:
            pos = len(out.effects) if cls.order is None else next(
                (i for i, e in enumerate(out.effects) if e.order is not None and e.order > cls.order), len(out.effects))
            out.effects.insert(pos, new)
        return out

    def controls(self) -> dict:
        """The camera's user controls: ``sharpness`` and ``saturation`` (when the chain has those effects) and
        ``exposure_s`` (s). The Blender add-on and nodes show these."""
        out = {"exposure_s": self.camera.exposure_s}
        for name in ("sharpness", "saturation"):
            effect = self.effect("sharpening" if name == "sharpness" else name)
            if effect is not None:
                out[name] = getattr(effect, name)
        return out

    def with_controls(self, sharpness: float | None = None, saturation: float | None = None) -> "Profile":
        """A copy with the sharpness and saturation settings changed, where the chain has those effects."""
        out = self
        for name, effect, value in (("sharpness", "sharpening", sharpness), ("saturation", "saturation", saturation)):
            if value is not None and out.effect(effect) is not None:
                out = out.with_effect(effect, **{name: value})
        return out

    def quiet(self) -> "Profile":
        """A copy without its random and stepped effects (``Effect.random``, ``Effect.stepped``: the noise, the
        quantisation): deterministic and smooth, what fits compare against."""
        names = [e.name for e in self.effects if e.random or e.stepped]
        return self.without(*names) if names else self

    def without(self, *names: str) -> "Profile":
        """A copy with the named effects disabled (e.g. ``profile.without("noise", "vignetting")``)."""
        out = self.copy()
        for name in names:
            effect = out.effect(name)
            if effect is None:
                raise ProfileError(f"{self.source}: no effect '{name}' to disable")
            effect.enabled = False
        return out

    def to_dict(self) -> dict:
        out = {"camera": self.camera.values(), "effect": []}
        for e in self.effects:
            entry = {"type": e.name if type(e).__module__.startswith("lowcam.") else
                     f"{type(e).__module__}:{type(e).__name__}"}
            if not e.enabled:
                entry["enabled"] = False
            entry.update({k: v for k, v in e.values().items() if v is not None})  # TOML has no null: unset paths
            out["effect"].append(entry)
        if self.provenance:
            out["provenance"] = dict(self.provenance)
        if self.video:
            out["video"] = dict(self.video)
        return out

    def save(self, path) -> Path:
        """Write the profile as TOML (atomically). Texture paths are written relative to the new file."""
        path = Path(path).resolve()
        data = self.to_dict()
        for entry, effect in zip(data["effect"], self.effects):
            for key, spec in effect.params.items():
                if spec.kind == "path" and getattr(effect, key):
                    entry[key] = os.path.relpath(getattr(effect, key), path.parent)
        atomic_write_bytes(path, tomli_w.dumps(data).encode())
        return path

    def __repr__(self) -> str:
        return f"Profile({self.name!r}, effects=[{', '.join(e.name for e in self.effects)}])"


def profile_search_path() -> list[Path]:
    """Folders searched for profiles by name: ``$LOWCAM_PROFILE_PATH`` (os.pathsep-separated), then the bundled."""
    extra = [Path(p) for p in os.environ.get("LOWCAM_PROFILE_PATH", "").split(os.pathsep) if p]
    return extra + [BUNDLED_PROFILES]


def list_profiles() -> list[tuple[str, Path]]:
    """(name, path) of every profile on the search path."""
    seen: dict[str, Path] = {}
    for folder in profile_search_path():
        for p in sorted(folder.glob("*.toml")):
            seen.setdefault(p.stem, p)
    return sorted(seen.items())


def find_profile(name_or_path) -> Path:
    """The file of a profile name or path (a clear error naming the known ones)."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or os.sep in str(name_or_path):
        if p.is_dir():
            raise ProfileError(f"{p}: is a folder, not a profile file")
        if not p.is_file():
            raise ProfileError(f"{p}: no such profile file")
        return p
    for folder in profile_search_path():
        if (folder / f"{name_or_path}.toml").is_file():
            return folder / f"{name_or_path}.toml"
    known = ", ".join(n for n, _ in list_profiles())
    raise ProfileError(f"unknown profile {schema.shown(str(name_or_path))} (bundled and on LOWCAM_PROFILE_PATH: "
                       f"{known})")


_LOADED: dict = {}


def load_profile(name_or_path) -> Profile:
    """Load and validate a profile by bundled name (``"fire-i"``) or path (``"my-camera.toml"``).

    Each call returns a copy of the file's last parse (kept while the file is unchanged); copies share the lens
    maps (:class:`~lowcam.effects.LensDistortion`), so a render handler that loads the profile every frame does
    not rebuild them."""
    if isinstance(name_or_path, Profile):
        return name_or_path
    path = find_profile(name_or_path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _LOADED:
        data = schema.read_toml(path, "profile", error=ProfileError)
        if len(_LOADED) > 16:
            _LOADED.clear()
        _LOADED[key] = profile_from_dict(data, path)
    return _LOADED[key].copy()


def profile_from_dict(data: dict, path: Path | None = None) -> Profile:
    """A validated :class:`Profile` from parsed TOML; every problem is a :class:`ProfileError` naming the file."""
    source = str(path) if path else "<profile>"
    base_dir = path.parent if path else None
    e = ProfileError
    data = schema.table(data, source, error=e)
    unknown = sorted(set(data) - {"camera", "effect", "provenance", "video"})
    if unknown:
        raise e(f"{source}: unknown top-level key {schema.shown(unknown[0])} (known: camera, effect, provenance, "
                "video)")
    camera = CameraSpec(source, base_dir, **schema.table(data.get("camera", {}), source, "camera", error=e))
    entries = data.get("effect", [])
    if not isinstance(entries, list) or not entries:
        raise e(f"{source}: no [[effect]] entries ('effect' must be an array of tables)")
    effects = []
    for i, entry in enumerate(entries):
        where = f"{source}: [[effect]] number {i + 1}"
        entry = dict(schema.table(entry, where, required=("type",), error=e))
        cls = effect_class(schema.string(entry.pop("type"), where, "type", nonempty=True, error=e), source)
        enabled = schema.boolean(entry.pop("enabled", True), f"{source}: effect '{cls.name}'", "enabled", error=e)
        effects.append(cls(enabled, source, base_dir, **entry))
    profile = Profile(camera, effects, path)
    profile.video = check_video(data.get("video", {}), source)
    profile.provenance = check_provenance(data.get("provenance", {}), profile)
    return profile


def check_video(table, source: str) -> dict:
    """The ``[video]`` table, checked: each value a string (at most 400 characters), a boolean or a finite
    number (a one-line :class:`ProfileError` otherwise)."""
    e = ProfileError
    table = schema.table(table, source, "video", error=e)
    for key, value in table.items():
        where = f"{source}: [video] {schema.shown(key)}"
        if isinstance(value, str):
            if len(value) > 400:
                raise e(f"{where}: a text of {len(value)} characters (at most 400)")
        elif isinstance(value, bool):
            continue
        elif not isinstance(value, (int, float)) or not math.isfinite(value):
            raise e(f"{where}: {schema.shown(value)} is not a text, a boolean or a finite number")
    return dict(table)


def inherited_provenance(base: Profile, replaced) -> dict[str, str]:
    """The ``[provenance]`` of a profile made from ``base`` with the effects ``replaced`` new: each other entry of
    the base marked ``(from base NAME)``, and ``not stated (from base NAME)`` for the camera and each kept effect
    the base says nothing of. A replaced effect's old entries no longer hold and are left out."""
    tag = f"(from base {base.name})"
    out = {k: v if tag in v else f"{v} {tag}" for k, v in base.provenance.items()
           if k.partition(".")[0] not in replaced}
    for owner in ("camera", *(e.name for e in base.effects)):
        if owner not in replaced and owner not in out:
            out[owner] = f"not stated {tag}"
    return out


def check_provenance(table, profile: Profile) -> dict[str, str]:
    """The ``[provenance]`` table, checked: each key is ``camera``, ``camera.KEY``, an effect of the chain or
    ``EFFECT.PARAM``; each value a non-empty string saying where the numbers came from (a one-line
    :class:`ProfileError` otherwise)."""
    e, source = ProfileError, profile.source
    table = schema.table(table, source, "provenance", error=e)
    owners = {"camera": profile.camera, **{x.name: x for x in profile.effects}}
    for key, value in table.items():
        owner, _, param = key.partition(".")
        if owner == "video" and profile.video and (not param or param in profile.video):
            schema.string(value, f"{source}: [provenance]", key, nonempty=True, error=e)
            continue
        if owner not in owners:
            raise e(f"{source}: [provenance] key {schema.shown(key)} names no effect of the chain "
                    f"(known: {', '.join(owners)})")
        if param and param not in owners[owner].params:
            raise e(f"{source}: [provenance] key {schema.shown(key)}: '{owner}' has no parameter "
                    f"{schema.shown(param)}")
        schema.string(value, f"{source}: [provenance]", key, nonempty=True, error=e)
    return dict(table)
