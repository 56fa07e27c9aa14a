"""The simulator: walk a profile's effects over one frame (Klein & Murray 2010, sec. 5.2 and 7).

Conventions
-----------
- The render is premultiplied linear RGBA (H, W, 4) of an ideal pinhole camera looking down the same axis as the
  simulated camera, covering its field of view (:func:`render_field_of_view`); any pixel size is accepted.
- ``angular_velocity`` is the camera's rotation rate in rad/s, in the camera frame: x right, y down, z forward
  (so positive y pans right, positive x tilts down, positive z rolls clockwise in the image). The render shows
  the middle of the exposure.
- Values are 8-bit digital numbers (DN) from Bayer sampling on; the output is an 8-bit RGB frame.
- Pixels the graphics do not change are the plate's, bit for bit; ``Result.footprint`` marks the others.

Contents
--------
- :func:`carried`: the contract (shape, dtype, unit, the part that writes it) of one :class:`SimState` array
- :class:`SimState`: everything one frame's simulation carries from stage to stage
- :class:`Result`: one simulated frame: ``frame``, ``footprint``, ``stages`` when asked for, and the final state
- :func:`render_field_of_view`: pinhole half-extents (X, Y) the render must cover
- :func:`render_focal_px`: focal length in render pixels for a render of ``width`` x ``height``
- :func:`render_camera`: the camera a renderer must use: projection (pinhole or equidistant fisheye), field of
  view (deg), sensor fit and resolution
- :data:`BYTES_PER_WORKING_PIXEL`: peak memory of the chain per working-grid pixel
- :func:`memory_needed`: the chain's peak memory for one frame of a profile
- :func:`available_memory`: the bytes this machine can give a new allocation now
- :func:`check_memory`: refuse a frame that needs more memory than the machine has, before allocating
- :func:`run`: simulate the camera on one frame as a :class:`Result`; see :func:`simulate`
- :func:`deterministic_prefix`: how many leading effects of a profile do not depend on (seed, frame)
- :func:`prefix_key`: identifies the first ``count`` effects of a profile (and its camera) for caching their output
- :func:`prepare`: run the chain up to its first random effect: the same for every frame of a static scene
- :func:`resume`: the 8-bit frame for ``(seed, frame)`` from a :func:`prepare` token
- :func:`has_temporal`: whether a profile has an effect that acts across frames (a video encoder)
- :func:`follows_previous`: whether a profile's shot frames depend on the frame delivered before (made in order)
- :func:`check_followed_output`: such a shot's frames must be PNG (the next frame reads them)
- :func:`finish_sequence`: frames of one shot or capture through the chain's temporal effects (a video encoder)
- :func:`resume_sequence`: frames ``0..count-1`` from a :func:`prepare` token as one sequence
- :func:`simulate`: the camera's 8-bit RGB frame for a premultiplied RGBA ``render`` composited over ``plate``
- :func:`stage_image`: a displayable picture of the state after a stage
- :func:`plain_composite`: the standard compositing the paper compares against: lens warp and alpha blend only

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import copy
import os
from pathlib import Path
from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from .effects.base import lead_frames, plugin_failures
from .effects.bayer import demosaic_bilinear, mosaic, sensel_shift_px, unmosaic
from .effects.delivered_frame import to_uint8
from .effects.yuv import yuv_to_rgb
from .errors import LowcamError
from .geometry import grid_points, sample_texture
from .io import CheckedRender, check_plate, check_render_window
from .passes import RenderPasses, check_passes
from .profile import Profile, load_profile
from .parallel import row_strips, thread_map
from .window import nonzero_window


def carried(shape: tuple, dtype: str, unit: str, part: str) -> dict:
    """The contract of one :class:`SimState` array, as its dataclass field's ``metadata``: ``shape`` (numbers, or
    names: ``"height"``, ``"width"`` (the output frame), ``"working rows"``, ``"working columns"``
    (:attr:`~lowcam.geometry.Geometry.working_shape`), ``"bayer rows"``, ``"bayer columns"``
    (:attr:`~lowcam.geometry.Geometry.bayer_shape`), ``"render rows"``, ``"render columns"``, or ``"grid rows"``,
    ``"grid columns"``, ``"taps x 2"`` for a grid of any size), numpy ``dtype``, ``unit`` (and meaning), and the
    ``part`` of the state it belongs to: only effects whose :attr:`~lowcam.effects.Effect.writes` names that part
    change it (``"input"``: no effect does)."""
    return {"shape": shape, "dtype": dtype, "unit": unit, "part": part}


@dataclass
class SimState:
    """Everything one frame's simulation carries from stage to stage (see :class:`lowcam.effects.Effect`).

    Each array field's shape, dtype, unit and the part of the chain that writes it are in its ``metadata``
    (:func:`carried`; ``dataclasses.fields(SimState)`` lists them), checked by a test that runs every bundled
    profile stage by stage. ``None`` means not made yet (or not by this chain)."""

    profile: Profile
    render: np.ndarray = field(metadata=carried(
        ("render rows", "render columns", 4), "float32",
        "premultiplied linear RGBA, 0-1: the ideal pinhole render (depth of field and object motion change it)",
        "render"))
    plate: np.ndarray = field(metadata=carried(
        ("height", "width", 3), "float32", "DN 0-255: the plate (zeros for a raw camera, whose plate is plate_raw)",
        "input"))
    plate_raw: np.ndarray | None = field(metadata=carried(
        ("height", "width"), "uint8", "DN 0-255: a raw camera's plate, the colour-filter mosaic", "input"))
    angular_velocity: tuple[float, float, float]  # rad/s, camera frame (x right, y down, z forward)
    exposure_s: float | None                        # s; None: the profile's
    seed: int
    frame: int
    passes: RenderPasses | None = None
    applied: list = field(default_factory=list)  # the effects applied so far, in order
    working: np.ndarray | None = field(default=None, metadata=carried(
        ("working rows", "working columns", 4), "float32",
        "premultiplied linear RGBA on the oversampled working grid, after the lens", "working"))
    ca_grid: np.ndarray | None = field(default=None, metadata=carried(
        ("grid rows", "grid columns", 4), "float32",
        "output px: red (du, dv) and blue (du, dv) sampling offsets over the frame (a coarse grid or per pixel)",
        "sampling"))
    motion_taps: np.ndarray | None = field(default=None, metadata=carried(
        ("grid rows", "grid columns", "taps x 2"), "float32",
        "output px: each motion-blur tap's (du, dv) offset over a grid of the working extent", "sampling"))
    motion_tap_spacing: np.ndarray | None = field(default=None, metadata=carried(
        ("grid rows", "grid columns"), "float32", "output px: the largest gap between successive taps", "sampling"))
    bayer: np.ndarray | None = field(default=None, metadata=carried(
        (4, "bayer rows", "bayer columns"), "float32",
        "DN: the four colour-filter planes (R, G1, G2, B) with a border, graphics premultiplied by bayer_alpha",
        "bayer"))
    bayer_alpha: np.ndarray | None = field(default=None, metadata=carried(
        (4, "bayer rows", "bayer columns"), "float32", "coverage of each sensel by the graphics, about 0-1",
        "bayer"))
    raw_touched: np.ndarray | None = field(default=None, metadata=carried(
        (4, "bayer rows", "bayer columns"), "bool", "the sensels a raw blend changed", "bayer"))
    rgb: np.ndarray | None = field(default=None, metadata=carried(
        ("height", "width", 3), "float32", "DN: the demosaiced graphics, premultiplied by rgb_alpha", "rgb"))
    rgb_alpha: np.ndarray | None = field(default=None, metadata=carried(
        ("height", "width", 3), "float32", "coverage of each pixel and channel by the graphics, about 0-1", "rgb"))
    delta_yuv: np.ndarray | None = field(default=None, metadata=carried(
        ("height", "width", 3), "float32", "DN: the graphics' change to the plate in YUV (the paper's blend)",
        "output"))
    colour_matrix: np.ndarray | None = field(default=None, metadata=carried(
        (3, 3), "float64", "the product of the colour matrices applied to rgb so far (saturation, colour "
        "correction): the YUV blend undoes it on the plate behind", "rgb"))
    sampling_offset: np.ndarray | None = field(default=None, metadata=carried(
        ("grid rows", "grid columns", 2), "float32",
        "output px: where each row's sensels look, (du, dv), over a grid of the working extent (rolling shutter)",
        "sampling"))
    lens: object = None                             # the profile's lens model (the lens effect's)
    _windows: dict = field(default_factory=dict, repr=False)  # image name -> (array, window, producer, applied)

    def __post_init__(self):
        self.lens = self.profile.lens

    def keep_window(self, name: str, window: tuple[slice, slice] | None, producer=None) -> None:
        """Note that every non-zero pixel of the image ``name`` ("render" or "working") lies in ``window`` (None:
        it is all zero), as its ``producer`` (the effect that just wrote it; None: the validation) knows."""
        self._windows[name] = (getattr(self, name), window, producer, len(self.applied))

    def window(self, name: str) -> tuple[slice, slice] | None:
        """The :func:`~lowcam.window.nonzero_window` of the image ``name`` ("render" or "working"): the one kept
        by :meth:`keep_window` while it is the same array and no other effect that writes it (its ``writes``) has
        run since, else found again."""
        image = getattr(self, name)
        kept = self._windows.get(name)
        if kept is not None and kept[0] is image and all(
                e is kept[2] or e.writes != name for e in self.applied[kept[3]:]):
            return kept[1]
        return nonzero_window(image)

    @property
    def camera(self):
        return self.profile.camera

    @property
    def geometry(self):
        return self.profile.geometry

    def render_focal_px(self) -> float:
        """The render's focal length in its pixels (:func:`render_focal_px`)."""
        rows, cols = self.render.shape[:2]
        return render_focal_px(self.profile, cols, rows)

    def render_pass(self, effect) -> np.ndarray:
        """The render pass ``effect`` needs (``effect.needs_pass``); a clear error when it was not given."""
        return (self.passes or RenderPasses()).get(effect.needs_pass, effect)


