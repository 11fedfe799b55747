"""Linearization of the flux observer + PLL at an operating point: continuous and at the firmware's period.

The observer's equilibrium on a motor in steady state (electrical speed w, torque T_e at the true
motor's MTPA current) rotates in the stationary frame; in the rotor frame (flux state rotated by
-theta, the PLL's angle error delta = theta - theta_pll, the PLL speed, and lambda_hat where it is
adapted) it is a fixed point. Both the continuous observer (symbolic ``rhs_function``) and the sampled
one that runs (its runtime step, the Function the C prints: the shared design/discrete.py analysis of
a :class:`SampledLoop`, on the motor sampled under zero-order hold) are written in that frame; Newton's
method finds the equilibrium (the continuous one starts the discrete one) and the poles are the
eigenvalues of the CasADi Jacobians there (discrete: ln(z)/T_obs). The previous period's voltage the
step stores is the plant's, not a state of the error dynamics. The PLL does not feed back into the
observer, so the poles are the observer's with the PLL's; the observer's steady angle error is
reported per point.

``clamped-gradient`` is linearized on its active side (|eta| > lambda, where it is the gradient
observer); inside, its correction is off. ``box-clamp`` has no linearization (CapabilityError): it is
judged by simulation.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.discrete import (
    SampledLoop,
    eigenvalues_by_size,
    fixed_points,
    pmsm_zoh_plant,
    pmsm_zoh_sample,
    poles_by_size,
    sensitivities,
)
from sensorless.design.family import CapabilityError, GainSet
from sensorless.design.linearization import Linearization
from sensorless.design.memo import kept_function
from sensorless.design.noise import noise_rms_periodic
from sensorless.design.pmsm_flux_observer.gains import runtime_setup
from sensorless.design.poles import eigvals_batched
from sensorless.design.rotor_frame import (
    RotorFrameLoop,
    equilibrium_points,
    pmsm_plant,
    pmsm_steady,
    pmsm_steady_current,
)
from sensorless.symbolic.frames import J, rot, wrap_angle
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current
from sensorless.symbolic.pmsm_flux_observer.observer import PARAMS, rhs_function, runtime_observer

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

# the sampled observer's damped Newton (discrete_analysis): each halved step costs an iteration; 40
# left NaN at three estimate-error corners of outrunner270 (0.24-1 p.u., the continuous equilibrium
# 0.2-0.5 rad from the sampled one) where plain Newton converges, and the flux tuner then judged the
# ODrive default as holding nowhere; 100 finds every one, the same fixed points to 1e-6
DAMPED_STEPS = 200
I_NOISE_DEFAULT = 0.003  # default current-sensor noise: 0.3 % of the current amplitude at T_N
_IX = {f.name: k for k, f in enumerate(PARAMS)}


@dataclass(frozen=True)
class FluxLinearization(Linearization):
    """The common result plus the observer's steady angle error (theta - theta_obs) per point."""

    theta_err: np.ndarray | None = None  # (N,) [rad], continuous observer
    theta_err_discrete: np.ndarray | None = None  # (N,) [rad], the sampled observer
    law: str = ""
    observer_decay: np.ndarray | None = None  # (N,) [1/s] decay rate of the observer's own modes

    def low_speed_decay(self) -> np.ndarray:
        """The observer's decay without the PLL's roots where the observer does not depend on the PLL.

        The PLL's roots (s^2 + k_p s + k_i) do not depend on the speed: a slow one (VESC's default
        k_p = 2000 1/s, k_i = 30000 1/s^2: -15.1 1/s) is slow at every speed and sets no minimum
        speed; the report judges it on its own (reports/pmsm_flux_observer: the speed estimate's
        settling). Where the gain is scheduled over the PLL speed (schedule) the modes are
        coupled and the slowest of all counts."""
        return self.decay_rate if self.observer_decay is None else self.observer_decay

    def point_columns(self) -> dict[str, np.ndarray]:
        err = self.theta_err_discrete
        return {} if err is None else {"theta_err_deg": np.degrees(err)}

    def notes(self) -> tuple[str, ...]:
        return (f"gain law: {self.law}",)

    def angle_bias(self) -> np.ndarray | None:
        """(N,) steady angle error of the sampled observer [rad], as its tuner judges it."""
        return self.theta_err_discrete


