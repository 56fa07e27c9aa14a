"""Cheap valid invocations of every ``lowcam`` command, for the generative fuzz suite (``test_fuzz_generative.py``).

A :class:`Baseline` is one command run with small valid inputs: the fuzz suite swaps one argument for a bad or
borderline value and keeps the rest, so that whatever is refused is that value. The inputs are made once per
session into a template folder (:class:`Workspace`, each input on first use) and copied into every example's own
folder (``in/``), so that a run that destroys an input destroys a copy, never the next example's input. The
profile is ``fuzzcam``, the Fire-i at 160x120 (runs four times faster), found on ``LOWCAM_PROFILE_PATH``
(``in/profiles``, beside ``fuzzcam640``, the Fire-i itself, for calibrations): an output aimed at "the profile given
by name" hits the copy, never the repository's ``profiles/``.

Contents
--------
- :class:`Baseline`: one command's valid arguments (by argparse ``dest``), the inputs it needs and what it costs
- :class:`Workspace`: the session's template inputs, made on first use by :data:`INPUTS`
- :data:`INPUTS`: input name -> the function that makes it in the template folder
- :data:`BASELINES`: command path -> its :class:`Baseline`
- :func:`baseline_for`: the baseline of a command with the companions one option needs (``--gyro`` needs ``--fps``)
- :func:`needs_bpy`: why Blender-side runs cannot happen here ("" when they can)
"""
from __future__ import annotations

import dataclasses
import functools
import importlib.util
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import fuzz_corpus as corpus

ROOT = corpus.ROOT

#: A baseline value: text with ``{in}`` (the example's copy of the inputs) and ``{out}`` (where outputs go).
Tokens = "list[str] | bool"


@dataclass(frozen=True)
class Baseline:
    """One command with valid arguments. ``args``: argparse ``dest`` -> its values (a list of text, one item for a
    single value, several for ``nargs`` or a repeated option; ``True`` for a flag); ``inputs``: the
    :data:`INPUTS` it needs; ``cost_s``: about how long a whole run takes here (the fast tier runs no accepted
    value of a command costing more than a few seconds); ``bpy``: a Blender-side run (a process, the Blender
    tier); ``partial_rc``: the exit status of a run whose every item failed alone (``batch``: 1);
    ``may_change``: Lowcam's own state inside an input (relative to the example) that a successful run rewrites;
    ``companions``: dest -> the arguments that option needs (``None`` removes one); ``caps``: dest -> the
    largest value a run may take here (larger valid values are only parsed: 1024 Dask workers on 2 cores);
    ``option_costs``: dest -> about how long a run takes with that option (``diagnose --only`` runs every
    candidate), where it differs from ``cost_s``."""

    args: dict
    inputs: tuple[str, ...] = ()
    cost_s: float = 0.5
    bpy: bool = False
    partial_rc: int | None = None
    may_change: tuple[str, ...] = ()
    companions: dict = field(default_factory=dict)
    caps: dict = field(default_factory=dict)
    option_costs: dict = field(default_factory=dict)

    def cost(self, dest: str) -> float:
        """About how long (s) a whole run takes here when option ``dest`` is given."""
        return self.option_costs.get(dest, self.cost_s)


# --- the inputs ----------------------------------------------------------------------------------------------------

def _save_rgb(frames, folder: Path, stem: str = "f") -> None:
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{stem}{i:02d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))


def _quiet(*off):
    """The Fire-i in calibration mode (RGB out, saturation at identity) without ``off``."""
    from lowcam.profile import load_profile

    p = load_profile("fire-i").without("chroma_subsampling", *off)
    p.effect("saturation").saturation = 65.0
    return p


def _profiles(path: Path) -> None:
    """``fuzzcam`` (the Fire-i at 160x120) and ``fuzzcam640`` (the Fire-i), textures beside them (relative paths,
    inside the copy)."""
    path.mkdir(parents=True)
    shutil.copytree(ROOT / "profiles" / "fire-i", path / "fire-i")
    text = (ROOT / "profiles" / "fire-i.toml").read_text()
    (path / "fuzzcam640.toml").write_text(text)
    small = text.replace("\nwidth = 640\n", "\nwidth = 160\n").replace("\nheight = 480\n", "\nheight = 120\n")
    assert small.count("= 160") == 1 and small.count("= 120") == 1
    (path / "fuzzcam.toml").write_text(small)


