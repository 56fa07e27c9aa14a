"""Every ``lowcam`` option declares what it is (:mod:`lowcam.arguments`): the files a command reads and writes,
the range of every number. The one error boundary in ``lowcam.cli.main`` refuses an output that is an input, and
parsing refuses numbers out of their range, each as one line naming the option or file, exit 2."""
import argparse
import json
import math

import pytest

from lowcam import arguments
from lowcam.arguments import Number, Numbers, Reads, Text, Writes, declared, undeclared


def test_number_refuses_nan_infinities_and_out_of_range_naming_the_range():
    fps = Number(0, 1000, low_open=True)
    assert fps("29.97") == pytest.approx(29.97) and fps(1000) == 1000.0
    for bad in ("0", "-30", "nan", "inf", "-inf", "1000.5", "fast", ""):
        with pytest.raises(argparse.ArgumentTypeError) as e:
            fps(bad)
        assert "(0, 1000]" in str(e.value) or "expected" in str(e.value), bad
    confidence = Number(0, 1)
    assert confidence("0") == 0.0 and confidence("1") == 1.0
    with pytest.raises(argparse.ArgumentTypeError, match=r"\[0, 1\]"):
        confidence("-1")
    count = Number(1, 20, integer=True)
    assert count("20") == 20 and isinstance(count("3"), int)
    for bad in ("0", "21", "2.5", "nan", True):
        with pytest.raises(argparse.ArgumentTypeError):
            count(bad)


def test_numbers_check_each_component():
    assert arguments.angular_velocity("0.1,-2,3") == (0.1, -2.0, 3.0)
    for bad in ("1,2", "1,2,3,4", "1,nan,2", "1,inf,2", "1,2,1e9", "a,b,c"):
        with pytest.raises(argparse.ArgumentTypeError):
            arguments.angular_velocity(bad)
    assert arguments.defocus("2,1.5") == (2.0, 1.5)
    for bad in ("0,1", "2,-1", "nan,1", "2,1e9"):
        with pytest.raises(argparse.ArgumentTypeError):
            arguments.defocus(bad)


def test_the_seed_and_frame_ranges_are_the_noise_models():
    from lowcam.effects.noise import FRAME_RANGE, SEED_RANGE
    from lowcam.motion import MAX_RATE

    assert (arguments.seed.low, arguments.seed.high + 1) == SEED_RANGE
    assert (arguments.frame_number.low, arguments.frame_number.high + 1) == FRAME_RANGE
    assert all(n.low == -MAX_RATE and n.high == MAX_RATE for n in arguments.angular_velocity.items)
    assert arguments.seed(str(2 ** 64 - 1)) == 2 ** 64 - 1
    with pytest.raises(argparse.ArgumentTypeError):
        arguments.seed(str(2 ** 64))


def test_reads_writes_and_text_declare_and_return_the_text():
    r, w = Reads("profile"), Writes("file", (".toml",))
    assert (r.role, r.kind, r("fire-i")) == ("reads", "profile", "fire-i")
    assert (w.role, w.kind, w.suffixes, w("a.toml")) == ("writes", "file", (".toml",), "a.toml")
    for t in (r, w):
        with pytest.raises(argparse.ArgumentTypeError):
            t("")
    with pytest.raises(ValueError):
        Reads("anything")
    t = Text(("a", "b"))
    assert t.role == "text" and t("a") == "a"
    with pytest.raises(argparse.ArgumentTypeError, match="not one of"):
        t("c")
    assert math.isfinite(Number(0, 1)("0.5"))


def test_declared_walks_sub_commands_of_sub_commands():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("top")
    p.add_argument("-o", type=Writes("file"))
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--size", choices=("a4", "a3"))
    inner = p.add_subparsers(dest="what").add_parser("inner", aliases=["in"])
    inner.add_argument("--fps", type=Number(0, 1000, low_open=True))
    inner.add_argument("--free")
    found = {(path, a.dest): d for path, a, d in declared(parser)}
    assert found[(("top",), "o")].role == "writes"
    assert found[(("top",), "quiet")] is None
    assert found[(("top",), "size")].choices == ("a4", "a3")
    assert found[(("top", "inner"), "fps")].high == 1000
    assert ("top", "in") not in {path for path, _ in found}  # an alias once
    assert undeclared(parser) == ["top inner --free"]


