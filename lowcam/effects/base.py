"""The effect interface: one physical effect, its typed parameters, and its simulation step.

Every stage of the imaging chain (Klein & Murray 2010, sec. 5.2) is an :class:`Effect`. A profile lists effects in
order; :mod:`lowcam.pipeline` walks that list. Calibration, comparison and diagnosis reuse the same objects.

Writing your own effect (a plug-in)::

    from lowcam.effects import Effect, Param

    class Haze(Effect):
        '''Adds a constant veil to the rendered light (DN, 8-bit units).'''
        name = "haze"
        section = "not in the paper"
        writes = "bayer"
        params = {"veil_dn": Param(2.0, low=0.0, high=255.0, unit="DN")}

        def apply(self, state):
            state.bayer += self.veil_dn * state.bayer_alpha

and in a profile: ``[[effect]]`` / ``type = "mypackage.haze:Haze"`` / ``veil_dn = 3.0``.

Contents
--------
- :class:`Param`: specification of one effect parameter (default, type, range, unit)
- :class:`ParamSet`: a named, validated set of :class:`Param` values (an effect, or the ``[camera]`` table)
- :class:`NodeStage`: how the compositor node group builds an effect (the Blender side reads this; no bpy here)
- :class:`Search`: how diagnosis fits an effect as a candidate (:mod:`lowcam.measure.diagnose` reads this)
- :class:`Effect`: base class of every stage
- :func:`plugin_failures`: a plug-in effect's exception as a one-line error naming the effect and where it raised
- :func:`lead_frames`: the most frames before a sequence's first that any of some effects needs to settle

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import sys
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .. import schema
from ..errors import LowcamError, ProfileError
from ..node_images import mosaic_kernel, planes_to_mosaic


@dataclass(frozen=True)
class Param:
    """Specification of one effect parameter.

    ``kind`` is one of ``float``, ``int``, ``bool``, ``str``, ``"path"`` (a file relative to the profile),
    ``"vector"`` (a list of floats, ``length`` long) or ``"matrix"`` (``length`` lists of ``length`` floats).
    Numbers are finite; ``low`` and ``high`` bound each entry of a vector or matrix too, and ``whole`` asks for
    whole-numbered entries (grid cells).
    """

    default: Any
    kind: Any = float
    low: float | None = None
    high: float | None = None
    unit: str = ""
    doc: str = ""
    choices: tuple[str, ...] | None = None
    length: int | None = None
    whole: bool = False


class ParamSet:
    """A named, validated set of :class:`Param` values (an effect, or the profile's ``[camera]`` table)."""

    name: ClassVar[str] = ""
    params: ClassVar[dict[str, Param]] = {}

    def __init__(self, source: str = "<python>", base_dir: Path | None = None, **values):
        self.source = source
        self.base_dir = Path(base_dir) if base_dir is not None else None
        where = f"{source}: [{self.name}]" if not isinstance(self, Effect) else f"{source}: effect '{self.name}'"
        unknown = sorted(set(values) - set(self.params))
        if unknown:
            raise ProfileError(f"{where}: unknown key {schema.shown(unknown[0])} "
                               f"(known keys: {', '.join(sorted(self.params))})")
        for key, spec in self.params.items():
            setattr(self, key, _validated(where, key, spec, values.get(key, spec.default), self.base_dir))
        self.check()

    def check(self) -> None:
        """Cross-parameter validation; raise :class:`ProfileError` on a problem."""

    def values(self) -> dict[str, Any]:
        """The parameters as plain TOML-ready values (paths as given relative to the profile when possible)."""
        out = {}
        for key in self.params:
            value = getattr(self, key)
            if isinstance(value, Path):
                value = str(value.relative_to(self.base_dir)) if self.base_dir and value.is_relative_to(
                    self.base_dir) else str(value)
            out[key] = value
        return out

    def error(self, message: str) -> ProfileError:
        return ProfileError(f"{self.source}: {self.name}: {message}")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.values().items())})"


