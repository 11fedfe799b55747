"""Hostile inputs against what the commands write and how they end (continues test_hostile_inputs.py):
every number written is finite, or its cell is empty and the row says why (reports/csv_cells.py); the
many-drive engine's summary gives each drive's error; work on a plausible-but-wrong input is bounded;
Ctrl-C on many drives is one line."""

from __future__ import annotations

import csv
import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive


# ------------------------------------------------------------------ no nan or inf in what is written
def test_montecarlo_draws_without_equilibrium_have_an_empty_cell_and_a_reason():
    from types import SimpleNamespace

    from sensorless.design.montecarlo import Draws, Uncertain
    from sensorless.reports.montecarlo import NO_EQUILIBRIUM, draws_csv

    params = [Uncertain("R_s", 1.0, 1.0, "ohm", True)]
    draws = Draws(("R_s",), np.array([[1.0], [2.0]]), np.array([[1.0], [1.0]]), {})
    res = SimpleNamespace(
        draws=draws,
        worst=np.array([0.5, -np.inf]),  # the second draw: no equilibrium somewhere (-inf: '-inf' before)
        at=np.array([1, 0]),
        w=np.array([10.0, 20.0]),
        torque=np.array([0.0, 1.0]),
        td=[],
    )
    text = draws_csv(res, params, 0.2)
    assert "inf" not in text and "nan" not in text, text
    rows = list(csv.DictReader(io.StringIO(text)))
    assert rows[0]["worst_damping"] == "0.5" and rows[0]["worst_speed_rad_s"] == "20"
    assert rows[0]["no_value_reason"] == ""
    assert rows[1]["worst_damping"] == "" and rows[1]["passes_damping"] == "0"
    assert rows[1]["no_value_reason"] == NO_EQUILIBRIUM


def test_a_flux_preset_point_without_a_sampled_fixed_point_is_said_not_written_as_nan():
    # analyze hubmotor48 wrote nan in the discrete columns of a row where Newton's method found no
    # sampled fixed point, silently (exit 0). The damped Newton now finds that point's fixed point, so
    # the case is made here: the same point's analysis with its sampled poles missing (NaN, as the
    # analysis leaves a point without a fixed point) must give empty cells and the row's reason.
    from sensorless.design.pmsm_flux_observer import FAMILY
    from sensorless.reports.pole_map import NO_POLES, pole_csv

    drive = load_drive("hubmotor48")
    W, T = drive.envelope.grid(2)
    k = np.flatnonzero(np.isclose(W / drive.w_base, 0.95682, atol=1e-5) & (T == drive.T_N))
    lin = FAMILY.linearize(drive, FAMILY.gains(drive), W[k], T[k])
    assert np.isfinite(lin.poles).all() and np.isfinite(lin.poles_discrete).all()  # found (damped Newton)
    missing = np.full_like(lin.poles_discrete, np.nan)
    for poles, reason in ((missing, NO_POLES), (lin.poles, "")):
        text = pole_csv(dataclasses.replace(lin, poles=poles), drive.w_base)
        assert "nan" not in text and "inf" not in text, text
        row = next(csv.DictReader(io.StringIO(text.split("\n", 1)[1])))
        assert row["no_value_reason"] == reason and (row["worst_damping"] == "") == bool(reason)


def test_the_whole_drive_csv_leaves_a_point_without_a_fixed_point_empty_and_says_why():
    # `analyze --drive` wrote nan into every cell of such a row (deangelo2006: 54 of its 120 points);
    # two points made here, the second without a fixed point (NaN, as linearize_drive leaves it)
    from sensorless.design.drive_analysis import DriveLinearization
    from sensorless.reports.drive_analysis import NO_FIXED_POINT
    from sensorless.reports.drive_analysis import csv as drive_csv

    drive = load_drive("piippo2008")
    n = 3
    y = np.array([[0.1, 0.2, 0.3], [np.nan] * n])
    poles = np.array([[-10.0 + 5j, -10.0 - 5j, -300.0], [np.nan] * n])
    lin = DriveLinearization(
        w=drive.w_base * np.array([0.5, 0.9]),
        torque=drive.T_N * np.array([1.0, -1.0]),
        names=("a", "b", "c"),
        y=y,
        J=np.zeros((2, n, n)),
        poles=poles,
        theta_err=np.array([0.01, np.nan]),
        ramp_lag=np.array([1e-6, np.nan]),
        T_s=1e-4,
    )
    text = drive_csv(lin, drive)
    assert "nan" not in text and "inf" not in text, text
    rows = list(csv.DictReader(io.StringIO(text.split("\n", 1)[1])))
    assert [r["no_value_reason"] for r in rows] == ["", NO_FIXED_POINT]
    assert [r["T_pu"] for r in rows] == ["1", "-1"] and [r["T_L_Nm"] for r in rows] == [
        format(drive.T_N, ".10g"),
        format(-drive.T_N, ".10g"),
    ]
    assert float(rows[0]["worst_damping"]) == pytest.approx(10 / np.hypot(10, 5))
    assert rows[1]["worst_damping"] == rows[1]["pole0_re_1_s"] == rows[1]["theta_err_deg"] == ""