# --- every option of every command declares itself ------------------------------------------------------------------

def test_every_option_that_takes_a_value_declares_what_it_is():
    """Blender-side commands (addon/commands.py, through the entry point) and calibrate's sub-commands included."""
    from lowcam.cli import build_parser

    parser = build_parser()
    assert undeclared(parser) == []
    paths = {path for path, _, _ in declared(parser)}
    for command in (("demo",), ("render",), ("motion",), ("node-asset",), ("calibrate", "plate"),
                    ("calibrate", "all"), ("profile", "from-dng"), ("compare",)):
        assert command in paths, command
    by = {(path, a.option_strings[0] if a.option_strings else a.dest): d for path, a, d in declared(parser)}
    # every command that writes declares it, and the reads that matter are declared by kind
    assert by[(("compare",), "--json")].role == "writes"
    assert by[(("compare",), "set")].kind == "set" and by[(("compare",), "--plate-only")].kind == "footage"
    assert by[(("diagnose",), "--profile")].kind == "profile"
    assert by[(("render",), "blend")].kind == "file" and by[(("render",), "-o")].kind == "pattern"
    assert by[(("calibrate", "plate"), "footage")].kind == "files"
    assert by[(("calibrate", "all"), "manifest")].kind == "manifest"
    # physical ranges
    assert by[(("calibrate", "plate"), "--fps")].range == "(0, 1000]"
    assert by[(("calibrate", "plate"), "--min-confidence")].range == "[0, 1]"
    assert by[(("profile", "from-lensfun"), "--aperture")].range == "[0.5, 64]"
    assert by[(("profile", "from-lensfun"), "--distance-m")].low > 0


def test_every_numeric_option_is_bounded_and_every_command_that_writes_declares_it():
    from lowcam.cli import build_parser

    writes = set()
    for path, action, decl in declared(build_parser()):
        if decl is None:
            continue
        if decl.role == "number":
            assert decl.low is not None and decl.high is not None, (path, action.dest)
        if decl.role == "writes":
            writes.add(path)
    for command in (("apply",), ("stages",), ("batch",), ("chart",), ("compare",), ("diagnose",), ("synth",),
                    ("profile", "from-dng"), ("profile", "from-lensfun"), ("calibrate", "lens"), ("demo",),
                    ("render",), ("motion",), ("node-asset",)):
        assert command in writes, command


def test_the_image_suffixes_the_cli_declares_are_the_ones_lowcam_writes():
    from lowcam.cli import IMAGE_SUFFIXES
    from lowcam.outputs import IMAGE_SUFFIXES as WRITTEN

    assert tuple(IMAGE_SUFFIXES) == tuple(WRITTEN)


# --- the error boundary: no output is an input ----------------------------------------------------------------------

import os  # noqa: E402
import shutil  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from lowcam.cli import main  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def refused(capsys, argv, names=(), unchanged=()):
    """Run ``lowcam argv``: exit 2, one line on stderr naming each of ``names``, no traceback, and each file of
    ``unchanged`` byte for byte as it was. Returns the line."""
    before = {Path(p): Path(p).read_bytes() for p in unchanged}
    capsys.readouterr()
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for name in names:
        assert str(name) in lines[0], (name, lines[0])
    for path, data in before.items():
        assert path.read_bytes() == data, f"{path} changed"
    return lines[0]


def frames(folder: Path, n: int = 4, size=(640, 480)) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        out.append(folder / f"f{i + 1:03d}.png")
        cv2.imwrite(str(out[-1]), rng.integers(0, 255, (size[1], size[0], 3), np.uint8))
    return out


@pytest.fixture
def mycam(tmp_path, monkeypatch):
    """A profile ``mycam`` on the search path (a copy of fire-i), found by name."""
    folder = tmp_path / "profiles"
    folder.mkdir()
    path = folder / "mycam.toml"
    shutil.copy(ROOT / "profiles" / "fire-i.toml", path)
    monkeypatch.setenv("LOWCAM_PROFILE_PATH", str(folder))
    return path


