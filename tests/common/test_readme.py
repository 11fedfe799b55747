"""The README's command lines run as written: every `sensorless` line of its ``sh`` blocks, in order,
in a fresh directory holding the README's example files (``toml`` blocks that start with a
``# NAME.toml`` line) and the repository's docs/examples (the firmware files it names), exits 0. The
install lines are what CI itself runs (.ci/run)."""

from __future__ import annotations

import json

import pytest
from helpers.readme import README, blocks, commands

# the README's commands run once per session (tests/conftest.py readme_run), on this file's worker
pytestmark = pytest.mark.long(70)


def test_the_readme_has_the_quick_start_and_your_own_motor():
    cmds = [" ".join(c[:2]) for c in commands()]
    assert "tune piippo2008" in cmds and "init servo.toml" in cmds
    # the install runs in a virtual environment (Debian 12 refuses pip into the system Python)
    assert "python3 -m venv" in blocks("sh")[0]


def test_every_readme_command_runs_as_written(readme_run):
    assert [argv for argv, _, _ in readme_run.results] == commands()  # all of them, in order
    for argv, code, err in readme_run.results:
        assert code == 0, (argv, err[-2000:])
    where = readme_run.dir
    assert (where / "servo.toml").is_file()
    # what the own-motor lines wrote
    assert (where / "servo-drive.toml").is_file()
    assert (where / "c-servo" / "servo400.c").is_file()
    assert (where / "report-servo" / "report.json").is_file()
    # what the firmware lines wrote: both firmwares' settings, and reports with the tuned gains beside
    # the firmwares' defaults
    assert (where / "firmware-skate-vesc" / "vesc.xml").is_file()
    assert (where / "firmware-skate-odrive" / "odrive.json").is_file()
    assert (where / "tune-skate-odrive" / "pareto_odrive.csv").is_file()
    for fw in ("vesc", "odrive"):
        rep = json.loads((where / f"report-skate-{fw}" / "report.json").read_text())
        assert {"tuned", "ODrive defaults", "VESC detection"} <= set(rep["analysis"])


@pytest.mark.parametrize(
    "pattern", ["tune-*/", "analysis-*/", "report-*/", "c-*/", "*-drive.toml", "firmware-*/"]
)
def test_the_readme_outputs_are_ignored_by_git(pattern):
    ignore = (README.parent / ".gitignore").read_text().splitlines()
    assert f"/{pattern}" in ignore
