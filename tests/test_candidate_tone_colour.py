"""The tone-curve and colour-matrix candidates against real cameras' curves and matrices.

The hidden effects are made by colour-science, not by Lowcam: broadcast and display transfer functions
(``colour.oetf``: ITU-R BT.709 in full and studio range, IEC 61966-2-1 sRGB, SMPTE 240M) and colour-correction
matrices derived from a real camera's measured spectral sensitivities (``colour.matrix_idt`` on the NPL-measured
Nikon D5100). Each is a small plug-in effect placed where a camera's image processor applies it: the matrix on
the demosaiced linear RGB (after the sensor noise, so it mixes the noise too), the transfer curve after it, on
the straight colour, before the YUV encoding. The diagnosed profile is the plain Fire-i.
"""
import warnings

import colour
import numpy as np
import pytest

import lowcam
from lowcam.effects import Effect, Param
from lowcam.errors import ProfileError
from lowcam.measure.diagnose import diagnose
from lowcam.measure.sets import load_set
from lowcam.measure.synth import synthesise

THIS = __name__


@pytest.fixture(autouse=True)
def trusted(monkeypatch):
    monkeypatch.setenv("LOWCAM_PLUGINS", THIS)  # the user's consent: this file's hidden effects are plug-ins


class HiddenTransfer(Effect):
    """A transfer function from colour-science (``colour.oetf``) on the straight demosaiced colour, scaled to
    the code range ``black``..``white`` (DN)."""

    name = "hidden_transfer"
    section = "test only: colour-science's OETFs"
    writes = "rgb"
    order = 250
    params = {"function": Param("ITU-R BT.709", str), "black": Param(0.0), "white": Param(255.0)}

    def apply(self, state):
        a = np.maximum(state.rgb_alpha, 1e-6)
        x = np.clip(state.rgb / a, 0.0, None) / 255.0
        v = self.black + (self.white - self.black) * colour.oetf(x, function=self.function)
        state.rgb = np.where(state.rgb_alpha > 0, v * state.rgb_alpha, state.rgb).astype(np.float32)


class HiddenColourCorrection(Effect):
    """A camera's colour-correction matrix on the demosaiced linear RGB (premultiplied), as an image processor
    applies it."""

    name = "hidden_colour_correction"
    section = "test only: colour-science's camera matrices"
    writes = "rgb"
    order = 235
    params = {"matrix": Param(np.eye(3).tolist(), "matrix", length=3, low=-10.0, high=10.0)}

    def apply(self, state):
        state.rgb = np.einsum("ij,hwj->hwi", np.asarray(self.matrix), state.rgb).astype(np.float32)


