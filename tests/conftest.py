"""Shared fixtures: the two built-in presets."""

import pytest
from sensorless.design.drive import load_drive


@pytest.fixture(scope="session")
def drive():
    return load_drive("piippo2008")


@pytest.fixture(scope="session")
def deangelo2006():
    return load_drive("deangelo2006")
