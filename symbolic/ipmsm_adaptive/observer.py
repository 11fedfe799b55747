"""Speed-adaptive stator-flux observer, eqs. (4)-(10), with the HF correction (20).

Piippo, Hinkkanen, Luomi (2008).

The observer runs in the estimated rotor reference frame (angle theta_hat, speed w_hat). Its states
are the stator-flux estimate psi_hat (2x1, V s) and the integral part w_i of the PI adaptation (9),
kept as a speed (rad/s) so that it has a physical unit and a natural bound. The position estimate
integrates w_hat; where it lives (error coordinate or wrapped angle) is the caller's business.
"""

from __future__ import annotations

from typing import NamedTuple

from sensorless.symbolic.frames import J, Sym
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, gain_matrix
from sensorless.symbolic.pmsm import PmsmParams, current_from_flux


def adaptation_gains(alpha_fo: Sym, psi_pm_hat: Sym) -> tuple[Sym, Sym]:
    """k_p = 2 alpha_fo / psi_pm_hat, k_i = alpha_fo^2 / psi_pm_hat, eq. (10)."""
    return 2 * alpha_fo / psi_pm_hat, alpha_fo**2 / psi_pm_hat


def error_term(i_tilde: Sym, L_q_hat: Sym) -> Sym:
    """F_eps = C1 i_tilde with C1 = [0, L_q_hat], eq. (8) (units V s)."""
    return L_q_hat * i_tilde[1]


class ObserverRates(NamedTuple):
    """Right-hand side and outputs of the adaptive observer at one instant."""

    dpsi_hat: Sym  # d psi_hat / dt, eq. (4) or (20) [V]
    dw_i: Sym  # d w_i / dt: integral part of (9) [rad/s^2]
    w_hat: Sym  # speed estimate, eq. (9) [rad/s]
    i_hat: Sym  # current estimate, eq. (5) [A]
    i_tilde: Sym  # current estimation error, eq. (6) [A]
    F_eps: Sym  # error term, eq. (8) [V s]
    lambda1: Sym  # gain actually applied [ohm]
    lambda2: Sym


class Adaptation(NamedTuple):
    """Current error and PI speed adaptation, eqs. (5), (6), (8), (9)."""

    w_hat: Sym  # speed estimate, eq. (9) [rad/s]
    dw_i: Sym  # d w_i / dt: integral part of (9) [rad/s^2]
    i_hat: Sym  # current estimate, eq. (5) [A]
    i_tilde: Sym  # current estimation error, eq. (6) [A]
    F_eps: Sym  # error term, eq. (8) [V s]


def speed_adaptation(psi_hat: Sym, w_i: Sym, i_s: Sym, est: PmsmParams, alpha_fo: Sym) -> Adaptation:
    """Current estimate (5), error (6), error term (8) and PI adaptation (9) with gains (10)."""
    k_p, k_i = adaptation_gains(alpha_fo, est.psi_pm)  # eq. (10)
    i_hat = current_from_flux(psi_hat, est)  # eq. (5)
    i_tilde = i_s - i_hat  # eq. (6)
    F_eps = error_term(i_tilde, est.L_q)  # eq. (8)
    w_hat = -k_p * F_eps + w_i  # eq. (9): proportional part + integral state
    return Adaptation(w_hat, -k_i * F_eps, i_hat, i_tilde, F_eps)


def observer_rates(
    psi_hat: Sym,
    w_i: Sym,
    u_s: Sym,
    i_s: Sym,
    est: PmsmParams,
    alpha_fo: Sym,
    law: GainLaw,
    gain_params: Sym,
    w_eps: Sym = 0,
    w_hat: Sym | None = None,
) -> ObserverRates:
    """Adaptive observer (4)-(10); with ``w_eps`` != 0 the HF-injection-corrected model (20).

    ``u_s`` and ``i_s`` are the measured voltage and current in the estimated rotor frame (the
    primed quantities of the paper). Passing ``w_hat`` imposes the speed estimate instead of the PI
    output (the adaptation loop opened, as in the open-loop system (12)-(13)).
    """
    a = speed_adaptation(psi_hat, w_i, i_s, est, alpha_fo)
    if w_hat is None:
        w_hat = a.w_hat
    lambda1, lambda2 = law.expr(w_hat, gain_params)
    lam = gain_matrix(lambda1, lambda2)  # eq. (7)
    dpsi_hat = u_s - est.R_s * a.i_hat - (w_hat - w_eps) * (J @ psi_hat) + lam @ a.i_tilde  # (4)/(20)
    return ObserverRates(dpsi_hat, a.dw_i, w_hat, a.i_hat, a.i_tilde, a.F_eps, lambda1, lambda2)
