"""A third observer family defined entirely in the test tree runs through every command.

The acceptance test of the family architecture (design/family.py, design/registry.py): the back-EMF
PLL observer of tests/families/pll (equations, runtime step, drive TOML, one scenario, one tunable)
registers from there with ``registered(FAMILY)`` and goes through ``analyze``, ``tune`` (a gain table),
``codegen`` (strict C99 that replays a trajectory like the Python step), ``simulate`` (the shared PMSM
drive loop, its scenario) and ``report`` (HTML + JSON with a verdict), with no line outside its own
files naming it. And a family that only loads drive files gets a one-line error, exit status 2, from
every command.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from families.pll import design
from families.pll import tuning as pll_tuning
from families.pll.constant_law import GRID
from families.pll.design import FAMILY
from families.pll.symbolic import OUTPUTS, STATE
from helpers.figures_off import figure_files_off
from helpers.fuzz import fuzz, pmsm_steady_segments, steady_rows
from sensorless.design.drive import load_drive, preset_names
from sensorless.design.family import GainSet, ObserverFamily
from sensorless.design.gain_table import read_gain_table
from sensorless.design.registry import kinds, registered
from sensorless.design.runtime import run_trajectory
from sensorless.design.scenario import builtin_names
from sensorless.reports.cli.main import main
from sensorless.reports.traces import read_csv

pytestmark = pytest.mark.long(33)  # CPU seconds of this file, measured: scheduled first (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[2]
PLL = ROOT / "tests" / "families" / "pll"
DRIVE = str(PLL / "presets" / "pll_servo.toml")
SCENARIO = str(PLL / "scenarios" / "speed_steps.toml")
CC = shutil.which("gcc") or shutil.which("cc")
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]


@pytest.fixture(scope="module", autouse=True)
def family():
    """Every test of this module runs with the test family registered (and only then)."""
    assert FAMILY.kind not in kinds()
    with registered(FAMILY):
        yield FAMILY
    assert FAMILY.kind not in kinds()


@pytest.fixture(scope="module")
def drive(family):
    return load_drive(DRIVE)


def run(args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def tuned(tmp_path_factory, family):
    """`sensorless tune` on the test drive: the gain table's path and the summary printed."""
    out = tmp_path_factory.mktemp("tune")
    code = main(["tune", DRIVE, "--quiet", "--out", str(out)])
    assert code == 0
    return out / "gains_pll.json"


def rot(th):
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s], [s, c]])


# ------------------------------------------------------------------------------------- one place
def test_registers_from_the_test_tree_and_nothing_else_names_it(drive):
    assert FAMILY.kind in kinds() and drive.kind == "pmsm-pll"
    assert "pll_servo" in preset_names() and builtin_names(drive.kind) == ["speed_steps"]
    for module in (FAMILY.presets, FAMILY.scenarios, FAMILY.tuning, FAMILY.report):
        assert module.startswith("families.pll.")
    # the proof that adding a family touches one place: no installed file mentions it
    needles = ("pmsm-pll", "pmsm_pll", "families.pll", "families/pll")
    for root in ("symbolic", "design", "tuning", "reports"):
        for path in (ROOT / root).rglob("*"):
            if path.is_file() and path.suffix in (".py", ".toml", ".j2"):
                text = path.read_text(encoding="utf-8")
                assert not any(n in text for n in needles), path
    for name in ("pyproject.toml", "setup.py"):
        assert not any(n in (ROOT / name).read_text() for n in needles)


