"""Session fixtures of the adaptive observer's tests."""

import contextlib
import io

import pytest


@pytest.fixture(scope="session")
def tune_cli_small(tmp_path_factory):
    """``sensorless tune piippo2008 --speeds 5 --torque=-1T_N,1T_N --quiet``, run once per worker: (argv
    without --out, output directory, exit status, stdout). test_tune.py (determinism: it runs the
    command again) and test_tune_global.py (the bound's line and table) read it, read only; both files
    run on one worker (group "tune-ipmsm" of tests/conftest.py's SHARED)."""
    from sensorless.reports.cli.main import main

    argv = ["tune", "piippo2008", "--speeds", "5", "--torque=-1T_N,1T_N", "--quiet"]
    out = tmp_path_factory.mktemp("tune_cli_small") / "o"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main([*argv, "--out", str(out)])
    return argv, out, code, stdout.getvalue()


@pytest.fixture(scope="session")
def schedule_small(drive):
    """piippo2008's schedule tuned on the small envelope (tests/helpers/tuning.py) with the default decay
    floor (its speed-dependent seed's) and breakpoints, once per worker: test_tune.py (it beats its
    seed, law (16)) and test_tune_global.py (it reaches the pointwise bound) read it, read only (group
    "tune-ipmsm" of tests/conftest.py's SHARED: one worker)."""
    from helpers.tuning import small
    from sensorless.tuning.tune import tune

    return tune(drive, "schedule", small(drive))