def test_plate_only_json_onto_a_footage_frame(tmp_path, capsys):
    f = frames(tmp_path / "footage")
    refused(capsys, ["compare", "--plate-only", tmp_path / "footage", "--json", f[0]], ("--json", f[0]), f)
    refused(capsys, ["compare", "--plate-only", tmp_path / "footage" / "f*.png", "--json", f[2]], ("--json",), f)


def test_links_to_an_input_are_the_input(tmp_path, capsys):
    f = frames(tmp_path / "footage")
    (tmp_path / "soft.json").symlink_to(f[1])
    os.link(f[2], tmp_path / "hard.json")
    for link, frame in (("soft.json", f[1]), ("hard.json", f[2])):
        refused(capsys, ["compare", "--plate-only", tmp_path / "footage", "--json", tmp_path / link],
                ("--json", frame), f)


def test_a_path_through_a_folder_still_to_be_made_is_the_file_it_reaches(tmp_path, capsys):
    """``new/../f.png``: the folder is made before the file is written, which then replaces the input."""
    f = frames(tmp_path / "footage")
    through = tmp_path / "footage" / "new" / ".." / f[1].name
    refused(capsys, ["compare", "--plate-only", tmp_path / "footage", "--json", through], ("--json", "this input"), f)
    refused(capsys, ["calibrate", "plate", tmp_path / "footage", "-o", tmp_path / "p.toml", "--json", through],
            ("--json", "this input"), f)


def outside_set(tmp_path) -> tuple[Path, list[Path], Path]:
    """A set whose set.toml names frames and an ideal outside its folder."""
    f = frames(tmp_path / "outside")
    ideal = tmp_path / "outside" / "ideal.exr"
    ideal.write_bytes(b"an ideal render")
    (tmp_path / "set").mkdir()
    (tmp_path / "set" / "set.toml").write_text('[[capture]]\nname = "a"\nframes = "../outside/f*.png"\n'
                                               'ideal = "../outside/ideal.exr"\n')
    return tmp_path / "set", f, ideal


def test_compare_and_diagnose_json_onto_what_set_toml_names_outside_the_set(tmp_path, capsys):
    mset, f, ideal = outside_set(tmp_path)
    kept = f + [ideal, mset / "set.toml"]
    refused(capsys, ["compare", mset, "--json", f[0]], ("--json", f[0]), kept)
    refused(capsys, ["compare", mset, "--json", ideal], ("--json", ideal), kept)
    refused(capsys, ["diagnose", mset, "--json", ideal], ("--json", ideal), kept)
    refused(capsys, ["diagnose", mset, "--json", mset / "set.toml"], ("--json", "set.toml"), kept)
    refused(capsys, ["diagnose", mset, "--json", tmp_path / "d.json", "--add-best", "-o", f[1]], ("-o", f[1]), kept)


def test_outputs_onto_a_profile_given_by_name(tmp_path, capsys, mycam):
    mset, f, ideal = outside_set(tmp_path)
    refused(capsys, ["diagnose", mset, "--json", tmp_path / "d.json", "--add-best", "-o", mycam, "--profile", "mycam"],
            ("-o", "--profile", mycam), [mycam])
    refused(capsys, ["compare", mset, "--json", mycam, "--profile", "mycam"], ("--json", "--profile"), [mycam])
    dng = tmp_path / "cam.dng"
    dng.write_bytes(b"a DNG")
    refused(capsys, ["profile", "from-dng", dng, "--base", "mycam", "-o", mycam], ("--base", mycam), [mycam, dng])
    refused(capsys, ["profile", "from-dng", dng, "--base", mycam, "-o", mycam], ("--base", mycam), [mycam, dng])
    refused(capsys, ["profile", "from-dng", dng, "-o", dng], ("-o", dng), [dng])


def test_two_outputs_that_are_one_file(tmp_path, capsys):
    mset, f, _ = outside_set(tmp_path)
    line = refused(capsys, ["diagnose", mset, "--json", tmp_path / "d.toml", "--add-best", "-o", tmp_path / "d.toml"],
                   ("--json", "-o"))
    assert "same file" in line and not (tmp_path / "d.toml").exists()


