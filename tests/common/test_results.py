"""Results that do not hold are never silent: a simulation that diverges (NaN) writes nothing and
exits 3; one that loses the rotor position writes its outputs with a warning and exits 3; tuned gains
below the damping a report requires give a warning and exit 3; a run longer than the documented
step-count limit is refused before anything is allocated; drive values that parse to infinity or
are far out of range are refused at load."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest
from helpers.figures_off import figures_off
from sensorless.design import simulate as sim
from sensorless.design.drive import load_drive
from sensorless.design.simulate import MAX_SAMPLES, Traces, position_lost
from sensorless.reports import time_domain
from sensorless.reports.cli.common import MIN_DAMPING
from sensorless.reports.cli.main import main

PRESET = (resources.files("sensorless.design.ipmsm_adaptive.presets") / "piippo2008.toml").read_text()


def edited(tmp_path, old, new, name="drive.toml"):
    assert old in PRESET, old
    p = tmp_path / name
    p.write_text(PRESET.replace(old, new))
    return p


def run(args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_diverging_simulation_is_an_error_and_writes_nothing(tmp_path, capsys):
    """A rotor inertia of 1e-6 kg m^2 on the 2.2-kW drive: the motor's integration at T_s blows up
    (every trace NaN from 0.5 s). Before: 'RMS nan' and exit 0."""
    drive = edited(tmp_path, 'J = "0.015 kgm2"', 'J = "1e-6 kgm2"')
    out = tmp_path / "o"
    code, stdout, err = run(
        ["simulate", drive, "--scenario", "fig9b", "--duration", "0.8", "--quiet", "--out", out], capsys
    )
    # the plausibility check has already warned about the inertia (design/plausibility.py)
    warning, error = err.splitlines()
    assert code == 3 and "motor.J" in warning and "mechanical time constant" in warning, err
    assert error.startswith("sensorless simulate: error: the simulation diverged: ")
    assert "not finite from t = 0." in error
    assert "nothing written" in err and "nan" not in stdout.lower()
    assert not out.exists()


def test_a_lost_rotor_is_a_warning_with_exit_3(tmp_path, capsys):
    """An R_s estimate of 1 ohm for the true 3.59 ohm: the speed-adaptive observer of Fig. 9(a) loses the
    rotor position at zero speed under load (it reaches 180 deg). Before: exit 0 and no word of it. The
    traces are the result, so they are written."""
    i = PRESET.index("[estimate]")
    drive = tmp_path / "drive.toml"
    drive.write_text(PRESET[:i] + PRESET[i:].replace('R_s = "3.59 ohm"', 'R_s = "1 ohm"', 1))
    out = tmp_path / "o"
    # the first 1.2 s: standstill under rated load from 0.5 s, where the estimate is lost, and the
    # first speed step
    short = ["--duration", "1.2", "--quiet"]
    code, _, err = run(["simulate", drive, "--scenario", "fig9a", *short, "--out", out], capsys)
    assert code == 3 and err.count("\n") == 1, err
    assert err.startswith(
        "sensorless simulate: warning: the position estimate was lost: its error reached 90 deg"
    )
    assert sorted(p.name for p in out.iterdir()) == ["fig9a.png", "fig9a.svg", "traces.csv"]
    # the paper's drive, same scenario: no warning
    code, _, err = run(
        ["simulate", "piippo2008", "--scenario", "fig9a", *short, "--out", tmp_path / "p"], capsys
    )
    assert code == 0 and err == ""


def test_position_lost_is_a_loss_after_lock_while_turning():
    t = np.linspace(0, 1, 101)
    deg = np.radians
    assert position_lost(t, deg(np.where(t < 0.5, 5.0, 100.0))) == pytest.approx(0.5)
    assert position_lost(t, deg(np.where(t < 0.5, 5.0, -170.0 + 360))) == pytest.approx(0.5)  # wrapped
    assert position_lost(t, deg(150 * np.exp(-10 * t))) is None  # a large initial error that converges
    flip = deg(np.where((t > 0.2) & (t < 0.23), 180.0, 0.0))
    assert position_lost(t, flip) == pytest.approx(0.21)
    assert position_lost(t, flip, moving=t > 0.3) is None  # at standstill the estimate is undefined
    assert position_lost(t, deg(np.full_like(t, 89.0))) is None


def test_traces_problems_name_the_first_nonfinite_signal():
    t = np.arange(5) * 0.1
    tr = Traces(
        t, {"w_m": np.array([0, 1, np.inf, 3, 4.0]), "T_e": np.array([0, 0, 0, np.nan, 0])}, {}, {}, {}
    )
    assert tr.nonfinite() == ("w_m", pytest.approx(0.2))
    assert tr.problems()[0].startswith("the simulation diverged: w_m is not finite from t = 0.2 s")


def test_the_step_count_limit_is_checked_before_anything_is_allocated(tmp_path, capsys, monkeypatch):
    """`--duration 1e9` tried to allocate 36 TiB. The limit is MAX_SAMPLES control periods: longer
    runs are one line naming the option (or the scenario file's key), before the run."""
    monkeypatch.setattr(sim, "run_loop", lambda *a, **k: pytest.fail("ran"))
    T_s = load_drive("piippo2008").T_s
    too_long = 1.01 * MAX_SAMPLES * T_s
    code, stdout, err = run(
        ["simulate", "piippo2008", "--scenario", "fig9b", "--duration", too_long, "--out", tmp_path / "o"],
        capsys,
    )
    assert code == 2 and err.count("\n") == 1 and stdout == "", err
    assert err.startswith(
        "sensorless simulate: error: argument --duration: 404 s at T_s = 200 us is 2.02e+06"
    )
    assert f"more than the limit of {MAX_SAMPLES}" in err
    sc = tmp_path / "long.toml"
    sc.write_text('[scenario]\nname = "long"\ntitle = "x"\nkind = "ipmsm-adaptive"\nduration = "1e5 s"\n')
    code, _, err = run(["simulate", "piippo2008", "--scenario", sc, "--out", tmp_path / "o"], capsys)
    assert code == 2 and f"{sc}: key 'scenario.duration': 100000 s at T_s = 200 us" in err, err
    assert not (tmp_path / "o").exists()
    with pytest.raises(sim.SimulationError, match="more than the limit"):  # the API refuses too
        from sensorless.design.scenario import load_scenario

        sim.simulate(load_drive("piippo2008"), load_scenario(sc, load_drive("piippo2008")))


def test_tuned_gains_below_the_report_threshold_warn_with_exit_3(tmp_path, capsys):
    """|lambda1|, |lambda2| <= 0.01 ohm leaves the observer barely damped: the best gains reach 0.12.
    The tables are written (they are the result), with a warning line and exit status 3."""
    out = tmp_path / "t"
    args = ["tune", "piippo2008", "--lambda-max", "0.01", "--speeds", "3", "--quiet", "--out", out]
    code, stdout, err = run(args, capsys)
    assert code == 3 and err.count("\n") == 1, err
    assert err.startswith("sensorless tune: warning: the tuned gains' worst damping (0.1")
    assert f"is below {MIN_DAMPING:g}" in err
    assert sorted(p.name for p in out.iterdir()) == [
        "gains_speed-dependent.csv",
        "gains_speed-dependent.json",
        "speeds_speed-dependent.csv",
    ]
    assert "wrote" in stdout


def test_a_report_says_when_a_time_domain_check_does_not_hold(
    tmp_path, capsys, monkeypatch, report_deangelo_quick
):
    """The report's time-domain checks re-run scenarios; a diverged run is named in the report and
    in a warning line, and the exit status is 3 (the report itself is written); its analyses are those
    of the same report whose runs hold (report_deangelo_quick, tests/common/conftest.py: made first, in
    this process, group report-runs of tests/conftest.py; its analyses are then in the memo,
    design/memo.py, not computed a second time)."""
    real = time_domain.simulated  # the report's runs (kept: design/simulate.py, read, never changed)

    def diverging(drive, sc, gains=None, **kw):
        tr = real(drive, sc, gains, **kw)
        w = tr["w_m"].copy()
        w[len(w) // 2 :] = np.nan
        return Traces(tr.t, {**tr.data, "w_m": w}, tr.units, tr.docs, tr.meta)

    monkeypatch.setattr(time_domain, "simulated", diverging)
    out = tmp_path / "r"
    with figures_off():  # the report's data and text only (tests/helpers/figures_off.py)
        code, _, err = run(["report", "deangelo2006", "--quick", "--out", out], capsys)
    lines = [ln for ln in err.splitlines() if "warning" in ln]
    assert code == 3 and len(lines) == 3, err
    # a run that does not hold makes the verdict "fail", whatever the poles say
    assert lines[0] == (
        "sensorless report: warning: the verdict is 'fail': see the verdict's findings in report.html"
    )
    checks = lines[1:]
    assert all(ln.startswith("sensorless report: warning: time-domain check fig") for ln in checks)
    assert all("failed: the simulation diverged: w_m is not finite" in ln for ln in checks)
    data = json.loads((out / "report.json").read_text())
    assert data["verdict"]["status"] == "fail"
    held = json.loads((report_deangelo_quick / "report.json").read_text())
    # the held report's checks pass; its verdict fails on the drive's range only (docs/tuning.md)
    assert all(c["passed"] for c in held["time_domain"])
    assert {x["check"] for x in held["verdict"]["findings"]} <= {"drive_range"}
    for key in ("analysis", "low_speed", "drive_analysis"):  # what the diverged runs leave as it was
        assert data[key] == held[key], key
    assert [c["passed"] for c in data["time_domain"]] == [False, False]
    html = (out / "report.html").read_text()
    assert html.count("the simulation diverged: w_m is not finite") >= 2


@pytest.mark.parametrize(
    ("old", "new", "key", "words"),
    [
        ('R_s = "3.59 ohm"', 'R_s = "1e999 ohm"', "motor.R_s", "is not finite"),
        ('L_d = "0.036 H"', 'L_d = "1e300 H"', "motor.L_d", "out of range"),
        ('J = "0.015 kgm2"', 'J = "1e-300 kgm2"', "motor.J", "out of range"),
        ('T_s = "200 us"', "T_s = nan", "control.T_s", "is not finite"),
        ('w_Delta = "0.13 pu"', 'w_Delta = "1e300 pu"', "injection.w_Delta", "out of range"),
        ('"-1 T_N", "0 T_N"', '"-1e999 T_N", "0 T_N"', "tuning.torques[0]", "is not finite"),
    ],
)
def test_values_that_parse_to_inf_or_out_of_range_are_refused_at_load(tmp_path, capsys, old, new, key, words):
    """'1e999 ohm' used to parse to inf and be accepted; 1e300 and 1e-300 gave NaN-laden outputs."""
    drive = edited(tmp_path, old, new)
    code, stdout, err = run(["analyze", drive, "--out", tmp_path / "o"], capsys)
    assert code == 2 and err.count("\n") == 1 and stdout == "", err
    assert f"{drive}: key '{key}'" in err and words in err, err
