"""Shared fixtures: bundled profiles and a seeded generator."""
import numpy as np
import pytest

import lowcam


@pytest.fixture(scope="session")
def fire_i():
    return lowcam.load_profile("fire-i")


@pytest.fixture(scope="session")
def ueye():
    return lowcam.load_profile("ueye")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
