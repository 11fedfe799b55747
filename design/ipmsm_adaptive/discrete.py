"""The adaptive observer that runs, analysed in discrete time: its one-step map on the sampled motor.

Piippo, Hinkkanen, Luomi (2008) analyse the continuous-time observer (11)-(15); what runs on a drive
(and what ``sensorless codegen`` prints) is the discrete-time step of symbolic/ipmsm_adaptive/step.py at
the sampling period T_s. This module linearizes that step the way design/ipmsm_adaptive/linearize.py
linearizes the continuous observer, by automatic Jacobians of the same expressions:

- **Plant, sampled exactly under zero-order hold.** At the operating point (w_m, T_e) the motor carries
  the MTPA current i_s0 of its true parameters at every sampling instant (rotor frame), as with ideal
  current control in the continuous analysis. The voltage is the one a real inverter holds: constant
  in the stationary frame over each period. The rotor-frame voltage u_z at the start of the period that
  brings the motor's flux back to L i_s0 + psi_pm one period later is found from the exact solution of
  (1)-(2) over the period (matrix exponential of the flux equation augmented by the voltage's rotation
  in the rotor frame); the samples are then i_ab = T(theta_m) i_s0 and u_ab = T(theta_m) u_z.
- **One-step map.** The runtime step (injection off: the HF chain is a carrier-periodic modulation, not
  a time-invariant map) fed by those samples, in the coordinates y = [psi_hat (estimated frame), w_i,
  theta_tilde = theta_m - theta_hat, w_hat of the previous sample (which schedules the gain (16))].
  Because the step sees the motor only through T(-theta_hat), the map y_k -> y_k+1 is time-invariant.
- **Equilibrium.** Its fixed point, by Newton's method from the continuous equilibrium: the discrete
  observer's own steady state. Its theta_tilde is the steady position error the discretization leaves
  at the sampling instants; the steady speed error w_m - w_hat is zero at any fixed point (theta_hat
  integrates the output w_hat, and theta_tilde is at rest). Where a real pole passes through zero (the
  edge of the low-speed unstable band) any bias grows without bound and the fixed point may not be
  found: NaN there.
- **Poles.** The eigenvalues z of the map's Jacobian at the fixed point, shown as s = ln(z)/T_s beside
  the continuous poles; the four of largest |z| correspond to the continuous observer's four, the
  fifth (the one-sample memory of the gain's schedule, z = 0 where the schedule does not act) is
  reported by its |z|. Also the voltage feedthrough: d w_hat_k / d u_k, how far the speed estimate of a
  sample moves with the voltage applied from that sample on, before the current has answered it.

The method and what it shows are in docs/families/ipmsm_adaptive.md ("Discrete-time analysis").
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.expm import expm_batched
from sensorless.design.ipmsm_adaptive.linearize import PoleSweep
from sensorless.design.ipmsm_adaptive.runtime import runtime_params
from sensorless.design.poles import sort_poles
from sensorless.symbolic.frames import rot
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw
from sensorless.symbolic.ipmsm_adaptive.step import OBSERVER, observer_step_function

STATE_NAMES = ("psi_hat_d", "psi_hat_q", "w_i", "theta_tilde", "w_hat_prev")
N_Y = len(STATE_NAMES)
N_POLES = 4  # the continuous observer's order
_X = {f.name: k for k, f in enumerate(OBSERVER.state)}
_Y = {f.name: k for k, f in enumerate(OBSERVER.outputs)}


def zoh_voltage(motor: Sequence[float], w_m: np.ndarray, i_s0: np.ndarray, T_s: float) -> np.ndarray:
    """(N, 2) rotor-frame voltage u_z at the start of a period that keeps the sampled current at i_s0.

    ``motor`` = [R_s, L_d, L_q, psi_pm] (the true motor), ``w_m`` (N,) [rad/s], ``i_s0`` (N, 2) [A]. The
    stationary-frame voltage T(theta_m(t_k)) u_z is held over [t_k, t_k + T_s]; in the rotor frame it
    is T(-w_m tau) u_z. Flux (1)-(2) in the rotor frame, d psi/dt = M psi + c + v with M = -R_s L^-1 -
    w_m J, c = R_s L^-1 psi_pm, and dv/dt = -w_m J v: one 5x5 matrix exponential per point gives
    psi(T_s) = E11 psi(0) + E12 u_z + E13, and psi(T_s) = psi(0) = L i_s0 + psi_pm fixes u_z.
    """
    R, Ld, Lq, psi_pm = (float(v) for v in motor)
    w = np.asarray(w_m, float).ravel()
    n = w.size
    Jm = np.array([[0.0, -1.0], [1.0, 0.0]])
    Linv = np.diag([1 / Ld, 1 / Lq])
    Ma = np.zeros((n, 5, 5))
    Ma[:, 0:2, 0:2] = -R * Linv - w[:, None, None] * Jm
    Ma[:, 0:2, 2:4] = np.eye(2)
    Ma[:, 0:2, 4] = R * Linv @ np.array([psi_pm, 0.0])
    Ma[:, 2:4, 2:4] = -w[:, None, None] * Jm
    E = expm_batched(Ma * T_s)
    psi0 = np.asarray(i_s0, float) * np.array([Ld, Lq]) + np.array([psi_pm, 0.0])
    rhs = psi0 - np.einsum("nij,nj->ni", E[:, 0:2, 0:2], psi0) - E[:, 0:2, 4]
    return np.linalg.solve(E[:, 0:2, 2:4], rhs[:, :, None])[:, :, 0]


@functools.cache
def one_step_function(discretization: str, law: GainLaw) -> ca.Function:
    """(y, w_m, i_s0, u_z, p, gain) -> (y_next, Jy, w_hat, D_u): the runtime step on the sampled motor.

    ``y`` of :data:`STATE_NAMES` at t_k; ``p`` the runtime step's parameter vector (step.PARAMS);
    ``gain`` the law's parameters. ``Jy`` = d y_next / d y (5x5), ``w_hat`` the step's output,
    ``D_u`` = d w_hat / d u (1x2, the voltage in the estimated frame) [rad/s per V].
    """
    step = observer_step_function(discretization, law)
    y = ca.SX.sym("y", N_Y)
    w_m = ca.SX.sym("w_m")
    i_s0, u_z = ca.SX.sym("i_s0", 2), ca.SX.sym("u_z", 2)
    p = ca.SX.sym("p", len(OBSERVER.params))
    gain = ca.SX.sym("gain", law.n_params)
    du = ca.SX.sym("du", 2)  # voltage perturbation (estimated frame = stationary frame here)
    x = ca.SX.zeros(len(OBSERVER.state))
    x[_X["psi_d"]], x[_X["psi_q"]], x[_X["w_i"]] = y[0], y[1], y[2]
    x[_X["w_hat"]] = y[4]
    # theta_hat = 0 at t_k (the map is invariant to a common rotation): theta_m = theta_tilde
    T = rot(y[3])
    meas = ca.vertcat(T @ i_s0, T @ u_z + du)
    x_next, out = step(x, meas, p, gain)
    T_s = p[OBSERVER.index("params", "T_s")]
    y_next = ca.vertcat(
        x_next[_X["psi_d"]],
        x_next[_X["psi_q"]],
        x_next[_X["w_i"]],
        y[3] + w_m * T_s - x_next[_X["theta"]],  # theta_hat advanced from 0 (small: no wrap)
        x_next[_X["w_hat"]],
    )
    w_hat = out[_Y["w_hat"]]
    outs = [y_next, ca.jacobian(y_next, y), ca.jacobian(w_hat, du), w_hat]
    outs = [ca.substitute(e, du, ca.DM.zeros(2)) for e in outs]
    y_next, Jy, D_u, w_hat = outs
    names = ["y", "w_m", "i_s0", "u_z", "p", "gain"]
    return ca.Function(
        f"one_step_{discretization.replace('-', '_')}_{law.name}",
        [y, w_m, i_s0, u_z, p, gain],
        ca.cse([ca.densify(v) for v in (y_next, Jy, w_hat, D_u)]),
        names,
        ["y_next", "Jy", "w_hat", "D_u"],
    )


@dataclass(frozen=True, kw_only=True)
class DiscretePoleSweep(PoleSweep):
    """A :class:`PoleSweep` (the continuous analysis) with the discrete observer that runs beside it:
    ``poles_discrete`` = ln(z)/T_s of the four largest |z| of the one-step map at its fixed point, and
    what the discretization leaves in steady state (NaN where no fixed point is found)."""

    discretization: str
    y_d: np.ndarray  # (N, 5) fixed point of the one-step map (STATE_NAMES)
    J_d: np.ndarray  # (N, 5, 5) Jacobian of the one-step map there
    memory_z: np.ndarray  # (N,) |z| of the fifth eigenvalue (the schedule's one-sample memory)
    err_theta: np.ndarray  # (N,) steady position error theta_m - theta_hat at the samples [rad]
    err_w: np.ndarray  # (N,) steady speed error w_m - w_hat [rad/s] (zero at any fixed point)
    feedthrough: np.ndarray  # (N, 2) d w_hat_k / d u_k, estimated d and q axes [rad/s per V]
    u_z: np.ndarray  # (N, 2) the plant's ZOH voltage, rotor frame at the start of a period [V]

    @property
    def pole_error(self) -> np.ndarray:
        """(N,) max |ln(z)/T_s - s| [1/s] over the best matching of discrete and continuous poles."""
        return pole_distance(self.poles, self.poles_discrete)


def fixed_points(
    discretization: str,
    law: GainLaw,
    y0: np.ndarray,
    w_m: np.ndarray,
    i_s0: np.ndarray,
    u_z: np.ndarray,
    p: np.ndarray,
    gain: np.ndarray,
    iterations: int = 12,
) -> dict[str, np.ndarray]:
    """Newton's method on y_next(y) = y from ``y0`` (N, 5); the map's Jacobian and feedthrough there.

    ``p`` is (n_p,) or (n_p, N). A point whose iteration does not settle (a residual above 1e-9 of its
    component's scale: the flux, the speed, 1 rad), or that starts from NaN, gets NaN.
    """
    fn = one_step_function(discretization, law)
    n = y0.shape[0]
    args = [w_m[None, :], i_s0.T, u_z.T, p, np.asarray(gain, float)[: law.n_params]]
    bad = ~np.isfinite(y0).all(axis=1)
    y = np.where(bad[:, None], 0.0, y0)
    flux, speed = 1.0 + np.abs(y[:, 0:2]).max(axis=1), 1.0 + np.abs(w_m)
    scale = np.column_stack([flux, flux, speed, np.ones(n), speed])
    eye = np.eye(N_Y)

    def residual(y_next: np.ndarray) -> np.ndarray:
        r = y_next[:, :, 0] - y
        r[:, 3] = np.angle(np.exp(1j * r[:, 3]))  # theta_tilde modulo 2 pi
        return r

    for _ in range(iterations):
        y_next, Jy = evaluate_batch(fn, n, [y.T, *args])[:2]
        r = residual(y_next)
        todo = ~(np.abs(r) <= 1e-13 * scale).all(axis=1) & np.isfinite(Jy).all(axis=(1, 2))
        if not todo.any():
            break
        A = Jy[todo] - eye
        ok = np.abs(np.linalg.det(A)) > 1e-300
        idx = np.flatnonzero(todo)[ok]
        y[idx] -= np.linalg.solve(A[ok], r[idx][:, :, None])[:, :, 0]
    y_next, Jy, w_hat, D_u = evaluate_batch(fn, n, [y.T, *args])
    bad |= ~(np.abs(residual(y_next)) <= 1e-9 * scale).all(axis=1)
    y[bad] = np.nan
    return {
        "y": y,
        "J": np.where(bad[:, None, None], np.nan, Jy),
        "err_w": np.where(bad, np.nan, w_m - w_hat[:, 0, 0]),
        "feedthrough": np.where(bad[:, None], np.nan, D_u[:, 0, :]),
    }


def discrete_poles(J: np.ndarray, T_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(ln(z)/T_s of the four largest |z|, sorted like sort_poles; |z| of the fifth) of each (5, 5)."""
    n = J.shape[0]
    z = np.full((n, N_Y), np.nan + 0j)
    ok = np.isfinite(J).all(axis=(1, 2))
    if ok.any():
        z[ok] = np.linalg.eigvals(J[ok]).astype(complex)
    order = np.argsort(-np.abs(np.where(np.isnan(z), 0, z)), axis=1, kind="stable")
    z = np.take_along_axis(z, order, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(z[:, :N_POLES]) / T_s
    return sort_poles(s), np.abs(z[:, N_POLES])


def pole_distance(poles_c: np.ndarray, poles_d: np.ndarray) -> np.ndarray:
    """(N,) max |s_d - s_c| [1/s] over the best one-to-one matching of each row's poles (NaN stays)."""
    n = poles_c.shape[1]
    best = np.full(poles_c.shape[0], np.inf)
    for perm in itertools.permutations(range(n)):
        best = np.minimum(best, np.abs(poles_d[:, list(perm)] - poles_c).max(axis=1))
    bad = np.isnan(poles_c).any(axis=1) | np.isnan(poles_d).any(axis=1)
    return np.where(bad, np.nan, best)


def discrete_sweep(
    drive: Any, sweep: PoleSweep, gain: np.ndarray, discretization: str, T_s: float | None, estimate: Any
) -> DiscretePoleSweep:
    """The discrete analysis at the operating points of the continuous ``sweep`` (injection off).

    ``gain`` is the law's parameter vector, ``estimate`` the observer's estimates (4,) or (4, N), and
    ``T_s`` the sampling period (default the drive's).
    """
    if sweep.injection:
        raise ValueError(
            "the discrete-time analysis is of the observer without HF injection (its sampled chain is "
            "periodic at the carrier, not a time-invariant map)"
        )
    if discretization not in OBSERVER.discretizations:
        raise ValueError(
            f"unknown discretization {discretization!r} (known: {', '.join(OBSERVER.discretizations)})"
        )
    T_s = float(drive.control.T_s if T_s is None else T_s)
    n = sweep.w.size
    params = dict(runtime_params(drive), injection=0.0, T_s=T_s)
    p = np.repeat(OBSERVER.pack_params(params)[:, None], n, axis=1)
    est = np.broadcast_to(np.asarray(estimate, float).reshape(4, -1), (4, n))
    for k, name in enumerate(("R_s", "L_d", "L_q", "psi_pm")):
        p[OBSERVER.index("params", name)] = est[k]
    u_z = zoh_voltage(drive.motor.vector(), sweep.w, sweep.i_s0, T_s)
    x0 = sweep.x0  # continuous equilibrium [psi_hat_d, psi_hat_q, theta_tilde, w_i]
    y0 = np.column_stack([x0[:, 0], x0[:, 1], x0[:, 3], x0[:, 2], sweep.w])
    fp = fixed_points(discretization, sweep.law, y0, sweep.w, sweep.i_s0, u_z, p, gain)
    poles_d, memory_z = discrete_poles(fp["J"], T_s)
    fields = {f.name: getattr(sweep, f.name) for f in dataclasses.fields(sweep)}
    return DiscretePoleSweep(
        **{**fields, "poles_discrete": poles_d, "T_s": T_s},
        discretization=discretization,
        y_d=fp["y"],
        J_d=fp["J"],
        memory_z=memory_z,
        err_theta=fp["y"][:, 3],
        err_w=fp["err_w"],
        feedthrough=fp["feedthrough"],
        u_z=u_z,
    )


# --------------------------------------------------------------------------------------------------
# The discretization study: every scheme over the sampling period
# --------------------------------------------------------------------------------------------------
STUDY_SAMPLING = (50e-6, 100e-6, 200e-6, 400e-6)  # [s]
STUDY_SPEEDS = (0.1, 0.2, 0.3, 0.5, 0.67, 0.8, 1.0)  # |w_m| [p.u.], both directions


@dataclass(frozen=True)
class StudyRow:
    """One scheme at one sampling period, over the operating points of the study."""

    discretization: str
    T_s: float  # [s]
    err_theta: float  # largest |steady position error| [rad]
    err_theta_w: float  # at this speed [rad/s]
    feedthrough: float  # largest |d w_hat / d u| [rad/s per V]
    decay_error: float  # largest |decay rate of the slowest discrete pole / continuous - 1|
    damping_c: float  # worst damping ratio, continuous poles
    damping_d: float  # worst damping ratio, discrete poles
    pole_error: float  # largest |ln(z)/T_s - s| [1/s]


def discretization_study(
    drive: Any,
    gain: Any,
    schemes: Sequence[str],
    sampling: Sequence[float],
    w: np.ndarray,
    torque: np.ndarray,
    progress: Any = None,
) -> list[StudyRow]:
    """Rows for every scheme x T_s at the operating points (w [rad/s], torque [N m], broadcast).

    ``gain`` as :func:`~sensorless.design.ipmsm_adaptive.linearize.linearize` takes it (a name of the
    drive's gains or a (law, params) pair); ``progress(text)`` is told each scheme and T_s.
    """
    from sensorless.design.ipmsm_adaptive.linearize import linearize

    rows = []
    for T_s in sampling:
        for m in schemes:
            if progress is not None:
                progress(f"{m} at {T_s * 1e6:g} us")
            a = linearize(drive, w, torque, gain=gain, discretization=m, T_s=T_s)
            k = int(np.nanargmax(np.abs(a.err_theta)))
            stable = a.decay_rate > 0
            rel = np.abs(a.decay_rate_discrete[stable] / a.decay_rate[stable] - 1)
            rows.append(
                StudyRow(
                    m,
                    float(T_s),
                    float(abs(a.err_theta[k])),
                    float(a.w[k]),
                    float(np.nanmax(np.abs(a.feedthrough))),
                    float(np.nanmax(rel)) if rel.size else float("nan"),
                    float(np.nanmin(a.worst_damping)),
                    float(np.nanmin(a.worst_damping_discrete)),
                    float(np.nanmax(a.pole_error)),
                )
            )
    return rows