def motor_vector(drive: FluxObserverDrive) -> np.ndarray:
    """[R_s, L_d, L_q, psi_pm, p] of the true motor: the loop's ``plant`` (design/rotor_frame.py)."""
    return pmsm_plant(drive.motor)


# kept on disk by its content (design/memo.py: the gain law pickles as its serialization), as the
# Functions design/rotor_frame.py builds from the loop are: a command reads the graph back, not builds it
@kept_function
def rotor_frame_loop(kind: str, rule: str, adapt: bool, law: ca.Function) -> RotorFrameLoop:
    """The continuous observer + PLL on the motor in steady state, in the rotor frame (design/rotor_frame.py):
    x_r = [flux state rotated by -theta (2), (lambda_hat), delta = theta - theta_pll, w_pll]; its ``p`` is
    the runtime parameters (PARAMS) followed by the schedule's gain vector; its output the observer's
    steady angle error theta - atan2(eta) (rotor frame: theta = 0)."""
    n = 5 if adapt else 4
    n_p = len(PARAMS)
    x_r = ca.SX.sym("x_r", n)
    w, T_e = ca.SX.sym("w"), ca.SX.sym("T_e")
    m, pg = ca.SX.sym("motor", 5), ca.SX.sym("p", n_p + law.size1_in(1))
    p, gain = pg[:n_p], pg[n_p:]
    i_r, u_r = pmsm_steady(w, T_e, m)
    lam = x_r[2] if adapt else p[_IX["psi_pm"]]
    delta, w_p = x_r[n - 2], x_r[n - 1]
    dx = rhs_function(kind, rule)(ca.vertcat(x_r[0:2], lam, -delta, w_p), i_r, u_r, p, law(w_p, gain))
    parts: list[Any] = [dx[0:2] - w * (J @ x_r[0:2])] + ([dx[2]] if adapt else []) + [w - dx[3], dx[4]]
    G = ca.vertcat(*parts)
    psi_r = flux_from_current(i_r, PmsmParams(m[0], m[1], m[2], m[3]))
    start: list[Any] = [psi_r] + ([p[_IX["psi_pm"]]] if adapt else []) + [0, w]
    x0 = ca.vertcat(*start)
    eta = x_r[0:2] - _inductance_at(rule, i_r, p) * i_r
    args, names = [x_r, w, T_e, m, pg], ["x_r", "w", "torque", "plant", "p"]
    return RotorFrameLoop(
        "pmsm_flux_observer",
        ca.Function("pmsm_flux_observer_rates", args, [G], names, ["f_r"]),
        ca.Function("pmsm_flux_observer_start", args[1:], [x0], names[1:], ["x_r"]),
        ca.Function(
            "pmsm_flux_observer_angle_error", args, [-ca.atan2(eta[1], eta[0])], names, ["theta_err"]
        ),
    )


def with_gain(p: np.ndarray, gain: Any) -> np.ndarray:
    """The loop's ``p``: the runtime parameters, then the gain; one vector or a column per point."""
    p, gain = np.asarray(p, float), np.asarray(gain, float)
    if p.ndim == 1 and gain.ndim <= 1:
        return np.concatenate([p, gain.ravel()])
    n = max(a.shape[1] for a in (p, gain) if a.ndim == 2)
    cols = lambda a: a if a.ndim == 2 else np.repeat(a.reshape(-1, 1), n, axis=1)  # noqa: E731
    return np.vstack([cols(p), cols(gain)])


