"""A profile from the plate itself: no chart, no ideal.

The footage a user films is itself a measurement of the camera. Each :class:`PlateProbe` measures one no-reference
statistic on the footage (the noise level function, the edge spread and overshoot, the radial fall-off, the gyro's
angular velocity, ...), and its estimator (a plain function in the effect's own module, beside the effect it sets)
turns the statistic into that effect's parameters with a confidence in 0..1. :func:`estimate_profile` applies the
confident estimates to a copy of a base profile and records where each number came from in the profile's
``[provenance]`` table; estimates below :data:`MIN_CONFIDENCE` are reported, not applied. :func:`model_statistics`
measures the same statistics on the base profile's simulation of similar content (the footage's denoised median
frame as an opaque ideal through :mod:`lowcam.pipeline`), so a report shows each estimate beside the model's value.

The probes are walked in the order of :func:`plate_probes`, each declared by its effect and its estimator in that effect's module; an estimate is
a :class:`lowcam.plate_estimate.PlateEstimate` (defined below the effects, which make them), and an estimator that
needs the model's frame of a scene is handed :func:`film`. Temporal statistics (the noise) compare frames registered
by a homography from tracked corners (:func:`lowcam.plate_estimate.register_footage`), so a panning camera and
people walking through a fixed camera's view are not read as noise. Each confidence is earned from the measurement's
own evidence (blocks, edges, levels, registered pixels, the scatter over tiles); footage that cannot show a
statistic at all (flat, still) gives "not measurable" and no value.

Contents
--------
- :class:`Footage`: the frames of a shot (RGB, DN 0-255 as the camera delivered them), fps, path, optional gyro
- :func:`read_footage`: a video file (:mod:`lowcam.video`) or a folder or glob of frames as :class:`Footage`
- :func:`check_footage`: footage too short or too small to measure, refused in one line
- :func:`read_phone_gyro`: a gyro log of rows ``wx wy wz t`` (and optional frame stamps) as ``t, wx, wy, wz``
- :func:`plate_probes`: every plate probe the effects declare, in the order they run
- :data:`MIN_CONFIDENCE`: estimates below this confidence are reported, not applied
- :func:`film`: the profile's frame of an ideal scene (how the effects' estimators ask the model)
- :func:`still_segments`: runs of consecutive frames in which the camera and scene hold still (frame differences;
  from :mod:`lowcam.plate_estimate`, where the effects' estimators find it)
- :func:`similar_content`: the footage's denoised median frame as an opaque ideal render, downscaled
- :func:`simulate_similar`: frames of the profile filming :func:`similar_content`
- :func:`headline`: the few numbers of a statistic worth a table (sigma at 64/128/192 DN, edge widths, ...)
- :func:`model_statistics`: fill each estimate's ``model`` with the statistic measured on the profile's simulation
- :func:`estimate_profile`: (profile, estimates): the confident estimates applied to a copy of the base profile
- :func:`plate_name`: the name of a profile estimated from a plate
- :func:`apply_estimate`: an estimate's params set in a profile (or an effect turned off), with provenance

References
----------
- [Liu2008] C. Liu, R. Szeliski, S. B. Kang, C. L. Zitnick and W. T. Freeman, "Automatic Estimation and Removal of
  Noise from a Single Image", IEEE TPAMI 30(2), 299-314, 2008 (the noise level function).
- [Foi2008] A. Foi, M. Trimeche, V. Katkovnik and K. Egiazarian, "Practical Poissonian-Gaussian Noise Modeling and
  Fitting for Single-Image Raw-Data", IEEE TIP 17(10), 1737-1754, 2008.
- [Goldman2010] D. B. Goldman, "Vignette and Exposure Calibration and Compensation", IEEE TPAMI 32(12),
  2276-2288, 2010 (vignetting from the same scene points seen at different image positions).
- [ISO12233] ISO 12233:2017 (edge spread, 10-90 % rise).
"""
from __future__ import annotations

import contextlib
import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..captures import expand_paths, load_frames
from ..effects import known_effects
from ..errors import LowcamError, NotFitted, ProfileError
from ..gyro_logs import log_kind, read_gyro_log
from ..pipeline import prepare, render_camera, resume_sequence, simulate
from ..plate_estimate import PlateEstimate, PlateProbe, still_segments  # noqa: F401  (still_segments: the API)
from ..profile import load_profile
from ..video import VideoReader, av_log_capture, is_video, stream_facts

