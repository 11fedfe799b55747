"""Time-domain simulation of the adaptive-observer drive: the plant, the controllers, the paper's claims.

Every expected value is derived independently in the test (scipy integration of the motor written in
the stationary frame, the analytic closed-loop speed response, the linearized poles of
design/ipmsm_adaptive/linearize.py) or is a claim of Piippo et al. (2008) checked with a margin stated
next to it.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from helpers.simulation import matrix_pencil, piippo2008, run, run_text
from sensorless.design.ipmsm_adaptive.one_step import linearize
from sensorless.symbolic.pmsm import Mechanics, PmsmParams, plant_period

DEG = np.pi / 180


# --------------------------------------------------------------------------------------------------
# Building blocks against independent derivations
# --------------------------------------------------------------------------------------------------
def test_sampled_plant_matches_scipy_in_the_stationary_frame():
    """RK4 between samples (rotor frame) vs. scipy's adaptive RK on eqs. (1)-(3) in alpha-beta."""
    from scipy.integrate import solve_ivp  # here, not at every worker's collection (~0.45 s)

    m = piippo2008().motor
    R, Ld, Lq, psi_f, p, J = m.R_s, m.L_d, m.L_q, m.psi_pm, m.p, m.J
    T_s, T_L = 2e-4, 3.0

    def rhs(t, x, u):  # x = [psi_a, psi_b, theta, w]: stationary-frame flux, independent of the package
        th = x[2]
        c, s = np.cos(th), np.sin(th)
        psi_d, psi_q = c * x[0] + s * x[1], -s * x[0] + c * x[1]
        i_d, i_q = (psi_d - psi_f) / Ld, psi_q / Lq
        i_a, i_b = c * i_d - s * i_q, s * i_d + c * i_q
        T_e = 1.5 * p * (x[0] * i_b - x[1] * i_a)
        return [u[0] - R * i_a, u[1] - R * i_b, x[3], p / J * (T_e - T_L)]

    xs = ca.SX.sym("x", 4)
    us = ca.SX.sym("u", 2)
    F = ca.Function(
        "period",
        [xs, us],
        [plant_period(xs, us, T_L, PmsmParams(R, Ld, Lq, psi_f), Mechanics(J, 0, p), 0, T_s, 4)],
    )
    rng = np.random.default_rng(0)
    th0, w0 = 0.3, 200.0
    x_rotor = np.array([psi_f + Ld * 1.0, Lq * 4.0, th0, w0])
    c, s = np.cos(th0), np.sin(th0)
    x_ab = np.array([c * x_rotor[0] - s * x_rotor[1], s * x_rotor[0] + c * x_rotor[1], th0, w0])
    for _ in range(200):
        th = x_ab[2]
        u = 120 * np.array([-np.sin(th), np.cos(th)]) + 30 * rng.standard_normal(2)  # ZOH voltage
        x_ab = solve_ivp(rhs, (0, T_s), x_ab, args=(u,), rtol=1e-11, atol=1e-12, method="DOP853").y[:, -1]
        x_rotor = np.asarray(F(x_rotor, u)).ravel()
    c, s = np.cos(x_ab[2]), np.sin(x_ab[2])
    psi_rotor_ref = [c * x_ab[0] + s * x_ab[1], -s * x_ab[0] + c * x_ab[1]]
    assert np.allclose(x_rotor[0:2], psi_rotor_ref, rtol=0, atol=1e-8)
    assert abs(np.remainder(x_rotor[2] - x_ab[2] + np.pi, 2 * np.pi) - np.pi) < 1e-8
    assert x_rotor[3] == pytest.approx(x_ab[3], rel=1e-9)


SPEED_STEP = """
[scenario]
name = "speed-step"
title = "small speed step, sensor feedback"
kind = "ipmsm-adaptive"
duration = "0.35 s"
[observer]
gain = "speed"
injection = false
[control]
feedback = "sensor"
[initial]
w_m = "0.3 pu"
[speed_reference]
t = [0, 0.05]
value = ["0.3 pu", "0.31 pu"]
"""


