"""One sampling period of the paper-002 observer: the discrete-time step that runs (and is generated to C).

The step integrates the observer ODE (16) over the sampling interval [t_(k-1), t_k] and returns the
estimates at t_k, after the current i_k and voltage u_k have been sampled (both measured, as in the
paper). It keeps the previous samples in its state so every scheme can use both ends of the interval:

    x = [zeta_a, zeta_b, tau, theta_hat, w_hat, i_a_prev, i_b_prev, u_a_prev, u_b_prev]

``theta_hat``/``w_hat`` are the previous estimates, needed by the harmonic removal (19)-(21) and the
speed sign (14). The right-hand side is evaluated by :func:`~sensorless.symbolic.reduced_order_observer.
observer_rhs` only; the schemes differ in where they evaluate it (docs/paper002.md, "Discretization"):

- ``euler``: forward Euler at the start of the interval (t_(k-1), i_(k-1), u_(k-1)).
- ``rk2-hold``: Heun's RK2 with the inputs held at the interval's first samples (what integrating
  forward from the newest sample gives: the input at the end of the step is not yet measured).
- ``rk2``: Heun's RK2 as in the textbook, each stage with the samples at its own time (t_(k-1), t_k):
  the paper's "second-order Runge-Kutta method" taken literally.
- ``midpoint``: the midpoint RK2, the middle stage with the mean of the two samples.
- ``rk2-rotating``: ``rk2`` in a frame that rotates at the previous speed estimate. The EMF state
  rotates at the electrical speed; a polynomial scheme in the stationary frame makes a small error per
  step that the load-torque integrator (and the speed (13)) turn into a steady bias. In the rotating
  frame a sinusoidal steady state is constant and the scheme is exact there.
- ``rk2-model`` (default): ``rk2-rotating`` around the observer model's own steady motion: the EMF the
  model predicts from the previous estimates, (w_hat/p_r) phi(theta_hat + w_hat t) by (3)-(4), harmonics
  included, is propagated exactly and Heun integrates only the (small, slow) remainder. Exact in the
  steady state of a sinusoidal motor, and far more accurate than the others with EMF harmonics.

Measured steady-state errors of each scheme are in docs/paper002.md.

The state's zeta/tau are the paper's (15); the position is the electrical angle in (-pi, pi].
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.pmac import EmfSeries, Sym, flux_derivative_slope
from sensorless.symbolic.pmac import emf as emf_of
from sensorless.symbolic.reduced_order_observer import (
    Estimates,
    ObserverParams,
    emf_from_zeta,
    emf_fundamental,
    estimates,
    observer_rhs,
    speed_sign,
)

DISCRETIZATIONS: dict[str, str] = {
    "euler": "forward Euler at the interval start",
    "rk2-hold": "Heun RK2, inputs held at the interval start",
    "rk2": "Heun RK2, samples at both interval ends (textbook, literal)",
    "midpoint": "midpoint RK2, mean of the two samples at mid-interval",
    "rk2-rotating": "Heun RK2 in the frame rotating at the speed estimate",
    "rk2-model": "Heun RK2 around the model's exactly propagated EMF, rotating frame (default)",
}
DEFAULT_DISCRETIZATION = "rk2-model"

STATE_NAMES = (
    "zeta_a",  # eq. (15) [V]
    "zeta_b",
    "tau",  # eq. (15) [N m]
    "theta_hat",  # previous position estimate [rad, electrical]
    "w_hat",  # previous speed estimate [rad/s, electrical]
    "i_a_prev",  # previous current sample [A]
    "i_b_prev",
    "u_a_prev",  # previous voltage sample [V]
    "u_b_prev",
)
N_STATE = len(STATE_NAMES)
BASE_PARAM_NAMES = ("R", "L", "J", "p_r", "g", "Gamma", "T_s")
OUTPUT_NAMES = ("x_next", "w_hat", "theta_hat", "T_L_hat", "e_hat", "phi_hat")


def param_names(orders: tuple[int, ...]) -> tuple[str, ...]:
    """Names of the ``params`` entries: R, L, J, p_r, g, Gamma, T_s, then Phi_n of each order."""
    return (*BASE_PARAM_NAMES, *(f"Phi_{n}" for n in orders))


def split_params(params: Sym, orders: tuple[int, ...]) -> tuple[ObserverParams, EmfSeries, Sym]:
    """(observer parameters, EMF series, T_s) from the ``params`` vector."""
    p = ObserverParams(params[0], params[1], params[2], params[3], params[4], params[5])
    n = len(BASE_PARAM_NAMES)
    return p, EmfSeries(tuple(orders), params[n : n + len(orders)]), params[6]


def rot(a: Sym) -> Sym:
    """Rotation matrix by angle a."""
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


JROT = ca.DM([[0.0, -1.0], [1.0, 0.0]])


class Step(NamedTuple):
    """The states at t_k and the estimates there."""

    x_next: Sym
    est: Estimates


def integrate(
    x: Sym, i: Sym, u: Sym, p: ObserverParams, emf: EmfSeries, T_s: Sym, method: str
) -> tuple[Sym, Sym]:
    """(zeta_k, tau_k) from the states at t_(k-1) with the chosen scheme (module docstring)."""
    zeta0, tau0, th0, w0 = x[0:2], x[2], x[3], x[4]
    i0, u0 = x[5:7], x[7:9]
    sigma0 = ca.if_else(w0 >= 0, 1, -1)  # speed sign during the step: the previous one, eq. (14)

    def f(zeta: Sym, tau: Sym, i_s: Sym, u_s: Sym, dt: Sym) -> tuple[Sym, Sym]:
        # stage at t_(k-1) + dt: harmonics predicted at theta_hat_(k-1) + w_hat_(k-1) dt, eqs. (20)-(21)
        dz, dtau, _ = observer_rhs(zeta, tau, i_s, u_s, th0 + w0 * dt, w0, sigma0, p, emf)
        return dz, dtau

    k1z, k1t = f(zeta0, tau0, i0, u0, 0)
    if method == "euler":
        return zeta0 + T_s * k1z, tau0 + T_s * k1t
    if method in ("rk2", "rk2-hold"):
        i1, u1 = (i, u) if method == "rk2" else (i0, u0)
        k2z, k2t = f(zeta0 + T_s * k1z, tau0 + T_s * k1t, i1, u1, T_s)
        return zeta0 + T_s / 2 * (k1z + k2z), tau0 + T_s / 2 * (k1t + k2t)
    if method == "midpoint":
        kmz, kmt = f(zeta0 + T_s / 2 * k1z, tau0 + T_s / 2 * k1t, (i0 + i) / 2, (u0 + u) / 2, T_s / 2)
        return zeta0 + T_s * kmz, tau0 + T_s * kmt
    if method in ("rk2-rotating", "rk2-model"):
        # zeta = E(dt) + R(w0 dt) z. "rk2-rotating": E = 0, z is zeta in the frame rotating at w0.
        # "rk2-model": E(dt) = (w0/p_r) phi(th0 + w0 dt) is the observer model's own steady EMF
        # (eqs. (3), (4) at the estimates), propagated exactly; Heun integrates only the remainder z.
        if method == "rk2-model":

            def E(dt: Sym) -> Sym:
                return emf_of(th0 + w0 * dt, w0, emf, p.p_r)  # eq. (3) at the estimates

            def dE(dt: Sym) -> Sym:
                return flux_derivative_slope(th0 + w0 * dt, emf) * (w0 * w0 / p.p_r)
        else:

            def E(dt: Sym) -> Sym:
                return ca.DM.zeros(2)

            dE = E
        R1 = rot(w0 * T_s)
        z0 = zeta0 - E(0)
        # dz/dt = R(-w0 dt) (dzeta/dt - dE/dt) - w0 J z
        s1 = k1z - dE(0) - w0 * (JROT @ z0)
        z_pred = z0 + T_s * s1
        k2z, k2t = f(E(T_s) + R1 @ z_pred, tau0 + T_s * k1t, i, u, T_s)
        s2 = R1.T @ (k2z - dE(T_s)) - w0 * (JROT @ z_pred)
        return E(T_s) + R1 @ (z0 + T_s / 2 * (s1 + s2)), tau0 + T_s / 2 * (k1t + k2t)
    raise ValueError(f"unknown discretization {method!r} (known: {', '.join(DISCRETIZATIONS)})")


def step(x: Sym, i: Sym, u: Sym, params: Sym, orders: tuple[int, ...], method: str) -> Step:
    """One sampling period: integrate (16) over [t_(k-1), t_k], then the estimates at t_k."""
    p, emf, T_s = split_params(params, orders)
    zeta, tau = integrate(x, i, u, p, emf, T_s, method)
    th0, w0 = x[3], x[4]
    theta_pred = th0 + w0 * T_s  # eq. (21)
    e1 = emf_fundamental(emf_from_zeta(zeta, i, p), theta_pred, w0, p.p_r, emf)  # eqs. (17), (19)-(22)
    sigma = speed_sign(ca.atan2(-e1[0], e1[1]), th0)  # eq. (14)
    est = estimates(zeta, tau, i, theta_pred, w0, sigma, p, emf)
    x_next = ca.vertcat(zeta, tau, est.theta_hat, est.w_hat, i, u)
    return Step(x_next, est)


@functools.cache
def observer_step_function(discretization: str, orders: tuple[int, ...] = (1,)) -> ca.Function:
    """The observer's discrete-time step as a named casadi Function (built once per scheme and series).

    Inputs:  x [9] (STATE_NAMES), i_ab [2] current sampled at t_k [A], u_ab [2] voltage sampled at t_k
             [V], params [7 + len(orders)] (:func:`param_names`: R, L, J, p_r, g, Gamma, T_s, Phi_n...).
    Outputs: x_next [9]; w_hat [rad/s, electrical]; theta_hat [rad, electrical, (-pi, pi]];
             T_L_hat [N m]; e_hat [2] (V); phi_hat [2] (phi at theta_hat, for the references (25)).
    """
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"unknown discretization {discretization!r} (known: {', '.join(DISCRETIZATIONS)})")
    orders = tuple(int(n) for n in orders)
    x = ca.SX.sym("x", N_STATE)
    i = ca.SX.sym("i_ab", 2)
    u = ca.SX.sym("u_ab", 2)
    params = ca.SX.sym("params", len(param_names(orders)))
    s = step(x, i, u, params, orders, discretization)
    e = s.est
    name = "deangelo2006_step_" + discretization.replace("-", "_")
    return ca.Function(
        name,
        [x, i, u, params],
        [s.x_next, e.w_hat, e.theta_hat, e.T_L_hat, e.e_hat, e.phi_hat],
        ["x", "i_ab", "u_ab", "params"],
        list(OUTPUT_NAMES),
    )