def test_an_output_folder_that_holds_an_input(tmp_path, capsys):
    render = tmp_path / "out" / "render.exr"
    render.parent.mkdir()
    render.write_bytes(b"a render")
    refused(capsys, ["stages", "--render", render, "-o", tmp_path / "out", "--force"], ("-o", render), [render])


def test_render_and_motion_outputs_onto_the_blend(tmp_path, capsys):
    """A ``#`` pattern is filled in for each frame: frame 1 of ``s####.blend`` is the .blend itself."""
    blend = tmp_path / "s0001.blend"
    blend.write_bytes(b"BLENDER a scene")
    refused(capsys, ["render", blend, "--frames", "1-3", "-o", tmp_path / "s####.blend"], ("-o", blend), [blend])
    refused(capsys, ["motion", blend, "--frames", "1", "-o", blend], ("-o", blend), [blend])


def test_calibrate_may_update_its_own_profile_but_not_overwrite_a_frame(tmp_path, capsys, mycam):
    """``calibrate -o mycam.toml --profile mycam`` updates the profile on purpose (the default when -o exists)."""
    from lowcam.boundary import check_declared_files
    from lowcam.cli import build_parser

    parser = build_parser()
    f = frames(tmp_path / "flat")
    args = parser.parse_args(["calibrate", "vignetting", str(tmp_path / "flat" / "f*.png"), "--profile", "mycam",
                              "-o", str(mycam)])
    check_declared_files(parser, args)  # allowed
    refused(capsys, ["calibrate", "vignetting", tmp_path / "flat" / "f*.png", "-o", f[3]], ("-o", f[3]), f)
    refused(capsys, ["calibrate", "vignetting", *f, "-o", tmp_path / "v.toml", "--report", tmp_path / "flat"],
            ("--report", "flat"), f)


def test_a_manifest_names_its_inputs_and_its_numbers_are_declared(tmp_path, capsys):
    f = frames(tmp_path / "flat")
    manifest = tmp_path / "manifest.toml"
    manifest.write_text('[vignetting]\nframes = ["flat/f*.png"]\n')
    refused(capsys, ["calibrate", "all", manifest, "-o", f[0]], ("-o", f[0]), f + [manifest])
    manifest.write_text('[plate]\nfootage = ["flat/f*.png"]\nfps = 0\n')
    line = refused(capsys, ["calibrate", "all", manifest, "-o", tmp_path / "o.toml"], ("manifest.toml", "fps"))
    assert "(0, 1000]" in line and not (tmp_path / "o.toml").exists()


# --- numbers out of their declared range: refused while parsing, naming the option ---------------------------------

LENSFUN = ["profile", "from-lensfun", "--maker", "Canon", "--model", "EF 50mm", "--focal-mm", "50", "--base", "fire-i"]


