"""The TuningModel of one gain law of the adaptive observer: its closed loop (local gain data,
linearization, noise), equilibria and gains, and the fields every law of tuning/ipmsm_adaptive/
laws.py shares (which laws, boxes and starts: there).

The law is plugged into the analysis closed loop (design/ipmsm_adaptive/operating_point.py
``rotor_frame_loop``, its Jacobians by design/rotor_frame.py ``point_function``): the NLP
differentiates exactly the Jacobian that ``sensorless analyze`` evaluates. theta is the law's
parameter vector, plus alpha_fo (10) when ``tune_alpha_fo`` is set.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.batch import evaluate_batch
from sensorless.design.envelope import NOISE_OUTPUTS, TuningSettings
from sensorless.design.ipmsm_adaptive.derive import ALPHA_FO_MAX_FS
from sensorless.design.ipmsm_adaptive.law_settings import law_settings
from sensorless.design.ipmsm_adaptive.operating_point import rotor_frame_loop
from sensorless.design.rotor_frame import continued_equilibria, disturbance_function, point_function
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, taylor_law
from sensorless.tuning.ipmsm_adaptive.size import gain_size_function
from sensorless.tuning.model import TuningModel

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

POINT_NAMES = ("w_m", "T_e", "R_s_hat", "L_d_hat", "L_q_hat", "psi_pm_hat")
N_PHI = 6  # local gain data: lambda1, lambda2, their slopes in w_hat, w_m, alpha_fo


def _closed_loop(
    drive: IpmsmDrive, law: GainLaw, tune_alpha: bool
) -> tuple[ca.Function, ca.Function, ca.Function, ca.Function]:
    """(local, linearization, noise, lag) Functions of the law.

    local(theta, point) -> phi = [lambda1, lambda2, dlambda1/dw_hat, dlambda2/dw_hat, w_m, alpha_fo]:
    the law (16) or schedule and its slope at the point's speed, by AD of the one law expression.
    linearization(phi, x, point) -> (A, x_dot): the analysis closed loop (rotor_frame ``point_function``)
    with the law replaced by its first-order expansion at w_m, which gives the same residual and Jacobian
    at any equilibrium (w_hat = w_m there; see ``taylor_law``). noise(phi, x, point) -> (B_n, C_n, D_n):
    the input from current-measurement noise and the outputs [theta_tilde, w_hat] (the loop's
    ``disturbance``, design/rotor_frame.py ``disturbance_function``). lag(phi, x, point) -> the steady
    position error per unit of speed ramp [rad per rad/s^2], -[A^-2 B]_theta_tilde of the same linearization
    (``PoleSweep.acceleration_lag``): what the damping does not see, and the time-domain checks punish.
    Drive constants are inlined.
    """
    nth = law.n_params + int(tune_alpha)
    th = ca.SX.sym("theta", nth)
    pt = ca.SX.sym("point", len(POINT_NAMES))
    w_hat = ca.SX.sym("w_hat")
    params = ca.vertcat(th[: law.n_params], ca.SX.zeros(law.width - law.n_params))
    l1, l2 = law.expr(w_hat, params)
    dl = ca.jacobian(ca.vertcat(l1, l2), w_hat)
    alpha_fo = th[law.n_params] if tune_alpha else ca.SX(drive.observer.alpha_fo)
    at = ca.substitute(ca.vertcat(l1, l2, dl), w_hat, pt[0])
    local = ca.Function(
        f"local_{law.name}", [th, pt], [ca.vertcat(at, pt[0], alpha_fo)], ["theta", "point"], ["phi"]
    )

    inj = drive.injection
    linear, noise, lag = _loop_functions(
        tuple(drive.motor.vector()), float(drive.motor.p), (inj.w_c, inj.u_c, inj.alpha_i, inj.w_Delta)
    )
    return local, linear, noise, lag


# The law enters the closed loop only through phi (its expansion at w_m): the linearization, noise and lag
# are the drive's, one set per process for every law tuned on it (a seeded law, its seed law, their
# pointwise bound's model, the second tuning with the handover's floor). Built per model, each was a new
# Function that ran on CasADi's VM again until it had seen JIT_MIN_POINTS (design/batch.py), then
# generated its C again to find its library.
@functools.lru_cache(maxsize=8)
def _loop_functions(
    motor: tuple[float, ...], pole_pairs: float, injection: tuple[float, float, float, float]
) -> tuple[ca.Function, ca.Function, ca.Function]:
    """(linearization, noise, lag) of :func:`_closed_loop` for the motor's vector, its pole pairs and the
    injection's (w_c, u_c, alpha_i, w_Delta)."""
    pt = ca.SX.sym("point", len(POINT_NAMES))
    phi = ca.SX.sym("phi", N_PHI)
    x = ca.SX.sym("x", 4)
    loop = rotor_frame_loop(taylor_law(), False)
    ins = {
        "x_r": x,
        "w": pt[0],
        "torque": pt[1],
        "plant": ca.vertcat(ca.DM(list(motor)), pole_pairs),
        "p": ca.vertcat(pt[2:6], phi[:5], phi[5], ca.DM(list(injection))),
    }
    out = point_function(loop)(**ins)
    linear = ca.Function(
        "closed_loop_local", [phi, x, pt], [out["A"], out["f_r"]], ["phi", "x", "point"], ["A", "x_dot"]
    )
    # B = d x_dot / d w_m with the gains' expansion point (phi[4]) held: the analysis' B at an equilibrium
    ramp = ca.solve(out["A"], ca.solve(out["A"], out["B"]))
    lag = ca.Function("acceleration_lag", [phi, x, pt], [-ramp[2]], ["phi", "x", "point"], ["lag"])
    nz = disturbance_function(loop)(**ins)
    noise = ca.Function(
        "closed_loop_noise",
        [phi, x, pt],
        [ca.densify(nz["B_d"]), ca.densify(nz["C_d"]), ca.densify(nz["D_d"])],
        ["phi", "x", "point"],
        ["B_n", "C_n", "D_n"],
    )
    return linear, noise, lag


