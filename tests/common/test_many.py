"""``tune``/``report`` over several drives (reports/cli/many.py): a directory and a glob on the synchronous
engine, each drive's set equal to its one-drive run, the summary, and the refusals (nothing written)."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from sensorless.design.drive import preset_text
from sensorless.reports.cli.main import main
from sensorless.reports.cli.many import drive_files


def _drive(path: Path, name: str, r_s: str | None = None) -> Path:
    """The preset piippo2008 renamed, on a tiny envelope (2 speeds, positive only, at T_N and the T_max
    the tuner adds: the tests check the many-drive machinery, not the gains), R_s maybe changed."""
    lines = []
    for line in preset_text("piippo2008").splitlines():
        if line.startswith("name = "):
            line = f'name = "{name}"'
        elif line.startswith("speeds = "):
            line = "speeds = 2"
        elif line.startswith("directions = "):
            line = 'directions = "positive"'
        elif line.startswith("torques = "):
            # and the adaptive observer's laws as the paper tunes them (a drive file of the user's own holds
            # the angle lag and tunes alpha_fo by default: 1.6x this test's CPU for gains it does not check)
            line = 'torques = ["1 T_N"]\nhold_lag = false\ntune_alpha_fo = false'
        elif r_s and line.startswith("R_s = "):
            line = f'R_s = "{r_s}"'
        lines.append(line)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def drives(tmp_path):
    d = tmp_path / "drives"
    d.mkdir()
    _drive(d / "alpha.toml", "alpha")
    _drive(d / "beta.toml", "beta", "4 ohm")
    (d / "notes.txt").write_text("not a drive")
    return d


def test_directory_and_glob_select_drive_files(drives, tmp_path):
    assert drive_files(str(drives)) == [str(drives / "alpha.toml"), str(drives / "beta.toml")]
    assert drive_files(str(drives / "b*.toml")) == [str(drives / "beta.toml")]
    # one drive: a file or a preset, whatever directories exist
    assert drive_files(str(drives / "alpha.toml")) is None
    assert drive_files("piippo2008") is None
    assert drive_files(str(tmp_path / "missing.toml")) is None  # the one-drive error names it


def test_tune_over_a_directory_equals_one_drive_runs(drives, tmp_path, capsys):
    out = tmp_path / "out"
    # --no-bound: the pointwise bound (a quarter of a tune) is not what this test checks, and the two runs
    # compared take the same options
    args = ["--law", "speed-dependent", "--quiet", "--no-bound"]
    assert main(["tune", str(drives), "--out", str(out), "--scheduler", "synchronous", *args]) == 0
    printed = capsys.readouterr().out
    assert "summary of 2 drives:" in printed
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["drive"] for r in rows] == ["alpha", "beta"]
    assert all(r["exit_status"] == "0" and r["result"].startswith("worst damping ") for r in rows)
    # the set of a drive is the one-drive command's, byte for byte
    single = tmp_path / "single"
    assert main(["tune", str(drives / "beta.toml"), "--out", str(single), *args]) == 0
    names = sorted(p.name for p in single.iterdir())
    assert names == sorted(p.name for p in (out / "beta").iterdir())
    for n in names:
        assert (single / n).read_bytes() == (out / "beta" / n).read_bytes(), n
    # the two drives differ (R_s): their tables too, so the sets are not one copied twice
    j = "gains_speed-dependent.json"
    assert (out / "alpha" / j).read_bytes() != (out / "beta" / j).read_bytes()
    # run again without --force: refused before any work, nothing changed
    before = (out / "summary.csv").read_bytes()
    assert main(["tune", str(drives), "--out", str(out), "--scheduler", "synchronous", *args]) == 2
    assert "exists" in capsys.readouterr().err
    assert (out / "summary.csv").read_bytes() == before


def test_refusals_write_nothing(drives, tmp_path, capsys):
    out = tmp_path / "out"
    sync = ["--scheduler", "synchronous"]
    # two files with the same drive name
    _drive(drives / "gamma.toml", "alpha")
    assert main(["tune", str(drives), "--out", str(out), *sync]) == 2
    assert "outputs would collide" in capsys.readouterr().err
    (drives / "gamma.toml").unlink()
    # a bad drive file among them: its one line
    (drives / "bad.toml").write_text("[drive]\nkind = 3\n")
    assert main(["report", str(drives), "--out", str(out), *sync]) == 2
    assert "bad.toml" in capsys.readouterr().err
    # no match, and the engine options with one drive
    assert main(["tune", str(tmp_path / "*.nothing"), "--out", str(out), *sync]) == 2
    assert "no drive file matches" in capsys.readouterr().err
    assert main(["tune", "piippo2008", "--out", str(out), *sync]) == 2
    assert "only with several drives" in capsys.readouterr().err
    assert not out.exists()
