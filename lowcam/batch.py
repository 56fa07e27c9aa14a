"""Shots: run the camera over a frame sequence, serially or on Dask, resumable, with progress.

A shot is described by file patterns in which a run of ``#`` stands for the zero-padded frame number
(``renders/####.exr`` -> ``renders/0007.exr``; ``%04d`` works too). Plates may instead be one video file, read
by :mod:`lowcam.video` with the stream's colour tags (``plate_colour`` overrides them): shot frame ``f`` is video
frame ``f - video_first_frame`` in presentation order, found by its time; the video is opened once per process
(also by the add-on's Movie Clip plates), not once per frame.

Every output is written atomically, so a frame file that exists is complete; a rerun skips those frames unless
``force``. A bad frame (missing, corrupt, NaN, wrong size) is reported by name while the others finish; a full disk
(or quota) stops the shot at the first write that fails, and the temporaries of killed workers are removed when
the shot ends. Noise is
seeded per frame, so a serial run, a Dask run and a run split into chunks give the same bytes.

Contents
--------
- :data:`VIDEO_SUFFIXES`: file suffixes read as a video of plates
- :func:`expand_pattern`: a ``####`` or ``%04d`` pattern with the frame number filled in
- :data:`MAX_FRAMES`: the most frames one job takes
- :func:`parse_frames`: ``"1-240"``, ``"1-10,15,20-30"``, ``"1-240x2"`` -> sorted frame numbers
- :func:`check_shot_outputs`: check every output of a shot before any frame is made
- :class:`Shot`: everything one frame's job needs; picklable, so Dask can ship it to workers
- :class:`FrameResult`: one frame's outcome in a shot
- :func:`read_video_frame`, :func:`close_videos`: :mod:`lowcam.video`'s, the shot's video reader
- :func:`process_frame`: simulate and write one frame; bad input is reported, never raised
- :data:`READ_AHEAD`: how many frames a serial shot reads ahead of the one it simulates
- :func:`run_shot`: process frames serially, on a local Dask cluster or on one at ``tcp://host:port``
- :func:`full_disk_stop`: the one line that ends a shot at its first write to a full disk, with how to resume
- :data:`QUIET_LOGGERS`: the loggers of Dask and the libraries under it, kept to critical messages
- :func:`local_cluster`: a Dask LocalCluster of single-threaded processes on loopback
- :func:`summary`: one line on a finished shot
"""
from __future__ import annotations

import contextlib
import itertools
import logging
import os
import re
import signal
import struct
import sys
import time
import uuid
import warnings
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
from tqdm import tqdm

from .effects import trust_plugins
from .effects.noise import FRAME_RANGE
from .errors import DiskFull, LowcamError
from .io import check_plate, read_plate, reusing_render_buffers
from .motion import FrameMotion
from .outputs import check_image_output, remove_stale_temporaries, write_image
from .passes import needed_passes, read_render_and_passes
from .pipeline import check_followed_output, follows_previous, simulate
from .profile import load_profile
from .video import VIDEO_SUFFIXES, close_videos, is_video, read_video_frame  # noqa: F401  (the shot's reader)


def expand_pattern(pattern: str, frame: int) -> str:
    """``renders/####.exr`` or ``renders/%04d.exr`` with the frame number filled in."""
    if "%" in pattern:
        try:
            return pattern % frame
        except (TypeError, ValueError) as e:
            raise LowcamError(f"{pattern}: not a frame pattern ({e}); use one %d or a run of '#'") from None
    runs = list(re.finditer(r"#+", pattern))
    if not runs:
        raise LowcamError(f"{pattern}: the pattern has no '#' (or %d) for the frame number")
    m = runs[-1]
    return pattern[:m.start()] + f"{frame:0{len(m.group())}d}" + pattern[m.end():]


#: The most frames one job takes (a day of 24 fps footage is 2 073 600): more is a typing error, not a shot.
MAX_FRAMES = 2_000_000


