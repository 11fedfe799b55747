"""Coupled motor + adaptive-observer system for analysis: Piippo et al. (2008) Section IV, Fig. 2.

The motor runs at an operating point: true electrical speed w_m and rotor-frame current i_s0, held
there by ideal (fast) current control, so its voltage is the steady-state voltage of eq. (1)/(29).
Seen from the estimated rotor frame (position error theta_tilde = theta_m - theta_hat) the motor's
current and voltage are T(theta_tilde) i_s0 and T(theta_tilde) u_s0 (eq. (24)). The observer (4)-(10)
processes those measurements; the position error integrates w_m - w_hat. With the HF injection the
averaged error (19) drives the PI (21), which corrects the flux model as in (20).

States x = [psi_hat_d, psi_hat_q, theta_tilde, w_i] (+ [x_eps] with injection); input w_m; output
w_hat. An optional second input, the current-measurement noise n (A, in the estimated rotor frame),
is added to the measured current the observer sees (not to the motor's): its Jacobians give the
noise input of the linearization, from the same expressions. The paper's error coordinates
(i_tilde, theta_tilde) are an output map z(x) of this system, so the linearization can be expressed in
either; nothing about the error dynamics is typed by hand.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import Sym, rot
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw
from sensorless.symbolic.ipmsm_adaptive.injection import (
    averaged_error,
    fade,
    faded_pi_gains,
    injection_gain,
    injection_pi,
)
from sensorless.symbolic.ipmsm_adaptive.observer import observer_rates, speed_adaptation
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, stator_voltage

N_INJ = 4  # injection vector: [w_c (rad/s), u_c (V), alpha_i (rad/s), w_Delta (rad/s)]


class ClosedLoop(NamedTuple):
    """Symbolic pieces of the coupled system."""

    x_dot: Sym  # state derivative
    w_hat: Sym  # speed estimate (output of G_c, eq. (15))
    i_tilde: Sym  # current estimation error in the estimated frame
    z: Sym  # paper coordinates [i_tilde; theta_tilde; remaining states]


def operating_point_signals(theta_tilde: Sym, w_m: Sym, i_s0: Sym, motor: PmsmParams) -> tuple[Sym, Sym, Sym]:
    """Current, voltage and flux of the motor at (w_m, i_s0), seen in the estimated frame.

    Rotor frame: psi_s0 by (2), u_s0 = R_s i_s0 + w_m J psi_s0 by (1) with dpsi/dt = 0, i.e. (29).
    """
    psi_s0 = flux_from_current(i_s0, motor)  # eq. (2)
    u_s0 = stator_voltage(i_s0, 0, psi_s0, w_m, motor.R_s)  # eq. (1) -> (29)
    T = rot(theta_tilde)  # eq. (24)
    return T @ i_s0, T @ u_s0, T @ psi_s0


def closed_loop(
    x: Sym,
    w_m: Sym,
    i_s0: Sym,
    motor: PmsmParams,
    est: PmsmParams,
    alpha_fo: Sym,
    law: GainLaw,
    gain_params: Sym,
    inj: Sym | None = None,
    w_hat_override: Sym | None = None,
    i_noise: Sym | None = None,
) -> ClosedLoop:
    """The coupled system's right-hand side.

    ``inj`` = [w_c, u_c, alpha_i, w_Delta] enables the averaged HF-injection loop (x has 5 states).
    ``w_hat_override`` opens the speed-adaptation loop: the given w_hat replaces the PI output (9),
    which gives the open-loop system (12) with the speed error w_m - w_hat as its input.
    ``i_noise`` (2x1, A) is added to the measured current (current-sensor noise seen in the estimated
    frame; white isotropic noise has the same statistics in every frame).
    """
    psi_hat, theta_tilde, w_i = x[0:2], x[2], x[3]
    i_meas, u_meas, _ = operating_point_signals(theta_tilde, w_m, i_s0, motor)
    if i_noise is not None:
        i_meas = i_meas + i_noise
    w_hat = w_hat_override
    if w_hat is None:
        w_hat = speed_adaptation(psi_hat, w_i, i_meas, est, alpha_fo).w_hat  # eq. (9)

    w_eps = 0
    dx_extra: list[Sym] = []
    if inj is not None:
        w_c, u_c, alpha_i, w_Delta = inj[0], inj[1], inj[2], inj[3]
        f = fade(w_hat, w_Delta)  # driven by the observer's estimate, not the true speed
        K_eps = injection_gain(u_c, w_c, motor)  # the motor's true saliency produces eps, (19)
        K_eps_hat = injection_gain(u_c, w_c, est)  # the controller designs (22) from estimates
        gamma_p, gamma_i = faded_pi_gains(f, alpha_i, K_eps_hat)
        eps = averaged_error(theta_tilde, f * K_eps)  # eq. (19) with u_c faded
        pi = injection_pi(eps, x[4], gamma_p, gamma_i)  # eq. (21)
        w_eps = pi.w_eps
        dx_extra = [pi.dx_eps]

    r = observer_rates(psi_hat, w_i, u_meas, i_meas, est, alpha_fo, law, gain_params, w_eps, w_hat_override)
    dtheta_tilde = w_m - r.w_hat  # theta_hat integrates w_hat
    x_dot = ca.vertcat(r.dpsi_hat, dtheta_tilde, r.dw_i, *dx_extra)
    z = ca.vertcat(r.i_tilde, x[2:])
    return ClosedLoop(x_dot, r.w_hat, r.i_tilde, z)