@pytest.mark.parametrize("v", [float("nan"), float("inf"), -float("inf"), None])
def test_a_csv_cell_is_a_finite_number_or_empty_with_the_rows_reason(v):
    from sensorless.reports.csv_cells import row

    assert row([1.5, v], "why") == "1.5,,why"
    assert row([1.5, 2], "why") == "1.5,2,"


# ------------------------------------------------------------------------------------- many drives
def _servo_dir(tmp_path, names=("a", "b")):
    import re

    from sensorless.design.drive import preset_text

    d = tmp_path / "drives"
    d.mkdir()
    for n in names:
        (d / f"{n}.toml").write_text(
            re.sub(r"^name = .*$", f'name = "{n}"', preset_text("piippo2008"), flags=re.M)
        )
    return d


def test_report_over_a_directory_reads_the_tables_tune_wrote_there(tmp_path, capsys, monkeypatch):
    # `report DIR --gains DIR` was refused per drive as "a directory" (and wrote summary.csv)
    from sensorless.reports.cli import many
    from sensorless.reports.cli.main import main

    drives = _servo_dir(tmp_path)
    tuned = tmp_path / "tuned"
    for n in ("a", "b"):
        (tuned / n).mkdir(parents=True)
        (tuned / n / "gains_speed-dependent.json").write_text("{}")
    seen = {}

    def one(command, base, file, out):  # the drive's run: which table it was given
        seen[Path(file).stem] = base["gains"]
        return {"code": 0, "stdout": "", "stderr": ""}

    monkeypatch.setattr(many, "one", one)
    argv = ["report", drives, "--gains", tuned, "--scheduler", "synchronous", "--out", tmp_path / "r"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert seen == {n: str(tuned / n / "gains_speed-dependent.json") for n in ("a", "b")}
    capsys.readouterr()
    # a drive without its table: one line naming --gains and the drive, before anything is written
    (tuned / "b" / "gains_speed-dependent.json").unlink()
    argv[-1] = tmp_path / "r2"
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--gains" in err and "'b'" in err, err
    assert not (tmp_path / "r2").exists()
    # one drive: a directory holding one table is that table
    assert many.gain_table_of(str(tuned / "a"), "piippo2008") == str(
        tuned / "a" / "gains_speed-dependent.json"
    )


def test_the_summary_gives_a_failed_drives_error_not_its_earlier_warning():
    from sensorless.reports.cli.many import _row

    stderr = "sensorless tune: warning: L/R is short\nsensorless tune: error: key 'x': bad\n"
    row = _row("tune", "a", "a.toml", Path("o"), {"code": 2, "stdout": "", "stderr": stderr})
    assert row["message"] == "sensorless tune: error: key 'x': bad"
    ok = _row(
        "tune", "a", "a.toml", Path("o/none"), {"code": 0, "stdout": "", "stderr": stderr.split("\n")[0]}
    )
    assert ok["message"] == "sensorless tune: warning: L/R is short"


# ------------------------------------------------------------------- bounded work, signals, Ctrl-C
SWALLOWING = """
import subprocess, sys, time
from sensorless.reports import interrupts
interrupts.GRACE = 0.5
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
with interrupts.handled("sensorless x"):
    told = False
    while True:  # as the tuner goes on after IPOPT returned from an interrupt it caught
        try:
            if not told:  # the pid only with the handler in place and inside the try: the test's
                told = True  # SIGTERM may come at once (a loaded machine)
                print(child.pid, flush=True)
            time.sleep(0.01)
        except KeyboardInterrupt:
            pass
"""


def test_a_signal_the_computation_swallows_still_ends_the_process_and_its_children():
    # a SIGTERMed tune computed on for 8 minutes (IPOPT catches the interrupt; the next round starts)
    import signal
    import subprocess
    import sys
    import time

    p = subprocess.Popen(
        [sys.executable, "-c", SWALLOWING], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    child = int(p.stdout.readline())
    p.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    _, err = p.communicate(timeout=60)
    assert p.returncode == 143 and err == "sensorless x: terminated\n", err
    assert time.monotonic() - t0 < 30
    for _ in range(100):  # the process it started has ended too (killed: a zombie until init reaps it)
        if _ended(child):
            break
        time.sleep(0.05)
    else:
        raise AssertionError(f"child {child} still running")


def _ended(pid: int) -> bool:
    """Whether the process ``pid`` no longer runs: gone, or (where /proc shows it) a zombie. Its parent
    was killed, so init reaps it, in its own time: here (a container's init) 1.3 s after the kill, a
    worker idle meanwhile; the test asks whether the child was ended, which the zombie state says."""
    import os

    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    if not os.path.exists("/proc/self/stat"):  # no /proc: only its being gone tells
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:  # reaped meanwhile
        return True


def test_tune_ends_at_its_time_budget_with_one_line_and_nothing_written(tmp_path, capsys):
    # the servo with J in kg m2 where kg cm2 was meant (the plausibility warning: 68.5 s) tuned on
    # past 300 s; a budget ends any tune, with the line saying why it may have run that long
    import re

    from sensorless.reports.cli.main import main

    servo = (
        Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "servo400.toml"
    ).read_text()
    f = tmp_path / "servo_J.toml"
    f.write_text(re.sub(r"^J = .*$", 'J = "0.277 kgm2"', servo, flags=re.M))
    code = main(["tune", str(f), "--time-limit", "0.5", "--quiet", "--out", str(tmp_path / "t")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and "68.5 s" in lines[0], lines
    assert lines[1:] == [lines[-1]] and "--time-limit" in lines[-1] and "0.5 s" in lines[-1], lines
    assert not (tmp_path / "t").exists()


def test_a_budget_the_computation_swallows_rings_again_and_ends_the_block(monkeypatch):
    # CasADi swallowed the budget's alarm inside a Function call and the tune computed on (past the
    # watchdog's GRACE: it ended the pytest worker that ran main([...]) in-process)
    import signal
    import time

    from sensorless.reports import interrupts

    monkeypatch.setattr(interrupts, "REPEAT", 0.05)  # the second alarm after 0.05 s, not 0.25 (idle)
    swallowed = 0
    with pytest.raises(interrupts.Interrupted) as e:
        with interrupts.budget(0.05, "the budget ran out"):
            try:
                time.sleep(30)  # the first alarm lands here and is swallowed, as CasADi does
            except KeyboardInterrupt:
                swallowed += 1
            time.sleep(30)  # the computation goes on: a repeated alarm ends it
    interrupts.reset()
    assert swallowed == 1 and e.value.signum == interrupts.BUDGET
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)  # no alarm left once the block ended


def test_main_run_in_process_is_never_ended_by_the_watchdog(monkeypatch, capsys):
    # the watchdog's os._exit is the script's: a caller of main([...]) (this test) gets the exit status
    import argparse
    import os
    import signal
    import time

    from sensorless.reports import interrupts
    from sensorless.reports.cli import main as cli

    ended = []
    monkeypatch.setattr(interrupts, "GRACE", 0.02)
    monkeypatch.setattr(interrupts, "kill_children", lambda: ended.append("children"))
    monkeypatch.setattr(interrupts.os, "_exit", ended.append)  # (the old code's watchdog: recorded)

    def swallowing(args):  # SIGTERM swallowed, then computing on for 10 x GRACE
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(30)
        except KeyboardInterrupt:
            pass
        time.sleep(0.2)  # (idle: this test's wall time)
        return 0

    parser = argparse.ArgumentParser()
    parser.set_defaults(func=swallowing)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert cli.main([]) == 143
    assert ended == [] and capsys.readouterr().err == "sensorless: terminated\n"


ENGINE_CTRL_C = """
import os, signal, sys
import distributed
from sensorless.reports.cli.main import main
real = distributed.LocalCluster.__init__
def started_then_ctrl_c(self, *a, **k):  # Ctrl-C at the terminal while the workers start
    real(self, *a, **k)
    os.killpg(0, signal.SIGINT)
distributed.LocalCluster.__init__ = started_then_ctrl_c
sys.argv[1:] = ["tune", sys.argv[1], "--workers", "1", "--out", sys.argv[2]]  # the script: main()
sys.exit(main())
"""


def test_ctrl_c_on_a_local_cluster_is_one_line(tmp_path):
    # 29-135 lines of the workers' and Dask's tracebacks (AssertionError: Status.init) before
    import subprocess
    import sys

    d = _servo_dir(tmp_path, ("a",))
    p = subprocess.run(
        [sys.executable, "-c", ENGINE_CTRL_C, str(d), str(tmp_path / "t")],
        capture_output=True,
        text=True,
        timeout=120,
        start_new_session=True,  # its own process group: the Ctrl-C reaches it and its workers only
    )
    assert p.returncode == 130 and p.stderr == "sensorless tune: interrupted\n", p.stderr
    assert not (tmp_path / "t").exists()