def parse_frames(spec: str) -> list[int]:
    """``"1-240"``, ``"1-10,15,20-30"``, ``"1-240x2"`` (every second frame) -> sorted frame numbers, at most
    :data:`MAX_FRAMES` of them, each a valid frame number (:data:`lowcam.effects.noise.FRAME_RANGE`)."""
    frames: set[int] = set()
    count = 0
    for part in spec.split(","):
        m = re.fullmatch(r"\s*(-?\d{1,12})(?:\s*-\s*(-?\d{1,12})(?:x(\d{1,12}))?)?\s*", part)
        if not m:
            raise LowcamError(f"frames '{spec}': cannot read '{part}' (use e.g. 1-240, 1-10,15 or 1-240x2)")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        step = int(m.group(3) or 1)
        if b < a or step < 1:
            raise LowcamError(f"frames '{spec}': '{part}' is an empty range")
        if a < FRAME_RANGE[0] or b >= FRAME_RANGE[1]:
            raise LowcamError(f"frames '{spec}': frame numbers must lie in [-2^31, 2^31)")
        count += (b - a) // step + 1
        if count > MAX_FRAMES:
            raise LowcamError(f"frames '{spec}': more than {MAX_FRAMES} frames in one job; split the shot")
        frames.update(range(a, b + 1, step))
    return sorted(frames)


@dataclass
class Shot:
    """Everything one frame's job needs; picklable, so Dask can ship it to workers."""

    profile: str
    renders: str
    output: str
    plates: str | None = None
    motion: dict[int, FrameMotion] = field(default_factory=dict)
    require_motion: bool = False
    seed: int = 0
    video_first_frame: int = 1
    layer: str | None = None
    motion_source: str = "the motion file"
    effects: tuple = ()            # (name, ((key, value), ...)) effects added to the profile, e.g. object motion
    fps: float = 24.0              # the frame rate the renders' Vector pass was made at
    metres_per_unit: float = 1.0   # the renders' Depth pass unit
    plugins: tuple = ()            # plug-in modules the user trusted (--plugin), trusted on every worker too
    render_space: str | None = None  # the renders' colour space (None: their header's, else linear Rec.709)
    plate_colour: str | None = None  # a video plate's matrix, range, transfer overriding its tags (--plate-colour)

    def load_profile(self):
        """The shot's profile with its added ``effects`` (cached per process), the shot's ``plugins`` trusted."""
        trust_plugins(*self.plugins)
        return _profile(self.profile, self.effects)

    def output_path(self, frame: int) -> Path:
        return Path(expand_pattern(self.output, frame))


@dataclass
class FrameResult:
    """One frame's outcome; its time split into reading (render, passes, plate), simulating and writing (s)."""

    frame: int
    status: str  # "written", "skipped" or "failed"
    message: str = ""
    read_s: float = 0.0
    simulate_s: float = 0.0
    write_s: float = 0.0

    @property
    def seconds(self) -> float:
        return self.read_s + self.simulate_s + self.write_s


_PROFILES: dict = {}


def _profile(name: str, effects: tuple = ()):
    if (name, effects) not in _PROFILES:
        profile = load_profile(name)
        for effect, values in effects:
            profile = profile.with_effect(effect, **dict(values))
        _PROFILES[name, effects] = profile
    return _PROFILES[name, effects]


def _is_video(plates: str | None) -> bool:
    return is_video(plates)


def _read_plate(shot: Shot, frame: int, profile):
    c = profile.camera
    if _is_video(shot.plates):
        img = read_video_frame(shot.plates, frame - shot.video_first_frame, shot.plate_colour)
        return check_plate(img, c.width, c.height, name=f"{shot.plates} frame {frame}", raw=profile.is_raw)
    return read_plate(expand_pattern(shot.plates, frame), c.width, c.height, None if profile.is_raw else 3)


def _frame_motion(shot: Shot, frame: int) -> FrameMotion:
    motion = shot.motion.get(frame)
    if motion is None and shot.require_motion:
        raise LowcamError(f"{shot.motion_source}: no entry for this frame")
    return motion or FrameMotion((0.0, 0.0, 0.0))


