"""Automatic linearization vs the paper's closed form (11)-(15), written out independently here."""

import dataclasses
import functools

import casadi as ca
import numpy as np
import pytest
from helpers.closed_form_ipmsm import mtpa_reference, paper_gain, paper_matrices
from sensorless.design.ipmsm_adaptive.linearize import drive_arguments, linearize
from sensorless.design.ipmsm_adaptive.operating_point import (
    PARAM_NAMES,
    analysis_symbols,
    coupled_system,
    nominal_equilibrium_function,
)
from sensorless.symbolic.ipmsm_adaptive.observer import error_term


@functools.cache
def paper_open_loop_function(law: str) -> ca.Function:
    """Open adaptation loop (12) in the paper's error coordinates (i_tilde, theta_tilde).

    Outputs A (3x3) = [[A1, A2], [0, 0]] and B (3x1) = [B1; 1] of eq. (11)-(12) with the speed error
    w_m - w_hat as input, and C = [C1, 0] of (12) with F_eps as output; obtained by differentiating
    the coupled system with the speed estimate imposed, then changing coordinates x -> z(x) with the
    Jacobian M = dz/dx. The imposed speed is the closed loop's own w_hat(x0), so this holds at any
    equilibrium.
    """
    s = analysis_symbols(law, False)
    x = s["x"]
    w_hat_in = ca.SX.sym("w_hat_in")
    ol, _ = coupled_system(law, False, s, w_hat_override=w_hat_in)
    cl, _ = coupled_system(law, False, s)
    xo, fo, zo = x[0:3], ol.x_dot[0:3], ol.z[0:3]
    M = ca.jacobian(zo, xo)
    A = ca.mtimes([M, ca.jacobian(fo, xo), ca.inv(M)])
    B = -M @ ca.jacobian(fo, w_hat_in)  # input: speed error w_m - w_hat
    B_wm = M @ ca.jacobian(fo, s["w_m"])  # the same input seen through w_m (must equal B)
    F_eps = error_term(ol.i_tilde, s["estimate"][2])  # eq. (8)
    C = ca.jacobian(F_eps, xo) @ ca.inv(M)
    outs = [ca.substitute(e, w_hat_in, cl.w_hat) for e in (A, B, B_wm, C)]
    names = ["x", *PARAM_NAMES]
    return ca.Function(f"paper_open_loop_{law}", [s[k] for k in names], outs, names, ["A", "B", "B_wm", "C"])


def random_cases(drive, n, rng):
    R0 = drive.motor.R_s
    wb = drive.base.w
    for _ in range(n):
        law = rng.choice(["zero", "constant", "speed"])
        if law == "constant":
            params = (rng.uniform(-0.9, 3) * R0, rng.uniform(-3, 3) * R0)
        elif law == "speed":
            params = (rng.uniform(0.5, 4) * R0, rng.uniform(0.3, 2) * wb)
        else:
            params = ()
        Ld = drive.motor.L_d * rng.uniform(0.7, 1.3)
        motor = dataclasses.replace(
            drive.motor,
            R_s=R0 * rng.uniform(0.5, 2),
            L_d=Ld,
            L_q=Ld * rng.uniform(1.0, 2.0),
            psi_pm=drive.motor.psi_pm * rng.uniform(0.7, 1.3),
        )
        est = dataclasses.replace(
            drive.estimate, R_s=motor.R_s, L_d=motor.L_d, L_q=motor.L_q, psi_pm=motor.psi_pm
        )
        d = dataclasses.replace(drive, motor=motor, estimate=est)
        w0 = rng.uniform(-1.2, 1.2) * wb
        T = rng.uniform(-1.5, 1.5) * drive.T_N
        yield d, str(law), params, w0, T


def test_open_loop_matches_eq11(drive):
    """A1, B1, A2 (and C1) from casadi.jacobian equal eq. (11)-(12) to 1e-9 at random points."""
    rng = np.random.default_rng(2008)
    for d, law, params, w0, T in random_cases(drive, 40, rng):
        _, args = drive_arguments(d, (law, params))
        args["w_m"], args["T_e"] = np.array(w0), np.array(T)
        x0 = nominal_equilibrium_function(False)(w0, T, args["motor"], args["p"])
        A, B, B_wm, C = (
            np.asarray(m) for m in paper_open_loop_function(law)(x0, *[args[k] for k in PARAM_NAMES])
        )
        m = d.motor
        i0 = mtpa_reference(T, m.L_d, m.L_q, m.psi_pm, m.p)
        l1, l2 = paper_gain(law, w0, params)
        A1, B1, A2 = paper_matrices(w0, i0, m.R_s, m.L_d, m.L_q, m.psi_pm, l1, l2)
        A_ref = np.zeros((3, 3))
        A_ref[:2, :2], A_ref[:2, 2] = A1, A2
        B_ref = np.append(B1, 1.0)
        C_ref = np.array([0.0, m.L_q, 0.0])
        # MTPA reference is a numerical optimum (~1e-12 accurate), everything else is exact
        for got, ref in ((A, A_ref), (B.ravel(), B_ref), (B_wm.ravel(), B_ref), (C.ravel(), C_ref)):
            err = np.abs(got - ref).max() / np.abs(ref).max()
            assert err < 1e-9, (law, w0, T, got, ref)


def closed_loop_reference(A1, B1, A2, Lq, alpha_fo, psi_pm):
    """4th-order closed loop of (12) with the PI (14), k_p and k_i of (10)."""
    A = np.zeros((3, 3))
    A[:2, :2], A[:2, 2] = A1, A2
    B = np.append(B1, 1.0)[:, None]
    C = np.array([[0.0, Lq, 0.0]])
    kp, ki = 2 * alpha_fo / psi_pm, alpha_fo**2 / psi_pm
    # w_hat = -kp F - ki xi, xi' = F; speed error w_m - w_hat drives (12)
    A_cl = np.block([[A + kp * B @ C, ki * B], [C, np.zeros((1, 1))]])
    return A, B, C, kp, ki, A_cl


