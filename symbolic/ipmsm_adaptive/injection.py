"""HF signal injection coupled to the adaptive observer: Piippo et al. (2008) Section V, eqs. (17)-(22).

For analysis the demodulated error is taken in its averaged (ideal) form (19),
eps = K_eps sin(2 theta_tilde). The real sampled chain (carrier (17), band-pass, demodulation and
low-pass (18)) is :func:`hf_chain_step`, used by the runtime step (ipmsm_adaptive/step.py) that
simulation and C generation share. Both the carrier amplitude u_c and the PI bandwidth alpha_i decrease
linearly with |w_hat| and reach zero at w_Delta (Section V); ``fade`` is that common factor.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.filters import band_pass, biquad_step, low_pass
from sensorless.symbolic.frames import Sym
from sensorless.symbolic.pmsm import PmsmParams


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


def carrier_voltage(u_c: Sym, phi_c: Sym) -> Sym:
    """u_c cos(w_c t), eq. (17), at the carrier phase phi_c = w_c t [V] (on the estimated d axis)."""
    return u_c * ca.cos(phi_c)


def demodulation_gain(w_c: Sym, T_s: Sym) -> Sym:
    """2 sin(Delta/2) / Delta with Delta = w_c T_s: undoes the gain of the sampled carrier response.

    A carrier held constant over each sampling period (zero-order hold) integrates, in the inductance,
    to a sampled current Delta / (2 sin(Delta/2)) times the continuous-time response of amplitude
    u_c / w_c; this factor makes the demodulated error equal (19) exactly (docs/families/ipmsm_adaptive.md).
    """
    Delta = w_c * T_s
    return 2 * ca.sin(Delta / 2) / Delta


def demodulation_phase(w_c: Sym, T_s: Sym, delay: Sym) -> Sym:
    """(delay + 1/2) w_c T_s [rad]: lag of the sampled q-current response behind the carrier command.

    ``delay`` samples pass between a command and the voltage the motor sees (1 for the usual one-sample
    computation delay); the zero-order hold adds half a sample (docs/families/ipmsm_adaptive.md).
    """
    return (delay + 0.5) * w_c * T_s


class HfChainStep(NamedTuple):
    """One sample of the HF-injection chain, eqs. (17), (18)."""

    u_c_d: Sym  # carrier voltage to add on the estimated d axis, eq. (17) [V]
    eps: Sym  # demodulated, low-pass filtered error, eq. (18) [A]
    z_bp_next: Sym  # band-pass state (2x1) [A]
    z_lp_next: Sym  # low-pass state (2x1) [A]


def hf_chain_step(
    i_q: Sym,
    phi_c: Sym,
    z_bp: Sym,
    z_lp: Sym,
    u_c: Sym,
    w_c: Sym,
    T_s: Sym,
    w_bp: Sym,
    w_lp: Sym,
    delay: Sym,
) -> HfChainStep:
    """Carrier command (17) and error signal (18) at one sample of the carrier phase phi_c = w_c t_k.

    ``i_q`` is the measured current on the estimated q axis [A]; ``u_c`` the (faded) carrier amplitude
    [V]. The band-pass (centre w_c, bandwidth w_bp) extracts i_qc; it is demodulated by the sine of the
    carrier phase delayed by :func:`demodulation_phase`, scaled by :func:`demodulation_gain`, and
    low-pass filtered (Butterworth, cut-off w_lp). In steady state eps = K_eps sin(2 theta_tilde), (19).
    """
    bp = biquad_step(band_pass(w_c, w_bp, T_s), z_bp, i_q)  # i_qc: HF part of i_q
    ref = ca.sin(phi_c - demodulation_phase(w_c, T_s, delay))  # sin(w_c t) aligned with the response
    lp = biquad_step(low_pass(w_lp, T_s), z_lp, demodulation_gain(w_c, T_s) * bp.y * ref)  # eq. (18)
    return HfChainStep(carrier_voltage(u_c, phi_c), lp.y, bp.z_next, lp.z_next)