def _timed(fn, *args):
    t = time.perf_counter()
    return fn(*args), time.perf_counter() - t


def _read_inputs(shot: Shot, frame: int, profile):
    """(render, passes, plate) of ``frame``."""
    render, passes = read_render_and_passes(expand_pattern(shot.renders, frame), shot.layer, needed_passes(profile),
                                            shot.fps, shot.metres_per_unit, shot.render_space)
    return render, passes, _read_plate(shot, frame, profile) if shot.plates else None


def _simulate_inputs(shot: Shot, frame: int, profile, motion: FrameMotion, inputs, previous=None):
    render, passes, plate = inputs
    return simulate(render, profile, plate, motion.angular_velocity, motion.exposure_s, shot.seed, frame, passes,
                    previous)


def _previous_output(shot: Shot, frame: int, profile):
    """The shot's written frame ``frame - 1``, for a profile whose frames follow the one before
    (:func:`~lowcam.pipeline.follows_previous`: a temporal filter); None where the shot has none (no render of
    ``frame - 1``: its first frame). A frame before that has a render but is not written yet is an error: made
    without it, the frame's bytes would depend on which frames a run happened to make first (chunks run at
    once, a preview of every other frame)."""
    if not follows_previous(profile):
        return None
    path = shot.output_path(frame - 1)
    if not path.is_file():
        if Path(expand_pattern(shot.renders, frame - 1)).is_file():
            raise LowcamError(f"{path}: frame {frame} follows frame {frame - 1}, which is not written yet (the "
                              "profile's temporal filter carries each frame into the next): make it first")
        return None
    c = profile.camera
    return read_plate(path, c.width, c.height, 3)


