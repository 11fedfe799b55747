"""Test helper: a sampled-data simulation of the IPMSM of Piippo et al. (2008) driving the runtime observer.

Not a drive simulator (that is `sensorless simulate`): the motor's speed is prescribed, its voltage is
open loop (the steady-state voltage (29) of the MTPA current for a prescribed torque, at the true angle)
plus the observer's own carrier (17) on its estimated d axis. Timing as docs/simulation.md ("Timing"): a
command computed at t_k is applied over [t_k+1, t_k+2] (one-sample computation delay, zero-order hold). The
motor's flux ODE (1)-(2) is integrated by RK4 substeps in the rotor frame from symbolic/pmsm.py; the
whole loop is one CasADi ``mapaccum`` (no Python loop).
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np
from sensorless.design.runtime import CHUNK
from sensorless.symbolic.pmsm import (
    PmsmParams,
    current_from_flux,
    flux_derivative,
    flux_from_current,
    mtpa_current,
    rot,
    stator_voltage,
)


@functools.cache
def loop_step(step: ca.Function, n_sub: int = 8) -> ca.Function:
    """(z, [w_m, T_e], p_obs, gain, motor[4], T_s, pole_pairs) -> (z_next, [meas; y; theta_m; w_m]).

    z = [psi_s (rotor frame, 2), theta_m, x_obs (n_x), u_now (2)]; u_now is applied over [t_k, t_k+1].
    """
    n_x = step.size1_in(0)
    z = ca.SX.sym("z", 3 + n_x + 2)
    op = ca.SX.sym("op", 2)
    p_obs = ca.SX.sym("p_obs", step.size1_in(2))
    gain = ca.SX.sym("gain", step.size1_in(3))
    mot = ca.SX.sym("motor", 4)
    T_s, pp = ca.SX.sym("T_s"), ca.SX.sym("pole_pairs")
    motor = PmsmParams.of(mot)
    w_m = op[0]
    psi, theta_m = z[0:2], z[2]
    x_obs = z[3 : 3 + n_x]
    u_now = z[3 + n_x : 5 + n_x]

    i_ab = rot(theta_m) @ current_from_flux(psi, motor)  # sampled at t_k
    x_next, y = step(x_obs, ca.vertcat(i_ab, u_now), p_obs, gain)
    theta_hat, u_c_d = y[1], y[4]
    # the command computed now: fundamental voltage at the angle it will be applied (1.5 samples on)
    i_s0 = mtpa_current(op[1], motor, pp)
    u_s0 = stator_voltage(i_s0, 0, flux_from_current(i_s0, motor), w_m, motor.R_s)  # eq. (29)
    u_cmd = rot(theta_m + 1.5 * w_m * T_s) @ u_s0 + rot(theta_hat) @ ca.vertcat(u_c_d, 0)

    # motor over [t_k, t_k+1] with u_now held in the stationary frame
    h = T_s / n_sub

    def f(ps: ca.SX, th: ca.SX) -> ca.SX:
        u_r = rot(th).T @ u_now
        return flux_derivative(u_r, current_from_flux(ps, motor), ps, w_m, motor.R_s)

    th = theta_m
    for _ in range(n_sub):
        k1 = f(psi, th)
        k2 = f(psi + h / 2 * k1, th + h / 2 * w_m)
        k3 = f(psi + h / 2 * k2, th + h / 2 * w_m)
        k4 = f(psi + h * k3, th + h * w_m)
        psi = psi + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        th = th + h * w_m
    th = ca.atan2(ca.sin(th), ca.cos(th))
    z_next = ca.vertcat(psi, th, x_next, u_cmd)  # the command is applied over [t_k+1, t_k+2]
    rec = ca.vertcat(i_ab, u_now, y, theta_m, w_m)
    return ca.Function("loop_step", [z, op, p_obs, gain, mot, T_s, pp], [z_next, rec], {"cse": True})


def simulate(setup, drive, profile: np.ndarray, theta0: float = 0.0) -> dict[str, np.ndarray]:
    """Run the loop over ``profile`` (N x 2: w_m [rad/s], T_e [N m] per sample).

    Returns meas (N x 4), y (N x n_y), theta_m, w_m (N) at each sample t_k.
    """
    step = setup.step_function()
    F = loop_step(step)
    n = profile.shape[0]
    motor = drive.motor
    i0 = np.zeros(2)
    psi0 = np.array([motor.L_d * i0[0] + motor.psi_pm, motor.L_q * i0[1]])
    z0 = np.concatenate([psi0, [theta0], setup.initial_state(), np.zeros(2)])
    # in chunks of at most design/runtime.CHUNK steps (a mapaccum of 10^4 steps or more takes CasADi
    # ~15x longer to build), the loop state carried from one to the next: the same numbers
    parts = []
    for k in range(0, n, CHUNK):
        prof = profile[k : k + CHUNK]
        zs, rec = F.mapaccum(prof.shape[0])(
            z0, prof.T, setup.p, np.asarray(setup.gain), motor.vector(), drive.control.T_s, motor.p
        )
        z0 = np.asarray(zs)[:, -1]
        parts.append(np.asarray(rec))
    rec = np.hstack(parts).T
    n_y = step.size1_out(1)
    return {
        "meas": rec[:, 0:4],
        "y": rec[:, 4 : 4 + n_y],
        "theta_m": rec[:, 4 + n_y],
        "w_m": rec[:, 5 + n_y],
    }


def profile_from_segments(segments, T_s: float, w_base: float, T_N: float) -> np.ndarray:
    """Piecewise-linear (speed, torque) profile; segments = [(duration s, w0 pu, w1 pu, T/T_N), ...]."""
    rows = []
    for dur, w0, w1, tq in segments:
        n = round(dur / T_s)
        w = np.linspace(w0, w1, n, endpoint=False) * w_base
        rows.append(np.column_stack([w, np.full(n, tq * T_N)]))
    return np.vstack(rows)


# The recorded trajectory that the C code is checked (tests) and timed (benchmarks) on: standstill
# with injection, ramps through w_Delta and zero, +-0.8 p.u., low speed. Rows: (duration [s], speed
# from, speed to [p.u.], torque [T_N]) as profile_from_segments takes them.
TRAJECTORY_SEGMENTS = (
    (0.3, 0, 0, 1.0),
    (0.3, 0, 0.3, 1.0),
    (0.3, 0.3, 0.3, 0.5),
    (0.4, 0.3, -0.8, 0.5),
    (0.4, -0.8, -0.8, -1.0),
    (0.3, -0.8, 0.05, 0.0),
    (0.4, 0.05, 0.05, 1.0),
)
