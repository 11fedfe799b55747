"""Monte-Carlo draws of the flux-observer drive (design/montecarlo.py): the spreadable parameters, every
draw's linearized observer in one batched evaluation, and a perturbed drive for the time domain.

The true motor's R_s, L_d, L_q, psi_pm (and J, time domain only) and the firmware's estimates of the
first four. Each draw is the sampled observer that runs (its runtime step at the firmware's period, on
the drawn motor sampled under zero-order hold: linearize.py ``sampled_loop``, the analysis the tuner and
the report make) with its PLL at every operating point: the continuous observer's equilibrium (Lee et
al. (2010) eq. (8), linearize.py ``rotor_frame_loop`` by design/rotor_frame.py) starts Newton's method
on the one-step map, whose Jacobian's eigenvalues give the poles ln(z)/T_obs; each step is one batched
call over draws x points (the drawn motor, its MTPA current and zero-order-hold voltage and the runtime
parameters are its columns). A point without a fixed point is NaN. The yield is the share of draws
whose sampled observer keeps the family's required damping (stable: its damping falls with speed by
design) at every point of the envelope (design/montecarlo.py ``chunk_damping`` judges
``poles_discrete``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.discrete import discrete_poles, pmsm_zoh_plant
from sensorless.design.family import CapabilityError, GainSet
from sensorless.design.montecarlo import Uncertain
from sensorless.design.montecarlo import perturbed as shared_perturbed
from sensorless.design.pmsm_drive import startup_values
from sensorless.design.pmsm_flux_observer.gains import runtime_setup
from sensorless.design.pmsm_flux_observer.linearize import (
    FluxLinearization,
    rotor_frame_loop,
    sampled_fixed_points,
    sampled_loop,
    with_gain,
)
from sensorless.design.poles import eigvals_batched
from sensorless.design.rotor_frame import equilibrium_points, pmsm_steady_current
from sensorless.symbolic.pmsm_flux_observer.observer import PARAMS

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

ELECTRICAL = ("R_s", "L_d", "L_q", "psi_pm")
# the plant's typical spread (1 sigma) a run assumes without --spread: the winding's resistance with its
# temperature, inductance tolerance, the magnets' flux; the load's inertia
TYPICAL = {"R_s": 0.10, "L_d": 0.10, "L_q": 0.10, "psi_pm": 0.05, "J": 0.30}
UNITS = {"R_s": "ohm", "L_d": "H", "L_q": "H", "psi_pm": "V s"}


def parameters(drive: FluxObserverDrive) -> tuple[Uncertain, ...]:
    m, e = drive.motor, drive.estimate
    out = [Uncertain(k, getattr(m, k), getattr(e, k), UNITS[k], True, TYPICAL[k]) for k in ELECTRICAL]
    out.append(Uncertain("J", m.J, None, "kg m^2", False, TYPICAL["J"]))
    return tuple(out)


perturbed = (
    shared_perturbed  # design/montecarlo.py: the same for every family with motor and estimate records
)


def envelope_points(drive: FluxObserverDrive, gains: GainSet | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Its drive file's [envelope] (speeds in both directions x torques); with ``gains``, the points
    where they run the drive sensorless: from the open-loop I-f start's hand-back speed w_off up (its
    [startup], else its rules at the gains: design/pmsm_drive.py ``startup_values``), since below it the
    drive runs open loop (no equilibrium there under an estimate error is no failure)."""
    W, T = drive.envelope.grid()
    if gains is None:
        return W, T
    try:
        values, _, _ = startup_values(drive, gains)
    except CapabilityError:
        return W, T
    w_off = (values or {}).get("if_w_off")
    if not w_off:
        return W, T
    keep = np.abs(W) >= float(w_off) * (1 - 1e-12)
    return (W[keep], T[keep]) if keep.any() else (W, T)


def linearize_draws(
    drive: FluxObserverDrive,
    gains: GainSet,
    plant: np.ndarray,
    estimate: np.ndarray,
    w: np.ndarray,
    torque: np.ndarray,
    complete: bool = True,
) -> FluxLinearization:
    """Every draw (rows, columns in :func:`parameters`' order) at every point, draw-major, one batched
    evaluation; ``complete`` False: a draw with a point without equilibrium is NaN at all its points."""
    o = drive.observer
    if o.correction == "box-clamp":
        raise CapabilityError(
            "the box-clamp observer (MXLEMMING) is not linearizable: no Monte-Carlo of its linearization"
        )
    w, torque = np.asarray(w, float).ravel(), np.asarray(torque, float).ravel()
    n_d, n_p = plant.shape[0], w.size
    k = len(ELECTRICAL)
    setup = runtime_setup(drive, gains)
    assert setup.schedule is not None  # the family's runtime set-up always has its schedule (gains.py)
    names = [f.name for f in PARAMS]
    base = dict(setup.params)
    P = np.empty((len(names), n_d))
    for j, name in enumerate(names):
        P[j] = base[name]
    for c, name in enumerate(ELECTRICAL):  # the estimates the observer runs with
        P[names.index(name)] = estimate[:, c]
    # VESC's run-time gain is 4 raw lambda_hat^2 x its factor: scaled with it
    if gains.law == "voltage-scaled":
        gain = np.asarray(setup.gain, float).reshape(-1, 1) * (estimate[:, 3] / drive.estimate.psi_pm) ** 2
    else:
        gain = np.repeat(np.asarray(setup.gain, float).reshape(-1, 1), n_d, axis=1)
    M = np.vstack([plant[:, :k].T, np.full((1, n_d), float(drive.motor.p))])
    W, T = np.tile(w, n_d), np.tile(torque, n_d)
    rep = lambda a: np.repeat(a, n_p, axis=1)  # noqa: E731  (draw-major columns)
    loop = rotor_frame_loop("gradient", o.inductance_rule, o.lambda_adaptation, setup.schedule.law)
    eq = equilibrium_points(loop, W, T, rep(M), with_gain(rep(P), rep(gain)))
    ok, A = eq.ok, eq.A
    if not complete:
        ok &= np.repeat(ok.reshape(n_d, n_p).all(axis=1), n_p)
    poles = np.full((W.size, A.shape[1]), np.nan + 0j)
    if ok.any():
        poles[ok] = eigvals_batched(np.ascontiguousarray(A[ok]))
    # the sampled observer from the continuous equilibria: each draw's true motor, its MTPA current at
    # each torque and the voltage that holds it under zero-order hold
    motors = rep(plant[:, :k].T).T  # (N, 4) R_s, L_d, L_q, psi_pm per point
    i_r = pmsm_steady_current(T, rep(M))
    sampled = sampled_loop("gradient", o.inductance_rule, o.lambda_adaptation, setup.schedule.law)
    zoh = pmsm_zoh_plant(motors, W, i_r, o.T_obs)
    y0 = np.where(ok[:, None], eq.x, np.nan)
    _, Jd = sampled_fixed_points(sampled, y0, W, zoh, rep(P), rep(gain))
    poles_d = discrete_poles(Jd, o.T_obs, sampled.n_y)[0]
    if not complete:
        bad = np.isnan(poles_d).all(axis=1).reshape(n_d, n_p).any(axis=1)
        poles_d[np.repeat(bad, n_p)] = np.nan
    return FluxLinearization(
        w=W,
        torque=T,
        poles=poles,
        poles_discrete=poles_d,
        T_s=o.T_obs,
        torque_name="T_e",
        theta_err=None if eq.y is None else np.where(ok, eq.y[:, 0], np.nan),
        theta_err_discrete=np.full(W.size, np.nan),
        law=gains.law,
    )
