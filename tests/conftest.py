"""Shared fixtures: the two built-in presets."""

import os

import pytest
from sensorless.design.drive import load_drive

# `sensorless tune` proves its table in the time domain before writing it (reports/tune_proof.py): only
# the tests of that proof ask for it (tests/ipmsm_adaptive/test_tune_proof.py), the others tune as before
os.environ.setdefault("SENSORLESS_TUNE_UNCHECKED", "1")


@pytest.fixture(scope="session")
def drive():
    return load_drive("piippo2008")


@pytest.fixture(scope="session")
def deangelo2006():
    return load_drive("deangelo2006")