@functools.lru_cache(maxsize=1)
def fuzzcam():
    """The ``fuzzcam`` profile (the Fire-i at 160x120)."""
    from lowcam.profile import load_profile

    with tempfile.TemporaryDirectory(prefix="fuzzcam-") as folder:
        _profiles(Path(folder) / "profiles")
        return load_profile(Path(folder) / "profiles" / "fuzzcam.toml")


def _render(path: Path) -> None:
    from lowcam.outputs import write_exr
    from lowcam.sample import sample_render

    write_exr(path, sample_render(fuzzcam(), 160))


def _plate(path: Path) -> None:
    from lowcam.outputs import write_png
    from lowcam.sample import sample_plate

    write_png(path, sample_plate(fuzzcam()))


def _renders(path: Path) -> None:
    path.mkdir(parents=True)
    _render(path / "0001.exr")


def _plates(path: Path) -> None:
    path.mkdir(parents=True)
    _plate(path / "0001.png")


def _set(path: Path) -> None:
    """A one-capture, one-frame measurement set of the sample render through ``fuzzcam``, with its plate."""
    import cv2

    from lowcam.io import read_render
    from lowcam.measure.sets import write_set
    from lowcam.pipeline import simulate

    _render(path.parent / ".set-render.exr")
    _plate(path.parent / ".set-plate.png")
    render = read_render(path.parent / ".set-render.exr")
    plate = cv2.cvtColor(cv2.imread(str(path.parent / ".set-plate.png")), cv2.COLOR_BGR2RGB)
    write_set(path, [{"name": "a", "ideal": render, "frames": [simulate(render, fuzzcam(), plate, seed=1)],
                      "plate": plate}])


def _motion(path: Path) -> None:
    path.write_text('{"format": "lowcam-motion", "version": 1, "frames": [{"frame": 1, "angular_velocity": '
                    '[0, 0.1, 0]}]}')


def _gyro(path: Path) -> None:
    path.write_text("t,wx,wy,wz\n" + "".join(f"{k * 0.01:.2f},0,0.1,0\n" for k in range(40)))


def _footage(path: Path) -> None:
    """Three 160x120 frames of a noisy ramp: a plate the plate probes and ``calibrate plate`` take."""
    import cv2

    path.mkdir(parents=True)
    rng = np.random.default_rng(7)
    ramp = np.linspace(30, 200, 160)[None, :, None] * np.ones((120, 1, 3))
    for i in range(3):
        cv2.imwrite(str(path / f"{i:03d}.png"), np.clip(np.round(ramp + rng.normal(0, 2, ramp.shape)), 0, 255)
                    .astype(np.uint8))


def _gyroflow(path: Path) -> None:
    """A Gyroflow lens profile of a 4:3 fisheye (fire-i's aspect ratio), with a read-out time and a frame rate."""
    import json

    path.write_text(json.dumps({
        "calib_dimension": {"w": 1920, "h": 1440}, "frame_readout_time": 15.0, "fps": 60.0,
        "fisheye_params": {"camera_matrix": [[850.0, 0.0, 959.5], [0.0, 850.0, 719.5], [0.0, 0.0, 1.0]],
                           "distortion_coeffs": [0.048, 0.014, 0.015, -0.017]}}))


def _gyroflow_profiles(path: Path) -> None:
    """A folder of Gyroflow lens profiles (one, :func:`_gyroflow`'s), as a copy of Gyroflow's database."""
    path.mkdir(parents=True)
    _gyroflow(path / "GoPro_HERO_fisheye.json")


