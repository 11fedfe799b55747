"""Shared fixtures of tests/common: one `report --quick` of each family with a paper's figures, and one
run of every command on another day; test_report.py and test_outputs.py read them (group ``report-runs``
of tests/conftest.py's SHARED: one worker, so each is made once)."""

import pytest


def _report(tmp_path_factory, preset):
    from helpers.another_day import REPORT_EXIT
    from sensorless.reports.cli.main import main

    out = tmp_path_factory.mktemp(f"report_{preset}_quick") / "report"
    assert main(["report", preset, "--quick", "--out", str(out)]) == REPORT_EXIT[preset]
    return out


@pytest.fixture(scope="session")
def report_piippo_quick(tmp_path_factory):
    """``sensorless report piippo2008 --quick``, run once per worker in this process: its output
    directory (read only)."""
    return _report(tmp_path_factory, "piippo2008")


@pytest.fixture(scope="session")
def report_deangelo_quick(tmp_path_factory):
    """``sensorless report deangelo2006 --quick``, run once per worker in this process: its output
    directory (read only)."""
    return _report(tmp_path_factory, "deangelo2006")


@pytest.fixture(scope="session")
def another_day(tmp_path_factory):
    """Every command, both reports above among them, run again in a fresh process on a faked other day
    (tests/helpers/another_day.py): started when first asked for, in the background; read only."""
    from helpers.another_day import AnotherDay

    later = AnotherDay(tmp_path_factory.mktemp("another_day"))
    yield later
    later.close()
