"""The Match loop in Blender: estimate a profile from the plate, compare it with measurements, diagnose what it
lacks, add the missing effect, watch the error fall, undo.

Every number comes from the ``lowcam`` command line (``calibrate plate``, ``compare``, ``diagnose``) run beside
Blender by :mod:`.jobs`, with ``--json`` outputs this module reads back on the main thread; nothing here measures or
fits. The settings live in ``scene.lowcam_match``: the measurement set, the candidates to try, the last
comparison (error, verdict, where), the ranked candidates and the profile versions with their errors.

Files: profiles go beside the .blend (a new file: a temporary folder), the JSON and HTML reports into
``<blend name>-match/`` beside it. Estimating writes ``<blend name>-plate.toml``; each added effect writes the next
version ``NAME-v2.toml``, ``NAME-v3.toml``, ... of the first profile's name and selects it.

Contents
--------
- :class:`LowcamCandidate`: one ranked candidate of a diagnosis (effect, errors, evidence)
- :class:`LowcamVersion`: one profile version of the loop and its error
- :class:`LowcamMatch`: the scene's Match settings and results (``scene.lowcam_match``)
- :func:`profile_folder`: where the loop writes profiles: beside the .blend, or a temporary folder
- :func:`work_folder`: where the loop writes its JSON and reports
- :func:`plate_footage`: the scene's plate as ``lowcam calibrate plate`` takes it (a video, or a glob of frames)
- :func:`plate_frames`: the scene frame showing the plate's first frame, and the plate's frame count
- :func:`select_profile`: make a profile (name or file) the scene's profile
- :func:`next_version`: the file of the next profile version (``NAME-vN.toml``)
- :func:`where_lines`: a comparison's ``where`` as short lines (worst channel, region, band, level)
- :func:`start_compare`, :func:`start_diagnose`, :func:`start_add`, :func:`start_until_explained`,
  :func:`start_estimate`: start each job of the loop (the operators call these)
- :func:`undo_to`: go back to an earlier profile version
- :class:`LOWCAM_OT_match_estimate`, :class:`LOWCAM_OT_match_compare`, :class:`LOWCAM_OT_match_diagnose`,
  :class:`LOWCAM_OT_match_add` (``index``: a row of the candidates, -1 the best),
  :class:`LOWCAM_OT_match_until_explained`: the operators that start the loop's jobs; in background mode
  (``blender -b``, the bpy module) they wait for their job, ``wait=False`` returns at once
- :class:`LOWCAM_OT_match_undo` (``index``: a version), :class:`LOWCAM_OT_match_cancel`,
  :class:`LOWCAM_OT_match_open_report`, :class:`LOWCAM_OT_match_report` (a job's error into the info log),
  :class:`LOWCAM_OT_save_profile_as`
- :data:`RESIDUAL_IMAGE`, :data:`HISTORY_IMAGE`: the names of the Blender images the pictures are loaded as
- :data:`classes`: the property and operator classes, for registration
- :func:`register`: add ``scene.lowcam_match``
- :func:`unregister`: remove it
"""
from __future__ import annotations

import glob
import json
import re
import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, CollectionProperty, FloatProperty, IntProperty, StringProperty

from lowcam.errors import LowcamError

from . import jobs
from ..blender_compat import path_options
from .motion import write_camera_gyro_csv
from .properties import profile_ref

#: Image names the loop's pictures get in Blender.
RESIDUAL_IMAGE, HISTORY_IMAGE = "Lowcam Residual Map", "Lowcam Error History"


class LowcamCandidate(bpy.types.PropertyGroup):
    effect: StringProperty(name="Effect")
    error_after: FloatProperty(name="Error After", description="The error with the effect added (1 = noise)")
    held_out: FloatProperty(name="Held Out", default=-1.0,
                            description="The error on captures the fit did not see (-1: nothing held out)")
    evidence: StringProperty(name="Evidence")
    flags: StringProperty(name="Flags")


class LowcamVersion(bpy.types.PropertyGroup):
    profile: StringProperty(name="Profile", description="The profile's name or absolute .toml path")
    label: StringProperty(name="Label")
    error: FloatProperty(name="Error", default=-1.0, description="Its error against the measurements (-1: not "
                                                                 "compared yet)")
    verdict: StringProperty(name="Verdict")
    report: StringProperty(name="Report", description="Its comparison's report folder")


