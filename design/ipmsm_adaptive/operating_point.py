"""Operating points of the adaptive-observer drive: MTPA current for a torque, motor+observer equilibrium.

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
from sensorless.design.batch import evaluate_batch, mapped
from sensorless.design.compiled import compiled
from sensorless.symbolic.ipmsm_adaptive.closed_loop import N_INJ, closed_loop
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, get_law
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current

N_MOTOR = 4  # [R_s, L_d, L_q, psi_pm]


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


def coupled_system(
    law: str | GainLaw, injection: bool, s: dict[str, ca.SX], w_hat_override=None, i_noise=None
):
    """The coupled system of symbolic/ipmsm_adaptive/closed_loop.py at the MTPA current of (w_m, T_e);
    ``i_noise`` (2x1) is the current-measurement noise added to what the observer measures."""
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
        i_noise,
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
    f = residual_function(law, injection)
    # Newton's steps evaluate the Jacobian the rootfinder would generate itself, compiled (cached on
    # disk, design/compiled.py): the same operations as on CasADi's VM, so the same bits, ~3x faster.
    jac = compiled(f.factory("jac_f_z", f.name_in(), ["jac:x_dot:x", "x_dot"]))
    return ca.rootfinder(
        "equilibrium",
        "newton",
        f,
        # plain Newton: its backtracking line search stalls on this badly scaled system (rows in V and
        # rad/s^2); continuation in solve_equilibrium keeps the starting points close instead
        {
            "abstol": 1e-12,
            "max_iter": 30,
            "error_on_fail": False,
            "line_search": False,
            "show_eval_warnings": False,
            "jacobian_function": jac,
        },
    )


def _columns(fn: ca.Function, args: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """``args`` (one instance or one column per point, as evaluate_batch takes them) as (rows, n) views."""
    out = {}
    for k in PARAM_NAMES:
        rows = fn.size1_in(fn.index_in(k))
        a = np.asarray(args[k], float)
        out[k] = np.broadcast_to(a.reshape(rows, 1), (rows, n)) if a.size == rows else a.reshape(rows, n)
    return out


def solve_equilibrium(
    law: str | GainLaw,
    injection: bool,
    args: dict[str, np.ndarray],
    n: int,
    exact: bool,
    max_rounds: int = 60,
) -> np.ndarray:
    """Equilibria for ``n`` operating points as an (n_x, n) array; NaN columns where none is found.

    With estimation errors, Newton's method is continued along the estimates
    est(tau) = true + tau (est - true) from tau = 0 (exact estimates, closed-form equilibrium with
    theta_tilde = 0) to tau = 1, each point with its own adaptive step (halved after a failed Newton
    solve, enlarged after a success), the points still under way advanced together in one mapped call
    per round (most points finish in three rounds, a few near a fold take dozens). This follows the
    equilibrium branch that starts at the exact-estimate equilibrium; a single Newton solve from
    theta_tilde = 0 misses it once the position error grows to tenths of a radian. Where the branch
    ends (a fold: the observer cannot hold the rotor position) the point is NaN.
    """
    ins = [np.asarray(args[k], float) for k in ("w_m", "T_e", "motor", "p")]
    x = np.ascontiguousarray(evaluate_batch(nominal_equilibrium_function(injection), n, ins)[0][:, :, 0].T)
    if exact:
        return x
    root, residual = equilibrium_function(law, injection), residual_function(law, injection)
    cols = _columns(residual, args, n)
    true = np.broadcast_to(np.asarray(args["motor"], float).reshape(4, -1), (4, n))
    est = cols["estimate"]
    scale = 1.0 + np.abs(cols["w_m"][0]) + np.abs(x).max(axis=0)
    tau = np.zeros(n)
    h = np.full(n, 0.25)
    lost = np.zeros(n, bool)
    for _ in range(max_rounds):
        act = np.flatnonzero((tau < 1) & ~lost)  # not the points done: the late rounds are a few points
        if act.size == 0:
            break
        t_try = np.minimum(1.0, tau[act] + h[act])
        a = {k: v[:, act] for k, v in cols.items()}
        a["estimate"] = true[:, act] + t_try * (est[:, act] - true[:, act])
        ins = [a[k] for k in PARAM_NAMES]
        x_try = np.asarray(mapped(root, act.size)(x[:, act], *ins))
        # The rootfinder does not raise on failure (error_on_fail=False): verify the residual.
        res = evaluate_batch(residual, act.size, [x_try, *ins])[0][:, :, 0]
        # x_dot is in V (flux rates) and rad/s^2; 1e-6 of the operating point's size is "at rest"
        ok = np.isfinite(res).all(axis=1) & (np.abs(res).max(axis=1) <= 1e-6 * scale[act])
        # a solve that jumps far in position is another branch, not a continuation step
        ok &= np.abs(x_try[2] - x[2, act]) < 0.3
        x[:, act[ok]] = x_try[:, ok]
        tau[act[ok]] = t_try[ok]
        h[act] = np.where(ok, np.minimum(2 * h[act], 0.5), h[act] / 2)
        lost[act] |= ~ok & (h[act] < 1e-3)
    x[:, lost | (tau < 1)] = np.nan
    return x