def alpha_fo_cap(drive: IpmsmDrive) -> float:
    """The upper end of a tuned alpha_fo's box [rad/s]; its lower end is the drive file's alpha_fo: never
    below it, since the speed estimate lags an acceleration by about its rate over alpha_fo, which the
    damping does not see (docs/tuning.md, "alpha_fo tuned"); at most 4x it and f_s/20 (init's own cap,
    design/ipmsm_adaptive/derive.py) where the drive file's is below that: the README servo's alpha_fo
    at 3.9x (f_s/5) ran the sampled drive unstable at 120 of 200 points, which the observer's
    linearization does not see (tune exit 3, no table)."""
    a0 = drive.observer.alpha_fo
    return max(a0, min(4.0 * a0, 2 * np.pi * ALPHA_FO_MAX_FS / drive.control.T_s))


def settled(drive: IpmsmDrive, settings: TuningSettings) -> TuningSettings:
    """``settings`` with alpha_fo not tuned where its box is one value (the drive file's alpha_fo already
    at the cap, :func:`alpha_fo_cap`: the README servo's f_s/20): a parameter that cannot move would
    only triple the global phase's and the pointwise bound's candidates (docs/tuning.md)."""
    law = law_settings(settings)
    if law.tune_alpha_fo and alpha_fo_cap(drive) <= drive.observer.alpha_fo * (1 + 1e-9):
        return dataclasses.replace(settings, law=dataclasses.replace(law, tune_alpha_fo=False))
    return settings


@functools.cache
def law_values(law: GainLaw) -> ca.Function:
    """(w_hat, params) -> (lambda1, lambda2) of a law, numerically."""
    w, p = ca.SX.sym("w_hat"), ca.SX.sym("params", law.width)
    l1, l2 = law.expr(w, p)
    return ca.Function(f"gains_{law.name}", [w, p], [l1, l2], ["w_hat", "params"], ["lambda1", "lambda2"])


