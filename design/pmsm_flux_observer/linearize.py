"""Linearization of the flux observer + PLL at an operating point: continuous and at the firmware's period.

The observer's equilibrium on a motor in steady state (electrical speed w, torque T_e at the true
motor's MTPA current) rotates in the stationary frame; in the rotor frame (flux state rotated by
-theta, the PLL's angle error delta = theta - theta_pll, the PLL speed, and lambda_hat where it is
adapted) it is a fixed point. Both the continuous observer (symbolic ``rhs_function``) and the sampled
one that runs (its runtime step, the Function the C prints) are written in that frame by composing
their own SX Functions with rotations; Newton's method on the SX expressions finds the equilibrium
and the poles are the eigenvalues of their CasADi Jacobians there (discrete: ln(z)/T_obs). The
previous period's voltage the step stores is an input here (the steady voltage at the middle of that
period), not a state of the error dynamics. The PLL does not feed back into the observer, so the poles
are the observer's with the PLL's; the observer's steady angle error is reported per point.

``clamped-gradient`` is linearized on its active side (|eta| > lambda, where it is the gradient
observer); inside, its correction is off. ``box-clamp`` has no linearization (CapabilityError): it is
judged by simulation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.family import CapabilityError, GainSet
from sensorless.design.linearization import Linearization
from sensorless.design.pmsm_flux_observer.gains import runtime_setup
from sensorless.design.poles import eigvals_batched
from sensorless.symbolic.frames import J, rot, wrap_angle
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current, stator_voltage
from sensorless.symbolic.pmsm_flux_observer.observer import PARAMS, observer_step_core, rhs_function

NEWTON_STEPS = 24
_IX = {f.name: k for k, f in enumerate(PARAMS)}


@dataclass(frozen=True)
class FluxLinearization(Linearization):
    """The common result plus the observer's steady angle error (theta - theta_obs) per point."""

    theta_err: np.ndarray | None = None  # (N,) [rad], continuous observer
    theta_err_discrete: np.ndarray | None = None  # (N,) [rad], the sampled observer
    law: str = ""

    def point_columns(self) -> dict[str, np.ndarray]:
        return {"theta_err_deg": np.degrees(self.theta_err_discrete)}

    def notes(self) -> tuple[str, ...]:
        return (f"gain law: {self.law}",)


def steady_motor(w: Any, T_e: Any, m: Any) -> tuple[Any, Any]:
    """(i_r, u_r) of the true motor m = [R_s, L_d, L_q, psi_pm, p] at speed w, torque T_e (MTPA, the
    steady voltage of the shared PMSM model)."""
    motor = PmsmParams(m[0], m[1], m[2], m[3])
    i_r = mtpa_current(T_e, motor, m[4])
    return i_r, stator_voltage(i_r, 0, flux_from_current(i_r, motor), w, motor.R_s)


def motor_vector(drive: Any) -> np.ndarray:
    mt = drive.motor
    return np.array([mt.R_s, mt.L_d, mt.L_q, mt.psi_pm, float(mt.p)])