def _dng(path: Path) -> None:
    """A 32x24 raw DNG (PiDNG): RGGB, levels 64..1023, a D65 colour matrix, an as-shot neutral, a noise profile."""
    from pidng.core import RAW2DNG
    from pidng.defs import CalibrationIlluminant, CFAPattern, PhotometricInterpretation
    from pidng.dng import DNGTags, Tag

    matrix = [[v, 10000] for v in (5603, -1351, -600, -2872, 11180, 2132, 600, 453, 5821)]
    tags = DNGTags()
    for tag, value in {Tag.ImageWidth: 32, Tag.ImageLength: 24, Tag.TileWidth: 32, Tag.TileLength: 24,
                       Tag.SamplesPerPixel: 1, Tag.BitsPerSample: 16, Tag.CFARepeatPatternDim: [2, 2],
                       Tag.PhotometricInterpretation: PhotometricInterpretation.Color_Filter_Array,
                       Tag.CFAPattern: CFAPattern.RGGB, Tag.BlackLevel: 64, Tag.WhiteLevel: 1023, Tag.Make: "Fuzz",
                       Tag.Model: "Cam", Tag.ColorMatrix1: matrix,
                       Tag.CalibrationIlluminant1: CalibrationIlluminant.D65,
                       Tag.AsShotNeutral: [[1, 2], [1, 1], [5, 8]],
                       Tag.NoiseProfile: [2e-4, 3e-6, 1e-4, 2e-6, 3e-4, 4e-6]}.items():
        tags.set(tag, value)
    r = RAW2DNG()
    r.options(tags, path="", compress=False)
    r.convert(np.full((24, 32), 164, np.uint16), filename=str(path.with_suffix("")))


def _patches(path: Path) -> None:
    rng = np.random.default_rng(5)
    ideal = rng.uniform(0.1, 0.8, (12, 3))
    mixing = np.array([[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]])
    measured = np.clip(ideal @ mixing.T * 255, 0, 255)
    rows = ["ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b"]
    rows += [",".join(f"{v:g}" for v in (*i, *m)) for i, m in zip(ideal, measured)]
    path.write_text("\n".join(rows) + "\n")


def _lens(path: Path) -> None:
    """Four views of a crisp 9x6 checkerboard, warped in perspective (OpenCV finds them; FOV fits)."""
    import cv2

    from test_calibration_refusals import chessboard

    page = chessboard()
    h, w = page.shape[:2]
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    frames = []
    for dx, dy, tilt in ((0, 0, 0.0), (40, 20, 0.08), (-30, 10, -0.06), (10, -25, 0.05)):
        dst = np.float32([[60 + dx + tilt * 400, 50 + dy], [580 + dx, 60 + dy - tilt * 300],
                          [570 + dx - tilt * 200, 420 + dy], [70 + dx, 430 + dy + tilt * 300]])
        m = cv2.getPerspectiveTransform(src, dst)
        frames.append(cv2.warpPerspective(page, m, (640, 480), borderValue=(255, 255, 255)))
    _save_rgb(frames, path)


