"""Video plates read with the stream's own colour tags, frame-accurate (:mod:`lowcam.video`).

The clips are made here with PyAV's own encoders (libx264 lossless, libx265 lossless), their Y'CbCr planes written
directly from colour-science's ``RGB_to_YCbCr`` (an implementation independent of Lowcam's decoder), and tagged as
phones and cameras tag them. The decoded grey and colour patches must come back within 2 DN of the sRGB values
the clip was made from. OpenCV's reader, which decodes every clip with BT.601's matrix, misses the BT.709 and
BT.2020 ones by 15-23 DN: the construction tells a right reader from a wrong one.

The long-GOP clip (libx264, CRF 18, key frame every 48 frames, 3 B-frames) codes each frame's index in its
picture (8 black or white blocks), so a frame read by seeking shows whether it is its own.
"""
import concurrent.futures
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

import av
import colour
import cv2
import numpy as np
import pytest

from lowcam import video as lv
from lowcam.errors import LowcamError, ProfileError
from lowcam.video import VideoReader, read_video_frame

DATA = Path(os.environ.get("LOWCAM_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")

#: The sRGB values the clips are made of: a flat grey frame with four colour patches.
PATCHES = {"red": (200, 40, 40), "green": (40, 180, 60), "blue": (50, 60, 190), "yellow": (220, 200, 50)}
GREY = (128, 128, 128)
W, H = 160, 96
WEIGHTS = {"bt601": colour.WEIGHTS_YCBCR["ITU-R BT.601"], "bt709": colour.WEIGHTS_YCBCR["ITU-R BT.709"],
           "bt2020": colour.WEIGHTS_YCBCR["ITU-R BT.2020"]}
#: H.273 code points: MatrixCoefficients, ColourPrimaries.
MATRIX_TAG = {"bt601": 6, "bt709": 1, "bt2020": 9}
PRIMARIES_TAG = {"bt601": 6, "bt709": 1, "bt2020": 9}
#: H.273 TransferCharacteristics: BT.709, BT.2020 10-bit, HLG, PQ, linear.
TRC = {"sdr": 1, "sdr10": 14, "hlg": 18, "pq": 16, "linear": 8}


def _patch_box(k):
    return slice(32, 64), slice(8 + 38 * k, 40 + 38 * k)


def _picture():
    img = np.empty((H, W, 3), np.uint8)
    img[:] = GREY
    for k, rgb in enumerate(PATCHES.values()):
        img[_patch_box(k)] = rgb
    return img


def _write(path, planes_per_frame, codec, pix, matrix_tag, range_tag, trc_tag, primaries_tag=1, options=None,
           rate=24, display_degrees=None):
    """A clip of the given Y'CbCr planes (one (Y, Cb, Cr) tuple per frame) with these tags; ``display_degrees``:
    a display matrix turning the picture that many degrees counter-clockwise (FFmpeg's, as phones write it)."""
    with av.open(str(path), "w") as out:
        s = out.add_stream(codec, rate=rate)
        s.width, s.height, s.pix_fmt = planes_per_frame[0][0].shape[1], planes_per_frame[0][0].shape[0], pix
        if display_degrees is not None:
            s.set_display_rotation(display_degrees)
        cc = s.codec_context
        cc.colorspace, cc.color_range, cc.color_trc, cc.color_primaries = matrix_tag, range_tag, trc_tag, primaries_tag
        s.options = options or ({"qp": "0"} if codec == "libx264" else {"x265-params": "lossless=1:log-level=error"})
        for i, planes in enumerate(planes_per_frame):
            f = av.VideoFrame(s.width, s.height, pix)
            for plane, a in zip(f.planes, planes):
                buf = np.zeros((plane.height, plane.line_size // a.itemsize), a.dtype)
                buf[:, :a.shape[1]] = a
                plane.update(buf.tobytes())
            f.colorspace, f.color_range, f.pts = matrix_tag, range_tag, i
            for packet in s.encode(f):
                out.mux(packet)
        for packet in s.encode():
            out.mux(packet)
    return path


def _ycbcr(img, matrix, limited, bits):
    """colour-science's Y'CbCr integer code values of an sRGB-coded uint8 picture, 4:2:0 planes (the picture's
    2x2 blocks are flat, so the chroma of each block is its own)."""
    ycc = colour.RGB_to_YCbCr(img / 255.0, K=WEIGHTS[matrix], out_bits=bits, out_legal=limited, out_int=True)
    dtype = np.uint8 if bits == 8 else np.dtype("<u2")
    return ycc[..., 0].astype(dtype), ycc[::2, ::2, 1].astype(dtype), ycc[::2, ::2, 2].astype(dtype)


def _tagged_clip(folder, matrix, rng, bits, transfer="sdr"):
    codec, pix = ("libx264", "yuv420p") if bits == 8 else ("libx265", "yuv420p10le")
    planes = _ycbcr(_picture(), matrix, rng == "limited", bits)
    path = folder / f"{matrix}-{rng}-{bits}bit-{transfer}.mkv"
    return _write(path, [planes] * 3, codec, pix, MATRIX_TAG[matrix], 1 if rng == "limited" else 2, TRC[transfer],
                  PRIMARIES_TAG[matrix])


def _upright_clip(folder, degrees, square=False):
    """The BT.709 colour patches as an MP4 whose display matrix turns them ``degrees`` counter-clockwise (None:
    no display matrix); ``square``: their left H x H px only."""
    planes = _ycbcr(_picture()[:, :H] if square else _picture(), "bt709", True, 8)
    return _write(folder / f"turned-{degrees}{'-square' if square else ''}.mp4", [planes] * 2, "libx264", "yuv420p", 1, 1, 1, 1,
                  display_degrees=degrees)


def _patch_errors(rgb):
    """The largest |decoded - known| (DN) over the grey and each colour patch's inner pixels."""
    errors = {"grey": np.abs(rgb[4:28, 4:-4].astype(int) - GREY).max()}
    for k, (name, value) in enumerate(PATCHES.items()):
        ys, xs = _patch_box(k)
        inner = rgb[ys.start + 2:ys.stop - 2, xs.start + 2:xs.stop - 2].astype(int)
        errors[name] = np.abs(inner - value).max()
    return errors


@pytest.mark.parametrize("bits", (8, 10))
@pytest.mark.parametrize("rng", ("limited", "full"))
@pytest.mark.parametrize("matrix", ("bt601", "bt709", "bt2020"))
def test_a_tagged_clip_decodes_to_its_known_colours(tmp_path, matrix, rng, bits):
    clip = _tagged_clip(tmp_path, matrix, rng, bits, "sdr10" if bits == 10 else "sdr")
    with VideoReader(clip) as video:
        assert (video.colour.matrix, video.colour.range, video.colour.transfer) == (matrix, rng, "sdr")
        assert video.count == 3
        errors = _patch_errors(video.frame(1))
    assert max(errors.values()) <= 2, errors


def test_opencv_reads_a_bt709_clip_with_bt601s_matrix(tmp_path):
    """The clip that the reader above gets right is 20 DN off through OpenCV's VideoCapture: the construction
    tells one matrix from another."""
    clip = _tagged_clip(tmp_path, "bt709", "limited", 8)
    cap = cv2.VideoCapture(str(clip))
    ok, bgr = cap.read()
    cap.release()
    assert ok
    errors = _patch_errors(bgr[..., ::-1])
    assert errors["red"] >= 15 and errors["green"] >= 15
    assert max(_patch_errors(read_video_frame(clip, 0)).values()) <= 2


def test_the_override_reads_a_clip_whose_tags_lie(tmp_path):
    """A BT.709 picture tagged BT.601: wrong by its tags, right with ``--plate-colour bt709,limited``."""
    planes = _ycbcr(_picture(), "bt709", True, 8)
    clip = _write(tmp_path / "lies.mp4", [planes] * 2, "libx264", "yuv420p", MATRIX_TAG["bt601"], 1, 1)
    with VideoReader(clip) as video:
        assert max(_patch_errors(video.frame(0)).values()) > 10
    with VideoReader(clip, "bt709,limited") as video:
        assert video.colour.matrix == "bt709" and "plate-colour" in video.colour.source
        assert max(_patch_errors(video.frame(0)).values()) <= 2
    full = _write(tmp_path / "full-untagged-range.mp4", [_ycbcr(_picture(), "bt709", False, 8)] * 2, "libx264",
                  "yuv420p", 1, 0, 1)          # full-range values with no range tag: read as limited
    assert max(_patch_errors(read_video_frame(full, 0, "full")).values()) <= 2


def test_an_untagged_hd_clip_is_read_as_bt709_and_an_sd_one_as_bt601(tmp_path):
    hd = np.zeros((64, 1040, 3), np.uint8)     # wider than 1024 px: HD
    hd[:] = GREY
    hd[:, :520] = PATCHES["red"]
    clip = _write(tmp_path / "hd.mp4", [_ycbcr(hd, "bt709", True, 8)], "libx264", "yuv420p", 2, 0, 2, 2)
    with VideoReader(clip) as video:
        assert video.colour.matrix == "bt709"
        assert np.abs(video.frame(0)[32, 260].astype(int) - PATCHES["red"]).max() <= 2
    sd = _write(tmp_path / "sd.mp4", [_ycbcr(_picture(), "bt601", True, 8)], "libx264", "yuv420p", 2, 0, 2, 2)
    assert max(_patch_errors(read_video_frame(sd, 0)).values()) <= 2


@pytest.mark.parametrize("transfer, name", (("hlg", "HLG"), ("pq", "PQ")))
def test_an_hdr_clip_is_refused_in_one_line_naming_its_transfer(tmp_path, transfer, name):
    clip = _tagged_clip(tmp_path, "bt2020", "limited", 10, transfer)
    with pytest.raises(LowcamError) as e:
        VideoReader(clip)
    assert str(clip) in str(e.value) and name in str(e.value) and "\n" not in str(e.value)
    with VideoReader(clip, "sdr") as video:   # the user takes its code values as SDR
        assert max(_patch_errors(video.frame(0)).values()) <= 2


@pytest.mark.parametrize("field, tag, words", (("matrix", 7, "matrix tag 7"), ("transfer", 8, "transfer tag 8")))
def test_an_unknown_matrix_or_transfer_tag_is_refused(tmp_path, field, tag, words):
    planes = _ycbcr(_picture(), "bt709", True, 8)
    matrix, trc = (tag, 1) if field == "matrix" else (1, tag)
    clip = _write(tmp_path / "odd.mp4", [planes], "libx264", "yuv420p", matrix, 1, trc)
    with pytest.raises(LowcamError, match=rf"odd\.mp4: {words} .*--plate-colour"):
        VideoReader(clip)
    fix = "bt709,limited" if field == "matrix" else "sdr"
    assert max(_patch_errors(read_video_frame(clip, 0, fix)).values()) <= 2


def test_bad_files_are_refused_in_one_line(tmp_path):
    (tmp_path / "noise.mp4").write_bytes(np.random.default_rng(0).bytes(5000))
    with av.open(str(tmp_path / "sound.mkv"), "w") as out:     # a file with a sound stream and no video
        s = out.add_stream("pcm_s16le", rate=8000)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 800), np.int16), format="s16", layout="mono")
        frame.sample_rate, frame.pts = 8000, 0
        for packet in [*s.encode(frame), *s.encode()]:
            out.mux(packet)
    for name, words in (("noise.mp4", "not a video FFmpeg can read"), ("sound.mkv", "holds no video stream"),
                        ("missing.mp4", "no such file")):
        with pytest.raises(LowcamError) as e:
            read_video_frame(tmp_path / name, 0)
        assert str(e.value).startswith(str(tmp_path / name)) and words in str(e.value) and "\n" not in str(e.value)
    for text, words in (("bt709,hd", "'hd' is none of"), ("bt709,bt601", "two values for the matrix")):
        with pytest.raises(LowcamError, match=words):
            lv.parse_plate_colour(text)