def _failed(frame: int, error: LowcamError, read_s: float = 0.0, simulate_s: float = 0.0) -> FrameResult:
    return FrameResult(frame, "failed", " ".join(str(error).splitlines()), read_s, simulate_s)  # one line


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of an image file from its header (a PNG's own, others through Pillow), None where it is no
    image, (0, 0) for one too large for Pillow to read its size (past its guard against decompression bombs)."""
    from PIL import Image

    try:
        with open(path, "rb") as f:
            head = f.read(24)
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            return struct.unpack(">II", head[16:24])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as img:
                return img.size
    except Image.DecompressionBombError:
        return (0, 0)
    except (OSError, ValueError):
        return None


def _already_made(shot: Shot, frame: int, profile) -> FrameResult:
    """A frame whose output exists: finished (skipped) where that file is an image of the camera's frame size;
    another picture, or a file that is no image, fails the frame in one line (it is no frame of this shot, and a
    resumed run would keep it). EXR frames are taken as they are."""
    out = shot.output_path(frame)
    if out.suffix.lower() == ".exr":
        return FrameResult(frame, "skipped")
    c = profile.camera
    size = _image_size(out)
    if size is None:
        return _failed(frame, LowcamError(f"{out}: there already, but no image; remove it, or make the frame again "
                                          "with --force"))
    if size not in ((c.width, c.height), (0, 0)):
        return _failed(frame, LowcamError(f"{out}: there already, but {size[0]}x{size[1]} where this camera's frames "
                                          f"are {c.width}x{c.height}: no frame of this shot; remove it, or make the "
                                          "frame again with --force"))
    return FrameResult(frame, "skipped")


def process_frame(shot: Shot, frame: int, force: bool = False, after=None) -> FrameResult:
    """Simulate one frame of ``shot`` and write it; never raises for bad input, reports it instead. A full disk
    (:class:`~lowcam.errors.DiskFull`) is raised: it is no frame's fault, and it ends the shot. A profile whose
    frames follow the one before (a temporal filter) reads the shot's written frame ``frame - 1``; ``after``
    (ignored) is the task Dask runs it after."""
    out = shot.output_path(frame)
    if out.exists() and not force:
        return _already_made(shot, frame, shot.load_profile())
    read_s = simulate_s = 0.0
    try:
        profile = shot.load_profile()
        motion = _frame_motion(shot, frame)
        inputs, read_s = _timed(_read_inputs, shot, frame, profile)
        previous = _previous_output(shot, frame, profile)
        image, simulate_s = _timed(_simulate_inputs, shot, frame, profile, motion, inputs, previous)
        _, write_s = _timed(write_image, out, image)
    except DiskFull:
        raise  # every later frame would fail alike: the shot stops (run_shot)
    except LowcamError as e:
        return _failed(frame, e, read_s, simulate_s)
    return FrameResult(frame, "written", "", read_s, simulate_s, write_s)


#: How many frames a serial shot reads ahead of the one it simulates (each a render, its passes and a plate in
#: memory); one frame is written behind it.
READ_AHEAD = 2


def _run_overlapped(shot: Shot, frames: list[int], force: bool, done) -> None:
    """A serial shot with its reading, simulation and writing overlapped: renders and plates are read on one thread
    up to :data:`READ_AHEAD` frames ahead, each frame is written on another while the next is simulated on this
    one. ``done(result)`` is called once per frame (a failed or skipped frame may be reported before the write of
    the one before it). The bytes are those of :func:`process_frame` frame after frame; a full disk raises
    :class:`~lowcam.errors.DiskFull` once the frames before it are reported."""
    profile = shot.load_profile()
    with ThreadPoolExecutor(1, thread_name_prefix="lowcam-read") as reader, \
            ThreadPoolExecutor(1, thread_name_prefix="lowcam-write") as writer, \
            reusing_render_buffers(READ_AHEAD + 2):   # read ahead, simulated, being read
        def start(frame):
            if shot.output_path(frame).exists() and not force:
                return _already_made(shot, frame, profile)
            try:
                motion = _frame_motion(shot, frame)
            except LowcamError as e:
                return _failed(frame, e)
            return motion, reader.submit(_timed, _read_inputs, shot, frame, profile)

        def finish(frame, write, read_s, simulate_s):
            try:
                _, write_s = write.result()
            except DiskFull:
                raise
            except LowcamError as e:
                return _failed(frame, e, read_s, simulate_s)
            return FrameResult(frame, "written", "", read_s, simulate_s, write_s)

        upcoming = iter(frames)
        queue = deque((f, start(f)) for f in itertools.islice(upcoming, READ_AHEAD))
        writing = None
        made = (None, None)  # the last frame made and its image: the next frame may follow it
        try:
            while queue:
                frame, started = queue.popleft()
                following = next(upcoming, None)
                if following is not None:
                    queue.append((following, start(following)))
                if isinstance(started, FrameResult):
                    done(started)
                    continue
                motion, read = started
                read_s = 0.0
                try:
                    inputs, read_s = read.result()
                    del read, started   # the frame's inputs go as soon as it is simulated
                    previous = made[1] if made[0] == frame - 1 else _previous_output(shot, frame, profile)
                    image, simulate_s = _timed(_simulate_inputs, shot, frame, profile, motion, inputs, previous)
                    made = (frame, image if follows_previous(profile) else None)
                except LowcamError as e:
                    done(_failed(frame, e, read_s))
                    continue
                del inputs
                if writing is not None:
                    done(finish(*writing))
                writing = (frame, writer.submit(_timed, write_image, shot.output_path(frame), image), read_s,
                           simulate_s)
            if writing is not None:
                done(finish(*writing))
        finally:
            for _, started in queue:   # a full disk or Ctrl-C: reads not begun are dropped
                if not isinstance(started, FrameResult):
                    started[1].cancel()


def check_shot_outputs(output: str, renders: str, plates: str | None, frames: list[int], inputs=()) -> None:
    """Check, before any frame is made, that every output path of the shot can be written and that none is a
    render, a plate or one of ``inputs`` (the profile, the motion file)."""
    check_image_output(expand_pattern(output, frames[0]), inputs)
    video = plates if _is_video(plates) else None
    for option, pattern in (("--renders", renders), ("--plates", None if video else plates)):
        if pattern and os.path.realpath(pattern) == os.path.realpath(output):
            raise LowcamError(f"{output}: the output pattern is the {option} pattern; choose another -o")
    for f in frames:  # an output that exists must be a regular file and no input
        out = expand_pattern(output, f)
        if os.path.lexists(out):
            sources = [expand_pattern(renders, f)] + ([expand_pattern(plates, f)] if plates and not video else [])
            check_image_output(out, sources + ([video] if video else []) + list(inputs))


@contextlib.contextmanager
def _progress(total: int, quiet: bool):
    """A progress bar on a terminal only (a log file gets the summary, not a stream of carriage returns). It writes
    to its own copy of stderr, so a reader thread keeping a codec's messages off descriptor 2 (:func:`quiet_stderr`)
    does not hide it."""
    try:
        stream = os.fdopen(os.dup(sys.stderr.fileno()), "w")
    except (AttributeError, OSError, ValueError):  # no descriptor behind stderr (a test's capture, a detached process)
        stream = None
    bar = tqdm(total=total, unit="frame", disable=True if quiet else None, dynamic_ncols=True, file=stream,
               bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} frames [{elapsed}<{remaining}, {rate_fmt}]")
    try:
        yield bar
    finally:
        bar.close()
        if stream is not None:
            stream.close()


def run_shot(shot: Shot, frames: list[int], force: bool = False, workers: int = 0, scheduler: str | None = None,
             quiet: bool = False) -> list[FrameResult]:
    """Process ``frames`` of ``shot``: serially (``workers`` 0), on a Dask LocalCluster of ``workers`` processes,
    or on the Dask cluster at ``scheduler`` (``tcp://host:port``). Returns one result per frame, in frame order."""
    check_followed_output(shot.load_profile(), shot.output)  # a bad profile fails here, once, before any frame
    if _is_video(shot.plates):
        read_video_frame(shot.plates, 0, shot.plate_colour)  # an unreadable video fails once, not once per frame
    if scheduler and not re.fullmatch(r"(tcp|tls|inproc|ucx)://[^\s/]+(:\d+)?/?", scheduler):
        raise LowcamError(f"--scheduler {scheduler}: not a Dask scheduler address (use tcp://host:port)")
    folders = {shot.output_path(f).parent for f in frames}

    def remove_temporaries_of_the_dead():  # killed runs' and killed workers'; a live run's stay
        for folder in folders:
            if folder.is_dir():
                remove_stale_temporaries(folder)

    remove_temporaries_of_the_dead()
    results: list[FrameResult] = []
    try:
        with _progress(len(frames), quiet) as bar:
            def done(result):
                results.append(result)
                bar.update()

            if workers or scheduler:
                _run_on_dask(shot, frames, force, workers, scheduler, done)
            else:
                _run_overlapped(shot, frames, force, done)
    except DiskFull as e:
        raise full_disk_stop(e, shot, frames, sum(r.status == "written" for r in results)) from None
    finally:
        remove_temporaries_of_the_dead()  # a worker killed mid-write left its temporary
    return sorted(results, key=lambda r: r.frame)


def _run_on_dask(shot: Shot, frames: list[int], force: bool, workers: int, scheduler: str | None, done) -> None:
    """Each frame a :func:`process_frame` task on Dask; ``done(result)`` as each finishes. A profile whose frames
    follow the one before (:func:`~lowcam.pipeline.follows_previous`) has each task run after the frame before it.
    Task keys are this run's own: a scheduler shared by several shots at once gives each its own tasks."""
    run = uuid.uuid4().hex[:12]
    with _dask_client(workers, scheduler) as client:
        client.run(_one_opencv_thread)  # one frame per worker process: no oversubscription
        ordered = follows_previous(shot.load_profile())  # each frame after the one before (a temporal filter)
        futures = []
        for f in frames:
            after = futures[-1] if ordered and futures else None
            futures.append(client.submit(process_frame, shot, f, force, after, pure=False,
                                         key=f"lowcam-frame-{f}-{run}"))
        from dask.distributed import as_completed

        frame_of = {future.key: f for future, f in zip(futures, frames)}
        try:
            # on this client's loop: Dask's default is the newest client of the process, which may be another
            # shot's, closed before this one ends (its futures then never reported done)
            for future in as_completed(futures, loop=client.loop):
                try:
                    result = future.result()
                except (DiskFull, KeyboardInterrupt):
                    raise
                except Exception as e:  # the task's worker died (killed for memory: KilledWorker) or was lost
                    result = _failed(frame_of[future.key], LowcamError(
                        f"frame {frame_of[future.key]}: its Dask worker failed ({type(e).__name__}: "
                        f"{str(e).split('. ')[0]})"))
                done(result)
        except DiskFull:
            client.cancel(futures)  # frames not started are not tried
            raise


def full_disk_stop(error: DiskFull, shot: Shot, frames: list[int], written: int) -> DiskFull:
    """The one line that ends a shot at its first write to a full disk: the failed write, the frames written by
    this run and in all, and how to resume (the same command again: finished frames are skipped)."""
    done = sum(shot.output_path(f).exists() for f in frames)
    return DiskFull(f"{error}; the shot stopped there: {written} frame{'s' * (written != 1)} written by this run, "
                    f"{done} of {len(frames)} done in all; free some space and run the same command again to "
                    "resume (finished frames are skipped)")


#: Dask's loggers, and those of the libraries under it, kept to critical messages in Lowcam's processes.
QUIET_LOGGERS = ("distributed", "tornado", "tornado.application", "asyncio")


@contextlib.contextmanager
def _dask_client(workers: int, scheduler: str | None):
    """A Dask client: on the cluster at ``scheduler``, or on a local cluster of ``workers`` processes that ignore
    Ctrl-C (the parent shuts them down), with Dask's own logging kept to errors that matter."""
    from dask.distributed import Client

    for name in [*QUIET_LOGGERS, *logging.root.manager.loggerDict]:  # Dask set some itself
        if name.split(".")[0] in QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.CRITICAL)
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            # the workers spawned now inherit an ignored Ctrl-C: it reaches only this process, which shuts them
            # down (one pressed in these two seconds of start-up is lost)
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                cluster = local_cluster(workers)
            finally:
                signal.signal(signal.SIGINT, previous)
            client = Client(cluster)
    except (OSError, TimeoutError) as e:
        raise LowcamError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({e})" if scheduler else
                          f"--workers {workers}: cannot start a local Dask cluster ({e})") from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def local_cluster(workers: int):
    """A Dask LocalCluster of ``workers`` single-threaded processes on loopback.

    Dask's nanny exports ``MALLOC_TRIM_THRESHOLD_`` to its workers, which switches off glibc's adaptive mmap
    threshold: every large frame buffer is then mapped and zero-filled afresh, and a frame takes 1.6x as long. The
    workers here get Dask's other settings without that one.
    """
    import dask
    from dask.distributed import LocalCluster

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    environ["PYTHONWARNINGS"] = "ignore"  # library warnings and Dask's chatter stay off the terminal
    # frame failures reach the parent with the result; a worker's own log of a connection its parent closed
    # (Ctrl-C under load) would print a traceback
    environ["DASK_LOGGING"] = repr({name: "critical" for name in QUIET_LOGGERS})
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None)


def _one_opencv_thread():
    cv2.setNumThreads(1)


def summary(results: list[FrameResult]) -> str:
    written = sum(r.status == "written" for r in results)
    skipped = sum(r.status == "skipped" for r in results)
    failed = [r for r in results if r.status == "failed"]
    line = f"{written} written, {skipped} already done, {len(failed)} failed"
    return line + "".join(f"\n  frame {r.frame}: {r.message}" for r in failed)