@dataclass(frozen=True)
class NodeStage:
    """How the compositor node group builds an effect (the Blender side reads this; no bpy here).

    ``label`` names the node; ``carries`` is what its sockets hold: ``"image"`` (RGBA on the working grid),
    ``"mosaic"`` (the sensel mosaic, colour in R, alpha in G), ``"rgb"`` (the demosaiced frame plus an Alpha
    socket) or ``"yuv"`` (the blended frame's YUV difference). ``builder`` names the node recipe in
    :mod:`nodes.build`: one of its generic recipes (``"kernel"``: convolve with the effect's ``kernel()``;
    ``"gain"``: multiply the colour by its baked ``gain`` map; ``"matrix"``: a 3x3 colour matrix) or a stage's own.
    ``baked_into`` names a later effect whose maps already hold this one (motion taps live in Bayer sampling).
    """

    label: str
    carries: str = "image"
    builder: str = ""
    baked_into: str = ""


@dataclass(frozen=True)
class Search:
    """How diagnosis fits an effect as a candidate (:mod:`lowcam.measure.diagnose` reads this).

    ``candidate`` is the name diagnosis lists; ``bounds`` the continuous parameters it searches (key ->
    (low, high)), from ``start``; ``grid`` ordered discrete values walked from the profile's value towards lower
    error (key -> values; scored on the full error when ``full_error``); ``fixed`` values set without a search
    (e.g. ``method = "bilinear"``). ``when``: values the profile's effect must already have (the lens model).
    ``fit`` is the effect's own closed-form fit instead (per-pixel maps, row noise, a grey camera), a function
    ``fit(ctx, effect_name)`` returning (profile, params, shown values) or None
    (``ctx`` is a :class:`lowcam.measure.diagnose.Context`: ``profile``, ``means``, ``clean()``, ``sse()``,
    ``simulate()``: the effects do not run the pipeline, the fit is handed it).
    ``captures``: which captures it changes (``"all"``, ``"textured"`` or ``"moving"``): it is fitted on
    those, and the others keep the profile's frames (a fit may look at fewer: the veiling glare is seen on
    textured captures' dark areas, yet lifts flat fields too, so it declares ``"all"``). ``requires``: an
    effect the profile must already have (a candidate that changes a parameter). ``replace``: start from the
    effect's defaults rather than the profile's values. ``after``: the effect is placed (or found) right after
    this one in the chain rather than at its ``order`` (:meth:`lowcam.profile.Profile.with_effect`; a blur that
    acts after sharpening). ``per_pixel``: the fit is a dense map with a value per pixel (it needs several frames
    per capture to tell the sensor's pattern from a frame's noise). ``reach``: searched keys the captures
    determine only where their compared, rendered pixels reach this far from the centre (a share of the
    half-diagonal; a fall-off's rho^4 term needs the corners): otherwise the key is held at the profile's value.
    ``changes_noise``: the fitted effect changes the frames' noise, which the screening's noise-free estimate
    cannot see (the candidate is always compared in full). ``held_noise``: the effect holds noise from one frame to
    the next (a temporal filter, a video encoder): it is fitted only where the captures' noise is held more than
    the profile's (:attr:`lowcam.measure.compare.Comparison.held_noise`), its own evidence. ``determined_by``:
    the captures (as ``captures``) without which a fit cannot determine the parameters (a flat capture shows that
    a video encoder holds noise, not how coarsely it codes): diagnosis holds out no capture whose fold would be
    fitted on none of them, and splits the frames into image tiles instead (a ``fit`` with ``honours_masks``).
    ``evidence`` is formatted with the fitted values (``{key}``) and the profile's (``{was_key}``).
    """

    candidate: str
    evidence: str
    bounds: dict = field(default_factory=dict)
    start: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    fixed: dict = field(default_factory=dict)
    when: dict = field(default_factory=dict)
    fit: Any = ""
    captures: str = "all"
    requires: str = ""
    replace: bool = False
    full_error: bool = False
    evals: int = 20
    after: str = ""
    per_pixel: bool = False
    reach: dict = field(default_factory=dict)
    changes_noise: bool = False
    held_noise: bool = False
    determined_by: str = ""


