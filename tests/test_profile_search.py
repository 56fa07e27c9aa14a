"""``lowcam profile search``: lensfun's lenses and cameras and a folder of Gyroflow lens profiles, typos allowed.

The lensfun database is lensfunpy's bundled copy; the Gyroflow files are written here (Gyroflow's own database is
not part of Lowcam). Each command a row prints is run, so a row that names a lens, a camera or a file Lowcam
cannot use fails here.
"""
import json
import os
import random
import shlex
import subprocess
import sys

import lensfunpy
import pytest

import lowcam
from lowcam import lensdb
from lowcam.cli import main
from test_gyroflow import GOPRO


def rows(capsys, *args):
    """(the rows, the last line, stderr) of ``lowcam profile search ARGS``."""
    assert main(["profile", "search", *args]) == 0
    captured = capsys.readouterr()
    out = captured.out.splitlines()
    return out[:-1], out[-1], captured.err


def run_row_command(capsys, row, tmp_path, name="mycam.toml"):
    """Run the command at the end of a search row (``lowcam profile ...``), writing into ``tmp_path``."""
    argv = shlex.split(row[row.index("lowcam profile "):])[1:]
    argv[argv.index("-o") + 1] = str(tmp_path / name)
    assert main(argv) == 0, capsys.readouterr().err
    capsys.readouterr()
    return lowcam.load_profile(tmp_path / name)


@pytest.fixture(autouse=True)
def no_gyroflow_folder(monkeypatch):
    monkeypatch.delenv(lensdb.GYROFLOW_ENV, raising=False)


def test_a_mistyped_phone_finds_the_iphones_and_not_a_phantom(capsys):
    found, last, err = rows(capsys, "iphnoe")
    assert "showing 'iphone'" in err
    assert found and all("iPhone" in row for row in found) and last == "2 lenses, 2 cameras"
    assert not any("Phantom" in m.entry.name for m in lensdb.search("iphnoe"))
    assert any("Phantom" in m.entry.name for m in lensdb.search("phantom"))   # the Phantom is there to be found


@pytest.mark.parametrize("text", ["sigma 18-35", "Sigma 18-35mm", "sigma 1835", "18-35 sigma", "sigam 18-35",
                                  "SIGMA 18-35MM F1.8", "sigma18-35"])
def test_the_ways_people_write_a_lens_find_it_first(capsys, text):
    found, _, _ = rows(capsys, *text.split())
    assert found[0].startswith("Sigma | Sigma 18-35mm f/1.8 DC HSM [A] | rectilinear | "), found[:3]


def _mangled(name, rng, how):
    """``name`` with one typo in a word of letters: two neighbours swapped, or one letter dropped."""
    words = name.split()
    where = [i for i, w in enumerate(words) if w.isalpha() and len(w) >= (4 if how == "swap" else 5)
             and (how == "drop" or len(set(w.lower())) > 1)]
    if not where:
        return None
    i = rng.choice(where)
    w = words[i]
    while True:
        j = rng.randrange(len(w) - 1 if how == "swap" else len(w))
        typo = w[:j] + w[j + 1] + w[j] + w[j + 2:] if how == "swap" else w[:j] + w[j + 1:]
        if typo.lower() != w.lower():
            break
    words[i] = typo
    return " ".join(words)


def test_real_lens_names_with_a_typo_are_found_in_the_top_rows():
    """Lens names drawn at random (seeded) from the database, each with two neighbouring letters swapped or one
    letter dropped: the lens is among the first 10 rows of the search."""
    rng = random.Random(2024)
    names = sorted({e.name for e in lensdb.lens_entries()})
    tried = 0
    for name in rng.sample(names, 40):
        for how in ("swap", "drop"):
            text = _mangled(name, rng, how)
            if text is None:
                continue
            tried += 1
            top = [m.entry.name for m in lensdb.search(text)[:10]]
            assert name in top, (name, text, top[:3])
    assert tried >= 30


