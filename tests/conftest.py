"""Shared fixtures: bundled profiles and a seeded generator; two lanes sharing one tier.

With ``LOWCAM_SHARED_TIER`` set to a folder (``scripts/test.sh --all``), each test claims its node id there before
its set-up, and a test another lane has claimed is skipped: two pytest runs of the same tier, one of them in
reverse order (``LOWCAM_SHARED_TIER_REVERSED=1``), run each test once between them and meet in the middle.
"""
import hashlib
import os

import numpy as np
import pytest

import lowcam

SHARED_TIER = os.environ.get("LOWCAM_SHARED_TIER")


def pytest_collection_modifyitems(items):
    if SHARED_TIER and os.environ.get("LOWCAM_SHARED_TIER_REVERSED") == "1":
        items.reverse()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    if SHARED_TIER:
        claim = os.path.join(SHARED_TIER, hashlib.sha1(item.nodeid.encode()).hexdigest())
        try:
            os.close(os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            pytest.skip("run by the other lane")


@pytest.fixture(scope="session")
def fire_i():
    return lowcam.load_profile("fire-i")


@pytest.fixture(scope="session")
def ueye():
    return lowcam.load_profile("ueye")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