class Effect(ParamSet):
    """Base class of every stage. Subclasses set the class attributes and implement :meth:`apply`.

    Attributes
    ----------
    name : str
        The profile's ``type`` for this effect.
    section : str
        Where the paper describes it.
    writes : str
        Which part of the simulation state the effect changes: ``"render"`` (the pinhole render, before the
        lens), ``"working"`` (the distorted RGBA image),
        ``"sampling"`` (where the Bayer sensels look), ``"bayer"`` (the per-channel sensel planes), ``"rgb"``
        (the demosaiced frame) or ``"output"`` (the blended frame).
    params : dict[str, Param]
    """

    section: ClassVar[str] = ""
    writes: ClassVar[str] = ""
    #: True for a stage the chain cannot skip; disabling it selects its neutral form (the lens becomes a pinhole).
    always_runs: ClassVar[bool] = False
    #: False for an effect diagnosis never offers to remove (no ``without_EFFECT`` candidate): the camera's noise,
    #: which every comparison is measured against. Effects that ``always_runs`` are never removed either.
    removable: ClassVar[bool] = True
    #: True for an effect whose result depends on (seed, frame): everything before the first one is the same for
    #: every frame of a static scene, so it is computed once (:func:`lowcam.pipeline.prepare`).
    random: ClassVar[bool] = False
    #: True for an effect whose output moves in steps (quantisation): an objective through it is not smooth, so
    #: fits leave it out with the random ones (:meth:`lowcam.profile.Profile.quiet`).
    stepped: ClassVar[bool] = False
    #: True for an effect that acts across the frames of a shot or capture in order (a video encoder's groups of
    #: pictures, a temporal filter): where frames are made together, :meth:`finish_frames` gets them all
    #: (:func:`lowcam.pipeline.resume_sequence`); a frame made on its own gets :meth:`finish`.
    temporal: ClassVar[bool] = False
    #: True for a :attr:`temporal` effect whose frame depends on the frame delivered before it and on nothing
    #: earlier (a recursive filter): a shot made frame by frame hands it that frame (:meth:`finish_after`), so
    #: ``lowcam batch`` makes such a shot's frames in order.
    follows_previous: ClassVar[bool] = False
    #: The render pass the effect reads (``"velocity"`` or ``"depth"``, see :mod:`lowcam.passes`), or "".
    needs_pass: ClassVar[str] = ""
    #: Where the effect stands in a complete chain (:func:`lowcam.effects.canonical_order`); an effect added to
    #: a profile goes there. Plug-ins without one go to the end.
    order: ClassVar[float | None] = None
    #: How the compositor node group builds it, or None when it has no node.
    node: ClassVar[NodeStage | None] = None
    #: How diagnosis may fit it: one :class:`Search` per candidate it offers.
    searches: ClassVar[tuple[Search, ...]] = ()
    #: How ``calibrate plate`` and ``compare --plate-only`` measure it on footage
    #: (:class:`lowcam.plate_estimate.PlateProbe`), or None.
    plate_probe: ClassVar[Any] = None
    #: The ``lowcam calibrate`` job that measures it (:data:`lowcam.calibrate.CALIBRATIONS`), or "".
    calibration: ClassVar[str] = ""

    def __init__(self, enabled: bool = True, source: str = "<python>", base_dir: Path | None = None, **values):
        self.enabled = bool(enabled)
        super().__init__(source, base_dir, **values)

    def implausible(self) -> list[str]:
        """What in this effect's parameters no real camera has, one short phrase each (empty: plausible).

        Box ranges of what diagnosis searches are :attr:`Search.bounds`; this says what boxes cannot (luma weights
        >= 0 summing to 1, a monotone tone curve, a noise variance >= 0 at every level 0-255). Diagnosis and plate
        estimation keep their fits inside; calibration and reports name what lies outside."""
        return []

    def apply(self, state) -> None:  # pragma: no cover - interface
        """Run this step of the imaging chain on ``state`` (a :class:`lowcam.pipeline.SimState`) in place."""
        raise NotImplementedError

    def bake_node(self, state, bake) -> None:
        """Put what this effect's compositor node reads into ``bake`` (a :class:`lowcam.node_maps.CameraBake`:
        ``images``, ``values``, ``geometry``, ``render_shape``), from ``state``: the chain run on an empty render up
        to Bayer sampling. The generic recipes of :class:`NodeStage` bake here from the effect's own arrays:
        ``"kernel"`` its ``kernel()`` as a mosaic row filter, ``"gain"`` its ``gain_planes(geometry)`` as a mosaic,
        ``"matrix"`` its ``total_matrix()``; an effect with a recipe of its own overrides this."""
        builder, g = self.node.builder, bake.geometry
        if builder == "kernel":
            bake.images[f"{self.name}_kernel"] = mosaic_kernel(self.kernel())
        elif builder == "gain":
            bake.images[f"{self.name}_gain"] = planes_to_mosaic(self.gain_planes(g), g)
        elif builder == "matrix":
            bake.values[f"{self.name}_matrix"] = self.total_matrix().ravel().tolist()

    def finish(self, state, frame, footprint):
        """After the blend: change the 8-bit ``frame`` (H, W, 3) and its ``footprint`` (H, W) bool of pixels the
        graphics changed, and return both (the chroma groups, a JPEG encode, a raw frame). The default keeps
        them."""
        return frame, footprint

    def finish_frames(self, frames, footprints):
        """After the blend, for a :attr:`temporal` effect: change the 8-bit ``frames`` (T, H, W, 3) of one shot or
        capture, in order, and their ``footprints`` (T, H, W) bool, and return both (a video encoder codes them
        as groups of pictures). Whatever the effect carries from frame to frame lives here, not in the effect
        between calls. The default finishes each frame on its own (:meth:`finish`, without a state)."""
        done = [self.finish(None, f, m) for f, m in zip(frames, footprints)]
        return np.stack([d[0] for d in done]), np.stack([d[1] for d in done])

    def finish_after(self, previous, frame, footprint):
        """For a :attr:`follows_previous` effect in a shot made frame by frame: finish ``frame`` (H, W, 3) uint8
        and its ``footprint`` given ``previous``, the frame the shot delivered before it. The default finishes the
        frame on its own (:meth:`finish`, without a state)."""
        return self.finish(None, frame, footprint)

    def lead_frames(self) -> int:
        """For a :attr:`temporal` effect: how many frames before a sequence's first it needs to reach its steady
        state (a recursive filter's memory): :func:`lowcam.pipeline.resume_sequence` makes them (other noise) and
        drops them after :meth:`finish_frames`, so a measurement capture's frames stand mid-stream, as a real
        camera's do. 0 by default."""
        return 0

    def error(self, message: str) -> ProfileError:
        return ProfileError(f"{self.source}: effect '{self.name}': {message}")