def law_model(
    drive: IpmsmDrive,
    gain_law: GainLaw,
    settings: TuningSettings,
    theta0: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    typical: ArrayLike,
    **kw: Any,
) -> TuningModel:
    """The TuningModel of ``gain_law`` on ``drive`` with the box (lower, upper), baseline theta0 and
    typical magnitudes of its parameters (alpha_fo appended when tuned); ``kw``: the law's own fields
    (``law``: its name)."""
    law = gain_law
    tune_alpha = law_settings(settings).tune_alpha_fo
    a0 = drive.observer.alpha_fo
    names, units = law.param_names, law.param_units
    if tune_alpha:
        names, units = (*names, "alpha_fo"), (*units, "rad/s")
        theta0 = np.append(theta0, a0)
        lower, upper = np.append(lower, a0), np.append(upper, alpha_fo_cap(drive))
        typical = np.append(typical, a0)
    motor = np.array(drive.motor.vector())
    inj = drive.injection
    loop, plant = rotor_frame_loop(law, False), np.append(motor, float(drive.motor.p))
    inj_vector = np.array([inj.w_c, inj.u_c, inj.alpha_i, inj.w_Delta])

    def equilibrium(theta: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Equilibria (4, N); theta (n_theta,) or one per point (n_theta, N): the closed form where the
        estimates are exact at every point, else continued (design/rotor_frame.py)."""
        N = P.shape[1]
        theta = np.asarray(theta, float)
        th = theta.reshape(theta.shape[0], -1)
        gain = np.zeros((law.width, th.shape[1]))
        gain[: law.n_params] = th[: law.n_params]
        alpha = th[law.n_params : law.n_params + 1] if tune_alpha else np.array([[a0]])
        cols = [P[2:6], gain, alpha, inj_vector[:, None]]  # the loop's p (operating_point.P_NAMES)
        p = np.vstack([np.broadcast_to(c, (c.shape[0], N)) for c in cols])
        if np.all(P[2:6] == motor[:, None]):  # exact estimates: the loop's start, whatever the gains
            return evaluate_batch(loop.start, N, [P[0:1], P[1:2], plant, p])[0][:, :, 0].T
        return continued_equilibria(loop, P[0], P[1], plant, p)

    def point_gains(theta: np.ndarray, w_hat: np.ndarray) -> dict[str, np.ndarray]:
        gain = np.zeros(law.width)
        gain[: law.n_params] = theta[: law.n_params]
        f = law_values(law).map(w_hat.size)
        l1, l2 = f(w_hat[None, :], gain)
        # keyed as the gain table's points (and the CSV columns of tuning/ipmsm_adaptive/__init__.py)
        return {"lambda1": np.asarray(l1).ravel(), "lambda2": np.asarray(l2).ravel()}

    def make_points(w: np.ndarray, T: np.ndarray, est: np.ndarray) -> np.ndarray:
        w_b, T_b = np.broadcast_arrays(np.asarray(w, float), np.asarray(T, float))
        return np.vstack([w_b.ravel(), T_b.ravel(), np.repeat(np.asarray(est, float)[:, None], w_b.size, 1)])

    def pointwise_gains(theta: np.ndarray, w: np.ndarray) -> np.ndarray:
        g = point_gains(theta, np.asarray(w, float))
        cols = [g["lambda1"], g["lambda2"]]
        if tune_alpha:
            cols.append(np.full(len(cols[0]), theta[law.n_params]))
        return np.column_stack(cols)

    est = drive.estimate
    local, linear, noise, lag = _closed_loop(drive, law, tune_alpha)
    # the angle lag under acceleration no worse than the drive file's gains' at any point (docs/tuning.md,
    # "Tuned gains that run worse"); the paper's law on its own preset reproduces the paper, without it
    hold = law_settings(settings).hold_lag
    R, wb = est.R_s, drive.base.w
    return TuningModel(
        names=tuple(names),
        units=tuple(units),
        theta0=np.asarray(theta0, float),
        lower=np.asarray(lower, float),
        upper=np.asarray(upper, float),
        typical=np.asarray(typical, float),
        local=local,
        phi_typical=np.array([R, R, R / wb, R / wb, wb, a0]),
        linearization=linear,
        x_typical=np.array([est.psi_pm, est.psi_pm, 1.0, drive.base.w]),
        point_names=POINT_NAMES,
        make_points=make_points,
        equilibrium=equilibrium,
        point_gains=point_gains,
        nominal_estimate=np.array(est.vector()),
        estimate_names=("R_s", "L_d", "L_q", "psi_pm"),
        # exact estimates: x0 = [psi_s0; 0; w_m] whatever the gains (closed form)
        fixed_equilibrium=lambda P: np.all(P[2:6] == motor[:, None], axis=0),
        noise=noise,
        noise_outputs=NOISE_OUTPUTS,
        noise_units=("rad", "rad/s"),
        noise_sigma=drive.control.i_noise,
        T_s=drive.control.T_s,
        pointwise_gains=pointwise_gains,
        gain_size=gain_size_function(law, R, wb, settings.resolved.rule.hi * wb),
        gain_size_unit="R_s_hat",
        gain_size_meaning="RMS over the speed range of the gain and its slope per p.u., in R̂s",
        bounded=lag if hold else None,
        bounded_names=("the angle lag under acceleration",) if hold else (),
        **kw,
    )
