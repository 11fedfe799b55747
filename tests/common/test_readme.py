"""The README's command lines run as written: every `sensorless` line of its ``sh`` blocks, in order,
in a fresh directory holding the README's example files (``toml`` blocks that start with a
``# NAME.toml`` line) and the repository's docs/examples (the firmware files it names), exits 0. The
install lines are what CI itself runs (.ci/run)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import pytest
from sensorless.reports.cli.main import main

README = Path(__file__).resolve().parents[2] / "README.md"
BLOCK = re.compile(r"^```(\w+)\n(.*?)^```", re.S | re.M)


def blocks(lang: str) -> list[str]:
    return [body for kind, body in BLOCK.findall(README.read_text(encoding="utf-8")) if kind == lang]


def commands() -> list[list[str]]:
    out = []
    for body in blocks("sh"):
        for line in body.splitlines():
            if line.startswith("sensorless "):
                out.append(shlex.split(line, comments=True)[1:])
    return out


def test_the_readme_has_the_quick_start_and_your_own_motor():
    cmds = [" ".join(c[:2]) for c in commands()]
    assert "tune piippo2008" in cmds and "init servo.toml" in cmds
    # the install runs in a virtual environment (Debian 12 refuses pip into the system Python)
    assert "python3 -m venv" in blocks("sh")[0]


def test_every_readme_command_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for body in blocks("toml"):
        first = body.splitlines()[0]
        m = re.fullmatch(r"# (\S+\.toml)", first)
        if m:
            (tmp_path / m.group(1)).write_text(body, encoding="utf-8")
    assert (tmp_path / "servo.toml").is_file()
    shutil.copytree(README.parent / "docs" / "examples", tmp_path / "docs" / "examples")
    for argv in commands():
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 0, (argv, err[-2000:])
    # what the own-motor lines wrote
    assert (tmp_path / "servo-drive.toml").is_file()
    assert (tmp_path / "c-servo" / "servo400.c").is_file()
    assert (tmp_path / "report-servo" / "report.json").is_file()
    # what the firmware lines wrote: both firmwares' settings, and reports with the tuned gains beside
    # the firmwares' defaults
    assert (tmp_path / "firmware-skate-vesc" / "vesc.xml").is_file()
    assert (tmp_path / "firmware-skate-odrive" / "odrive.json").is_file()
    assert (tmp_path / "tune-skate-odrive" / "pareto_odrive.csv").is_file()
    for fw in ("vesc", "odrive"):
        rep = json.loads((tmp_path / f"report-skate-{fw}" / "report.json").read_text())
        assert {"tuned", "ODrive defaults", "VESC detection"} <= set(rep["analysis"])


@pytest.mark.parametrize(
    "pattern", ["tune-*/", "analysis-*/", "report-*/", "c-*/", "*-drive.toml", "firmware-*/"]
)
def test_the_readme_outputs_are_ignored_by_git(pattern):
    ignore = (README.parent / ".gitignore").read_text().splitlines()
    assert f"/{pattern}" in ignore