class LowcamMatch(bpy.types.PropertyGroup):
    measurement_set: StringProperty(
        name="Measurement Set", subtype="DIR_PATH", options=path_options(),
        description="A measurement set folder (set.toml: captures of known scenes, e.g. made by lowcam synth); "
                    "without one, Compare looks at the plate alone and Diagnose is not possible")
    only: StringProperty(name="Candidates", description="Comma-separated effects Diagnose tries (empty: all "
                                                        "of them, which takes minutes)")
    max_steps: IntProperty(name="Most Effects", default=6, min=1, max=20,
                           description="How many effects Until Explained may add")
    error: FloatProperty(name="Error", default=-1.0, precision=3,
                         description="The last comparison's error in noise floors (1 = the noise; explained "
                                     "below 1.1; -1: not compared)")
    verdict: StringProperty(name="Verdict")
    families: StringProperty(name="Families")
    where: StringProperty(name="Where", description="Where the error lives: lines separated by ';'")
    summary: StringProperty(name="Summary", description="The last job's one-line outcome")
    report: StringProperty(name="Report", subtype="FILE_PATH", description="The last comparison's HTML report")
    candidates: CollectionProperty(type=LowcamCandidate)
    candidate_index: IntProperty(name="Candidate", default=0)
    versions: CollectionProperty(type=LowcamVersion)
    version_index: IntProperty(name="Version", default=0)
    progress: StringProperty(name="Progress")
    job_error: StringProperty(name="Error Message", description="The last job's one-line error")


# --- files -----------------------------------------------------------------------------------------------------------

_temporary: Path | None = None


def _temporary_folder() -> Path:
    global _temporary
    if _temporary is None or not _temporary.is_dir():
        _temporary = Path(tempfile.mkdtemp(prefix="lowcam-match-"))
    return _temporary


def profile_folder() -> Path:
    """Beside the .blend, or (a file never saved) a temporary folder for this Blender session."""
    return Path(bpy.data.filepath).resolve().parent if bpy.data.filepath else _temporary_folder()


def work_folder() -> Path:
    """``<blend name>-match/`` beside the .blend (or in the temporary folder): the JSON and HTML reports."""
    name = Path(bpy.data.filepath).stem if bpy.data.filepath else "untitled"
    folder = profile_folder() / f"{name}-match"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _glob_of_pattern(pattern: str) -> str:
    """``####`` and ``%04d`` frame numbers as a glob (``[0-9][0-9][0-9][0-9]``)."""
    pattern = re.sub(r"#+", lambda m: "[0-9]" * len(m.group(0)), pattern)
    pattern = re.sub(r"%0(\d+)d", lambda m: "[0-9]" * int(m.group(1)), pattern)
    return pattern.replace("%d", "*")


def plate_footage(scene) -> tuple[str, float]:
    """(footage, frames/s): the scene's plate as ``calibrate plate`` and ``compare --plate-only`` take it: the
    Movie Clip's video file or a glob of its image sequence's files, or the Image Sequence's pattern as a glob."""
    s = scene.lowcam
    fps = scene.render.fps / scene.render.fps_base
    if s.plate_source == "CLIP":
        clip = s.plate_clip
        if clip is None:
            raise LowcamError("the plate is a Movie Clip but no clip is chosen (Lowcam Camera > Plate)")
        path = bpy.path.abspath(clip.filepath, library=clip.library)
        if clip.source == "SEQUENCE":        # its file names number the frames: every file of the sequence
            p = Path(path)
            path = str(p.with_name(re.sub(r"\d+(?=\.[^.]+$)", lambda m: "[0-9]" * len(m.group(0)), p.name)))
        return path, float(clip.fps or fps)
    if s.plate_source == "SEQUENCE":
        return _glob_of_pattern(bpy.path.abspath(s.plate_pattern)), fps
    raise LowcamError("the scene has no plate: choose a Movie Clip or an Image Sequence as the Plate")


def plate_frames(scene) -> tuple[int, int]:
    """(the scene frame that shows the plate's first frame, how many frames the plate has)."""
    s = scene.lowcam
    if s.plate_source == "CLIP" and s.plate_clip is not None:
        return s.plate_clip.frame_start, s.plate_clip.frame_duration
    footage, _ = plate_footage(scene)
    numbers = sorted(int(re.findall(r"\d+", Path(f).stem)[-1]) for f in glob.glob(footage)
                     if re.search(r"\d", Path(f).stem))
    if not numbers:
        raise LowcamError(f"{footage}: no plate frames")
    return numbers[0], len(numbers)


