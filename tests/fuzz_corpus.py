"""A corpus of hostile and careless input for the ``lowcam`` command line (used by ``test_fuzz_cli.py``).

Lowcam's promise: bad input gets exit status 2 (1 for ``lowcam batch`` when some frames are bad and others fine)
and exactly one line on stderr naming the file or option and the problem; no traceback, no output left behind
(no new file at ``-o``, no ``.part`` temporaries) and never a changed input file.

Each case is a function that writes its inputs into a given folder and returns a :class:`Case`: the argv, the exit
statuses it accepts, what the error line must name, and extra checks. :data:`CASES` maps case ids to those
functions; :func:`generate_corpus` writes every case into its own sub-folder (for running cases by hand).

Categories (the id's prefix):

1. ``out-*``: OS errors on the output (read-only folder, a parent that is a file, a directory, '', long names,
   a FIFO, a character device like /dev/null)
2. ``same-*``: the output is an input (render, plate, renders/plates pattern, a measurement set, set.toml)
3. ``profile-*``, ``motion-*``, ``gyro-*``, ``set-*``, ``ca-*``: malformed profiles, motion.json, gyro CSV,
   set.toml, chromatic-aberration grids
4. ``size-*``: absurd sizes (frame ranges, workers, schedulers, a 16384^2 x8 working grid)
5. ``input-*``: renders and plates that look valid (two Combined layers, float TIFF, 3e38, a truncated JPEG,
   EXR bytes in a .png, zero bytes, no alpha, NaN, wrong size, a missing batch frame, seeds, .jpg/.exr output)

Where the right behaviour is a judgement call, the case's ``note`` says which behaviour a careful user expects.
"""
from __future__ import annotations

import copy
import functools
import os
import shutil
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FIRE_I = ROOT / "profiles" / "fire-i.toml"

IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


@dataclass
class Case:
    """One fuzz case. ``argv`` is given to ``lowcam.cli.main`` (or ``python -m lowcam.cli`` when ``subprocess``).

    ``rc``: the accepted exit statuses. On an error (2) stderr must be exactly one line holding one of ``names``
    (any) and all of ``also``. On 1 (a batch with bad frames) each of ``bad_frames`` must be named on its own line
    together with one of ``names``. ``may_change``: Lowcam's own state files that a successful run may rewrite.
    ``outputs``: paths that must not appear on an error (nor the outputs of
    ``bad_frames`` on 1). ``inputs``: files outside the case folder whose bytes must not change (everything inside
    the folder is hashed anyway). ``special``: non-regular files (FIFO, device) that must keep their type.
    ``check(folder, rc, stdout, stderr)``: extra assertions, called after the common ones.
    """

    argv: list[str]
    rc: tuple[int, ...] = (2,)
    names: tuple[str, ...] = ()
    also: tuple[str, ...] = ()
    outputs: tuple[Path, ...] = ()
    inputs: tuple[Path, ...] = ()
    special: tuple[Path, ...] = ()
    may_change: tuple[Path, ...] = ()
    bad_frames: tuple[int, ...] = ()
    check: Callable | None = None
    subprocess: bool = False
    mem_limit_gb: float | None = None
    timeout: float = 120.0
    skip: str = ""
    note: str = ""


#: case id -> (builder(folder) -> Case, pytest marker names such as "slow" or "blender")
CASES: dict[str, tuple[Callable[[Path], Case], tuple[str, ...]]] = {}


def case(name: str, slow: bool = False, blender: bool = False):
    def register(fn):
        assert name not in CASES, name
        CASES[name] = (fn, ("slow",) * slow + ("blender",) * blender)
        return fn
    return register


def build(name: str, folder: Path) -> Case:
    """Write case ``name``'s inputs into ``folder`` (created) and return its :class:`Case`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return CASES[name][0](folder)


def generate_corpus(folder) -> dict[str, Case]:
    """Every case in its own sub-folder of ``folder``."""
    return {name: build(name, Path(folder) / name) for name in CASES}


# --- real inputs ---------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _profile():
    from lowcam.profile import load_profile

    return load_profile("fire-i")


@functools.lru_cache(maxsize=None)
def render_array() -> np.ndarray:
    """The sample scene at the Fire-i's 640x480 (premultiplied RGBA, transparent background)."""
    from lowcam.sample import sample_render

    out = sample_render(_profile(), 640)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=None)
def opaque_render_array() -> np.ndarray:
    """The sample scene over a grey wall: alpha 1 everywhere (straight and premultiplied alpha agree)."""
    r = render_array().copy()
    r[..., :3] += 0.2 * (1 - r[..., 3:])
    r[..., 3] = 1.0
    r.setflags(write=False)
    return r


@functools.lru_cache(maxsize=None)
def plate_array() -> np.ndarray:
    from lowcam.sample import sample_plate

    out = sample_plate(_profile())
    out.setflags(write=False)
    return out


def write_render(path: Path, rgba=None) -> Path:
    from lowcam.outputs import write_exr

    return write_exr(path, render_array() if rgba is None else rgba)


def write_plate(path: Path, image=None) -> Path:
    from lowcam.outputs import write_png

    return write_png(path, plate_array() if image is None else image)


def _sequence(folder: Path, frames, pattern: str, write_first) -> str:
    """Frames ``frames`` of a sequence: ``write_first(path)`` once, then copies; returns the #### pattern."""
    first = None
    for f in frames:
        p = folder / pattern.format(f)
        if first is None:
            first = write_first(p)
        else:
            shutil.copyfile(first, p)
    return str(folder / pattern.replace("{:04d}", "####"))


def write_renders(folder: Path, frames, pattern: str = "renders/{:04d}.exr") -> str:
    """The sample render as frames ``frames`` of a sequence (copies of one file); returns the #### pattern."""
    return _sequence(folder, frames, pattern, write_render)


def write_plates(folder: Path, frames, pattern: str = "plates/{:04d}.png") -> str:
    return _sequence(folder, frames, pattern, write_plate)


def reference_frame(folder: Path, name: str, rgba=None, seed: int = 0, frame: int = 0, plate: bool = True) -> Path:
    """The frame ``lowcam apply`` must give for ``rgba`` (default the sample render) over the sample plate."""
    from lowcam.outputs import write_png
    from lowcam.pipeline import simulate

    img = simulate(render_array() if rgba is None else rgba, _profile(), plate_array() if plate else None,
                   seed=seed, frame=frame)
    return write_png(folder / name, img)


# --- profiles ------------------------------------------------------------------------------------------------------

def fire_i_dict() -> dict:
    """The bundled Fire-i profile as a dict, texture paths made absolute (so a copy works from anywhere)."""
    d = tomllib.loads(FIRE_I.read_text())
    for e in d["effect"]:
        if e.get("texture"):
            e["texture"] = str(FIRE_I.parent / e["texture"])
    return d


def effect(d: dict, name: str) -> dict:
    return next(e for e in d["effect"] if e["type"] == name)


def write_profile(path: Path, mutate: Callable[[dict], None] | None = None) -> Path:
    import tomli_w

    d = fire_i_dict()
    if mutate:
        mutate(d)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(tomli_w.dumps(d))
    return path


# --- measurement sets ----------------------------------------------------------------------------------------------

def write_measurement_set(folder: Path, **capture_extra) -> Path:
    """A one-capture, one-frame measurement set (valid); ``capture_extra`` overrides keys of its [[capture]]."""
    import tomli_w

    from lowcam.outputs import write_exr, write_png
    from lowcam.pipeline import simulate

    frame = simulate(render_array(), _profile(), plate_array(), seed=1)
    write_exr(folder / "ideal" / "a.exr", render_array())
    write_png(folder / "frames" / "a-000.png", frame)
    write_png(folder / "plates" / "a.png", plate_array())
    entry = {"name": "a", "ideal": "ideal/a.exr", "frames": ["frames/a-*.png"], "plate": "plates/a.png"}
    entry.update(capture_extra)
    (folder / "set.toml").write_text(tomli_w.dumps({"capture": [entry]}))
    return folder


