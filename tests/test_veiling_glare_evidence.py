"""The veiling glare candidate says what it saw: dark areas lifted above the model, more in brighter captures.

The veil is made here with OpenCV, not by Lowcam's effect: 6 % of the render's light spread by a Gaussian blur
(sigma 40 px of the render) added to the render; the bundled chart at full and at half exposure and a photograph,
through a quiet Fire-i profile.
"""
import re

import cv2
import numpy as np
import pytest

from helpers import quiet_fire_i
from lowcam.measure.diagnose import diagnose
from lowcam.measure.sets import load_set, write_set
from lowcam.measure.synth import scenes as bundled
from lowcam.pipeline import simulate


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_the_veil_s_evidence_names_the_lift_of_the_dark_areas(tmp_path):
    profile = quiet_fire_i()
    every = bundled(profile, 640)
    captures = []
    for i, (name, scene, exposure) in enumerate((("bright", "chart", 1.0), ("dim", "chart", 0.5),
                                                 ("photo", "photo", 1.0))):
        ideal, omega = every[scene]
        ideal = ideal.copy()
        ideal[..., :3] *= exposure
        veiled = ideal.copy()
        veiled[..., :3] += 0.06 * cv2.GaussianBlur(np.ascontiguousarray(ideal[..., :3]), (0, 0), 40.0)
        frames = [simulate(veiled, profile, None, omega, None, 7 + 1000 * i, k) for k in range(3)]
        captures.append({"name": name, "ideal": ideal, "frames": frames, "angular_velocity": omega})
    mset = load_set(write_set(tmp_path / "set", captures), profile)
    d = diagnose(mset, profile, only=["veiling_glare"], workdir=tmp_path / "work", rounds=1)
    best = d.candidates[0]
    numbers = [float(x) for x in re.findall(r"[-+]?\d+\.\d+", best.evidence)]
    lift, bright, dim, strength, haze = numbers[0], numbers[1], numbers[2], numbers[3], numbers[4]
    assert lift >= 1.0 and bright > 1.5 * dim > 0, best.evidence  # seen: lifted, more where brighter
    assert abs(haze - lift) <= 0.35 * lift, best.evidence  # and the fitted haze lifts them as much
    assert 0.04 <= best.params["strength"] <= 0.08 and best.error_after < 0.8 * d.error, (best.params, d.error)
