"""The constant law (De Angelo et al. 2006: g, Gamma): the closed form against an independent scan of the
hand-derived characteristic polynomial, the tuned gains against the paper's on the dense discrete-time
grid (through the analysis path), the gain table, and the CLI."""

import dataclasses
import json

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.gain_table import read_gain_table
from sensorless.design.pmac_reduced_order.linearize import analyze
from sensorless.reports.cli.main import main
from sensorless.reports.gain_csv import table_csv
from sensorless.tuning.family import tunable_for
from sensorless.tuning.pmac_reduced_order.settings import closed_form, default_settings, grid, speed_grid
from sensorless.tuning.pmac_reduced_order.tuner import tune_constant_gains

pytestmark = pytest.mark.long(20)  # CPU seconds of this file, measured: scheduled first (tests/conftest.py)


def hand_poles(g, Gamma, Phi1, J):
    """Roots of (s + g)(s^2 + g s + Gamma (Phi1/J)^2): the hand derivation of the family doc."""
    return np.roots(np.polymul([1, g], [1, g, Gamma * (Phi1 / J) ** 2]))


def hand_poles_batched(g, Gamma, Phi1, J):
    """hand_poles for arrays of g and Gamma: the eigenvalues of each cubic's companion matrix (what
    np.roots computes, one polynomial at a time)."""
    # (s + g)(s^2 + g s + K) = s^3 + 2 g s^2 + (g^2 + K) s + g K, K = Gamma (Phi1/J)^2
    K = Gamma * (Phi1 / J) ** 2
    C = np.zeros((g.size, 3, 3))
    C[:, 0, :] = -np.stack([2 * g, g**2 + K, g * K], axis=1)
    C[:, 1, 0] = C[:, 2, 1] = 1.0
    return np.linalg.eigvals(C)


@pytest.mark.parametrize("bounds", [(800.0, 1e6), (800.0, 2e4), (300.0, 1e6)])
def test_closed_form_is_the_best_of_a_scan(deangelo2006, bounds):
    """No (g, Gamma) in the box with damping >= 0.707 decays faster than the closed form, which is
    itself feasible (damping 1): an independent scan of the hand-derived polynomial."""
    g_max, G_max = bounds
    Phi1, J = deangelo2006.estimate.Phi[0], deangelo2006.estimate.J
    g, G = closed_form(deangelo2006, g_max, G_max)
    assert g <= g_max * (1 + 1e-12) and G <= G_max * (1 + 1e-12)
    p = hand_poles(g, G, Phi1, J)
    best = -p.real.max()
    assert (-p.real / np.abs(p)).min() >= 1 - 1e-6
    # the scan, batched: every (g, Gamma) pair's cubic through its companion matrix (as np.roots)
    gs, Gs = (a.ravel() for a in np.meshgrid(np.linspace(4, g_max, 120), np.geomspace(100, G_max, 120)))
    q = hand_poles_batched(gs, Gs, Phi1, J)
    np.testing.assert_allclose(np.sort_complex(q[7]), np.sort_complex(hand_poles(gs[7], Gs[7], Phi1, J)))
    ok = (-q.real / np.abs(q)).min(axis=1) >= 1 / np.sqrt(2)
    scan = max(0.0, float((-q.real.max(axis=1))[ok].max(initial=0.0)))
    assert best >= scan * (1 - 1e-3)
    assert best <= scan * 1.05  # the scan gets close: the bound is attained, not just an upper bound


def small_settings(drive):
    s = default_settings(drive)
    # the observer's poles alone: what these tests check (the whole drive's constraint, 30 s of CPU more
    # here: test_tune_whole_drive.py)
    return dataclasses.replace(s, speeds_rpm=(250.0, 1000.0), loads_Nm=(0.0, 5.0), whole_drive=False)


@pytest.fixture(scope="module")
def deangelo(deangelo2006):
    return tune_constant_gains(deangelo2006, small_settings(deangelo2006))


