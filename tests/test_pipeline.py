"""Properties of the Fire-i and raw-Bayer chains (paper sec. 4-5, 7) that would fail if the code were wrong."""
import numpy as np
import pytest

import lowcam
from lowcam.effects.saturation import saturation_matrix
from lowcam.effects.yuv import rgb_to_yuv
from lowcam.sample import sample_plate, sample_render

from helpers import disk_render, flat_render


@pytest.fixture(scope="module")
def scene(fire_i):
    return sample_render(fire_i, 1200), sample_plate(fire_i)


def test_saturation_is_the_identity_at_65_and_grey_at_0():
    assert np.array_equal(saturation_matrix(65.0), np.eye(3)) or np.abs(saturation_matrix(65.0) - np.eye(3)).max() < 1e-15
    grey = saturation_matrix(0.0)
    assert np.allclose(grey, grey[0][None, :])  # every output channel is the same luma
    # the printed matrices of the paper (sec. 4.4.2) are reproduced to 4 decimals at beta = 90
    b = (saturation_matrix(90.0) - saturation_matrix(0.0)) / 90.0
    printed = np.array([[0.0109, -0.0090, -0.0017], [-0.0045, 0.0063, -0.0017], [-0.0045, -0.0090, 0.0137]])
    assert np.abs(b - printed).max() < 1.2e-4


def test_yuv411_chroma_is_constant_within_each_group_of_four(fire_i, scene):
    render, plate = scene
    result = lowcam.run(render, fire_i, plate, seed=3)
    uv = result.state.delta_yuv[..., 1:]
    groups = uv.reshape(480, 160, 4, 2)
    assert np.abs(groups - groups[:, :, :1]).max() == 0
    # in the 8-bit output over a black plate, chroma is constant up to the final rounding (where nothing clipped)
    out = lowcam.simulate(render, fire_i, None, seed=3).astype(np.float32)
    ouv = rgb_to_yuv(out)[..., 1:].reshape(480, 160, 4, 2)
    unclipped = ((out > 0) & (out < 255)).all(axis=-1).reshape(480, 160, 4).all(axis=-1)
    assert unclipped.mean() > 0.1
    assert np.abs(ouv - ouv.mean(axis=2, keepdims=True))[unclipped].max() < 1.5
    # and the chroma really is squashed: without the stage it varies within groups
    free = lowcam.run(render, fire_i.without("chroma_subsampling"), plate, seed=3).state.delta_yuv[..., 1:]
    assert np.abs(free.reshape(480, 160, 4, 2) - free.reshape(480, 160, 4, 2)[:, :, :1]).max() > 5


def test_at_most_64_levels_per_channel_after_quantisation(fire_i, scene):
    render, plate = scene
    state = lowcam.run(render, fire_i, plate, angular_velocity=(0.1, 0.3, 0.0), stop_after="quantisation").state
    assert np.all(np.mod(state.bayer, 4.0) == 0)  # 6 bits of 8: steps of 4 DN
    for k in range(4):
        levels = np.unique(state.bayer[k][(state.bayer[k] >= 0) & (state.bayer[k] <= 255)])
        assert 20 < len(levels) <= 64
    assert state.bayer.min() < 0  # sharpening undershoot survives until blending


def test_alpha_zero_leaves_the_plate_bit_exact(fire_i, scene):
    _, plate = scene
    empty = np.zeros((600, 800, 4), np.float32)
    out = lowcam.simulate(empty, fire_i, plate, angular_velocity=(0.3, 0.5, 0.2), seed=9)
    assert np.array_equal(out, plate)


def test_pixels_outside_the_footprint_are_the_plate_and_the_footprint_hugs_the_object(fire_i, scene):
    _, plate = scene
    render = disk_render(fire_i, radius=0.15)
    result = lowcam.run(render, fire_i, plate, seed=2)
    fp = result.footprint
    assert np.array_equal(result.frame[~fp], plate[~fp])
    assert np.any(result.frame[fp] != plate[fp])
    # The footprint is the disk plus the reach of the filters: horizontally the 7-tap blur and sharpening on
    # 2-px sensels and the 4-px chroma groups, vertically only the demosaic and the optical blur.
    ys, xs = np.nonzero(fp)
    radius = fire_i.lens.distort(np.array([0.15]), np.array([0.0]))[0][0] - fire_i.lens.distort(
        np.array([0.0]), np.array([0.0]))[0][0]
    assert np.abs(xs - 319.5).max() < radius + 20
    assert np.abs(ys - 239.5).max() < radius + 5


