"""Continuous plants for simulation: the IPMSM of paper 000 (1)-(3) with its mechanics, integrated per sample.

The motor is a continuous-time system driven by an ideal inverter: the stator voltage is held constant
in the stationary frame over each sampling period (zero-order hold). Between samples the plant is
integrated by the classical fourth-order Runge-Kutta method with ``n_sub`` substeps, unrolled in SX so
that a whole sampling period is one expression (and the whole simulation one compiled loop).

Plant state (paper 000): x = [psi_d, psi_q, theta_m, w_m]: the stator flux in the true rotor frame
(V s), the rotor angle and the electrical rotor speed (rad, rad/s). Mechanics in electrical speed:
(J/p) dw_m/dt = T_e - T_L - B w_m/p, with B the viscous friction [N m s/rad, mechanical]; a prescribed
speed (a stiff load machine, ``stiff``) replaces that equation by dw_m/dt = 0 over the period.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.pmsm import (
    PmsmParams,
    Sym,
    current_from_flux,
    flux_derivative,
    rot,
    torque,
)


def rk4(f: Callable[[Sym], Sym], x: Sym, h: Sym, n_sub: int) -> Sym:
    """x advanced by n_sub classical RK4 steps of length h/n_sub for the autonomous dx/dt = f(x)."""
    dt = h / n_sub
    for _ in range(n_sub):
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


class Mechanics(NamedTuple):
    """Mechanical parameters [J (kg m^2), B (N m s/rad), p]."""

    J: Sym
    B: Sym
    pole_pairs: Sym


def ipmsm_rates(x: Sym, u_ab: Sym, T_L: Sym, motor: PmsmParams, mech: Mechanics, stiff: Sym) -> Sym:
    """dx/dt of the plant state [psi_d, psi_q, theta_m, w_m] for the stationary-frame voltage u_ab.

    Flux: eq. (1) in the rotor frame, dpsi/dt = u - R_s i - w_m J psi with i from (2); torque (3).
    ``stiff`` = 1 holds the speed (prescribed by a load machine), 0 lets the mechanics act.
    """
    psi, theta_m, w_m = x[0:2], x[2], x[3]
    u_r = rot(theta_m).T @ u_ab  # stationary -> rotor frame, eq. (24) with theta_tilde = theta_m
    i_r = current_from_flux(psi, motor)  # eq. (2)
    dpsi = flux_derivative(u_r, i_r, psi, w_m, motor.R_s)  # eq. (1)
    T_e = torque(psi, i_r, mech.pole_pairs)  # eq. (3)
    dw = (1 - stiff) * mech.pole_pairs / mech.J * (T_e - T_L - mech.B * w_m / mech.pole_pairs)
    return ca.vertcat(dpsi, w_m, dw)


class PlantOutputs(NamedTuple):
    """What the plant shows at a sampling instant."""

    i_ab: Sym  # stator current, stationary frame [A]
    i_r: Sym  # stator current, true rotor frame [A]
    T_e: Sym  # electromagnetic torque [N m]


def ipmsm_outputs(x: Sym, motor: PmsmParams, pole_pairs: Sym) -> PlantOutputs:
    """Current (2) in both frames and torque (3) at the plant state x."""
    psi, theta_m = x[0:2], x[2]
    i_r = current_from_flux(psi, motor)
    return PlantOutputs(rot(theta_m) @ i_r, i_r, torque(psi, i_r, pole_pairs))


def ipmsm_period(
    x: Sym,
    u_ab: Sym,
    T_L: Sym,
    motor: PmsmParams,
    mech: Mechanics,
    stiff: Sym,
    T_s: Sym,
    n_sub: int,
) -> Sym:
    """Plant state one sampling period later, u_ab and T_L held (zero-order hold), RK4 x n_sub.

    The angle is wrapped to (-pi, pi] at the end of the period (atan2), so that it stays accurate in
    long runs; it enters the dynamics only through sin and cos.
    """
    x_next = rk4(lambda xx: ipmsm_rates(xx, u_ab, T_L, motor, mech, stiff), x, T_s, n_sub)
    theta = ca.atan2(ca.sin(x_next[2]), ca.cos(x_next[2]))
    return ca.vertcat(x_next[0:2], theta, x_next[3])