def test_tuned_beat_the_papers_gains_on_the_dense_grid(deangelo2006, deangelo):
    """Re-verified through design/linearize_pmac.analyze: the tuned gains decay faster than the
    paper's g = 400, Gamma = 10000 at every dense point's worst, meet the damping floor, and the
    table reports exactly that grid."""
    st = small_settings(deangelo2006)
    n, T = grid(st, st.dense_factor)
    assert speed_grid(st.speeds_rpm, st.dense_factor).size == 5 and n.size == 25
    w = deangelo2006.rpm_to_w(n)
    ref = analyze(deangelo2006, w, T, g=deangelo.g, Gamma=deangelo.Gamma)
    ref0 = analyze(deangelo2006, w, T, g=400.0, Gamma=10000.0)
    s = deangelo.table.summary
    decay, decay0 = -ref.poles_discrete.real.max(axis=1), -ref0.poles_discrete.real.max(axis=1)
    assert s["slowest_decay_rate"] == pytest.approx(decay.min(), rel=1e-9)
    assert s["baseline_slowest_decay_rate"] == pytest.approx(decay0.min(), rel=1e-9)
    assert s["baseline_parameters"] == {"g": 400.0, "Gamma": 10000.0}
    assert decay.min() > 5 * decay0.min()  # much faster than the paper's 10.7 1/s (the observer alone)
    assert np.nanmin(ref.damping_discrete) >= st.min_damping - 1e-9
    assert len(deangelo.table.points) == n.size
    assert deangelo.g <= st.g_max and deangelo.Gamma <= st.Gamma_max


def test_constant_table_round_trip(tmp_path, deangelo):
    doc = json.loads(deangelo.table.to_json())
    assert doc["law"] == "constant" and set(doc["gains"]) == {"g", "Gamma"}
    f = tmp_path / "t.json"
    f.write_text(deangelo.table.to_json())
    assert read_gain_table(f).gains == doc["gains"]
    csv = table_csv(deangelo.table, tunable_for(load_drive("deangelo2006"), "constant").columns).splitlines()
    assert csv[2].startswith("n_rpm,w_rad_s,T_L_Nm,g_1_s,Gamma_A2s2,damping,decay_rate_1_s")
    assert len(csv) == 3 + len(deangelo.table.points)


def test_cli_tune_refuses_another_familys_options(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["tune", "deangelo2006", "--lambda-max", "5R_s_hat", "--out", str(out)]) == 2
    assert "--lambda-max" in capsys.readouterr().err
    assert main(["tune", "piippo2008", "--g-max", "800", "--out", str(out)]) == 2
    assert "--g-max" in capsys.readouterr().err
    assert main(["tune", "deangelo2006", "--g-max", "1", "--out", str(out)]) == 2  # g_max < g_min
    assert "--g-max" in capsys.readouterr().err
    assert not out.exists()


def test_noise_figure_matches_the_observer_run_with_noisy_currents(deangelo2006):
    """The RMS of the position and speed estimates from current-sensor noise (the discrete observer's
    linearization, a sample's noise entering two steps; design/noise.py) against the observer step that
    runs, fed by the motor's samples plus white noise of i_noise per axis: within 15 %."""
    import casadi as ca
    from sensorless.design.pmac_reduced_order.operating_point import (
        analysis_arguments,
        exact_state_function,
        plant_signals,
        symbols,
    )
    from sensorless.symbolic.frames import wrap_angle
    from sensorless.symbolic.pmac_reduced_order.step import N_STATE, step

    d, g, G = deangelo2006, 800.0, 4e5
    w, T_L = d.rpm_to_w(250.0), 5.0
    r = analyze(d, w, T_L, g=g, Gamma=G, noise=True)
    om, oo, motor, params = analysis_arguments(d, g=g, Gamma=G)
    s = symbols(om, oo)
    x, nz = ca.SX.sym("x", N_STATE), ca.SX.sym("n", 2)
    th0 = ca.SX.sym("theta")
    th1 = th0 + s["w"] * d.T_s
    sig1, _ = plant_signals(s, th1, om)
    st = step(x, sig1.i + nz, sig1.v, s["params"], oo, d.control.discretization)
    err = ca.vertcat(wrap_angle(th1 - st.est.theta_hat), s["w"] - st.est.w_hat)
    f = ca.Function("f", [ca.vertcat(x, th0), nz, s["w"], s["T_L"], s["motor"], s["params"]],
                    [ca.vertcat(st.x_next, wrap_angle(th1)), err])  # fmt: skip
    N = 40_000
    F = f.mapaccum(N)
    x0 = np.asarray(exact_state_function(om, oo, True)(0.3, w, T_L, motor, params)).ravel()
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, d.control.i_noise, size=(2, N))
    _, e = F(np.append(x0, 0.3), noise, w, T_L, motor, params)
    e = np.asarray(e)[:, N // 4 :]
    sim = np.sqrt(np.mean((e - e.mean(axis=1, keepdims=True)) ** 2, axis=1))
    np.testing.assert_allclose(sim, r.noise[0], rtol=0.15)