def test_speed_loop_is_critically_damped_at_alpha_s():
    """IP speed control: w_m/w_ref = alpha_s^2/(s + alpha_s)^2 (design of drive_control.speed_gains)."""
    d = piippo2008()
    tr = run_text(SPEED_STEP)
    a = d.control.alpha_s
    m = tr.t >= 0.05
    tau = tr.t[m] - 0.05
    step = 0.01 * d.base.w
    expected = 0.3 * d.base.w + step * (1 - (1 + a * tau) * np.exp(-a * tau))
    # the current loop (bandwidth 16x alpha_s) and the sampling delay shift the response by well
    # under 3 % of the step
    assert np.max(np.abs(tr["w_m"][m] - expected)) < 0.03 * step
    # the observer runs alongside with sensor feedback: it tracks the speed in steady state
    assert abs(tr["w_hat"][-1] - tr["w_m"][-1]) < 1e-3 * step


# --------------------------------------------------------------------------------------------------
# Piippo et al. (2008) Fig. 6: low speed, nominal load, no injection
# --------------------------------------------------------------------------------------------------
def test_fig6a_diverges_at_0p01pu_motoring():
    d = piippo2008()
    tr = run("fig6a")
    e = tr["theta_err"]
    assert np.max(np.abs(e[tr.window(0, 1)])) < 0.01 * DEG  # converged before the load step
    assert np.max(np.abs(e)) > 30 * DEG  # ... and lost after it
    # the drive cannot hold its 0.01 p.u. reference any more
    assert np.mean(tr["w_m"][tr.window(9, 10)]) < 0.5 * 0.01 * d.base.w
    # growth while still small is exponential at about the rate of the linearized unstable pole
    # (Fig. 5); the speed loop, absent from the analysis, changes it somewhat: accept 0.5x..2x
    grow = tr.window(3, 6)
    rate = np.polyfit(tr.t[grow], np.log(np.abs(e[grow])), 1)[0]
    pole = linearize(d, 0.01 * d.base.w, d.T_N, gain="speed").max_real[0]
    assert pole > 0
    assert 0.5 * pole < rate < 2 * pole


@pytest.mark.parametrize("name", ["fig6b", "fig6c"])
def test_fig6bc_stay_bounded(name):
    d = piippo2008()
    tr = run(name)
    assert np.max(np.abs(tr["theta_err"])) < 5 * DEG  # the load-step transient (measured 2.2 deg)
    end = tr.window(5, 6)
    assert np.max(np.abs(tr["theta_err"][end])) < 0.1 * DEG
    assert np.max(np.abs(tr["w_m"] - tr["w_hat"])[end]) < 1e-4 * d.base.w


def test_injection_stabilizes_fig6a():
    d = piippo2008()
    tr = run("fig6a", injection=True)
    after = tr.window(2, 10)
    assert np.max(np.abs(tr["theta_err"][after])) < 1 * DEG
    assert np.max(np.abs(tr["w_m"][after] - 0.01 * d.base.w)) < 0.001 * d.base.w


STANDSTILL = """
[scenario]
name = "standstill"
title = "zero speed, nominal load step, injection"
kind = "ipmsm-adaptive"
duration = "3 s"
[observer]
gain = "speed"
injection = true
[speed_reference]
t = [0]
value = ["0 pu"]
[load_torque]
t = [0, 0.5]
value = ["0 Nm", "1 T_N"]
"""


def test_zero_speed_under_nominal_load_is_held_with_injection():
    d = piippo2008()
    tr = run_text(STANDSTILL)
    held = tr.window(1.5, 3)
    assert np.max(np.abs(tr["w_m"][held])) < 0.001 * d.base.w
    assert np.max(np.abs(tr["theta_err"][held])) < 1 * DEG
    assert np.mean(tr["T_e"][held]) == pytest.approx(d.T_N, rel=0.01)
    # the injection removes the error the load step caused (measured: 0.005 deg left after 2.5 s);
    # without it zero speed is only marginally stable (Section IV-B) and that error stays (0.73 deg)
    e_on = np.abs(tr["theta_err"][tr.window(2.5, 3)]).max()
    e_off = np.abs(run_text(STANDSTILL, injection=False)["theta_err"][tr.window(2.5, 3)]).min()
    assert e_on < 0.05 * DEG < 0.2 * DEG < e_off


