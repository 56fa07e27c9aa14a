"""JPEG with an encoder's own quantisation tables, against real codecs:
the engine's numpy coding path against Pillow's libjpeg and OpenCV's, and the tables read off decoded frames
against the tables Pillow wrote."""
import io

import numpy as np
import pytest

import lowcam
from lowcam.effects.jpeg import ijg_quality, jpeg_roundtrip, jpeg_roundtrip_tables, read_tables, standard_tables
from lowcam.errors import ProfileError
from lowcam.measure.synth import scenes

PIL = pytest.importorskip("PIL")


def pillow(frame, **options):
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, "JPEG", **options)
    image = Image.open(io.BytesIO(buf.getvalue()))
    return np.asarray(image.convert("RGB")), image.quantization


@pytest.fixture(scope="module")
def frames(fire_i):
    every = scenes(fire_i)
    return {name: [lowcam.simulate(every[name][0], fire_i, None, seed=41, frame=k) for k in range(4)]
            for name in ("photo", "noise-field")}


@pytest.mark.parametrize("preset", ["web_low", "web_medium", "web_high"])
def test_tables_coding_matches_pillow_with_its_own_tables(frames, preset):
    for frame in frames.values():
        decoded, tables = pillow(frame[0], quality=preset)
        ours = jpeg_roundtrip_tables(frame[0], tables[0], tables[1], "4:2:0" if preset != "web_high" else "4:4:4")
        diff = ours.astype(float) - decoded
        assert (diff == 0).mean() > 0.75 and np.sqrt((diff ** 2).mean()) < 1.0, (preset, (diff == 0).mean())
        # the coding itself is far larger than the difference
        assert np.sqrt(((decoded.astype(float) - frame[0]) ** 2).mean()) > 3.0


def test_tables_coding_matches_opencv_at_the_standard_tables(frames):
    frame = frames["photo"][0]
    for quality, subsampling in ((40, "4:2:0"), (75, "4:2:2"), (90, "4:4:4")):
        diff = jpeg_roundtrip_tables(frame, *standard_tables(quality), subsampling).astype(float) - \
            jpeg_roundtrip(frame, quality, subsampling)
        assert (diff == 0).mean() > 0.75 and np.sqrt((diff ** 2).mean()) < 1.0, (quality, (diff == 0).mean())


def test_standard_tables_are_the_ones_pillow_writes_at_an_ijg_quality(frames):
    for quality in (10, 50, 85):
        _, tables = pillow(frames["photo"][0], quality=quality)
        assert standard_tables(quality) == (list(tables[0]), list(tables[1]))


@pytest.mark.parametrize("preset", ["web_low", "web_medium"])
def test_tables_read_off_decoded_frames_are_the_encoders(frames, preset):
    """Every step the frames show is the encoder's, exactly (the lowest frequencies always, 25-50 % of all), and
    they are no IJG quality's."""
    decoded, tables = zip(*(pillow(f, quality=preset) for f in frames["noise-field"]))
    luma, chroma = read_tables(np.stack(decoded), "4:2:0")
    for steps, true in ((luma, tables[0][0]), (chroma, tables[0][1])):
        found = np.reshape([0 if x is None else x for x in steps], (8, 8))
        true = np.reshape(true, (8, 8))
        assert np.array_equal(found[:3, :3], true[:3, :3]), found
        assert np.mean(found[found > 0] == true[found > 0]) >= 0.95, found - true  # a near-tie may miss by 1
    assert 0.25 <= sum(x is not None for x in luma + chroma) / 128 <= 0.5
    assert ijg_quality(luma) is None


@pytest.mark.parametrize("quality", [30, 60, 85])
def test_an_ijg_quality_is_told_from_the_steps_read(frames, quality):
    decoded = [pillow(f, quality=quality)[0] for f in frames["noise-field"]]
    luma, chroma = read_tables(np.stack(decoded), "4:2:0")
    assert standard_tables(ijg_quality(luma, near=50))[0] == standard_tables(quality)[0]
    # the chroma's steps, read through its upsampling undone, may miss by one
    assert all(x is None or abs(x - t) <= 0.04 * t for x, t in zip(chroma, standard_tables(quality)[1]))


def test_tables_are_checked_in_the_profile(fire_i):
    with pytest.raises(ProfileError, match="64 steps each"):
        fire_i.with_effect("jpeg", luma_table=[16] * 63)
    with pytest.raises(ProfileError, match="'chroma_table' needs 'luma_table'"):
        fire_i.with_effect("jpeg", chroma_table=[16] * 64)
    with pytest.raises(ProfileError, match="luma_table"):
        fire_i.with_effect("jpeg", luma_table=[0] * 64)
    tables = fire_i.with_effect("jpeg", subsampling="4:2:0", luma_table=standard_tables(60)[0],
                                chroma_table=standard_tables(60)[1])
    render = np.zeros((450, 600, 4), np.float32)
    render[100:300, 200:400] = (0.6, 0.3, 0.2, 1.0)
    a = lowcam.simulate(render, tables, None, seed=2)
    b = lowcam.simulate(render, fire_i.with_effect("jpeg", quality=60, subsampling="4:2:0"), None, seed=2)
    assert np.sqrt(((a.astype(float) - b) ** 2).mean()) < 1.0 and not np.array_equal(a, b)