# --- helpers for the argv ------------------------------------------------------------------------------------------

def apply_argv(folder: Path, *extra, render=None, plate=None, out=None) -> list[str]:
    render = render or write_render(folder / "render.exr")
    argv = ["apply", "--render", str(render)]
    if plate is not False:
        argv += ["--plate", str(plate or write_plate(folder / "plate.png"))]
    argv += ["-o", str(out if out is not None else folder / "out.png")]
    return argv + [str(a) for a in extra]


def profile_case(folder: Path, mutate, *also, name="bad.toml", note="") -> Case:
    """``lowcam apply --profile BAD`` with the Fire-i profile changed by ``mutate``."""
    path = write_profile(folder / name, mutate)
    return Case(apply_argv(folder, "--profile", path, plate=False), names=(name,), also=also,
                outputs=(folder / "out.png",), note=note)


# ===================================================================================================================
# 1. OS errors on the output
# ===================================================================================================================

@case("out-readonly-folder")
def _(folder):
    if IS_ROOT:  # root writes through mode bits: use sysfs, where nobody can create files
        out = Path("/sys/lowcam-fuzz-out.png")
        return Case(apply_argv(folder, out=out, plate=False), names=("lowcam-fuzz-out.png", "/sys"),
                    outputs=(out,), note="running as root: /sys stands in for a read-only folder")
    ro = folder / "readonly"
    ro.mkdir()
    ro.chmod(0o555)
    return Case(apply_argv(folder, out=ro / "out.png", plate=False), names=("out.png", "readonly"),
                outputs=(ro / "out.png",))


@case("out-readonly-folder-batch")
def _(folder):
    renders = write_renders(folder, (1, 2))
    if IS_ROOT:
        pattern = "/sys/lowcam-fuzz-####.png"
        outs = (Path("/sys/lowcam-fuzz-0001.png"), Path("/sys/lowcam-fuzz-0002.png"))
    else:
        ro = folder / "readonly"
        ro.mkdir()
        ro.chmod(0o555)
        pattern = str(ro / "####.png")
        outs = (ro / "0001.png", ro / "0002.png")
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", pattern, "--quiet"], rc=(1, 2),
                names=("lowcam-fuzz", "readonly", "/sys"), bad_frames=(1, 2), outputs=outs,
                note="every frame fails for the same reason: 2 (one line) is best, 1 naming each frame is acceptable")


@case("out-parent-is-a-file")
def _(folder):
    (folder / "notes.txt").write_text("my notes\n")
    out = folder / "notes.txt" / "out.png"
    return Case(apply_argv(folder, out=out, plate=False), names=("notes.txt", "out.png"), outputs=(out,))


@case("out-is-an-existing-directory")
def _(folder):
    (folder / "outdir").mkdir()
    (folder / "outdir" / "keep.txt").write_text("keep me\n")
    return Case(apply_argv(folder, out=folder / "outdir", plate=False), names=("outdir",))


@case("out-empty-string")
def _(folder):
    return Case(apply_argv(folder, out="", plate=False), names=("-o", "--output", "output"))


@case("out-name-300-chars")
def _(folder):
    out = folder / ("a" * 296 + ".png")
    return Case(apply_argv(folder, out=out, plate=False), names=("a" * 40, "too long"), outputs=(out,))


@case("out-name-250-chars-is-legal-must-succeed")
def _(folder):
    # 250 characters is a legal file name (limit 255); the temporary '.NAME.XXXXXXXX.part' beside it is not.
    out = folder / ("b" * 246 + ".png")

    def check(folder, rc, stdout, stderr):
        assert out.is_file() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    return Case(apply_argv(folder, out=out, plate=False), rc=(0,), check=check,
                note="a careful user expects a legal file name to work")


def _fifo_drain(path: Path):
    """A reader for a FIFO, so that a program that streams into it does not block; returns a stop function that
    gives the bytes read."""
    import threading

    got = bytearray()

    def read():
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            return
        with os.fdopen(fd, "rb") as f:
            while chunk := f.read(65536):
                got.extend(chunk)

    t = threading.Thread(target=read, daemon=True)
    t.start()

    def stop() -> bytes:
        if t.is_alive():
            try:  # release a reader still waiting for a writer
                os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
            t.join(5)
        return bytes(got)

    return stop


@case("out-fifo")
def _(folder):
    fifo = folder / "pipe.png"
    os.mkfifo(fifo)
    stop = _fifo_drain(fifo)

    def check(folder, rc, stdout, stderr):
        data = stop()
        if rc == 0:
            assert data[:8] == b"\x89PNG\r\n\x1a\n", "exit 0 but the FIFO's reader got no PNG"

    return Case(apply_argv(folder, out=fifo, plate=False), rc=(2, 0), names=("pipe.png",), special=(fifo,),
                check=check, timeout=60,
                note="refusing (2) or streaming into the FIFO (0) are both fine; replacing the FIFO by a file is not")


@case("out-dev-null")
def _(folder):
    # Running as root, the real /dev/null could be *replaced* by a rename: use a twin device node (1, 3) here.
    dev = Path("/dev/null")
    if IS_ROOT or os.access("/dev", os.W_OK):
        dev = folder / "null"
        try:
            os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except (OSError, AttributeError) as e:
            return Case([], skip=f"cannot make a /dev/null twin ({e}) and /dev is writable: unsafe")
    return Case(apply_argv(folder, out=dev, plate=False), rc=(0, 2), names=(dev.name,), special=(dev,),
                note="discarding the frame (0) or refusing (2) are both fine; replacing the device is not")


@case("out-into-new-nested-folders-must-succeed")
def _(folder):
    out = folder / "a" / "b" / "c" / "out.png"

    def check(folder, rc, stdout, stderr):
        assert out.is_file()

    return Case(apply_argv(folder, out=out, plate=False), rc=(0,), check=check)


@case("out-existing-file-kept-on-error")
def _(folder):
    (folder / "out.png").write_bytes(b"an earlier result")
    return Case(apply_argv(folder, plate=folder / "missing.png"), names=("missing.png",),
                note="out.png existed before: it must be left as it was")


@case("out-stages-onto-an-existing-file")
def _(folder):
    plate = write_plate(folder / "plate.png")
    return Case(["stages", "--render", str(write_render(folder / "render.exr")), "-o", str(plate)],
                names=("plate.png",))


@case("out-batch-pattern-with-percent-sign")
def _(folder):
    renders = write_renders(folder, (1,))
    return Case(["batch", "--renders", renders, "--frames", "1", "-o", str(folder / "out" / "50%-####.png"),
                 "--quiet"], names=("50%-####.png", "--output", "-o"))


@case("out-batch-pattern-without-hash")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "out.png"), "--quiet"],
                names=("out.png",), outputs=(folder / "out.png",))


@case("out-chart-layout-clobbers-a-foreign-json")
def _(folder):
    (folder / "shot.json").write_text('{"format": "lowcam-motion", "version": 1, "frames": []}\n')
    return Case(["chart", "--dpi", "72", "-o", str(folder / "shot.png")], names=("shot.json",),
                outputs=(folder / "shot.png",),
                note="the layout goes to <name>.json beside the chart: an existing JSON that is not a chart layout "
                     "is someone's file (a careful user expects a refusal, not an overwrite)")


# ===================================================================================================================
# 2. The output is an input
# ===================================================================================================================

@case("same-apply-out-is-the-render")
def _(folder):
    render = write_render(folder / "render.exr")
    return Case(apply_argv(folder, render=render, out=render, plate=False), names=("render.exr",))


@case("same-apply-out-is-the-plate")
def _(folder):
    plate = write_plate(folder / "plate.png")
    return Case(apply_argv(folder, plate=plate, out=plate), names=("plate.png",))


