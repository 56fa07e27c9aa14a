"""Every ``lowcam`` option declares what it is (:mod:`lowcam.arguments`): the files a command reads and writes,
the range of every number. The one error boundary in ``lowcam.cli.main`` refuses an output that is an input, and
parsing refuses numbers out of their range, each as one line naming the option or file, exit 2."""
import argparse
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
    from lowcam.io import IMAGE_SUFFIXES as WRITTEN

    assert tuple(IMAGE_SUFFIXES) == tuple(WRITTEN)
