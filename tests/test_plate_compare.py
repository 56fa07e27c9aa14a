"""Codec estimates from the plate alone, and ``lowcam compare --plate-only``.

The JPEG and chroma-subsampling estimators are tested on frames coded by outside encoders (Pillow's and OpenCV's
libjpeg, with their own ``quality`` and ``subsampling`` arguments) of scikit-image's photographs; the comparison's
diagnose -> add -> error-falls loop on footage the engine made with known codec settings.
"""
import io
import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image
from skimage import data

from lowcam.effects.jpeg import jpeg_blockiness, jpeg_quality_from_plate
from lowcam.effects.yuv import RGB_TO_YUV, chroma_subsampling_from_plate
from lowcam.measure.plate import Footage, estimate_profile, plate_probes
from lowcam.measure.plate_compare import compare_plate, flatten_statistic, tile_slices
from lowcam.pipeline import prepare, render_camera, resume
from lowcam.profile import load_profile

CODEC = [p for p in plate_probes() if p.name in ("jpeg_blockiness", "chroma_bandwidth")]


def noisy(name, frames=2, sigma=2.0, seed=1):
    """A scikit-image photograph with a camera's mild Gaussian noise, as ``frames`` uint8 RGB frames."""
    img = np.ascontiguousarray(getattr(data, name)()[..., :3]).astype(np.float32)
    rng = np.random.default_rng(seed)
    return [np.clip(img + rng.normal(0, sigma, img.shape), 0, 255).astype(np.uint8) for _ in range(frames)]


def pillow_jpeg(frame, quality, subsampling=2):
    """Pillow's JPEG (subsampling 0: 4:4:4, 1: 4:2:2, 2: 4:2:0) encoded and decoded."""
    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, "JPEG", quality=quality, subsampling=subsampling)
    return np.array(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))


def footage(frames):
    return Footage(np.stack([np.asarray(f) for f in frames]), path="test footage")


@pytest.mark.parametrize("name", ["astronaut", "chelsea"])
def test_jpeg_quality_of_pillows_jpegs_is_recovered_within_15(name):
    frames = noisy(name)
    for quality in (20, 45, 70):
        est = jpeg_quality_from_plate(footage([pillow_jpeg(f, quality) for f in frames]))
        assert est.effect == "jpeg" and est.confidence >= 0.5, est.line()
        assert abs(est.params["quality"] - quality) <= 15, (quality, est.line())


def engine_frames(profile, scene, frames, seed=7):
    """``frames`` frames of ``profile`` filming a scikit-image photograph (an opaque ideal filling the view)."""
    cam = render_camera(profile, profile.camera.width)
    img = cv2.resize(getattr(data, scene)()[..., :3].astype(np.float32) / 255, (cam["width"], cam["height"]),
                     interpolation=cv2.INTER_AREA)
    ideal = np.ones(img.shape[:2] + (4,), np.float32)
    ideal[..., :3] = img
    token = prepare(ideal, profile)
    return Footage(np.stack([resume(token, seed, k, profile) for k in range(frames)]), path=f"engine {scene}")


def test_jpeg_quality_of_a_sharpened_noisy_camera_is_recovered_within_10():
    """The Fire-i sharpens and quantises to 6 bits before its JPEG: the calibration's second recoding corrects
    for the frame being coded already (without it: 67 for 50, 86 for 75)."""
    base = load_profile("fire-i")
    for quality in (50, 75):
        shot = engine_frames(base.with_effect("jpeg", quality=quality, subsampling="4:2:0"), "astronaut", 3)
        est = jpeg_quality_from_plate(shot)
        assert abs(est.params["quality"] - quality) <= 10, (quality, est.line())


def test_no_blockiness_is_claimed_on_uncompressed_frames():
    for name in ("astronaut", "coffee"):
        est = jpeg_quality_from_plate(footage(noisy(name)))
        assert est.confidence < 0.2 and not est.params, est.line()
    # the grid must be on both axes: vertical 8 px stripes alone (a scaler's artefact, not a codec) are no JPEG
    frames = noisy("coffee")
    striped = [np.clip(f.astype(np.int16) + 6 * (np.arange(f.shape[1]) % 8 == 0)[None, :, None], 0, 255)
               .astype(np.uint8) for f in frames]
    assert jpeg_quality_from_plate(footage(striped)).confidence < 0.2


