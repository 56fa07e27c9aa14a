"""Uncompressed OpenEXR files read by Lowcam itself (:mod:`lowcam.uncompressed_exr`) against the OpenEXR library:
files of random layout written by the OpenEXR binding give the binding's own channels, names, order, pixel types
and bits, and every file outside the common case is left to the library."""
import numpy as np
import OpenEXR
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lowcam.io import exr_render, read_exr_tagged
from lowcam import uncompressed_exr
from lowcam.uncompressed_exr import group_names, read_uncompressed_exr

PREFIXES = ("", "ViewLayer.Combined", "ViewLayer.Vector", "Lowcam Overlay.Combined", "L.Shadow", "p.q", "x")
SUFFIXES = ("R", "G", "B", "A", "X", "Y", "Z", "W", "r", "RY", "BY", "depth")
TYPES = (np.float32, np.float16, np.uint32)


@st.composite
def layouts(draw):
    """(parts, first header's tags, whether some group mixes pixel types): 1-3 parts of random channels, each
    part's pixel types uniform per prefix or (now and then) mixed, random data windows and sizes."""
    names_used, parts, mixed = set(), [], False
    for k in range(draw(st.integers(1, 3))):
        width, height = draw(st.integers(1, 37)), draw(st.integers(1, 23))
        x0, y0 = draw(st.integers(-5, 5)), draw(st.integers(-5, 5))
        prefixes = draw(st.lists(st.sampled_from(PREFIXES), min_size=1, max_size=3, unique=True))
        channels = {}
        for prefix in prefixes:
            suffixes = draw(st.lists(st.sampled_from(SUFFIXES), min_size=1, max_size=6, unique=True))
            if draw(st.booleans()):                  # a colour layer: R, G, B, maybe A, among the others
                suffixes = ["R", "G", "B", *(["A"] if draw(st.booleans()) else []), *suffixes]
            uniform = draw(st.sampled_from(TYPES))
            for suffix in suffixes:
                name = f"{prefix}.{suffix}" if prefix else suffix
                if name in names_used or name in channels:
                    continue
                names_used.add(name)
                dtype = draw(st.sampled_from(TYPES)) if draw(st.integers(0, 9)) == 0 else uniform
                bits = np.random.default_rng(len(names_used)).integers(0, 2 ** 32, (height, width), np.uint32)
                channels[name] = {np.float32: bits.view(np.float32), np.float16: bits.astype(np.uint16).view(
                    np.float16), np.uint32: bits}[dtype]             # every bit pattern: NaNs, infinities
            grouped = [f"{prefix}.{c}" if prefix else c for c in "RGBA"]
            types = {channels[n].dtype for n in grouped if n in channels}
            mixed |= all((f"{prefix}.{c}" if prefix else c) in channels for c in "RGB") and len(types) > 1
        if not channels:
            continue
        header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage,
                  "dataWindow": (np.array([x0, y0], np.int32), np.array([x0 + width - 1, y0 + height - 1], np.int32)),
                  "displayWindow": (np.array([0, 0], np.int32), np.array([31, 19], np.int32))}   # one for every part
        if k == 0 and draw(st.booleans()):
            header["chromaticities"] = (0.708, 0.292, 0.17, 0.797, 0.131, 0.046, 0.3127, 0.329)
            header["colorInteropID"] = "lin_rec2020_scene"
        parts.append((f"part{k}", header, channels))
    return parts, mixed