@pytest.mark.parametrize("argv, option", [
    (LENSFUN + ["--aperture", "nan"], "--aperture"),
    (LENSFUN + ["--aperture", "inf"], "--aperture"),
    (LENSFUN + ["--aperture", "1e9"], "--aperture"),
    (LENSFUN + ["--aperture", "0"], "--aperture"),
    (LENSFUN + ["--distance-m", "nan"], "--distance-m"),
    (LENSFUN + ["--distance-m", "1e-9"], "--distance-m"),
    (LENSFUN + ["--distance-m", "-1"], "--distance-m"),
    (LENSFUN + ["--focal-mm", "0"], "--focal-mm"),
    (LENSFUN + ["--crop-factor", "inf"], "--crop-factor"),
    (["calibrate", "plate", "FOOTAGE", "--fps", "0"], "--fps"),
    (["calibrate", "plate", "FOOTAGE", "--fps", "-30"], "--fps"),
    (["calibrate", "plate", "FOOTAGE", "--fps", "nan"], "--fps"),
    (["calibrate", "plate", "FOOTAGE", "--min-confidence", "-1"], "--min-confidence"),
    (["calibrate", "plate", "FOOTAGE", "--min-confidence", "1.5"], "--min-confidence"),
    (["calibrate", "sharpening", "--soft", "FOOTAGE", "--sharp", "FOOTAGE", "--sharpness", "inf"], "--sharpness"),
    (["apply", "--render", "FOOTAGE", "--fps", "0"], "--fps"),
    (["apply", "--render", "FOOTAGE", "--exposure-s", "0"], "--exposure-s"),
    (["apply", "--render", "FOOTAGE", "--metres-per-unit", "-1"], "--metres-per-unit"),
    (["apply", "--render", "FOOTAGE", "--angular-velocity", "1e9,0,0"], "--angular-velocity"),
    (["apply", "--render", "FOOTAGE", "--defocus", "0,1"], "--defocus"),
    (["batch", "--renders", "r/####.exr", "--frames", "1", "--gyro-t0", "inf"], "--gyro-t0"),
    (["batch", "--renders", "r/####.exr", "--frames", "1-x"], "--frames"),
    (["diagnose", "FOOTAGE", "--json", "d.json", "--max-steps", "0"], "--max-steps"),
    (["synth", "--width", "1e9"], "--width"),
    (["synth", "--add", "vignetting:k2=1e9"], "--add vignetting:k2=1e9: effect 'vignetting': 'k2'"),
    (["synth", "--add", "vignetting:k2=abc"], "--add vignetting:k2=abc: effect 'vignetting': 'k2' must be a number"),
    (["synth", "--add", "vignet"], "--add vignet: unknown effect type 'vignet'"),
    (["synth", "--remove", "vignet"], "--remove vignet: "),
])
def test_numbers_out_of_range_are_refused_naming_the_option(tmp_path, capsys, argv, option):
    f = frames(tmp_path / "footage", 2, (64, 48))
    argv = [str(tmp_path / "footage") if a == "FOOTAGE" else a for a in argv]
    out = tmp_path / "o.toml"
    line = refused(capsys, argv + ["-o", str(out)], (option,), f)
    assert "error:" in line and not out.exists()


# --- the same command works the second time; errors name the file they are about -----------------------------------

@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_compare_into_the_set_folder_works_the_second_time(tmp_path, capsys):
    """Lowcam's own earlier output in the set's folder is no input: set.toml names the inputs."""
    mset = tmp_path / "set"
    assert main(["synth", "--frames", "1", "--width", "64", "-o", str(mset)]) == 0
    toml = (mset / "set.toml").read_text()
    (mset / "set.toml").write_text(toml[:toml.index("[[capture]]", 1)])  # one capture: the chart
    inputs = {p: p.read_bytes() for p in mset.rglob("*") if p.is_file()}
    for run in range(2):
        capsys.readouterr()
        code = main(["compare", str(mset), "--json", str(mset / "c.json"), "--report", str(mset / "report")])
        assert code == 0, (run, capsys.readouterr().err)
        assert json.loads((mset / "c.json").read_text())["error"] > 0
    assert all(p.read_bytes() == data for p, data in inputs.items() if p.name != "history.json")


def test_a_board_not_found_names_the_set_and_the_frames(tmp_path, capsys):
    f = frames(tmp_path / "set" / "grey")
    for p in f:
        cv2.imwrite(str(p), np.full((480, 640, 3), 128, np.uint8))
    toml = tmp_path / "set" / "set.toml"
    toml.write_text('[[capture]]\nname = "board"\nframes = "grey/f*.png"\ntarget = "checkerboard:9x6:0.025"\n')
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "set")]) == 2
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "Traceback" not in err, err
    for name in (str(toml), "capture board", "f001.png", "not found"):
        assert name in errors[0], errors[0]


def test_a_batch_output_frame_that_is_a_link_to_the_gyro_log(tmp_path, capsys):
    """The ``#`` pattern's existing frames are outputs too: frame 2 of ``out/####.png`` links to the gyro log."""
    gyro = tmp_path / "gyro.csv"
    gyro.write_text("t,wx,wy,wz\n0,0,0,0\n1,0,0,0\n")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "0002.png").symlink_to(gyro)
    refused(capsys, ["batch", "--renders", tmp_path / "r" / "####.exr", "--frames", "1-3", "--gyro", gyro,
                     "--fps", "24", "--exposure-s", "0.01", "-o", tmp_path / "out" / "####.png"],
            ("-o", "--gyro", gyro), [gyro])