@case("same-apply-out-is-the-plate-spelt-differently")
def _(folder):
    plate = write_plate(folder / "plate.png")
    (folder / "sub").mkdir()
    return Case(apply_argv(folder, plate=plate, out=folder / "sub" / ".." / "plate.png"), names=("plate.png",))


@case("same-batch-force-out-is-renders")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", renders, "--force", "--quiet"],
                names=("####.exr", "--output", "-o", "--renders"))


@case("same-batch-force-out-is-plates")
def _(folder):
    renders = write_renders(folder, (1, 2))
    plates = write_plates(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--plates", plates, "--frames", "1-2", "-o", plates, "--force",
                 "--quiet"], names=("####.png", "--output", "-o", "--plates"))


@case("same-batch-noforce-out-is-renders-silently-skips")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", renders, "--quiet"],
                names=("####.exr", "--output", "-o", "--renders"),
                note="without --force every frame 'already exists' (they are the renders): a careful user expects "
                     "a refusal, not '0 written, 2 already done'")


@case("same-synth-out-is-an-existing-measurement-set")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["synth", "--frames", "1", "--width", "64", "-o", str(mset)], names=("myset",),
                note="a measurement set holds real captures: refuse to write over one")


@case("same-compare-json-is-set-toml")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["compare", str(mset), "--json", str(mset / "set.toml")], names=("set.toml", "--json"))


# ===================================================================================================================
# 3. Profiles, motion.json, gyro CSV, set.toml, chromatic-aberration grids
# ===================================================================================================================

def _set(path: str, value):
    """A mutation: ``"camera.width"`` or ``"noise.red"`` (an effect's key) set to ``value``."""
    table, key = path.split(".")

    def mutate(d):
        (d["camera"] if table == "camera" else effect(d, table))[key] = copy.deepcopy(value)
    return mutate


NAN, INF = float("nan"), float("inf")

for _name, _mutate, _also in [
    ("camera-not-a-table", lambda d: d.update(camera=5), ("camera",)),
    ("camera-array-of-tables", lambda d: d.update(camera=[d["camera"]]), ("camera",)),
    ("effect-list-of-ints", lambda d: d.update(effect=[1, 2]), ("effect",)),
    ("effect-type-int", lambda d: d["effect"][0].update(type=5), ("type",)),
    ("effect-type-colon-X", lambda d: d["effect"][0].update(type=":X"), (":X",)),
    ("effect-type-module-colon-nothing", lambda d: d["effect"][0].update(type="lowcam.effects:"), ()),
    ("effect-enabled-string", lambda d: d["effect"][0].update(enabled="yes"), ("enabled",)),
    ("width-inf", _set("camera.width", INF), ("width",)),
    ("width-nan", _set("camera.width", NAN), ("width",)),
    ("width-true", _set("camera.width", True), ("width",)),
    ("width-1e300", _set("camera.width", 1e300), ("width",)),
    ("exposure-neg-inf", _set("camera.exposure_s", -INF), ("exposure_s",)),
    ("oversample-nan", _set("camera.oversample", NAN), ("oversample",)),
    ("unknown-camera-key", _set("camera.lens", "2.1mm"), ("lens",)),
    ("unknown-effect-key", _set("noise.sigma", 1.0), ("sigma",)),
    ("unknown-top-level-key", lambda d: d.update(extra={"a": 1}), ("extra",)),
    ("noise-vector-nan", _set("noise.red", [NAN, 0.015]), ("red",)),
    ("noise-vector-inf", _set("noise.green", [INF, 0.012]), ("green",)),
    ("noise-vector-negative", _set("noise.blue", [1.8, -0.016]), ("blue",)),  # a negative intercept is allowed
    ("noise-vector-absurd", _set("noise.red", [1e30, 1e30]), ("red",)),
    ("noise-vector-strings", _set("noise.red", ["a", "b"]), ("red",)),
    ("motion-blur-grid-nan", _set("motion_blur.grid", [NAN, 18.0]), ("grid",)),
    ("motion-blur-grid-inf", _set("motion_blur.grid", [INF, 18.0]), ("grid",)),
    ("motion-blur-grid-negative", _set("motion_blur.grid", [-24.0, 18.0]), ("grid",)),
    ("motion-blur-grid-zero", _set("motion_blur.grid", [0.0, 0.0]), ("grid",)),
    ("motion-blur-grid-fractional", _set("motion_blur.grid", [2.5, 1.5]), ("grid",)),
    ("spatial-blur-grid-negative", _set("spatial_blur.grid", [-1.0, -1.0]), ("grid",)),
    ("crosstalk-matrix-nan", _set("crosstalk.matrix", [[NAN, 0.04, 0.01], [0.07, 0.89, 0.04], [0, 0.06, 0.94]]),
     ("matrix",)),
    ("crosstalk-matrix-inf", _set("crosstalk.matrix", [[INF, 0.04, 0.01], [0.07, 0.89, 0.04], [0, 0.06, 0.94]]),
     ("matrix",)),
    ("crosstalk-matrix-absurd", _set("crosstalk.matrix", [[1e30, 0, 0], [0, 1e30, 0], [0, 0, 1e30]]), ("matrix",)),
    ("crosstalk-matrix-ragged", _set("crosstalk.matrix", [[1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), ("matrix",)),
    ("saturation-luma-nan", _set("saturation.luma", [NAN, 0.587, 0.114]), ("luma",)),
    ("lens-principal-point-absurd", _set("lens_distortion.principal_point", [1e6, -1e6]), ("principal_point",)),
]:
    def _make(mutate=_mutate, also=_also):
        return lambda folder: profile_case(folder, mutate, *also)
    case(f"profile-{_name}")(_make())


@case("profile-not-utf8")
def _(folder):
    path = folder / "latin1.toml"
    path.write_bytes(FIRE_I.read_text().replace("Unibrain", "Unibr\u00e4in").encode("latin-1"))
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("latin1.toml",))


@case("profile-binary")
def _(folder):
    path = folder / "binary.toml"
    path.write_bytes(bytes(range(256)) * 4)
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("binary.toml",))


@case("profile-a-directory-named-x.toml")
def _(folder):
    (folder / "x.toml").mkdir()
    return Case(apply_argv(folder, "--profile", folder / "x.toml", plate=False), names=("x.toml",))


@case("profile-texture-is-a-directory")
def _(folder):
    (folder / "tex").mkdir()
    return profile_case(folder, _set("vignetting.texture", str(folder / "tex")), "texture")


# --- motion.json ---------------------------------------------------------------------------------------------------

def motion_case(folder: Path, doc_text: str | bytes, frames=(1, 2), rc=(2,), bad_frames=(), note="") -> Case:
    renders = write_renders(folder, frames)
    path = folder / "motion.json"
    path.write_bytes(doc_text if isinstance(doc_text, bytes) else doc_text.encode())
    spec = f"{frames[0]}-{frames[-1]}"
    outs = tuple(folder / "out" / f"{f:04d}.png" for f in (bad_frames or frames))
    return Case(["batch", "--renders", renders, "--motion", str(path), "--frames", spec, "-o",
                 str(folder / "out" / "####.png"), "--quiet"], rc=rc, names=("motion.json",),
                outputs=outs, bad_frames=bad_frames, note=note)


def _motion(frames_json: str) -> str:
    return '{"format": "lowcam-motion", "version": 1, "frames": ' + frames_json + "}"