def _measurement_set(scene, needed: str | None = None) -> str | None:
    folder = scene.lowcam_match.measurement_set
    if not folder:
        if needed:
            raise LowcamError(f"{needed} needs a measurement set: choose its folder (Measurement Set)")
        return None
    return bpy.path.abspath(folder).rstrip("/\\") or "/"


def _is_file(ref: str) -> bool:
    return ref.lower().endswith(".toml") or "/" in ref or "\\" in ref


def _tag(ref: str) -> str:
    return Path(ref).stem if _is_file(ref) else ref


def select_profile(scene, ref: str) -> None:
    """Make ``ref`` (a profile name, or a .toml path) the scene's profile: the render handler and the camera nodes
    that follow the scene use it from now on."""
    s = scene.lowcam
    if _is_file(ref):
        s.profile_file = bpy.path.relpath(ref) if bpy.data.filepath else ref
    else:
        s.profile_file = ""
        s.profile = ref


def _chain(scene) -> str:
    """The scene's profile, first version of a new chain unless it is one of the chain's versions."""
    m = scene.lowcam_match
    ref = profile_ref(scene.lowcam)
    if ref not in [v.profile for v in m.versions]:
        m.versions.clear()
        v = m.versions.add()
        v.profile, v.label = ref, _tag(ref)
        m.version_index = 0
    return ref


def next_version(scene) -> Path:
    """The next version's file beside the .blend: ``NAME-vN.toml`` after the chain's first profile ``NAME``, N one
    more than the chain's versions and not a file that exists."""
    m = scene.lowcam_match
    first = m.versions[0].profile if len(m.versions) else profile_ref(scene.lowcam)
    base = re.sub(r"-v\d+$", "", _tag(first))
    folder = profile_folder()
    n = max(len(m.versions), 1) + 1
    while (folder / f"{base}-v{n}.toml").exists():
        n += 1
    return folder / f"{base}-v{n}.toml"


def _version(scene, ref: str):
    return next((v for v in scene.lowcam_match.versions if v.profile == ref), None)


# --- showing results -------------------------------------------------------------------------------------------------

def where_lines(where: dict) -> list[str]:
    """The comparison's ``where`` as short lines: the worst channel, region, band and level of a measurement set,
    or the worst probe of a plate."""
    if "worst" in where:                                   # compare --plate-only
        w = where["worst"]
        return [f"probe {w['probe']} ({w['effect']}) {w['error']:.2f}",
                f"{w['worst_statistic']}: footage {w['footage']:.4g}, model {w['model']:.4g}"]
    out = []
    for key, field, name in (("channels", "channel", "channel"), ("regions", "region", "region"),
                             ("bands", "band", "band"), ("intensities", "range_dn", "level")):
        entries = where.get(key) or []
        if entries:
            e = max(entries, key=lambda e: e["error"])
            shown = f"{e[field][0]:.0f}-{e[field][1]:.0f} DN" if field == "range_dn" else e[field]
            out.append(f"{name} {shown} {e['error']:.2f}")
    return out


def _show_comparison(m, doc: dict) -> None:
    m.error = doc["error"]
    m.verdict = doc["verdict"]
    m.families = ", ".join(f"{k} {v:.3f}" for k, v in doc.get("families", {}).items())
    m.where = "; ".join(where_lines(doc.get("where", {})))


#: The longest side (px) of a panel picture's preview: Blender makes previews of 256 px, too small to read a plot.
PREVIEW_PX = 1200