def test_maker_filter_and_a_mistyped_maker(capsys):
    found, _, _ = rows(capsys, "18-35", "--maker", "sigma", "--limit", "0")
    assert found and all(row.startswith("Sigma | ") for row in found)
    assert any(m.entry.maker != "Sigma" for m in lensdb.search("18-35"))   # the filter took some out
    alone, _, _ = rows(capsys, "--maker", "DJI", "--limit", "0")
    assert alone and all(row.startswith("DJI | ") for row in alone)
    corrected, _, err = rows(capsys, "--maker", "Snoy", "--limit", "0")
    assert "showing 'Sony'" in err and corrected and all(row.startswith("Sony | ") for row in corrected)
    assert main(["profile", "search", "lens", "--maker", "Qwxz"]) == 2
    err = capsys.readouterr().err
    assert "--maker Qwxz: no lens, camera or Gyroflow profile of that maker" in err and len(err.splitlines()) == 1


def test_a_long_list_is_cut_at_the_limit_with_a_line_saying_how_to_see_more(capsys):
    total = len(lensdb.search("Sony"))
    assert total > 100
    shown, last, _ = rows(capsys, "Sony")
    assert len(shown) == 20 and last.startswith(f"20 of {total} shown (")
    assert "--limit 0 shows all" in last and "--maker" in last
    five, last, _ = rows(capsys, "Sony", "--limit", "5")
    assert five == shown[:5] and last.startswith(f"5 of {total} shown")
    every, last, _ = rows(capsys, "Sony", "--limit", "0")
    assert len(every) == total and every[:20] == shown and "shown" not in last


def test_cameras_are_listed_with_their_crop_factor_and_a_command_that_works(capsys, tmp_path):
    """A fixed-lens camera's row names its lens; running the row's command gives the camera's crop factor. A
    camera whose model has several sensor modes (lensfun's variants) is given by its crop factor."""
    found, last, _ = rows(capsys, "powershot", "g12")
    camera = next(row for row in found if " | camera | " in row)
    g12 = next(c for c in lensfunpy.Database().cameras if c.model == "Canon PowerShot G12")
    assert camera.startswith("Canon | Canon PowerShot G12 | camera | canonG12 | crop 4.63 | ") and last.endswith(
        "1 camera")
    profile = run_row_command(capsys, camera, tmp_path)
    assert profile.effect("lens_distortion").crop_factor == pytest.approx(g12.crop_factor, rel=1e-6)
    assert "PowerShot G12 in the lensfun database" in profile.provenance["lens_distortion"]
    found, _, _ = rows(capsys, "lx3", "16:9")
    camera = next(row for row in found if " | camera | " in row)
    assert "DMC-LX3 (16:9)" in camera and "--crop-factor 5.753" in camera
    assert run_row_command(capsys, camera, tmp_path, "lx3.toml").effect("lens_distortion").crop_factor == \
        pytest.approx(5.753)
    body, _, _ = rows(capsys, "EOS", "5D", "Mark", "III")
    assert body[0].startswith("Canon | Canon EOS 5D Mark III | camera | Canon EF | crop 1 | ")
    assert "--maker LENS-MAKER --model LENS-MODEL" in body[0]             # an interchangeable lens: yours to add
    assert main(["profile", "search", "5D", "--type", "rectilinear", "--limit", "0"]) == 0
    assert " | camera | " not in capsys.readouterr().out                  # a camera has no lens type


def _gyroflow_folder(tmp_path):
    """A small copy of Gyroflow's database layout: brand folders of .json lens profiles, one of a lens model
    Lowcam does not read, one that is no JSON."""
    folder = tmp_path / "lens_profiles"
    (folder / "GoPro").mkdir(parents=True)
    (folder / "Phone").mkdir()
    (folder / "GoPro" / "GoPro_HERO11 Black_Wide_NO-EIS_1440p_4by3_1920x1440-59.94fps.json").write_text(
        json.dumps(GOPRO))
    phone = {"calib_dimension": {"w": 1280, "h": 960}, "use_opencv_fisheye": False, "use_opencv_standard": True,
             "calib_params": {"camera_matrix": [[1000.0, 0, 641.3], [0, 1002.0, 478.9], [0, 0, 1]],
                              "distortion_coeffs": [-0.21, 0.09, 0.0012, -0.0008, -0.015]},
             "camera_brand": "Phone", "camera_model": "Model X", "lens_model": "Main", "camera_setting": "4:3 30p",
             "fps": 30}
    (folder / "Phone" / "Phone_Model X_Main.json").write_text(json.dumps(phone))
    (folder / "GoPro" / "superview.json").write_text(json.dumps({**GOPRO, "distortion_model": "gopro_superview"}))
    (folder / "GoPro" / "broken.json").write_text("{")
    return folder


