"""Extended reduced-order EMF + load-torque observer, eqs. (9)-(24), in the zeta/tau form (15)-(17).

De Angelo, Bossio, Solsona, Garcia, Valla (2006).

The observer's states are zeta = e_hat + g L i (2x1, V) and tau = T_L_hat - (Gamma L / J) phi_hat . i
(N m), eq. (15); it never differentiates the measured current. At any instant the estimates follow
algebraically (:func:`estimates`): the EMF (17), its fundamental after removing the predicted
harmonics (19)-(22), the position (18), phi_hat (23), the speed (13)-(14), d phi_hat/dt (24), and the
load torque (17). The rates (16) use them (:func:`rates`). Gamma = 0 is the observer without load-torque
estimation ([11]): tau, hence T_L_hat, then stays at its initial value.

Choices where the paper is open or misprinted (docs/families/pmac_reduced_order.md, all tested):
- Speeds are electrical (w_hat); the paper's omega is w_hat / p_r (symbolic/pmac.py).
- (16) multiplies d phi_hat/dt by the unsigned speed (13); that is the term d phi_hat/dt * omega_hat of
  (9) only for omega >= 0. Here the signed speed (14) is used, as (9) requires in both directions.
- (18) with tan^-1 of a ratio leaves a branch open. The EMF fundamental is omega_hat * phi_1(theta), so
  it points the other way at negative speed: theta_hat = atan2(-sigma e_a1, sigma e_b1) with sigma the
  speed sign. The branch-free angle atan2(-e_a1, e_b1) moves with the rotor in both directions and gives
  the sign of (14) (:func:`speed_sign`).
- (21) is read as the prediction theta~_(k) = theta_hat_(k-1) + w_hat_(k-1) T_s used in (19); its
  printed left-hand side theta_hat_(k) would contradict (18). (20) is the constant-speed assumption
  behind it: the speed in (19) and (21) is the previous estimate.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import Sym, half_open
from sensorless.symbolic.pmac import (
    EmfSeries,
    current_derivative,
    flux_derivative,
    flux_derivative_slope,
    harmonic_flux_derivative,
    torque,
)


class ObserverParams(NamedTuple):
    """The observer's model parameters (estimates) and gains."""

    R: Sym  # estimated stator resistance [ohm]
    L: Sym  # estimated inductance [H]
    J: Sym  # estimated inertia [kg m^2, reading's units]
    p_r: Sym  # speed factor of the reading: omega_paper = w / p_r
    g: Sym  # EMF observer gain [1/s], eq. (9)
    Gamma: Sym  # load-torque adaptation gain [A^2 s^2], eq. (10)


class Estimates(NamedTuple):
    """The observer's algebraic outputs at one instant."""

    e_hat: Sym  # EMF estimate, eq. (17) [V]
    theta_raw: Sym  # branch-free angle of the EMF fundamental, (18) without the sign [rad]
    theta_hat: Sym  # position estimate, eq. (18) [rad, electrical, in (-pi, pi]]
    w_hat: Sym  # speed estimate, eqs. (13)-(14) [rad/s, electrical]
    phi_hat: Sym  # flux derivative at theta_hat, eq. (23)
    dphi_hat: Sym  # its time derivative, eq. (24)
    T_L_hat: Sym  # load-torque estimate, eq. (17) [N m]


def emf_from_zeta(zeta: Sym, i: Sym, p: ObserverParams) -> Sym:
    """e_hat = zeta - g L i, eq. (17)."""
    return zeta - p.g * p.L * i


def load_torque_from_tau(tau: Sym, phi_hat: Sym, i: Sym, p: ObserverParams) -> Sym:
    """T_L_hat = tau + (Gamma L / J) phi_hat . i, eq. (17)."""
    return tau + p.Gamma * p.L / p.J * torque(phi_hat, i)


def zeta_tau(e_hat: Sym, T_L_hat: Sym, phi_hat: Sym, i: Sym, p: ObserverParams) -> tuple[Sym, Sym]:
    """The change of variables (15): (zeta, tau) from (e_hat, T_L_hat); used to initialise the states."""
    return e_hat + p.g * p.L * i, T_L_hat - p.Gamma * p.L / p.J * torque(phi_hat, i)


