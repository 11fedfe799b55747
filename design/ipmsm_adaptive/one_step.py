"""The adaptive observer that runs, analysed in discrete time: its one-step map on the sampled motor.

Piippo, Hinkkanen, Luomi (2008) analyse the continuous-time observer (11)-(15); what runs on a drive
(and what ``sensorless codegen`` prints) is the discrete-time step of symbolic/ipmsm_adaptive/step.py at
the sampling period T_s. The shared discrete-time analysis (design/discrete.py) linearizes that step on
the sampled motor; this module declares what it cannot know (:func:`sampled_loop`: the coordinates)
and reads the results the way this family reports them:

- **Plant, sampled exactly under zero-order hold** (design/discrete.py ``zoh_voltage``): at the
  operating point (w_m, T_e) the motor carries the MTPA current i_s0 of its true parameters at every
  sampling instant (rotor frame), as with ideal current control in the continuous analysis, with the
  voltage an inverter holds constant in the stationary frame over each period.
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
  sample moves with the voltage applied from that sample on, before the current has answered.

The method and what it shows are in docs/families/ipmsm_adaptive.md ("Discrete-time analysis").
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, overload

import casadi as ca
import numpy as np
from sensorless.design import discrete as shared
from sensorless.design.discrete import SampledLoop, pole_distance
from sensorless.design.ipmsm_adaptive.linearize import PoleSweep, gain_parameters, operating_points
from sensorless.design.ipmsm_adaptive.linearize import linearize as linearize_continuous
from sensorless.design.ipmsm_adaptive.runtime import law_function, runtime_params
from sensorless.symbolic.frames import wrap_angle
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw
from sensorless.symbolic.ipmsm_adaptive.step import OBSERVER

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

STATE_NAMES = ("psi_hat_d", "psi_hat_q", "w_i", "theta_tilde", "w_hat_prev")
N_Y = len(STATE_NAMES)
N_POLES = 4  # the continuous observer's order
_X = {f.name: k for k, f in enumerate(OBSERVER.state)}
_Y = {f.name: k for k, f in enumerate(OBSERVER.outputs)}
_N_X = len(OBSERVER.state) - 1  # without the contract's counter


def _state(y: ca.SX, theta: ca.SX, w: ca.SX, plant: ca.SX, p: ca.SX) -> ca.SX:
    """The runtime state at the coordinates y with the motor at theta; the HF chain at rest (off)."""
    x = ca.SX.zeros(_N_X)
    x[_X["psi_d"]], x[_X["psi_q"]], x[_X["w_i"]] = y[0], y[1], y[2]
    x[_X["theta"]] = theta - y[3]
    x[_X["w_hat"]] = y[4]
    return x


def _rotor(x: ca.SX, theta: ca.SX) -> ca.SX:
    """The coordinates y of a runtime state with the motor at theta."""
    theta_tilde = wrap_angle(theta - x[_X["theta"]])
    return ca.vertcat(x[_X["psi_d"]], x[_X["psi_q"]], x[_X["w_i"]], theta_tilde, x[_X["w_hat"]])


@functools.cache
def sampled_loop(discretization: str, law: GainLaw) -> SampledLoop:
    """The runtime step with the gain law ``law`` on the PMSM sampled under zero-order hold."""
    return SampledLoop(
        observer=OBSERVER,
        discretization=discretization,
        law=law_function(law),
        names=STATE_NAMES,
        n_plant=4,
        sample=shared.pmsm_zoh_sample,
        state=_state,
        rotor=_rotor,
        angles=(STATE_NAMES.index("theta_tilde"),),
    )


@dataclass(frozen=True, kw_only=True)
class DiscretePoleSweep(PoleSweep):
    """A :class:`PoleSweep` (the continuous analysis) with the discrete observer that runs beside it:
    ``poles_discrete`` = ln(z)/T_s of the four largest |z| of the one-step map at its fixed point, and
    what the discretization leaves in steady state (NaN where no fixed point is found)."""

    poles_discrete: np.ndarray  # always here (Linearization's, required)
    T_s: float  # its sampling period [s]
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


def discrete_sweep(
    drive: IpmsmDrive,
    sweep: PoleSweep,
    gain: np.ndarray,
    discretization: str,
    T_s: float | None,
    estimate: Any,
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
    plant = shared.pmsm_zoh_plant(drive.motor.vector(), sweep.w, sweep.i_s0, T_s)
    x0 = sweep.x0  # continuous equilibrium [psi_hat_d, psi_hat_q, theta_tilde, w_i]
    y0 = np.column_stack([x0[:, 0], x0[:, 1], x0[:, 3], x0[:, 2], sweep.w])
    # the Newton tolerances: the flux, the speed, 1 rad
    flux = 1.0 + np.abs(np.nan_to_num(y0[:, 0:2])).max(axis=1)
    speed = 1.0 + np.abs(sweep.w)
    scale = np.column_stack([flux, flux, speed, np.ones(n), speed])
    loop = sampled_loop(discretization, sweep.law)
    g = np.asarray(gain, float)[: sweep.law.n_params]
    y, J = shared.fixed_points(loop, y0, sweep.w, plant, p, g, scale=scale)
    sens = shared.sensitivities(loop, y, sweep.w, plant, p, g, outputs_only=True)
    # d w_hat / d u in the estimated frame: u_ab = T(theta_hat) u_est, theta_hat = -theta_tilde here
    th = -np.nan_to_num(y[:, 3])
    T = np.stack([np.stack([np.cos(th), -np.sin(th)], -1), np.stack([np.sin(th), np.cos(th)], -1)], -2)
    feedthrough = np.einsum("ni,nij->nj", sens["Dm"][:, _Y["w_hat"], 2:4], T)
    poles_d, memory_z = shared.discrete_poles(J, T_s, N_POLES)
    fields = {f.name: getattr(sweep, f.name) for f in dataclasses.fields(sweep)}
    return DiscretePoleSweep(
        **{**fields, "poles_discrete": poles_d, "T_s": T_s},
        discretization=discretization,
        y_d=y,
        J_d=J,
        memory_z=memory_z[:, 0],
        err_theta=y[:, 3],
        err_w=sweep.w - sens["out"][:, _Y["w_hat"]],
        feedthrough=feedthrough,
        u_z=plant[:, 2:4],
    )


@overload
def linearize(
    drive: IpmsmDrive,
    w_m: Any,
    T_e: Any,
    gain: str | tuple | None = None,
    discretization: None = None,
    T_s: float | None = None,
    **options: Any,
) -> PoleSweep: ...


@overload
def linearize(
    drive: IpmsmDrive,
    w_m: Any,
    T_e: Any,
    gain: str | tuple | None = None,
    *,
    discretization: str,
    T_s: float | None = None,
    **options: Any,
) -> DiscretePoleSweep: ...


def linearize(
    drive: IpmsmDrive,
    w_m: Any,
    T_e: Any,
    gain: str | tuple | None = None,
    discretization: str | None = None,
    T_s: float | None = None,
    **options: Any,
) -> PoleSweep:
    """The continuous analysis (design/ipmsm_adaptive/linearize.py ``linearize``, with its options) and,
    with ``discretization`` (a scheme of the runtime step), also the discrete-time observer that runs
    at ``T_s`` (default the drive's): then a :class:`DiscretePoleSweep`."""
    sweep = linearize_continuous(drive, w_m, T_e, gain=gain, **options)
    if discretization is None:
        return sweep
    params, est = _discrete_inputs(drive, w_m, T_e, gain, options.get("estimate"))
    return discrete_sweep(drive, sweep, params, discretization, T_s, est)


def _discrete_inputs(
    drive: IpmsmDrive, w_m: Any, T_e: Any, gain: str | tuple | None, estimate: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The gain law's parameters and the estimates (per point, or the drive file's) that
    :func:`discrete_sweep` takes beside the continuous analysis of the same points, gain and estimate."""
    est = operating_points(w_m, T_e, estimate)[2]
    return gain_parameters(drive, gain)[1], np.array(drive.estimate.vector()) if est is None else est


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
    drive: IpmsmDrive,
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
    rows = []
    # the continuous analysis is the same for every scheme and T_s: once, not once per row (as
    # :func:`linearize` with a discretization computes it, at the drive file's estimates)
    continuous = linearize_continuous(drive, w, torque, gain=gain)
    params, est = _discrete_inputs(drive, w, torque, gain, None)
    for T_s in sampling:
        for m in schemes:
            if progress is not None:
                progress(f"{m} at {T_s * 1e6:g} us")
            a = discrete_sweep(drive, continuous, params, m, T_s, est)
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