_GOOD2 = '{"frame": 2, "angular_velocity": [0, 0.1, 0]}'
for _name, _frames, _note in [
    ("frames-null", "null", ""),
    ("frames-a-string", '"1-2"', ""),
    ("frame-1e400", '[{"frame": 1e400, "angular_velocity": [0, 0, 0]}, ' + _GOOD2 + "]", ""),
    ("frame-fractional", '[{"frame": 1.5, "angular_velocity": [0, 0, 0]}, ' + _GOOD2 + "]",
     "frame 1.5 is not frame 1: refuse rather than round"),
    ("frame-duplicate", '[{"frame": 2, "angular_velocity": [0, 0, 0]}, ' + _GOOD2 + "]",
     "two entries for frame 2: refuse rather than let the last win"),
    ("angular-velocity-1e400", '[{"frame": 1, "angular_velocity": [1e400, 0, 0]}, ' + _GOOD2 + "]", ""),
    ("angular-velocity-a-string", '[{"frame": 1, "angular_velocity": "123"}, ' + _GOOD2 + "]",
     "the string \"123\" is not [1, 2, 3]"),
    ("exposure-negative", '[{"frame": 1, "angular_velocity": [0, 0, 0], "exposure_s": -0.01}, ' + _GOOD2 + "]", ""),
    ("entry-not-an-object", "[5, " + _GOOD2 + "]", ""),
]:
    def _make(frames=_frames, note=_note):
        return lambda folder: motion_case(folder, _motion(frames), note=note)
    case(f"motion-{_name}")(_make())


@case("motion-not-json")
def _(folder):
    return motion_case(folder, b"\x89PNG\r\n\x1a\n\x00\x00binary")


@case("motion-is-a-directory")
def _(folder):
    (folder / "motion.json").mkdir()
    renders = write_renders(folder, (1,))
    return Case(["batch", "--renders", renders, "--motion", str(folder / "motion.json"), "--frames", "1", "-o",
                 str(folder / "out" / "####.png"), "--quiet"], names=("motion.json",))


@case("motion-missing-one-frame")
def _(folder):
    return motion_case(folder, _motion("[" + _GOOD2 + "]"), rc=(1,), bad_frames=(1,),
                       note="frame 1 has no entry: that frame fails, naming the motion file; frame 2 is written")


# --- gyro CSV ------------------------------------------------------------------------------------------------------

def gyro_case(folder: Path, content: bytes | str, *extra, names=("gyro.csv",), fps="24", exposure="0.02") -> Case:
    renders = write_renders(folder, (1, 2))
    path = folder / "gyro.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return Case(["batch", "--renders", renders, "--gyro", str(path), "--fps", fps, "--exposure-s", exposure,
                 "--frames", "1-2", "-o", str(folder / "out" / "####.png"), "--quiet", *extra], names=names,
                outputs=(folder / "out" / "0001.png", folder / "out" / "0002.png"))


_GYRO_OK = "t,wx,wy,wz\n" + "".join(f"{k * 0.01:.2f},0,0.1,0\n" for k in range(20))

for _name, _content in [
    ("empty", b""),
    ("only-comments-and-blanks", "# nothing\n\n   \n"),
    ("binary", bytes(range(256)) * 8),
    ("nan-time", "t,wx,wy,wz\nnan,0,0,0\nnan,0,0,0\n0.5,0,0,0\n"),
    ("inf-rate", "t,wx,wy,wz\n0,inf,0,0\n0.5,0,0,0\n"),
    ("duplicate-times", "t,wx,wy,wz\n0,0,0,0\n0,1,1,1\n0,2,2,2\n"),
    ("ragged-rows", "t,wx,wy,wz\n0,0,0,0\n0.5,0,0\n"),
]:
    def _make(content=_content):
        return lambda folder: gyro_case(folder, content)
    case(f"gyro-{_name}")(_make())


def clip_case(folder: Path, name: str, content: bytes, says: str) -> Case:
    """``--gyro`` given a binary file (read as a video clip with its own gyro): one line naming it and saying
    ``says``."""
    renders = write_renders(folder, (1, 2))
    path = folder / name
    path.write_bytes(content)
    return Case(["batch", "--renders", renders, "--gyro", str(path), "--exposure-s", "0.02", "--frames", "1-2", "-o",
                 str(folder / "out" / "####.png"), "--quiet"], names=(name,), also=(says,),
                outputs=(folder / "out" / "0001.png", folder / "out" / "0002.png"))


def _box(kind: bytes, body: bytes, size: int | None = None) -> bytes:
    """An MP4 box: 32-bit big-endian size (``size``, else the true one), type, body."""
    return (size or 8 + len(body)).to_bytes(4, "big") + kind + body


@case("gyro-clip-cut-short")
def _(folder):   # an MP4 whose media data box says 1 MB and holds 64 bytes: a copy cut short
    data = _box(b"ftyp", b"isom\0\0\2\0isomiso2mp41") + _box(b"mdat", bytes(range(64)), size=1 << 20)
    return clip_case(folder, "GX010001.MP4", data, "cut short")


@case("gyro-clip-not-a-video")
def _(folder):   # binary bytes that are no container FFmpeg or telemetry-parser knows
    return clip_case(folder, "clip.mp4", b"\0\1\2\3" * 512 + bytes(range(256)), "not a video clip")


@case("gyro-clip-is-a-picture")
def _(folder):
    return clip_case(folder, "clip.mov", (ROOT / "lowcam" / "data" / "coffee.png").read_bytes(), "not a video clip")


@case("gyro-fps-nan")
def _(folder):
    return gyro_case(folder, _GYRO_OK, names=("--fps", "fps"), fps="nan")


@case("gyro-exposure-negative")
def _(folder):
    return gyro_case(folder, _GYRO_OK, names=("--exposure-s", "exposure"), exposure="-0.02")


@case("gyro-exposure-inf")
def _(folder):
    return gyro_case(folder, _GYRO_OK, names=("--exposure-s", "exposure", "gyro.csv"), exposure="inf")


# --- set.toml ------------------------------------------------------------------------------------------------------

def set_case(folder: Path, text: str | None = None, **capture_extra) -> Case:
    mset = write_measurement_set(folder / "myset", **capture_extra)
    if text is not None:
        (mset / "set.toml").write_text(text)
    return Case(["compare", str(mset), "--json", str(folder / "out.json")], names=("set.toml",),
                outputs=(folder / "out.json",))


for _name, _text, _extra in [
    ("capture-5", "capture = 5\n", {}),
    ("capture-array-of-ints", "capture = [5, 6]\n", {}),
    ("capture-frames-int", None, {"frames": 5}),
    ("angular-velocity-strings", None, {"angular_velocity": ["a", "b", "c"]}),
    ("angular-velocity-nan", None, {"angular_velocity": [NAN, 0.0, 0.0]}),
    ("angular-velocity-scalar", None, {"angular_velocity": 0.5}),
    ("exposure-fast", None, {"exposure_s": "fast"}),
    ("exposure-negative", None, {"exposure_s": -0.01}),
    ("exposure-inf", None, {"exposure_s": INF}),
    ("ideal-is-a-directory", None, {"ideal": "frames"}),
]:
    def _make(text=_text, extra=_extra):
        return lambda folder: set_case(folder, text, **extra)
    case(f"set-{_name}")(_make())


# --- chromatic-aberration grids -----------------------------------------------------------------------------------

def ca_case(folder: Path, content: bytes | str, note="") -> Case:
    path = folder / "ca.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return profile_case(folder, _set("chromatic_aberration.texture", str(path)), "ca.csv", note=note)


_CA_HEADER = "u,v,red_du,red_dv,blue_du,blue_dv\n"


def _ca_grid(offset: float) -> str:
    rows = [f"{u},{v},{offset},{offset},{-offset},{-offset}" for v in (120, 360) for u in (160, 480)]
    return _CA_HEADER + "\n".join(rows) + "\n"


for _name, _content, _note in [
    ("header-only", _CA_HEADER, ""),
    ("one-column", "u\n1\n2\n3\n", ""),
    ("rows-of-one-value", _CA_HEADER + "1\n2\n3\n4\n", ""),
    ("binary", bytes(range(256)) * 8, ""),
    ("offsets-1e6-px", _ca_grid(1e6), "offsets a thousand frames wide are not lateral colour: refuse"),
    ("offsets-nan", _ca_grid(NAN), ""),
]:
    def _make(content=_content, note=_note):
        return lambda folder: ca_case(folder, content, note)
    case(f"ca-{_name}")(_make())


