"""The codec and demosaicing candidates against real codecs and real demosaicers.

Every hidden effect here is made OUTSIDE the engine:

- JPEG: Pillow's encoder (its own libjpeg build) with its named presets, whose quantisation tables are not the
  IJG-scaled standard ones the engine uses (``PIL.JpegPresets``), or an IJG quality with a chroma subsampling,
  applied to the profile's delivered frames;
- demosaicing: colour-demosaicing's Malvar (2004), Menon (2007) and bilinear implementations, applied to the
  profile's own sensel mosaic (``run(..., stop_after="demosaic")``, ``Result.state.bayer`` with its border
  sensels), after which the rest of the chain runs as usual.

Each test asserts that the right candidate ranks first against decoys and that adding it brings the error to at
most 1.25.
"""
import io
import time

import numpy as np
import pytest

from lowcam.geometry import BAYER_BORDER, CFA_CHANNELS
from lowcam.measure.diagnose import diagnose
from lowcam.measure.sets import load_set, write_set
from lowcam.measure.synth import scenes
from lowcam.pipeline import _finish, _prepare_plate, _walk, run, simulate

PIL = pytest.importorskip("PIL")
colour_demosaicing = pytest.importorskip("colour_demosaicing")

FRAMES = 4


def _write(tmp_path, profile, scene_names, frame_fn):
    """A measurement set of ``scene_names`` whose frame k is ``frame_fn(ideal, k)``."""
    every = scenes(profile)
    captures = [{"name": n, "ideal": every[n][0], "frames": [frame_fn(every[n][0], k) for k in range(FRAMES)],
                 "angular_velocity": every[n][1]} for n in scene_names]
    return write_set(tmp_path / "set", captures)


def _diagnose(tmp_path, folder, profile, only):
    start = time.perf_counter()
    d = diagnose(load_set(folder, profile), profile, only=only, workdir=tmp_path / "work", rounds=1)
    return d, time.perf_counter() - start


def _report(name, d, seconds):
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    print(f"{name}: error {d.error:.3f} -> {d.candidates[0].error_after:.3f} ({d.candidates[0].effect}, "
          f"{d.candidates[0].params}); {seconds:.1f} s; {ranking}")
    return ranking


# --- JPEG by Pillow ------------------------------------------------------------------------------------------------