def emf_fundamental(e_hat: Sym, theta_pred: Sym, w_pred: Sym, p_r: Sym, emf: EmfSeries) -> Sym:
    """The EMF fundamental [e_a1, e_b1]: e_hat minus the predicted harmonics, eqs. (19)-(22).

    The harmonics (19) are evaluated at the predicted angle ``theta_pred`` (21) with the speed
    ``w_pred`` (20), both electrical; (22) subtracts them from e_hat.
    """
    e_h = harmonic_flux_derivative(theta_pred, emf) * (w_pred / p_r)  # eq. (19)
    return e_hat - e_h  # eq. (22)


def speed_from_emf(e_hat: Sym, phi_hat: Sym, sigma: Sym, p_r: Sym) -> Sym:
    """w_hat = sigma p_r |e_hat| / |phi_hat|, eqs. (13)-(14): the electrical speed with the sign (14)."""
    return sigma * p_r * ca.sqrt(ca.dot(e_hat, e_hat) / ca.dot(phi_hat, phi_hat))


def speed_sign(theta_raw: Sym, theta_prev: Sym) -> Sym:
    """sign(Delta theta_hat / Delta t) of eq. (14), +1 or -1 (+1 when the angle has not moved).

    The branch-free EMF angle and the previous position differ by the rotation over the step plus 0 or
    pi, so the step is read modulo pi (valid while |w| T_s < pi/2).
    """
    d = theta_raw - theta_prev
    d = d - ca.pi * ca.floor(d / ca.pi + 0.5)  # wrap to [-pi/2, pi/2)
    return ca.if_else(d >= 0, 1, -1)


def estimates(
    zeta: Sym,
    tau: Sym,
    i: Sym,
    theta_pred: Sym,
    w_pred: Sym,
    sigma: Sym,
    p: ObserverParams,
    emf: EmfSeries,
) -> Estimates:
    """All estimates from the states (zeta, tau) and the measured current i, eqs. (13)-(14), (17)-(24).

    ``theta_pred``/``w_pred`` feed the harmonic removal (19)-(22); ``sigma`` (+1/-1) is the speed sign of
    (14) and picks the branch of (18).
    """
    e_hat = emf_from_zeta(zeta, i, p)  # eq. (17)
    e1 = emf_fundamental(e_hat, theta_pred, w_pred, p.p_r, emf)  # eqs. (19)-(22)
    theta_raw = ca.atan2(-e1[0], e1[1])  # eq. (18), branch-free
    theta_hat = half_open(ca.atan2(-sigma * e1[0], sigma * e1[1]))  # eq. (18), speed-sign branch, (-pi, pi]
    phi_hat = flux_derivative(theta_hat, emf)  # eq. (23)
    w_hat = speed_from_emf(e_hat, phi_hat, sigma, p.p_r)  # eqs. (13)-(14)
    dphi_hat = w_hat * flux_derivative_slope(theta_hat, emf)  # eq. (24)
    T_L_hat = load_torque_from_tau(tau, phi_hat, i, p)  # eq. (17)
    return Estimates(e_hat, theta_raw, theta_hat, w_hat, phi_hat, dphi_hat, T_L_hat)


def rates(est: Estimates, i: Sym, v: Sym, p: ObserverParams) -> tuple[Sym, Sym]:
    """d zeta/dt and d tau/dt of eq. (16), with d i_hat/dt of (11).

    The first term is d phi_hat/dt * omega_hat with the signed paper speed omega_hat = w_hat / p_r (see
    the module docstring: (16) prints the unsigned (13)).
    """
    di_hat = current_derivative(i, est.e_hat, v, p.R, p.L)  # eq. (11)
    k = 1 / p.J
    dzeta = (
        est.dphi_hat * (est.w_hat / p.p_r)
        + k * est.phi_hat * (torque(est.phi_hat, i) - est.T_L_hat)
        + p.g * p.L * di_hat
    )  # eq. (16)
    dtau = -p.Gamma * p.L * k * (ca.dot(est.phi_hat, di_hat) + ca.dot(est.dphi_hat, i))  # eq. (16)
    return dzeta, dtau


def observer_rhs(
    zeta: Sym,
    tau: Sym,
    i: Sym,
    v: Sym,
    theta_pred: Sym,
    w_pred: Sym,
    sigma: Sym,
    p: ObserverParams,
    emf: EmfSeries,
) -> tuple[Sym, Sym, Estimates]:
    """The continuous-time observer: (d zeta/dt, d tau/dt, estimates) at one instant."""
    est = estimates(zeta, tau, i, theta_pred, w_pred, sigma, p, emf)
    dzeta, dtau = rates(est, i, v, p)
    return dzeta, dtau, est
