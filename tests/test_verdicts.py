"""Verdicts that are never confidently wrong: a candidate that does not lower the error is not named, and an
unexplained residual is named by its family (edges, levels, space or time), read from where it lives."""
from dataclasses import replace

import pytest

from lowcam.measure.compare import compare, residual_family
from lowcam.measure.diagnose import NAMED_GAIN, Candidate, Diagnosis
from lowcam.measure.sets import load_set
from lowcam.measure.synth import synthesise

#: family -> (effects added to the data, effects switched off in the profile, scenes that show it)
FAMILIES = {
    "edges": ([("vertical_blur", {"sigma": 1.0})], [], ("chart",)),  # blur: the residual follows the edges
    "levels": ([("tone_curve", {"gamma": 1.6})], [], ("flat-bright", "flat-dark", "photo")),  # a tone curve
    "space": ([], ["vignetting"], ("flat-bright", "photo")),  # fall-off towards the corners
    "time": ([("row_noise", {"sigma_dn": 2.5})], [], ("flat-bright", "photo")),  # noise that changes per frame
}


def comparison_of(tmp_path, fire_i, add, remove, scenes):
    folder = synthesise(fire_i, tmp_path / "set", add=add, seed=7, frames=4, only_scenes=scenes)
    profile = fire_i.without(*remove) if remove else fire_i
    return compare(load_set(folder, profile), profile)


@pytest.mark.slow  # over 4 s each: a synthetic set and a comparison
@pytest.mark.parametrize("family", list(FAMILIES))
def test_the_residual_of_a_hidden_effect_is_named_by_its_family(tmp_path, fire_i, family):
    """Measured (seed 7, 4 frames): blur 37 % of the residual on the 10 % of pixels at edges; tone curve worst
    at 64-96 DN (27.2) against 5.5 at 224-256; vignetting 14.2 top-left against 1.3 in the middle; row noise: rows
    130 against the mean's 0.99."""
    cmp = comparison_of(tmp_path, fire_i, *FAMILIES[family])
    found, numbers = residual_family(cmp)
    print(found, numbers)
    assert found == family, numbers
    assert cmp.error > 1.5


@pytest.mark.slow  # over 4 s: a synthetic set and a comparison
def test_a_candidate_that_does_not_lower_the_error_is_never_named(tmp_path, fire_i):
    """On a set at 1.231, a candidate leaving 1.233 held out (below the 1.25 that would once name it) is not the
    missing effect: the verdict is unexplained, says that nothing lowers the error and names the residual's family.
    One that lowers it by more than NAMED_GAIN is named."""
    real = comparison_of(tmp_path, fire_i, *FAMILIES["levels"])
    at = replace(real, error=1.231)

    def diagnosis(held_out):
        best = Candidate("tone_curve", error_after=1.2, params={}, evidence="", held_out=held_out, base_error=1.231)
        return Diagnosis(at, [best])

    worse = diagnosis(1.233)
    assert worse.verdict == "unexplained"
    assert "no candidate lowers it" in worse.summary() and "one of levels" in worse.summary(), worse.summary()
    assert worse.as_json()["residual_family"] == "levels"
    assert diagnosis(1.231 * (1 - NAMED_GAIN) + 1e-4).verdict == "unexplained"  # within the gain: not earned
    better = diagnosis(1.15)
    assert better.verdict == "missing-effect" and "tone_curve brings it to 1.150" in better.summary()