def pillow_jpeg(frame: np.ndarray, **options) -> np.ndarray:
    """Encode an 8-bit RGB frame with Pillow's JPEG encoder and decode it again (Pillow's own libjpeg)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, "JPEG", **options)
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))


#: Pillow settings -> the options. IJG qualities with each subsampling; Pillow's web presets carry their own tables
#: (not IJG-scaled standard ones, which is all OpenCV's encoder writes): the candidate reads them off the frames.
PILLOW_JPEG = {
    "q40_420": {"quality": 40, "subsampling": "4:2:0"},
    "q60_422": {"quality": 60, "subsampling": "4:2:2"},
    "q75_444": {"quality": 75, "subsampling": "4:4:4"},
    "web_low": {"quality": "web_low"},
    "web_medium": {"quality": "web_medium"},
}


@pytest.mark.parametrize("case", [c if c == "q40_420" else pytest.param(
    c, marks=pytest.mark.slow) for c in PILLOW_JPEG])
def test_a_pillow_jpeg_is_named_and_fitted(tmp_path, fire_i, case):
    options = PILLOW_JPEG[case]
    folder = _write(tmp_path, fire_i, ("photo", "noise-field"),
                    lambda ideal, k: pillow_jpeg(simulate(ideal, fire_i, None, seed=41, frame=k), **options))
    d, seconds = _diagnose(tmp_path, folder, fire_i, ["jpeg", "chroma_subsampling", "defocus"])
    ranking = _report(f"jpeg {case}", d, seconds)
    assert d.error > 1.5, f"the hidden JPEG is not visible: error {d.error:.3f}"
    assert d.candidates[0].effect == "jpeg", ranking
    assert d.candidates[0].error_after <= 1.25, ranking
    params = d.candidates[0].params
    if "subsampling" in options:
        assert params["subsampling"] == options["subsampling"], params
    else:  # the preset's own tables, read off the frames where their blocks show them (the lowest frequencies)
        from PIL import JpegPresets

        preset = JpegPresets.presets[options["quality"]]["quantization"]
        for fitted, true in ((params["luma_table"], preset[0]), (params["chroma_table"], preset[1])):
            assert np.array_equal(np.reshape(fitted, (8, 8))[:3, :3], np.reshape(true, (8, 8))[:3, :3]), fitted


# --- demosaicing by colour-demosaicing -----------------------------------------------------------------------------

def sensor_mosaic(planes: np.ndarray, geometry) -> np.ndarray:
    """The sensel planes (4, rows, cols), R, Gr, Gb, B, interleaved with their border sensels into one mosaic."""
    out = np.empty((2 * planes.shape[1], 2 * planes.shape[2]), np.float64)
    for k, name in enumerate(CFA_CHANNELS):
        dy, dx = geometry.cfa[name]
        out[dy::2, dx::2] = planes[k]
    return out


def with_demosaicer(ideal, profile, seed, frame, demosaic) -> np.ndarray:
    """The profile's frame with its demosaicing replaced by ``demosaic(cfa, pattern) -> (H, W, 3)``: the chain
    runs to the demosaic stage, the external demosaicer rebuilds the colour from the sensel mosaic (border
    sensels included, then cropped to the frame, as a camera demosaics its whole active area), and the rest of
    the chain runs on that. The sensels are laid out as an interpolating demosaicer delivers them (no shift:
    ``bayer.DEMOSAIC_SHIFT_PX``), not where the profile's own 2x2 blocks would."""
    result = run(ideal, profile.with_effect("demosaic", method="bilinear"), seed=seed, frame=frame,
                 stop_after="demosaic")
    state, g = result.state, profile.geometry
    by, bx = BAYER_BORDER
    full = demosaic(sensor_mosaic(state.bayer, g), g.bayer_pattern)
    state.rgb = np.ascontiguousarray(full[2 * by:2 * by + g.height, 2 * bx:2 * bx + g.width], np.float32)
    start = [e.name for e in profile.effects].index("demosaic") + 1
    _walk(state, start=start)
    return _finish(state, _prepare_plate(profile, None)[0])[0]


DEMOSAICERS = {
    "malvar2004": ("demosaicing_CFA_Bayer_Malvar2004", "gradient_corrected_demosaic"),
    "menon2007": ("demosaicing_CFA_Bayer_Menon2007", None),  # any of the two new methods, whichever fits best
    "bilinear": ("demosaicing_CFA_Bayer_bilinear", "bilinear_demosaic"),
}
DEMOSAIC_CANDIDATES = ["gradient_corrected_demosaic", "edge_aware_demosaic", "bilinear_demosaic"]
DEMOSAIC_DECOYS = ["horizontal_blur", "chroma_subsampling"]


@pytest.mark.parametrize("case", [c if c != "bilinear" else pytest.param(c, marks=pytest.mark.slow)
                                  for c in DEMOSAICERS])
def test_a_colour_demosaicing_method_is_named_and_fitted(tmp_path, fire_i, case):
    fn_name, expected = DEMOSAICERS[case]
    fn = getattr(colour_demosaicing, fn_name)
    folder = _write(tmp_path, fire_i, ("noise-field", "photo"),
                    lambda ideal, k: with_demosaicer(ideal, fire_i, 43, k, fn))
    d, seconds = _diagnose(tmp_path, folder, fire_i, DEMOSAIC_CANDIDATES + DEMOSAIC_DECOYS)
    ranking = _report(f"demosaic {case}", d, seconds)
    assert d.error > 1.5, f"the hidden demosaicer is not visible: error {d.error:.3f}"
    if expected:
        assert d.candidates[0].effect == expected, ranking
    else:
        assert d.candidates[0].effect in DEMOSAIC_CANDIDATES[:2], ranking
    assert d.candidates[0].error_after <= 1.25, ranking