def test_reads_the_shared_pmsm_records_and_refuses_a_salient_motor(drive, tmp_path, capsys):
    from sensorless.design.pmsm_schema import PmsmEstimate, PmsmMotor

    assert type(drive.motor) is PmsmMotor and type(drive.estimate) is PmsmEstimate
    assert drive.motor.L_d == drive.motor.L_q == pytest.approx(5e-3)
    for section in ("motor", "estimate"):
        text = Path(DRIVE).read_text()
        head, _, tail = text.partition(f"[{section}]")
        bad = tmp_path / f"salient_{section}.toml"
        bad.write_text(head + f"[{section}]" + tail.replace('L_q = "5 mH"', 'L_q = "6 mH"', 1))
        code, _, err = run(["analyze", bad, "--out", tmp_path / "out"], capsys)
        assert code == 2 and f"key '{section}.L_q'" in err and "non-salient" in err and err.count("\n") == 1


# --------------------------------------------------------------------------------------- analyze
def test_analyze_writes_poles_from_the_casadi_jacobians(drive, tmp_path, capsys):
    # the figure built, not rendered (tests/helpers/figures_off.py): its name is checked here; the
    # report below renders this family's figures
    with figure_files_off():
        code, stdout, err = run(["analyze", DRIVE, "--out", tmp_path], capsys)
    assert code == 0, err
    names = ["poles.csv", "poles.png", "poles.svg", "poles_discrete.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == names  # the shared analyze output
    assert "worst over 148 points" in stdout and "T_e = 1.3 N m" in stdout
    # the terminal shows the envelope's own speeds (10 per direction) of each torque, not the refined grid
    shown = [
        float(ln.split()[0])
        for ln in stdout.splitlines()
        if ln.startswith("  ") and ln.split()[0][-1].isdigit()
    ]
    assert shown == 2 * [round(x, 3) for x in (*np.linspace(-1, -0.1, 10), *np.linspace(0.1, 1, 10))]
    for name in ("poles.csv", "poles_discrete.csv"):
        rows = [ln for ln in (tmp_path / name).read_text().splitlines() if not ln.startswith("#")]
        # the family's own column (the steady angle error) after the operating point
        assert rows[0].startswith("w_m_pu,w_m_rad_s,T_e_Nm,theta_err_rad,pole0_re") and len(rows) == 1 + 148


def test_linearization_is_the_sampled_observer_that_runs(drive):
    """The discrete poles and steady angle error of the family's linearization against the runtime step
    itself: run it on the sampled steady state of the motor until it has converged, then a central
    finite-difference Jacobian of one step in the rotor frame (nothing shared with the linearization
    but the step)."""
    gains = FAMILY.gains(drive)
    setup = FAMILY.runtime(drive, gains)
    m, T_s = drive.motor, drive.T_s
    w, T_e = 0.6 * drive.w_base, drive.T_N
    lin = FAMILY.linearize(drive, gains, w, T_e)
    i_r = np.array([0.0, T_e / (1.5 * m.p * m.psi_pm)])
    # the voltage an inverter holds over the period (constant in the stationary frame) that brings the
    # current back to i_r: in the rotor frame, complex, d psi/dt = a psi + (R/L) psi_pm + u e^(-j w t)
    # with a = -R/L - j w, solved in closed form over one period (non-salient: psi = L i + psi_pm)
    L = m.L_d
    assert m.L_q == L
    r, a = m.R_s / L, -m.R_s / L - 1j * w
    psi0 = L * complex(*i_r) + m.psi_pm
    E = np.exp(a * T_s)
    u = (psi0 * (1 - E) - r * m.psi_pm * (E - 1) / a) / (E * (np.exp(r * T_s) - 1) / r)
    u_z = np.array([u.real, u.imag])

    def meas(th):  # current at t_k, voltage held over the period
        return np.concatenate([rot(th) @ i_r, rot(th) @ u_z])

    n = 4000
    th = w * T_s * np.arange(n)
    M = np.array([meas(t) for t in th])
    x0 = np.array([*(w * m.psi_pm * np.array([0.0, 1.0])), 0.0, w, 0.0])  # last: the contract's counter
    xs, _ = run_trajectory(setup, M, x0)

    def to_rotor(x, th):
        d = math.remainder(th - x[2], 2 * math.pi)
        return np.array([*(rot(-th) @ x[0:2]), d, x[3]])

    def F(x_r):  # one step from theta = 0, in the rotor frame
        x = np.array([x_r[0], x_r[1], -x_r[2], x_r[3], 0.0])
        x1, _ = run_trajectory(setup, meas(0.0)[None, :], x)
        return to_rotor(x1[0], w * T_s)

    x_star = to_rotor(xs[-1], th[-1] + w * T_s)
    assert np.allclose(F(x_star), x_star, rtol=0, atol=1e-9 * np.abs(x_star).max())
    assert lin.theta_err[0] == pytest.approx(x_star[2], abs=1e-9)
    h = 1e-6 * np.maximum(np.abs(x_star), 1.0)
    A = np.column_stack(
        [(F(x_star + h[j] * e) - F(x_star - h[j] * e)) / (2 * h[j]) for j, e in enumerate(np.eye(4))]
    )
    p_fd = np.sort_complex(np.log(np.linalg.eigvals(A).astype(complex)) / T_s)
    p = np.sort_complex(lin.poles_discrete[0])
    assert np.allclose(p, p_fd, rtol=1e-5, atol=1e-3), (p, p_fd)
    # the continuous observer's poles are close to the sampled one's at 10 kHz
    assert np.allclose(np.sort(lin.poles[0].real), np.sort(p.real), rtol=0.15)


# ------------------------------------------------------------------------------------------ tune
def _dense_points(table):
    return (np.array([p["w_m_rad_s"] for p in table.points]), np.array([p["T_e_Nm"] for p in table.points]))


def test_tune_goes_through_the_shared_pipeline_and_the_analysis_confirms_its_table(drive, tuned):
    """The family's law ``pll`` is tuned by the shared global phase, NLP, tie-break and pointwise bound
    (families/pll/tuning.py gives only its TuningModel); the analysis path confirms the table."""
    table = read_gain_table(tuned)
    assert table.law == "pll" and table.drive["kind"] == "pmsm-pll"
    w_pll = table.gains["w_pll"]
    assert w_pll != pytest.approx(drive.observer.w_pll, rel=1e-3)
    s = table.summary
    assert s["global_phase"]["candidates"] == GRID + 1  # its log grid and the drive's gain
    assert "tie_break" in s["selection"] and "bound" in s and s["exchange_rounds"] >= 1
    floor = s["decay_floor_1_s"]
    assert floor == pytest.approx(pll_tuning.FLOOR * drive.observer.w_pll)
    assert table.envelope["constraints"]["w_pll_max_rad_s"] == pytest.approx(20 * drive.observer.w_pll)
    W, T = _dense_points(table)
    lin = FAMILY.linearize(drive, FAMILY.gains(drive, table=table), W, T)
    assert np.min(lin.worst_damping) == pytest.approx(s["worst_damping"], abs=1e-9)
    assert np.min(lin.decay_rate) == pytest.approx(s["min_decay_rate"], rel=1e-9)
    assert s["min_decay_rate"] >= floor * (1 - 1e-6)
    # the drive file's bandwidth is better damped but settles slower than the floor
    assert s["baseline_min_decay_rate"] < floor <= s["min_decay_rate"]
    csv = (tuned.parent / "gains_pll.csv").read_text().splitlines()
    assert csv[2].startswith("w_m_pu,w_m_rad_s,T_e_Nm,w_pll_rad_s,damping,decay_rate_1_s,pole0_re_1_s")
    assert len(csv) == 3 + len(table.points)
    assert (tuned.parent / "speeds_pll.csv").exists()


def test_tuned_bandwidth_matches_a_brute_force_search_and_stays_below_its_bound(drive, tuned):
    """Independent of the tuner: every bandwidth of a 40-point log grid over the box, refined three
    times 10-fold around the best (21 points over the neighbouring steps each time), through the
    family's loop (its continuous poles: the equilibria of every bandwidth at every point in one batched
    call of the shared equilibrium_points, as FAMILY.linearize computes them; FAMILY.linearize itself
    at the best bandwidth, below) on the table's dense grid; the best worst damping among those that
    decay at least at the floor. The tuner may stop up to its tie tolerance (5e-4) below the best it
    found, and the brute force resolves the bandwidth to better than 0.02 % (103 bandwidths; 80 points
    refined twice 20-fold took 162 for 0.02 %): tolerance 1e-3 in damping, 1 % in the bandwidth. The
    pointwise bound (no bandwidth does better at any speed) is at least the tuned worst damping."""
    from sensorless.design.poles import max_real, worst_damping
    from sensorless.design.rotor_frame import equilibrium_points

    table = read_gain_table(tuned)
    s = table.summary
    W, T = _dense_points(table)
    floor = s["decay_floor_1_s"]
    lo, hi = table.envelope["bounds"]["w_pll"]
    loop, motor = design.rotor_loop(), design.pmsm_plant(drive.motor)

    def best_of(ws):
        p = np.column_stack([FAMILY.runtime(drive, GainSet("pll", {"w_pll": float(w)})).p for w in ws])
        n = W.size
        poles = equilibrium_points(
            loop, np.tile(W, ws.size), np.tile(T, ws.size), motor, np.repeat(p, n, axis=1)
        ).poles()
        z = worst_damping(poles).reshape(ws.size, n).min(axis=1)
        d = (-max_real(poles)).reshape(ws.size, n).min(axis=1)
        z = np.where(d >= floor, z, -np.inf)
        k = int(np.argmax(z))
        return ws[k], z[k]

    ws = np.geomspace(lo, hi, 40)
    for _ in range(3):  # refine around the best: its neighbours' interval, 10x finer
        w_best, z_best = best_of(ws)
        step = ws[1] / ws[0]
        ws = np.geomspace(w_best / step, w_best * step, 21)
    w_best, z_best = best_of(ws)
    assert np.isfinite(z_best)
    lin = FAMILY.linearize(drive, GainSet("pll", {"w_pll": float(w_best)}), W, T)
    assert np.min(lin.worst_damping) == pytest.approx(z_best, abs=1e-9)  # the family's own analysis
    assert s["worst_damping"] == pytest.approx(z_best, abs=1e-3)
    assert table.gains["w_pll"] == pytest.approx(w_best, rel=0.01)
    assert s["bound"]["worst_damping"] >= s["worst_damping"] - 1e-9
    assert s["bound"]["gap"] == pytest.approx(s["bound"]["worst_damping"] - s["worst_damping"])


# --------------------------------------------------------------------------------------- codegen
def _trajectory(drive, n=12000, seed=3):
    """Measurements of a motor at a varying speed and torque (positive speeds, the observer starting
    unlocked from zero), with current and voltage noise and three NaN samples."""
    m, T_s, wb = drive.motor, drive.T_s, drive.w_base
    t = np.arange(n) * T_s
    w = np.interp(t, [0, 0.2, 0.5, 0.8, 1.2], [0.3, 1.0, 1.0, 0.2, 0.25]) * wb
    th = 0.4 + np.concatenate([[0.0], np.cumsum(w[:-1]) * T_s])
    i_q = np.interp(t, [0, 0.4, 0.6, 1.2], [0.5, 1.0, -1.0, 0.3]) * drive.T_N / (1.5 * m.p * m.psi_pm)
    u_d, u_q = -w * m.L_q * i_q, m.R_s * i_q + w * m.psi_pm
    c, s = np.cos(th), np.sin(th)
    cm, sm = np.cos(th + w * T_s / 2), np.sin(th + w * T_s / 2)
    rng = np.random.default_rng(seed)
    M = np.column_stack([-s * i_q, c * i_q, cm * u_d - sm * u_q, sm * u_d + cm * u_q])
    M += rng.standard_normal(M.shape) * np.array([0.02, 0.02, 0.5, 0.5])
    M[[1000, 5000, 5001], [0, 3, 2]] = np.nan
    return M


@pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")
def test_codegen_compiles_strictly_and_replays_like_python(drive, tuned, tmp_path, capsys):
    src = tmp_path / "c"
    code, stdout, err = run(
        ["codegen", DRIVE, "--gains", tuned, "--precision", "double", "--out", src], capsys
    )
    assert code == 0, err
    assert "pll_servo_init, pll_servo_step" in stdout and "pll table" in stdout
    exe = tmp_path / "example"
    r = subprocess.run(
        [CC, *STRICT, "-o", exe, src / "main.c", src / "pll_servo.c", "-lm"], capture_output=True, text=True
    )
    assert r.returncode == 0 and r.stderr == "", r.stderr
    meas = _trajectory(drive)
    f = tmp_path / "samples.bin"
    np.ascontiguousarray(meas, dtype="<f8").tofile(f)
    r = subprocess.run([str(exe), str(f)], capture_output=True)
    assert r.returncode == 0 and r.stderr == b"", r.stderr.decode()
    c = np.frombuffer(r.stdout, "<f8").reshape(len(meas), len(OUTPUTS) + len(STATE))
    setup = FAMILY.runtime(drive, FAMILY.gains(drive, table=read_gain_table(tuned), table_file=str(tuned)))
    xs, ys = run_trajectory(setup, meas)
    ref = np.hstack([ys, xs])
    d = np.abs(c - ref)
    for j in (1, len(OUTPUTS) + 2):  # theta_hat, state theta: modulo 2 pi
        d[:, j] = np.abs(np.angle(np.exp(1j * (c[:, j] - ref[:, j]))))
    rel = d.max(axis=0) / np.maximum(np.abs(ref).max(axis=0), 1e-300)
    names = [f.name for f in OUTPUTS] + [f"x.{f.name}" for f in STATE]
    assert rel.max() < 1e-12, dict(zip(names, rel, strict=True))
    valid = ref[:, [f.name for f in OUTPUTS].index("valid")]
    assert valid.sum() == len(meas) - 3  # the NaN samples coasted, in C as in Python
    w_hat = ref[:, 0]
    assert abs(w_hat[-1] / drive.w_base - 0.25) < 0.01  # a real run: the PLL locked and tracks
    # float: strict compilation too
    code, _, err = run(["codegen", DRIVE, "--precision", "float", "--out", tmp_path / "f"], capsys)
    assert code == 0, err
    r = subprocess.run(
        [CC, *STRICT, "-c", "-o", tmp_path / "f.o", tmp_path / "f" / "pll_servo.c"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0 and r.stderr == "", r.stderr


PLL_RECOVER = 10_000  # samples (1 s at 100 us): the PLL's pull-in from anywhere within its bounds


@pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")
@pytest.mark.parametrize("precision", ["double", "float"])
def test_generated_c_keeps_its_promises_under_hostile_input_and_recovers(drive, tmp_path, precision):
    """The runtime contract's guard, bounds and self-reset are generic: the test family declares its
    bounds (the angle, the PLL integrator within +-w_max, the EMF state) and the contract's fields, and
    its generated C passes the same fuzzing as the built-in families (tests/helpers/fuzz.py: >= 10^6
    seeded steps under sanitizers, every range and bound on every step, recovery within PLL_RECOVER
    clean samples). The clean samples are of the motor at 0.5-1 p.u.: the PLL's pull-in time grows
    with the square of the speed error it starts from (up to w_max + 1 p.u. = 3 p.u.; measured up to
    about 7000 samples over 16 million steps). Below 0.5 p.u. the PLL can lock into a limit cycle
    instead, e.g. at 0.3 p.u. from w_i slightly below 0 (its speed sign resolves the 180-degree
    ambiguity of (2) wrongly): a property of this family's PLL, which the fuzzing found, not of the
    runtime contract."""
    rows = steady_rows(np.random.default_rng(2000), 20, (0.5, 1.0), drive.w_base, drive.T_N)
    m = drive.motor
    segments = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), drive.T_s, rows, PLL_RECOVER + 1000)
    r = fuzz(
        FAMILY.runtime(drive, FAMILY.gains(drive)),
        segments,
        precision=precision,
        recover=PLL_RECOVER,
        tol_theta=0.1,
        tol_w=0.05 * drive.w_base,
        seed=21 + (precision == "float"),
        work=tmp_path,
    )
    assert r["steps"] >= 1_000_000 and r["resets"] > 10 and r["recovery_max"] <= PLL_RECOVER


# -------------------------------------------------------------------------------------- simulate
def test_simulate_runs_its_scenario_on_the_shared_drive_loop(drive, tuned, tmp_path, capsys):
    code, stdout, _ = run(["simulate", DRIVE, "--list"], capsys)
    assert code == 0 and stdout.split()[0] == "speed_steps"
    out = tmp_path / "sim"
    args = ["simulate", DRIVE, "--scenario", SCENARIO, "--gains", tuned, "--quiet", "--out", out]
    with figure_files_off():  # the traces are read here; the figure built, not rendered (as above)
        code, stdout, err = run(args, capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["speed_steps.png", "speed_steps.svg", "traces.csv"]
    assert "pll table" in stdout and "position error: RMS" in stdout
    tr = read_csv(out / "traces.csv")
    assert {"e_alpha", "e_beta", "eps", "valid"} <= set(tr)  # the observer's own outputs are recorded
    assert tr["t"][-1] == pytest.approx(0.6) and np.all(tr["valid"] == 1)
    assert abs(np.degrees(tr["theta_err"][0])) == pytest.approx(20, abs=0.01)  # the scenario's start
    tail = tr["t"] > 0.55
    assert np.abs(np.degrees(tr["theta_err"][tail])).max() < 2  # the PLL has converged
    assert np.abs(tr["w_m"][tail] / drive.w_base - 0.4).max() < 0.02  # and the drive tracks 0.4 p.u.
    assert np.abs(tr["T_e"][tail] - drive.T_N).max() < 0.1 * drive.T_N  # carrying the nominal load


# ---------------------------------------------------------------------------------------- report
def test_report_has_a_verdict_a_figure_and_a_time_domain_check(tuned, tmp_path, capsys):
    code, stdout, err = run(["report", DRIVE, "--gains", tuned, "--quick", "--out", tmp_path], capsys)
    assert code == 0, err
    assert "verdict: pass" in stdout
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["format"] == "sensorless-report/1" and data["review"] == "tuned"
    assert set(data["analysis"]) == {"drive file", "tuned"} and data["verdict"]["status"] == "pass"
    assert data["analysis"]["tuned"]["w_pll"] == pytest.approx(read_gain_table(tuned).gains["w_pll"])
    assert {c["name"]: c for c in data["time_domain"]}["speed_steps"]["metrics"]["rms_theta_err_deg"] < 10
    html = (tmp_path / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "Verdict: pass" in html
    assert html.count("<figure") >= 2 and "Time-domain checks" in html


def test_foreign_options_and_wrong_gains_are_one_line_errors(tmp_path, capsys):
    bad = tmp_path / "t.json"
    table = {"format": "sensorless-gain-table/2", "drive": {"name": "x"}, "law": "constant"}
    bad.write_text(json.dumps({**table, "gains": {"g": 1, "Gamma": 1}}))
    for args, words in (
        (["analyze", DRIVE, "--study"], "--study: not an option"),
        (["tune", DRIVE, "--g-max", "3"], "--g-max: not an option"),
        (["tune", DRIVE, "--law", "law16"], "cannot be tuned"),
        (["codegen", DRIVE, "--gain-set", "speed", "--out", tmp_path / "c"], "one gain"),
        (["simulate", DRIVE, "--scenario", "speed_steps", "--injection", "on"], "--injection"),
        (["simulate", DRIVE, "--scenario", "speed_steps", "--gains", bad], "its laws: pll"),
    ):
        code, _, err = run(args, capsys)
        assert code == 2 and err.count("\n") == 1 and words in err, (args, err)


# ---------------------------------------------------------------------------- lacking capabilities
class DriveFilesOnly(ObserverFamily):
    """A family record that only loads drive files (the PLL family's schema, under its own kind)."""

    kind = "pmsm-bare"
    name = "pmsm_bare"
    title = "a family that only loads drive files"
    citation = ""

    def load(self, data, file, digest):
        return design.load(data, file, digest, self.kind)


class GainsOnly(DriveFilesOnly):
    """... and gives gains, but has no runtime observer."""

    kind = "pmsm-gains"
    name = "pmsm_gains"

    def gains(self, drive, *, name=None, table=None, table_file=""):
        return design.drive_gains(drive)


class NoSteadyState(GainsOnly):
    """... and runs on the shared PMSM drive loop, but its runtime observer has no steady state."""

    kind = "pmsm-nss"
    name = "pmsm_nss"

    def runtime(self, drive, gains, *, discretization=None):
        setup = FAMILY.runtime(drive, gains, discretization=discretization)
        return dataclasses.replace(setup, observer=dataclasses.replace(setup.observer, steady_state=None))

    def simulation(self, drive, scenario, gains):
        setup = self.runtime(drive, gains or self.gains(drive))
        return design.loop_setup(drive, scenario, setup, meta={})


def _files_of(family, tmp_path):
    """A drive and a scenario file of ``family``'s kind (the PLL family's, relabelled)."""
    drive, scenario = tmp_path / "drive.toml", tmp_path / "scenario.toml"
    drive.write_text(Path(DRIVE).read_text().replace('kind = "pmsm-pll"', f'kind = "{family.kind}"'))
    scenario.write_text(Path(SCENARIO).read_text().replace('kind = "pmsm-pll"', f'kind = "{family.kind}"'))
    return drive, scenario


def test_a_family_lacking_capabilities_gets_one_line_errors_from_every_command(tmp_path, capsys):
    fam = DriveFilesOnly()
    drive, scenario = _files_of(fam, tmp_path)
    out = tmp_path / "out"
    with registered(fam):
        assert load_drive(drive).kind == "pmsm-bare"
        for args in (
            ["analyze", drive, "--out", out],
            ["tune", drive, "--out", out],
            ["codegen", drive, "--out", out],
            ["simulate", drive, "--scenario", scenario, "--quiet", "--out", out],
            ["report", drive, "--out", out],
        ):
            code, _, err = run(args, capsys)
            assert code == 2, (args[0], err)
            assert err.count("\n") == 1 and "Traceback" not in err, (args[0], err)
            assert err.startswith(f"sensorless {args[0]}: error: ") and "pmsm_bare" in err, (args[0], err)
    assert not out.exists()  # nothing written


@pytest.mark.parametrize(
    ("cls", "command", "words"),
    [
        (GainsOnly, "codegen", "observer family 'pmsm_gains' has no runtime observer"),
        (
            NoSteadyState,
            "simulate",
            "observer family 'pmsm_nss': its runtime observer pmsm_pll has no steady",
        ),
    ],
)
def test_a_partial_family_is_told_what_it_lacks_in_one_line(cls, command, words, tmp_path, capsys):
    fam = cls()
    drive, scenario = _files_of(fam, tmp_path)
    extra = ["--scenario", scenario, "--quiet"] if command == "simulate" else []
    with registered(fam):
        code, _, err = run([command, drive, *extra, "--out", tmp_path / "out"], capsys)
    assert code == 2 and err.startswith(f"sensorless {command}: error: ")
    assert err.count("\n") == 1 and words in err and "--discretization" not in err, err
    assert not (tmp_path / "out").exists()
