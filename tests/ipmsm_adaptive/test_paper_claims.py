"""The paper's analytical findings (Section IV-B, Figs. 4-5, Section V) reproduced by the analysis."""

import dataclasses

import numpy as np
import pytest
from sensorless.design.ipmsm_adaptive.linearize import drive_arguments, linearize
from sensorless.design.ipmsm_adaptive.operating_point import PARAM_NAMES, residual_function

GAINS = ["zero", "constant", "speed"]


def speeds(drive, lo, hi, n):
    return np.linspace(lo, hi, n) * drive.base.w


@pytest.mark.parametrize("gain", GAINS)
def test_rhp_pole_at_low_motoring_speed_only(drive, gain):
    """Fig. 4/5: at nominal motoring torque one real pole is in the RHP at very low positive speed
    (the paper: about |w_m0| < 0.02 p.u.); none in the regenerating mode (negative speed)."""
    w = speeds(drive, 0.0005, 0.005, 10)
    s = linearize(drive, w, drive.T_N, gain=gain)
    assert (s.max_real > 0).all()
    rhp = s.poles[np.arange(w.size), np.argmax(s.poles.real, axis=1)]
    assert np.all(np.abs(rhp.imag) < 1e-9), "the unstable pole is real"
    # the band ends at a few hundredths of a p.u.; beyond it everything is stable up to 1 p.u.
    w_hi = speeds(drive, 0.05, 1.0, 200)
    assert (linearize(drive, w_hi, drive.T_N, gain=gain).max_real < 0).all()
    w_reg = speeds(drive, -1.0, -0.0005, 400)
    assert (linearize(drive, w_reg, drive.T_N, gain=gain).max_real < 0).all()
    # and the edge is where the paper puts it (order 0.02 p.u.)
    w_fine = speeds(drive, 0.0005, 0.05, 400)
    mr = linearize(drive, w_fine, drive.T_N, gain=gain).max_real
    edge = w_fine[mr > 0].max() / drive.base.w
    assert 0.01 < edge < 0.04, edge


@pytest.mark.parametrize("gain", GAINS)
@pytest.mark.parametrize("T_sign", [1, -1])
def test_nonsalient_motor_is_stable_everywhere(drive, gain, T_sign):
    """With L_d = L_q the linearized system is stable in the whole range, marginally at zero speed."""
    m = dataclasses.replace(drive.motor, L_q=drive.motor.L_d)
    e = dataclasses.replace(drive.estimate, L_q=drive.estimate.L_d)
    d = dataclasses.replace(drive, motor=m, estimate=e)
    w = speeds(drive, -1, 1, 801)  # contains 0 exactly
    s = linearize(d, w, T_sign * drive.T_N, gain=gain)
    zero = np.abs(w) < 1e-12
    scale = np.abs(s.poles).max()
    assert (s.max_real[~zero] < 0).all()
    assert abs(s.max_real[zero][0]) < 1e-12 * scale  # a pole at the origin: marginal
    assert np.abs(s.poles[zero]).min() < 1e-12 * scale


def test_speed_dependent_gain_damps_best_at_high_speed(drive):
    """Section IV-B: the speed-dependent gain gives better worst-case damping at high speeds than
    zero and constant gains (and the constant gain is worse than zero gain)."""
    w = np.concatenate([speeds(drive, -1, -0.5, 101), speeds(drive, 0.5, 1, 101)])
    worst = {g: linearize(drive, w, drive.T_N, gain=g).worst_damping.min() for g in GAINS}
    assert worst["speed"] > worst["zero"] + 0.1
    assert worst["speed"] > worst["constant"] + 0.1
    assert worst["constant"] < worst["zero"]


@pytest.mark.parametrize("T_sign", [1, -1])
def test_injection_stabilizes_low_speeds(drive, T_sign):
    """Section V: with the (averaged) HF injection no closed-loop pole is in the RHP over the
    low-speed range, zero speed included, at nominal torque in both directions."""
    wd = drive.injection.w_Delta / drive.base.w
    w = speeds(drive, -wd, wd, 521)
    assert np.any(w == 0)
    for gain in GAINS:
        s = linearize(drive, w, T_sign * drive.T_N, gain=gain, injection=True)
        assert np.isfinite(s.max_real).all()
        low = np.abs(w) < drive.injection.w_Delta
        assert (s.max_real[low] < 0).all(), gain
        # and without it the same range does have the RHP pole (motoring side)
        s0 = linearize(drive, w, T_sign * drive.T_N, gain=gain)
        assert (s0.max_real > 1e-9).any()