@functools.cache
def sampled_loop(kind: str, rule: str, adapt: bool, law: ca.Function) -> SampledLoop:
    """The runtime step on the motor sampled under zero-order hold (design/discrete.py), in rotor
    coordinates y = [flux state rotated by -theta (2), (lambda_hat), delta = theta - theta_pll, w_pll];
    the stored voltage of the previous period is the plant's (held over the period before theta)."""
    ix_T = _IX["T_s"]
    ix_psi = _IX["psi_pm"]
    n = 5 if adapt else 4

    def state(y: Any, theta: Any, w: Any, plant: Any, p: Any) -> Any:
        lam = y[2] if adapt else p[ix_psi]
        u_prev = rot(theta - w * p[ix_T]) @ plant[2:4]
        return ca.vertcat(rot(theta) @ y[0:2], lam, u_prev, theta - y[n - 2], y[n - 1])

    def rotor(x: Any, theta: Any) -> Any:
        turn: Any = rot(theta)  # of an SX angle: an SX matrix
        back = turn.T
        return ca.vertcat(*([back @ x[0:2]] + ([x[2]] if adapt else []) + [wrap_angle(theta - x[5]), x[6]]))

    names = ("x_d", "x_q", *(("lambda_hat",) if adapt else ()), "delta", "w_pll")
    obs = runtime_observer(kind, rule)
    return SampledLoop(obs, "euler", law, names, 4, pmsm_zoh_sample, state, rotor, (n - 2,))


def discrete_analysis(
    drive: FluxObserverDrive,
    loop: SampledLoop,
    y0: np.ndarray,
    W: np.ndarray,
    T: np.ndarray,
    p: np.ndarray,
    gain: Any,
    sigma: float | None = None,
    observer_decay: bool = False,
) -> tuple[np.ndarray, ...]:
    """(poles ln(z)/T_obs, |z| largest, angle error theta - theta_hat) of the sampled observer from the
    start points y0 (the continuous equilibria); p (n_p,) or (n_p, N), gain one or per point. With
    ``sigma`` [A rms per axis and sample], a fourth: (N, 2) RMS of the PLL's angle [rad] and speed
    [rad/s] for that current-sensor noise (design/noise.py, the per-sample propagation through the
    one-step Jacobian; inf where unstable). With ``observer_decay``, last: (N,) the decay rate [1/s] of
    the observer's own modes, without the PLL's (``_observer_decay``, sampled)."""
    T_obs = drive.observer.T_obs
    plant = sampled_plant(drive, W, T)
    y, Jd = sampled_fixed_points(loop, y0, W, plant, p, gain)
    z = eigenvalues_by_size(Jd)
    poles = poles_by_size(z, T_obs, loop.n_y)[0]
    sens = sensitivities(loop, y, W, plant, p, gain)
    err = -sens["out"][:, loop.observer.index("outputs", "theta_hat")]  # atan2's range: no wrap
    z = np.abs(z[:, 0])
    own = (_sampled_observer_decay(Jd, poles, T_obs),) if observer_decay else ()
    if sigma is None:
        return poles, z, err, *own
    # the current samples are meas[0:2] (stationary frame: the noise is isotropic, so its rotation
    # into the rotor coordinates leaves its covariance unchanged)
    n = loop.n_y
    C = np.zeros((2, n))
    C[0, n - 2] = C[1, n - 1] = 1.0  # delta = theta - theta_pll, w_pll
    # the one-step window's monodromy is Jd: its spectral radius is z, from the same eigenvalues
    noise = noise_rms_periodic(Jd[:, None], sens["Jm"][:, None, :, 0:2], C, sigma, rho=z)
    return poles, z, err, noise, *own


def sampled_plant(drive: FluxObserverDrive, W: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(N, 4) the sampled loop's plant vectors (design/discrete.py ``pmsm_zoh_plant``: the true motor's
    MTPA current and the voltage that holds it under zero-order hold) at speeds W, torques T. They
    depend on the operating point alone: computed once per distinct (speed, torque), since a tuner's
    assessment repeats the envelope for every candidate and estimate corner (each point's matrix
    exponential is its own: the same numbers as point by point)."""
    m = drive.motor
    points, at = np.unique(np.column_stack([W, T]), axis=0, return_inverse=True)
    i_r = pmsm_steady_current(points[:, 1], pmsm_plant(m))
    return pmsm_zoh_plant(m.vector(), points[:, 0], i_r, drive.observer.T_obs)[at.ravel()]


@functools.cache
def _steady_voltage() -> ca.Function:
    """(w, T_e, plant) -> the rotor-frame steady voltage u_r of :func:`rotor_frame_loop`'s motor."""
    w, T_e, m = ca.SX.sym("w"), ca.SX.sym("T_e"), ca.SX.sym("plant", 5)
    return ca.Function("pmsm_steady_voltage", [w, T_e, m], [pmsm_steady(w, T_e, m)[1]])