def _binding(path):
    with OpenEXR.File(str(path)) as f:
        parts = [(p.name(), {n: c.pixels for n, c in p.channels.items()}) for p in f.parts]
        header = f.parts[0].header
        tags = {k: header[k] for k in ("chromaticities", "colorInteropID") if header.get(k) is not None}
    return parts, tags


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(layout=layouts())
def test_mapped_channels_are_the_openexr_bindings_own(tmp_path, monkeypatch, layout):
    """Random uncompressed files, single- and multi-part, written by the OpenEXR binding: mapped, each part's
    channels are the binding's (names in its order, RGB(A) grouped as it groups them, pixel types, shapes and
    every bit, NaNs included) and so are the colour tags; only a group of mixed pixel types, which the binding
    refuses, is left to it. A float32 group read strip by strip holds the same bits."""
    parts, mixed = layout
    if not parts:
        return
    path = tmp_path / "layout.exr"
    if len(parts) == 1:
        OpenEXR.File(parts[0][1], parts[0][2]).write(str(path))
    else:
        OpenEXR.File([OpenEXR.Part(h, c, name) for name, h, c in parts]).write(str(path))
    mapped = read_uncompressed_exr(path)
    if mixed:
        assert mapped is None
        with pytest.raises(ValueError, match="cannot coalesce"):
            _binding(path)
        return
    assert mapped is not None
    expected_parts, expected_tags = _binding(path)
    got_parts, tags = mapped
    assert [name for name, _ in got_parts] == [name if len(parts) > 1 else "" for name, _ in expected_parts]
    for (_, got), (_, expected) in zip(got_parts, expected_parts):
        assert list(got) == list(expected)
        for key, pixels in expected.items():
            assert got[key].dtype == pixels.dtype and got[key].shape == pixels.shape, key
            assert got[key].tobytes() == pixels.tobytes(), key
            # read a line or two at a time instead: the same bits, every strip visited (no line is all zero)
            monkeypatch.setattr(uncompressed_exr, "_STRIP_BYTES", 1 + len(key) * 97)
            depth = pixels.shape[2] if pixels.ndim == 3 else 1
            strips = got.read_in_strips(key, depth, lambda top, lines: (top, len(lines)))
            if pixels.dtype != np.float32:
                assert strips is None
            elif strips is not None:                    # None: lines off float32's 4-byte grid
                assert strips[0].tobytes() == pixels.tobytes(), key
                assert sum(n for _, n in strips[1]) == pixels.shape[0] and strips[1][0][0] == 0
    assert tags == {k: list(v) if k == "chromaticities" else v for k, v in expected_tags.items()}


@pytest.mark.parametrize("codec", ("RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "DWAA"))
def test_compressed_and_tiled_files_are_left_to_the_library(tmp_path, codec):
    rgba = np.random.default_rng(3).uniform(0, 1, (20, 30, 4)).astype(np.float32)
    channels = {c: rgba[..., i].copy() for i, c in enumerate("RGBA")}
    path = tmp_path / f"{codec}.exr"
    OpenEXR.File({"compression": getattr(OpenEXR, f"{codec}_COMPRESSION"), "type": OpenEXR.scanlineimage},
                 channels).write(str(path))
    assert read_uncompressed_exr(path) is None
    tiled = tmp_path / "tiled.exr"
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.tiledimage,
                  "tiles": OpenEXR.TileDescription()}, channels).write(str(tiled))
    assert read_uncompressed_exr(tiled) is None
    assert read_exr_tagged(tiled)[0]["RGBA"].tobytes() == rgba.tobytes()


def test_a_shot_reads_only_the_channels_it_takes(tmp_path):
    """A Blender-shaped render (the view layer's Combined and Vector, the overlay layer): taking the Combined
    layer reads that one group and nothing else; the bits are the binding's."""
    rgba = np.random.default_rng(5).uniform(0, 1, (48, 64, 4)).astype(np.float32)
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    layers = ("ViewLayer.Combined", "ViewLayer.Vector", "Lowcam Overlay.Combined")
    OpenEXR.File([OpenEXR.Part(dict(header), {f"{layer}.{c}": (rgba[..., i] + k).copy()
                                              for i, c in enumerate("XYZW" if "Vector" in layer else "RGBA")},
                               layer) for k, layer in enumerate(layers)]).write(str(tmp_path / "r.exr"))
    taken = []
    parts, _ = read_uncompressed_exr(tmp_path / "r.exr", convert=lambda pixels: taken.append(pixels.shape) or pixels)
    assert [list(channels) for _, channels in parts] == [["ViewLayer.Combined"],
                                                        [f"ViewLayer.Vector.{c}" for c in "WXYZ"],
                                                        ["Lowcam Overlay.Combined"]]
    assert parts[0][1]["ViewLayer.Combined"].tobytes() == rgba.tobytes()
    assert parts[0][1]["ViewLayer.Combined"] is parts[0][1]["ViewLayer.Combined"]   # read once
    assert taken == [(48, 64, 4)]
    assert read_exr_tagged(tmp_path / "r.exr")[0]["Lowcam Overlay.Combined"].tobytes() == (rgba + 2).tobytes()


def test_groups_are_named_as_the_binding_names_them():
    assert group_names(["A", "B", "BY", "G", "R", "p.B", "p.G", "p.R", "p.X"]) == [
        ("RGBA", ["R", "G", "B", "A"]), ("BY", ["BY"]), ("p", ["p.R", "p.G", "p.B"]), ("p.X", ["p.X"])]
    assert group_names(["p.A", "p.G", "p.R"]) == [("p.A", ["p.A"]), ("p.G", ["p.G"]), ("p.R", ["p.R"])]