def test_gyroflow_profiles_of_a_folder_are_listed_with_the_command_that_reads_them(capsys, tmp_path, monkeypatch):
    folder = _gyroflow_folder(tmp_path)
    found, last, err = rows(capsys, "gopro", "hero11", "--gyroflow", str(folder))
    gopro = next(row for row in found if "Gyroflow" in row)
    path = folder / "GoPro" / "GoPro_HERO11 Black_Wide_NO-EIS_1440p_4by3_1920x1440-59.94fps.json"
    assert gopro == (f"GoPro | Hero11 Black | Gyroflow fisheye | lens Wide | mode NO-EIS 1440p 4by3 "
                     f"1920x1440-59.94fps | 1920x1440 at 59.94 fps | lowcam profile from-gyroflow "
                     f"{shlex.quote(str(path))} -o mycam.toml")
    assert last.endswith("1 Gyroflow profile") and "2 .json files are not listed" in err
    assert run_row_command(capsys, gopro, tmp_path).camera.name == "GoPro Hero11 Black Wide"
    monkeypatch.setenv(lensdb.GYROFLOW_ENV, str(folder))                 # the folder from the environment
    found, _, _ = rows(capsys, "phnoe", "model", "x")
    assert found == [f"Phone | Model X | Gyroflow standard | lens Main | mode 4:3 30p | 1280x960 at 30 fps | "
                     f"lowcam profile from-gyroflow {shlex.quote(str(folder / 'Phone' / 'Phone_Model X_Main.json'))} "
                     f"-o mycam.toml"]
    assert rows(capsys, "phone", "model", "x", "--type", "rectilinear")[0] == found  # OpenCV's standard model
    assert main(["profile", "search", "phone", "model", "x", "--type", "fisheye"]) == 2
    err = capsys.readouterr().err
    assert "nothing matching 'phone model x' is of the maker, type and focal length asked for" in err
    monkeypatch.setenv(lensdb.GYROFLOW_ENV, str(tmp_path / "nowhere"))
    assert main(["profile", "search", "gopro"]) == 2
    err = capsys.readouterr().err
    assert f"{lensdb.GYROFLOW_ENV} {tmp_path / 'nowhere'}: not a folder" in err and len(err.splitlines()) == 1


def test_without_lensfunpy_a_gyroflow_folder_is_still_searched(capsys, tmp_path, monkeypatch):
    folder = _gyroflow_folder(tmp_path)
    for cache in (lensdb._database, lensdb.lens_entries, lensdb.camera_entries):
        cache.cache_clear()
    monkeypatch.setitem(sys.modules, "lensfunpy", None)  # import lensfunpy -> ImportError
    try:
        found, last, err = rows(capsys, "gopro", "--gyroflow", str(folder))
        assert last == "1 Gyroflow profile" and found[0].startswith("GoPro | Hero11 Black | Gyroflow fisheye")
        assert "pip install lowcam[lensfun]" in err
    finally:
        for cache in (lensdb._database, lensdb.lens_entries, lensdb.camera_entries):
            cache.cache_clear()


#: A user's environment: no Gyroflow folder, and stdout buffered as in a terminal session's pipe (an unbuffered
#: stdout would meet the closed pipe at the first row, not at the flush on the way out).
ENV = {**{k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}, lensdb.GYROFLOW_ENV: ""}


def test_a_reader_that_leaves_is_no_error(tmp_path):
    """``lowcam profile search Canon | head -1`` through a real shell pipe, and a pipe whose reader is gone before
    the first row (the rows fit in the pipe's buffer, so only the flush sees it): status 0, nothing on stderr."""
    r = subprocess.run(["bash", "-c", f"set -o pipefail; {shlex.quote(sys.executable)} -m lowcam.cli profile search "
                        "Canon | head -1"], capture_output=True, text=True, timeout=120, env=ENV)
    assert r.returncode == 0 and r.stderr == "" and r.stdout.startswith("Canon | ") and r.stdout.count("\n") == 1
    read, write = os.pipe()
    os.close(read)
    try:
        r = subprocess.run([sys.executable, "-m", "lowcam.cli", "profile", "search", "Canon", "--gyroflow",
                            str(_gyroflow_folder(tmp_path))], stdout=write, stderr=subprocess.PIPE, text=True,
                           timeout=120, env=ENV)
    finally:
        os.close(write)
    assert r.returncode == 0 and r.stderr.count("\n") == 1 and ".json files are not listed" in r.stderr, r.stderr


