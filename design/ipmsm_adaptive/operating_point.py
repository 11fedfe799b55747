"""Operating points of the adaptive-observer drive: MTPA current for a torque, motor+observer equilibrium.

An operating point is physical: true electrical speed w_m (rad/s) and true electromagnetic torque T_e
(N m); the motor carries the MTPA current of its *true* parameters for that torque (maximum torque per
current [12], no voltage limit, as in the paper's analysis). The observer's equilibrium at that point
is where all its states are at rest. With exact estimates it is known in closed form (theta_tilde = 0,
psi_hat = psi_s0, w_i = w_m); with estimation errors it is found by Newton's method continued from that
closed form along the estimates: the coupled system is a ``RotorFrameLoop`` with a ``Continuation``
(design/rotor_frame.py, :func:`rotor_frame_loop`).
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np
from sensorless.design.memo import kept_function
from sensorless.design.rotor_frame import Continuation, Disturbance, RotorFrameLoop
from sensorless.symbolic.ipmsm_adaptive.closed_loop import N_INJ, closed_loop
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, get_law
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current

N_MOTOR = 4  # [R_s, L_d, L_q, psi_pm]
THETA_TILDE = 2  # the state's position error theta_tilde = theta_m - theta_hat [rad]


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
P_NAMES = ("estimate", "gain", "alpha_fo", "inj")  # the rotor-frame loop's ``p``, in order


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


@kept_function
def nominal_equilibrium_function(injection: bool) -> ca.Function:
    """Closed-form equilibrium for exact estimates: x0 = [psi_s0; 0; w_m (; 0)]."""
    s = analysis_symbols("zero", injection)
    motor = PmsmParams.of(s["motor"])
    psi_s0 = flux_from_current(mtpa_current(s["T_e"], motor, s["p"]), motor)  # eq. (2)
    extra = [0] if injection else []
    x0 = ca.vertcat(psi_s0, 0, s["w_m"], *extra)
    ins = ["w_m", "T_e", "motor", "p"]
    return ca.Function("nominal_equilibrium", [s[k] for k in ins], [ca.densify(x0)], ins, ["x0"])


@kept_function
def residual_function(law: str | GainLaw, injection: bool) -> ca.Function:
    """(x, w_m, T_e, motor, p, estimate, gain, alpha_fo, inj) -> x_dot of the coupled system."""
    s = analysis_symbols(law, injection)
    cl, _ = coupled_system(law, injection, s)
    names = ["x", *PARAM_NAMES]
    return ca.Function("residual", [s[k] for k in names], [cl.x_dot], names, ["x_dot"])


# kept on disk (design/memo.py): the coupled system's graph costs each process ~0.05 s per loop, and
# the Functions design/rotor_frame.py builds from a loop are kept by its content
@kept_function
def rotor_frame_loop(law: str | GainLaw, injection: bool) -> RotorFrameLoop:
    """The coupled system as a :class:`RotorFrameLoop` (design/rotor_frame.py): its state is already in
    the (estimated) rotor frame; ``plant`` = [motor, p], ``p`` = [estimate, gain, alpha_fo, inj]
    (:func:`loop_parameters`); Newton's start the closed-form equilibrium of exact estimates, continued
    along the estimates from it; its output the speed estimate w_hat, with the state-space model from
    w_m to it (G_c(s), eq. (15)) and the characteristic polynomial that design/poles.py takes the
    quartic's roots of."""
    s = analysis_symbols(law, injection)
    cl, _ = coupled_system(law, injection, s)
    plant = ca.vertcat(s["motor"], s["p"])
    p = ca.vertcat(s["estimate"], s["gain"], s["alpha_fo"], s["inj"])
    exact = ca.vertcat(s["motor"], s["gain"], s["alpha_fo"], s["inj"])  # p with exact estimates
    x0 = nominal_equilibrium_function(injection)(s["w_m"], s["T_e"], s["motor"], s["p"])
    args, names = [s["x"], s["w_m"], s["T_e"], plant, p], ["x_r", "w", "torque", "plant", "p"]
    name = f"ipmsm_adaptive_{get_law(law).name}{'_inj' if injection else ''}"
    return RotorFrameLoop(
        name,
        ca.Function(f"{name}_rates", args, [cl.x_dot], names, ["f_r"]),
        ca.Function(f"{name}_start", args[1:], [x0], names[1:], ["x_r"]),
        ca.Function(f"{name}_speed", args, [cl.w_hat], names, ["w_hat"]),
        Continuation(ca.Function(f"{name}_exact", [plant, p], [exact], ["plant", "p"], ["p0"]), THETA_TILDE),
        statespace=True,
        charpoly=True,
        disturbance=functools.partial(_current_noise, law, injection),
    )


@functools.cache
def _current_noise(law: str | GainLaw, injection: bool) -> Disturbance:
    """The current sensor's noise n (2x1, A, estimated rotor frame) added to the current the observer
    measures, judged by the position error theta_tilde and the speed estimate (design/noise.py)."""
    s = analysis_symbols(law, injection)
    n = ca.SX.sym("i_noise", 2)
    noisy, _ = coupled_system(law, injection, s, i_noise=n)
    plant = ca.vertcat(s["motor"], s["p"])
    p = ca.vertcat(s["estimate"], s["gain"], s["alpha_fo"], s["inj"])
    ins, names = [s["x"], s["w_m"], s["T_e"], plant, p, n], ["x_r", "w", "torque", "plant", "p", "d"]
    name = f"ipmsm_adaptive_{get_law(law).name}{'_inj' if injection else ''}"
    return Disturbance(
        ca.Function(f"{name}_noisy", ins, [noisy.x_dot], names, ["f_r"]),
        ca.Function(f"{name}_noise_out", ins, [ca.vertcat(s["x"][2], noisy.w_hat)], names, ["z"]),
    )


def loop_parameters(args: dict[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    """(plant, p) of :func:`rotor_frame_loop` at ``n`` points from the analysis inputs ``args`` (named
    as PARAM_NAMES; each one instance or one column per point, as evaluate_batch takes them): one
    vector where every input is one, else one column per point."""
    a = {k: np.asarray(args[k], float) for k in ("motor", "p", *P_NAMES)}
    if all(v.ndim < 2 or v.shape[1] == 1 for v in a.values()):
        v = {k: x.ravel() for k, x in a.items()}
        return np.concatenate([v["motor"], v["p"]]), np.concatenate([v[k] for k in P_NAMES])
    c = {
        k: x if x.ndim == 2 and x.shape[1] == n else np.broadcast_to(x.reshape(-1, 1), (x.size, n))
        for k, x in a.items()
    }
    return np.vstack([c["motor"], c["p"]]), np.vstack([c[k] for k in P_NAMES])