def gain_voltage(drive: FluxObserverDrive, W: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(N,) the smaller of the voltage amplitudes |u| the observer gain's factor max(k_slow, |u|/u_ref)
    (VESC's schedule, symbolic ``observer_gain``) reads at the points: the continuous loop's steady
    voltage (:func:`rotor_frame_loop`) and the voltage the sampled loop holds over the period
    (:func:`sampled_loop`'s stored u_prev, of :func:`sampled_plant`). Neither depends on the observer's
    state or estimates, so where k_slow is below |u|/u_ref at both, the factor is that of |u|, the same
    number for every such k_slow."""
    u_r = evaluate_batch(_steady_voltage(), W.size, [W, T, pmsm_plant(drive.motor)])[0][:, :, 0]
    u_d = sampled_plant(drive, W, T)[:, 2:4]
    return np.minimum(np.hypot(u_r[:, 0], u_r[:, 1]), np.hypot(u_d[:, 0], u_d[:, 1]))


def sampled_fixed_points(
    loop: SampledLoop, y0: np.ndarray, W: np.ndarray, plant: np.ndarray, p: np.ndarray, gain: Any
) -> tuple[np.ndarray, np.ndarray]:
    """(fixed points y (N, n_y), one-step Jacobians there (N, n_y, n_y)) of the sampled observer by
    design/discrete.py's damped Newton from the continuous equilibria ``y0`` (NaN rows: none found, and
    none iterated); ``plant`` (N, n_plant), ``p`` and ``gain`` one vector or one column per point.

    Damped: the continuous equilibrium may lie outside the sampled one's Newton basin near a slow
    observer mode (hubmotor48 at rated load near 1 p.u.: a full step landed on another fixed point)."""
    return fixed_points(loop, y0, W, plant, p, gain, iterations=DAMPED_STEPS, damped=True)


def _sampled_observer_decay(Jd: np.ndarray, poles: np.ndarray, T: float) -> np.ndarray:
    """(N,) -max ln|z|/T of the one-step map's observer block where the map is block triangular (as
    ``_observer_decay``: the PLL's modes, the last two coordinates, left out); elsewhere of all poles."""
    m = Jd.shape[1] - 2
    ok = np.isfinite(Jd).all(axis=(1, 2))
    out = np.full(Jd.shape[0], np.nan)
    out[ok] = -np.max(poles[ok].real, axis=1)
    if ok.any():
        J = Jd[ok]
        with np.errstate(divide="ignore", invalid="ignore"):
            own = -np.max(np.log(np.abs(eigvals_batched(np.ascontiguousarray(J[:, :m, :m])))), axis=1) / T
        coupled = np.abs(J[:, :m, m:]).max(axis=(1, 2)) > 0
        out[ok] = np.where(coupled, out[ok], own)
    return out


def current_noise(drive: FluxObserverDrive) -> float:
    """The current-sensor noise [A rms per axis and sample]: ``[control] i_noise``, or I_NOISE_DEFAULT
    of the current amplitude at rated torque (the other families' default)."""
    if drive.i_noise > 0:
        return float(drive.i_noise)
    i_r = pmsm_steady_current(np.array([drive.T_N]), pmsm_plant(drive.motor))
    return I_NOISE_DEFAULT * float(np.hypot(*i_r[0]))


def _inductance_at(rule: str, i_r: Any, p: Any) -> Any:
    """The rule's inductance in the rotor frame (the interpolated rule at the true frame: an
    approximation of the steady error that the exact Newton state does not need)."""
    L_d, L_q = p[_IX["L_d"]], p[_IX["L_q"]]
    if rule == "fixed":
        return (L_d + L_q) / 2
    if rule == "q-axis":
        return L_q
    return L_d + (L_q - L_d) * i_r[1] ** 2 / (ca.sumsqr(i_r) + 1e-9)


def linearize(
    drive: FluxObserverDrive, gains: GainSet, w: Any, torque: Any, estimate: Any = None
) -> FluxLinearization:
    """Continuous and discrete poles at speeds ``w`` [rad/s] x torques [N m] (broadcast together).

    ``estimate``: an optional dict of runtime parameter overrides (R_s, L_d, L_q, psi_pm) to study
    estimate errors; the true motor is the drive's."""
    o = drive.observer
    if o.correction == "box-clamp":
        raise CapabilityError(
            "the box-clamp observer (MXLEMMING) is not linearizable: its clamp is the whole correction "
            "and has no smooth equilibrium; it is judged by simulation (sensorless simulate, report)"
        )
    kind = "gradient"  # the clamped observer on its active side (module docstring)
    W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
    n = W.size
    setup = runtime_setup(drive, gains)
    params = dict(setup.params)
    if estimate:
        params.update(estimate)
    p = setup.observer.pack_params(params)
    assert setup.schedule is not None  # the family's runtime set-up always has its schedule (gains.py)
    law = setup.schedule.law
    rule, adapt = o.inductance_rule, o.lambda_adaptation
    eq = equilibrium_points(
        rotor_frame_loop(kind, rule, adapt, law), W, T, motor_vector(drive), with_gain(p, setup.gain)
    )
    ok = eq.ok
    poles = np.full((n, eq.A.shape[1]), np.nan + 0j)
    own = np.full(n, np.nan)
    if ok.any():
        poles[ok] = eigvals_batched(eq.A[ok])
        own[ok] = _observer_decay(eq.A[ok], poles[ok])
    poles_d, _, err_d = discrete_analysis(
        drive, sampled_loop(kind, rule, adapt, law), eq.x, W, T, p, setup.gain
    )
    return FluxLinearization(
        w=W,
        torque=T,
        poles=poles,
        poles_discrete=poles_d,
        T_s=o.T_obs,
        torque_name="T_e",
        theta_err=None if eq.y is None else eq.y[:, 0],
        theta_err_discrete=err_d,
        law=gains.law,
        observer_decay=own,
    )


def sampled_angle_errors(
    drive: FluxObserverDrive, gains: GainSet, w: Any, torque: Any, estimates: Sequence[Mapping[str, float]]
) -> np.ndarray:
    """(len(estimates), N) the sampled observer's steady angle error theta - theta_hat [rad] at speeds
    ``w`` x torques (broadcast together) under each of the ``estimates`` (runtime parameter overrides,
    as :func:`linearize`'s): its ``theta_err_discrete`` of each, in one batch (each point's numbers
    are its own: the same as one :func:`linearize` per estimate, without its continuous poles)."""
    o = drive.observer
    if o.correction == "box-clamp":
        linearize(drive, gains, w, torque)  # its CapabilityError
    W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
    setup = runtime_setup(drive, gains)
    assert setup.schedule is not None  # the family's runtime set-up always has its schedule (gains.py)
    P = np.repeat(
        np.column_stack([setup.observer.pack_params({**setup.params, **e}) for e in estimates]), W.size, 1
    )
    Wk, Tk = np.tile(W, len(estimates)), np.tile(T, len(estimates))
    law, rule, adapt = setup.schedule.law, o.inductance_rule, o.lambda_adaptation
    loop = rotor_frame_loop("gradient", rule, adapt, law)
    y0 = equilibrium_points(loop, Wk, Tk, motor_vector(drive), with_gain(P, setup.gain)).x
    err = discrete_analysis(drive, sampled_loop("gradient", rule, adapt, law), y0, Wk, Tk, P, setup.gain)[2]
    return err.reshape(len(estimates), W.size)


def _observer_decay(A: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """(N,) -max Re of the observer block's eigenvalues (flux state, lambda_hat) where the Jacobian is
    block triangular (the observer rows do not depend on the PLL's delta, w_pll: then its eigenvalues
    are the observer block's and the PLL block's); elsewhere of all poles."""
    m = A.shape[1] - 2
    own = -np.max(eigvals_batched(np.ascontiguousarray(A[:, :m, :m])).real, axis=1)
    coupled = np.abs(A[:, :m, m:]).max(axis=(1, 2)) > 0
    return np.where(coupled, -np.max(poles.real, axis=1), own)