def test_closed_loop_poles_and_Gc_match_eqs_12_to_15(drive):
    """Poles of the automatic 4-state closed loop equal those of (12)+(14); G_c(s) equals (15)."""
    rng = np.random.default_rng(15)
    for d, law, params, w0, T in random_cases(drive, 25, rng):
        s = linearize(d, w0, T, gain=(law, params))
        m = d.motor
        i0 = mtpa_reference(T, m.L_d, m.L_q, m.psi_pm, m.p)
        l1, l2 = paper_gain(law, w0, params)
        A1, B1, A2 = paper_matrices(w0, i0, m.R_s, m.L_d, m.L_q, m.psi_pm, l1, l2)
        A, B, C, kp, ki, A_cl = closed_loop_reference(A1, B1, A2, m.L_q, d.observer.alpha_fo, m.psi_pm)
        ref = np.sort_complex(np.linalg.eigvals(A_cl))
        got = np.sort_complex(s.poles[0])
        scale = np.abs(ref).max()
        # compare as multisets (sorting can pair conjugates differently only if equal)
        assert np.abs(np.poly(got) - np.poly(ref)).max() / np.abs(np.poly(ref)).max() < 1e-9
        assert np.abs(got - ref).max() / scale < 1e-9
        # G_c(s) = F G / (1 + F G), eq. (15), at a few frequencies
        sys = s.statespace(0)
        for sv in (0.3j, 7j, 120j, 50 + 900j):
            F = (C @ np.linalg.solve(sv * np.eye(3) - A, B))[0, 0]
            G = -kp - ki / sv
            Gc_ref = F * G / (1 + F * G)
            Gc = sys(sv)
            assert abs(Gc - Gc_ref) / abs(Gc_ref) < 1e-9


def test_mtpa_matches_brute_force(drive):
    """The operating points' MTPA current (design/rotor_frame.py, the sweeps' i_d, i_q columns)."""
    from sensorless.design.rotor_frame import pmsm_plant, pmsm_steady_current

    m = drive.motor
    torques = (-30.0, -14.0, -0.5, 0.1, 14.0, 22.0, 60.0)
    for T, got in zip(torques, pmsm_steady_current(np.array(torques), pmsm_plant(m)), strict=True):
        ref = mtpa_reference(T, m.L_d, m.L_q, m.psi_pm, m.p)
        assert np.allclose(got, ref, rtol=1e-8, atol=1e-10), (T, got, ref)


@pytest.mark.parametrize("law", ["zero", "constant", "speed"])
def test_transfer_function_dc_gain_is_one(drive, law):
    """G_c(0) = 1: the adaptation integrates, so the estimate tracks a constant speed exactly."""
    s = linearize(drive, 0.5 * drive.base.w, drive.T_N, gain=law)
    assert abs(s.statespace(0)(1e-9) - 1) < 1e-6


def test_schedule_law_reproduces_speed_dependent_at_breakpoints_and_interpolates(drive):
    """A schedule sampled from (16) on a grid equals (16) at the breakpoints, is linear between them
    and is held beyond the ends; linearization with it matches the law-(16) poles at breakpoints."""
    from sensorless.symbolic.ipmsm_adaptive.gains import schedule_law

    wb = drive.base.w
    grid = tuple(np.linspace(-1.5, 1.5, 13) * wb)
    lp, wl = drive.gain("speed").lambda_p, drive.gain("speed").w_lambda
    l1 = [paper_gain("speed", w, (lp, wl))[0] for w in grid]
    l2 = [paper_gain("speed", w, (lp, wl))[1] for w in grid]
    law = schedule_law(grid)
    import casadi as ca

    wsym = ca.SX.sym("w")
    p = ca.SX.sym("p", law.n_params)
    f = ca.Function("f", [wsym, p], list(law.expr(wsym, p)))
    for w in (*grid, 0.37 * wb, -2 * wb, 2 * wb):
        got = [float(v) for v in f(w, l1 + l2)]
        wc = min(max(w, grid[0]), grid[-1])
        ref = [np.interp(wc, grid, l1), np.interp(wc, grid, l2)]
        assert np.allclose(got, ref, rtol=1e-12, atol=1e-12)
    w = np.array(grid[1:-1])
    a = linearize(drive, w, drive.T_N, gain=(law, l1 + l2))
    b = linearize(drive, w, drive.T_N, gain="speed")
    assert np.allclose(a.poles, b.poles, rtol=1e-9)


def test_a_schedule_pickles_as_its_grid_and_reads_back_as_the_same_law():
    """A schedule's expression is a closure, so it pickles as its breakpoints (symbolic/ipmsm_adaptive/
    gains.py): the same law comes back, and the key of a Function kept on disk (design/memo.py) is the
    grid, different for another grid; the named laws pickle as before."""
    import pickle

    from sensorless.symbolic.ipmsm_adaptive.gains import get_law, schedule_law

    law = schedule_law((-2.0, 0.5, 3.0))
    assert pickle.loads(pickle.dumps(law)) is law
    assert pickle.dumps(schedule_law((-2.0, 0.5, 3.0))) == pickle.dumps(law)
    assert pickle.dumps(schedule_law((-2.0, 0.5, 3.5))) != pickle.dumps(law)
    assert pickle.loads(pickle.dumps(get_law("speed"))) == get_law("speed")