def test_a_structure_of_2_px_is_no_jpeg_grid():
    """A block demosaic fills each 2x2 block from one sensel's neighbourhood: the steps across blocks exceed those
    inside on every second phase of the 8 alike, which the other phases' median read as an 8x8 grid (t 13-25 and
    quality 95 at full confidence on the Fire-i's frames). Here 2x2 blocks of a photograph, each repeated, noise on
    top."""
    rng = np.random.default_rng(3)
    img = cv2.resize(data.coffee(), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA).astype(np.float32)
    blocks = np.repeat(np.repeat(img, 2, axis=0), 2, axis=1)
    frames = [np.clip(blocks + rng.normal(0, 1.0, blocks.shape), 0, 255).astype(np.uint8) for _ in range(2)]
    grid = jpeg_blockiness(np.stack(frames).astype(np.float32))
    assert max(grid["t_h"], grid["t_v"]) < 3, grid  # the median of all the others: t 20 and 23
    est = jpeg_quality_from_plate(footage(frames))
    assert est.confidence < 0.2 and not est.params, est.line()


def test_the_fire_is_own_frames_show_no_jpeg_grid_and_pillows_jpeg_of_them_does():
    """The Fire-i (Bayer demosaicing, 4:1:1 chroma) without a JPEG: no grid on two photographs; the same
    frames through Pillow's JPEG at qualities drawn at random: the grid and the quality within 10."""
    base = load_profile("fire-i")
    rng = np.random.default_rng(5)
    for scene in ("astronaut", "coffee"):
        shot = engine_frames(base, scene, 3)
        est = jpeg_quality_from_plate(shot)
        assert est.confidence < 0.2 and not est.params, est.line()
        quality = int(rng.integers(20, 91))
        coded = jpeg_quality_from_plate(footage([pillow_jpeg(f.astype(np.uint8), quality) for f in shot.stack()]))
        assert coded.confidence >= 0.5 and abs(coded.params["quality"] - quality) <= 10, (quality, coded.line())


@pytest.mark.parametrize("name", ["astronaut", "coffee", "chelsea"])
def test_chroma_subsampling_of_pillows_jpegs_is_told_apart(name):
    """The JPEG's subsampling replaces the base's own chroma subsampling (the Fire-i's 4:1:1 of the graphics)
    rather than stacking both; without a JPEG effect in the profile (its quality unmeasured) it is reported only,
    not written beside a JPEG of an assumed quality."""
    frames = noisy(name)
    coded = load_profile("fire-i").with_effect("jpeg", quality=90)
    for code, expected in ((0, "4:4:4"), (1, "4:2:2"), (2, "4:2:0")):
        shot = footage([pillow_jpeg(f, 90, code) for f in frames])
        est = chroma_subsampling_from_plate(shot, coded)
        assert est.measured["subsampling"] == expected, (expected, est.line())
        assert est.confidence >= 0.5, est.line()
        assert est.effect == "jpeg" and est.params == {"subsampling": expected, "chroma_subsampling.enabled": False}
        alone = chroma_subsampling_from_plate(shot, load_profile("fire-i"))
        assert alone.params == {} and alone.measured["subsampling"] == expected and "reported only" in alone.reason


