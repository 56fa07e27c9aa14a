"""Profiles: bundled ones load, bad keys and values get clear errors, plug-in effects work, save round-trips."""
import sys
import textwrap

import numpy as np
import pytest

import lowcam
from lowcam import ProfileError

FIRE_I_TEXT = (lowcam.profile.BUNDLED_PROFILES / "fire-i.toml").read_text()


def test_bundled_profiles_load_and_list():
    names = [n for n, _ in lowcam.list_profiles()]
    assert {"fire-i", "ueye"} <= set(names)
    for name in names:
        p = lowcam.load_profile(name)
        assert p.camera.width > 0 and p.effects


def _variant(tmp_path, old, new):
    text = FIRE_I_TEXT.replace(old, new)
    assert text != FIRE_I_TEXT
    path = tmp_path / "variant.toml"
    path.write_text(text)
    # the textures are found relative to the profile file
    (tmp_path / "fire-i").symlink_to(lowcam.profile.BUNDLED_PROFILES / "fire-i")
    return path


@pytest.mark.parametrize("old, new, message", [
    ("bits = 6", "bitz = 6", "effect 'quantisation': unknown key 'bitz'"),
    ("sigma = 0.7", "sigma = -0.7", "'sigma' = -0.7 sensels is out of range"),
    ("saturation = 90.0", "saturation = 300.0", "'saturation' = 300.0 is out of range [0.0, 255.0]"),
    ('law = "sigma_linear"', 'law = "quadratic"', "'law' must be one of sigma_linear, variance_linear"),
    ('type = "sharpening"', 'type = "sharpenning"', "unknown effect type 'sharpenning'"),
    ("width = 640", "width = 641", "multiple of 4"),
    ("taps = 16", "taps = 16.5", "'taps' must be a whole number"),
    ('texture = "fire-i/vignetting.png"', 'texture = "fire-i/nothing.png"', "names a file that does not exist"),
    ("[camera]", "colour = 1\n[camera]", "unknown top-level key 'colour'"),
])
def test_bad_profiles_get_one_line_errors_naming_file_and_key(tmp_path, old, new, message):
    path = _variant(tmp_path, old, new)
    with pytest.raises(ProfileError) as e:
        lowcam.load_profile(path)
    assert message in str(e.value) and str(path) in str(e.value) and "\n" not in str(e.value)


def test_unknown_profile_name_lists_the_known_ones():
    with pytest.raises(ProfileError, match="unknown profile 'fire-j'.*fire-i"):
        lowcam.load_profile("fire-j")


def test_save_and_reload_gives_the_same_frame(tmp_path):
    p = lowcam.load_profile("fire-i")
    saved = p.save(tmp_path / "copy" / "mine.toml")
    q = lowcam.load_profile(saved)
    render = np.zeros((300, 400, 4), np.float32)
    render[100:200, 150:250] = 0.8
    assert np.array_equal(lowcam.simulate(render, p, seed=4), lowcam.simulate(render, q, seed=4))


def test_a_user_effect_from_their_own_module_runs_in_the_chain(tmp_path, monkeypatch):
    (tmp_path / "my_effects.py").write_text(textwrap.dedent('''
        from lowcam.effects import Effect, Param

        class Haze(Effect):
            """Adds a veil of light where the graphics are (DN)."""
            name = "haze"
            writes = "bayer"
            params = {"veil_dn": Param(2.0, low=0.0, high=255.0, unit="DN")}

            def apply(self, state):
                state.bayer += self.veil_dn * state.bayer_alpha
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("LOWCAM_PLUGINS", "my_effects")  # the user's consent
    path = _variant(tmp_path, '[[effect]]\ntype = "horizontal_blur"',
                    '[[effect]]\ntype = "my_effects:Haze"\nveil_dn = 40.0\n\n[[effect]]\ntype = "horizontal_blur"')
    p = lowcam.load_profile(path)
    assert "haze" in [e.name for e in p.effects]
    render = np.zeros((300, 400, 4), np.float32)
    render[..., 3] = 1.0  # opaque black
    base = lowcam.simulate(render, "fire-i", seed=1).astype(float).mean()
    hazy = lowcam.simulate(render, p, seed=1).astype(float).mean()
    assert hazy - base > 25
    sys.modules.pop("my_effects", None)
    lowcam.effects.PLUGINS.pop("my_effects:Haze", None)  # another test registers its own "haze"


def test_render_camera_reports_the_field_the_render_must_cover():
    cam = lowcam.render_camera("fire-i", 3000, 2250)
    assert 100 < cam["hfov_deg"] < 130  # a 2.1 mm lens on a 1/4" sensor sees very wide
    with pytest.raises(lowcam.LowcamError, match="covers too little vertically"):
        lowcam.simulate(np.zeros((300, 900, 4), np.float32), "fire-i")


def test_changing_a_lens_parameter_in_place_takes_effect():
    p = lowcam.load_profile("fire-i").without("noise")
    render = np.zeros((600, 800, 4), np.float32)
    render[280:320, 600:700] = 1.0
    before = lowcam.simulate(render, p)
    p.effect("lens_distortion").w = 0.3
    after = lowcam.simulate(render, p)
    assert np.abs(before.astype(int) - after.astype(int)).sum() > 1000


def test_controls_read_and_set_the_cameras_user_settings():
    p = lowcam.load_profile("fire-i")
    assert p.controls() == {"exposure_s": 0.033, "sharpness": 80.0, "saturation": 90.0}
    q = p.with_controls(sharpness=25.0, saturation=65.0)
    assert q.effect("sharpening").sharpness == 25.0 and q.effect("saturation").saturation == 65.0
    assert p.effect("sharpening").sharpness == 80.0                      # the original is untouched
    raw = lowcam.load_profile("ueye")
    assert "saturation" not in raw.controls() and raw.with_controls(saturation=80.0).to_dict() == raw.to_dict()


def test_provenance_round_trips_and_bad_keys_are_named(tmp_path):
    chain = FIRE_I_TEXT.split("\n[provenance]")[0]
    text = chain + '\n[provenance]\ncamera = "data sheet"\nnoise = "sec. 4.3"\n"noise.red" = "dark frame"\n'
    path = tmp_path / "p.toml"
    (tmp_path / "fire-i").symlink_to(lowcam.profile.BUNDLED_PROFILES / "fire-i")
    path.write_text(text)
    p = lowcam.load_profile(path)
    assert p.provenance_of("noise", "red") == "dark frame"
    assert p.provenance_of("noise", "green") == "sec. 4.3"
    assert p.provenance_of("vignetting") == ""
    assert lowcam.load_profile("fire-i").provenance_of("quantisation").startswith("Klein & Murray 2010")
    again = lowcam.load_profile(p.save(tmp_path / "q.toml"))
    assert again.provenance == p.provenance
    for bad, message in [('"noize" = "x"', "names no effect of the chain"),
                         ('"noise.sigmaa" = "x"', "'noise' has no parameter 'sigmaa'"),
                         ('"camera" = ""', "provenance")]:
        path.write_text(chain + f"\n[provenance]\n{bad}\n")
        with pytest.raises(ProfileError, match=message):
            lowcam.load_profile(path)