def nikon_d5100_matrix(illuminant: str, target: str) -> np.ndarray:
    """The Nikon D5100's white-balanced camera RGB -> linear ``target`` RGB under ``illuminant``, from its
    NPL-measured spectral sensitivities (colour-science's IDT by least squares on training spectra)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sensitivities = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
        idt, _ = colour.matrix_idt(sensitivities, colour.SDS_ILLUMINANTS[illuminant])  # -> ACES2065-1
        if target == "ACES2065-1":
            return idt
        aces, out = colour.RGB_COLOURSPACES["ACES2065-1"], colour.RGB_COLOURSPACES[target]
        cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(colour.xy_to_XYZ(aces.whitepoint),
                                                                     colour.xy_to_XYZ(out.whitepoint))
        return out.matrix_XYZ_to_RGB @ cat @ aces.matrix_RGB_to_XYZ @ idt


def hidden_set(tmp_path, fire_i, effect, values, scenes, seed):
    data = fire_i.with_effect(f"{THIS}:{effect}", **values)
    return synthesise(data, tmp_path / "set", seed=seed, frames=4, only_scenes=scenes)


LEGAL = [float(v) for v in colour.CV_range(8, True, True)]  # studio range: 16..235 DN
CURVES = {  # case -> (colour-science function, black DN, white DN)
    "bt709-legal": ("ITU-R BT.709", *LEGAL),
    "srgb": ("ITU-T H.273 IEC 61966-2", 0.0, 255.0),
    "bt709": ("ITU-R BT.709", 0.0, 255.0),
    "smpte240m": ("SMPTE 240M", 0.0, 255.0),
}
MATRICES = {  # case -> (illuminant, target colour space)
    "nikon-d5100-srgb-d65": ("D65", "sRGB"),
    "nikon-d5100-aces-d65": ("D65", "ACES2065-1"),
    "nikon-d5100-srgb-a": ("A", "sRGB"),
}
FAST = {"bt709-legal", "srgb", "nikon-d5100-srgb-d65"}  # the rest run in the slow tier (about 30 s each)


def cases(table):
    return [pytest.param(k, marks=() if k in FAST else pytest.mark.slow) for k in table]


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("case", cases(CURVES))
def test_a_real_transfer_curve_is_named_and_fitted(tmp_path, fire_i, case):
    """The curve candidate ranks first against the colour matrix and vignetting, closes the error, and its
    curve follows colour-science's over the inputs the scenes hold."""
    from lowcam.effects.tone_curve import transfer_curve

    function, black, white = CURVES[case]
    folder = hidden_set(tmp_path, fire_i, "HiddenTransfer", {"function": function, "black": black, "white": white},
                        ("flat-bright", "flat-dark", "photo"), seed=40 + len(case))
    d = diagnose(load_set(folder, fire_i), fire_i, only=["tone_curve", "colour_matrix", "vignetting"],
                 workdir=tmp_path / "work")
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    assert d.error > 5, f"the hidden curve is not visible: error {d.error:.3f}"
    assert d.candidates[0].effect == "tone_curve", ranking
    assert d.candidates[0].error_after <= 1.25, ranking
    v = d.candidates[0].params
    x = np.linspace(0.05, 0.9, 200)
    fitted = v["black_dn"] + (v["white_dn"] - v["black_dn"]) * transfer_curve(x, v["gamma"], v["toe_break"])
    assert np.abs(fitted - (black + (white - black) * colour.oetf(x, function=function))).max() < 1.5, v


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
@pytest.mark.parametrize("case", cases(MATRICES))
def test_a_real_colour_correction_matrix_is_named_and_fitted(tmp_path, fire_i, case):
    """The colour-matrix candidate ranks first against the tone curve and chroma subsampling, closes the error,
    places the matrix after demosaicing (it mixes the noise) and recovers its negative entries."""
    hidden = nikon_d5100_matrix(*MATRICES[case])
    assert (hidden < -0.1).any()
    folder = hidden_set(tmp_path, fire_i, "HiddenColourCorrection", {"matrix": hidden.tolist()}, ("photo", "chart"),
                        seed=50 + len(case))
    d = diagnose(load_set(folder, fire_i), fire_i, only=["colour_matrix", "tone_curve", "chroma_subsampling"],
                 workdir=tmp_path / "work")
    ranking = [(c.effect, round(c.score, 3)) for c in d.candidates]
    assert d.error > 1.5, f"the hidden matrix is not visible: error {d.error:.3f}"
    assert d.candidates[0].effect == "colour_matrix", ranking
    assert d.candidates[0].error_after <= 1.25, ranking
    best = d.candidates[0]
    assert best.params["stage"] == "saturation", best.evidence
    assert np.abs(np.asarray(best.params["matrix"]) - hidden).max() < 0.05, (best.params, hidden.round(3))


def test_the_bt709_settings_reproduce_colour_sciences_bt709(fire_i):
    """The engine's curve with BT.709's constants is colour-science's BT.709 OETF (to 0.05 DN: the standard
    rounds the slope to 4.5 and the offset to 0.099)."""
    from lowcam.effects.tone_curve import ToneCurve, transfer_curve

    x = np.linspace(0.0, 1.0, 1001)
    assert np.abs(255 * transfer_curve(x, 1 / 0.45, 0.018) - 255 * colour.oetf(x, "ITU-R BT.709")).max() < 0.05
    sRGB = 255 * colour.oetf(x, "ITU-T H.273 IEC 61966-2")
    assert np.abs(255 * transfer_curve(x, 2.4, 0.0031308) - sRGB).max() < 0.2  # sRGB's constants are rounded
    with pytest.raises(ProfileError, match="white_dn"):
        ToneCurve(black_dn=100.0, white_dn=90.0)
    with pytest.raises(ProfileError):
        ToneCurve(toe_break=-0.1)