@pytest.mark.parametrize("change", ("rendered again", "cut short"))
def test_a_render_changed_before_its_channels_are_taken_is_refused_in_one_line(tmp_path, change):
    """The header is read first and a part's bytes when a channel is taken: a file rendered again (replaced) or
    cut short in between is refused naming it, and again when asked again, never read as a mixture of the two.
    (A file cut short during the part's own read, after its size was checked, is refused the same way.)"""
    from lowcam import LowcamError

    rgba = np.random.default_rng(9).uniform(0, 1, (40, 50, 4)).astype(np.float32)
    path = tmp_path / "frame.exr"

    def write(pixels, to):
        OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {c: pixels[..., i].copy() for i, c in enumerate("RGBA")}).write(str(to))

    write(rgba, path)
    channels, _ = read_exr_tagged(path)
    if change == "rendered again":
        write(rgba[::-1], tmp_path / "next.exr")
        (tmp_path / "next.exr").replace(path)
    else:
        path.write_bytes(path.read_bytes()[:-1000])
    assert "RGBA" in channels                # asking does not read
    for take in (lambda: channels["RGBA"], lambda: channels["RGBA"], lambda: exr_render(path, channels, {})):
        with pytest.raises(LowcamError) as e:
            take()                           # the part whole, again, or strip by strip as a shot reads it
        assert str(e.value).startswith(f"{path}: the file changed while it was read") and "\n" not in str(e.value)
    if change == "rendered again":          # read again: the new render
        assert read_exr_tagged(path)[0]["RGBA"].tobytes() == rgba[::-1].tobytes()
    else:                                   # read again: the OpenEXR library's refusal of a truncated file
        with pytest.raises(LowcamError, match="not a readable OpenEXR file"):
            read_exr_tagged(path)[0]["RGBA"]


@pytest.mark.parametrize("channels", [
    {"R": np.float32, "G": np.float32, "B": np.float32, "Z": np.float16},      # lines of 2 bytes past a float's
    {".R": np.float32, "R": np.float32, "G": np.float32, "B": np.float32},      # an empty prefix
    {"p": np.float32, "p.R": np.float32, "p.G": np.float32, "p.B": np.float32},  # a channel named as its group
], ids=["odd line", "empty prefix", "named as its group"])
def test_awkward_layouts_read_as_the_binding_reads_them(tmp_path, channels):
    """A line whose length leaves float samples off their 4-byte grid (an odd width and a half channel), and names
    the binding groups its own way: read_exr_tagged gives the binding's channels and bits, or its refusal."""
    from lowcam import LowcamError

    pixels = {n: np.random.default_rng(1).uniform(0, 1, (6, 3)).astype(t) for n, t in channels.items()}
    path = tmp_path / "awkward.exr"
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}, pixels).write(str(path))
    try:
        with OpenEXR.File(str(path)) as f:
            expected = {n: c.pixels for n, c in f.parts[0].channels.items()}
    except ValueError:                       # "p" beside p.R, p.G, p.B: the binding refuses to group them
        assert read_uncompressed_exr(path) is None
        with pytest.raises(LowcamError, match="not a readable OpenEXR file .*collides"):
            read_exr_tagged(path)
        return
    got, _ = read_exr_tagged(path)
    assert list(got) == list(expected)
    for n, p in expected.items():
        assert got[n].tobytes() == p.astype(np.float32).tobytes(), n     # read_exr_tagged gives float32


def test_a_render_cut_short_while_its_strips_are_read_is_refused_once_every_strip_is_done(tmp_path, monkeypatch):
    """A file cut short after its size was checked, under one strip, while others are still being read: the read
    is refused in one line, and only once every other strip is done, so none writes into an array the shot has
    already given to the next frame."""
    import io
    import time

    from lowcam import LowcamError

    rgba = np.random.default_rng(2).uniform(0, 1, (64, 40, 4)).astype(np.float32)
    path = tmp_path / "frame.exr"
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {c: rgba[..., i].copy() for i, c in enumerate("RGBA")}).write(str(path))
    parts, _ = read_uncompressed_exr(path)
    monkeypatch.setattr(uncompressed_exr, "_STRIP_BYTES", 8 * (8 + 40 * 16))    # eight strips of 8 lines
    calls, done = [], []

    class CutShortOnce(io.FileIO):
        def readinto(self, buffer):
            calls.append(self.tell())
            if len(calls) == 1:
                return 0                                # the file ends here now
            time.sleep(0.05)
            done.append(self.tell())
            return super().readinto(buffer)

    monkeypatch.setattr(uncompressed_exr, "open", lambda path, *args, **kw: CutShortOnce(path), raising=False)
    with pytest.raises(LowcamError) as e:
        parts[0][1].read_in_strips("RGBA", 4, lambda top, lines: top)
    assert str(e.value).startswith(f"{path}: the file was cut short while it was read") and "\n" not in str(e.value)
    assert len(calls) == 8 and len(done) == 7