def test_opaque_white_over_white_has_no_dark_fringe(fire_i):
    profile = fire_i.without("noise", "vignetting")
    plate = np.full((480, 640, 3), 255, np.uint8)
    for centre in [(0.0, 0.0), (0.9, 0.6)]:  # centre, and a corner where chromatic aberration is largest
        render = disk_render(profile, radius=0.2, centre=centre)
        out = lowcam.simulate(render, profile, plate)
        assert out.min() >= 250, f"dark fringe down to {out.min()} at {centre}"
    # the same object over black shows its edge, so the test is not vacuous
    out = lowcam.simulate(render, profile, np.zeros_like(plate))
    assert out.min() == 0 and out.max() >= 250


def test_straight_alpha_would_have_left_a_fringe(fire_i):
    # The property above depends on premultiplied handling: un-premultiplied input darkens the edge.
    profile = fire_i.without("noise", "vignetting")
    render = disk_render(profile, radius=0.2)
    straight = render.copy()
    straight[..., :3] = np.where(render[..., 3:] > 0, 1.0, 0.0)  # colour not multiplied by alpha
    straight[..., :3] *= render[..., 3:] ** 2  # what a pipeline that multiplies twice produces
    out = lowcam.simulate(straight, profile, np.full((480, 640, 3), 255, np.uint8))
    assert out.min() < 240


def test_same_seed_same_bytes_other_frame_other_noise(fire_i, scene):
    render, plate = scene
    a = lowcam.simulate(render, fire_i, plate, angular_velocity=(0.1, 0.2, 0.3), seed=5, frame=7)
    b = lowcam.simulate(render, fire_i, plate, angular_velocity=(0.1, 0.2, 0.3), seed=5, frame=7)
    c = lowcam.simulate(render, fire_i, plate, angular_velocity=(0.1, 0.2, 0.3), seed=5, frame=8)
    d = lowcam.simulate(render, fire_i, plate, angular_velocity=(0.1, 0.2, 0.3), seed=6, frame=7)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes() and a.tobytes() != d.tobytes()


def test_every_stage_is_recorded_and_changes_something(fire_i, scene):
    render, plate = scene
    result = lowcam.run(render, fire_i, plate, angular_velocity=(0.0, 0.5, 0.0), keep_stages=True)
    names = [k.split("-", 1)[1] for k in result.stages]
    assert names == [e.name for e in fire_i.effects]
    assert np.array_equal(result.stages[next(reversed(result.stages))], result.frame)
    pictures = list(result.stages.values())
    for name, before, after in zip(names[1:], pictures, pictures[1:]):
        if before.shape == after.shape:  # the same kind of picture: the stage must have changed it
            assert np.abs(after.astype(float) - before.astype(float)).mean() > 1e-4, f"{name} changed nothing"


@pytest.mark.parametrize("name", ["crosstalk", "spatial_blur", "vignetting", "noise", "horizontal_blur",
                                  "sharpening", "quantisation", "saturation", "chroma_subsampling",
                                  "chromatic_aberration", "motion_blur"])
def test_switching_an_effect_off_changes_the_frame(fire_i, scene, name):
    render, plate = scene
    args = dict(angular_velocity=(0.0, 0.5, 0.0), seed=1)
    on = lowcam.simulate(render, fire_i, plate, **args).astype(int)
    off = lowcam.simulate(render, fire_i.without(name), plate, **args).astype(int)
    assert np.abs(on - off).mean() > 0.01


def test_raw_pipeline_blends_into_the_bayer_frame(ueye):
    rng = np.random.default_rng(0)
    plate_raw = rng.integers(0, 256, (480, 752), dtype=np.uint8)
    empty = np.zeros((564, 752, 4), np.float32)
    result = lowcam.run(empty, ueye, plate_raw, seed=1)
    from lowcam.effects.bayer import demosaic_bilinear, mosaic, unmosaic

    g = ueye.geometry
    assert np.array_equal(mosaic(result.state.bayer, g), plate_raw)  # the raw frame is untouched
    expected = np.clip(np.rint(demosaic_bilinear(unmosaic(plate_raw, g), g)), 0, 255).astype(np.uint8)
    assert np.array_equal(result.frame, expected)
    assert not result.footprint.any()
    obj = lowcam.run(disk_render(ueye, 0.2), ueye, plate_raw, seed=1)
    assert obj.footprint.mean() > 0.05
    assert np.array_equal(obj.frame[~obj.footprint], expected[~obj.footprint])
    assert np.abs(obj.frame[240, 376].astype(int) - 245).max() < 25  # white disk at the centre (vignetting ~1)