def _flat(path: Path) -> None:
    """Two 320x240 flat fields falling off by 30 % to the corners, with noise."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:240, 0:320]
    r2 = ((xx - 160) ** 2 + (yy - 120) ** 2) / (160 ** 2 + 120 ** 2)
    _save_rgb([np.clip(180 * (1 - 0.3 * r2)[..., None] + rng.normal(0, 2, (240, 320, 3)), 0, 255).astype(np.uint8)
               for _ in range(2)], path)


def _ca(path: Path) -> None:
    from test_calibration_refusals import textured

    _save_rgb([textured()], path)


def _static(path: Path) -> None:
    """Ten 320x240 frames of a static grey ramp with signal-dependent noise (noise and demosaicing)."""
    rng = np.random.default_rng(4)
    ramp = np.linspace(20, 235, 320)[None, :, None] * np.ones((240, 1, 3))
    _save_rgb([np.clip(np.round(ramp + rng.normal(0, 1, ramp.shape) * np.sqrt(1 + ramp / 20)), 0, 255)
               .astype(np.uint8) for _ in range(10)], path)


def _blur(path: Path) -> None:
    from helpers import slanted_squares
    from lowcam.pipeline import simulate

    p = _quiet("noise", "quantisation", "vignetting", "chromatic_aberration", "lens_distortion")
    _save_rgb([simulate(slanted_squares(800, 600), p)], path)


def _sharpening(path: Path) -> None:
    from helpers import noise_field
    from lowcam.pipeline import simulate

    soft = _quiet("noise", "quantisation", "vignetting", "chromatic_aberration", "motion_blur")
    soft.effect("sharpening").sharpness = 0.0
    sharp = soft.copy()
    sharp.effect("sharpening").sharpness = 80.0
    scene = noise_field(width=800, height=600, cells=(300, 225), crisp=True)
    _save_rgb([simulate(scene, soft)], path / "soft")
    _save_rgb([simulate(scene, sharp)], path / "sharp")


def _manifest(path: Path) -> None:
    _flat(path / "flat")
    (path / "manifest.toml").write_text('profile = "fire-i"\n[vignetting]\nframes = ["flat/*.png"]\n')


def _chart(path: Path) -> None:
    """The printable chart at 100 dpi and its layout: the page itself is a frame of the chart, seen square-on."""
    from lowcam.chart import write_chart

    path.mkdir(parents=True)
    write_chart(path / "chart.png", dpi=100)


def _phone_footage(path: Path) -> None:
    """The phone-gyro-video data set (``../shared/data``) copied, for ``demo --footage``; an empty folder when it is
    not there (``demo --footage`` then refuses it)."""
    src = ROOT.parent / "shared" / "data" / "phone-gyro-video"
    if src.is_dir():
        shutil.copytree(src, path)
    else:
        path.mkdir()


def _blend(path: Path) -> None:
    """A small scene (Blender's default cube and camera, 64x48, 1 sample), saved by bpy in a process."""
    code = ("import bpy, sys; s = bpy.context.scene; s.render.resolution_x, s.render.resolution_y = 64, 48; "
            "s.render.resolution_percentage = 100; s.frame_start, s.frame_end = 1, 2; "
            "s.render.engine = 'CYCLES'; s.cycles.samples = 1; s.cycles.device = 'CPU'; "
            "bpy.ops.wm.save_as_mainfile(filepath=sys.argv[-1])")
    r = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300)
    if r.returncode or not path.is_file():
        raise RuntimeError(f"could not make the fuzz .blend: {r.stderr[-2000:]}")


#: input name -> the function that makes it at a path in the template folder
INPUTS = {
    "profiles": _profiles,
    "render.exr": _render,
    "plate.png": _plate,
    "renders": _renders,
    "plates": _plates,
    "motion.json": _motion,
    "gyro.csv": _gyro,
    "set": _set,
    "footage": _footage,
    "cam.dng": _dng,
    "gyroflow.json": _gyroflow,
    "gyroflow-profiles": _gyroflow_profiles,
    "patches.csv": _patches,
    "lens": _lens,
    "flat": _flat,
    "ca": _ca,
    "static": _static,
    "blur": _blur,
    "sharpening": _sharpening,
    "manifest": _manifest,
    "chart": _chart,
    "phone-footage": _phone_footage,
    "scene.blend": _blend,
}


