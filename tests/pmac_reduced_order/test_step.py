"""The discrete observer step (the Function that runs and is generated to C) and the paper's open choices."""

import casadi as ca
import numpy as np
import pytest
from sensorless.symbolic.pmac import EmfSeries, flux_derivative
from sensorless.symbolic.pmac_reduced_order.observer import ObserverParams, estimates, rates, zeta_tau
from sensorless.symbolic.pmac_reduced_order.step import (
    DISCRETIZATIONS,
    MEAS,
    OUTPUTS,
    STATE,
    param_names,
    runtime_observer,
)


def test_step_function_interface():
    """The runtime contract (symbolic/runtime.py): named vectors, g, Gamma and the EMF series as
    runtime parameters, no scheduled gains, built once per series and scheme."""
    obs = runtime_observer((1, 5))
    F = obs.core("rk2-model")
    assert F.name() == "pmac_reduced_order_1_5_core_rk2_model"
    assert F.name_in() == ["x", "meas", "p", "lam"] and F.name_out() == ["x_next", "y"]
    assert [f.name for f in OUTPUTS] == [
        "w_hat",
        "theta_hat",
        "T_L_hat",
        "e_alpha",
        "e_beta",
        "phi_alpha",
        "phi_beta",
        "valid",
        "reset",
    ]
    assert [F.size1_in(k) for k in range(4)] == [len(STATE), len(MEAS), 10, 0]
    assert param_names((1, 5)) == ("R", "L", "J", "p_r", "g", "Gamma", "T_s", "T_max", "Phi_1", "Phi_5")
    assert [f.name for f in obs.params] == list(param_names((1, 5)))
    assert runtime_observer((1, 5)) is obs and obs.core("rk2-model") is F  # built once
    assert obs.discretizations[0] == "rk2-model"
    with pytest.raises(ValueError, match="unknown discretization"):
        runtime_observer((1,)).core("rk4")


def exact_state(drive, theta, w, T_L_hat=0.0):
    """Observer state agreeing with a sinusoidal-plus-harmonics motor at (theta, w), no load, and the
    samples (i, v) of that instant: i = 0, v = e (unloaded, no current)."""
    emf = EmfSeries(drive.estimate.harmonics, drive.estimate.Phi)
    p_r = drive.motor.p_r
    e = np.asarray(flux_derivative(theta, emf)).ravel() * w / p_r
    return np.r_[e, T_L_hat, theta, w, 0, 0, e, 0], e  # the last: no sample rejected


@pytest.mark.parametrize("method", sorted(DISCRETIZATIONS))
@pytest.mark.parametrize("sign", [1, -1])
def test_every_scheme_tracks_both_directions(deangelo2006, method, sign):
    """Unloaded motor at +-250 r/min, observer started 0.2 rad behind with the speed 5 % off: every
    scheme converges to the right position (the atan2 branch follows the speed sign, eq. (18)) and
    speed sign (14). Tolerances are loose: this is about branch and sign, not accuracy."""
    w = sign * float(deangelo2006.rpm_to_w(250.0))
    T_s = deangelo2006.control.T_s
    n = 600  # 0.11 s: 40 time constants of the EMF error dynamics (g = 400)
    th = 0.3 + w * T_s * np.arange(1, n + 1)
    emf = EmfSeries(deangelo2006.motor.harmonics, deangelo2006.motor.Phi)
    phi = np.asarray(ca.Function("phi", [(t := ca.SX.sym("t"))], [flux_derivative(t, emf)]).map(n)(th[None]))
    e = phi * w / deangelo2006.motor.p_r
    x0, _ = exact_state(deangelo2006, 0.3 - 0.2 * sign, 1.05 * w)
    x0[5:7], x0[7:9] = 0, np.asarray(flux_derivative(0.3, emf)).ravel() * w / deangelo2006.motor.p_r
    F = runtime_observer(tuple(deangelo2006.estimate.harmonics)).core(method)
    x, u = ca.MX.sym("x", len(STATE)), ca.MX.sym("u", 4)
    x_next, y = F(x, u, deangelo2006.observer_params(), ca.DM(0, 1))
    G = ca.Function("g", [x, u], [x_next, y[0:2]]).mapaccum(n)
    _, out = G(x0, np.vstack([np.zeros((2, n)), e]))
    w_hat, th_hat = np.asarray(out)
    assert np.all(np.sign(w_hat[-100:]) == sign)
    assert np.abs(np.angle(np.exp(1j * (th[-100:] - th_hat[-100:])))).max() < 0.05
    assert np.abs(w_hat[-100:] / w - 1).max() < 0.02


