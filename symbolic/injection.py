"""HF signal injection coupled to the adaptive observer, paper 000 Section V, eqs. (17)-(22).

For analysis the demodulated error is taken in its averaged (ideal) form (19),
eps = K_eps sin(2 theta_tilde); the real carrier/band-pass/demodulation chain belongs to simulation
and C generation. Both the carrier amplitude u_c and the PI bandwidth alpha_i decrease linearly with
|w_hat| and reach zero at w_Delta (Section V); ``fade`` is that common factor.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.pmsm import PmsmParams, Sym


def fade(w_hat: Sym, w_Delta: Sym) -> Sym:
    """Linear fade factor max(0, 1 - |w_hat|/w_Delta) applied to u_c and alpha_i (Section V)."""
    return ca.fmax(0, 1 - ca.fabs(w_hat) / w_Delta)


def injection_gain(u_c: Sym, w_c: Sym, p: PmsmParams) -> Sym:
    """K_eps = (u_c / w_c) (L_q - L_d) / (4 L_q L_d), eq. (19) [A]."""
    return u_c / w_c * (p.L_q - p.L_d) / (4 * p.L_q * p.L_d)


def averaged_error(theta_tilde: Sym, K_eps: Sym) -> Sym:
    """eps = K_eps sin(2 theta_tilde), eq. (19): the ideal demodulated error signal [A]."""
    return K_eps * ca.sin(2 * theta_tilde)


def pi_gains(alpha_i: Sym, K_eps_hat: Sym) -> tuple[Sym, Sym]:
    """gamma_p = alpha_i / (2 K_eps), gamma_i = alpha_i^2 / (6 K_eps), eq. (22)."""
    return alpha_i / (2 * K_eps_hat), alpha_i**2 / (6 * K_eps_hat)


def faded_pi_gains(f: Sym, alpha_i0: Sym, K_eps_hat0: Sym) -> tuple[Sym, Sym]:
    """Eq. (22) with alpha_i = f alpha_i0 and K_eps_hat = f K_eps_hat0 (u_c faded alike).

    The common factor f cancels in gamma_p and leaves one f in gamma_i; writing it out keeps the
    expression finite where the injection is off (f = 0), where eps = 0 anyway.
    """
    gamma_p, gamma_i = pi_gains(alpha_i0, K_eps_hat0)
    return gamma_p, f * gamma_i


class InjectionRates(NamedTuple):
    """Correction speed and integrator rate of the PI mechanism (21)."""

    w_eps: Sym  # omega_eps, eq. (21) [rad/s]
    dx_eps: Sym  # d/dt of the integral part of (21) [rad/s^2]
    eps: Sym  # error signal, eq. (18)/(19) [A]


def injection_pi(eps: Sym, x_eps: Sym, gamma_p: Sym, gamma_i: Sym) -> InjectionRates:
    """omega_eps = gamma_p eps + x_eps with d x_eps/dt = gamma_i eps: the PI (21).

    The integral part is kept as a speed x_eps = integral(gamma_i eps dt) [rad/s] so that a faded
    gamma_i does not rescale what was already integrated, and so it can be bounded (Section V).
    """
    return InjectionRates(gamma_p * eps + x_eps, gamma_i * eps, eps)