@pytest.mark.parametrize("pattern", ["GBRG", "RGGB"])
def test_block_demosaic_fills_the_2x2_block_with_the_sensel_at_its_top_right(pattern):
    from lowcam.effects.bayer import demosaic_block
    from lowcam.geometry import BAYER_BORDER, FrameGeometry

    g = FrameGeometry(16, 8, bayer_pattern=pattern)
    by, bx = BAYER_BORDER
    for k, name in enumerate(("R", "Gr", "Gb", "B")):
        planes = np.zeros((4,) + g.bayer_shape, np.float32)
        planes[k, by + 1, bx + 2] = 1.0  # the sensel of cell (1, 2)
        dy, dx = g.cfa[name]
        sy, sx = 2 + dy, 4 + dx  # its output pixel
        out = demosaic_block(planes, g)[..., (0, 1, 1, 2)[k]]
        expected = np.zeros((8, 16), np.float32)
        expected[sy:sy + 2, sx - 1:sx + 1] = 0.5 if name in ("Gr", "Gb") else 1.0
        assert np.array_equal(out, expected), name


def test_prepare_and_resume_give_the_bytes_of_simulate(fire_i, scene):
    from lowcam.pipeline import prepare, resume

    render, plate = scene
    token = prepare(render, fire_i, plate, (0.1, 0.4, 0.0))
    for frame in (0, 3):
        assert resume(token, 5, frame).tobytes() == lowcam.simulate(render, fire_i, plate, (0.1, 0.4, 0.0), None, 5,
                                                                    frame).tobytes()


def _every_effect(profile):
    """``profile`` with every bundled effect of its kind (raw or not) enabled: the optional ones at their
    defaults, the render-pass ones too."""
    from lowcam.effects import EFFECTS

    raw_only, not_raw = {"raw_blend"}, {"yuv_blend", "chroma_subsampling", "jpeg", "saturation", "noise_reduction",
                                     "local_tone_mapping", "edge_enhancement"}
    for name in EFFECTS:
        if name in (not_raw if profile.is_raw else raw_only) or (profile.effect(name) and profile.effect(name).enabled):
            continue
        profile = profile.with_effect(name)
    return profile


def _fingerprint(value):
    return None if value is None else (id(value), hash(np.ascontiguousarray(value).tobytes()))


@pytest.mark.parametrize("name", ["fire-i", "iphone-xs-lens", "phone-video", "rpi-hq", "ueye"])
def test_every_stage_keeps_the_state_contract(name):
    """Each bundled profile, and the same with every other effect enabled (object motion and depth of field with
    their passes), run stage by stage through the pipeline's own loop on a moving camera: after every stage each
    array of the state has the shape, dtype and finiteness its field's contract (``SimState`` metadata) states,
    and a stage changes only the arrays of the part its ``writes`` names."""
    from dataclasses import fields

    from lowcam import pipeline
    from lowcam.passes import RenderPasses

    contracts = {f.name: f.metadata for f in fields(pipeline.SimState) if f.metadata}
    for profile in (lowcam.load_profile(name), _every_effect(lowcam.load_profile(name))):
        render = disk_render(profile)
        rows, cols = render.shape[:2]
        passes = RenderPasses(velocity_px_s=np.full((rows, cols, 2), 30.0, np.float32),
                              depth_m=np.linspace(0.5, 5.0, rows * cols, dtype=np.float32).reshape(rows, cols))
        state, _ = pipeline._start(render, profile, None, (0.2, -0.4, 0.1), 0.02, 3, 7, passes)
        g = profile.geometry
        sizes = {"height": g.height, "width": g.width, "working rows": g.working_shape[0],
                 "working columns": g.working_shape[1], "bayer rows": g.bayer_shape[0],
                 "bayer columns": g.bayer_shape[1], "render rows": rows, "render columns": cols}
        made = set()
        for i, effect in enumerate(profile.effects):
            before = {k: _fingerprint(getattr(state, k)) for k in contracts}
            pipeline._walk(state, i, i + 1)
            changed = {k for k in contracts if _fingerprint(getattr(state, k)) != before[k]}
            wrong = {k: contracts[k]["part"] for k in changed if contracts[k]["part"] != effect.writes}
            assert not wrong, f"{profile.name}: {effect.name} (writes {effect.writes!r}) changed {wrong}"
            for k, c in contracts.items():
                value = getattr(state, k)
                if value is None:
                    continue
                made.add(k)
                assert value.dtype == np.dtype(c["dtype"]), (profile.name, effect.name, k, value.dtype)
                assert value.ndim == len(c["shape"]), (profile.name, effect.name, k, value.shape)
                for size, want in zip(value.shape, c["shape"]):
                    expected = want if isinstance(want, int) else sizes.get(want, size)
                    assert size == expected and size > 0, (profile.name, effect.name, k, value.shape, c["shape"])
                if value.dtype.kind == "f":
                    assert np.isfinite(value).all(), (profile.name, effect.name, k)
        assert {"working", "bayer", "bayer_alpha", "rgb", "rgb_alpha"} <= made, made
