"""Reading and writing real files: OpenEXR through the OpenEXR package, PNG/JPEG through OpenCV; bad input."""
import os

import cv2
import numpy as np
import OpenEXR
import pytest

import lowcam
from lowcam import LowcamError
from lowcam.io import read_exr, read_render
from lowcam.outputs import write_exr, write_png


def test_single_layer_exr_round_trip(tmp_path, rng):
    rgba = rng.random((40, 60, 4)).astype(np.float32)
    rgba[..., :3] *= rgba[..., 3:]
    write_exr(tmp_path / "r.exr", rgba)
    assert np.array_equal(read_render(tmp_path / "r.exr"), rgba)


def test_blender_multilayer_exr_is_read_from_its_combined_layer(tmp_path, rng):
    rgba = rng.random((32, 48, 4)).astype(np.float32)
    depth = rng.random((32, 48)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {f"ViewLayer.Combined.{c}": rgba[..., i].copy() for i, c in enumerate("RGBA")}
    channels["ViewLayer.Depth.Z"] = depth
    OpenEXR.File(header, channels).write(str(tmp_path / "multi.exr"))
    assert np.array_equal(read_render(tmp_path / "multi.exr"), rgba)


def test_png_render_is_premultiplied_on_read(tmp_path):
    img = np.zeros((20, 20, 4), np.uint8)
    img[..., 0] = 255
    img[..., 3] = 51  # straight red at alpha 0.2
    cv2.imwrite(str(tmp_path / "r.png"), cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA))
    r = read_render(tmp_path / "r.png")
    assert r[0, 0, 0] == pytest.approx(0.2 * 1.0) and r[0, 0, 3] == pytest.approx(0.2)


def _exr(path, rgba):
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"RGBA": rgba}).write(str(path))


@pytest.mark.parametrize("problem, make, message", [
    ("nan", lambda p: _exr(p, np.where(np.arange(64 * 64 * 4).reshape(64, 64, 4) == 77, np.nan, 0.5).astype(np.float32)),
     "NaN or Inf"),
    ("inf", lambda p: _exr(p, np.full((64, 64, 4), np.inf, np.float32)), "NaN or Inf"),
    ("no alpha", lambda p: OpenEXR.File({"type": OpenEXR.scanlineimage},
                                        {"RGB": np.zeros((64, 64, 3), np.float32)}).write(str(p)), "no alpha channel"),
    ("corrupt", lambda p: p.write_bytes(b"v/1\x01" + os.urandom(300)), "not a readable OpenEXR file"),
    ("truncated", lambda p: (_exr(p, np.zeros((64, 64, 4), np.float32)), p.write_bytes(p.read_bytes()[:200])),
     "not a readable OpenEXR file"),
    ("missing", lambda p: None, "no such file"),
])
def test_bad_renders_get_a_one_line_error_naming_the_file(tmp_path, problem, make, message):
    path = tmp_path / f"{problem.replace(' ', '_')}.exr"
    make(path)
    with pytest.raises(LowcamError) as e:
        read_render(path)
    text = str(e.value)
    assert message in text and str(path) in text and "\n" not in text


def test_alpha_out_of_range_is_rejected():
    r = np.zeros((64, 64, 4), np.float32)
    r[..., 3] = 1.5
    with pytest.raises(LowcamError, match="alpha must lie in"):
        lowcam.simulate(r)


def test_wrong_plate_size_is_rejected_naming_the_file(tmp_path):
    cv2.imwrite(str(tmp_path / "plate.png"), np.zeros((600, 800, 3), np.uint8))
    with pytest.raises(LowcamError, match=r"plate.png: the plate is 800x600, the camera delivers 640x480"):
        lowcam.read_plate(tmp_path / "plate.png", 640, 480)
    with pytest.raises(LowcamError, match="the camera delivers 640x480"):
        lowcam.simulate(np.zeros((300, 400, 4), np.float32), "fire-i", np.zeros((600, 800, 3), np.uint8))


def test_writes_are_atomic_and_leave_no_partial_file(tmp_path):
    target = tmp_path / "frame.png"
    write_png(target, np.full((8, 8, 3), 7, np.uint8))
    before = target.read_bytes()
    with pytest.raises(Exception):
        write_png(target, np.zeros((8, 8, 5, 2), np.uint8))  # cannot be encoded
    assert target.read_bytes() == before  # the old complete frame is still there
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.png"]
    assert oct(target.stat().st_mode & 0o777) != oct(0o600)  # readable like a normal file