def test_linearization_predicts_nonlinear_response(drive):
    """Simulate the coupled nonlinear system from a small perturbation of its equilibrium and compare
    with exp(A t) from the Jacobian: the linear model is what the nonlinear system does."""
    from scipy.integrate import solve_ivp  # here, not at every worker's collection (~0.45 s)
    from scipy.linalg import expm

    for w_pu, gain in ((0.5, "speed"), (-0.3, "constant"), (0.01, "speed")):
        w0, T = w_pu * drive.base.w, drive.T_N
        s = linearize(drive, w0, T, gain=gain)
        law, args = drive_arguments(drive, gain)
        args["w_m"], args["T_e"] = np.array(w0), np.array(T)
        f = residual_function(law, False)
        x0 = s.x0[0]
        dx0 = np.array([1e-5, -1e-5, 1e-4, 0.01])  # V s, V s, rad, rad/s

        def rhs(t, x, args=args, f=f):
            return np.asarray(f(x, *[args[k] for k in PARAM_NAMES])).ravel()

        t_end = 0.3
        sol = solve_ivp(
            rhs, (0, t_end), x0 + dx0, rtol=1e-11, atol=1e-14, method="LSODA", t_eval=[0.05, 0.15, t_end]
        )
        for t, x in zip(sol.t, sol.y.T, strict=True):
            lin = expm(s.A[0] * t) @ dx0
            err = np.abs((x - x0) - lin) / (np.abs(dx0) + np.abs(lin))
            assert err.max() < 2e-2, (w_pu, gain, t, x - x0, lin)
    # at 0.01 p.u. motoring the perturbation grows (the RHP pole), as Fig. 6(a) shows in simulation
    assert s.max_real[0] > 0


def test_estimation_errors_move_the_equilibrium(drive):
    """With parameter errors the equilibrium has theta_tilde != 0 and is found by Newton's method."""
    e = dataclasses.replace(drive.estimate, R_s=1.3 * drive.motor.R_s, psi_pm=0.9 * drive.motor.psi_pm)
    d = dataclasses.replace(drive, estimate=e)
    w = speeds(drive, 0.2, 1, 5)
    s = linearize(d, w, drive.T_N, gain="speed")
    assert np.isfinite(s.x0).all()
    assert (np.abs(s.x0[:, 2]) > 1e-4).all()  # position error at rest
    law, args = drive_arguments(d, "speed")
    args["w_m"], args["T_e"] = w[None, :], np.full((1, w.size), drive.T_N)
    res = residual_function(law, False).map(w.size)(s.x0.T, *[args[k] for k in PARAM_NAMES])
    assert np.abs(np.asarray(res)).max() < 1e-8
    np.testing.assert_allclose(s.x0[:, 3], w, rtol=1e-9)  # w_hat = w_m at rest (F_eps = 0)


def test_per_point_estimates_match_drive_estimates_and_follow_the_branch(drive):
    """Robustness maps pass estimates per point; the equilibrium branch is followed by continuation
    (checked against scipy's fsolve started from the continued solution's neighbourhood)."""
    from scipy.optimize import fsolve

    w = np.array([-0.3, -0.1, 0.1, 0.5]) * drive.base.w
    k = np.array([0.8, 1.0, 1.0, 1.0])
    est = np.array(drive.estimate.vector()) * k  # R̂s 20 % low
    d = dataclasses.replace(drive, estimate=dataclasses.replace(drive.estimate, R_s=est[0]))
    a = linearize(d, w, drive.T_N, gain="speed")
    b = linearize(drive, w, drive.T_N, gain="speed", estimate=est)
    assert np.array_equal(a.x0, b.x0) and np.array_equal(a.A, b.A)
    assert np.isfinite(a.x0).all()
    law, args = drive_arguments(d, "speed")
    f = residual_function(law, False)
    for j, wj in enumerate(w):
        args["w_m"], args["T_e"] = np.array(wj), np.array(drive.T_N)
        x = fsolve(
            lambda x: np.asarray(f(x, *[args[k] for k in PARAM_NAMES])).ravel(), a.x0[j] + 1e-3, xtol=1e-13
        )
        assert np.allclose(x, a.x0[j], rtol=1e-7, atol=1e-9)
    # the position error at rest grows as the speed falls (resistance error matters at low speed)
    assert abs(a.x0[1, 2]) > abs(a.x0[0, 2]) > 0.01