@functools.cache
def equilibrium_function(kind: str, rule: str, adapt: bool, discrete: bool, law: ca.Function) -> ca.Function:
    """(w, T_e, motor[5], p, gain) -> (x_r*, A, residual) with x_r = [x_r (2), (lambda_hat), delta, w_pll]."""
    n = 5 if adapt else 4
    x_r = ca.SX.sym("x_r", n)
    w, T_e = ca.SX.sym("w"), ca.SX.sym("T_e")
    m, p, gain = ca.SX.sym("motor", 5), ca.SX.sym("p", len(PARAMS)), ca.SX.sym("gain", law.size1_in(1))
    i_r, u_r = steady_motor(w, T_e, m)
    lam = x_r[2] if adapt else p[_IX["psi_pm"]]
    delta, w_p = x_r[n - 2], x_r[n - 1]
    k_0 = law(w_p, gain)
    if discrete:
        T = p[_IX["T_s"]]
        x = ca.vertcat(x_r[0:2], lam, rot(w * T / 2) @ u_r, -delta, w_p, 0)
        meas = ca.vertcat(rot(w * T) @ i_r, rot(3 * w * T / 2) @ u_r)
        x1, _ = observer_step_core(kind, rule)(x, meas, p, k_0)
        F = [rot(-w * T) @ x1[0:2]] + ([x1[2]] if adapt else []) + [wrap_angle(w * T - x1[5]), x1[6]]
        F = ca.vertcat(*F)
        G = F - x_r
    else:
        dx = rhs_function(kind, rule)(ca.vertcat(x_r[0:2], lam, -delta, w_p), i_r, u_r, p, k_0)
        G = ca.vertcat(*([dx[0:2] - w * (J @ x_r[0:2])] + ([dx[2]] if adapt else []) + [w - dx[3], dx[4]]))
        F = G
    g_fn = ca.Function("G", [x_r, w, T_e, m, p, gain], [G, ca.jacobian(G, x_r)])
    psi_r = flux_from_current(i_r, PmsmParams(m[0], m[1], m[2], m[3]))
    xk = ca.vertcat(*([psi_r] + ([p[_IX["psi_pm"]]] if adapt else []) + [0, w]))
    for _ in range(NEWTON_STEPS):
        Gk, Jk = g_fn(xk, w, T_e, m, p, gain)
        xk = xk - ca.solve(Jk, Gk)
    Gk, _ = g_fn(xk, w, T_e, m, p, gain)
    A = ca.substitute(ca.jacobian(F, x_r), x_r, xk)
    # the observer's angle error theta - atan2(eta) at the equilibrium (rotor frame: theta = 0, or
    # theta = w T after the step)
    L = _inductance_at(rule, i_r, p)
    eta = xk[0:2] - L * i_r
    err = -ca.atan2(eta[1], eta[0])
    tag = "d" if discrete else "c"
    return ca.Function(
        f"pmsm_flux_observer_equilibrium_{tag}",
        [w, T_e, m, p, gain],
        [xk, ca.densify(A), ca.norm_inf(Gk), err],
        ["w", "T_e", "motor", "p", "gain"],
        ["x", "A", "res", "theta_err"],
    )


def _inductance_at(rule: str, i_r: Any, p: Any) -> Any:
    """The rule's inductance in the rotor frame (the interpolated rule at the true frame: an
    approximation of the steady error that the exact Newton state does not need)."""
    L_d, L_q = p[_IX["L_d"]], p[_IX["L_q"]]
    if rule == "fixed":
        return (L_d + L_q) / 2
    if rule == "q-axis":
        return L_q
    return L_d + (L_q - L_d) * i_r[1] ** 2 / (ca.sumsqr(i_r) + 1e-9)


def linearize(drive: Any, gains: GainSet, w: Any, torque: Any, estimate: Any = None) -> FluxLinearization:
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
    motor = motor_vector(drive)
    out, errs = {}, {}
    for discrete in (False, True):
        fn = equilibrium_function(kind, o.inductance_rule, o.lambda_adaptation, discrete, setup.schedule.law)
        x, A, res, err = evaluate_batch(fn, n, [W, T, motor, p, setup.gain])
        scale = np.maximum(np.abs(x[:, :, 0]).max(axis=1), 1.0)
        ok = np.isfinite(A).all(axis=(1, 2)) & (res[:, 0, 0] <= 1e-9 * scale)
        ev = np.full((n, A.shape[1]), np.nan + 0j)
        if ok.any():
            ev[ok] = eigvals_batched(A[ok])
        if discrete:
            with np.errstate(divide="ignore", invalid="ignore"):
                ev = np.log(ev.astype(complex)) / o.T_obs
        out[discrete] = ev
        errs[discrete] = np.where(ok, np.asarray(wrap(err[:, 0, 0])), np.nan)
    return FluxLinearization(
        w=W,
        torque=T,
        poles=out[False],
        poles_discrete=out[True],
        T_s=o.T_obs,
        torque_name="T_e",
        theta_err=errs[False],
        theta_err_discrete=errs[True],
        law=gains.family,
    )


def wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