@dataclass
class Result:
    """One simulated frame: ``frame`` (H, W, 3) uint8, ``footprint`` (H, W) bool marks pixels the graphics
    changed (every other pixel is the plate's, bit for bit), ``stages`` maps ``"NN-effect"`` to each stage's
    output when asked for, and ``state`` is the final :class:`SimState` (its raw arrays: ``working``,
    ``bayer``, ``bayer_alpha``, ``rgb``, ``rgb_alpha``, ``delta_yuv``)."""

    frame: np.ndarray | None
    footprint: np.ndarray | None
    stages: "OrderedDict[str, np.ndarray]" = field(default_factory=OrderedDict)
    state: SimState | None = None


def render_field_of_view(profile: Profile) -> tuple[float, float]:
    """Pinhole half-extents (X, Y) the render must cover (:meth:`LensDistortion.render_field_of_view
    <lowcam.effects.LensDistortion.render_field_of_view>`)."""
    return profile.effect("lens_distortion").render_field_of_view(profile.geometry)


def render_focal_px(profile: Profile, width: int, height: int) -> float:
    """Focal length in render pixels for a render of ``width`` x ``height`` (square pixels, centred)."""
    return profile.effect("lens_distortion").render_focal_px(profile.geometry, width, height)


def render_camera(profile, width: int | None = None, height: int | None = None) -> dict:
    """The camera a renderer must use: ``projection`` ("pinhole" or "fisheye_equidistant", :meth:`LensDistortion.
    projection <lowcam.effects.LensDistortion.projection>`), horizontal field of view ``hfov_deg`` (a fisheye's
    spans the render's width and its height: Cycles' ``fisheye_fov``), sensor fit and resolution (a fisheye's
    square unless ``height`` is given) and ``focal_px`` (a fisheye's: render pixels per radian at the centre).

    >>> cam = render_camera("fire-i", 3000, 2250)
    >>> round(cam["hfov_deg"]) > 90
    True
    """
    profile = load_profile(profile)
    lens = profile.effect("lens_distortion")
    width = width or 3000
    if lens.projection(profile.geometry) == "fisheye_equidistant":
        field = lens.render_fisheye_field(profile.geometry)
        return {"projection": "fisheye_equidistant", "hfov_deg": float(np.degrees(field)),
                "sensor_fit": "HORIZONTAL", "width": width, "height": height or width, "focal_px": width / field}
    half_x, _ = render_field_of_view(profile)
    height = height or int(round(width * profile.camera.height / profile.camera.width))
    return {"projection": "pinhole", "hfov_deg": float(np.degrees(2 * np.arctan(half_x))),
            "sensor_fit": "HORIZONTAL", "width": width, "height": height,
            "focal_px": render_focal_px(profile, width, height)}


