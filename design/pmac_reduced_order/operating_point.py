"""Operating points of the reduced-order observer's analysis: the motor at constant speed and load, and
the observer state that agrees with it exactly (De Angelo et al. 2006).

An operating point is an electrical speed w and a load torque T_L: the motor turns at w carrying the
ripple-free current (25) of T_e = T_L + B omega, with the voltage (2) that holds it. The analysis
Functions of linearize.py share the named inputs of :func:`symbols`; one_step.py samples the same signals.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.memo import kept_function
from sensorless.symbolic.pmac import EmfSeries, PmacParams, flux_derivative, operating_point_signals
from sensorless.symbolic.pmac_reduced_order.observer import (
    zeta_tau,
)
from sensorless.symbolic.pmac_reduced_order.step import param_names, split_params

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

INPUT_NAMES = ("theta", "w", "T_L", "motor", "params")


def motor_names(orders: tuple[int, ...]) -> tuple[str, ...]:
    """Entries of the ``motor`` input: R, L, J, B, p_r, Phi_n of each order."""
    return ("R", "L", "J", "B", "p_r", *(f"Phi_{n}" for n in orders))


def split_motor(motor: Any, orders: tuple[int, ...]) -> tuple[PmacParams, EmfSeries]:
    """(motor parameters, EMF series) from the ``motor`` vector."""
    return PmacParams(motor[0], motor[1], motor[2], motor[3], motor[4]), EmfSeries(orders, motor[5:])


def symbols(orders_m: tuple[int, ...], orders_o: tuple[int, ...]) -> dict[str, ca.SX]:
    """Named inputs shared by the analysis Functions."""
    return {
        "theta": ca.SX.sym("theta"),  # electrical rotor angle [rad]
        "w": ca.SX.sym("w"),  # electrical speed [rad/s]
        "T_L": ca.SX.sym("T_L"),  # load torque [N m] (viscosity added by the model)
        "motor": ca.SX.sym("motor", len(motor_names(orders_m))),
        "params": ca.SX.sym("params", len(param_names(orders_o))),
    }


def plant_signals(s: dict[str, ca.SX], theta: Any, orders_m: tuple[int, ...]):
    mp, emf_m = split_motor(s["motor"], orders_m)
    sig, T_e = operating_point_signals(theta, s["w"], s["T_L"], mp, emf_m)
    return sig, T_e


def no_load_estimation(params: ca.SX) -> ca.SX:
    """The params with Gamma = 0: the observer without load-torque estimation ([11])."""
    return ca.vertcat(params[0:5], 0, params[6:])


def exact_state(
    s: dict[str, ca.SX],
    orders_m: tuple[int, ...],
    orders_o: tuple[int, ...],
    load_estimation: bool,
    theta: Any = None,
) -> ca.SX:
    """Observer state x (9) that agrees exactly with the motor at angle theta (the continuous orbit)."""
    theta = s["theta"] if theta is None else theta
    params = s["params"] if load_estimation else no_load_estimation(s["params"])
    p, emf_o, _ = split_params(params, orders_o)
    sig, T_e = plant_signals(s, theta, orders_m)
    T_L_hat = T_e if load_estimation else 0  # T_L + B omega, or nothing without estimation
    zeta, tau = zeta_tau(sig.e, T_L_hat, flux_derivative(theta, emf_o), sig.i, p)  # eq. (15)
    return ca.vertcat(zeta, tau, theta, s["w"], sig.i, sig.v)


@kept_function
def exact_state_function(
    orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool
) -> ca.Function:
    """(theta, w, T_L, motor, params) -> x: the observer state that matches the motor exactly."""
    s = symbols(orders_m, orders_o)
    x = exact_state(s, orders_m, orders_o, load_estimation)
    return ca.Function("exact_state", list(s.values()), [x], list(INPUT_NAMES), ["x"])


def analysis_arguments(
    drive: PmacDrive, T_s: float | None = None, g: float | None = None, Gamma: float | None = None
) -> tuple[tuple[int, ...], tuple[int, ...], np.ndarray, np.ndarray]:
    """(orders_m, orders_o, motor vector, params vector) of a drive of this family."""
    return (
        tuple(drive.motor.harmonics),
        tuple(drive.estimate.harmonics),
        drive.motor.vector(),
        drive.observer_params(g=g, Gamma=Gamma, T_s=T_s),
    )