# ===================================================================================================================
# 4. Sizes
# ===================================================================================================================

@case("size-batch-frames-1-200000000")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-200000000", "-o", str(folder / "out" / "####.png"),
                 "--quiet"], names=("--frames", "frames", "200000000"), subprocess=True, mem_limit_gb=3,
                timeout=40, note="a typo'd range: refuse at once (exit 2) rather than build 200M jobs")


@case("size-batch-workers-minus-1")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "out" / "####.png"),
                 "--workers", "-1", "--quiet"], names=("--workers", "workers"), subprocess=True, timeout=60,
                outputs=(folder / "out" / "0001.png",))


@case("size-batch-scheduler-garbage")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "out" / "####.png"),
                 "--scheduler", "garbage", "--quiet"], names=("--scheduler", "garbage"), subprocess=True,
                timeout=60, outputs=(folder / "out" / "0001.png",))


@case("size-batch-scheduler-unreachable", slow=True)
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "out" / "####.png"),
                 "--scheduler", "tcp://127.0.0.1:1", "--quiet"], names=("127.0.0.1:1", "--scheduler"),
                subprocess=True, timeout=120, outputs=(folder / "out" / "0001.png",))


@case("size-profile-16384-oversample-8")
def _(folder):
    def huge(d):
        d["camera"].update(width=16384, height=16384, oversample=8.0)
        effect(d, "chromatic_aberration").pop("texture")  # the bundled grid is for 640x480
        effect(d, "vignetting").pop("texture")
    path = write_profile(folder / "huge.toml", huge)
    small = np.zeros((48, 64, 4), np.float32)
    small[..., 3] = 1
    render = write_render(folder / "small.exr", small)
    return Case(apply_argv(folder, "--profile", path, render=render, plate=False),
                names=("huge.toml", "oversample", "width"), subprocess=True, mem_limit_gb=4, timeout=90,
                outputs=(folder / "out.png",),
                note="a 131072^2 working grid needs ~1 TB: refuse up front naming the profile, no MemoryError")


@case("size-profile-motion-blur-grid-1e9")
def _(folder):
    path = write_profile(folder / "grid.toml", _set("motion_blur.grid", [1e9, 1e9]))
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("grid.toml",), also=("grid",),
                subprocess=True, mem_limit_gb=4, timeout=90, outputs=(folder / "out.png",))


for _name, _frames, _width, _option in (("size-synth-width-0", "1", "0", "--width"),
                                        ("size-synth-width-8", "1", "8", "--width"),
                                        ("size-synth-frames-0", "0", "64", "--frames")):
    @case(_name)
    def _(folder, frames=_frames, width=_width, option=_option):
        return Case(["synth", "--frames", frames, "--width", width, "-o", str(folder / "set")], names=(option,),
                    outputs=(folder / "set" / "set.toml",))


@case("size-apply-exposure-inf")
def _(folder):
    return Case(apply_argv(folder, "--exposure-s", "inf", plate=False), names=("--exposure-s", "exposure"))


@case("size-apply-exposure-nan")
def _(folder):
    return Case(apply_argv(folder, "--exposure-s", "nan", plate=False), names=("--exposure-s", "exposure"))


# ===================================================================================================================
# 5. Renders and plates that look valid
# ===================================================================================================================

@case("input-exr-two-combined-layers")
def _(folder):
    import OpenEXR

    r = np.ascontiguousarray(render_array())
    path = folder / "layers.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION},
                 {"ViewLayer.Combined": r, "Overlay.Combined": np.ascontiguousarray(r[::-1])}).write(str(path))
    return Case(apply_argv(folder, render=path, plate=False), names=("layers.exr",),
                note="two Combined layers in one part: which one is meant is not knowable; refuse naming both "
                     "rather than pick one silently")


@case("input-float32-tiff-render")
def _(folder):
    import cv2

    path = folder / "render.tif"
    cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(opaque_render_array()), cv2.COLOR_RGBA2BGRA))
    ref = reference_frame(folder, "reference.png", opaque_render_array(), plate=False)

    def check(folder, rc, stdout, stderr):
        if rc == 0:
            import cv2

            got, want = cv2.imread(str(folder / "out.png")), cv2.imread(str(ref))
            assert got is not None and np.array_equal(got, want), \
                "float TIFF read differently from the same render as EXR (float values divided by 255?)"

    return Case(apply_argv(folder, render=path, plate=False), rc=(0, 2), names=("render.tif",), check=check,
                note="read the float TIFF as linear light (same frame as from EXR) or refuse it; never scale it")


@case("input-finite-3e38-render")
def _(folder):
    r = opaque_render_array().copy()
    r[180:300, 240:400, :3] = 3e38
    path = write_render(folder / "hot.exr", r)

    def check(folder, rc, stdout, stderr):
        if rc == 0:
            import cv2

            out = cv2.imread(str(folder / "out.png"))
            assert out[220:260, 290:350].mean() > 240, "a 3e38 (finite) patch did not come out white"

    return Case(apply_argv(folder, render=path, plate=False), rc=(0, 2), names=("hot.exr",), check=check,
                note="finite but absurd: either clip to white (0) or refuse naming the file (2); not NaN garbage")


