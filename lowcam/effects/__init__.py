"""Physical effects, one module each. :data:`EFFECTS` maps a profile's ``type`` to its class.

Each effect declares itself (:class:`Effect`): its place in the chain (``order``), its compositor node
(``node``), how diagnosis searches it (``searches``) and which calibration measures it (``calibration``). The
chain order, the node stages, the diagnosis candidates and the calibration listing are derived from these
declarations (:func:`known_effects`), for bundled effects and plug-ins (``"module:Class"``) alike.

Plug-ins run code, and profiles travel with shots, profile packs and .blend files, so a plug-in module is imported
only when the user trusts it: ``lowcam --plugin MODULE``, ``LOWCAM_PLUGINS=MODULE[,MODULE...]``,
:func:`trust_plugins` from Python, or the Blender add-on's Trusted Plug-ins preference. A profile naming an
effect of any other module is refused (:class:`~lowcam.errors.UntrustedPlugin`) before anything is imported, so
listing or validating a profile never runs a plug-in's code.

Contents
--------
- :data:`EFFECTS`: every bundled effect class by its profile ``type``
- :data:`PLUGINS`: plug-in effects loaded so far in this process (``"module:Class"`` -> class)
- :data:`PLUGINS_ENV`: the environment variable that lists trusted plug-in modules (``LOWCAM_PLUGINS``)
- :data:`TRUSTED`: plug-in modules trusted in this process (``--plugin``, :func:`trust_plugins`)
- :data:`TRUST_PROVIDERS`: functions that name more trusted modules when asked (the Blender add-on's preference)
- :func:`trust_plugins`: trust plug-in modules: profiles may then name their effects
- :func:`trusted_modules`: every module trusted now: :data:`TRUSTED`, ``$LOWCAM_PLUGINS`` and the providers'
- :func:`plugin_trusted`: whether a module, or a package holding it, is trusted
- :func:`known_effects`: every effect class known in this process, bundled and plug-in, in chain order
- :func:`canonical_order`: the names of :func:`known_effects` in the order they stand in a complete chain
- :func:`effect_class`: the class for a profile ``type``: a bundled name or ``"package.module:ClassName"``
- :class:`Effect`: base class of every stage (:mod:`lowcam.effects.base`)
- :class:`Param`, :class:`ParamSet`: an effect's typed, validated parameters
- :class:`NodeStage`, :class:`Search`: how the compositor node builds an effect and how diagnosis fits it

Modules, in chain order (sections of [Klein2010]):

- :mod:`~lowcam.effects.object_motion`: motion blur of moving objects, from a velocity pass (beyond the paper)
- :mod:`~lowcam.effects.depth_of_field`: defocus from a depth pass (beyond the paper)
- :mod:`~lowcam.effects.lens`: lens distortion (sec. 5.2 step 1); the lens models in :mod:`~lowcam.effects.lens_models`,
  their calibration fit in :mod:`~lowcam.effects.lens_fit` (sec. 4.1)
- :mod:`~lowcam.effects.half_sampling`: half-sampling (sec. 5.2 step 2)
- :mod:`~lowcam.effects.crosstalk`: Bayer filter crosstalk (sec. 4.2, 5.2 step 2)
- :mod:`~lowcam.effects.motion_blur`: motion blur from camera rotation (sec. 5.2 step 4)
- :mod:`~lowcam.effects.rolling_shutter`: rolling shutter (sec. 3; not simulated in the paper)
- :mod:`~lowcam.effects.chromatic_aberration`: lateral chromatic aberration (sec. 4.1, 5.2 step 5)
- :mod:`~lowcam.effects.blur`: spatially varying, horizontal and vertical blur (sec. 4.3, 5.2 steps 3 and 6)
- :mod:`~lowcam.effects.defocus`: uniform defocus (sec. 2-3; not simulated in the paper)
- :mod:`~lowcam.effects.veiling_glare`: veiling glare (sec. 3: flare)
- :mod:`~lowcam.effects.bayer`: Bayer sampling and demosaicing (sec. 4.4.1, 5.2 steps 5 and 8, sec. 7)
- :mod:`~lowcam.effects.vignetting`: vignetting (sec. 4.1, 5.2 step 5)
- :mod:`~lowcam.effects.noise`: sensor noise (sec. 4.3, 5.2 step 5)
- :mod:`~lowcam.effects.fixed_pattern`: row noise, PRNU, DSNU and hot pixels (sec. 4.3, after Irie et al.)
- :mod:`~lowcam.effects.sharpening`: in-camera sharpening (sec. 4.4.3, 5.2 step 7)
- :mod:`~lowcam.effects.quantisation`: quantisation (sec. 4.3, 5.2 step 7)
- :mod:`~lowcam.effects.raw_blend`: blending into a raw Bayer frame (sec. 7)
- :mod:`~lowcam.effects.saturation`: colour correction and the saturation control (sec. 4.4.2)
- :mod:`~lowcam.effects.tone_curve`: the tone curve (not in the paper; sec. 8)
- :mod:`~lowcam.effects.yuv`: YUV blending and 4:1:1 chroma (sec. 5.2 steps 8-10)
- :mod:`~lowcam.effects.temporal_noise_reduction`: an image processor's recursive, motion-adaptive temporal noise
  reduction, over a sequence of frames (not in the paper)
- :mod:`~lowcam.effects.noise_reduction`: an image processor's spatial noise reduction (not in the paper)
- :mod:`~lowcam.effects.local_tone_mapping`: an image processor's local tone mapping (CLAHE; not in the paper)
- :mod:`~lowcam.effects.edge_enhancement`: an image processor's edge enhancement with coring (not in the paper);
  what these four share in :mod:`~lowcam.effects.delivered_frame`
- :mod:`~lowcam.effects.jpeg`: JPEG compression (not in the paper)
- :mod:`~lowcam.effects.video_codec`: H.264 or HEVC video coding with x264 or x265, over a sequence of frames
  (not in the paper)

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import importlib
import os
import re

from .. import schema
from ..errors import LowcamError, ProfileError, UntrustedPlugin
from .base import Effect, NodeStage, Param, ParamSet, Search
from .bayer import BayerSampling, Demosaic
from .blur import HorizontalBlur, SpatialBlur, VerticalBlur
from .chromatic_aberration import ChromaticAberration
from .crosstalk import Crosstalk
from .defocus import Defocus
from .depth_of_field import DepthOfField
from .edge_enhancement import EdgeEnhancement
from .fixed_pattern import DSNU, HotPixels, PRNU, RowNoise
from .half_sampling import HalfSampling
from .jpeg import Jpeg
from .lens import LensDistortion
from .local_tone_mapping import LocalToneMapping
from .motion_blur import MotionBlur
from .noise import Noise
from .noise_reduction import NoiseReduction
from .object_motion import ObjectMotion
from .quantisation import Quantisation
from .raw_blend import RawBlend
from .rolling_shutter import RollingShutter
from .saturation import Saturation
from .sharpening import Sharpening
from .tone_curve import ToneCurve
from .veiling_glare import VeilingGlare
from .temporal_noise_reduction import TemporalNoiseReduction
from .video_codec import VideoCodec
from .vignetting import Vignetting
from .yuv import ChromaSubsampling, YuvBlend

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (LensDistortion, HalfSampling, Crosstalk, MotionBlur, ChromaticAberration, SpatialBlur,
                BayerSampling, Vignetting, Noise, HorizontalBlur, Sharpening, Quantisation, RawBlend, Demosaic,
                Saturation, YuvBlend, ChromaSubsampling,
                # beyond the paper: candidates for what a camera does that a profile lacks
                Defocus, VeilingGlare, RollingShutter, RowNoise, VerticalBlur, PRNU, DSNU, HotPixels, ToneCurve,
                TemporalNoiseReduction, NoiseReduction, LocalToneMapping, EdgeEnhancement, Jpeg, VideoCodec,
                # need render passes (velocity, depth): added by the Blender add-on when asked for
                ObjectMotion, DepthOfField)
}


#: Plug-in effects loaded so far in this process (``"module:Class"`` -> class).
PLUGINS: dict[str, type[Effect]] = {}

#: The environment variable that lists trusted plug-in modules, separated by commas or ``os.pathsep``.
PLUGINS_ENV = "LOWCAM_PLUGINS"
#: Plug-in modules trusted in this process (``lowcam --plugin``, :func:`trust_plugins`).
TRUSTED: set[str] = set()
#: Functions that return more trusted module names each time they are asked (the Blender add-on's preference,
#: which holds only while the open .blend may run scripts).
TRUST_PROVIDERS: list = []

_MODULE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


def _module_names(names, where: str) -> set[str]:
    out = set()
    for name in names:
        name = name.strip()
        if name and not _MODULE_NAME.fullmatch(name):
            raise LowcamError(f"{where} {schema.shown(name)}: not a Python module name (e.g. my_effects or "
                              "studio.effects)")
        if name:
            out.add(name)
    return out


def trust_plugins(*modules: str, option: str = "plug-in") -> None:
    """Trust plug-in ``modules`` (``"my_effects"``, ``"studio.effects"``; a package trusts its submodules): profiles
    may then name their effects (``"my_effects:Haze"``), and the module is imported when one does. A name that is
    no module name is a :class:`~lowcam.errors.LowcamError` naming ``option``."""
    TRUSTED.update(_module_names(modules, option))


def trusted_modules() -> set[str]:
    """Every module trusted now: :data:`TRUSTED`, ``$LOWCAM_PLUGINS`` (commas or ``os.pathsep`` between names) and
    what each of :data:`TRUST_PROVIDERS` names."""
    env = re.split(rf"[,{re.escape(os.pathsep)}]", os.environ.get(PLUGINS_ENV, ""))
    out = TRUSTED | _module_names(env, PLUGINS_ENV)
    for provider in TRUST_PROVIDERS:
        out |= set(provider())
    return out


def plugin_trusted(module_name: str) -> bool:
    """Whether ``module_name``, or a package that holds it, is trusted (:func:`trusted_modules`)."""
    parts = module_name.split(".")
    trusted = trusted_modules()
    return any(".".join(parts[:k]) in trusted for k in range(1, len(parts) + 1))


def known_effects() -> list[type[Effect]]:
    """Every effect class known in this process, bundled and plug-in, in chain order (``Effect.order``; those
    without an order last)."""
    classes = list(EFFECTS.values()) + [c for c in PLUGINS.values() if c not in EFFECTS.values()]
    return sorted(classes, key=lambda c: (c.order is None, c.order or 0.0))


def canonical_order() -> list[str]:
    """The names of :func:`known_effects` in the order they stand in a complete chain."""
    return [c.name for c in known_effects()]


def effect_class(type_name: str, source: str = "<python>") -> type[Effect]:
    """The class for a profile ``type``: a bundled name, or ``"package.module:ClassName"`` for a plug-in."""
    if not isinstance(type_name, str):
        raise ProfileError(f"{source}: effect 'type' must be a string (a bundled effect or 'module:Class'), "
                           f"got {schema.shown(type_name)}")
    if type_name in EFFECTS:
        return EFFECTS[type_name]
    if type_name in PLUGINS:
        return PLUGINS[type_name]
    loaded = next((cls for cls in PLUGINS.values() if cls.name == type_name), None)
    if loaded is not None:  # a plug-in loaded earlier, by its own name
        return loaded
    if ":" in type_name:
        module_name, _, class_name = type_name.partition(":")
        if not (all(p.isidentifier() for p in module_name.split(".")) and class_name.isidentifier()):
            raise ProfileError(f"{source}: effect type {schema.shown(type_name)} is not 'package.module:ClassName'")
        if not plugin_trusted(module_name):  # checked before any import: an untrusted module's code never runs
            raise UntrustedPlugin(source, type_name, module_name)
        try:
            cls = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as e:
            raise ProfileError(f"{source}: effect type {schema.shown(type_name)} cannot be loaded: "
                               f"{_first_line(e)}") from None
        except SystemExit as e:  # a module that ends the process on import must not end the command
            raise ProfileError(f"{source}: effect type {schema.shown(type_name)} exits on import "
                               f"(sys.exit({e.code!r}))") from None
        except Exception as e:  # the plug-in's own module fails on import
            raise ProfileError(f"{source}: effect type {schema.shown(type_name)} fails on import: "
                               f"{type(e).__name__}: {_first_line(e)}") from None
        if not (isinstance(cls, type) and issubclass(cls, Effect)):
            raise ProfileError(f"{source}: effect type {schema.shown(type_name)} is not a lowcam.effects.Effect "
                               "subclass")
        PLUGINS[type_name] = cls
        return cls
    raise ProfileError(f"{source}: unknown effect type {schema.shown(type_name)} (known: {', '.join(EFFECTS)}, "
                       "or 'module:Class' for a plug-in)")


def _first_line(e: Exception) -> str:
    return (str(e).splitlines() or [""])[0]


__all__ = ["EFFECTS", "PLUGINS", "PLUGINS_ENV", "TRUSTED", "TRUST_PROVIDERS", "Effect", "NodeStage", "Param",
           "ParamSet", "Search", "canonical_order", "effect_class", "known_effects", "plugin_trusted",
           "trust_plugins", "trusted_modules"] + [c.__name__ for c in EFFECTS.values()]