# --------------------------------------------------------------------------------------------------
# Piippo et al. (2008) Fig. 9: speed steps at nominal load; constant vs speed-dependent gain
# --------------------------------------------------------------------------------------------------
STEPS = (1.0, 2.0, 3.0)


def oscillation(tr, t0, t1):
    """RMS of the speed-estimation error's oscillating part in [t0, t1): the error minus its 20-ms
    moving average (one period of the constant gain's weakly damped mode, ~48 Hz at 0.67 p.u., so the
    average removes the slow transient and keeps the vibration) [rad/s]."""
    e = tr["w_m"] - tr["w_hat"]
    n = round(0.02 / tr.meta["T_s"])
    slow = np.convolve(e, np.ones(n) / n, mode="same")
    m = tr.window(t0, t1)
    return float(np.sqrt(np.mean((e[m] - slow[m]) ** 2)))


@pytest.mark.parametrize("name", ["fig9a", "fig9b"])
def test_fig9_estimate_follows_the_steps(name):
    d = piippo2008()
    wb = d.base.w
    tr = run(name)
    assert np.max(np.abs(tr["w_m"] - tr["w_hat"])) < 0.05 * wb  # through every step, under load
    for t_step, nxt in zip(STEPS, (*STEPS[1:], 4.0), strict=True):
        settled = tr.window(t_step + 0.4, nxt)
        assert np.max(np.abs(tr["w_m"] - tr["w_ref"])[settled]) < 0.005 * wb
        assert np.max(np.abs(tr["w_m"] - tr["w_hat"])[settled]) < 0.001 * wb
    assert np.max(np.abs(tr["theta_err"][tr.window(0.9, 1.0)])) < 1 * DEG  # zero speed under load


def test_fig9_speed_dependent_gain_damps_better():
    """Oscillation after the steps to 0.67 p.u. and to -0.67 p.u. (measured ratio speed-dependent /
    constant 0.38 and 0.70); the paper's claim is the direction. The third step ends at standstill,
    where (16) gives zero gain and the damping argument does not apply: both oscillations are at the
    floor there (0.018 and 0.026 rad/s, 5e-5 p.u.; with Heun's voltage feedthrough the constant gain's
    was 0.051 rad/s, which made that ratio look like 0.48)."""
    a, b = run("fig9a"), run("fig9b")
    osc = [(oscillation(b, t + 0.03, t + 0.5), oscillation(a, t + 0.03, t + 0.5)) for t in STEPS]
    assert max(ob / oa for ob, oa in osc[:2]) < 0.8
    assert max(osc[2]) < 1e-4 * piippo2008().base.w
    # the linear analysis predicts the same ranking at the step speeds (Fig. 4(b) vs (c))
    d = piippo2008()
    for w in (0.67, -0.67):
        z_const = linearize(d, w * d.base.w, d.T_N, gain="constant").worst_damping[0]
        z_speed = linearize(d, w * d.base.w, d.T_N, gain="speed").worst_damping[0]
        assert z_speed > 3 * z_const


# --------------------------------------------------------------------------------------------------
# Linear analysis and simulation agree
# --------------------------------------------------------------------------------------------------
SMALL_STEP = """
[scenario]
name = "small-step"
title = "0.01 p.u. speed step on a stiff load at 0.5 p.u., nominal torque"
kind = "ipmsm-adaptive"
duration = "0.55 s"
[observer]
gain = "constant"
injection = false
[control]
mode = "torque"
stiff_load = true
[initial]
w_m = "0.5 pu"
[speed_reference]
t = [0, 0.3]
value = ["0.5 pu", "0.51 pu"]
[torque_reference]
t = [0]
value = ["1 T_N"]
"""