def test_only_temporaries_of_dead_processes_are_removed(tmp_path):
    """A farm task's start-up removes what killed runs left, never a live task's temporary or a user's file."""
    import subprocess
    import sys
    import time

    from lowcam.outputs import _HOST, remove_stale_temporaries

    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    zombie = subprocess.Popen([sys.executable, "-c", "pass"])  # exited, never reaped: as under an init that does not
    while open(f"/proc/{zombie.pid}/stat").read().rpartition(")")[2].split()[0] != "Z":
        time.sleep(0.01)
    try:
        names = {"live": f".lowcam-{_HOST}-{live.pid}-abc123.0001.png.part",
                 "dead": f".lowcam-{_HOST}-{dead.pid}-abc123.0002.png.part",
                 "zombie": f".lowcam-{_HOST}-{zombie.pid}-abc123.0006.png.part",
                 "other_host": f".lowcam-elsewhere-{dead.pid}-abc123.0003.png.part",
                 "user": ".0004.png.part", "frame": "0005.png"}
        for name in names.values():
            (tmp_path / name).write_bytes(b"x")
        assert remove_stale_temporaries(tmp_path) == 2
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(n for k, n in names.items()
                                                                     if k not in ("dead", "zombie"))
    finally:
        live.kill()
        live.wait()
        zombie.wait()


def test_a_jpeg_damaged_in_the_middle_is_refused_and_one_with_a_trailer_is_read(tmp_path):
    """OpenCV decodes a JPEG whose scan data is damaged as a partly grey picture; libjpeg's complaint (captured off
    the terminal) makes it an error. Bytes after the end-of-image marker, as phones append, are fine."""
    from lowcam.io import read_image
    from lowcam.sample import sample_plate

    data = cv2.imencode(".jpg", sample_plate("fire-i"))[1].tobytes()
    damaged, trailer = tmp_path / "damaged.jpg", tmp_path / "trailer.jpg"
    # 200 random bytes in the scan data (zeros can decode as valid codes without a complaint, whatever the picture)
    damaged.write_bytes(data[:3000] + np.random.default_rng(1).integers(0, 256, 200, dtype=np.uint8).tobytes() +
                        data[3200:])
    trailer.write_bytes(data + b"an appended clip" * 100)
    assert cv2.imread(str(damaged)) is not None  # what OpenCV alone would take as a picture
    with pytest.raises(LowcamError, match=r"damaged\.jpg: the image is truncated or corrupt \(Corrupt JPEG data"):
        read_image(damaged)
    assert read_image(trailer).shape == (480, 640, 3)


def test_an_exr_read_in_a_child_python_gives_the_same_channels_and_the_same_errors(tmp_path, monkeypatch):
    """Where the process holds an OpenEXR core older than the wheel's (Debian's Blender links 3.1, soname 30) the
    file is read in a child Python: the same channels, and a corrupt file is the same one-line error."""
    from lowcam import io

    maps = {b"7f00 r-xp /usr/lib/x86_64-linux-gnu/libOpenEXRCore-3_1.so.30.3.2.12\n": True,
            b"7f00 r-xp /site-packages/bpy/lib/libOpenEXRCore.so.32\n": False, b"7f00 r-xp /usr/lib/libc.so.6\n": False}
    for text, old in maps.items():
        assert any(int(n) < 31 for n in io._EXR_CORE_SONAME.findall(text)) is old
    rgba = np.random.default_rng(0).uniform(0, 1, (6, 7, 4)).astype(np.float32)
    write_exr(tmp_path / "a.exr", rgba)
    monkeypatch.setattr(io, "_exr_core_too_old", lambda: True)
    channels = io.read_exr(tmp_path / "a.exr")
    assert list(channels) == ["RGBA"] and np.array_equal(channels["RGBA"], rgba)
    (tmp_path / "bad.exr").write_bytes((tmp_path / "a.exr").read_bytes()[:200])
    with pytest.raises(LowcamError, match=r"bad\.exr: not a readable OpenEXR file") as e:
        io.read_exr(tmp_path / "bad.exr")
    assert "\n" not in str(e.value)