@case("input-truncated-jpeg-plate")
def _(folder):
    import cv2

    ok, data = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(plate_array()), cv2.COLOR_RGB2BGR))
    data = data.tobytes()
    path = folder / "plate.jpg"
    path.write_bytes(data[:len(data) * 2 // 3])
    return Case(apply_argv(folder, plate=path), names=("plate.jpg",),
                note="libjpeg pads a truncated file with grey and says so on fd 2; refuse it in one line")


@case("input-truncated-png-plate")
def _(folder):
    write_plate(folder / "full.png")
    data = (folder / "full.png").read_bytes()
    path = folder / "plate.png"
    path.write_bytes(data[:len(data) * 2 // 3])
    (folder / "full.png").unlink()
    return Case(apply_argv(folder, plate=path), names=("plate.png",))


@case("input-exr-bytes-named-png")
def _(folder):
    path = folder / "render.png"
    write_render(folder / "real.exr")
    os.replace(folder / "real.exr", path)
    ref = reference_frame(folder, "reference.png")

    def check(folder, rc, stdout, stderr):
        if rc == 0:
            assert (folder / "out.png").read_bytes() == ref.read_bytes(), "EXR bytes in a .png read differently"

    return Case(apply_argv(folder, render=path), rc=(0, 2), names=("render.png",), check=check,
                note="read by content (0, same frame as the .exr) or refuse naming the file (2)")


@case("input-zero-byte-render-exr")
def _(folder):
    (folder / "render.exr").write_bytes(b"")
    return Case(apply_argv(folder, render=folder / "render.exr", plate=False), names=("render.exr",))


@case("input-zero-byte-render-png")
def _(folder):
    (folder / "render.png").write_bytes(b"")
    return Case(apply_argv(folder, render=folder / "render.png", plate=False), names=("render.png",))


@case("input-zero-byte-plate")
def _(folder):
    (folder / "plate.png").write_bytes(b"")
    return Case(apply_argv(folder, plate=folder / "plate.png"), names=("plate.png",))


@case("input-png-render-without-alpha")
def _(folder):
    from lowcam.outputs import write_png

    path = write_png(folder / "rgb.png", np.full((480, 640, 3), 128, np.uint8))
    return Case(apply_argv(folder, render=path, plate=False), names=("rgb.png",))


@case("input-exr-render-rgb-only")
def _(folder):
    import OpenEXR

    path = folder / "rgb.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage},
                 {"RGB": np.ascontiguousarray(render_array()[..., :3])}).write(str(path))
    return Case(apply_argv(folder, render=path, plate=False), names=("rgb.exr",))


@case("input-render-nan-pixels")
def _(folder):
    r = render_array().copy()
    r[100:110, 200:210, 1] = np.nan
    return Case(apply_argv(folder, render=write_render(folder / "nan.exr", r), plate=False), names=("nan.exr",))


@case("input-render-nan-alpha-only")
def _(folder):
    r = render_array().copy()
    r[5, 5, 3] = np.nan
    return Case(apply_argv(folder, render=write_render(folder / "nan.exr", r), plate=False), names=("nan.exr",))


@case("input-render-minus-inf")
def _(folder):
    r = render_array().copy()
    r[7, 9, 0] = -np.inf
    return Case(apply_argv(folder, render=write_render(folder / "inf.exr", r), plate=False), names=("inf.exr",))


@case("input-render-alpha-above-1")
def _(folder):
    r = render_array().copy()
    r[..., 3] *= 3
    return Case(apply_argv(folder, render=write_render(folder / "alpha.exr", r), plate=False),
                names=("alpha.exr",))


@case("input-render-8x8-too-small")
def _(folder):
    r = np.ones((8, 8, 4), np.float32)
    return Case(apply_argv(folder, render=write_render(folder / "tiny.exr", r), plate=False), names=("tiny.exr",))


@case("input-plate-wrong-size")
def _(folder):
    import cv2

    plate = write_plate(folder / "small.png", cv2.resize(np.ascontiguousarray(plate_array()), (320, 240)))
    return Case(apply_argv(folder, plate=plate), names=("small.png",))


@case("input-plate-greyscale")
def _(folder):
    plate = write_plate(folder / "grey.png", np.full((480, 640), 100, np.uint8))
    return Case(apply_argv(folder, plate=plate), names=("grey.png",))


@case("input-plate-is-a-fifo")
def _(folder):
    os.mkfifo(folder / "plate.png")
    return Case(apply_argv(folder, plate=folder / "plate.png"), names=("plate.png",), special=(folder / "plate.png",),
                timeout=60)


@case("input-batch-missing-frame")
def _(folder):
    renders = write_renders(folder, (1, 3))
    out = folder / "out"

    def check(folder, rc, stdout, stderr):
        assert (out / "0001.png").is_file() and (out / "0003.png").is_file(), "the good frames were not written"

    return Case(["batch", "--renders", renders, "--frames", "1-3", "-o", str(out / "####.png"), "--quiet"],
                rc=(1,), names=("0002.exr",), bad_frames=(2,), outputs=(out / "0002.png",), check=check)


@case("input-batch-nan-frame")
def _(folder):
    renders = write_renders(folder, (1, 2))
    r = render_array().copy()
    r[0, 0, 0] = np.nan
    write_render(folder / "renders" / "0002.exr", r)
    out = folder / "out"
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(out / "####.png"), "--quiet"],
                rc=(1,), names=("0002.exr",), bad_frames=(2,), outputs=(out / "0002.png",))


@case("input-batch-truncated-jpeg-plate-frame")
def _(folder):
    import cv2

    renders = write_renders(folder, (1, 2))
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(plate_array()), cv2.COLOR_RGB2BGR))
    (folder / "plates").mkdir()
    (folder / "plates" / "0001.jpg").write_bytes(data.tobytes())
    (folder / "plates" / "0002.jpg").write_bytes(data.tobytes()[:len(data) * 2 // 3])
    out = folder / "out"
    return Case(["batch", "--renders", renders, "--plates", str(folder / "plates" / "####.jpg"), "--frames", "1-2",
                 "-o", str(out / "####.png"), "--quiet"], rc=(1,), names=("0002.jpg",), bad_frames=(2,),
                outputs=(out / "0002.png",))


@case("input-batch-plates-video-garbage")
def _(folder):
    renders = write_renders(folder, (1, 2))
    (folder / "video.mp4").write_bytes(np.random.default_rng(0).bytes(5000))
    out = folder / "out"
    return Case(["batch", "--renders", renders, "--plates", str(folder / "video.mp4"), "--frames", "1-2",
                 "-o", str(out / "####.png"), "--quiet"], rc=(2, 1), names=("video.mp4",), bad_frames=(1, 2),
                outputs=(out / "0001.png", out / "0002.png"),
                note="FFmpeg's 'moov atom not found' on fd 2 is a second line; 2 (one line) is best")


def _differs_or_refused(ref: Path, option: str):
    def check(folder, rc, stdout, stderr):
        if rc == 0:
            assert (folder / "out.png").read_bytes() != ref.read_bytes(), \
                f"{option} gives the same bytes as the reference: it wraps modulo 2**32"
    return check


@case("input-seed-4294967296-vs-0")
def _(folder):
    ref = reference_frame(folder, "seed0.png", seed=0)
    return Case(apply_argv(folder, "--seed", "4294967296"), rc=(0, 2), names=("--seed",),
                check=_differs_or_refused(ref, "--seed 4294967296"),
                note="must give other noise than seed 0, or be refused")


@case("input-seed-minus-1-vs-4294967295")
def _(folder):
    ref = reference_frame(folder, "seedmax.png", seed=4294967295)
    return Case(apply_argv(folder, "--seed", "-1"), rc=(0, 2), names=("--seed",),
                check=_differs_or_refused(ref, "--seed -1"))


@case("input-frame-4294967296-vs-0")
def _(folder):
    ref = reference_frame(folder, "frame0.png", frame=0)
    return Case(apply_argv(folder, "--frame", "4294967296"), rc=(0, 2), names=("--frame",),
                check=_differs_or_refused(ref, "--frame 4294967296"))


@case("input-out-jpg-is-jpeg")
def _(folder):
    def check(folder, rc, stdout, stderr):
        import cv2

        data = (folder / "out.jpg").read_bytes()
        assert data[:2] == b"\xff\xd8", f"out.jpg holds {data[:8]!r}, not JPEG"
        assert cv2.imread(str(folder / "out.jpg")).shape == (480, 640, 3)

    return Case(apply_argv(folder, out=folder / "out.jpg"), rc=(0,), check=check)


@case("input-out-tif-is-tiff-or-refused")
def _(folder):
    def check(folder, rc, stdout, stderr):
        if rc == 0:
            data = (folder / "out.tif").read_bytes()
            assert data[:4] in (b"II*\x00", b"MM\x00*"), f"out.tif holds {data[:8]!r}, not TIFF"

    return Case(apply_argv(folder, out=folder / "out.tif"), rc=(0, 2), names=("out.tif",), check=check)


@case("input-out-exr-is-float-0-1")
def _(folder):
    def check(folder, rc, stdout, stderr):
        import OpenEXR

        with OpenEXR.File(str(folder / "out.exr")) as f:
            channels = {k: np.asarray(v.pixels) for p in f.parts for k, v in p.channels.items()}
        assert channels, "no channels"
        for name, px in channels.items():
            assert px.dtype.kind == "f", f"channel {name} is {px.dtype}, not float"
            assert px.shape[:2] == (480, 640), f"channel {name} is {px.shape}"
            assert np.isfinite(px).all() and px.min() >= 0 and px.max() <= 1, \
                f"channel {name} spans {px.min()}..{px.max()}, not 0..1"
            assert px.max() > 0.5, f"channel {name} is dark throughout: max {px.max()}"

    return Case(apply_argv(folder, out=folder / "out.exr"), rc=(0,), check=check)


# ===================================================================================================================
# Deeper cases: aliases of inputs, special files as inputs, hostile text, textures, codecs
# ===================================================================================================================

@case("same-apply-out-is-a-symlink-to-the-plate")
def _(folder):
    plate = write_plate(folder / "plate.png")
    os.symlink(plate, folder / "link.png")
    return Case(apply_argv(folder, plate=plate, out=folder / "link.png"), names=("link.png", "plate.png"))


@case("same-apply-out-is-a-hard-link-to-the-render")
def _(folder):
    render = write_render(folder / "render.exr")
    os.link(render, folder / "copy.exr")
    return Case(apply_argv(folder, render=render, out=folder / "copy.exr", plate=False),
                names=("copy.exr", "render.exr"))


@case("same-batch-out-is-plates-spelt-pct04d")
def _(folder):
    renders = write_renders(folder, (1, 2))
    plates = write_plates(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--plates", plates, "--frames", "1-2", "-o",
                 str(folder / "plates" / "%04d.png"), "--force", "--quiet"],
                names=("%04d.png", "####.png", "--plates", "-o"))


@case("same-batch-out-pattern-000hash-hits-the-renders")
def _(folder):
    renders = write_renders(folder, (1, 2))
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "renders" / "000#.exr"),
                 "--force", "--quiet"], names=("000#.exr", "0001.exr", "--renders", "-o"),
                note="a different pattern that names the same files is still the renders")