# --- seeking --------------------------------------------------------------------------------------------------------

GOP_FRAMES = 120
BLOCK = 16


def _indexed_picture(i, width, height, rng):
    """A textured frame moving 3 px a frame, with ``i`` coded in 8 blocks of BLOCK px (white: bit set)."""
    y = cv2.GaussianBlur(rng.integers(40, 200, (height, width + 3 * GOP_FRAMES)).astype(np.float32), (0, 0), 2)
    y = y[:, 3 * i:3 * i + width].astype(np.uint8)
    for bit in range(8):
        y[:BLOCK, bit * BLOCK:(bit + 1) * BLOCK] = 235 if (i >> bit) & 1 else 16
    return y


def _long_gop_clip(path, width=192, height=112, frames=GOP_FRAMES):
    ys = [_indexed_picture(i, width, height, np.random.default_rng(7)) for i in range(frames)]
    chroma = np.full((height // 2, width // 2), 128, np.uint8)
    return _write(path, [(y, chroma, chroma) for y in ys], "libx264", "yuv420p", 1, 1, 1,
                  options={"crf": "18", "g": "48", "bf": "3", "x264-params": "keyint=48:min-keyint=48:bframes=3:"
                                                                            "b-adapt=0:scenecut=0"})


def _index_in(rgb) -> int:
    luma = rgb[:BLOCK, :8 * BLOCK].astype(np.float32).mean(axis=-1)
    bits = [luma[2:-2, b * BLOCK + 2:(b + 1) * BLOCK - 2].mean() > 128 for b in range(8)]
    return sum(1 << b for b, on in enumerate(bits) if on)


def _read_in_order(path, order):
    with VideoReader(path) as video:
        return [(i, _index_in(video.frame(i)), video.frame(i).tobytes()) for i in order]


@pytest.fixture(scope="module")
def long_gop(tmp_path_factory):
    path = _long_gop_clip(tmp_path_factory.mktemp("gop") / "long-gop.mp4")
    with VideoReader(path) as video:
        sequential = [rgb for _, rgb in video.frames()]
        types = "".join(video.pict_types[i] for i in range(len(sequential)))
    return path, sequential, types


def test_the_long_gop_clip_has_b_frames_and_every_frame_its_own_index(long_gop):
    path, sequential, types = long_gop
    assert len(sequential) == GOP_FRAMES and "B" in types and types.count("I") == GOP_FRAMES // 48 + 1
    assert [_index_in(f) for f in sequential] == list(range(GOP_FRAMES))


def test_frames_read_by_seeking_on_two_processes_are_each_their_own(long_gop):
    """Random orders (seeded), so most reads seek into a group of pictures with B-frames; two worker processes,
    each with its own reader, as Dask workers have."""
    path, sequential, _ = long_gop
    rng = np.random.default_rng(37)
    orders = [list(rng.permutation(GOP_FRAMES)[:40]), list(rng.permutation(GOP_FRAMES)[:40])]
    # spawned, not forked: a fork of this threaded process may inherit a lock another thread holds
    with concurrent.futures.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = list(pool.map(_read_in_order, [path, path], orders))
    for order, result in zip(orders, results):
        for i, index, data in result:
            assert index == i
            assert data == sequential[i].tobytes()    # the same bytes as reading from the start


def test_a_far_jump_back_and_forward_reads_the_right_frame(long_gop):
    path, sequential, _ = long_gop
    lv.close_videos()
    for i in (100, 3, 99, 50, 51, 47, 48, 119, 0):
        assert np.array_equal(read_video_frame(path, i), sequential[i])
    with pytest.raises(LowcamError, match=r"has 120 frames, frame 120 \(0-based\) does not exist"):
        read_video_frame(path, 120)
    lv.close_videos()


def test_the_bitstream_tells_codec_gop_and_rate(long_gop):
    from lowcam.measure.plate import read_footage

    path, _, _ = long_gop
    facts = read_footage(path).video
    assert facts["codec"] == "h264" and facts["codec_profile"] == "High"
    assert facts["gop_length"] == 48 and facts["key_frames"] == 3
    assert facts["b_frames"] and facts["max_consecutive_b_frames"] == 3
    assert facts["gop_frame_types"].startswith("I") and facts["gop_frame_types"].count("B") >= 30
    assert facts["encoder"].startswith("x264") and facts["encoder_crf"] == "18.0"
    size = sum(p.size for p in av.open(str(path)).demux() if p.size)
    assert abs(facts["bitrate_bps"] - 8 * size / (GOP_FRAMES / 24)) < 0.01 * facts["bitrate_bps"]
    assert facts["colour"] == "bt709,limited,sdr"


def test_the_shared_opencv_videos_still_read():
    """MPEG-4 (MS v3) and Cinepak, the old codecs of the shared data: the same frame count as before, and
    vtest.avi (untagged SD: BT.601) within 2 DN of OpenCV's decode on average."""
    vtest = DATA / "opencv-video" / "vtest.avi"
    if not vtest.is_file():
        pytest.skip("the shared data is not beside the repository")
    with VideoReader(vtest) as video:
        assert video.count == 795 and video.colour.matrix == "bt601" and video.fps == 10
        ours = video.frame(400).astype(int)
    cap = cv2.VideoCapture(str(vtest))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 400)
    ok, bgr = cap.read()
    cap.release()
    assert ok and np.abs(ours - bgr[..., ::-1]).mean() < 2
    with VideoReader(DATA / "opencv-video" / "tree.avi") as video:   # 376 of its 444 chunks are empty
        assert video.count == 68 and video.colour.matrix == "rgb"
        assert video.frame(67).shape == (240, 320, 3)


def test_a_profile_keeps_the_video_table_and_refuses_a_bad_one(tmp_path):
    from lowcam.profile import load_profile

    p = load_profile("fire-i").copy()
    p.video = {"codec": "h264", "gop_length": 48, "b_frames": True}
    p.provenance["video"] = "the bitstream of clip.mp4"
    back = load_profile(p.save(tmp_path / "p.toml"))
    assert back.video == p.video and back.provenance["video"] == "the bitstream of clip.mp4"
    text = (tmp_path / "p.toml").read_text().replace("gop_length = 48", "gop_length = [1, 2]")
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ProfileError, match=r"bad\.toml: \[video\] 'gop_length'"):
        load_profile(tmp_path / "bad.toml")


