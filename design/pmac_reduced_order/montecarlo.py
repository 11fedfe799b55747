"""Monte-Carlo draws of the reduced-order observer drive (design/montecarlo.py): the spreadable
parameters, every draw's linearized observer in one batched evaluation, and a perturbed drive.

The true motor's R, L, J and EMF amplitude Phi (the fundamental; its harmonics scaled with it) and the
observer's estimates of the same. Each draw is the continuous error dynamics of De Angelo et al. (2006),
eq. (16) with (13)-(22) in rotor coordinates (linearize.py ``continuous_poles``: eigenvalues, or Floquet
exponents with EMF harmonics) at every operating point, in one mapped call over draws x points whose
motor and observer vectors are the draw's. The sampled observer's analysis (its steady orbit simulated
per point) stays the report's and the tuner's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.linearization import Linearization
from sensorless.design.montecarlo import Uncertain
from sensorless.design.pmac_reduced_order.linearize import continuous_poles

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

NAMES = ("R", "L", "J", "Phi")
UNITS = {"R": "ohm", "L": "H", "J": "kg m^2", "Phi": "V s"}
# the plant's typical spread (1 sigma) a run assumes without --spread: the winding's resistance with its
# temperature, inductance tolerance, the load's inertia, the magnets' EMF
TYPICAL = {"R": 0.10, "L": 0.10, "J": 0.30, "Phi": 0.05}


def _values(record: Any) -> dict[str, float]:
    return {"R": record.R, "L": record.L, "J": record.J, "Phi": record.Phi[0]}


def parameters(drive: PmacDrive) -> tuple[Uncertain, ...]:
    """R, L, J, Phi of the motor with the observer's estimates of each (all enter its linearization:
    J through the load-torque estimate)."""
    m, e = _values(drive.motor), _values(drive.estimate)
    return tuple(Uncertain(k, m[k], e[k], UNITS[k], True, TYPICAL[k]) for k in NAMES)


def _replaced(record: Any, values: Mapping[str, float]) -> Any:
    new: dict[str, float | tuple[float, ...]] = {k: float(v) for k, v in values.items() if k != "Phi"}
    if "Phi" in values:  # the EMF's harmonics scale with its fundamental
        r = float(values["Phi"]) / record.Phi[0]
        new["Phi"] = tuple(x * r for x in record.Phi)
    return dataclasses.replace(record, **new)


def envelope_points(drive: PmacDrive, gains: GainSet | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Its drive file's [envelope] (design/envelope.py, the grid its tuner reads): electrical speeds,
    sorted and distinct, x load torques, sorted and distinct."""
    return drive.envelope.grid()


def perturbed(drive: PmacDrive, plant: Mapping[str, float], estimate: Mapping[str, float]) -> PmacDrive:
    return dataclasses.replace(
        drive, motor=_replaced(drive.motor, plant), estimate=_replaced(drive.estimate, estimate)
    )


def linearize_draws(
    drive: PmacDrive,
    gains: GainSet,
    plant: np.ndarray,
    estimate: np.ndarray,
    w: np.ndarray,
    torque: np.ndarray,
    complete: bool = True,
) -> Linearization:
    """Every draw (rows, columns in :func:`parameters`' order) at every point, draw-major, in one mapped
    evaluation; ``torque`` is the load T_L. The Jacobian is taken on the exact-estimate orbit (as the
    family's continuous analysis), so a draw always has its poles; ``complete`` has nothing to stop."""
    w, torque = np.asarray(w, float).ravel(), np.asarray(torque, float).ravel()
    n_d, n_p = plant.shape[0], w.size
    g = gains.values
    over = {"g": g["g"], "Gamma": g["Gamma"]}
    motor = drive.motor.vector()
    params = drive.observer_params(**over)
    m_cols = np.repeat(motor[:, None], n_d, axis=1)
    p_cols = np.repeat(params[:, None], n_d, axis=1)
    # vector layouts (schema.py PmacMotor.vector, PmacDrive.observer_params): R, L, J first; Phi last
    n_h = len(drive.motor.Phi)
    for c, row in ((0, 0), (1, 1), (2, 2)):
        m_cols[row] = plant[:, c]
        p_cols[row] = estimate[:, c]
    m_cols[-n_h:] = np.asarray(drive.motor.Phi)[:, None] * (plant[:, 3] / drive.motor.Phi[0])[None, :]
    n_e = len(drive.estimate.Phi)
    p_cols[-n_e:] = (
        np.asarray(drive.estimate.Phi)[:, None] * (estimate[:, 3] / drive.estimate.Phi[0])[None, :]
    )
    rep = lambda a: np.repeat(a, n_p, axis=1)  # noqa: E731  (draw-major columns)
    W, T = np.tile(w, n_d), np.tile(torque, n_d)
    poles = continuous_poles(drive, W, T, columns=(rep(m_cols), rep(p_cols)), **over)
    return Linearization(
        w=W, torque=T, poles=poles, poles_discrete=None, T_s=drive.control.T_s, torque_name="T_L"
    )
