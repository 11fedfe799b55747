"""Linearized error dynamics of the reduced-order observer by automatic Jacobians, continuous and discrete.

De Angelo, Bossio, Solsona, Garcia, Valla (2006).

Operating point = true electrical speed w (rad/s) and load torque T_L (N m). The motor runs at constant
speed carrying the ripple-free current (25) of T_e = T_L + B omega (viscosity is part of the load, as in
the paper); its voltage follows from (2). The observer is fed by those signals.

- **Continuous time**: the observer (16) with the position defined by (18)-(22) in the limit T_s -> 0,
  where the predicted angle equals the estimate (an implicit equation, differentiated implicitly). The
  states are taken in rotor coordinates y = [R(-theta) zeta, tau], which makes the linearization
  time-invariant for a sinusoidal EMF. The Jacobian is evaluated on the exact-estimate orbit (e_hat = e,
  T_L_hat = T_L + B omega), which the continuous observer follows exactly. With EMF harmonics the
  linearization is periodic in theta and the poles are its Floquet exponents over one period (frozen-
  angle eigenvalues would be misleading: the variation is fast at speed).
- **Discrete time**: the Jacobian of the one-step map that runs (symbolic/pmac_reduced_order/step.py) in
  rotor coordinates y = [R(-theta) zeta, tau, theta_hat - theta, w_hat], evaluated on the discrete
  observer's own steady orbit (simulated from the exact state until settled; the same simulation gives
  the steady-state errors). Its eigenvalues z map to s = ln(z) / T_s; with harmonics, the product of the
  one-step Jacobians over whole periods (Floquet multipliers).

docs/families/pmac_reduced_order.md explains the method and its choices.

Without load-torque estimation (Gamma = 0, [11]) T_L_hat stays 0 and tau is left out of the state.
Sweeps over speed x load are ``Function.map`` calls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.batch import mapped as _mapped
from sensorless.design.discrete import (
    discrete_poles,
    fixed_points,
    map_function,
    rotor_function,
    run_orbit,
    sensitivities,
    sensitivity_function,
)
from sensorless.design.expm import expm_batched
from sensorless.design.linearization import Linearization
from sensorless.design.memo import kept_function
from sensorless.design.noise import noise_rms_periodic
from sensorless.design.pmac_reduced_order.one_step import (
    angle_period,
    ordered_product,
    period_steps,
    sampled_loop,
    torque_function,
)
from sensorless.design.pmac_reduced_order.operating_point import (
    INPUT_NAMES,
    analysis_arguments,
    exact_state,
    exact_state_function,
    no_load_estimation,
    plant_signals,
    symbols,
)
from sensorless.design.poles import damping_ratio, eigvals_finite, sort_poles
from sensorless.symbolic.frames import J, rot
from sensorless.symbolic.pmac import flux_derivative
from sensorless.symbolic.pmac_reduced_order.observer import (
    emf_from_zeta,
    estimates,
    rates,
    speed_from_emf,
)
from sensorless.symbolic.pmac_reduced_order.step import split_params

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive


# kept on disk (design/memo.py): with exact_state_function, built for both load-estimation variants, it
# cost each analyze ~0.05 s of graph building (the implicit position's Jacobians); read back ~4 ms
@kept_function
def continuous_jacobian_function(
    orders_m: tuple[int, ...], orders_o: tuple[int, ...], load_estimation: bool = True
) -> ca.Function:
    """(theta, w, T_L, motor, params) -> A: the continuous-time error dynamics in rotor coordinates.

    A = dF/dy - dF/da (dh/da)^-1 dh/dy, where F is the rotor-frame rate of y = [R(-theta) zeta, tau]
    (tau left out without load estimation) and h = sin(theta_hat(y, a) - a) = 0 defines the position
    a = theta_hat implicitly: the harmonics (19) are removed at the estimate itself (T_s -> 0 limit of
    (21)). Evaluated on the exact-estimate orbit at angle theta. Also returns y0 and the rate dy/dt
    there (zero for a sinusoidal EMF: the orbit is an equilibrium in rotor coordinates).
    """
    s = symbols(orders_m, orders_o)
    params = s["params"] if load_estimation else no_load_estimation(s["params"])
    p, emf_o, _ = split_params(params, orders_o)
    th, w = s["theta"], s["w"]
    ny = 3 if load_estimation else 2
    y, a = ca.SX.sym("y", ny), ca.SX.sym("a")
    zeta = rot(th) @ y[0:2]
    tau = y[2] if load_estimation else 0
    sig, _ = plant_signals(s, th, orders_m)
    sigma = ca.if_else(w >= 0, 1, -1)
    # speed (13) at the implicit position a, used by the harmonic removal (19)
    e_hat = emf_from_zeta(zeta, sig.i, p)  # eq. (17)
    w_a = speed_from_emf(e_hat, flux_derivative(a, emf_o), sigma, p.p_r)  # eqs. (13)-(14)
    est = estimates(zeta, tau, sig.i, a, w_a, sigma, p, emf_o)
    dzeta, dtau = rates(est, sig.i, sig.v, p)  # eq. (16)
    F = ca.vertcat(rot(th).T @ dzeta - w * (J @ y[0:2]), *([dtau] if load_estimation else []))
    h = ca.sin(est.theta_hat - a)
    A = ca.jacobian(F, y) - ca.jacobian(F, a) @ ca.jacobian(h, y) / ca.jacobian(h, a)
    x0 = exact_state(s, orders_m, orders_o, load_estimation)
    y0 = ca.vertcat(rot(th).T @ x0[0:2], *([x0[2]] if load_estimation else []))
    sub = ca.Function("sub", [y, a, *s.values()], [A, F])
    A0, F0 = sub(y0, th, *s.values())
    name = f"pmac_reduced_order_jacobian_c{'' if load_estimation else '_noTL'}"
    return ca.Function(name, list(s.values()), [A0, y0, F0], list(INPUT_NAMES), ["A", "y0", "dy"])


@dataclass(frozen=True, kw_only=True)
class ObserverPoles(Linearization):
    """Continuous- (``poles``) and discrete-time (``poles_discrete``: ln(z)/T_s of the n dominant
    eigenvalues of the one-step map) poles of the observer error dynamics at N operating points
    (``w`` electrical speed, ``torque`` the load torque T_L), and the discrete observer's steady errors.

    With EMF harmonics the poles are Floquet exponents over one period of the rotor-frame dynamics
    (imaginary parts modulo 2 pi / period); for a sinusoidal EMF they are plain eigenvalues.
    """

    poles_discrete: np.ndarray  # always: the observer that runs is sampled (Linearization's, required)
    T_s: float  # its sampling period [s]
    load_estimation: bool
    method: str  # discretization
    memory_z: np.ndarray  # (N, n_d - n) |z| of the other one-step eigenvalues (largest along the window)
    steps: np.ndarray  # (N,) steps M of the discrete monodromy (1 for a sinusoidal EMF)
    err_w: np.ndarray  # steady-state speed error w - w_hat, mean over a period [rad/s]
    err_theta: np.ndarray  # steady-state position error theta - theta_hat, mean [rad]
    err_T: np.ndarray  # steady-state load error T_L + B omega - T_L_hat, mean [N m]
    ripple_w: np.ndarray  # peak-to-peak speed error over the window [rad/s]
    ripple_T: np.ndarray  # peak-to-peak load error over the window [N m]
    # (N, 2) RMS of the position [rad] and speed [rad/s] estimates from the drive's current-sensor
    # noise (``analyze(..., noise=True)``, design/noise.py); inf where unstable
    noise: np.ndarray | None = None

    def angle_bias(self) -> np.ndarray:
        """(N,) steady position error of the discrete observer [rad] (NaN: ``errors=False``)."""
        return self.err_theta

    def angle_noise(self) -> np.ndarray | None:
        """(N,) RMS position error [rad] from the current-sensor noise (``noise=True``)."""
        return None if self.noise is None else self.noise[:, 0]

    @property
    def T_L(self) -> np.ndarray:
        """(N,) load torque [N m] (the operating point's torque)."""
        return self.torque

    @property
    def damping_discrete(self) -> np.ndarray:
        """(N, n) damping ratio of each discrete pole mapped to s."""
        return damping_ratio(self.poles_discrete)


def floquet_exponents(monodromy: np.ndarray, duration: np.ndarray) -> np.ndarray:
    """ln(eig(monodromy)) / duration, principal branch, sorted like sort_poles (imag, then real)."""
    mu = eigvals_finite(monodromy)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(mu) / np.asarray(duration)[:, None]
    return sort_poles(s)


def continuous_poles(
    drive: PmacDrive,
    w: Any,
    T_L: Any,
    load_estimation: bool = True,
    n_angles: int = 64,
    columns: tuple[np.ndarray, np.ndarray] | None = None,
    **over: Any,
) -> np.ndarray:
    """Continuous-time poles at the operating points (broadcast, flattened) [1/s].

    For a sinusoidal EMF the linearization is time-invariant in rotor coordinates: its eigenvalues. With
    harmonics it is periodic in theta: the Floquet exponents ln(mu)/T_p of the monodromy matrix over one
    period T_p (a product of matrix exponentials over ``n_angles`` sub-intervals); their real parts are
    the decay rates, their imaginary parts are defined modulo 2 pi / T_p (principal branch).
    ``columns``: (motor, params) vectors per point, (n_m, N) and (n_p, N), instead of the drive's (the
    draws of a Monte-Carlo run: design/pmac_reduced_order/montecarlo.py).
    """
    w_f, T_f = (a.ravel() for a in np.broadcast_arrays(np.asarray(w, float), np.asarray(T_L, float)))
    om, oo, motor, params = analysis_arguments(drive, **over)
    period = angle_period(om, oo)
    n = w_f.size
    K = 1 if math.isinf(period) else n_angles
    step = 0.0 if K == 1 else period / K
    # midpoints of the K sub-intervals, in the direction of rotation
    theta = 0.3 + np.sign(w_f)[:, None] * (np.arange(K)[None, :] + 0.5) * step  # (n, K)
    fn = _mapped(continuous_jacobian_function(om, oo, load_estimation), n * K)
    if columns is None:
        m_cols, p_cols = motor[:, None], params[:, None]
    else:  # each point's own vectors, repeated over its sub-intervals
        m_cols, p_cols = (np.repeat(np.asarray(c, float), K, axis=1) for c in columns)
    A = np.asarray(
        fn(
            theta.reshape(1, -1),
            np.repeat(w_f, K)[None],
            np.repeat(T_f, K)[None],
            m_cols,
            p_cols,
        )[0]
    )
    ny = A.shape[0]
    A = A.reshape(ny, n * K, ny).transpose(1, 0, 2).reshape(n, K, ny, ny)
    if K == 1:
        return sort_poles(eigvals_finite(A[:, 0]))
    T_p = period / np.abs(w_f)  # [s]
    # every sub-interval's exponential at once (scipy's expm loops over a batch in Python)
    E = expm_batched((A * (T_p / K)[:, None, None, None]).reshape(n * K, ny, ny))
    M = ordered_product(E.reshape(n, K, ny, ny))
    return floquet_exponents(M, T_p)


def analyze(
    drive: PmacDrive,
    w: Any,
    T_L: Any,
    load_estimation: bool = True,
    method: str | None = None,
    T_s: float | None = None,
    g: float | None = None,
    Gamma: float | None = None,
    settle_time: float | None = None,
    n_angles: int = 64,
    noise: bool = False,
    errors: bool = True,
) -> ObserverPoles:
    """Continuous and discrete poles and the discrete steady-state errors at (w [rad/s], T_L [N m]).

    ``w`` and ``T_L`` broadcast; the result is flat (row-major). The discrete observer is simulated from
    the exact state for ``settle_time`` (default: 8 time constants of the slowest continuous pole,
    0.02..3 s), then over a window of M steps covering whole periods of the rotor-frame dynamics: the
    errors are averaged over it and the one-step Jacobians along it multiply to the monodromy matrix.
    ``noise``: also the RMS of the position and speed estimates from the drive's current-sensor noise
    (``[control] i_noise`` per axis and sample): the periodic discrete Lyapunov equation over the same
    window, with the noise of a sample entering two steps (design/noise.py).
    ``errors=False``: poles (and noise) only, the error window is not simulated (NaN errors); the poles
    do not depend on it: both windows start after the same settling (the tuner's fast path: with a
    sinusoidal EMF the error window is a whole electrical period, thousands of steps at low speed,
    against one step for the poles).
    """
    method = method or drive.control.discretization
    T_s = drive.control.T_s if T_s is None else T_s
    over = {"T_s": T_s, "g": g, "Gamma": Gamma}
    w_f, T_f = (a.ravel() for a in np.broadcast_arrays(np.asarray(w, float), np.asarray(T_L, float)))
    if np.any(w_f == 0):
        raise ValueError("zero speed: the EMF observer is undefined at standstill")
    n = w_f.size
    om, oo, motor, params = analysis_arguments(drive, **over)
    poles_c = continuous_poles(drive, w_f, T_f, load_estimation, n_angles, T_s=T_s, g=g, Gamma=Gamma)
    n_c = poles_c.shape[1]
    # per point, so that a point's result does not depend on the others analysed with it
    slow = np.nanmax(poles_c.real, axis=1)
    if settle_time is None:
        t_set = np.where(slow < 0, np.clip(8 / np.abs(slow), 0.02, 3.0), 3.0)
    else:
        t_set = np.full(n, float(settle_time))
    period = angle_period(om, oo)
    M = period_steps(2 * math.pi if math.isinf(period) else period, w_f, T_s)  # error window
    M_jac = period_steps(period, w_f, T_s)  # monodromy window (1 step for a sinusoidal EMF)
    settle = np.ceil(t_set / T_s).astype(int)
    # both windows start after the settling: the poles do not depend on whether errors are wanted
    end = settle + M  # error window [end - M, end)
    end_jac = settle + M_jac  # monodromy window [end_jac - M_jac, end_jac)
    n_steps = int((np.maximum(end, end_jac) if errors else end_jac).max())  # steps simulated
    theta0 = np.full(n, 0.3)  # start on the exact (continuous-time) orbit
    x0 = np.asarray(
        _mapped(exact_state_function(om, oo, load_estimation), n)(
            theta0[None], w_f[None], T_f[None], motor[:, None], params[:, None]
        )
    )
    loop = sampled_loop(method, om, oo, load_estimation)
    p_run = params if load_estimation else np.asarray(no_load_estimation(params)).ravel()  # Gamma = 0
    plant = np.vstack([T_f[None], np.repeat(motor[:, None], n, 1)])  # [T_L; motor] per point
    ctx = [w_f[None], plant, p_run, np.zeros(0)]  # the inputs after x (or y) and theta
    # the runtime step on the sampled motor (through the buffer interface: converting a long orbit
    # through casadi.DM costs more than running it)
    x0 = np.vstack([x0, np.zeros((1, n))])  # the contract's counter of rejected samples: 0
    xs, ths, outs = run_orbit(loop, n_steps, n, [x0, theta0, *ctx])
    out_of = {f.name: k for k, f in enumerate(loop.observer.outputs)}
    T_e = evaluate_batch(torque_function(om), n, [w_f, T_f, motor])[0][:, 0, 0]  # T_L + B omega
    err = np.stack(
        [
            w_f[:, None] - outs[:, out_of["w_hat"]],  # speed error [rad/s]
            np.angle(np.exp(1j * (ths[:, 0] - outs[:, out_of["theta_hat"]]))),  # position error [rad]
            T_e[:, None] - outs[:, out_of["T_L_hat"]],  # load-torque error (viscosity included) [N m]
        ]
    )  # (3, n, n_steps)
    # a scheme can diverge at a point (too long T_s for its speed): NaN results there, not an exception.
    # Judged over the point's own steps only: the batch runs to its longest point's end, and what a
    # shorter point's orbit does after its own end must not make it invalid (batch independence)
    k_idx = np.arange(n_steps)[None, :]
    own = k_idx < (np.maximum(end, end_jac) if errors else end_jac)[:, None]  # (n, n_steps)
    accepted = np.where(own, outs[:, out_of["valid"]] == 1, True).all(axis=1)
    ok = accepted & np.where(own[:, None], np.isfinite(xs), True).all(axis=(1, 2))
    if errors:
        win = (k_idx >= (end - M)[:, None]) & (k_idx < end[:, None])  # (n, n_steps): each point's window
        ok &= np.where(own[None], np.isfinite(err), True).all(axis=(0, 2))
        e_win = np.where(win[None], err, 0.0)
        mean = np.where(ok, e_win.sum(axis=2) / M, np.nan)
        ptp = np.where(
            ok,
            np.where(win[None], err, -np.inf).max(axis=2) - np.where(win[None], err, np.inf).min(axis=2),
            np.nan,
        )
    else:
        ok &= np.isfinite(err[:, np.arange(n), end_jac - 1]).all(axis=0)
        mean = ptp = np.full((3, n), np.nan)
    # one-step Jacobians along each point's last M_jac steps: the state after step j (at angle
    # theta_j) is mapped one step further; shorter windows are padded with identities after their end
    # (their last step repeated, masked): the product's pairing (ordered_product) then groups a point's
    # own factors as it does alone, so its bits do not depend on the batch's longest window
    mj = int(M_jac.max())
    rows = np.arange(n)[:, None]
    cols = (end_jac - 1 - M_jac)[:, None] + np.minimum(np.arange(mj)[None, :], (M_jac - 1)[:, None])
    keep = np.arange(mj)[None, :] < M_jac[:, None]  # (n, mj)
    x_w = xs[rows, :, cols].reshape(n * mj, -1).T
    th_w = ths[rows, 0, cols].reshape(n * mj)
    ctx_w = [np.repeat(w_f, mj)[None], np.repeat(plant, mj, axis=1), p_run, np.zeros(0)]
    y_w = evaluate_batch(rotor_function(loop), n * mj, [x_w, th_w])[0][:, :, 0].T
    if math.isinf(period):
        # sinusoidal EMF: in rotor coordinates the orbit is a fixed point of the one-step map, found by
        # Newton's method from the settled state (design/discrete.py); the errors are its own, no ripple
        y_fp = fixed_points(loop, np.where(ok[:, None], y_w.T, np.nan), w_f, plant.T, p_run, theta=th_w)[0]
        ok &= np.isfinite(y_fp).all(axis=1)
        y_w = np.nan_to_num(y_fp).T
        if errors:
            out = sensitivities(loop, y_fp, w_f, plant.T, p_run, theta=th_w)["out"]
            th1 = th_w + w_f * T_s  # the motor's angle at the samples
            mean = np.stack(
                [
                    w_f - out[:, out_of["w_hat"]],
                    np.angle(np.exp(1j * (th1 - out[:, out_of["theta_hat"]]))),
                    T_e - out[:, out_of["T_L_hat"]],
                ]
            )
            mean[:, ~ok] = np.nan
            ptp = np.where(ok, 0.0, np.nan) * np.ones((3, 1))
    # compiled whatever the batch size (a tuner evaluates these two Functions at every candidate)
    Jy = evaluate_batch(map_function(loop), n * mj, [y_w, th_w, *ctx_w], jit=True)[1]
    nd = Jy.shape[1]
    Jy = Jy.reshape(n, mj, nd, nd)
    Jy = np.where(keep[:, :, None, None], Jy, np.eye(nd))
    ok &= np.isfinite(Jy).all(axis=(1, 2, 3))
    Jy[~ok] = np.eye(nd)
    noise_rms = None
    if noise:
        sens = evaluate_batch(sensitivity_function(loop), n * mj, [y_w, th_w, *ctx_w], jit=True)
        # noise on the new current sample (meas) and on the stored previous one (state i_prev)
        G1 = sens[2][:, :, 0:2].reshape(n, mj, nd, 2)
        G0 = sens[1][:, :, 5:7].reshape(n, mj, nd, 2)
        G1 = np.where(keep[:, :, None, None], G1, 0.0)
        G0 = np.where(keep[:, :, None, None], G0, 0.0)
        # augmented state [y; n_(k-1)]: y_k = F y_(k-1) + G_prev n_(k-1) + G_new n_k, then store n_k
        Fa = np.zeros((n, mj, nd + 2, nd + 2))
        Fa[:, :, :nd, :nd] = Jy
        Fa[:, :, :nd, nd:] = G0
        Ga = np.zeros((n, mj, nd + 2, 2))
        Ga[:, :, :nd, :] = G1
        # the padding after a point's window is the identity of the augmented state (keeps the stored
        # sample, adds no noise): the periodic covariance is the point's own whatever the batch
        pad = ~keep[:, :, None, None]
        Fa[:, :, nd:, nd:] = np.where(pad, np.eye(2), 0.0)
        Ga[:, :, nd:, :] = np.where(pad, 0.0, np.eye(2))
        Ca = np.zeros((2, nd + 2))
        Ca[0, nd - 2], Ca[1, nd - 1] = 1.0, 1.0  # position error, speed estimate
        noise_rms = noise_rms_periodic(Fa, Ga, Ca, float(drive.control.i_noise), steps=M_jac)
        noise_rms[~ok] = np.nan
    # the monodromy over the window: its eigenvalues are the Floquet multipliers, z of one step for a
    # sinusoidal EMF (M_jac = 1)
    s_d = discrete_poles(ordered_product(Jy), M_jac * T_s, n_c)[0]
    s_d[~ok] = np.nan
    # the fast "memory" modes (previous position/speed of (19)-(21)) vanish in the product; their
    # size per step comes from the single-step eigenvalues, largest along the window
    z1 = -np.sort(-np.abs(eigvals_finite(Jy)), axis=-1)[..., n_c:]  # (n, mj, nd - n_c)
    memory_z = np.where(keep[:, :, None], z1, 0.0).max(axis=1)
    memory_z[~ok] = np.nan
    return ObserverPoles(
        w=w_f,
        torque=T_f,
        torque_name="T_L",
        load_estimation=load_estimation,
        method=method,
        T_s=T_s,
        poles=poles_c,
        poles_discrete=s_d,
        memory_z=memory_z,
        steps=M_jac,
        err_w=mean[0],
        err_theta=mean[1],
        err_T=mean[2],
        ripple_w=ptp[0],
        ripple_T=ptp[2],
        noise=noise_rms,
    )
