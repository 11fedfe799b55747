"""Tunable gain families of the adaptive observer: law (16) and the free speed schedule.

Both are gain laws of symbolic/ipmsm_adaptive/gains.py plugged into the analysis closed loop of
design/ipmsm_adaptive/linearize.py (``linearization_function``): the NLP differentiates exactly the
Jacobian that ``sensorless analyze`` evaluates. theta is the law's parameter vector, plus alpha_fo (10) when
``tune_alpha_fo`` is set.

- law16: theta = [lambda' (ohm), omega_lambda (rad/s)], eq. (16) of Piippo, Hinkkanen, Luomi (2008).
  Baseline: the drive's ``[observer.gains.speed]`` (the paper's Fig. 4(c): lambda' = 2 R̂s,
  omega_lambda = 1 p.u.).
- schedule: theta = [lambda1 at each breakpoint..., lambda2 at each breakpoint...] (ohm), linear in
  the speed estimate between breakpoints, held beyond the ends (``schedule_law``). Breakpoints: zero,
  ``breakpoints`` speeds per direction from speed_min to speed_max, and the kinks +-omega_lambda of
  the drive file's law (16) and of the tuned law16 (its seed) inside the envelope. Eq. (16) is
  piecewise linear with kinks only at 0 and +-omega_lambda, so on these breakpoints the schedule reproduces
  both laws *exactly* over the envelope: its baseline is the drive file's gains sampled at the
  breakpoints, its NLP start the tuned law16 sampled there, and the tuner can only improve on law16.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.envelope import NOISE_OUTPUTS, TuningSettings
from sensorless.design.ipmsm_adaptive.linearize import linearization_function, noise_function
from sensorless.design.ipmsm_adaptive.operating_point import solve_equilibrium
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, get_law, schedule_law, taylor_law
from sensorless.tuning.ipmsm_adaptive.size import gain_size_function
from sensorless.tuning.model import TuningModel

POINT_NAMES = ("w_m", "T_e", "R_s_hat", "L_d_hat", "L_q_hat", "psi_pm_hat")
N_PHI = 6  # local gain data: lambda1, lambda2, their slopes in w_hat, w_m, alpha_fo
GAIN_BOX = 20.0  # default search box |lambda| <= 20 R̂s when no lambda_max is given
LAMBDA1_MIN = -0.9  # lambda1 > -R̂s (Section IV-B): the box keeps lambda1 >= -0.9 R̂s


def _closed_loop(drive: Any, law: GainLaw, tune_alpha: bool) -> tuple[ca.Function, ca.Function, ca.Function]:
    """(local, linearization, noise) Functions of the family.

    local(theta, point) -> phi = [lambda1, lambda2, dlambda1/dw_hat, dlambda2/dw_hat, w_m, alpha_fo]:
    the law (16) or schedule and its slope at the point's speed, by AD of the one law expression.
    linearization(phi, x, point) -> (A, x_dot): the analysis closed loop (ipmsm_adaptive/linearize.py)
    with the law replaced by its first-order expansion at w_m, which gives the same residual and Jacobian
    at any equilibrium (w_hat = w_m there; see ``taylor_law``). noise(phi, x, point) -> (B_n, C_n, D_n):
    the input from current-measurement noise and the outputs [theta_tilde, w_hat]
    (design/ipmsm_adaptive/linearize.py ``noise_function``). Drive constants are inlined.
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

    lin = linearization_function(taylor_law(), False)
    phi = ca.SX.sym("phi", N_PHI)
    x = ca.SX.sym("x", 4)
    inj = drive.injection
    args = {
        "x": x,
        "w_m": pt[0],
        "T_e": pt[1],
        "motor": ca.DM(drive.motor.vector()),
        "p": float(drive.motor.p),
        "estimate": pt[2:6],
        "gain": phi[:5],
        "alpha_fo": phi[5],
        "inj": ca.DM([inj.w_c, inj.u_c, inj.alpha_i, inj.w_Delta]),
    }
    out = lin(**args)
    linear = ca.Function(
        "closed_loop_local", [phi, x, pt], [out["A"], out["x_dot"]], ["phi", "x", "point"], ["A", "x_dot"]
    )
    nz = noise_function(taylor_law(), False)(**args)
    noise = ca.Function(
        "closed_loop_noise",
        [phi, x, pt],
        [ca.densify(nz["B_n"]), ca.densify(nz["C_n"]), ca.densify(nz["D_n"])],
        ["phi", "x", "point"],
        ["B_n", "C_n", "D_n"],
    )
    return local, linear, noise


