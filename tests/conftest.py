"""Shared fixtures: the built-in presets and one run of the README's commands; the order and grouping
of the test files on the pytest-xdist workers.

Scheduling: a file's tests run on one worker (so its module fixtures are built once, as with
``--dist loadfile``), except the groups of :data:`SHARED`: tests (from one file or several) that run
together on one worker to share a session fixture. The README's commands form independent chains (the
commands of one drive, tests/helpers/readme.py): each chain is a group of its own, so that the workers
run them in parallel (in one sequence they were the suite's longest step), and the servo's chain is
shared with the own-motor tests. Files marked
``pytest.mark.long(cpu_seconds)`` start first, longest first (pyproject.toml passes
``--no-loadscope-reorder`` so that this order holds), so that a long file does not start last and
bound the wall time alone. (``--dist loadgroup`` would say the groups with markers, but pytest-xdist
3.8 cannot rename the node ids of pytest 9, so groups are matched on the node ids here.)
"""

import os
import re
import shutil

# numpy's OpenBLAS in one thread in the test processes (set before numpy is first imported): the suite
# runs one pytest-xdist worker per core, and a second BLAS thread per worker only spins for a core the
# other worker is using (a 225 x 226 SVD of tests/helpers/simulation.py: 0.73 s of CPU with two threads
# on two busy cores, 0.014 s with one). Dask's workers run so by default (tuning/slots.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest
from sensorless.design.drive import load_drive

# `sensorless tune` proves its table in the time domain before writing it (reports/tune_proof.py): only
# the tests of that proof ask for it (tests/ipmsm_adaptive/test_tune_proof.py), the others tune as before
os.environ.setdefault("SENSORLESS_TUNE_UNCHECKED", "1")
# analyses kept on disk for later processes (design/memo.py): not across the suite's processes, where a
# test that patches what an analysis calls would leave its result for another worker (and the user's
# cache); tests/common/test_memo.py tests the disk layer
os.environ.setdefault("SENSORLESS_NO_DISK_MEMO", "1")
# the CasADi libraries the suite compiles (design/compiled.py) at -O0: on an empty cache the suite compiles
# ~100 of them and runs each briefly (side by side on the README test and six analysis files, from empty
# caches: 127.2 s CPU at the product's -O1, 118.6 s at -O0; the same bits: no fast-math either way)
os.environ.setdefault("SENSORLESS_CC_OPT", "-O0")
# ... and with TinyCC where it is installed (.ci/run installs Debian's tcc; design/compiled.py compiles with
# $CC): it compiles them about 11 times faster than gcc -O0 (0.07 against 0.81 s for the seven libraries of
# `report piippo2008 --quick`), and the suite's wall time on a fresh clone, gcc and tcc back to back on an
# idle 2-core machine, twice: 101.3 -> 89.0 s and 113.6 -> 95.0 s. The same IEEE double arithmetic (SSE2,
# no contraction into fused multiply-adds): tests/common/test_compiled_paths.py checks the compiled
# libraries' bits against CasADi's virtual machine. The tests that build the generated C call gcc by name.
if "CC" not in os.environ and shutil.which("tcc"):
    os.environ["CC"] = "tcc"

# the node ids of a group's tests -> the group (one worker runs them all); \1 is the README chain
SHARED = {
    re.compile(r"tests/common/test_readme\.py::test_every_readme_command_runs_as_written\[(.+)\]"): (
        "readme-\\1"
    ),
    re.compile(r"tests/ipmsm_adaptive/test_any_motor\.py::.*\[(servo)\]"): "readme-\\1",
    # the ODrive flow of a motor that is not a preset: the README's skate-odrive chain (readme_run)
    re.compile(r"tests/pmsm_flux_observer/test_drive_file\.py::test_commands_end_to_end_on_.*"): (
        "readme-skate-odrive"
    ),
    # the session fixtures speed_dependent_small and tune_cli_small (tests/ipmsm_adaptive/conftest.py)
    re.compile(r"tests/ipmsm_adaptive/test_tune(_global)?\.py::.*"): "tune-ipmsm",
    # the session fixture outrunner_constant (tests/pmsm_flux_observer/conftest.py)
    re.compile(r"tests/pmsm_flux_observer/test_(tune|criterion)\.py::.*"): "tune-flux",
    # the session fixtures report_piippo_quick, report_deangelo_quick, another_day (tests/common/conftest.py):
    # only the tests that read them (test_outputs.py's other tests run beside the group, on the other worker);
    # test_results.py's diverged report reads report_deangelo_quick's analyses from the memo
    re.compile(
        r"tests/common/test_report\.py::.*|tests/common/test_outputs\.py::test_outputs_are_byte_identical_on_another_day"
        r"|tests/common/test_results\.py::test_a_report_says_when_a_time_domain_check_does_not_hold"
    ): "report-runs",
}


def group(nodeid: str) -> str | None:
    """The group of :data:`SHARED` a test belongs to, if any."""
    for ids, name in SHARED.items():
        m = ids.fullmatch(nodeid)
        if m:
            return m.expand(name)
    return None


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
            return group(nodeid) or super()._split_scope(nodeid)

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
def speed_dependent_small(drive):
    """piippo2008's speed-dependent law tuned on the small envelope (tests/helpers/tuning.py), once per
    worker: tests/ipmsm_adaptive/test_tune.py and test_tune_global.py read it (read only)."""
    from helpers.tuning import small
    from sensorless.tuning.tune import tune

    return tune(drive, "speed-dependent", small(drive))


@pytest.fixture(scope="session")
def readme_run(tmp_path_factory):
    """``readme_run(chain)``: the README commands of one chain run once as written, in a directory of
    their own (tests/helpers/readme.py); the README test checks each chain, the own-motor servo tests
    read the servo chain's outputs (group ``readme-servo`` of SHARED: one worker)."""
    from helpers.readme import run_readme

    runs = {}

    def run(chain):
        if chain not in runs:
            runs[chain] = run_readme(tmp_path_factory.mktemp(f"readme-{chain}"), chain)
        return runs[chain]

    return run
