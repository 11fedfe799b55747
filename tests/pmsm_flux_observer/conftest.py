"""Session fixtures of the flux observer's tests."""

import dataclasses

import pytest

COARSE_SPEEDS = 4  # speeds per direction of the coarse outrunner (the preset's: 12)


@pytest.fixture(scope="session")
def outrunner_coarse():
    """The ODrive-class preset outrunner270 on a coarser envelope (COARSE_SPEEDS per direction): the same
    laws, limits and criterion, tuned and judged on a third of the points."""
    from sensorless.design.drive import load_drive

    d = load_drive("outrunner270")
    env = dataclasses.replace(d.envelope, rule=dataclasses.replace(d.envelope.rule, count=COARSE_SPEEDS))
    return dataclasses.replace(d, envelope=env)


@pytest.fixture(scope="session")
def outrunner_constant(outrunner_coarse):
    """The coarse outrunner's ``constant`` law tuned with the default settings, once per worker:
    test_tune.py (limits, table, baselines, noise limit) and test_criterion.py (against a brute-force
    grid) read it, read only; both files run on one worker (group "tune-flux" of tests/conftest.py's
    SHARED)."""
    from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings, tune_constant

    return tune_constant(outrunner_coarse, FluxTuneSettings())


@pytest.fixture(scope="session")
def outrunner_schedule(outrunner_coarse):
    """The coarse outrunner's ``schedule`` law tuned with the default settings, once per worker: two tests
    of test_tune.py read it, read only."""
    from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings, tune_schedule

    return tune_schedule(outrunner_coarse, FluxTuneSettings())