@pytest.mark.slow
def test_a_shot_on_two_dask_workers_gets_every_frame_of_a_long_gop_clip(tmp_path):
    """``lowcam batch`` with a long-GOP, B-frame H.264 plate on two Dask workers: transparent renders, so each
    output is its plate frame; every one shows its own index and the bytes of the frame read in order."""
    from lowcam.batch import Shot, run_shot
    from lowcam.outputs import write_exr

    frames = 60
    clip = _long_gop_clip(tmp_path / "plate.mp4", 640, 480, frames)
    with VideoReader(clip) as video:
        sequential = [rgb for _, rgb in video.frames()]
    for f in range(1, frames + 1):
        write_exr(tmp_path / "renders" / f"{f:04d}.exr", np.zeros((150, 200, 4), np.float32))
    shot = Shot("fire-i", str(tmp_path / "renders" / "####.exr"), str(tmp_path / "out" / "####.png"), str(clip))
    order = [int(f) for f in np.random.default_rng(5).permutation(np.arange(1, frames + 1))]
    results = run_shot(shot, order, workers=2, quiet=True)
    assert [r.status for r in results] == ["written"] * frames
    for f in range(1, frames + 1):
        out = cv2.cvtColor(cv2.imread(str(tmp_path / "out" / f"{f:04d}.png")), cv2.COLOR_BGR2RGB)
        assert _index_in(out) == f - 1 and np.array_equal(out, sequential[f - 1])


