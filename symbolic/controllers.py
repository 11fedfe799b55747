"""Discrete-time drive controllers: PI current control, IP/PI speed control, speed filter, limits.

Piippo, Hinkkanen, Luomi (2008) Section VI names the structure but not the formulas: "IP-type speed
control", "PI-type current control in the estimated rotor reference frame", references by maximum torque
per current [12], the torque limited to 1.57 T_N. The formulas chosen here are the standard model-based
designs of that school (Harnefors: internal model control, IP speed control), written so that with exact
parameters and no delay the closed loops are first order (current, bandwidth alpha_c) and critically
damped second order (speed, bandwidth alpha_s). Every choice is listed in docs/simulation.md.

All controllers run once per sampling period T_s; their integral states are kept in physical units
(volts, newton metres) so that they can be limited and initialized at an operating point. Anti-windup
is the "realizable reference" method: after limiting, the integral state is corrected so that the
controller's output equals what was actually realized.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import J, Sym
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current


class CurrentControl(NamedTuple):
    """One sample of the PI current controller."""

    u_ref: Sym  # limited voltage reference in the controller's frame (2x1) [V]
    u_i_next: Sym  # next integral state (2x1) [V]


def current_gains(alpha_c: Sym, est: PmsmParams) -> tuple[Sym, Sym]:
    """PI gains (k_p, k_i) by internal model control (Harnefors and Nee), diagonal 2x2 [ohm, ohm/s].

    k_p = alpha_c L̂, k_i = alpha_c R̂: the PI zero cancels the stator pole -R/L, so with the cross
    coupling decoupled and exact estimates i/i_ref = alpha_c/(s + alpha_c). (The 2DOF variant with
    k_p = 2 alpha_c L̂ crosses over at ~2 alpha_c, where the 1.5-sample delay of a 5-kHz drive with
    alpha_c = 2 pi 400 rad/s costs 86 degrees of phase; IMC crosses over at alpha_c: 43 degrees.)
    """
    L_hat = ca.diag(ca.vertcat(est.L_d, est.L_q))
    return alpha_c * L_hat, alpha_c * est.R_s * ca.DM.eye(2)


def limit_magnitude(u: Sym, u_max: Sym) -> Sym:
    """u scaled down to |u| <= u_max (direction kept): the linear range of the inverter."""
    mag = ca.sqrt(u[0] ** 2 + u[1] ** 2)
    return u * ca.fmin(1, u_max / ca.fmax(mag, 1e-12))


def pi_current_control(
    i_ref: Sym,
    i_s: Sym,
    u_i: Sym,
    w_f: Sym,
    est: PmsmParams,
    alpha_c: Sym,
    T_s: Sym,
    u_max: Sym,
    u_ff: Sym = 0,
) -> CurrentControl:
    """PI current control in a frame rotating at w_f (the estimated rotor frame), with decoupling.

    u_ref = k_p (i_ref - i_s) + u_i + w_f J psî_s, psî_s = L̂ i_s + psî_pm (eqs. (1)-(2) with the
    estimates): the back-EMF and the cross coupling of (1) are fed forward, the PI handles the rest.
    The integral u_i advances by T_s k_i (i_ref - i_s) and is corrected by the limiting deficit
    (realizable reference), so it never winds up against the voltage limit u_max. ``u_ff`` is an
    extra feedforward voltage in the same frame (De Angelo et al.: the model EMF with its harmonics).
    """
    k_p, k_i = current_gains(alpha_c, est)
    e = i_ref - i_s
    ff = w_f * (J @ flux_from_current(i_s, est))  # eq. (1) rotational voltage, estimated
    u_unlim = k_p @ e + u_i + ff + u_ff
    u_ref = limit_magnitude(u_unlim, u_max)
    u_i_next = u_i + T_s * (k_i @ e) + (u_ref - u_unlim)  # realizable reference anti-windup
    return CurrentControl(u_ref, u_i_next)


class SpeedControl(NamedTuple):
    """One sample of the speed controller."""

    T_ref: Sym  # limited torque reference [N m]
    x_next: Sym  # next integral state [N m]


def speed_gains(alpha_s: Sym, J_hat: Sym, pole_pairs: Sym) -> tuple[Sym, Sym]:
    """IP gains (k_p, k_i) on the electrical speed [N m s/rad, N m/rad].

    With the electrical-speed mechanics (J/p) dw_m/dt = T_e - T_L, k_p = 2 alpha_s J/p and
    k_i = alpha_s^2 J/p place both closed-loop poles at -alpha_s: w_m/w_ref = alpha_s^2/(s + alpha_s)^2.
    """
    J_el = J_hat / pole_pairs
    return 2 * alpha_s * J_el, alpha_s**2 * J_el


def speed_control(
    w_ref: Sym,
    w: Sym,
    x_s: Sym,
    alpha_s: Sym,
    J_hat: Sym,
    pole_pairs: Sym,
    T_s: Sym,
    T_max: Sym,
    T_ff: Sym = 0,
    ip: Sym = 1,
) -> SpeedControl:
    """IP (``ip`` = 1, Piippo et al.) or PI (``ip`` = 0) speed control with torque feedforward.

    T_ref = x_s - k_p w (IP: the proportional part acts on the speed only, so a reference step does
    not kick the torque) or T_ref = x_s + k_p (w_ref - w) (PI), plus the feedforward T_ff (De Angelo et
    al. add their load-torque estimate, Fig. 1 and eq. (25)), limited to +-T_max. The integral state x_s
    [N m] advances by T_s k_i (w_ref - w) and takes the limiting deficit (realizable reference).
    """
    k_p, k_i = speed_gains(alpha_s, J_hat, pole_pairs)
    e = w_ref - w
    T_unlim = x_s + k_p * (ip * (-w) + (1 - ip) * e) + T_ff
    T_ref = ca.fmin(ca.fmax(T_unlim, -T_max), T_max)
    x_next = x_s + T_s * k_i * e + (T_ref - T_unlim)
    return SpeedControl(T_ref, x_next)


def delay_compensated_angle(theta: Sym, w: Sym, T_s: Sym) -> Sym:
    """theta + 1.5 w T_s: the mean angle over the period in which a command computed now is applied.

    With a one-sample computation delay and a zero-order hold, a voltage computed at t_k is applied
    over [t_k + T_s, t_k + 2 T_s], whose midpoint the rotor reaches 1.5 samples later.
    """
    return theta + 1.5 * w * T_s


def low_pass_step(y: Sym, u: Sym, alpha: Sym, T_s: Sym) -> Sym:
    """First-order low-pass alpha/(s + alpha) sampled exactly for an input held over the period.

    Used on the speed estimate fed to the controllers: the adaptation law (9) has a proportional path
    (k_p = 2 alpha_fo / psî_pm) that passes current-measurement ripple straight into w_hat, and
    through the speed controller's and the decoupling's gains that would close a loop at the
    Nyquist frequency with the computation delay (docs/simulation.md).
    """
    return y + (1 - ca.exp(-alpha * T_s)) * (u - y)


def ramp_step(w_r: Sym, w_cmd: Sym, a_max: Sym, T_s: Sym) -> Sym:
    """The speed reference's rate limiter: w_r moves towards the command w_cmd by at most a_max T_s a
    period (a_max [rad/s^2]); a_max <= 0 passes the command through (no limiter).

    What drives put before the speed controller so that a step of the command becomes a ramp the
    drive can follow (ODrive's velocity-ramp input mode, ``controller.config.vel_ramp_rate``; the
    drive file's ``[control] speed_ramp``, docs/simulation.md). Inside the limit w_r_next = w_cmd
    exactly, so at a steady operating point the limiter is no dynamics of the loop (its derivative
    with respect to w_r is 0, with respect to w_cmd 1).
    """
    d = a_max * T_s
    return ca.if_else(a_max > 0, w_r + ca.fmin(ca.fmax(w_cmd - w_r, -d), d), w_cmd)