#: Estimates below this confidence are reported, not applied to the profile.
MIN_CONFIDENCE = 0.5

#: A shot needs at least this many frames.
MIN_FRAMES = 2
#: Footage narrower or lower than this (px) is refused: its statistics need blocks, edges and tiles.
MIN_SIDE_PX = 64

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr"}


@dataclass
class Footage:
    """The frames of one shot as the camera delivered them: ``frames`` (T, H, W, 3) uint8 or float32, DN 0-255,
    RGB (a sequence of (H, W, 3) arrays also works); ``fps`` (frames/s); ``path`` (for messages); ``gyro``:
    optional samples (N, 4) ``t, wx, wy, wz`` (s, rad/s, Lowcam's camera axes) with ``frame_times`` (s, the start
    of each frame on the gyro's clock; None: frame i starts at ``i / fps`` after the first sample)."""

    frames: Sequence[np.ndarray]
    fps: float = 30.0
    path: str = "footage"
    gyro: np.ndarray | None = None
    frame_times: np.ndarray | None = None
    names: list[str] = field(default_factory=list)
    video: dict | None = None   # a video file's coding, read from its bitstream (lowcam.video.stream_facts)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in px."""
        return tuple(np.shape(self.frames[0])[:2])

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` as float32 RGB, DN 0-255."""
        return np.asarray(self.frames[i], np.float32)

    def stack(self, indices=None, max_frames: int | None = None) -> np.ndarray:
        """Frames (T, H, W, 3) float32 DN: ``indices`` (default all), evenly thinned to ``max_frames``."""
        idx = list(range(len(self))) if indices is None else list(indices)
        if max_frames is not None and len(idx) > max_frames:
            idx = [idx[int(round(k))] for k in np.linspace(0, len(idx) - 1, max_frames)]
        return np.stack([self.frame(i) for i in idx])


def _frame_paths(path: Path) -> list[Path]:
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file())
        return sorted(files, key=_natural_key)
    return sorted((p for p in expand_paths([path]) if p.is_file()), key=_natural_key)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


def read_footage(path, fps: float | None = None, gyro=None, max_frames: int = 2000,
                 colour: str | None = None) -> Footage:
    """Read a shot: a video file (:class:`lowcam.video.VideoReader`: its own colour tags, ``colour``, the
    ``--plate-colour`` text, overriding them), a folder of frames (PNG/JPEG/TIFF, in natural name
    order) or a glob pattern of frames. ``gyro``: optional gyro log (:func:`read_phone_gyro`). Every problem is
    one line naming the file: missing, unreadable, too few
    frames, mismatched sizes, video data the decoder reports damaged (it would conceal it with grey blocks)."""
    p = Path(path)
    name = str(path)
    if p.is_file() and is_video(p):
        frames, rate, facts = _read_video(p, max_frames, colour)
        footage = Footage(frames, fps or rate or 30.0, name, video=facts)
    else:
        paths = _frame_paths(p)
        if not paths:
            raise LowcamError(f"{name}: no such video file, folder or frames")
        if len(paths) < MIN_FRAMES:
            raise LowcamError(f"{name}: {len(paths)} frame(s); plate estimation needs at least {MIN_FRAMES}")
        paths = paths[:max_frames]
        frames, names = load_frames(paths, MIN_FRAMES, name)
        footage = Footage(np.stack(frames), fps or 30.0, name, names=names)
    check_footage(footage)
    if gyro is not None:
        footage.gyro, footage.frame_times = read_phone_gyro(gyro)
    return footage


def check_footage(footage: Footage) -> None:
    """Refuse, in one line naming it, footage a plate cannot be measured on: fewer than :data:`MIN_FRAMES`
    frames, or frames under :data:`MIN_SIDE_PX` either way."""
    if len(footage) < MIN_FRAMES:
        raise LowcamError(f"{footage.path}: {len(footage)} frame(s); plate estimation needs at least {MIN_FRAMES}")
    h, w = footage.shape
    if min(h, w) < MIN_SIDE_PX:
        raise LowcamError(f"{footage.path}: frames of {w}x{h} px are too small to measure (at least {MIN_SIDE_PX} "
                          "px each way)")


def _read_video(path: Path, max_frames: int, colour: str | None = None):
    """The video's frames (T, H, W, 3) uint8 RGB (:class:`lowcam.video.VideoReader`: the stream's own matrix,
    range and transfer, ``colour`` overriding them), its frame rate (or None) and what its bitstream says of its
    coding (:func:`lowcam.video.stream_facts`)."""
    frames = []
    with contextlib.ExitStack() as open_video:
        with av_log_capture() as said:   # FFmpeg conceals damage (grey blocks) and says so
            # opened under the capture, so it decodes on this thread only (see VideoReader)
            video = open_video.enter_context(VideoReader(path, colour))
            try:
                for _, rgb in video.frames(max_frames):
                    frames.append(rgb)
            except LowcamError:
                if video.decode_error is None:
                    raise
        complaint = next((line for line in said if _VIDEO_DAMAGE.search(line)), video.decode_error)
        if complaint is None and video.corrupt:
            complaint = f"frame {video.corrupt[0]} flagged corrupt by the decoder"
        if complaint:
            raise LowcamError(f"{path}: damaged video data ({complaint.strip()}; {len(frames)} of {video.count} "
                              "frames decoded); damaged footage is not measured")
        if not frames:
            raise LowcamError(f"{path}: no frame could be decoded")
        if len(frames) < min(video.count, max_frames) - 1:
            print(f"note: {path}: only the first {len(frames)} of the {video.count} frames its packets list could "
                  "be decoded; measuring those", file=sys.stderr)
        facts = stream_facts(video)
        rate = video.fps
    return np.stack(frames), rate, facts


#: What FFmpeg's decoders say of damaged video data they conceal.
_VIDEO_DAMAGE = re.compile(r"damaged|corrupt|conceal|error|invalid|missing|truncat", re.IGNORECASE)


def read_phone_gyro(path, framestamps=None) -> tuple[np.ndarray, np.ndarray | None]:
    """A gyro log as (samples (N, 4) ``t, wx, wy, wz``, frame start times or None). Reads a log with a header
    (Lowcam's CSV, Gyroflow's ``.gcsv`` or project, a clip's own gyro: :func:`lowcam.gyro_logs.read_gyro_log`) or
    the phone format:
    whitespace-separated rows ``wx wy wz t`` (rad/s, s), with ``framestamp.txt`` beside it (or ``framestamps``)
    giving each frame's start time (s). Times logged in milliseconds (samples about 2.4 ms apart read as 2.4 "s")
    are converted to seconds. The phone format's axes are kept as logged: a phone's gyro axes need not be Lowcam's
    camera axes (x right, y down, z forward)."""
    path = Path(path)
    if not path.is_file():
        raise LowcamError(f"{path}: no such gyro log")
    if log_kind(path) == "clip":   # a video clip's own gyro
        return read_gyro_log(path).samples, None
    text = path.read_text(errors="replace")
    first = next((ln for ln in text.splitlines() if ln.strip()), "")
    if first and not _numeric_row(first):  # a header: Lowcam's CSV or Gyroflow's
        return read_gyro_log(path).samples, None
    try:
        rows = np.loadtxt(path, delimiter="," if "," in first else None, ndmin=2)
    except ValueError as e:
        raise LowcamError(f"{path}: not a gyro log of rows 'wx wy wz t' ({str(e).splitlines()[0]})") from None
    if rows.shape[1] != 4 or len(rows) < 2 or not np.isfinite(rows).all():
        raise LowcamError(f"{path}: a gyro log needs at least 2 finite rows of 4 numbers 'wx wy wz t', got "
                          f"{rows.shape[0]} row(s) of {rows.shape[1]}")
    t = rows[:, 3]
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise LowcamError(f"{path}: row {k + 1}: time {t[k]:g} does not follow the previous row's {t[k - 1]:g}")
    scale = 1e-3 if np.median(np.diff(t)) > 0.5 else 1.0  # milliseconds (a gyro samples faster than 2 Hz)
    samples = np.column_stack([t * scale, rows[:, :3]])
    stamps = Path(framestamps) if framestamps else path.with_name("framestamp.txt")
    times = None
    if stamps.is_file():
        try:
            times = np.loadtxt(stamps, delimiter="," if "," in stamps.read_text()[:200] else None, ndmin=1)
        except ValueError:
            raise LowcamError(f"{stamps}: not a list of frame times (one number per line)") from None
        times = np.asarray(times, np.float64).ravel() * scale
    elif framestamps:
        raise LowcamError(f"{stamps}: no such frame-stamp file")
    return samples, times


def _numeric_row(line: str) -> bool:
    try:
        [float(v) for v in line.replace(",", " ").split()]
        return True
    except ValueError:
        return False


def _target(est: "PlateEstimate", key: str) -> tuple[str, str]:
    """(effect, param) of one of an estimate's params: ``"effect.param"`` or a param of ``est.effect``."""
    return tuple(key.split(".", 1)) if "." in key else (est.effect, key)


def film(profile, make_ideal, seed: int = 0, frame: int = 0) -> np.ndarray:
    """The frame (float32 DN) of ``profile`` filming the opaque ideal ``make_ideal(width, height)`` (RGBA 0-1, at
    the pinhole field of view the profile's render needs): how the estimators in the effect modules, which do not
    run the pipeline themselves, ask the model what it makes of a scene."""
    cam = render_camera(profile, profile.camera.width)
    return simulate(make_ideal(cam["width"], cam["height"]), profile, seed=seed, frame=frame).astype(np.float32)


def plate_probes() -> list[PlateProbe]:
    """Every plate probe the known effects declare (``Effect.plate_probe``, plug-ins included), in the order they
    run (``PlateProbe.order``): the edges first and the codec (JPEG blockiness, chroma bandwidth) next, since the
    noise estimate divides by the gain of the row filters the edges fit (:func:`lowcam.effects.noise.noise_gain`),
    reads JPEG-coded frames on their luma and judges the codec's share of a moving shot's noise by the JPEG quality
    found (:data:`lowcam.effects.noise.CODEC_FLICKER`)."""
    probes = [replace(cls.plate_probe, effect=cls.name) for cls in known_effects() if cls.plate_probe is not None]
    return sorted(probes, key=lambda p: p.order)


def similar_content(footage: Footage, width: int, height: int) -> np.ndarray:
    """A denoised frame of the footage, scaled to ``width`` x ``height``, as an opaque premultiplied RGBA ideal
    render (0-1): the per-pixel temporal median of its longest still segment (up to 15 frames), or, where the
    camera never holds still (a median would smear the moving scene), its middle frame denoised by OpenCV's
    non-local means. The frame is not deblurred, so the model films content already as soft as the footage:
    the statistics compare like with like, absolute sharpness is the edge estimate's job."""
    runs = still_segments(footage)
    if runs:
        start, stop = max(runs, key=lambda r: r[1] - r[0])
        med = np.median(footage.stack(range(start, stop), max_frames=15), axis=0)
    else:
        middle = np.clip(np.round(footage.frame(len(footage) // 2)), 0, 255).astype(np.uint8)
        med = cv2.fastNlMeansDenoisingColored(middle, None, 5, 5, 7, 21).astype(np.float32)
    small = cv2.resize(med, (int(width), int(height)), interpolation=cv2.INTER_AREA)
    out = np.ones((int(height), int(width), 4), np.float32)
    out[..., :3] = np.clip(small / 255.0, 0.0, 1.0)
    return out


def simulate_similar(footage: Footage, profile, frames: int = 4, seed: int = 0) -> np.ndarray:
    """``frames`` frames (T, H, W, 3) float32 DN of ``profile`` filming :func:`similar_content` (a still
    camera), each with its own noise, in order (:func:`lowcam.pipeline.resume_sequence`: a temporal filter holds
    some of it)."""
    profile = load_profile(profile) if isinstance(profile, (str, Path)) else profile
    cam = render_camera(profile, profile.camera.width)
    ideal = similar_content(footage, cam["width"], cam["height"])
    return resume_sequence(prepare(ideal, profile), seed, frames, profile).astype(np.float32)


def model_statistics(footage: Footage, profile, estimates: list[PlateEstimate], frames: int = 4) -> None:
    """Fill each estimate's ``model`` with its statistic measured on ``profile`` filming similar content."""
    by_name = {p.name: p for p in plate_probes()}
    sim = simulate_similar(footage, profile, frames)
    for est in estimates:
        probe = by_name.get(est.statistic)
        if probe is not None:
            try:
                est.model = probe.statistic(sim)
            except (ValueError, np.linalg.LinAlgError) as e:
                est.model = {"not measured": str(e)}


_HEADLINE_KEYS = ("method", "frames", "still_pairs", "grid_pairs", "compared", "sigma_at_dn", "edges",
                  "width_10_90_px", "overshoot", "gain_at_rho", "pairs",
                  "shift_px_total", "median_speed_rad_s", "max_speed_rad_s", "fit_rms")


def headline(stat: dict) -> dict:
    """The few numbers of a statistic (``PlateEstimate.measured`` or ``model``) worth a table, nested as found."""
    out = {}
    for key, value in (stat or {}).items():
        if key in _HEADLINE_KEYS:
            out[key] = value
        elif isinstance(value, dict):
            sub = headline(value)
            if sub:
                out[key] = sub
    return out


def estimate_profile(footage: Footage, base_profile, progress: bool = True, min_confidence: float = MIN_CONFIDENCE,
                     probes: list[PlateProbe] | None = None):
    """(profile, estimates): every probe of :func:`plate_probes` run on ``footage``; the params of each estimate
    with a confidence of at least ``min_confidence`` applied to a copy of ``base_profile`` (a profile or a name),
    with a ``[provenance]`` entry per parameter (``"effect.enabled": False`` turns the effect off, with an entry
    for the effect: a JPEG chroma subsampling found replaces the base's own chroma subsampling rather than
    stacking both), unless an effect it sets becomes one no real camera has (:meth:`Effect.implausible`: then it
    is reported, not applied). The profile is named after the plate (``camera.name``, with provenance) once
    anything is applied. A probe whose fit cannot be made (:class:`lowcam.errors.NotFitted`) gives a not
    measurable estimate with its reason. Progress goes to stderr."""
    base = load_profile(base_profile) if isinstance(base_profile, (str, Path)) else base_profile
    probes = plate_probes() if probes is None else probes
    out = base.copy()
    estimates = []
    for i, probe in enumerate(probes):
        if progress:
            print(f"[{i + 1}/{len(probes)}] {probe.name}", file=sys.stderr, flush=True)
        try:
            est = probe.estimate(footage, out, film)  # later probes see earlier estimates (noise: the fitted filters, codec)
        except NotFitted as e:
            est = PlateEstimate.not_measurable(probe.name, probe.effect, {}, str(e))
        if est is None:
            continue
        estimates.append(est)
        est.base_params = {}
        for key in est.params:
            effect, param = _target(est, key)
            e = base.effect(effect)
            value = getattr(e, param, None) if e is not None else None
            est.base_params[key] = str(value) if isinstance(value, Path) else value  # a texture's path
        if est.params and est.measurable and est.confidence >= min_confidence:
            note = (f"estimated from the plate {footage.path} ({probe.name.replace('_', ' ')}, confidence "
                    f"{est.confidence:.2f})")
            try:
                trial, entries = apply_estimate(out, est, note)
            except ProfileError as e:  # a value the effect refuses (binary frames' noise): reported, not applied
                est.reason += f"; not applied: {e}"
                continue
            touched = [trial.effect(name) for name in {_target(est, k)[0] for k in est.params}]
            bad = [f"{e.name}: {why}" for e in touched if e is not None and e.enabled for why in e.implausible()]
            if bad:
                est.reason += f"; not applied: {'; '.join(bad)}"
                continue
            out = trial
            out.provenance.update(entries)
            est.applied = True
    if any(e.applied for e in estimates):
        out.camera.name = plate_name(base, footage)
        out.provenance["camera.name"] = f"the plate {footage.path}, starting from {base.camera.name or base.name}"
    return out, estimates


def plate_name(base, footage: Footage) -> str:
    """The name of a profile estimated from ``footage`` starting from ``base``."""
    return f"{base.camera.name or base.name}, estimated from the plate {Path(str(footage.path)).name}"


def apply_estimate(profile, est: PlateEstimate, note: str):
    """(a copy of ``profile`` with ``est.params`` set, its ``[provenance]`` entries): ``"effect.enabled": False``
    disables that effect (entry ``effect``: off, and why), any other key sets a parameter (entry
    ``effect.param``: ``note``)."""
    out, entries = profile, {}
    for key, value in est.params.items():
        effect, param = _target(est, key)
        if param == "enabled":
            if not value and out.effect(effect) is not None and out.effect(effect).enabled:
                out = out.without(effect)
                entries[effect] = f"off: {note}"
            continue
        out = out.with_effect(effect, **{param: value})
        entries[f"{effect}.{param}"] = note
    return out, entries