@pytest.mark.parametrize("gain", ["constant", "speed"])
@pytest.mark.parametrize("discretization", ["zoh", "heun", "euler", "heun-model"])
def test_small_step_decays_at_the_dominant_discrete_pole(gain, discretization):
    """The load machine holds the speed (the analysis' input w_m) and steps it by 0.01 p.u.; the
    speed-estimation error then decays through the closed loop G_c(s) of eq. (15). Its dominant
    pole, estimated from the simulated error by the matrix pencil (no model), is compared with the
    dominant pole ln(z)/T_s of the discrete-time observer that runs (design/ipmsm_adaptive/one_step.py)
    at 0.5 p.u., nominal torque.

    Tolerance: the analysis assumes ideal current control (the sampled current held on its operating
    point); what remains is the drive's current loop (bandwidth alpha_c = 11 |p|, 1.5-sample delay)
    and the fit: 8 % on the decay rate and 5 % on the frequency (measured within 4 % and 3 %). For
    forward Euler the continuous pole decays 22 % faster (constant gain) and fails this tolerance.
    """
    d = piippo2008()
    tr = run_text(SMALL_STEP, gain=gain, discretization=discretization)
    e = tr["w_m"] - tr["w_hat"]
    win = tr.window(0.32, 0.5)  # from 20 ms after the step: the faster poles have decayed by e^-4
    p_sim = matrix_pencil(e[win][::2], 2 * tr.meta["T_s"])
    p_sim = p_sim[np.argmax(p_sim.imag)]
    a = linearize(d, 0.5 * d.base.w, d.T_N, gain=gain, discretization=discretization, T_s=tr.meta["T_s"])
    poles = a.poles_discrete[0]
    p_lin = poles[np.argmax(poles.real)]
    p_lin = complex(p_lin.real, abs(p_lin.imag))
    assert -p_sim.real == pytest.approx(-p_lin.real, rel=0.08)
    assert p_sim.imag == pytest.approx(p_lin.imag, rel=0.05)
    if discretization == "euler" and gain == "constant":
        p_c = a.poles[0][np.argmax(a.poles[0].real)]
        assert -p_c.real > 1.2 * -p_sim.real


def test_fig9_position_error_speed_dependent_against_constant_gain():
    """Piippo et al. (2008) on Fig. 9: "the estimation error of the rotor position remains slightly
    smaller when using the speed-dependent gain". Re-examined with the default discretization (zoh,
    no voltage feedthrough, no steady lag):

    - in the torque-limited reversal the speed-dependent gain lags about twice as much (measured peak
      11.9 vs 5.7 deg without noise): the continuous observer's own acceleration lag -[A^-2 B]_theta
      (PoleSweep.acceleration_lag) at the operating point of the peak predicts the ranking (ratio 1.9);
    - with current-measurement noise (0.02 A) the steady-state error at +-0.67 p.u. is smaller with the
      speed-dependent gain (RMS 0.035 vs 0.041 deg): the paper's claim holds for the noise, not for the
      transients.
    """
    d = piippo2008()
    a, b = run("fig9a"), run("fig9b")
    assert a.meta["discretization"] == b.meta["discretization"] == "zoh"
    rev = a.window(2.0, 3.0)
    peak_a = np.abs(a["theta_err"][rev]).max()
    peak_b = np.abs(b["theta_err"][rev]).max()
    assert peak_b > 1.6 * peak_a
    k = np.flatnonzero(rev)[np.argmax(np.abs(b["theta_err"][rev]))]
    w, T = b["w_m"][k], b["T_e"][k]
    lag = {g: linearize(d, w, T, gain=g).acceleration_lag[0] for g in ("constant", "speed")}
    assert lag["speed"] > 1.5 * lag["constant"] > 0
    noisy = {n: run(n, i_noise=0.02) for n in ("fig9a", "fig9b")}
    steady = a.window(1.5, 2.0) | a.window(2.5, 3.0)
    rms = {n: np.sqrt(np.mean(tr["theta_err"][steady] ** 2)) for n, tr in noisy.items()}
    assert rms["fig9b"] < 0.95 * rms["fig9a"]
    peak = {n: np.abs(tr["theta_err"][rev]).max() for n, tr in noisy.items()}
    assert peak["fig9b"] > 1.6 * peak["fig9a"]