@pytest.mark.parametrize("degrees", (90, 180, 270))
def test_an_upright_phone_clip_is_turned_as_its_display_matrix_says(tmp_path, degrees):
    """A phone held upright records its sensor's landscape frames and a display matrix that turns them: each
    frame comes out turned (``degrees`` counter-clockwise: numpy's ``rot90`` that many quarter turns), its size
    the shown one, and the ``[video]`` facts say so."""
    plain = read_video_frame(_upright_clip(tmp_path, None), 0)
    clip = _upright_clip(tmp_path, degrees)
    with VideoReader(clip) as video:
        shown = video.frame(1)
        assert (video.width, video.height) == ((H, W) if degrees % 180 else (W, H))
        assert lv.stream_facts(video)["display_turned_deg"] == degrees
    assert np.array_equal(shown, np.rot90(plain, degrees // 90))
    assert np.array_equal(read_video_frame(clip, 1, turned=False), plain)   # as coded, where asked (Blender 4.2)
    assert shown.shape[:2] == (video.height, video.width)
    assert max(_patch_errors(np.rot90(shown, -(degrees // 90))).values()) <= 2   # turned back: the known colours


def test_a_display_matrix_at_an_odd_angle_is_refused_in_one_line(tmp_path):
    clip = _upright_clip(tmp_path, 45)
    with pytest.raises(LowcamError) as e:
        read_video_frame(clip, 0)
    assert str(clip) in str(e.value) and "45 degrees" in str(e.value) and "\n" not in str(e.value)


def test_super_white_and_super_black_saturate_not_wrap(tmp_path):
    """Limited-range codes beyond nominal white (Y' 940 of 1023) and black come out 255 and 0, not wrapped."""
    y = np.full((H, W), 1019, np.dtype("<u2"))
    y[:, :W // 2] = 4
    c = np.full((H // 2, W // 2), 512, np.dtype("<u2"))
    clip = _write(tmp_path / "super.mkv", [(y, c, c)], "libx265", "yuv420p10le", 1, 1, 14)
    rgb = read_video_frame(clip, 0)
    assert (rgb[:, W // 2 + 4:] == 255).all() and (rgb[:, :W // 2 - 4] == 0).all()


@pytest.mark.blender
@pytest.mark.parametrize("matrix, rng, bits", (("bt709", "limited", 8), ("bt601", "full", 8),
                                               ("bt2020", "limited", 10)))
def test_blenders_movie_clip_decode_agrees_with_the_add_ons_plate(tmp_path, matrix, rng, bits):
    """Blender decodes a movie with its own FFmpeg; the add-on's plate (this reader) and Blender's pixels of the
    same clip agree within 1 DN everywhere, colour edges included (each chroma sample over its 2x2 luma samples
    both ways), from Blender 4.5. Blender 4.2 rounds up to 2 DN apart, and on the 10-bit clip spreads chroma along
    colour edges (up to 92 DN there): within 2 DN where the plate is flat over 5x5 pixels, and on 8 bits
    everywhere."""
    import bpy

    clip = _tagged_clip(tmp_path, matrix, rng, bits, "sdr10" if bits == 10 else "sdr")
    image = bpy.data.images.load(str(clip))
    try:
        image.colorspace_settings.name = "Non-Color"            # the code values, no view transform
        assert image.source == "MOVIE"
        w, h = image.size
        blender = np.rint(np.array(image.pixels[:]).reshape(h, w, 4)[::-1, :, :3] * 255).astype(int)
    finally:
        bpy.data.images.remove(image)
    ours = read_video_frame(clip, 0).astype(int)
    diff = np.abs(blender - ours).max(axis=2)
    if bpy.app.version >= (4, 5, 0):
        assert diff.max() <= 1
        return
    flat = np.all([cv2.erode(c, np.ones((5, 5), np.uint8)) == cv2.dilate(c, np.ones((5, 5), np.uint8))
                   for c in np.moveaxis(ours.astype(np.uint8), 2, 0)], axis=0)
    assert diff[flat].max() <= 2 and (bits == 10 or diff.max() <= 2)


@pytest.mark.blender
@pytest.mark.parametrize("degrees, square", [(None, False), (270, False), (90, True)])
def test_the_add_ons_plate_of_an_upright_clip_is_turned_as_blender_shows_it(tmp_path, degrees, square):
    """Blender 4.5 and 5.0 show a phone's upright clip turned as its display matrix says, Blender 4.2 as coded:
    the add-on reads the plate as this Blender shows it (``turned_as_blender_shows``), the same size and pixels
    within 1 DN (4.2: 2 DN, its rounding). A clip without a display matrix is read as coded everywhere. A square
    clip's size cannot tell whether Blender turned it: its pixels do."""
    import bpy
    from lowcam_blender import submodule

    clip = _upright_clip(tmp_path, degrees, square)
    movie = bpy.data.movieclips.load(str(clip))
    image = bpy.data.images.load(str(clip))
    try:
        image.colorspace_settings.name = "Non-Color"
        w, h = image.size
        blender = np.rint(np.array(image.pixels[:]).reshape(h, w, 4)[::-1, :, :3] * 255).astype(int)
        turned = submodule("addon.frames").turned_as_blender_shows(movie, str(clip))
    finally:
        bpy.data.images.remove(image)
        bpy.data.movieclips.remove(movie)
    if degrees is not None:
        assert turned == (bpy.app.version >= (4, 5, 0))
    ours = read_video_frame(clip, 0, turned=turned).astype(int)
    width = H if square else W
    assert blender.shape == ours.shape == ((width, H, 3) if turned and degrees else (H, width, 3))
    assert np.abs(blender - ours).max() <= (1 if bpy.app.version >= (4, 5, 0) else 2)   # 4.2 rounds otherwise


# --- a shot written as a video --------------------------------------------------------------------------------------

def _indexed_colour_clip(path, frames=6):
    """A 640x480 (the Fire-i's frame) BT.709 limited-range H.264 clip, CRF 18, GOP 4 with 2 B-frames: the
    colour patches, and the frame index in 8 blocks."""
    planes = []
    for i in range(frames):
        img = cv2.resize(_picture(), (640, 480), interpolation=cv2.INTER_NEAREST)
        for bit in range(8):
            img[:BLOCK, bit * BLOCK:(bit + 1) * BLOCK] = 235 if (i >> bit) & 1 else 16
        planes.append(_ycbcr(img, "bt709", True, 8))
    return _write(path, planes, "libx264", "yuv420p", 1, 1, 1,
                  options={"crf": "18", "x264-params": "keyint=4:min-keyint=4:bframes=2:b-adapt=0:scenecut=0"})


def test_batch_writes_a_shot_as_a_video_coded_and_tagged_as_its_plate_and_resumes(tmp_path, capsys):
    from lowcam.cli import main
    from lowcam.outputs import write_exr

    plate = _indexed_colour_clip(tmp_path / "plate.mp4")
    for f in range(1, 7):                                       # transparent renders: the output is the plate
        write_exr(tmp_path / "renders" / f"{f:04d}.exr", np.zeros((150, 200, 4), np.float32))
    shot = tmp_path / "out" / "shot.mp4"
    args = ["batch", "--renders", str(tmp_path / "renders" / "####.exr"), "--plates", str(plate), "--frames", "1-6",
            "-o", str(shot), "--quiet"]
    assert main(args) == 0
    assert "coded by libx264 (CRF 18, GOP 4, 2 B-frames, bt709 limited)" in capsys.readouterr().out
    with VideoReader(shot) as ours, VideoReader(plate) as theirs:
        assert (ours.colour.matrix, ours.colour.range, ours.count, ours.fps) == ("bt709", "limited", 6, 24)
        for i in range(6):
            out, src = ours.frame(i), theirs.frame(i)
            assert _index_in(out) == i
            assert np.abs(out.astype(int) - src).mean() < 1.5
            for k, value in enumerate(PATCHES.values()):            # the patches, scaled 4x across, 5x down
                centre = out[230:250, (24 + 38 * k) * 4 - 10:(24 + 38 * k) * 4 + 10].astype(int)
                assert np.abs(centre - value).max() <= 3
        facts = stream_facts_of(ours)
    assert facts["codec"] == "h264" and facts["gop_length"] == 4 and facts["max_consecutive_b_frames"] == 2
    # resumable as image sequences: a frame lost and the video gone, a rerun makes that frame alone
    (tmp_path / "out" / "shot.mp4.frames" / "000003.png").unlink()
    shot.unlink()
    assert main(args) == 0
    assert "1 written, 5 already done" in capsys.readouterr().out and shot.is_file()
    assert [n for n in os.listdir(tmp_path / "out") if n != "shot.mp4.frames"] == ["shot.mp4"]   # no temporaries
    # run again by a process that decodes no plate frame (every frame is done): the same coding, the same bytes;
    # a killed run's temporary beside the video goes
    from lowcam.outputs import _part_prefix

    made = shot.read_bytes()
    lv.close_videos()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / "out" / (_part_prefix().rsplit("-", 2)[0] + f"-{int(dead.stdout)}-ab12.shot.mp4.part")
    stale.write_bytes(b"half a video")
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "0 written, 6 already done" in out and "GOP 4, 2 B-frames" in out and shot.read_bytes() == made
    assert not stale.exists()
    # a file there that is no frame of this shot (another picture, no image) is not taken for a finished frame
    frames = tmp_path / "out" / "shot.mp4.frames"
    cv2.imwrite(str(frames / "000002.png"), np.zeros((240, 320, 3), np.uint8))
    (frames / "000004.png").write_text("notes")
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "000002.png: there already, but 320x240 where this camera's frames are 640x480" in err
    assert "000004.png: there already, but no image" in err and shot.read_bytes() == made


def stream_facts_of(video):
    for _ in video.frames():
        pass
    return lv.stream_facts(video)


def test_a_video_output_that_is_the_plate_is_refused_and_nothing_written(tmp_path, capsys):
    from lowcam.cli import main

    plate = _indexed_colour_clip(tmp_path / "plate.mp4", 2)
    before = plate.read_bytes()
    rc = main(["batch", "--renders", str(tmp_path / "r" / "####.exr"), "--plates", str(plate), "--frames", "1-2",
               "-o", str(plate), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "the output is the input" in err and len(err.strip().splitlines()) == 1
    assert plate.read_bytes() == before and not (tmp_path / "plate.mp4.frames").exists()


def test_a_shot_over_image_plates_is_coded_as_the_default_h264(tmp_path, capsys):
    from lowcam.cli import main
    from lowcam.outputs import write_exr, write_png

    for f in (1, 2):
        write_exr(tmp_path / "renders" / f"{f:04d}.exr", np.zeros((150, 200, 4), np.float32))
        write_png(tmp_path / "plates" / f"{f:04d}.png", cv2.resize(_picture(), (640, 480),
                                                                   interpolation=cv2.INTER_NEAREST))
    shot = tmp_path / "shot.mkv"
    assert main(["batch", "--renders", str(tmp_path / "renders" / "####.exr"), "--plates",
                 str(tmp_path / "plates" / "####.png"), "--frames", "1-2", "-o", str(shot), "--quiet"]) == 0
    assert "Lowcam's default" in capsys.readouterr().out
    with VideoReader(shot) as video:
        assert (video.colour.matrix, video.colour.range, video.count) == ("bt709", "limited", 2)
        red = video.frame(1)[230:250, 86:106].astype(int)
        assert np.abs(red - PATCHES["red"]).max() <= 3


def test_batch_over_an_hdr_plate_is_refused_in_one_line_and_writes_nothing(tmp_path, capsys):
    from lowcam.cli import main

    clip = _tagged_clip(tmp_path, "bt2020", "limited", 10, "hlg")
    rc = main(["batch", "--renders", str(tmp_path / "r" / "####.exr"), "--plates", str(clip), "--frames", "1-2",
               "-o", str(tmp_path / "out" / "####.png"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "HLG" in err and clip.name in err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_calibrate_plate_writes_the_clips_coding_into_the_profile_with_provenance(tmp_path, capsys):
    """A noisy ramp (as tests/test_plate.py films it) coded losslessly as BT.709 H.264 4:4:4: the estimated
    profile's [video] table holds what the bitstream says, with its provenance; the noise is still estimated."""
    from test_plate import W as PW, H as PH, _noisy, _profile

    from lowcam.cli import main
    from lowcam.profile import load_profile

    rng = np.random.default_rng(7)
    ramp = np.linspace(30, 200, PW)[None, :, None] * np.ones((PH, 1, 3))
    planes = []
    for _ in range(5):
        rgb = np.round(_noisy(ramp, ((1.0, 0.01),) * 3, rng)) / 255.0
        ycc = colour.RGB_to_YCbCr(rgb, K=WEIGHTS["bt709"], out_bits=8, out_legal=True, out_int=True).astype(np.uint8)
        planes.append((ycc[..., 0], ycc[..., 1], ycc[..., 2]))
    clip = _write(tmp_path / "ramp.mp4", planes, "libx264", "yuv444p", 1, 1, 1, options={"qp": "0", "x264-params": "keyint=2:min-keyint=2:scenecut=0"})
    base = tmp_path / "base.toml"
    _profile().save(base)
    out = tmp_path / "mycam.toml"
    assert main(["calibrate", "plate", str(clip), "--base", str(base), "-o", str(out)]) == 0
    assert "(h264 High 4:4:4 Predictive, bt709,limited,sdr)" in capsys.readouterr().out
    profile = load_profile(out)
    assert profile.video["codec"] == "h264" and profile.video["frames"] == 5 and profile.video["gop_length"] == 2
    assert profile.video["colour"] == "bt709,limited,sdr" and profile.video["encoder_rc"] == "cqp"
    assert profile.provenance["video"].startswith(f"the bitstream of {clip}")
    assert "noise.red" in profile.provenance
    with pytest.raises(LowcamError, match="only a video has colour tags"):   # an override for frames: refused
        from lowcam.calibrate.plate import calibrate_plate
        calibrate_plate(tmp_path / "nothing", _profile(), plate_colour="bt709")