def test_a_half_float_render_reads_as_exactly_its_float32_values(tmp_path):
    """Every half-float bit pattern (NaN aside) read through OpenEXR comes back as numpy's exact float32 value."""


    every_half = np.arange(65536, dtype=np.uint16).view(np.float16).reshape(128, 128, 4)
    path = tmp_path / "half.exr"
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"RGBA": every_half}).write(str(path))
    pixels = read_exr(path)["RGBA"]
    expected = every_half.astype(np.float32)
    assert pixels.dtype == np.float32 and pixels.shape == (128, 128, 4)
    assert np.array_equal(pixels, expected, equal_nan=True)
    assert np.array_equal(np.signbit(pixels), np.signbit(expected))    # -0.0 stays -0.0


#: How far a composite from a half-float render may stand from the 32-bit render's (stated in docs/blender.md):
#: share of values changed, mean and largest difference in 8-bit levels.
HALF_FLOAT_BOUNDS = {"fire-i": (0.005, 0.01, 5), "iphone-xs-lens": (0.005, 0.01, 5), "rpi-hq": (0.005, 0.01, 5),
                     "ueye": (0.005, 0.01, 5), "phone-video": (0.05, 0.1, 12)}


@pytest.mark.parametrize("name", sorted(HALF_FLOAT_BOUNDS))
def test_a_half_float_render_gives_nearly_the_32_bit_renders_composite(tmp_path, name):
    """The add-on's Half Float render depth: the render rounded to 11 significant bits moves few values of the
    composite (the 6-bit quantisation hides most), a few levels where noise or a video codec's block choices tip;
    the same file at 32 bits gives the same bytes as the render in memory."""
    from lowcam.sample import sample_plate, sample_render

    render, plate = sample_render(name, 1600), sample_plate(name)
    write_exr(tmp_path / "32.exr", render)
    write_exr(tmp_path / "16.exr", render, half=True)
    assert (tmp_path / "16.exr").stat().st_size < 0.35 * (tmp_path / "32.exr").stat().st_size
    frames = {}
    for depth, source in (("memory", render), ("32", tmp_path / "32.exr"), ("16", tmp_path / "16.exr")):
        pixels = source if depth == "memory" else read_render(source)
        frames[depth] = lowcam.run(pixels, name, plate, (0.05, 0.8, 0.1), seed=1, frame=2).frame.astype(int)
    assert np.array_equal(frames["32"], frames["memory"])
    diff = np.abs(frames["16"] - frames["32"])
    share, mean, largest = HALF_FLOAT_BOUNDS[name]
    assert 0 < (diff > 0).mean() <= share and diff.mean() <= mean and diff.max() <= largest


#: The lossless OpenEXR compressions Blender writes (the add-on's Render Compression menu).
LOSSLESS = ("NO", "RLE", "ZIPS", "ZIP", "PIZ")


def test_every_lossless_compression_gives_the_same_render_passes_and_frame(tmp_path):
    """A Blender-shaped render (one part per pass: the view layer's Combined and Vector, the overlay layer's
    Combined) written in each lossless compression is read as the same bits, passes included, so each gives the
    frame of the arrays in memory (object motion from the Vector pass; run on the uncompressed file, the add-on's
    default); a lossy compression (PXR24) is read as other bits."""
    from lowcam.passes import from_blender, read_render_and_passes
    from lowcam.profile import load_profile
    from lowcam.sample import sample_plate, sample_render

    render = sample_render("fire-i", 480)
    vector = (np.float32((-3.0, 1.0, -3.0, 1.0)) * (render[..., 3:] > 0)).astype(np.float32)   # moving right
    overlay = np.zeros_like(render)
    overlay[100:130, 150:250] = (0.0, 1.0, 0.0, 1.0)
    velocity = from_blender(vector, None, 24.0).velocity_px_s
    read = {}
    for codec in (*LOSSLESS, "PXR24"):
        path = tmp_path / f"{codec}.exr"
        header = {"compression": getattr(OpenEXR, f"{codec}_COMPRESSION"), "type": OpenEXR.scanlineimage}
        parts = [OpenEXR.Part(dict(header), {f"ViewLayer.Combined.{c}": render[..., i].copy()
                                             for i, c in enumerate("RGBA")}, "ViewLayer.Combined"),
                 OpenEXR.Part(dict(header), {f"ViewLayer.Vector.{c}": vector[..., i].copy()
                                             for i, c in enumerate("XYZW")}, "ViewLayer.Vector"),
                 OpenEXR.Part(dict(header), {f"Lowcam Overlay.Combined.{c}": overlay[..., i].copy()
                                             for i, c in enumerate("RGBA")}, "Lowcam Overlay.Combined")]
        OpenEXR.File(parts).write(str(path))
        read[codec] = read_render_and_passes(path, None, ("Vector",), 24.0)
    for codec in LOSSLESS:
        checked, passes = read[codec]
        assert checked.rgba.tobytes() == render.tobytes(), codec
        assert passes.velocity_px_s.tobytes() == velocity.tobytes(), codec
    assert read["PXR24"][0].rgba.tobytes() != render.tobytes()     # the comparison sees a lossy codec's change
    sizes = {codec: (tmp_path / f"{codec}.exr").stat().st_size for codec in LOSSLESS}
    assert sizes["NO"] > 10 * sizes["ZIP"]       # the files differ; what they hold does not
    profile = load_profile("fire-i").with_effect("object_motion")
    plate = sample_plate("fire-i")
    expected = lowcam.run(render, profile, plate, (0.05, 0.8, 0.1), seed=1, frame=2,
                          passes=from_blender(vector, None, 24.0)).frame
    checked, passes = read["NO"]
    frame = lowcam.run(checked, profile, plate, (0.05, 0.8, 0.1), seed=1, frame=2, passes=passes).frame
    assert frame.tobytes() == expected.tobytes()