def _prepare_plate(profile: Profile, plate) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    c = profile.camera
    if plate is None:
        u8 = np.zeros((c.height, c.width) if profile.is_raw else (c.height, c.width, 3), np.uint8)
    else:
        u8 = check_plate(plate, c.width, c.height, raw=profile.is_raw)
    if profile.is_raw:
        return u8, np.zeros((c.height, c.width, 3), np.float32), u8
    return u8, u8.astype(np.float32), None


def _any_nonzero(a: np.ndarray) -> np.ndarray:
    """(H, W) bool: any of the last axis's three values is non-zero (faster than ``.any(axis=-1)``)."""
    return (a[..., 0] != 0) | (a[..., 1] != 0) | (a[..., 2] != 0)


def _finish(state: SimState, plate_u8: np.ndarray, in_sequence: bool = False,
            previous: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The 8-bit frame and its footprint from the current state: the blended graphics over the plate, then each
    effect's :meth:`~lowcam.effects.Effect.finish` (the chroma groups, JPEG, a raw frame) in chain order.
    ``in_sequence``: the frame is one of a sequence, and the finishing stops before the first temporal effect
    (:func:`finish_sequence` goes on from there). ``previous``: the frame delivered before this one in a shot,
    handed to the effects that follow it (:meth:`~lowcam.effects.Effect.finish_after`)."""
    frame = plate_u8.copy()
    footprint = np.empty(plate_u8.shape[:2], bool)

    def blend(part: slice) -> None:  # per pixel: one strip of rows per thread gives the same bytes
        if state.delta_yuv is not None:
            out = cv2.add(state.plate[part], yuv_to_rgb(state.delta_yuv[part]))
            footprint[part] = _any_nonzero(state.delta_yuv[part])
        else:
            out = state.plate[part] * (1 - state.rgb_alpha[part]) + state.rgb[part]
            footprint[part] = _any_nonzero(state.rgb_alpha[part])
        cv2.copyTo(to_uint8(out), footprint[part].astype(np.uint8), frame[part])

    thread_map(blend, row_strips(frame.shape[0], min_rows=256))
    for effect in state.applied:
        if in_sequence and effect.temporal:
            break
        with plugin_failures(effect):
            if previous is not None and effect.follows_previous:
                frame, footprint = effect.finish_after(previous, frame, footprint)
            else:
                frame, footprint = effect.finish(state, frame, footprint)
    return frame, footprint


def follows_previous(profile: Profile) -> bool:
    """Whether an enabled effect of ``profile`` finishes a shot's frame from the frame delivered before it
    (:attr:`~lowcam.effects.Effect.follows_previous`, a recursive temporal filter): a shot's frames are then made
    in order."""
    return any(e.follows_previous and e.enabled for e in profile.effects)


def check_followed_output(profile: Profile, path) -> None:
    """Refuse, in one line, a shot output other than PNG for a profile whose frames follow the one before
    (:func:`follows_previous`): the next frame reads this one as written, and a JPEG or EXR would change it (and
    a resumed shot's bytes)."""
    if follows_previous(profile) and Path(str(path)).suffix.lower() != ".png":
        name = next(e.name for e in profile.effects if e.follows_previous and e.enabled)
        raise LowcamError(f"{path}: the profile's {name} follows each frame with the next, which reads it as "
                          "written: write PNG frames")


def _sequence_tail(profile: Profile) -> list:
    """The enabled effects from the profile's first temporal one (:attr:`~lowcam.effects.Effect.temporal`) on, or
    [] when it has none."""
    effects = [e for e in profile.effects if e.enabled or e.always_runs]
    first = next((i for i, e in enumerate(effects) if e.temporal), None)
    return [] if first is None else effects[first:]


def has_temporal(profile: Profile) -> bool:
    """Whether an enabled effect of ``profile`` acts across frames (:attr:`~lowcam.effects.Effect.temporal`)."""
    return bool(_sequence_tail(profile))


def finish_sequence(profile: Profile, frames: np.ndarray, footprints: np.ndarray,
                    lead: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frames (T, H, W, 3) uint8 of one shot or capture, in order, finished up to the profile's first temporal
    effect, and their footprints (T, H, W) bool, taken through the rest of the chain: each temporal effect's
    :meth:`~lowcam.effects.Effect.finish_frames` on the sequence, each other effect after the first temporal one
    frame by frame (:meth:`~lowcam.effects.Effect.finish` without a state: the stages that need the frame's
    state, a raw blend, stand before the encoders). The first ``lead`` frames settle the temporal effects that need
    them (:meth:`~lowcam.effects.Effect.lead_frames`): each effect gets as many of them as it or a later temporal
    effect needs, the rest dropped before it (a video encoder's frame 0 is then the sequence's own), and none is
    returned."""
    tail = _sequence_tail(profile)
    count = len(frames) - lead
    for k, effect in enumerate(tail):
        with plugin_failures(effect):
            frames, footprints = effect.finish_frames(frames, footprints)
        keep = count + lead_frames(e for e in tail[k + 1:] if e.temporal)
        frames, footprints = frames[len(frames) - keep:], footprints[len(footprints) - keep:]
    return frames, footprints


#: Peak memory of the chain per working-grid pixel (bytes), measured on the bundled profiles (about 380), with
#: room for the effects that keep more.
BYTES_PER_WORKING_PIXEL = 480


def memory_needed(profile, render_shape=(0, 0)) -> int:
    """The chain's peak memory (bytes) for one frame of ``profile`` from a render of ``render_shape`` (rows,
    columns): :data:`BYTES_PER_WORKING_PIXEL` per working-grid pixel plus a few copies of the render."""
    profile = load_profile(profile)
    rows, cols = profile.geometry.working_shape
    return BYTES_PER_WORKING_PIXEL * rows * cols + 64 * int(render_shape[0]) * int(render_shape[1])


def available_memory() -> int | None:
    """Bytes this machine can give a new allocation now (``MemAvailable`` on Linux, physical memory elsewhere),
    or None when unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(profile, render_shape=(0, 0)) -> None:
    """Refuse, before allocating anything, a frame whose chain needs more memory than the machine has."""
    need, have = memory_needed(profile, render_shape), available_memory()
    if have is not None and need > have:
        profile = load_profile(profile)
        rows, cols = profile.geometry.working_shape
        raise LowcamError(f"{profile.source}: one frame needs about {need / 2**30:.1f} GiB of memory (a {cols}x{rows} "
                          f"working grid), this machine has {have / 2**30:.1f} GiB free; lower camera.oversample, "
                          "camera.margin_px or the frame size")


def _checked(render) -> CheckedRender:
    """``render`` checked (:func:`~lowcam.io.check_render_window`), or a :class:`~lowcam.io.CheckedRender` taken
    as checked when it was read (not scanned again), once what the chain relies on holds: float32 (H, W, 4) in C
    order, its window inside it."""
    if not isinstance(render, CheckedRender):
        return check_render_window(render)
    rgba, window = render
    if not (isinstance(rgba, np.ndarray) and rgba.dtype == np.float32 and rgba.ndim == 3 and rgba.shape[2] == 4
            and rgba.flags.c_contiguous) or (window is not None and not all(
                0 <= part.start < part.stop <= size for part, size in zip(window, rgba.shape))):
        raise LowcamError("render: a CheckedRender must be what lowcam.io.check_render_window returned; pass the "
                          "render's array instead")
    return render


def _start(render, profile, plate, angular_velocity, exposure_s, seed, frame, passes):
    """A validated :class:`SimState` at the start of the chain, and the plate's bytes."""
    profile = load_profile(profile)
    shape = np.shape(render.rgba if isinstance(render, CheckedRender) else render)
    check_memory(profile, shape[:2] if len(shape) >= 2 else (0, 0))
    render, window = _checked(render)
    passes = check_passes(passes, render.shape)
    plate_u8, plate_f, plate_raw = _prepare_plate(profile, plate)
    w = tuple(float(x) for x in angular_velocity)
    if len(w) != 3 or not all(np.isfinite(w)):
        raise LowcamError(f"angular_velocity must be three finite numbers (rad/s), got {angular_velocity!r}")
    if exposure_s is not None and not (0 <= exposure_s <= 10):
        raise LowcamError(f"exposure_s = {exposure_s} is out of range [0, 10] s")
    state = SimState(profile, render, plate_f, plate_raw, w, exposure_s, int(seed), int(frame), passes)
    state.keep_window("render", window)
    return state, plate_u8


def _walk(state: SimState, start: int = 0, stop: int | None = None, stages=None, plate_u8=None,
          stop_after: str | None = None) -> None:
    """The one effect loop: apply the profile's effects ``start:stop`` to ``state`` (skipping disabled ones
    that may be skipped), recording each stage's picture in ``stages`` when given."""
    effects = state.profile.effects
    for i in range(start, len(effects) if stop is None else stop):
        effect = effects[i]
        if not effect.enabled and not effect.always_runs:
            continue
        with plugin_failures(effect):
            effect.apply(state)
        state.applied.append(effect)
        if stages is not None:
            stages[f"{i:02d}-{effect.name}"] = stage_image(state, effect.writes, plate_u8)
        if stop_after == effect.name:
            break


def run(render: np.ndarray, profile="fire-i", plate: np.ndarray | None = None, angular_velocity=(0.0, 0.0, 0.0),
        exposure_s: float | None = None, seed: int = 0, frame: int = 0, keep_stages: bool = False,
        stop_after: str | None = None, passes: RenderPasses | None = None,
        previous: np.ndarray | None = None) -> Result:
    """Simulate the camera on one frame; see :func:`simulate`. ``keep_stages`` records every stage's output
    (as displayable arrays, see :func:`stage_image`); ``stop_after`` ends the chain after that effect."""
    state, plate_u8 = _start(render, profile, plate, angular_velocity, exposure_s, seed, frame, passes)
    stages: OrderedDict = OrderedDict()
    _walk(state, stages=stages if keep_stages else None, plate_u8=plate_u8, stop_after=stop_after)
    result_frame, footprint = _finish(state, plate_u8, previous=previous) if state.rgb is not None else (None, None)
    return Result(result_frame, footprint, stages, state)


def deterministic_prefix(profile, until: str | None = None) -> int:
    """How many leading effects of ``profile`` do not depend on (seed, frame) (at most up to ``until``)."""
    for i, effect in enumerate(profile.effects):
        if effect.random and effect.enabled:
            return i
        if effect.name == until:
            return i + 1
    return len(profile.effects)


def prefix_key(profile, count: int) -> str:
    """Identifies the first ``count`` effects of a profile (and its camera) for caching their output, with where
    its demosaicing delivers each sensel (:func:`~lowcam.effects.bayer.sensel_shift_px`), which the lens stage
    lays the working grid out by: a later effect's method moves the earlier stages' output."""
    return repr((profile.camera.values(), sensel_shift_px(profile),
                 [(e.name, e.enabled, e.values()) for e in profile.effects[:count]]))


def prepare(render: np.ndarray, profile, plate=None, angular_velocity=(0.0, 0.0, 0.0),
            exposure_s: float | None = None, until: str | None = None, passes: RenderPasses | None = None):
    """Run the chain up to its first random effect (noise), or through ``until``: that part is the same for
    every frame of a static scene. Returns a token for :func:`resume`; ``resume(token, seed, frame)`` equals
    ``simulate(render, profile, plate, angular_velocity, exposure_s, seed, frame)`` byte for byte."""
    state, plate_u8 = _start(render, profile, plate, angular_velocity, exposure_s, 0, 0, passes)
    start = deterministic_prefix(state.profile, until)
    _walk(state, stop=start)
    if any(effect.name == "bayer_sampling" for effect in state.applied) and all(
            type(effect).__module__.startswith("lowcam.") for effect in state.profile.effects[start:]):
        state.working = None   # of Lowcam's effects, the Bayer sampling alone reads it: a kept token need not hold it
        state._windows.pop("working", None)
    return state, start, plate_u8


def resume(token, seed: int = 0, frame: int = 0, profile: Profile | None = None, in_sequence: bool = False):
    """The 8-bit frame for ``(seed, frame)`` from a :func:`prepare` token (which it leaves untouched).
    ``profile`` may replace the token's for the remaining effects (its leading effects must be the same).
    ``in_sequence``: (frame, footprint) finished up to the first temporal effect, for :func:`resume_sequence`."""
    prefix, start, plate_u8 = token
    state = copy.copy(prefix)
    if profile is not None:
        state.profile = profile
    for name in ("bayer", "bayer_alpha", "rgb", "rgb_alpha", "delta_yuv", "working"):
        if getattr(state, name) is not None:
            setattr(state, name, getattr(state, name).copy())
    state.applied = list(prefix.applied)
    state._windows = dict(prefix._windows)
    state.seed, state.frame = int(seed), int(frame)
    _walk(state, start=start)
    if in_sequence:
        return _finish(state, plate_u8, in_sequence=True)
    return _finish(state, plate_u8)[0]


def resume_sequence(token, seed: int = 0, count: int = 1, profile: Profile | None = None) -> np.ndarray:
    """Frames ``0..count-1`` of ``seed`` from a :func:`prepare` token as one sequence (T, H, W, 3) uint8: each
    frame as :func:`resume` makes it up to the chain's first temporal effect (a video encoder), and the frames
    together through the rest (:func:`finish_sequence`). Without a temporal effect, frame k equals
    ``resume(token, seed, k, profile)``. A temporal effect that needs frames before the first
    (:meth:`~lowcam.effects.Effect.lead_frames`, a recursive filter) gets them: noise frames ``count`` on, put
    before frame 0 and dropped after."""
    prof = profile if profile is not None else token[0].profile
    tail = _sequence_tail(prof)
    if not tail:
        return np.stack([resume(token, seed, k, profile) for k in range(count)])
    lead = lead_frames(tail)
    done = [resume(token, seed, k, profile, in_sequence=True) for k in (*range(count, count + lead), *range(count))]
    frames, _ = finish_sequence(prof, np.stack([d[0] for d in done]), np.stack([d[1] for d in done]), lead)
    return frames


def simulate(render: np.ndarray, profile="fire-i", plate: np.ndarray | None = None,
             angular_velocity=(0.0, 0.0, 0.0), exposure_s: float | None = None, seed: int = 0,
             frame: int = 0, passes: RenderPasses | None = None, previous: np.ndarray | None = None) -> np.ndarray:
    """The camera's 8-bit RGB frame (H, W, 3) for a premultiplied RGBA ``render`` composited over ``plate``.

    Parameters
    ----------
    render : (H, W, 4) float array, premultiplied linear RGBA of an ideal pinhole camera, or a
        :class:`lowcam.io.CheckedRender` (:func:`lowcam.io.read_checked_render`), which is not checked again.
    profile : a profile name (``"fire-i"``, ``"ueye"``), a path to a TOML file, or a :class:`Profile`.
    plate : (h, w, 3) uint8 video frame at the camera's size (a (h, w) Bayer frame for a raw profile); None: black.
    angular_velocity : (wx, wy, wz) rad/s in the camera frame (x right, y down, z forward).
    exposure_s : exposure time in seconds; None uses the profile's.
    seed, frame : the noise of a frame depends on these two numbers only.
    passes : the render's velocity and depth (:class:`lowcam.passes.RenderPasses`), for the ``object_motion`` and
        ``depth_of_field`` effects.
    previous : the (H, W, 3) uint8 frame the shot delivered before this one, for an effect that carries from frame
        to frame (``temporal_noise_reduction``); None: the frame is made on its own.

    Examples
    --------
    >>> import numpy as np, lowcam
    >>> render = np.zeros((600, 800, 4), np.float32)
    >>> render[250:350, 350:450] = 1.0                      # an opaque white square
    >>> out = lowcam.simulate(render, "fire-i", seed=1)
    >>> out.shape, out.dtype
    ((480, 640, 3), dtype('uint8'))
    """
    return run(render, profile, plate, angular_velocity, exposure_s, seed, frame, passes=passes,
               previous=previous).frame


def stage_image(state: SimState, writes: str, plate_u8: np.ndarray) -> np.ndarray:
    """A displayable picture of the state after a stage: float RGBA for the working image, a colour-coded
    mosaic for the sensel planes, 8-bit RGB for the frame, and an arrow plot for sampling fields."""
    if writes in ("render", "working"):
        return getattr(state, writes).copy()
    if writes == "bayer":
        g = state.geometry
        m = mosaic(state.bayer, g) / 255.0
        rgb = np.zeros(m.shape + (3,), np.float32)
        for name, (dy, dx) in g.cfa.items():
            c = {"R": 0, "Gr": 1, "Gb": 1, "B": 2}[name]
            rgb[dy::2, dx::2, c] = m[dy::2, dx::2]
        return np.clip(rgb * 255, 0, 255).astype(np.uint8)
    if writes in ("rgb", "output"):
        return _finish(state, plate_u8)[0]
    return _sampling_plot(state)


def _sampling_plot(state: SimState) -> np.ndarray:
    """Arrows of the chromatic-aberration offsets (x10; red and blue) and motion streaks (white)."""
    g = state.geometry
    img = np.full((g.height, g.width, 3), 40, np.uint8)
    u, v = grid_points(g.frame_extent)
    if state.ca_grid is not None:
        ca = sample_texture(state.ca_grid, g.frame_extent, u, v)
        for (uu, vv, d) in zip(u.ravel(), v.ravel(), ca.reshape(-1, 4)):
            for c, colour in ((0, (255, 60, 60)), (2, (80, 120, 255))):
                cv2.arrowedLine(img, (int(uu), int(vv)), (int(uu + 10 * d[c]), int(vv + 10 * d[c + 1])), colour, 1,
                                tipLength=0.3)
    if state.motion_taps is not None:
        taps = sample_texture(state.motion_taps, g.working_extent, u, v).reshape(u.shape + (-1, 2))
        for (uu, vv, t) in zip(u.ravel(), v.ravel(), taps.reshape(-1, taps.shape[-2], 2)):
            pts = np.round(np.stack([uu + t[:, 0], vv + t[:, 1]], -1)).astype(np.int32)
            cv2.polylines(img, [pts], False, (255, 255, 255), 1)
    return img


def plain_composite(render: np.ndarray, profile="fire-i", plate: np.ndarray | None = None) -> np.ndarray:
    """The standard compositing the paper compares against: the render warped through the lens, resampled to the
    frame and blended over the plate with its alpha, with none of the camera's degradations."""
    profile = load_profile(profile)
    render, window = _checked(render)
    plate_u8, plate_f, _ = _prepare_plate(profile, plate)
    if profile.is_raw:
        plate_f = demosaic_bilinear(unmosaic(plate_u8, profile.geometry), profile.geometry)
    state = SimState(profile, render, plate_f, None, (0.0, 0.0, 0.0), None, 0, 0)
    state.keep_window("render", window)
    profile.effect("lens_distortion").apply(state)
    profile.effect("half_sampling").apply(state)
    g = profile.geometry
    u, v = np.meshgrid(np.arange(g.width, dtype=np.float64), np.arange(g.height, dtype=np.float64))
    x, y = g.output_to_working(u, v)
    rgba = cv2.remap(state.working, x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR)
    out = plate_f * (1 - rgba[..., 3:]) + 255.0 * rgba[..., :3]
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
