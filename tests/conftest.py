"""Shared fixtures: the built-in paper-000 drive."""

import pytest
from sensorless.design.drive import load_drive


@pytest.fixture(scope="session")
def drive():
    return load_drive("piippo2008")


@pytest.fixture(scope="session")
def drive002():
    return load_drive("deangelo2006")
