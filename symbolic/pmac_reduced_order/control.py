"""Speed control of the reduced-order-observer drive, Fig. 1: PI, load-torque feedforward, references (25).

De Angelo et al. (2006).

The speed loop closes on the observer's estimates: the PI acts on w_ref - w_hat (electrical rad/s), the
estimated load torque T_L_hat is added to its output as a feedforward, and the current references (25)
shape the current along phi_hat so that phi . i (the torque (5)) is smooth with the least copper loss.
The paper gives neither the PI structure nor its gains; the drive description names a bandwidth
``alpha_s`` and a limit ``T_max`` (docs/families/pmac_reduced_order.md).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import Sym
from sensorless.symbolic.pmac import ripple_free_current

SPEED_PARAM_NAMES = ("k_p", "k_i", "T_max", "T_s", "feedforward")


def speed_pi_gains(alpha_s: Sym, J: Sym, p_r: Sym) -> tuple[Sym, Sym]:
    """k_p = 2 alpha_s J / p_r [N m s/rad], k_i = alpha_s^2 J / p_r [N m/rad].

    With the mechanics (2), dw/dt = p_r (T - T_L) / J, a PI on the electrical speed error places both
    closed-loop poles at -alpha_s: s^2 + (p_r k_p / J) s + p_r k_i / J = (s + alpha_s)^2.
    """
    return 2 * alpha_s * J / p_r, alpha_s**2 * J / p_r


def current_references(T_total: Sym, phi_hat: Sym) -> Sym:
    """i* = (T_e* + T_L_hat) phi_hat / |phi_hat|^2, eq. (25): phi_hat . i* = T_total, least |i*|."""
    return ripple_free_current(T_total, phi_hat)


class SpeedControl(NamedTuple):
    """Outputs of the speed controller at one instant."""

    T_ref: Sym  # total torque reference T_e* + T_L_hat after the limit [N m]
    i_ref: Sym  # current references (25) [A]
    dx_i: Sym  # rate of the PI integral [N m/s]


def speed_controller(
    w_ref: Sym,
    w_hat: Sym,
    x_i: Sym,
    T_L_hat: Sym,
    phi_hat: Sym,
    k_p: Sym,
    k_i: Sym,
    T_max: Sym,
    feedforward: Sym = 1,
) -> SpeedControl:
    """Speed PI with load-torque feedforward (Fig. 1) and the references (25).

    T_ref = clip(k_p (w_ref - w_hat) + x_i + feedforward * T_L_hat, -T_max, T_max). The integral stops
    while the limit is active and the error pushes further into it (conditional integration), so it does
    not wind up. ``feedforward`` is 1 (with, Fig. 5(b)) or 0 (without, Fig. 5(a)).
    """
    e_w = w_ref - w_hat
    T_raw = k_p * e_w + x_i + feedforward * T_L_hat
    T_ref = ca.fmin(ca.fmax(T_raw, -T_max), T_max)
    winding = ca.logic_or(ca.logic_and(T_raw > T_max, e_w > 0), ca.logic_and(T_raw < -T_max, e_w < 0))
    dx_i = ca.if_else(winding, 0, k_i * e_w)
    return SpeedControl(T_ref, current_references(T_ref, phi_hat), dx_i)


@functools.cache
def speed_controller_function() -> ca.Function:
    """One control period of the speed loop as a casadi Function (forward Euler on the integral).

    Inputs: x_i [N m], w_ref, w_hat [rad/s], T_L_hat [N m], phi_hat [2], params = SPEED_PARAM_NAMES
    (k_p, k_i, T_max, T_s, feedforward). Outputs: x_i_next, T_ref [N m], i_ref [2] (A).
    """
    x_i, w_ref, w_hat, T_L_hat = (ca.SX.sym(n) for n in ("x_i", "w_ref", "w_hat", "T_L_hat"))
    phi_hat = ca.SX.sym("phi_hat", 2)
    par = ca.SX.sym("params", len(SPEED_PARAM_NAMES))
    k_p, k_i, T_max, T_s, ff = (par[k] for k in range(5))
    c = speed_controller(w_ref, w_hat, x_i, T_L_hat, phi_hat, k_p, k_i, T_max, ff)
    return ca.Function(
        "pmac_reduced_order_speed_control",
        [x_i, w_ref, w_hat, T_L_hat, phi_hat, par],
        [x_i + T_s * c.dx_i, c.T_ref, c.i_ref],
        ["x_i", "w_ref", "w_hat", "T_L_hat", "phi_hat", "params"],
        ["x_i_next", "T_ref", "i_ref"],
    )
