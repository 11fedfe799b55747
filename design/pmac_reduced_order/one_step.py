"""The one-step map of the sampled reduced-order observer fed by the motor, in rotor coordinates.

The step that runs (symbolic/pmac_reduced_order/step.py) takes the motor from angle theta to
theta + w T_s; its Jacobian in rotor coordinates y = [R(-theta) zeta, tau, theta_hat - theta, w_hat] on
the observer's own orbit gives the discrete-time poles (linearize.analyze), the orbit Function the
steady errors, and the products of one-step Jacobians over whole periods the Floquet multipliers.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.pmac_reduced_order.operating_point import (
    INPUT_NAMES,
    no_load_estimation,
    plant_signals,
    symbols,
)
from sensorless.symbolic.frames import rot, wrap_angle
from sensorless.symbolic.pmac_reduced_order.step import N_STATE, split_params, step


def _rotor_coordinates(x: Any, theta: Any, load_estimation: bool) -> Any:
    """y = [R(-theta) zeta, tau, wrap(theta_hat - theta), w_hat] from the step state x."""
    parts = [
        rot(theta).T @ x[0:2],
        *([x[2]] if load_estimation else []),
        wrap_angle(x[3] - theta),
        x[4],
    ]
    return ca.vertcat(*parts)


def _coupled_step(
    s: dict[str, ca.SX], x: Any, method: str, orders_m, orders_o, load_estimation: bool, noise=None
):
    """One observer step from angle theta (t_(k-1)) to theta + w T_s, fed by the motor's samples;
    ``noise`` = (n_prev, n_new) current-sensor noise added to the previous and the new current sample."""
    params = s["params"] if load_estimation else no_load_estimation(s["params"])
    _, _, T_s = split_params(params, orders_o)
    th0 = s["theta"]
    th1 = th0 + s["w"] * T_s
    sig0, _ = plant_signals(s, th0, orders_m)
    sig1, T_e = plant_signals(s, th1, orders_m)
    n_prev, n_new = noise if noise is not None else (0, 0)
    x_in = ca.vertcat(x[0:5], sig0.i + n_prev, sig0.v)  # the previous samples are the motor's
    st = step(x_in, sig1.i + n_new, sig1.v, params, orders_o, method)
    return st, th1, T_e


@functools.cache
def discrete_jacobian_function(
    method: str, orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool = True
) -> ca.Function:
    """(x, theta, w, T_L, motor, params) -> Jy: the one-step map's Jacobian in rotor coordinates.

    ``x`` is the observer state at t_(k-1) (its stored samples are replaced by the motor's at theta);
    the step takes the motor from theta to theta + w T_s. Jy = d y_k / d y_(k-1) with y of
    :func:`_rotor_coordinates` (5 states; 4 without load estimation, tau held at 0).
    """
    s = symbols(orders_m, orders_o)
    ny = 5 if load_estimation else 4
    y = ca.SX.sym("y", ny)
    th0 = s["theta"]
    zeta = rot(th0) @ y[0:2]
    tau = y[2] if load_estimation else 0
    x = ca.vertcat(zeta, tau, y[ny - 2] + th0, y[ny - 1], ca.DM.zeros(4))
    st, th1, _ = _coupled_step(s, x, method, orders_m, orders_o, load_estimation)
    y1 = _rotor_coordinates(st.x_next, th1, load_estimation)
    Jy = ca.jacobian(y1, y)
    x_sym = ca.SX.sym("x", N_STATE)
    y_of_x = _rotor_coordinates(x_sym, th0, load_estimation)
    f = ca.Function("f", [y, *s.values()], [Jy, st.x_next])
    Jy0, x_next = f(y_of_x, *s.values())
    name = f"pmac_reduced_order_jacobian_d_{method.replace('-', '_')}{'' if load_estimation else '_noTL'}"
    return ca.Function(name, [x_sym, *s.values()], [Jy0, x_next], ["x", *INPUT_NAMES], ["Jy", "x_next"])


@functools.cache
def discrete_noise_function(
    method: str, orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool = True
) -> ca.Function:
    """(x, theta, w, T_L, motor, params) -> (G_new, G_prev): the one-step map's input from current-
    sensor noise (stationary frame, A) added to the new sample and to the stored previous one, in the
    rotor coordinates of :func:`discrete_jacobian_function` (Jacobians of the step that runs, at zero
    noise). A sample's noise enters two steps (as the new sample, then as the previous one)."""
    s = symbols(orders_m, orders_o)
    ny = 5 if load_estimation else 4
    y = ca.SX.sym("y", ny)
    n_prev, n_new = ca.SX.sym("n_prev", 2), ca.SX.sym("n_new", 2)
    th0 = s["theta"]
    zeta = rot(th0) @ y[0:2]
    tau = y[2] if load_estimation else 0
    x = ca.vertcat(zeta, tau, y[ny - 2] + th0, y[ny - 1], ca.DM.zeros(4))
    st, th1, _ = _coupled_step(s, x, method, orders_m, orders_o, load_estimation, (n_prev, n_new))
    y1 = _rotor_coordinates(st.x_next, th1, load_estimation)
    outs = [ca.jacobian(y1, n_new), ca.jacobian(y1, n_prev)]
    outs = [ca.substitute(o, ca.vertcat(n_prev, n_new), ca.DM.zeros(4)) for o in outs]
    x_sym = ca.SX.sym("x", N_STATE)
    y_of_x = _rotor_coordinates(x_sym, th0, load_estimation)
    f = ca.Function("f", [y, *s.values()], outs)
    G1, G0 = f(y_of_x, *s.values())
    name = f"pmac_reduced_order_noise_d_{method.replace('-', '_')}{'' if load_estimation else '_noTL'}"
    return ca.Function(name, [x_sym, *s.values()], [G1, G0], ["x", *INPUT_NAMES], ["G_new", "G_prev"])


@functools.cache
def _coupled_step_function(method: str, orders_m, orders_o, load_estimation: bool) -> ca.Function:
    """(xc = [x; theta], par = [w; T_L; motor; params]) -> (xc_next, errors at t_k)."""
    s = symbols(orders_m, orders_o)
    x = ca.SX.sym("x", N_STATE)
    st, th1, T_e = _coupled_step(s, x, method, orders_m, orders_o, load_estimation)
    err = ca.vertcat(
        s["w"] - st.est.w_hat,  # speed error [rad/s]
        wrap_angle(th1 - st.est.theta_hat),  # position error [rad]
        T_e - st.est.T_L_hat,  # load-torque error (viscosity included) [N m]
    )
    par = ca.vertcat(s["w"], s["T_L"], s["motor"], s["params"])
    xc = ca.vertcat(x, s["theta"])
    # keep the angle bounded so long runs do not lose precision
    return ca.Function("coupled", [xc, par], [ca.vertcat(st.x_next, wrap_angle(th1)), err])


@functools.cache
def orbit_function(
    method: str, orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool, n_steps: int
) -> ca.Function:
    """(xc0 [10], par) -> (xc [10 x n], err [3 x n]): n steps of the observer fed by the motor."""
    F = _coupled_step_function(method, orders_m, orders_o, load_estimation).mapaccum(n_steps)
    xc0 = ca.MX.sym("xc0", N_STATE + 1)
    par = ca.MX.sym("par", F.size1_in(1))
    xc, err = F(xc0, ca.repmat(par, 1, n_steps))
    return ca.Function(f"orbit{n_steps}", [xc0, par], [xc, err], ["xc0", "par"], ["xc", "err"])


def angle_period(orders_m: tuple[int, ...], orders_o: tuple[int, ...]) -> float:
    """Period in theta of the rotor-frame dynamics: 2 pi / gcd(|n - 1|) over all harmonics (inf if none)."""
    g = 0
    for n in (*orders_m, *orders_o):
        g = math.gcd(g, abs(n - 1))
    return 2 * math.pi / g if g else math.inf


def ordered_product(mats: np.ndarray) -> np.ndarray:
    """mats[..., M-1, :, :] @ ... @ mats[..., 0, :, :] (later factors left), in log2(M) batched steps."""
    while mats.shape[-3] > 1:
        if mats.shape[-3] % 2:
            eye = np.broadcast_to(np.eye(mats.shape[-1]), (*mats.shape[:-3], 1, *mats.shape[-2:]))
            mats = np.concatenate([mats, eye], axis=-3)
        mats = mats[..., 1::2, :, :] @ mats[..., 0::2, :, :]
    return mats[..., 0, :, :]


def period_steps(period: float, w: np.ndarray, T_s: float, cap: int = 4000, tol: float = 0.005) -> np.ndarray:
    """Steps M per point that cover a whole number of rotor-frame periods as closely as possible.

    The angle advances |w| T_s per step; M = round(q P / (|w| T_s)) for the smallest q whose rounding
    error is below ``tol`` of M (else the best q with M <= cap). 1 for a sinusoidal EMF (P = inf).
    """
    if math.isinf(period):
        return np.ones(w.size, int)
    r = period / (np.abs(w) * T_s)  # steps per period (real)
    out = np.empty(w.size, int)
    for k, rk in enumerate(r):  # a few points; each a short scalar search
        best, best_err = max(1, round(rk)), math.inf
        q = 1
        while q * rk <= cap or q == 1:
            m = max(1, round(q * rk))
            err = abs(m - q * rk) / m
            if err < best_err:
                best, best_err = m, err
            if err < tol:
                break
            q += 1
        out[k] = min(best, cap)
    return out