@case("same-batch-out-through-a-symlinked-folder")
def _(folder):
    renders = write_renders(folder, (1, 2))
    os.symlink(folder / "renders", folder / "alias")
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "alias" / "####.exr"),
                 "--force", "--quiet"], names=("alias", "####.exr", "--renders", "-o"))


@case("same-compare-json-is-a-frame-of-the-set")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["compare", str(mset), "--json", str(mset / "frames" / "a-000.png")], names=("a-000.png", "--json"))


@case("same-compare-report-is-the-set-folder")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["compare", str(mset), "--report", str(mset)], names=("myset", "--report"))


@case("same-diagnose-json-is-set-toml")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["diagnose", str(mset), "--only", "tone_curve", "--json", str(mset / "set.toml")],
                names=("set.toml", "--json"))


@case("same-diagnose-add-best-o-is-set-toml")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    return Case(["diagnose", str(mset), "--only", "tone_curve", "--json", str(folder / "d.json"), "--add-best",
                 "-o", str(mset / "set.toml")], names=("set.toml", "-o"), outputs=(folder / "d.json",))


@case("same-diagnose-json-and-o-are-one-file")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    out = folder / "result.json"
    return Case(["diagnose", str(mset), "--only", "tone_curve", "--json", str(out), "--add-best", "-o", str(out)],
                names=("result.json", "--json", "-o"), outputs=(out,),
                note="two outputs on one path: the second would overwrite the first")


@case("out-upper-case-suffix-PNG")
def _(folder):
    def check(folder, rc, stdout, stderr):
        assert (folder / "OUT.PNG").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    return Case(apply_argv(folder, out=folder / "OUT.PNG", plate=False), rc=(0,), check=check)


@case("out-batch-jpg-pattern-is-jpeg")
def _(folder):
    renders = write_renders(folder, (1, 2))

    def check(folder, rc, stdout, stderr):
        for f in (1, 2):
            assert (folder / "out" / f"{f:04d}.jpg").read_bytes()[:2] == b"\xff\xd8"

    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(folder / "out" / "####.jpg"),
                 "--quiet"], rc=(0,), check=check)


@case("input-exr-two-parts-both-rgba")
def _(folder):
    import OpenEXR

    r = np.ascontiguousarray(render_array())
    parts = [OpenEXR.Part({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION, "name": n},
                          {"RGBA": r if n == "left" else np.ascontiguousarray(r[:, ::-1])}, n)
             for n in ("left", "right")]
    path = folder / "stereo.exr"
    OpenEXR.File(parts).write(str(path))
    return Case(apply_argv(folder, render=path, plate=False), names=("stereo.exr",),
                note="two parts (views) each with RGBA: refuse naming them, as for two Combined layers")


def _jpeg_bytes() -> bytes:
    import cv2

    ok, data = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(plate_array()), cv2.COLOR_RGB2BGR))
    return data.tobytes()


@case("input-jpeg-plate-with-trailer-after-eoi-is-valid")
def _(folder):
    path = folder / "plate.jpg"
    path.write_bytes(_jpeg_bytes() + b"\x00\x00\x00\x18ftypmp42" + bytes(200))  # a phone's appended motion clip
    return Case(apply_argv(folder, plate=path), rc=(0,),
                note="bytes after the end-of-image marker (phones append clips) do not make a JPEG truncated")


@case("input-png-plate-with-bytes-after-iend-is-valid")
def _(folder):
    write_plate(folder / "full.png")
    path = folder / "plate.png"
    path.write_bytes((folder / "full.png").read_bytes() + b"trailing junk" * 4)
    (folder / "full.png").unlink()
    return Case(apply_argv(folder, plate=path), rc=(0,),
                note="decoders ignore bytes after IEND; the picture is whole")


@case("input-float-tiff-plate")
def _(folder):
    import cv2

    path = folder / "plate.tif"
    cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(plate_array()), cv2.COLOR_RGB2BGR).astype(np.float32)
                / 255)
    return Case(apply_argv(folder, plate=path), rc=(0, 2), names=("plate.tif",),
                note="use it (0) or refuse it naming the file (2)")


@case("input-plate-16-bit-png-is-fine")
def _(folder):
    plate = write_plate(folder / "plate16.png", plate_array().astype(np.uint16) * 257)
    return Case(apply_argv(folder, plate=plate), rc=(0,))


@case("input-render-is-a-directory")
def _(folder):
    (folder / "render.exr").mkdir()
    return Case(apply_argv(folder, render=folder / "render.exr", plate=False), names=("render.exr",))


@case("input-batch-video-plates-too-short")
def _(folder):
    import cv2

    renders = write_renders(folder, (1, 2, 3))
    w = cv2.VideoWriter(str(folder / "plates.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 24, (640, 480))
    for _ in range(2):
        w.write(cv2.cvtColor(np.ascontiguousarray(plate_array()), cv2.COLOR_RGB2BGR))
    w.release()
    out = folder / "out"
    return Case(["batch", "--renders", renders, "--plates", str(folder / "plates.avi"), "--frames", "1-3", "-o",
                 str(out / "####.png"), "--quiet"], rc=(1,), names=("plates.avi",), bad_frames=(3,),
                outputs=(out / "0003.png",))


@case("input-batch-render-is-a-directory")
def _(folder):
    renders = write_renders(folder, (1,))
    (folder / "renders" / "0002.exr").mkdir()
    out = folder / "out"
    return Case(["batch", "--renders", renders, "--frames", "1-2", "-o", str(out / "####.png"), "--quiet"],
                rc=(1,), names=("0002.exr",), bad_frames=(2,), outputs=(out / "0002.png",))


# --- special files and hostile text as inputs ---------------------------------------------------------------------

def _batch_with(folder: Path, option: str, value, *extra) -> list[str]:
    renders = write_renders(folder, (1, 2))
    return ["batch", "--renders", renders, option, str(value), *extra, "--frames", "1-2", "-o",
            str(folder / "out" / "####.png"), "--quiet"]


def _fifo_feed(path: Path, data: bytes):
    """A writer for a FIFO (as ``<(...)`` gives a program); returns a stop function that releases it."""
    import threading

    def write():
        try:
            with open(path, "wb") as f:
                f.write(data)
        except OSError:
            pass

    t = threading.Thread(target=write, daemon=True)
    t.start()

    def stop():
        if t.is_alive():
            try:  # release a writer still waiting for a reader
                os.close(os.open(path, os.O_RDONLY | os.O_NONBLOCK))
            except OSError:
                pass
            t.join(5)
    return stop


@case("motion-from-a-pipe-is-fine")
def _(folder):
    # `lowcam batch --motion <(make-motion ...)`: a pipe with a writer; it can be read once only. (A FIFO that
    # nobody writes blocks, as it does for cat: not tested, that is the pipe's nature.)
    fifo = folder / "motion.json"
    os.mkfifo(fifo)
    stop = _fifo_feed(fifo, _motion('[{"frame": 1, "angular_velocity": [0, 0.1, 0]}, ' + _GOOD2 + "]").encode())

    def check(folder, rc, stdout, stderr):
        stop()
        assert (folder / "out" / "0001.png").is_file() and (folder / "out" / "0002.png").is_file()

    return Case(_batch_with(folder, "--motion", fifo), rc=(0,), special=(fifo,), subprocess=True, timeout=20,
                check=check, note="a second read of the pipe would block for ever")


@case("motion-is-dev-zero")
def _(folder):
    return Case(_batch_with(folder, "--motion", "/dev/zero"), names=("/dev/zero",), subprocess=True,
                mem_limit_gb=1.5, timeout=10, note="an endless file: refuse non-regular files, do not read until OOM")


@case("gyro-is-dev-urandom")
def _(folder):
    return Case(_batch_with(folder, "--gyro", "/dev/urandom", "--fps", "24", "--exposure-s", "0.02"),
                names=("/dev/urandom",), subprocess=True, mem_limit_gb=1.5, timeout=10)


@case("set-is-dev-zero")
def _(folder):
    return Case(["compare", "/dev/zero"], names=("/dev/zero",), subprocess=True, mem_limit_gb=1.5, timeout=10)


@case("profile-deeply-nested-array")
def _(folder):
    path = folder / "deep.toml"
    path.write_text(FIRE_I.read_text().replace("[camera]", "deep = " + "[" * 50000 + "]" * 50000 + "\n[camera]", 1))
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("deep.toml",))


@case("profile-5000-digit-integer")
def _(folder):
    path = folder / "digits.toml"
    path.write_text(FIRE_I.read_text().replace("width = 640", "width = 6" + "0" * 5000, 1))
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("digits.toml",))