class Workspace:
    """The session's template inputs under ``root``: :meth:`need` makes each on first use; :meth:`copy_into`
    copies a baseline's inputs into an example's ``in/`` folder."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def need(self, name: str) -> Path:
        path = self.root / name
        if not path.exists():
            INPUTS[name](path)
        return path

    def copy_into(self, names, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        for name in ("profiles", *names):
            src = self.need(name)
            if src.is_dir():
                shutil.copytree(src, folder / name)
            else:
                shutil.copyfile(src, folder / name)


def needs_bpy() -> str:
    """Why a Blender-side run cannot happen here ("" when bpy is importable)."""
    return "" if importlib.util.find_spec("bpy") else "bpy is not installed"


# --- the baselines -------------------------------------------------------------------------------------------------

P = "fuzzcam"


def _calibrate(frames: list[str], inputs: tuple[str, ...], cost_s: float, option_costs=None, **args) -> Baseline:
    return Baseline({"frames": frames, "output": ["{out}/cam.toml"], **args}, inputs, cost_s,
                    option_costs=option_costs or {})


_FLAT = ["{in}/flat/f00.png", "{in}/flat/f01.png"]

#: command path -> its baseline
BASELINES: dict[tuple[str, ...], Baseline] = {
    ("apply",): Baseline(
        {"profile": [P], "render": ["{in}/render.exr"], "output": ["{out}/frame.png"]}, ("render.exr", "plate.png"),
        0.3, companions={"plate": {"plate": ["{in}/plate.png"]}}),
    ("stages",): Baseline(
        {"profile": [P], "render": ["{in}/render.exr"], "output": ["{out}/stages"]}, ("render.exr", "plate.png"), 0.6,
        companions={"plate": {"plate": ["{in}/plate.png"]}}),
    ("batch",): Baseline(
        {"profile": [P], "renders": ["{in}/renders/####.exr"], "frames": ["1"], "output": ["{out}/####.png"],
         "quiet": True}, ("renders", "plates", "motion.json", "gyro.csv"), 0.3, partial_rc=1,
        companions={"plates": {"plates": ["{in}/plates/####.png"]},
                    "gyro": {"gyro": ["{in}/gyro.csv"], "fps": ["24"], "exposure_s": ["0.02"]},
                    "fps": {"gyro": ["{in}/gyro.csv"], "exposure_s": ["0.02"]},
                    "exposure_s": {"gyro": ["{in}/gyro.csv"], "fps": ["24"]},
                    "gyro_t0": {"gyro": ["{in}/gyro.csv"], "fps": ["24"], "exposure_s": ["0.02"]},
                    "gyro_first_frame": {"gyro": ["{in}/gyro.csv"], "fps": ["24"], "exposure_s": ["0.02"]},
                    "motion": {"motion": ["{in}/motion.json"]}},
        caps={"workers": 0}),
    ("chart",): Baseline({"output": ["{out}/chart.png"], "dpi": ["72"]}, (), 0.2, caps={"dpi": 150}),
    ("calibrate", "lens"): _calibrate(["{in}/lens/f00.png", "{in}/lens/f01.png", "{in}/lens/f02.png",
                                       "{in}/lens/f03.png"], ("lens",), 2.0, {"model": 15.0}, model=["fov"]),
    ("calibrate", "vignetting"): _calibrate(_FLAT, ("flat",), 1.2),
    ("calibrate", "chromatic_aberration"): _calibrate(["{in}/ca/f00.png"], ("ca",), 4.0),
    ("calibrate", "noise"): _calibrate(["{in}/static/f*.png"], ("static",), 1.5),
    ("calibrate", "demosaic"): _calibrate(["{in}/static/f*.png"], ("static",), 14.0),
    ("calibrate", "blur"): _calibrate(["{in}/blur/f00.png"], ("blur",), 0.6),
    ("calibrate", "sharpening"): Baseline(
        {"soft": ["{in}/sharpening/soft/f00.png"], "sharp": ["{in}/sharpening/sharp/f00.png"], "sharpness": ["80"],
         "output": ["{out}/cam.toml"]}, ("sharpening",), 2.0),
    ("calibrate", "colour"): Baseline(
        {"frames": [], "patches": ["{in}/patches.csv"], "output": ["{out}/cam.toml"]}, ("patches.csv", "chart"), 0.4,
        companions={dest: {"patches": None, "frames": ["{in}/chart/chart.png"], "chart": ["{in}/chart/chart.json"]}
                    for dest in ("frames", "chart")}),
    ("calibrate", "plate"): Baseline(
        {"footage": ["{in}/footage"], "output": ["{out}/cam.toml"]}, ("footage", "gyro.csv"), 6.0,
        companions={"gyro": {"gyro": ["{in}/gyro.csv"], "fps": ["30"]}}),
    ("calibrate", "all"): Baseline(
        {"manifest": ["{in}/manifest/manifest.toml"], "output": ["{out}/cam.toml"]}, ("manifest",), 1.2),
    ("calibrate", "list"): Baseline({}, (), 0.1),
    ("compare",): Baseline(
        {"set": ["{in}/set"], "profile": [P], "json": ["{out}/compare.json"]}, ("set", "footage"), 0.4,
        may_change=("in/set/.lowcam/history.json",), option_costs={"plate_only": 4.0, "probes": 4.0},
        companions={dest: {"set": None, "plate_only": ["{in}/footage"]} for dest in ("plate_only", "probes")}),
    ("diagnose",): Baseline(
        {"set": ["{in}/set"], "profile": [P], "json": ["{out}/diagnose.json"], "only": ["vignetting"]}, ("set",),
        0.6, may_change=("in/set/.lowcam/history.json",),
        companions={"output": {"add_best": True}, "add_best": {"output": ["{out}/best.toml"]},
                    "until_explained": {"output": ["{out}/explained.toml"], "max_steps": ["1"]},
                    "max_steps": {"until_explained": True, "output": ["{out}/explained.toml"]}},
        caps={"max_steps": 1}, option_costs={"only": 20.0, "until_explained": 25.0, "max_steps": 25.0,
                                             "add_best": 1.5, "output": 1.5}),
    ("synth",): Baseline({"profile": [P], "frames": ["1"], "width": ["64"], "output": ["{out}/set"]}, (), 1.5,
                         caps={"frames": 2, "width": 128}),
    ("profiles",): Baseline({}, (), 0.1, companions={"name": {"name": [P]}}),
    ("profile", "from-lensfun"): Baseline(
        {"maker": ["Canon"], "model": ["PowerShot G12"], "focal_mm": ["6.1"], "base": [P],
         "output": ["{out}/lens.toml"]}, (), 0.5,
        companions={"camera_maker": {"camera_model": ["PowerShot G12"]},
                    "camera_model": {"camera_maker": ["Canon"]}}),
    ("profile", "search"): Baseline({"text": ["G12"]}, ("gyroflow-profiles",), 0.2,
                                    companions={"gyroflow": {"gyroflow": ["{in}/gyroflow-profiles"]}}),
    ("profile", "from-gyroflow"): Baseline(
        {"lens_profile": ["{in}/gyroflow.json"], "base": [P], "output": ["{out}/gyroflow.toml"]}, ("gyroflow.json",),
        0.2),
    ("profile", "from-dng"): Baseline(
        {"dng": ["{in}/cam.dng"], "base": [P], "output": ["{out}/dng.toml"]}, ("cam.dng",), 0.2),
    ("demo",): Baseline(
        {"profile": [P], "synthetic": True, "render_width": ["64"], "output": ["{out}/demo"]}, (), 1.2,
        companions={"footage": {"synthetic": None, "footage_frames": ["2"], "footage": ["{in}/phone-footage"]},
                    "footage_frames": {"synthetic": None, "footage": ["{in}/phone-footage"]}},
        caps={"render_width": 256, "footage_frames": 2}, option_costs={"footage": 150.0, "footage_frames": 150.0}),
    ("render",): Baseline(
        {"blend": ["{in}/scene.blend"], "frames": ["1"], "output": ["{out}/####.png"]}, ("scene.blend",), 6.0,
        bpy=True),
    # the gyro form runs without Blender; the .blend form is Blender-side (_BPY_OPTIONS)
    ("motion",): Baseline(
        {"gyro": ["{in}/gyro.csv"], "fps": ["24"], "exposure_s": ["0.02"], "frames": ["1"],
         "output": ["{out}/motion.json"]}, ("gyro.csv",), 0.2,
        companions={"blend": {"gyro": None, "fps": None, "exposure_s": None, "blend": ["{in}/scene.blend"]}},
        option_costs={"blend": 3.5}),
    ("node-asset",): Baseline({"output": ["{out}/asset.blend"], "render_width": ["64"], "profile": [P]}, (), 10.0,
                              bpy=True, caps={"render_width": 256}),
}

# demo --footage and --footage-frames run Blender (addon.footage imports bpy), and so does motion's .blend
_BPY_OPTIONS = {("demo",): ("footage", "footage_frames"), ("motion",): ("blend",)}


def baseline_for(command: tuple[str, ...], dest: str) -> Baseline | None:
    """The baseline of ``command`` with the companions option ``dest`` needs applied (and Blender-side when that
    option makes the command run Blender); None if the command has none."""
    base = BASELINES.get(command)
    if base is None:
        return None
    args = dict(base.args)
    if dest == "profile" and dest not in args:  # calibrate's --profile/--base: the Fire-i's copy
        args[dest] = ["fuzzcam640"]
    for key, value in base.companions.get(dest, {}).items():
        if value is None:
            args.pop(key, None)
        else:
            args[key] = value
    named = [v.split("/")[1] for vs in args.values() if isinstance(vs, list) for v in vs if v.startswith("{in}/")]
    return dataclasses.replace(base, args=args, inputs=tuple(dict.fromkeys(base.inputs + tuple(named))),
                               bpy=base.bpy or dest in _BPY_OPTIONS.get(command, ()))