def test_position_branch_and_signed_speed_at_negative_speed(deangelo2006):
    """(18) as atan2(-e_a1, e_b1) is off by pi at negative speed; with the sign (14) the estimate is the
    rotor position and the speed is negative (symbolic/pmac_reduced_order/observer.py)."""
    p = ObserverParams(0.01, 1e-4, 0.78, 8.0, 400.0, 1e4)
    emf = EmfSeries((1, 5), ca.DM(deangelo2006.motor.Phi))
    theta, w = 1.1, -200.0
    e = flux_derivative(theta, emf) * w / 8.0
    i = ca.DM([3.0, -2.0])
    zeta, tau = zeta_tau(e, 0.0, flux_derivative(theta, emf), i, p)
    est = estimates(zeta, tau, i, theta, w, -1, p, emf)
    assert float(est.theta_hat) == pytest.approx(theta, abs=1e-12)
    assert float(est.w_hat) == pytest.approx(w, rel=1e-12)
    assert float(est.theta_raw) == pytest.approx(theta - np.pi, abs=1e-12)  # the literal branch


@pytest.mark.parametrize("w", [200.0, -200.0])
def test_rates_keep_the_exact_orbit_in_both_directions(deangelo2006, w):
    """On the exact orbit (e_hat = e, T_L_hat = T_L) the observer's rates equal the true rates, so the
    orbit is a solution: d zeta/dt = de/dt + g L di/dt. The literal (16), which multiplies d phi_hat/dt by
    the unsigned speed (13), breaks this at negative speed (the paper's (9) has the signed speed)."""
    p = ObserverParams(0.01, 1e-4, 0.78, 8.0, 400.0, 1e4)
    Phi = deangelo2006.motor.Phi
    emf = EmfSeries((1, 5), ca.DM(Phi))
    th = ca.SX.sym("th")
    T = 5.0
    phi = flux_derivative(th, emf)
    i = T * phi / ca.dot(phi, phi)  # ripple-free current: constant torque T, constant speed
    e = phi * w / 8.0
    di = ca.jacobian(i, th) * w
    de = ca.jacobian(e, th) * w
    v = 0.01 * i + 1e-4 * di + e
    zeta, tau = zeta_tau(e, T, phi, i, p)
    est = estimates(zeta, tau, i, th, w, np.sign(w), p, emf)
    dzeta, dtau = rates(est, i, v, p)
    literal = rates(est._replace(w_hat=ca.fabs(est.w_hat)), i, v, p)[0]
    f = ca.Function(
        "f", [th], [dzeta - de - 400 * 1e-4 * di, dtau - ca.jacobian(tau, th) * w, literal - dzeta]
    )
    for t in np.linspace(0, 2 * np.pi, 7):
        r_zeta, r_tau, lit = (np.asarray(a).ravel() for a in f(t))
        assert np.abs(r_zeta).max() < 1e-9 * abs(w) ** 2
        assert abs(r_tau[0]) < 1e-6
        if w > 0:
            assert np.abs(lit).max() < 1e-12
        else:  # off by 2 w^2 d phi/d theta / p_r: a large EMF-rate error
            assert np.abs(lit).max() > 0.1 * w**2 * Phi[0] / 8.0


@pytest.mark.parametrize("method", ["rk2-model", "rk2"])
def test_one_absurd_sample_is_rejected_and_forgotten(deangelo2006, method):
    """Guard and coasting (symbolic/pmac_reduced_order/step.py): one absurd but finite sample (an ADC
    glitch) or a NaN on any channel is rejected (with the next period, whose first stage uses the
    stored sample, if it was stored), and the observer is back within 0.1 s. Before the speed range
    |w_hat| T_s <= pi/2 was part of the guard, a 1e5 A or 1e20 V sample made it accept a diverging
    state, then reject every later sample for good. Coasting stores the newest sample only when it
    is finite."""
    from helpers.plant_pmac import codegen_trajectory
    from sensorless.design.pmac_reduced_order import FAMILY
    from sensorless.design.runtime import run_trajectory

    setup = FAMILY.runtime(deangelo2006, FAMILY.gains(deangelo2006), discretization=method)
    meas = codegen_trajectory(deangelo2006, ((0.5, 250, 250, 5.0),))["meas"]
    _, clean = run_trajectory(setup, meas)
    k = 1500
    for ch in range(4):
        for v in (1e5, -1e20, np.nan):
            m = meas.copy()
            m[k, ch] = v
            xs, ys = run_trajectory(setup, m)
            # rejected: the glitch, and the next period (whose stage at t_(k-1) uses it) if it was stored
            n = 2 if np.isfinite(v) else 1
            assert np.all(ys[k : k + n, 7] == 0) and np.all(ys[k + n :, 7] == 1)
            assert xs[k, 5 + ch] == (v if np.isfinite(v) else meas[k - 1, ch])  # newest finite sample
            back = slice(k + 550, None)  # 0.1 s on
            assert np.abs(ys[back, 0] - clean[back, 0]).max() < 1e-3 * np.abs(clean[back, 0]).max()