@case("motion-deeply-nested-json")
def _(folder):
    return motion_case(folder, _motion("[" * 50000 + "]" * 50000))


@case("motion-frame-5000-digit-integer")
def _(folder):
    return motion_case(folder, _motion('[{"frame": 1' + "0" * 5000 + ', "angular_velocity": [0, 0, 0]}]'))


@case("size-frames-5000-digit-number")
def _(folder):
    renders = write_renders(folder, (1,))
    return Case(["batch", "--renders", renders, "--frames", "1-1" + "0" * 5000, "-o",
                 str(folder / "out" / "####.png"), "--quiet"], names=("--frames", "frames"))


@case("gyro-t0-nan")
def _(folder):
    return gyro_case(folder, _GYRO_OK, "--gyro-t0", "nan", names=("--gyro-t0", "t0"))


@case("set-corrupt-history-json")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    history = mset / ".lowcam" / "history.json"
    history.parent.mkdir()
    history.write_text('[{"time": "2026-01-01", "error": 1.0')  # cut off mid-write by an old version
    return Case(["compare", str(mset)], rc=(0, 2), names=("history.json",), may_change=(history,),
                note="Lowcam's own history file is corrupt: start it afresh (0) or refuse naming it (2)")


@case("set-history-json-is-an-object")
def _(folder):
    mset = write_measurement_set(folder / "myset")
    history = mset / ".lowcam" / "history.json"
    history.parent.mkdir()
    history.write_text('{"error": 1.0}')
    return Case(["compare", str(mset)], rc=(0, 2), names=("history.json",), may_change=(history,))


# --- textures ------------------------------------------------------------------------------------------------------

def _with_pixel_map(kind: str, texture: Path):
    def mutate(d):
        i = next(k for k, e in enumerate(d["effect"]) if e["type"] == "yuv_blend")
        d["effect"].insert(i, {"type": kind, "texture": str(texture)})
    return mutate


@case("profile-prnu-texture-not-npy")
def _(folder):
    write_plate(folder / "map.npy")  # PNG bytes under a .npy name
    return profile_case(folder, _with_pixel_map("prnu", folder / "map.npy"), "map.npy")


@case("profile-prnu-texture-pickled-objects")
def _(folder):
    np.save(folder / "map.npy", np.array([{"evil": 1}] * 3, dtype=object), allow_pickle=True)
    return profile_case(folder, _with_pixel_map("prnu", folder / "map.npy"), "map.npy")


@case("profile-prnu-texture-nan")
def _(folder):
    m = np.zeros((480, 640, 3), np.float32)
    m[10, 10] = np.nan
    np.save(folder / "map.npy", m)
    return profile_case(folder, _with_pixel_map("prnu", folder / "map.npy"), "map.npy")


@case("profile-dsnu-texture-wrong-shape")
def _(folder):
    np.save(folder / "map.npy", np.zeros((2, 2), np.float32))
    return profile_case(folder, _with_pixel_map("dsnu", folder / "map.npy"), "map.npy")


def _vignetting_tiff(folder: Path, values: np.ndarray) -> Case:
    import cv2

    cv2.imwrite(str(folder / "gain.tif"), values.astype(np.float32))
    return profile_case(folder, _set("vignetting.texture", str(folder / "gain.tif")), "gain.tif")


@case("profile-vignetting-texture-float-tiff-nan")
def _(folder):
    v = np.ones((60, 80), np.float32)
    v[30, 40] = np.nan
    return _vignetting_tiff(folder, v)


@case("profile-vignetting-texture-float-tiff-negative")
def _(folder):
    return _vignetting_tiff(folder, np.full((60, 80), -0.5, np.float32) + np.eye(60, 80, dtype=np.float32))


@case("size-profile-16384-square-oversample-1")
def _(folder):
    def big(d):
        d["camera"].update(width=16384, height=16384, oversample=1.0)
        effect(d, "chromatic_aberration").pop("texture")
        effect(d, "vignetting").pop("texture")
    path = write_profile(folder / "big.toml", big)
    return Case(apply_argv(folder, "--profile", path, plate=False), names=("big.toml",), subprocess=True,
                mem_limit_gb=4, timeout=120, outputs=(folder / "out.png",),
                note="within every key's range but ~16 GB of working arrays: refuse naming the profile (or the "
                     "memory needed), not a bare 'out of memory'")


# --- the Blender-side commands (addon/commands.py) -----------------------------------------------------------------

def _needs_bpy() -> str:
    import importlib.util

    return "" if importlib.util.find_spec("bpy") else "bpy is not installed"


@case("blender-demo-synthetic-into-a-foreign-folder")
def _(folder):
    (folder / "results").mkdir()
    (folder / "results" / "notes.txt").write_text("mine\n")
    return Case(["demo", "--synthetic", "-o", str(folder / "results")], names=("results",))


@case("blender-motion-out-is-the-blend")
def _(folder):
    (folder / "shot.blend").write_bytes(b"BLENDER-v500" + bytes(64))
    return Case(["motion", str(folder / "shot.blend"), "--frames", "1", "-o", str(folder / "shot.blend")],
                names=("shot.blend",))


@case("blender-motion-not-a-blend", blender=True)
def _(folder):
    (folder / "shot.blend").write_text("not a blend\n")
    return Case(["motion", str(folder / "shot.blend"), "--frames", "1", "-o", str(folder / "motion.json")],
                names=("shot.blend",), outputs=(folder / "motion.json",), subprocess=True, timeout=60,
                skip=_needs_bpy())


@case("blender-render-missing-blend", blender=True)
def _(folder):
    return Case(["render", str(folder / "missing.blend"), "--frames", "1", "-o", str(folder / "out" / "####.png")],
                names=("missing.blend",), subprocess=True, timeout=60, skip=_needs_bpy())


@case("blender-render-frames-garbage")
def _(folder):
    (folder / "shot.blend").write_bytes(b"BLENDER-v500" + bytes(64))
    return Case(["render", str(folder / "shot.blend"), "--frames", "1-", "-o", str(folder / "out" / "####.png")],
                names=("--frames", "frames"))
