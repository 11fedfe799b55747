"""Shared fixtures: the built-in presets and one run of the README's commands; the order and grouping
of the test files on the pytest-xdist workers.

Scheduling: a file's tests run on one worker (so its module fixtures are built once, as with
``--dist loadfile``), except the groups of :data:`SHARED`, whose tests from several files run on one
worker to share a session fixture (the README run: the suite's longest step). Files marked
``pytest.mark.long(cpu_seconds)`` start first, longest first (pyproject.toml passes
``--no-loadscope-reorder`` so that this order holds), so that a long file does not start last and
bound the wall time alone. (``--dist loadgroup`` would say the groups with markers, but pytest-xdist
3.8 cannot rename the node ids of pytest 9, so groups are matched on the node ids here.)
"""

import os
import re

import pytest
from sensorless.design.drive import load_drive

# `sensorless tune` proves its table in the time domain before writing it (reports/tune_proof.py): only
# the tests of that proof ask for it (tests/ipmsm_adaptive/test_tune_proof.py), the others tune as before
os.environ.setdefault("SENSORLESS_TUNE_UNCHECKED", "1")

# group -> the node ids of its tests (from several files: one worker runs them all)
SHARED = {
    "readme": re.compile(
        r"tests/common/test_readme\.py::.*|tests/ipmsm_adaptive/test_any_motor\.py::.*\[servo\]"
    ),
}


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "long(cpu_seconds): a long test file (its CPU seconds, measured): scheduled first"
    )


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist: none without it
def pytest_xdist_make_scheduler(config, log):
    from xdist.scheduler import LoadFileScheduling

    class Scheduling(LoadFileScheduling):
        """--dist loadfile, with the groups of SHARED."""

        def _split_scope(self, nodeid: str) -> str:
            group = next((g for g, ids in SHARED.items() if ids.fullmatch(nodeid)), None)
            return group or super()._split_scope(nodeid)

    return Scheduling(config, log)


def pytest_collection_modifyitems(config, items):
    def cost(item):
        mark = item.get_closest_marker("long")
        return -(mark.args[0] if mark and mark.args else 0)

    items.sort(key=cost)  # stable: within equal cost, the collection order


@pytest.fixture(scope="session")
def drive():
    return load_drive("piippo2008")


@pytest.fixture(scope="session")
def deangelo2006():
    return load_drive("deangelo2006")


@pytest.fixture(scope="session")
def readme_run(tmp_path_factory):
    """Every README command run once as written (tests/helpers/readme.py); the README test checks it,
    the own-motor servo tests read its servo's outputs (group ``readme`` of SHARED: one worker)."""
    from helpers.readme import run_readme

    return run_readme(tmp_path_factory.mktemp("readme"))