@functools.cache
def _law_values(law: GainLaw) -> ca.Function:
    """(w_hat, params) -> (lambda1, lambda2) of a law, numerically."""
    w, p = ca.SX.sym("w_hat"), ca.SX.sym("params", law.width)
    l1, l2 = law.expr(w, p)
    return ca.Function(f"gains_{law.name}", [w, p], [l1, l2], ["w_hat", "params"], ["lambda1", "lambda2"])


def _common(drive: Any, law: GainLaw, settings: TuningSettings, theta0, lower, upper, typical, **kw):
    """Fields shared by both families."""
    tune_alpha = settings.tune_alpha_fo
    a0 = drive.observer.alpha_fo
    names, units = law.param_names, law.param_units
    if tune_alpha:
        names, units = (*names, "alpha_fo"), (*units, "rad/s")
        theta0 = np.append(theta0, a0)
        lower, upper = np.append(lower, 0.2 * a0), np.append(upper, 4.0 * a0)
        typical = np.append(typical, a0)
    motor = np.array(drive.motor.vector())
    inj = drive.injection

    def equilibrium(theta: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Equilibria (4, N); theta (n_theta,) or one per point (n_theta, N)."""
        N = P.shape[1]
        exact = bool(np.all(P[2:6] == motor[:, None]))
        if exact:  # closed form, independent of the gains
            return solve_equilibrium(
                law,
                False,
                {"w_m": P[0:1], "T_e": P[1:2], "motor": motor, "p": np.array(float(drive.motor.p))},
                N,
                True,
            )
        theta = np.asarray(theta, float)
        th = theta.reshape(theta.shape[0], -1)
        gain = np.zeros((law.width, th.shape[1]))
        gain[: law.n_params] = th[: law.n_params]
        args = {
            "w_m": P[0:1],
            "T_e": P[1:2],
            "motor": motor,
            "p": np.array(float(drive.motor.p)),
            "estimate": P[2:6],
            "gain": gain,
            "alpha_fo": th[law.n_params : law.n_params + 1] if tune_alpha else np.array(a0),
            "inj": np.array([inj.w_c, inj.u_c, inj.alpha_i, inj.w_Delta]),
        }
        return solve_equilibrium(law, False, args, N, False)

    def point_gains(theta: np.ndarray, w_hat: np.ndarray) -> dict[str, np.ndarray]:
        gain = np.zeros(law.width)
        gain[: law.n_params] = theta[: law.n_params]
        f = _law_values(law).map(w_hat.size)
        l1, l2 = f(w_hat[None, :], gain)
        return {"lambda1_ohm": np.asarray(l1).ravel(), "lambda2_ohm": np.asarray(l2).ravel()}

    def make_points(w: np.ndarray, T: np.ndarray, est: np.ndarray) -> np.ndarray:
        w_b, T_b = np.broadcast_arrays(np.asarray(w, float), np.asarray(T, float))
        return np.vstack([w_b.ravel(), T_b.ravel(), np.repeat(np.asarray(est, float)[:, None], w_b.size, 1)])

    def pointwise_gains(theta: np.ndarray, w: np.ndarray) -> np.ndarray:
        g = point_gains(theta, np.asarray(w, float))
        cols = [g["lambda1_ohm"], g["lambda2_ohm"]]
        if tune_alpha:
            cols.append(np.full(len(cols[0]), theta[law.n_params]))
        return np.column_stack(cols)

    est = drive.estimate
    local, linear, noise = _closed_loop(drive, law, tune_alpha)
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
        pointwise=lambda: build_pointwise(drive, settings),
        pointwise_gains=pointwise_gains,
        gain_size=gain_size_function(law, R, wb, settings.envelope.speed_max * wb),
        **kw,
    )


def _alpha_reg(th: ca.SX, law: GainLaw, settings: TuningSettings, a0: float) -> ca.SX:
    """Keep a tuned alpha_fo near the drive's value unless damping needs otherwise."""
    return (th[law.n_params] / a0 - 1) ** 2 if settings.tune_alpha_fo else 0


def build_law16(drive: Any, settings: TuningSettings, seed: np.ndarray | None = None) -> TuningModel:
    """Family law16: eq. (16) with lambda' and omega_lambda free."""
    law = get_law("speed")
    R = drive.estimate.R_s
    wb = drive.base.w
    g = drive.gain("speed")
    lam_max = settings.lambda_max if settings.lambda_max is not None else GAIN_BOX * R
    a0 = drive.observer.alpha_fo

    def table_gains(theta: np.ndarray) -> dict[str, Any]:
        return {
            "lambda_p": float(theta[0]),
            "w_lambda": float(theta[1]),
            "alpha_fo": float(theta[2] if settings.tune_alpha_fo else a0),
        }

    def starts() -> np.ndarray:
        """Global phase: a log grid of lambda' (0.25 R̂s .. the bound) x omega_lambda (0.02 .. 5 p.u.)."""
        lp = np.geomspace(0.25 * R, lam_max, 10)
        wl = np.geomspace(0.02 * wb, 5.0 * wb, 10)
        L, Wl = np.meshgrid(lp, wl)
        out = np.column_stack([L.ravel(), Wl.ravel()])
        return with_alpha_fo_starts(out, settings, a0)

    return _common(
        drive,
        law,
        settings,
        theta0=[g.lambda_p, g.w_lambda],
        lower=[0.0, 0.01 * wb],
        upper=[lam_max, 10.0 * wb],
        typical=[R, wb],
        family="law16",
        # no regularizer: the optimum is a ridge (lambda' |w|/omega_lambda fixed at the binding
        # speed) and any point on it is as good; the NLP is deterministic for given inputs
        regularizer=None,
        table_gains=table_gains,
        # exact Hessian: with the equilibria as data (exact estimates) the slots' second derivatives
        # are cheap, and IPOPT needs fewer iterations than with L-BFGS (benchmarks/bench_tune.py);
        # 8 points in the first round: the binding ones of the default envelope in one round
        hessian="exact",
        n_initial_active=8,
        starts=starts,
    )


def schedule_breakpoints(
    drive: Any, settings: TuningSettings, kinks: tuple[float, ...] = ()
) -> tuple[float, ...]:
    """Breakpoints [rad/s]: zero, ``breakpoints`` speeds per direction over the envelope, and +-each
    of ``kinks`` [rad/s] that lies inside the envelope and not within 1e-3 p.u. of another."""
    e = settings.envelope
    wb = drive.base.w
    mag = list(np.linspace(e.speed_min, e.speed_max, settings.breakpoints) * wb)
    for k in kinks:
        k = abs(float(k))
        if e.speed_min * wb < k < e.speed_max * wb and min(abs(k - m) for m in mag) > 1e-3 * wb:
            mag.append(k)
    mag = np.sort(mag)
    return tuple(float(v) for v in np.concatenate([-mag[::-1], [0.0], mag]))


def _law16_at(grid: tuple[float, ...], params: np.ndarray) -> np.ndarray:
    """eq. (16) with params [lambda', omega_lambda] sampled at the breakpoints: [lambda1..., lambda2...]."""
    l1, l2 = _law_values(get_law("speed")).map(len(grid))(np.array(grid)[None, :], params[:2])
    return np.concatenate([np.asarray(l1).ravel(), np.asarray(l2).ravel()])


def build_schedule(drive: Any, settings: TuningSettings, seed: np.ndarray | None = None) -> TuningModel:
    """Family schedule: free (lambda1, lambda2) at each breakpoint, linear in between; started from
    ``seed``, the tuned law16 parameters (lambda', omega_lambda[, alpha_fo]), when given."""
    g = drive.gain("speed")
    baseline = np.array([g.lambda_p, g.w_lambda])
    grid = schedule_breakpoints(drive, settings, (g.w_lambda, *(() if seed is None else (seed[1],))))
    law = schedule_law(grid)
    K = len(grid)
    R = drive.estimate.R_s
    a0 = drive.observer.alpha_fo
    lam_max = settings.lambda_max if settings.lambda_max is not None else GAIN_BOX * R
    theta0 = _law16_at(grid, baseline)
    lower = np.concatenate([np.full(K, max(LAMBDA1_MIN * R, -lam_max)), np.full(K, -lam_max)])
    upper = np.full(2 * K, lam_max)
    w = np.array(grid)
    h = np.diff(w)
    h_mean = float(h.mean())

    def regularizer(th: ca.SX) -> ca.SX:
        # roughness: squared change of slope between neighbouring intervals (zero for a straight
        # line, as (16) is below omega_lambda), plus a small pull towards small gains
        total = 0
        for part in (th[:K], th[K : 2 * K]):
            slope = [(part[k + 1] - part[k]) / h[k] for k in range(K - 1)]
            total += sum(((slope[k + 1] - slope[k]) * h_mean / R) ** 2 for k in range(K - 2))
            total += 0.01 * sum((part[k] / R) ** 2 for k in range(K)) / K
        return total + _alpha_reg(th, law, settings, a0)

    def table_gains(theta: np.ndarray) -> dict[str, Any]:
        return {
            "w_hat": list(grid),
            "lambda1": [float(v) for v in theta[:K]],
            "lambda2": [float(v) for v in theta[K : 2 * K]],
            "alpha_fo": float(theta[2 * K] if settings.tune_alpha_fo else a0),
        }

    start = None
    if seed is not None:
        start = _law16_at(grid, np.asarray(seed, float))
        if settings.tune_alpha_fo:
            start = np.append(start, seed[2])

    def from_pointwise(speeds: np.ndarray, optima: np.ndarray) -> np.ndarray:
        """The pointwise optima (per speed: lambda1, lambda2[, alpha_fo]) sampled at the breakpoints
        (linear between speeds, held beyond; zero speed: the mean of the two directions' nearest)."""
        out = [_sample(speeds, optima[:, c], w) for c in range(2)]
        th = np.concatenate(out)
        if settings.tune_alpha_fo:
            th = np.append(th, float(np.median(optima[:, 2])) if optima.shape[1] > 2 else a0)
        return th

    return _common(
        drive,
        law,
        settings,
        theta0=theta0,
        lower=lower,
        upper=upper,
        typical=np.full(2 * K, R),
        family="schedule",
        regularizer=regularizer,
        table_gains=table_gains,
        start=start,
        start_label="law16 optimum" if seed is not None else "",
        from_pointwise=from_pointwise,
        n_initial_active=16,
    )


def _running_median(speeds: np.ndarray, v: np.ndarray, k: int = 5) -> np.ndarray:
    """Running median over k neighbours within each direction (speeds of one sign)."""
    out = v.copy()
    for sign in (-1, 1):
        idx = np.flatnonzero(np.sign(speeds) == sign)
        for j, i in enumerate(idx):
            lo, hi = max(0, j - k // 2), min(idx.size, j + k // 2 + 1)
            out[i] = np.median(v[idx[lo:hi]])
    return out


def _sample(speeds: np.ndarray, v: np.ndarray, at: np.ndarray) -> np.ndarray:
    """v(speeds) at the breakpoints ``at``: linear within each direction, held beyond its ends; at zero
    (between the directions) the mean of the nearest values of both."""
    out = np.empty(at.size)
    neg, pos = speeds < 0, speeds > 0
    for i, x in enumerate(at):
        if x < 0 and neg.any():
            out[i] = np.interp(x, speeds[neg], v[neg])
        elif x > 0 and pos.any():
            out[i] = np.interp(x, speeds[pos], v[pos])
        else:
            near = [v[m][np.argmin(np.abs(speeds[m]))] for m in (neg, pos) if m.any()]
            out[i] = float(np.mean(near))
    return out


def with_alpha_fo_starts(starts: np.ndarray, settings: Any, a0: float) -> np.ndarray:
    """The global phase's starts, each at 0.5, 1 and 2 x the drive's alpha_fo when it is tuned too."""
    if not settings.tune_alpha_fo:
        return starts
    return np.vstack([np.column_stack([starts, np.full(len(starts), k * a0)]) for k in (0.5, 1.0, 2.0)])


def _signed_log(lo: float, hi: float, R: float, n: int) -> np.ndarray:
    """Gains from lo to hi [ohm]: zero, and geometric from 0.1 R̂s to the bound on each side."""
    out = [0.0]
    if hi > 0.1 * R:
        out += list(np.geomspace(0.1 * R, hi, n))
    if lo < -0.1 * R:
        out += list(-np.geomspace(0.1 * R, -lo, n))
    return np.unique(np.clip(out, lo, hi))


def build_pointwise(drive: Any, settings: TuningSettings, seed: np.ndarray | None = None) -> TuningModel:
    """The free gains at one operating point: theta = [lambda1, lambda2] (constant law, eq. (7)), in the
    box of the schedule; the model of the pointwise bound (tuning/bound.py)."""
    law = get_law("constant")
    R = drive.estimate.R_s
    a0 = drive.observer.alpha_fo
    lam_max = settings.lambda_max if settings.lambda_max is not None else GAIN_BOX * R
    g = drive.gain("speed")

    def starts() -> np.ndarray:
        l1 = _signed_log(max(LAMBDA1_MIN * R, -lam_max), lam_max, R, 9)
        l2 = _signed_log(-lam_max, lam_max, R, 8)
        L1, L2 = np.meshgrid(l1, l2)
        out = np.column_stack([L1.ravel(), L2.ravel()])
        return with_alpha_fo_starts(out, settings, a0)

    return _common(
        drive,
        law,
        settings,
        theta0=[g.lambda_p, g.lambda_p],
        lower=[max(LAMBDA1_MIN * R, -lam_max), -lam_max],
        upper=[lam_max, lam_max],
        typical=[R, R],
        family="pointwise",
        regularizer=None,
        table_gains=lambda theta: {"lambda1": float(theta[0]), "lambda2": float(theta[1])},
        starts=starts,
    )


def with_estimate(drive: Any, estimate: np.ndarray) -> Any:
    """The drive with other parameter estimates (for analysis of the error scenarios)."""
    e = dataclasses.replace(
        drive.estimate, R_s=estimate[0], L_d=estimate[1], L_q=estimate[2], psi_pm=estimate[3]
    )
    return dataclasses.replace(drive, estimate=e)
