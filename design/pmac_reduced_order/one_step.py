"""The sampled reduced-order observer fed by the motor, in rotor coordinates: what the shared discrete-time
analysis (design/discrete.py) needs from this family, and the Floquet extension on top of it.

The step that runs (the runtime observer of symbolic/pmac_reduced_order/step.py, as generated) takes the
motor from angle theta to theta + w T_s; the motor's current and voltage are sampled from the
continuous signals of the operating point (the paper measures the voltage; nothing is held). In rotor
coordinates y = [R(-theta) zeta, tau, theta_hat - theta, w_hat] (:func:`sampled_loop`) its one-step map
and Jacobian are the shared ones. With a sinusoidal EMF the map does not depend on theta; with EMF
harmonics it is periodic in theta and the observer runs on a periodic orbit, not at a fixed point: the
Floquet multipliers are eigenvalues of the product of the one-step Jacobians along the simulated orbit
over whole periods (:func:`angle_period`, :func:`period_steps`, :func:`ordered_product`; used by
linearize.analyze).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.discrete import SampledLoop
from sensorless.design.pmac_reduced_order.operating_point import motor_names, plant_signals
from sensorless.symbolic.frames import rot, wrap_angle
from sensorless.symbolic.pmac_reduced_order.step import runtime_observer, split_params

_N = {"zeta": slice(0, 2), "tau": 2, "theta": 3, "w_hat": 4, "i": slice(5, 7), "u": slice(7, 9)}


def coordinate_names(load_estimation: bool) -> tuple[str, ...]:
    """Names of the rotor coordinates y (tau left out without load estimation)."""
    return ("zeta_d", "zeta_q", *(["tau"] if load_estimation else []), "theta_err_hat", "w_hat")


@functools.cache
def sampled_loop(
    method: str, orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool = True
) -> SampledLoop:
    """The runtime step of scheme ``method`` on the motor at an operating point (plant = [T_L, motor])."""
    obs = runtime_observer(tuple(orders_o))

    def signals(theta: Any, w: Any, plant: Any) -> Any:
        s = {"w": w, "T_L": plant[0], "motor": plant[1:]}
        return plant_signals(s, theta, orders_m)[0]

    def sample(theta: Any, w: Any, plant: Any, p: Any) -> Any:
        # the samples at the end of the period [t_(k-1), t_k] the step integrates over
        sig = signals(theta + w * split_params(p, orders_o)[2], w, plant)
        return ca.vertcat(sig.i, sig.v)

    def state(y: Any, theta: Any, w: Any, plant: Any, p: Any) -> Any:
        # the stored previous samples are the motor's at theta
        sig = signals(theta, w, plant)
        ny = len(y.nz)
        tau = y[2] if load_estimation else 0
        return ca.vertcat(rot(theta) @ y[0:2], tau, y[ny - 2] + theta, y[ny - 1], sig.i, sig.v)

    def rotor(x: Any, theta: Any) -> Any:
        return ca.vertcat(
            rot(theta).T @ x[_N["zeta"]],
            *([x[_N["tau"]]] if load_estimation else []),
            wrap_angle(x[_N["theta"]] - theta),
            x[_N["w_hat"]],
        )

    names = coordinate_names(load_estimation)
    return SampledLoop(
        obs, method, None, names, 1 + len(motor_names(orders_m)), sample, state, rotor, (len(names) - 2,)
    )


@functools.cache
def torque_function(orders_m: tuple[int, ...]) -> ca.Function:
    """(w, T_L, motor) -> T_e = T_L + B omega: the motor's torque at an operating point."""
    n_motor = len(motor_names(orders_m))
    s = {"w": ca.SX.sym("w"), "T_L": ca.SX.sym("T_L"), "motor": ca.SX.sym("motor", n_motor)}
    T_e = plant_signals(s, 0, orders_m)[1]
    return ca.Function("pmac_torque", list(s.values()), [T_e], list(s), ["T_e"])


def angle_period(orders_m: tuple[int, ...], orders_o: tuple[int, ...]) -> float:
    """Period in theta of the rotor-frame dynamics: 2 pi / gcd(|n - 1|) over all harmonics (inf if none)."""
    g = 0
    for n in (*orders_m, *orders_o):
        g = math.gcd(g, abs(n - 1))
    return 2 * math.pi / g if g else math.inf


def ordered_product(mats: np.ndarray) -> np.ndarray:
    """mats[..., M-1, :, :] @ ... @ mats[..., 0, :, :] (later factors left), in log2(M) batched steps."""
    while mats.shape[-3] > 1:
        if mats.shape[-3] % 2:
            eye = np.broadcast_to(np.eye(mats.shape[-1]), (*mats.shape[:-3], 1, *mats.shape[-2:]))
            mats = np.concatenate([mats, eye], axis=-3)
        mats = mats[..., 1::2, :, :] @ mats[..., 0::2, :, :]
    return mats[..., 0, :, :]


def period_steps(period: float, w: np.ndarray, T_s: float, cap: int = 4000, tol: float = 0.005) -> np.ndarray:
    """Steps M per point that cover a whole number of rotor-frame periods as closely as possible.

    The angle advances |w| T_s per step; M = round(q P / (|w| T_s)) for the smallest q whose rounding
    error is below ``tol`` of M (else the best q with M <= cap). 1 for a sinusoidal EMF (P = inf).
    """
    if math.isinf(period):
        return np.ones(w.size, int)
    r = period / (np.abs(w) * T_s)  # steps per period (real)
    out = np.empty(w.size, int)
    for k, rk in enumerate(r):  # a few points; each a short scalar search
        best, best_err = max(1, round(rk)), math.inf
        q = 1
        while q * rk <= cap or q == 1:
            m = max(1, round(q * rk))
            err = abs(m - q * rk) / m
            if err < best_err:
                best, best_err = m, err
            if err < tol:
                break
            q += 1
        out[k] = min(best, cap)
    return out
