"""Operating points of the paper-000 drive: MTPA current for a torque, and the motor+observer equilibrium.

An operating point is physical: true electrical speed w_m (rad/s) and true electromagnetic torque T_e
(N m); the motor carries the MTPA current of its *true* parameters for that torque (maximum torque per
current [12], no voltage limit, as in the paper's analysis). The observer's equilibrium at that point
is where all its states are at rest. With exact estimates it is known in closed form (theta_tilde = 0,
psi_hat = psi_s0, w_i = w_m); with estimation errors it is found by Newton's method (casadi
rootfinder) started from that closed form.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np
from sensorless.symbolic.closed_loop import N_INJ, closed_loop
from sensorless.symbolic.gains import GainLaw, get_law
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current

N_MOTOR = 4  # [R_s, L_d, L_q, psi_pm]


class EquilibriumError(RuntimeError):
    """No motor+observer equilibrium was found at an operating point."""


def analysis_symbols(law: str | GainLaw, injection: bool) -> dict[str, ca.SX]:
    """Named SX inputs shared by every analysis Function of the coupled system."""
    n = 5 if injection else 4
    return {
        "x": ca.SX.sym("x", n),
        "w_m": ca.SX.sym("w_m"),
        "T_e": ca.SX.sym("T_e"),
        "motor": ca.SX.sym("motor", N_MOTOR),
        "p": ca.SX.sym("p"),
        "estimate": ca.SX.sym("estimate", N_MOTOR),
        "gain": ca.SX.sym("gain", get_law(law).width),
        "alpha_fo": ca.SX.sym("alpha_fo"),
        "inj": ca.SX.sym("inj", N_INJ),
    }


PARAM_NAMES = ("w_m", "T_e", "motor", "p", "estimate", "gain", "alpha_fo", "inj")


def coupled_system(law: str | GainLaw, injection: bool, s: dict[str, ca.SX], w_hat_override=None):
    """The coupled system of symbolic/closed_loop.py at the MTPA current of (w_m, T_e)."""
    motor = PmsmParams.of(s["motor"])
    i_s0 = mtpa_current(s["T_e"], motor, s["p"])
    return closed_loop(
        s["x"],
        s["w_m"],
        i_s0,
        motor,
        PmsmParams.of(s["estimate"]),
        s["alpha_fo"],
        get_law(law),
        s["gain"],
        s["inj"] if injection else None,
        w_hat_override,
    ), i_s0


@functools.cache
def mtpa_function() -> ca.Function:
    """Function mtpa(T_e [N m], motor [4], p) -> i_s0 [A] (rotor frame, [i_d, i_q])."""
    T_e, motor, p = ca.SX.sym("T_e"), ca.SX.sym("motor", N_MOTOR), ca.SX.sym("p")
    i_s0 = mtpa_current(T_e, PmsmParams.of(motor), p)
    return ca.Function("mtpa", [T_e, motor, p], [i_s0], ["T_e", "motor", "p"], ["i_s0"])


@functools.cache
def nominal_equilibrium_function(injection: bool) -> ca.Function:
    """Closed-form equilibrium for exact estimates: x0 = [psi_s0; 0; w_m (; 0)]."""
    s = analysis_symbols("zero", injection)
    motor = PmsmParams.of(s["motor"])
    psi_s0 = flux_from_current(mtpa_current(s["T_e"], motor, s["p"]), motor)  # eq. (2)
    extra = [0] if injection else []
    x0 = ca.vertcat(psi_s0, 0, s["w_m"], *extra)
    ins = ["w_m", "T_e", "motor", "p"]
    return ca.Function("nominal_equilibrium", [s[k] for k in ins], [ca.densify(x0)], ins, ["x0"])


@functools.cache
def residual_function(law: str | GainLaw, injection: bool) -> ca.Function:
    """(x, w_m, T_e, motor, p, estimate, gain, alpha_fo, inj) -> x_dot of the coupled system."""
    s = analysis_symbols(law, injection)
    cl, _ = coupled_system(law, injection, s)
    names = ["x", *PARAM_NAMES]
    return ca.Function("residual", [s[k] for k in names], [cl.x_dot], names, ["x_dot"])


@functools.cache
def equilibrium_function(law: str | GainLaw, injection: bool) -> ca.Function:
    """Rootfinder: (x_guess, w_m, T_e, motor, p, estimate, gain, alpha_fo, inj) -> x0 at rest."""
    return ca.rootfinder(
        "equilibrium",
        "newton",
        residual_function(law, injection),
        {"abstol": 1e-12, "max_iter": 50, "error_on_fail": False},
    )


def solve_equilibrium(
    law: str | GainLaw,
    injection: bool,
    args: dict[str, np.ndarray],
    n: int,
    exact: bool,
) -> np.ndarray:
    """Equilibria for ``n`` operating points as an (n_x, n) array; NaN columns where none exists."""
    nominal = nominal_equilibrium_function(injection).map(n)
    x_nom = np.asarray(nominal(args["w_m"], args["T_e"], args["motor"], args["p"]))
    if exact:
        return x_nom
    root = equilibrium_function(law, injection).map(n)
    x0 = np.asarray(root(x_nom, *[args[k] for k in PARAM_NAMES]))
    # The rootfinder does not raise on failure (error_on_fail=False): verify the residual here.
    res = np.asarray(residual_function(law, injection).map(n)(x0, *[args[k] for k in PARAM_NAMES]))
    # x_dot is in V (flux rates) and rad/s^2; 1e-6 of the operating point's size is "at rest"
    scale = 1.0 + np.abs(np.asarray(args["w_m"])).ravel() + np.abs(x_nom).max(axis=0)
    bad = ~np.isfinite(res).all(axis=0) | (np.abs(res).max(axis=0) > 1e-6 * scale)
    x0[:, bad] = np.nan
    return x0
