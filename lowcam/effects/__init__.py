"""Physical effects, one module each. :data:`EFFECTS` maps a profile's ``type`` to its class."""
from __future__ import annotations

import importlib

from ..errors import ProfileError
from .base import Effect, Param, ParamSet
from .bayer import BayerSampling, Demosaic
from .blur import HorizontalBlur, SpatialBlur
from .chromatic_aberration import ChromaticAberration
from .crosstalk import Crosstalk, Saturation
from .lens import LensDistortion
from .motion_blur import MotionBlur
from .object_motion import ObjectMotion
from .noise import Noise
from .raw import RawBlend
from .resample import HalfSampling
from .sharpen import Quantisation, Sharpening
from .vignetting import Vignetting
from .yuv import ChromaSubsampling, YuvBlend
from .blur import VerticalBlur
from .defocus import Defocus
from .depth_of_field import DepthOfField
from .fixed_pattern import DSNU, PRNU, HotPixels, RowNoise
from .glare import VeilingGlare
from .jpeg import Jpeg
from .rolling_shutter import RollingShutter
from .tone import ToneCurve

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (LensDistortion, HalfSampling, Crosstalk, MotionBlur, ChromaticAberration, SpatialBlur,
                BayerSampling, Vignetting, Noise, HorizontalBlur, Sharpening, Quantisation, RawBlend, Demosaic,
                Saturation, YuvBlend, ChromaSubsampling,
                # beyond the paper: candidates for what a camera does that a profile lacks
                Defocus, VeilingGlare, RollingShutter, RowNoise, VerticalBlur, PRNU, DSNU, HotPixels, ToneCurve,
                Jpeg,
                # need render passes (velocity, depth): added by the Blender add-on when asked for
                ObjectMotion, DepthOfField)
}


def effect_class(type_name: str, source: str = "<python>") -> type[Effect]:
    """The class for a profile ``type``: a bundled name, or ``"package.module:ClassName"`` for a plug-in."""
    if type_name in EFFECTS:
        return EFFECTS[type_name]
    if ":" in type_name:
        module_name, _, class_name = type_name.partition(":")
        try:
            cls = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as e:
            raise ProfileError(f"{source}: effect type '{type_name}' cannot be loaded: {e}") from None
        if not (isinstance(cls, type) and issubclass(cls, Effect)):
            raise ProfileError(f"{source}: effect type '{type_name}' is not a lowcam.effects.Effect subclass")
        return cls
    raise ProfileError(f"{source}: unknown effect type '{type_name}' (known: {', '.join(EFFECTS)}, "
                       "or 'module:Class' for a plug-in)")


__all__ = ["EFFECTS", "Effect", "Param", "ParamSet", "effect_class"] + [c.__name__ for c in EFFECTS.values()]
