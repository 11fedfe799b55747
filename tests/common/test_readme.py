"""The README's command lines run as written: every `sensorless` line of its ``sh`` blocks, in order,
in a fresh directory holding the README's example files (``toml`` blocks that start with a
``# NAME.toml`` line) and the repository's docs/examples (the firmware files it names), exits 0. The
install lines are what CI itself runs (.ci/run)."""

from __future__ import annotations

import json

import pytest
from helpers.readme import README, blocks, chain_commands, chains, commands

# each chain of the README's commands runs once per session (tests/conftest.py readme_run), the chains
# on different workers (groups readme-CHAIN of tests/conftest.py); each chain is scheduled by its own CPU
# seconds (measured, with its report's SVG children), so that the longest groups of the suite start first
CPU = {"servo": 27, "skate-vesc": 19, "skate-odrive": 11, "piippo2008": 10}

# what each chain's lines write (checked beside their exit status)
WRITES = {
    "servo": ["servo.toml", "servo-drive.toml", "c-servo/servo400.c", "report-servo/report.json"],
    # both firmwares' settings, and reports with the tuned gains beside the firmwares' defaults
    "skate-vesc": ["firmware-skate-vesc/vesc.xml", "report-skate-vesc/report.json"],
    "skate-odrive": [
        "firmware-skate-odrive/odrive.json",
        "tune-skate-odrive/pareto_constant.csv",
        "report-skate-odrive/report.json",
    ],
}


def test_the_readme_has_the_quick_start_and_your_own_motor():
    cmds = [" ".join(c[:2]) for c in commands()]
    assert "tune piippo2008" in cmds and "init servo.toml" in cmds
    # the install runs in a virtual environment (Debian 12 refuses pip into the system Python)
    assert "python3 -m venv" in blocks("sh")[0]


def test_the_chains_are_all_the_readme_commands_in_order():
    # each command in exactly one chain, and each chain a run of consecutive lines: running the chains
    # one after the other is running the README in its order
    assert [argv for c in chains() for argv in chain_commands(c)] == commands()
    assert set(WRITES) < set(chains())


@pytest.mark.parametrize("chain", [pytest.param(c, marks=pytest.mark.long(CPU.get(c, 20))) for c in chains()])
def test_every_readme_command_runs_as_written(readme_run, chain):
    run = readme_run(chain)
    assert [argv for argv, _, _ in run.results] == chain_commands(chain)  # all of them, in order
    for argv, code, err in run.results:
        assert code == 0, (argv, err[-2000:])
    for file in WRITES.get(chain, []):
        assert (run.dir / file).is_file(), file
    if chain == "servo":  # the line the README quotes is the line its tune prints
        quoted = [b.strip() for b in blocks("text") if b.startswith("sensorless down to")]
        tune = next(k for k, (argv, _, _) in enumerate(run.results) if argv[0] == "tune")
        assert quoted and quoted[0] in run.outputs[tune] + run.results[tune][2], run.outputs[tune][-2000:]
    if chain in ("skate-vesc", "skate-odrive"):
        rep = json.loads((run.dir / f"report-{chain}" / "report.json").read_text())
        assert {"tuned", "ODrive defaults", "VESC detection"} <= set(rep["analysis"])


@pytest.mark.parametrize(
    "pattern", ["tune-*/", "analysis-*/", "report-*/", "c-*/", "*-drive.toml", "firmware-*/"]
)
def test_the_readme_outputs_are_ignored_by_git(pattern):
    ignore = (README.parent / ".gitignore").read_text().splitlines()
    assert f"/{pattern}" in ignore