def test_chroma_subsampling_of_opencvs_411_jpeg_and_of_repeated_chroma():
    frames = noisy("coffee")
    flags = [cv2.IMWRITE_JPEG_QUALITY, 80, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411]
    coded = [cv2.imdecode(cv2.imencode(".jpg", f[..., ::-1], flags)[1], cv2.IMREAD_COLOR)[..., ::-1] for f in frames]
    est = chroma_subsampling_from_plate(footage(coded))
    assert est.measured["subsampling"] == "4:1:1" and est.confidence >= 0.5, est.line()
    assert est.effect == "chroma_subsampling" and est.params == {"group": 4}

    # no codec: chroma averaged over pairs of pixels across and repeated (4:2:2 as a YUV camera delivers it),
    # written here with the BT.601 matrix
    def halve_chroma(f):
        yuv = f.astype(np.float64) @ RGB_TO_YUV.T
        for c in (1, 2):
            pairs = yuv[:, : yuv.shape[1] // 2 * 2, c].reshape(yuv.shape[0], -1, 2).mean(axis=2)
            yuv[:, : pairs.shape[1] * 2, c] = np.repeat(pairs, 2, axis=1)
        return np.clip(np.rint(yuv @ np.linalg.inv(RGB_TO_YUV).T), 0, 255).astype(np.uint8)

    est = chroma_subsampling_from_plate(footage([halve_chroma(f) for f in frames]))
    assert est.measured["subsampling"] == "4:2:2" and est.confidence >= 0.5, est.line()
    assert est.effect == "chroma_subsampling" and est.params == {"group": 2}
    est = chroma_subsampling_from_plate(footage(frames))
    assert est.measured["subsampling"] == "4:4:4"


def test_statistics_are_flattened_and_tiles_keep_the_jpeg_grid():
    assert flatten_statistic({"a": 1, "b": {"c": [2.0, float("nan"), 3]}, "m": "temporal", "n": None}) == \
        {"a": 1.0, "b.c.0": 2.0, "b.c.2": 3.0}
    tiles = tile_slices(480, 640)
    assert len(tiles) == 12 and all(sy.start % 16 == 0 and sx.start % 16 == 0 for sy, sx in tiles)
    covered = np.zeros((480, 640), int)
    for sy, sx in tiles:
        covered[sy, sx] += 1
    assert (covered == 1).all()


@pytest.fixture(scope="module")
def engine_footage():
    """Six frames of the Fire-i with JPEG at quality 30, 4:2:0 appended, filming scikit-image's coffee."""
    base = load_profile("fire-i")
    truth = base.with_effect("jpeg", quality=30, subsampling="4:2:0")
    return base, truth, engine_frames(truth, "coffee", 6)


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_plate_compare_finds_the_missing_codec_and_the_error_falls_when_it_is_added(engine_footage):
    base, truth, shot = engine_footage
    without = compare_plate(shot, base, CODEC, progress=False)
    assert without.error > 5 and without.verdict == "not explained"
    assert without.where["worst"]["probe"] == "jpeg_blockiness" and without.where["worst"]["effect"] == "jpeg"

    added = compare_plate(shot, truth, CODEC, progress=False)
    assert added.error <= 2.0, added.families  # measured 1.68 here; 0.7-1.9 over three scenes and two settings

    wrong_chroma = compare_plate(shot, base.with_effect("jpeg", quality=30, subsampling="4:4:4"), CODEC,
                                 progress=False)
    assert wrong_chroma.error > 3
    assert wrong_chroma.where["worst"]["probe"] == "chroma_bandwidth"
    assert wrong_chroma.where["worst"]["effect"] == "chroma_subsampling"

    # the profile estimated from the plate gets the codec nearly right, and the error falls by far
    estimated, estimates = estimate_profile(shot, base, progress=False, probes=CODEC)
    jpeg = estimated.effect("jpeg")
    assert jpeg is not None and jpeg.subsampling == "4:2:0" and abs(jpeg.quality - 30) <= 10, \
        [e.line() for e in estimates]
    fitted = compare_plate(shot, estimated, CODEC, progress=False)
    assert fitted.error < without.error / 4, (fitted.error, without.error)


def lowcam(*args):
    return subprocess.run([sys.executable, "-m", "lowcam.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_cli_plate_only_writes_json_and_report(engine_footage, tmp_path):
    import json

    _, _, shot = engine_footage
    folder = tmp_path / "shot"
    folder.mkdir()
    for i, f in enumerate(shot.frames[:4]):
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), cv2.cvtColor(np.asarray(f, np.uint8), cv2.COLOR_RGB2BGR))
    r = lowcam("compare", "--plate-only", folder, "--profile", "fire-i", "--probes", "jpeg_blockiness",
               "--json", tmp_path / "c.json", "--report", tmp_path / "rep")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["error"] > 5 and doc["where"]["worst"]["effect"] == "jpeg" and doc["verdict"] == "not explained"
    assert "where: jpeg_blockiness (jpeg)" in r.stdout
    assert (tmp_path / "rep" / "index.html").is_file() and (tmp_path / "rep" / "plate_probes.png").is_file()


@pytest.mark.parametrize("args, says", [
    (("compare", "--profile", "fire-i"), "give a measurement set or --plate-only FOOTAGE"),
    (("compare", "--plate-only", "/nonexistent/shot", "--profile", "fire-i"), "/nonexistent/shot: no such"),
    (("compare", "--plate-only", ".", "--probes", "jpeg_blockines"), "no plate probe jpeg_blockines"),
])
def test_cli_plate_only_bad_input_is_one_line(args, says, tmp_path):
    r = lowcam(*args)
    assert r.returncode == 2 and says in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