def _full_size_preview(image) -> None:
    """The image's panel preview (its icon) at the image's own resolution, up to :data:`PREVIEW_PX` on the longer
    side (every other row and column dropped until it fits), so that text in the picture can be read."""
    try:
        preview = image.preview_ensure() or image.preview
        width, height = image.size
        if not (width and height and preview):
            return
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
        step = -(-max(width, height) // PREVIEW_PX)
        pixels = np.ascontiguousarray(pixels.reshape(height, width, 4)[::step, ::step])
        preview.image_size = (pixels.shape[1], pixels.shape[0])
        preview.image_pixels_float.foreach_set(pixels.ravel())
    except (AttributeError, RuntimeError, TypeError, ValueError):
        pass   # a Blender without writable previews keeps its own 256 px one


def _load_image(name: str, path: Path, show: bool = False):
    """``path`` as the Blender image ``name`` (a new image each time, so that its panel preview is new too);
    ``show``: in every Image Editor."""
    if not path.is_file():
        return None
    old = bpy.data.images.get(name)
    if old is not None:
        bpy.data.images.remove(old)
    image = bpy.data.images.load(str(path))
    image.name = name
    _full_size_preview(image)
    if show:
        for window in getattr(bpy.context.window_manager, "windows", ()):
            for area in window.screen.areas:
                if area.type == "IMAGE_EDITOR":
                    area.spaces.active.image = image
    return image


def _show_report(m, report: Path) -> None:
    m.report = str(report / "index.html") if (report / "index.html").is_file() else ""
    maps = next((report / n for n in ("residual_maps.png", "plate_probes.png") if (report / n).is_file()),
                report / "residual_maps.png")      # a plate alone has probes, no residual
    _load_image(RESIDUAL_IMAGE, maps, show=True)
    _load_image(HISTORY_IMAGE, report / "history.png")


def _read_json(path: Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise LowcamError(f"{path}: cannot read the command's JSON ({e})") from None


# --- jobs ------------------------------------------------------------------------------------------------------------

def _scene_of(name: str):
    return bpy.data.scenes.get(name)


def _job(scene, title: str, steps, outputs, on_done) -> jobs.Job:
    """A job whose outcome lands in ``scene``'s Match settings: ``on_done(scene, job)`` after success, the one-line
    error in the panel and Blender's info log after a failure."""
    name = scene.name

    def done(job):
        scene = _scene_of(name)
        if scene is None:
            return
        m = scene.lowcam_match
        m.progress = ""
        try:
            on_done(scene, job)
        except LowcamError as e:
            job.state, job.error = "failed", str(e)
            failed(job)

    def failed(job):
        scene = _scene_of(name)
        if scene is not None:
            scene.lowcam_match.progress = ""
            scene.lowcam_match.job_error = job.error
        print(f"lowcam: {job.title}: {job.error}", file=sys.stderr, flush=True)
        if job.state == "failed" and not getattr(job, "waited", False):   # a waiting operator reports it itself
            try:
                bpy.ops.lowcam.match_report(message=f"{job.title}: {job.error}")
            except RuntimeError:
                pass                            # an error report raises in the caller: it is in the log already

    job = jobs.Job(title, steps, outputs, done, failed)
    m = scene.lowcam_match
    m.job_error, m.summary = "", ""
    jobs.start(job)
    m.progress = job.progress
    return job


def _compare_step(scene, ref: str):
    """(step, outputs, json, report folder) of ``lowcam compare`` for ``ref`` on the set, or the plate alone."""
    work = work_folder()
    out, report = work / f"compare-{_tag(ref)}.json", work / f"compare-{_tag(ref)}"
    mset = _measurement_set(scene)
    if mset:
        args = ["compare", mset]
    else:
        footage, _ = plate_footage(scene)
        args = ["compare", "--plate-only", footage]
    args += ["--profile", ref, "--json", out, "--report", report]
    return ("comparing", args), [out, report], out, report


def _record(scene, ref: str, doc: dict, report: Path) -> None:
    m = scene.lowcam_match
    _show_comparison(m, doc)
    _show_report(m, report)
    v = _version(scene, ref)
    if v is not None:
        v.error, v.verdict, v.report = doc["error"], doc["verdict"], str(report)


def start_compare(scene) -> jobs.Job:
    """``lowcam compare`` of the scene's profile with the measurement set (without one: the plate alone)."""
    ref = _chain(scene)
    step, outputs, out, report = _compare_step(scene, ref)

    def done(scene, job):
        doc = _read_json(out)
        _record(scene, ref, doc, report)
        scene.lowcam_match.summary = next((ln for ln in job.stdout if ": error " in ln), "")

    return _job(scene, "Compare", [step], outputs, done)


def _only(scene) -> list[str]:
    only = scene.lowcam_match.only.replace(" ", "")
    return ["--only", only] if only else []


def start_diagnose(scene) -> jobs.Job:
    """``lowcam diagnose``: the candidates ranked, into the panel's list; its HTML report one click away."""
    mset = _measurement_set(scene, "Diagnose")
    ref = _chain(scene)
    out = work_folder() / f"diagnose-{_tag(ref)}.json"
    report = work_folder() / f"diagnose-{_tag(ref)}-report"

    def done(scene, job):
        doc = _read_json(out)
        m = scene.lowcam_match
        _show_comparison(m, doc)
        _show_report(m, report)
        m.summary = doc.get("summary", "")
        m.candidates.clear()
        for c in doc.get("candidates", []):
            row = m.candidates.add()
            row.effect, row.error_after, row.evidence = c["effect"], c["error_after"], c.get("evidence", "")
            row.held_out = -1.0 if c.get("error_held_out") is None else c["error_held_out"]
            row.flags = "; ".join(c.get("flags", []))
        m.candidate_index = 0
        v = _version(scene, ref)
        if v is not None and v.error < 0:       # compare's error is unrounded: it stays when there is one
            v.error, v.verdict = doc["error"], doc["verdict"]

    args = ["diagnose", mset, "--profile", ref, "--json", out, "--report", report] + _only(scene)
    return _job(scene, "Diagnose", [("diagnosing", args)], [out, report], done)


def _add_version(scene, new: Path, label: str, compare_out: Path, report: Path) -> None:
    m = scene.lowcam_match
    v = m.versions.add()
    v.profile, v.label = str(new), label
    m.version_index = len(m.versions) - 1
    m.candidates.clear()                     # they were ranked for the version before
    select_profile(scene, str(new))
    _record(scene, str(new), _read_json(compare_out), report)


def start_add(scene, index: int = -1) -> jobs.Job:
    """Add the candidate of row ``index`` (-1: the best) as the next profile version: ``lowcam diagnose --only
    EFFECT --add-best -o NAME-vN.toml`` refits it on the scene's profile, then ``lowcam compare`` measures it."""
    mset = _measurement_set(scene, "Add")
    m = scene.lowcam_match
    if not len(m.candidates):
        raise LowcamError("no candidates to add: run Diagnose first")
    effect = m.candidates[0 if index < 0 else index].effect
    ref = _chain(scene)
    new = next_version(scene)
    out = work_folder() / f"add-{new.stem}.json"
    step, outputs, compare_out, report = _compare_step(scene, str(new))

    def done(scene, job):
        _add_version(scene, new, f"+ {effect}", compare_out, report)
        scene.lowcam_match.summary = f"{new.name}: {effect} added"

    args = ["diagnose", mset, "--profile", ref, "--only", effect, "--add-best", "-o", new, "--json", out]
    return _job(scene, f"Add {effect}", [(f"adding {effect}", args), step],
                [new, new.with_suffix(""), out] + outputs, done)


def start_until_explained(scene) -> jobs.Job:
    """``lowcam diagnose --until-explained``: add the best candidate and refit until explained, as one new version
    (each step's profile in ``NAME-vN-steps/``), then compare it."""
    mset = _measurement_set(scene, "Until Explained")
    ref = _chain(scene)
    new = next_version(scene)
    out = work_folder() / f"explain-{new.stem}.json"
    step, outputs, compare_out, report = _compare_step(scene, str(new))

    def done(scene, job):
        added = [s["added"] for s in _read_json(out).get("steps", []) if s.get("added")]
        _add_version(scene, new, "+ " + " + ".join(added) if added else "(nothing added)", compare_out, report)
        scene.lowcam_match.summary = f"{new.name}: " + (f"{', '.join(added)} added" if added else "nothing added")

    args = ["diagnose", mset, "--profile", ref, "--until-explained", "--max-steps", scene.lowcam_match.max_steps,
            "-o", new, "--json", out] + _only(scene)
    steps_dir = new.parent / f"{new.stem}-steps"
    return _job(scene, "Until Explained", [("adding effects until explained", args), step],
                [new, new.with_suffix(""), steps_dir, out] + outputs, done)


def start_estimate(scene) -> jobs.Job:
    """``lowcam calibrate plate`` on the scene's plate, starting from the scene's profile, with a gyro log: the
    motion file when it is a CSV or text log, or, when the motion comes from the scene camera (a camera solved
    from the clip's tracking), that camera's motion over the plate's frames. Writes ``<blend name>-plate.toml``
    beside the .blend and selects it: the first version of a new chain."""
    footage, fps = plate_footage(scene)
    base = profile_ref(scene.lowcam)
    name = Path(bpy.data.filepath).stem if bpy.data.filepath else "untitled"
    new = profile_folder() / f"{name}-plate.toml"
    out = work_folder() / "estimate.json"
    args = ["calibrate", "plate", footage, "--fps", f"{fps:g}", "--profile", base, "-o", new, "--json", out]
    s = scene.lowcam
    if s.motion_source == "FILE" and s.motion_file.lower().endswith((".csv", ".txt")):
        args += ["--gyro", bpy.path.abspath(s.motion_file)]
    elif s.motion_source == "CAMERA" and scene.camera is not None:      # the camera solved from the clip's tracks
        first, frames = plate_frames(scene)
        args += ["--gyro", write_camera_gyro_csv(scene, scene.camera, first, frames, s.exposure_s,
                                                 work_folder() / "camera-gyro.csv")]

    def done(scene, job):
        doc = _read_json(out)
        select_profile(scene, str(new))
        m = scene.lowcam_match
        m.versions.clear()
        v = m.versions.add()
        v.profile, v.label = str(new), "plate estimate"
        m.version_index = 0
        m.candidates.clear()
        m.error, m.verdict, m.where, m.families, m.report = -1.0, "", "", "", ""
        m.summary = "; ".join(c["summary"] for c in doc.get("calibrations", []))

    return _job(scene, "Estimate from Plate", [("estimating from the plate", args)],
                [new, new.with_suffix(""), new.parent / f"{new.stem}-plots", out], done)


def undo_to(scene, index: int) -> None:
    """Go back to version ``index``: it becomes the scene's profile, the later versions leave the list (their
    files stay) and the panel shows its error again."""
    m = scene.lowcam_match
    if not 0 <= index < len(m.versions):
        raise LowcamError(f"no profile version {index + 1} (there are {len(m.versions)})")
    v = m.versions[index]
    ref, error, verdict, report = v.profile, v.error, v.verdict, v.report
    while len(m.versions) > index + 1:
        m.versions.remove(len(m.versions) - 1)
    m.version_index = index
    m.candidates.clear()
    select_profile(scene, ref)
    m.error, m.verdict, m.where, m.families, m.report = error, verdict, "", "", ""
    if report:
        _show_report(m, Path(report))
    m.summary = f"back to {v.label}" + (f": error {error:.3f}" if error >= 0 else "")


# --- operators -------------------------------------------------------------------------------------------------------

class _JobOperator:
    wait: BoolProperty(name="Wait", options={"HIDDEN", "SKIP_SAVE"},
                       description="Wait for the job to end (the default in background mode, where no timer runs)")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and jobs.current() is None

    def start(self, context):
        raise NotImplementedError

    def execute(self, context):
        try:
            job = self.start(context)
        except LowcamError as e:
            context.scene.lowcam_match.job_error = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        wait = self.wait if self.properties.is_property_set("wait") else bpy.app.background
        if wait:
            job.waited = True
            jobs.wait()
            if job.state != "finished":
                self.report({"ERROR"}, f"{job.title}: {job.error}")
                return {"CANCELLED"}
            self.report({"INFO"}, context.scene.lowcam_match.summary or f"{job.title}: done")
        return {"FINISHED"}


class LOWCAM_OT_match_estimate(_JobOperator, bpy.types.Operator):
    """Estimate a profile from the scene's plate (noise, edges, vignetting, gyro motion) and select it"""

    bl_idname = "lowcam.match_estimate"
    bl_label = "Estimate from Plate"

    def start(self, context):
        return start_estimate(context.scene)


class LOWCAM_OT_match_compare(_JobOperator, bpy.types.Operator):
    """Compare the scene's profile with the measurement set (or the plate alone): error, verdict, where it fails"""

    bl_idname = "lowcam.match_compare"
    bl_label = "Compare"

    def start(self, context):
        return start_compare(context.scene)


class LOWCAM_OT_match_diagnose(_JobOperator, bpy.types.Operator):
    """Rank the effects the profile may lack, each fitted to the measurement set and judged on held-out captures"""

    bl_idname = "lowcam.match_diagnose"
    bl_label = "Diagnose"

    def start(self, context):
        return start_diagnose(context.scene)


class LOWCAM_OT_match_add(_JobOperator, bpy.types.Operator):
    """Add this effect, refitted, as a new profile version, and compare it"""

    bl_idname = "lowcam.match_add"
    bl_label = "Add"
    index: IntProperty(name="Row", default=-1, description="The candidate's row (-1: the best)")

    def start(self, context):
        return start_add(context.scene, self.index)


class LOWCAM_OT_match_until_explained(_JobOperator, bpy.types.Operator):
    """Add the best effect and refit, step by step, until the error reaches the noise or nothing helps"""

    bl_idname = "lowcam.match_until_explained"
    bl_label = "Until Explained"

    def start(self, context):
        return start_until_explained(context.scene)


class LOWCAM_OT_match_undo(bpy.types.Operator):
    """Go back to this profile version (later versions leave the list; their files stay)"""

    bl_idname = "lowcam.match_undo"
    bl_label = "Undo to Version"
    bl_options = {"REGISTER", "UNDO"}
    index: IntProperty(name="Version", default=-1, description="The version's row (-1: the selected one)")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and jobs.current() is None

    def execute(self, context):
        m = context.scene.lowcam_match
        try:
            undo_to(context.scene, m.version_index if self.index < 0 else self.index)
        except LowcamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, m.summary)
        return {"FINISHED"}


class LOWCAM_OT_match_cancel(bpy.types.Operator):
    """Stop the running job: its process ends and its partial files are removed"""

    bl_idname = "lowcam.match_cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return jobs.current() is not None

    def execute(self, context):
        job = jobs.cancel()
        if job is not None:
            self.report({"INFO"}, f"{job.title}: cancelled")
        return {"FINISHED"}


class LOWCAM_OT_match_open_report(bpy.types.Operator):
    """Open the last comparison's HTML report"""

    bl_idname = "lowcam.match_open_report"
    bl_label = "Open Report"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and bool(context.scene.lowcam_match.report)

    def execute(self, context):
        bpy.ops.wm.path_open(filepath=context.scene.lowcam_match.report)
        return {"FINISHED"}


class LOWCAM_OT_match_report(bpy.types.Operator):
    """Put a job's one-line error into Blender's info log"""

    bl_idname = "lowcam.match_report"
    bl_label = "Report"
    bl_options = {"INTERNAL"}
    message: StringProperty()

    def execute(self, context):
        self.report({"ERROR"}, self.message)
        return {"FINISHED"}


class LOWCAM_OT_save_profile_as(bpy.types.Operator):
    """Save the scene's profile, with its sharpness and saturation, as a .toml file and select that file"""

    bl_idname = "lowcam.save_profile_as"
    bl_label = "Save Profile As"
    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="*.toml", options={"HIDDEN"})

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = str(profile_folder() / f"{_tag(profile_ref(context.scene.lowcam))}.toml")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        from lowcam.outputs import check_output
        from lowcam.profile import load_profile

        s = context.scene.lowcam
        path = Path(bpy.path.abspath(self.filepath))
        if path.suffix.lower() != ".toml":
            path = path.with_name(path.name + ".toml")
        try:
            check_output(path, [profile_ref(s)] if _is_file(profile_ref(s)) else [], "Save Profile As")
            saved = load_profile(profile_ref(s)).with_controls(s.sharpness, s.saturation).save(path)
        except (LowcamError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        select_profile(context.scene, str(saved))
        self.report({"INFO"}, f"{saved}: profile saved and selected")
        return {"FINISHED"}


classes = (LowcamCandidate, LowcamVersion, LowcamMatch, LOWCAM_OT_match_estimate, LOWCAM_OT_match_compare,
           LOWCAM_OT_match_diagnose, LOWCAM_OT_match_add, LOWCAM_OT_match_until_explained, LOWCAM_OT_match_undo,
           LOWCAM_OT_match_cancel, LOWCAM_OT_match_open_report, LOWCAM_OT_match_report, LOWCAM_OT_save_profile_as)


def register():
    bpy.types.Scene.lowcam_match = bpy.props.PointerProperty(type=LowcamMatch)
    jobs.register()


def unregister():
    jobs.unregister()
    del bpy.types.Scene.lowcam_match