@pytest.mark.parametrize("codec", LOSSLESS)
def test_a_render_truncated_in_its_last_pass_names_the_layer_and_its_channels(tmp_path, codec):
    """A multilayer render cut short inside its Vector part: the OpenEXR binding hands back the parts before it and
    drops that one (its C core complains on stderr); the refusal names the file, the layer and its channels
    instead of saying the pass was never rendered."""
    from lowcam.passes import read_render_and_passes

    rgba = np.random.default_rng(7).uniform(0, 1, (64, 80, 4)).astype(np.float32)
    header = {"compression": getattr(OpenEXR, f"{codec}_COMPRESSION"), "type": OpenEXR.scanlineimage}
    path = tmp_path / "cut.exr"
    OpenEXR.File([OpenEXR.Part(dict(header), {f"ViewLayer.Combined.{c}": rgba[..., i].copy()
                                              for i, c in enumerate("RGBA")}, "ViewLayer.Combined"),
                  OpenEXR.Part(dict(header), {f"ViewLayer.Vector.{c}": rgba[..., i].copy()
                                              for i, c in enumerate("XYZW")}, "ViewLayer.Vector")]).write(str(path))
    whole = path.read_bytes()
    path.write_bytes(whole[:len(whole) - len(whole) // 20])     # the last 5 %: inside the Vector part
    for needs in (("Vector",), ()):
        with pytest.raises(LowcamError) as e:
            read_render_and_passes(path, None, needs, 24.0)
        text = str(e.value)
        assert text.startswith(f"{path}: not a readable OpenEXR file: layer 'ViewLayer.Vector' (channels "
                               "ViewLayer.Vector.W, ViewLayer.Vector.X, ViewLayer.Vector.Y, ViewLayer.Vector.Z)")
        assert "\n" not in text
    path.write_bytes(whole)
    assert read_render_and_passes(path, None, ("Vector",), 24.0)[0].rgba.tobytes() == rgba.tobytes()


def _strip_test_render() -> np.ndarray:
    """A 240x200 render with zero margins, graphics in the middle and, below them, a band holding only -0.0."""
    rgba = np.zeros((240, 200, 4), np.float32)
    rgba[60:130, 70:150] = np.random.default_rng(4).uniform(0, 1, (70, 80, 4))
    rgba[170:180, 20:40] = -0.0
    return rgba


def _uncompressed_exr(path, rgba):
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {c: rgba[..., i].copy() for i, c in enumerate("RGBA")}).write(str(path))


@pytest.mark.parametrize("spot, value", [(None, None), ((150, 5, 2), np.nan), ((2, 190, 0), np.inf),
                                         ((100, 100, 3), 1.5), ((175, 30, 1), -1e6), ((239, 199, 3), np.nan)])
def test_a_render_checked_strip_by_strip_is_checked_as_a_whole(tmp_path, monkeypatch, spot, value):
    """An uncompressed render is checked a strip of lines at a time as it is read: the same array (bits, -0.0
    included) and window as the whole array checked, or the same refusal, wherever the bad value lies (a strip
    otherwise zero, a band of -0.0, the graphics, the last line)."""
    from lowcam import uncompressed_exr
    from lowcam.io import check_render_window, read_checked_render

    monkeypatch.setattr(uncompressed_exr, "_STRIP_BYTES", 7 * 200 * 16)      # strips of 7 lines
    rgba = _strip_test_render()
    if spot is not None:
        rgba[spot] = value
    path = tmp_path / "render.exr"
    _uncompressed_exr(path, rgba)
    try:
        expected = check_render_window(rgba, path)
    except LowcamError as e:
        with pytest.raises(LowcamError) as got:
            read_checked_render(path)
        assert str(got.value) == str(e)
        return
    got = read_checked_render(path)
    assert got.rgba.tobytes() == rgba.tobytes() and got.window == expected.window == (slice(60, 130), slice(70, 150))


def test_a_shots_renders_reuse_arrays_no_one_holds(tmp_path):
    """While reusing_render_buffers is on, an uncompressed render is read into an array of an earlier one once
    nothing refers to that array any more (not while a view of it lives); without it nothing is kept."""
    from lowcam.io import read_render, reusing_render_buffers

    rgba = _strip_test_render()
    path = tmp_path / "render.exr"
    _uncompressed_exr(path, rgba)
    with reusing_render_buffers(3):
        first = read_render(path)
        address = first.__array_interface__["data"][0]
        second = read_render(path)                      # the first is held: another array
        assert second.__array_interface__["data"][0] != address
        corner = first[:5]
        del first
        assert read_render(path).__array_interface__["data"][0] != address    # a view of it is held
        del corner
        again = read_render(path)
        assert again.__array_interface__["data"][0] == address and again.tobytes() == rgba.tobytes()
    held = read_render(path)
    assert read_render(path).__array_interface__["data"][0] != held.__array_interface__["data"][0]


@pytest.mark.parametrize("height, width", [(10, 10), (200, 8), (8, 200)])
def test_a_render_too_small_is_refused_when_read_strip_by_strip_too(tmp_path, height, width):
    from lowcam.io import check_render_window, read_checked_render

    rgba = np.zeros((height, width, 4), np.float32)
    rgba[height // 2, width // 2] = 0.5
    _uncompressed_exr(tmp_path / "small.exr", rgba)
    with pytest.raises(LowcamError) as whole:
        check_render_window(rgba, tmp_path / "small.exr")
    with pytest.raises(LowcamError) as got:
        read_checked_render(tmp_path / "small.exr")
    assert str(got.value) == str(whole.value) and "too small" in str(got.value)


def test_a_read_error_under_a_strip_fails_the_render_in_one_line(tmp_path, monkeypatch):
    """An I/O error (a network disk gone) while strips are read is a one-line error naming the file, which a shot
    reports as that frame's failure, not a traceback."""
    import errno
    import io

    from lowcam import uncompressed_exr
    from lowcam.io import read_checked_render

    _uncompressed_exr(tmp_path / "render.exr", _strip_test_render())

    class Failing(io.FileIO):
        def readinto(self, buffer):
            raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(uncompressed_exr, "open", lambda path, *args, **kw: Failing(path), raising=False)
    with pytest.raises(LowcamError) as e:
        read_checked_render(tmp_path / "render.exr")
    assert str(e.value).startswith(f"{tmp_path / 'render.exr'}: cannot read it any more (Input/output error)")


def test_a_part_holding_the_render_and_its_passes_is_read_once(tmp_path, monkeypatch):
    """Combined and Vector in one part (as writers other than Blender put them): the part is read once for both,
    not strip by strip for the render and again for the pass."""
    from lowcam.passes import read_render_and_passes
    from lowcam.uncompressed_exr import LazyChannels

    rgba = _strip_test_render()
    channels = {f"ViewLayer.Combined.{c}": rgba[..., i].copy() for i, c in enumerate("RGBA")}
    channels |= {f"ViewLayer.Vector.{c}": np.zeros(rgba.shape[:2], np.float32) for c in "XYZW"}
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                 channels).write(str(tmp_path / "render.exr"))
    reads, read_part = [], LazyChannels._read_part
    monkeypatch.setattr(LazyChannels, "_read_part", lambda self: reads.append(1) or read_part(self))
    monkeypatch.setattr(LazyChannels, "read_in_strips", None)     # never called for such a part
    checked, passes = read_render_and_passes(tmp_path / "render.exr", None, ("Vector",), 24.0)
    assert checked.rgba.tobytes() == rgba.tobytes() and passes is not None and len(reads) == 1