def test_every_gyroflow_row_ends_with_a_command_that_works_at_any_frame_shape(capsys, tmp_path):
    """A folder with a GoPro's 16:9 and anamorphic modes, a narrow phone lens with large alternating terms, a
    SuperView file and a lens that folds over inside its frame: the three Lowcam makes profiles of are listed, each
    row's command makes the profile at the mode's own frame (16:9 1920x1080; the anamorphic 2880x1080 calibration's
    recorded 1920x1080); the other two are counted as not listed."""
    from test_gyroflow import TELEPHOTO
    folder = tmp_path / "lens_profiles" / "GoPro"
    folder.mkdir(parents=True)
    k16 = [[850.9, 0.0, 961.2], [0.0, 851.2, 541.7], [0.0, 0.0, 1.0]]
    modes = {"GoPro_HERO10 Black_Linear_1080p_16by9_1920x1080.json":
             dict(GOPRO, camera_model="HERO10 Black", lens_model="Linear", calib_dimension={"w": 1920, "h": 1080},
                  fisheye_params=dict(GOPRO["fisheye_params"], camera_matrix=k16)),
             "GoPro_HERO10 Black_Linear_anamorphic_2880x1080.json":
             dict(GOPRO, camera_model="HERO10 Black", lens_model="Linear", calib_dimension={"w": 2880, "h": 1080},
                  input_horizontal_stretch=1.5, camera_setting="anamorphic",
                  fisheye_params=dict(GOPRO["fisheye_params"], camera_matrix=[[1276.4, 0.0, 1441.8],
                                                                              [0.0, 851.2, 541.7], [0, 0, 1]])),
             "GoPro_HERO10 Black_Linear_SuperView.json": dict(GOPRO, camera_model="HERO10 Black",
                                                              digital_lens="gopro_superview"),
             "GoPro_HERO10 Black_Linear_folds.json":
             dict(GOPRO, camera_model="HERO10 Black", fisheye_params=dict(GOPRO["fisheye_params"],
                                                                          distortion_coeffs=[-0.9, 0, 0, 0]))}
    for name, doc in modes.items():
        (folder / name).write_text(json.dumps(doc))
    (folder / "Apple_iPhone 12 Pro_Telephoto.json").write_text(json.dumps(TELEPHOTO))
    found, last, err = rows(capsys, "hero10", "linear", "--gyroflow", str(folder.parent))
    assert last == "2 Gyroflow profiles" and "2 .json files are not listed" in err
    frames = {}
    for i, row in enumerate(found):
        profile = run_row_command(capsys, row, tmp_path, f"mode{i}.toml")
        frames[row.split(" | ")[4]] = (profile.camera.width, profile.camera.height)
    assert frames == {"mode 1080p 16by9 1920x1080": (1920, 1080), "mode anamorphic": (1920, 1080)}
    found, _, _ = rows(capsys, "iphone", "12", "pro", "telephoto", "--gyroflow", str(folder.parent))
    gyroflow = [row for row in found if "Gyroflow" in row]
    assert len(gyroflow) == 1 and " | 3840x2160 at 25 fps | " in gyroflow[0]
    assert run_row_command(capsys, gyroflow[0], tmp_path, "tele.toml").camera.width == 3840


@pytest.mark.parametrize("text", ["[(*+?", "***", "Объектив", "カメラ"])
def test_a_search_that_matches_nothing_says_so(capsys, text):
    """Punctuation alone, Cyrillic or Japanese text: no name holds it, so the search says that nothing matches, in
    one line, with status 2 (as for any text that matches nothing), instead of listing every lens."""
    assert main(["profile", "search", text]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and f"matches '{text}'" in captured.err and len(captured.err.strip().splitlines()) == 1