def _validated(where: str, key: str, spec: Param, value: Any, base_dir: Path | None) -> Any:
    """``value`` checked against ``spec`` (:mod:`lowcam.schema`); a miss is a :class:`ProfileError`."""
    e = ProfileError
    if spec.kind is bool:
        return schema.boolean(value, where, key, error=e)
    if spec.kind is str:
        return schema.string(value, where, key, choices=spec.choices, error=e)
    if spec.kind == "path":
        if value is None or value == "":
            return None
        return schema.existing_file(value, where, key, base_dir, error=e)
    if spec.kind in ("vector", "matrix"):
        def row(v, w, k):  # one vector: floats, element-wise in [low, high]
            return [float(x) for x in schema.numbers(v, w, k, spec.length, spec.low, spec.high, spec.unit,
                                                      spec.whole, error=e)]

        if spec.kind == "vector":
            return row(value, where, key)
        return schema.array_of(value, where, key, row, spec.length, error=e)  # length x length
    if spec.kind is int:
        return schema.integer(value, where, key, spec.low, spec.high, spec.unit, error=e)
    return schema.number(value, where, key, spec.low, spec.high, spec.unit, error=e)


@contextmanager
def plugin_failures(effect: Effect):
    """Around a call into ``effect``: an exception (or ``sys.exit``) a plug-in effect raises becomes a one-line
    :class:`~lowcam.errors.LowcamError` naming the effect, its type and the line of its module that raised (a shot
    fails that frame and goes on, as for bad input); a bundled effect's exception passes through with its
    traceback (a bug)."""
    try:
        yield
    except (LowcamError, MemoryError):
        raise
    except (Exception, SystemExit) as e:
        kind = type(effect)
        if kind.__module__.startswith("lowcam."):
            raise
        frames = traceback.extract_tb(e.__traceback__)
        own = getattr(sys.modules.get(kind.__module__), "__file__", None)  # never imported again here
        where = next((f for f in reversed(frames) if f.filename == own), frames[-1])  # the plug-in's own line
        message = " ".join(str(e).split())
        raise LowcamError(f"plug-in effect '{effect.name}' ({kind.__module__}:{kind.__qualname__}) failed at "
                          f"{where.filename}:{where.lineno}: {type(e).__name__}" + (f": {message}" if message
                                                                                    else "")) from e


def lead_frames(effects) -> int:
    """The most frames before a sequence's first that any of ``effects`` needs to settle
    (:meth:`Effect.lead_frames`; 0 for none)."""
    def one(effect):
        with plugin_failures(effect):
            return effect.lead_frames()
    return max(map(one, effects), default=0)
