"""Two motors that are not presets, from minimal drive files, through every command: a non-salient
400-W servo (L_d = L_q, no injection possible; the README's own motor, its run shared with the README
test) and a strongly salient traction IPMSM. Each: init ->
tune -> codegen (float; it builds and the example initializes) -> report, no traceback, gains found,
a verdict that agrees with its own checks; and the derivation rules checked against values typed from
their documented formulas (design/ipmsm_adaptive/derive.py)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.figures_off import figures_off
from helpers.report_checks import c_example_initializes, verdict_agrees_with_checks
from sensorless.design.drive import load_drive
from sensorless.design.poles import MIN_DAMPING
from sensorless.reports.cli.main import main

DRIVES = Path(__file__).parent / "drives"
MOTORS = {"servo": "servo_minimal.toml", "traction": "traction_minimal.toml"}
CC = shutil.which("gcc") or shutil.which("cc")


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


# the servo is the README's own motor (its servo.toml: the same motor in its datasheet's terms), whose
# commands the README test runs once for both (one worker: group "readme-servo" of tests/conftest.py); the
# traction motor runs here
pytestmark = pytest.mark.long(40)


@pytest.fixture(scope="module", params=["servo", "traction"])
def flow(request, tmp_path_factory):
    """init, tune, codegen and report of one motor (module scope: the steps are the slow part):
    (name, minimal file, written drive file, {step: output directory}, {step: exit status})."""
    name = request.param
    if name == "servo":
        r = request.getfixturevalue("readme_run")("servo")
        drive = r.dir / "servo-drive.toml"
        dirs = {"tune": r.dir / "tune-servo", "codegen": r.dir / "c-servo", "report": r.dir / "report-servo"}
        codes = {"init": r.code("init", "servo.toml"), **{k: r.code(k, str(drive.name)) for k in dirs}}
        return name, r.dir / "servo.toml", drive, dirs, codes
    d = tmp_path_factory.mktemp(name)
    src = DRIVES / MOTORS[name]
    drive = d / "drive.toml"
    dirs = {"tune": d / "tune", "codegen": d / "c", "report": d / "r"}
    codes = {
        "init": main(["init", str(src), "--out", str(drive)]),
        # a coarser optimization grid than the default 20 speeds per direction (the same law, envelope,
        # dense re-verification and checks; the suite's budget: its tune is 9.5 s of CPU at 6 speeds, 11
        # at 10, about 30 at 20)
        "tune": main(["tune", str(drive), "--out", str(dirs["tune"]), "--quiet", "--speeds", "6"]),
    }
    table = dirs["tune"] / "gains_schedule.json"
    codes["codegen"] = main(
        ["codegen", str(drive), "--gains", str(table), "--precision", "float", "--out", str(dirs["codegen"])]
    )
    # the report's data and text only are read here (tests/helpers/figures_off.py); the servo's report,
    # the README's, is drawn in full
    with figures_off():
        codes["report"] = main(
            ["report", str(drive), "--gains", str(table), "--quick", "--out", str(dirs["report"])]
        )
    return name, src, drive, dirs, codes


def test_every_command_succeeds_and_finds_gains(flow):
    _, _, _, d, codes = flow
    assert codes["init"] == codes["tune"] == codes["codegen"] == 0, codes
    assert codes["report"] in (0, 3), codes  # 3: a check failed; the report says so (below)
    table = json.loads((d["tune"] / "gains_schedule.json").read_text())
    # stable gains with the damping a report requires, found on the motor's own envelope
    assert table["summary"]["worst_damping"] > MIN_DAMPING, table["summary"]
    # on a drive of the user's own the default is the family's best law (the schedule), which gets
    # closer to the pointwise bound than the paper's law (16) it starts from
    assert table["law"] == "schedule"
    bound = table["summary"]["bound"]
    assert bound["gap"] <= bound["gap_seed"] + 1e-9, bound


def test_the_minimal_file_and_the_written_one_are_the_same_drive(flow):
    _, src, drive, _, _ = flow
    a, b = load_drive(str(src)), load_drive(str(drive))
    for section in ("motor", "estimate", "control", "observer", "injection", "runtime"):
        assert getattr(a, section) == getattr(b, section), section
    assert a.w_base == b.w_base and a.T_N == b.T_N


def test_derived_values_follow_their_documented_rules(flow):
    name, src, _, _, _ = flow
    d = load_drive(str(src))
    m, c = d.motor, d.control
    f_s = 10e3
    w_N = 2 * math.pi * d.rating.n_N / 60 * m.p  # n_N in r/min
    tau_m = m.J * w_N / m.p / d.T_N
    alpha_fo = min(max(2 * math.pi * f_s / 100, 50 / tau_m), 2 * math.pi * f_s / 20)
    assert c.T_s == pytest.approx(1 / f_s)
    assert d.observer.alpha_fo == pytest.approx(alpha_fo, rel=1e-5)
    # no faster than the injection's PI where the drive injects (it gives the estimate at low speed)
    alpha_i = d.injection.alpha_i if d.injection.enabled else math.inf
    assert c.alpha_s == pytest.approx(min(5 / tau_m, alpha_fo / 5, alpha_i), rel=1e-5)
    assert c.alpha_c == pytest.approx(2 * math.pi * f_s / 12.5, rel=1e-5)
    assert c.T_max == pytest.approx(1.5 * d.T_N, rel=1e-5)
    assert d.w_base == pytest.approx(w_N, rel=1e-5)
    # injection only where the saliency gives an error signal: off for L_d = L_q
    salient = 2 * abs(m.L_q - m.L_d) / (m.L_q + m.L_d) >= 0.1
    assert d.injection.enabled is salient is (name == "traction")


def test_the_verdict_agrees_with_its_checks(flow):
    _, _, drive, d, codes = flow
    data = verdict_agrees_with_checks(d["report"], codes["report"])
    v, td = data["verdict"], data["time_domain"]
    # generic, scaled; low_hold where the drive injects (its own low-speed range: DriveScales.hold_speed)
    hold = ["low_hold"] if load_drive(drive).injection.enabled else []
    assert [c["name"] for c in td] == ["speed_steps", "load_steps", "reversal", "start", *hold]
    assert v["limitations"] == []  # this observer runs through zero speed: nothing left out
    # a user's gains are not the paper's
    assert "paper speed" not in (d["report"] / "report.html").read_text()


def test_the_schedule_keeps_the_seed_law_inside_the_injection_band(flow):
    """Where the drive injects, the schedule's breakpoints with |w_hat| <= w_Delta hold the seed's gains:
    eq. (16) of Piippo et al. (2008) with the seed's lambda', omega_lambda, typed here from the
    equation (lambda1 = lambda' min(|w|/omega_lambda, 1), lambda2 = lambda' clip(w/omega_lambda, -1, 1))
    with w_Delta from the written drive file; the breakpoints beyond the band are the tuner's. Without
    injection (the servo) nothing is held."""
    name, _, drive, d, _ = flow
    table = json.loads((d["tune"] / "gains_schedule.json").read_text())
    g, s = table["gains"], table["summary"]
    inj = load_drive(str(drive)).injection
    w = np.array(g["w_hat"])
    l1, l2 = np.array(g["lambda1"]), np.array(g["lambda2"])
    if not inj.enabled:
        assert name == "servo" and "law_note" not in s
        return
    lp, wl = s["seed"]["parameters"]["lambda_p"], s["seed"]["parameters"]["w_lambda"]
    band = np.abs(w) <= inj.w_Delta
    assert band.sum() >= 3  # zero and at least one breakpoint per direction
    np.testing.assert_allclose(l1[band], lp * np.minimum(np.abs(w[band]) / wl, 1), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(l2[band], lp * np.clip(w[band] / wl, -1, 1), rtol=1e-12, atol=1e-12)
    assert "injection band" in s["law_note"] and "Piippo" in s["law_note"]
    # beyond the band the gains are tuned (not all the seed's); where the tuning kept the schedule's
    # start (with the angle lag held to the drive file's gains' it may find nothing better: the traction
    # motor at 6 speeds), the law's box shows it: one value at the band's breakpoints, free beyond
    free = ~band
    seed1 = lp * np.minimum(np.abs(w[free]) / wl, 1)
    if np.max(np.abs(l1[free] - seed1)) <= 1e-3 * lp:
        from sensorless.tuning.family import tunable_for

        dd = load_drive(str(drive))
        t = tunable_for(dd, "schedule")
        a = s["seed"]["parameters"].get("alpha_fo", dd.observer.alpha_fo)
        m = t.build(dd, t.settings(dd), np.array([lp, wl, a]))
        K = w.size
        for part in (slice(0, K), slice(K, 2 * K)):
            lo, hi = m.lower[part], m.upper[part]
            assert np.array_equal(lo[band], hi[band]) and np.all(lo[free] < hi[free])


@pytest.mark.skipif(CC is None, reason="no C compiler")
def test_the_generated_float_c_builds_and_its_example_initializes(flow):
    _, _, _, d, _ = flow
    c_example_initializes(d["codegen"])


def test_injection_on_a_non_salient_motor_is_a_one_line_error(capsys, tmp_path):
    src = DRIVES / MOTORS["servo"]
    code, _, err = run(["analyze", src, "--injection", "--out", tmp_path / "a"], capsys)
    assert code == 2 and err.count("\n") == 1 and "injection is off" in err, err
    code, _, err = run(["simulate", src, "--scenario", "fig9a", "--quiet", "--out", tmp_path / "s"], capsys)
    assert code == 2 and "sensorless simulate --injection off" in err, err
    assert not (tmp_path / "a").exists() and not (tmp_path / "s").exists()


def test_a_table_tuned_for_another_drive_is_said_by_codegen_and_report(tmp_path):
    from types import SimpleNamespace

    from sensorless.reports.cli.common import foreign_table

    servo = load_drive(str(DRIVES / MOTORS["servo"]))
    mine = SimpleNamespace(drive={"name": servo.name, "sha256": servo.digest})
    other = SimpleNamespace(drive={"name": "traction", "sha256": "0" * 64})
    edited = SimpleNamespace(drive={"name": servo.name, "sha256": "1" * 64})
    assert foreign_table(mine, "t.json", servo) is None
    assert "tuned for drive 'traction', not for 'servo400'" in foreign_table(other, "t.json", servo)
    assert "another version of its file" in foreign_table(edited, "t.json", servo)


@pytest.mark.parametrize(
    "path", sorted((Path(__file__).parents[2] / "docs" / "examples" / "motors").glob("*.toml")), ids=str
)
def test_the_example_motors_load_with_plausible_data(path):
    d = load_drive(str(path))  # plausibility errors would raise; warnings are allowed
    assert d.motor.psi_pm > 0 and d.observer.alpha_fo > d.control.alpha_s > 0


def test_the_report_page_shows_a_foreign_table_warning():
    from sensorless.reports.document import Report, Verdict
    from sensorless.reports.html import render

    inputs = {"drive_sha256": "0" * 64, "gains_sha256": "1" * 64}
    page = render(Report("servo400", "tuned speed-dependent", {"inputs": inputs}, Verdict("pass", ())), "0")
    assert "Warning:" not in page
    inputs["gain_table_warning"] = "t.json was tuned for drive 'traction', not for 'servo400'"
    page = render(Report("servo400", "tuned speed-dependent", {"inputs": inputs}, Verdict("pass", ())), "0")
    assert "Warning: t.json was tuned for drive &#39;traction&#39;" in page
