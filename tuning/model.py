"""What the shared NLP needs from a tunable gain family on a drive: the TuningModel contract.

A tunable (law16, schedule, ...; tuning/family.py) on a drive supplies one :class:`TuningModel`. The
generic NLP (tuning/nlp.py) and the verification only see this: a parameter vector theta with
bounds; ``local``, what the closed loop at one operating point needs of theta (phi: e.g. the gains
and their slopes there), so that per-point derivatives do not grow with the size of theta; the
linearized closed loop as a CasADi Function of (phi, state, operating point) built from the analysis
model in symbolic/ (never a second copy of the equations); numeric equilibria; and the gains to
write into the table. A tunable's ``build`` returns one (tuning/family.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np


@dataclass(frozen=True, eq=False)  # identity-hashed: Functions are cached per model
class TuningModel:
    """A tunable family on one drive.

    Operating points are columns of a point matrix (rows: ``point_names``); each point carries the
    true speed and torque and the *estimated* parameters the observer uses there, so parameter-error
    scenarios are just more points.
    """

    family: str
    names: tuple[str, ...]  # tunable parameters, in theta order
    units: tuple[str, ...]
    theta0: np.ndarray  # the drive file's gains: the baseline (and the NLP's start if no ``start``)
    lower: np.ndarray  # box bounds of theta
    upper: np.ndarray
    typical: np.ndarray  # magnitudes that scale theta to O(1) for the NLP
    local: ca.Function  # (theta, point) -> phi: what the closed loop at the point needs of theta
    phi_typical: np.ndarray  # magnitudes of phi
    linearization: ca.Function  # (phi, x, point) -> (A [1/s], x_dot): the analysis model
    x_typical: np.ndarray  # magnitudes of the states (scale of the equilibrium unknowns)
    point_names: tuple[str, ...]
    make_points: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (w_m, T_e, est) -> P
    equilibrium: Callable[[np.ndarray, np.ndarray], np.ndarray]  # (theta, P) -> x0 (n_x, N); NaN: none
    regularizer: Callable[[ca.SX], ca.SX] | None  # dimensionless penalty of theta (x smoothing); None: none
    table_gains: Callable[[np.ndarray], dict[str, Any]]  # the gain table's "gains" entry
    point_gains: Callable[[np.ndarray, np.ndarray], dict[str, np.ndarray]]  # (theta, w_hat) -> columns
    nominal_estimate: np.ndarray  # the drive's own estimates (no error)
    estimate_names: tuple[str, ...]  # names of the estimate entries of a point, for error scenarios
    start: np.ndarray | None = None  # NLP start (e.g. the seed family's optimum); None: theta0
    start_label: str = ""  # what ``start`` is, for messages and the table's summary
    hessian: str = "exact"  # IPOPT hessian_approximation: "exact" or "limited-memory" (L-BFGS)

    @property
    def n_theta(self) -> int:
        """Number of tunable parameters."""
        return len(self.names)

    @property
    def n_x(self) -> int:
        """States of the linearized closed loop."""
        return int(self.linearization.size1_in(1))


def poles(model: TuningModel, theta: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(poles (N, n) complex, x0 (n_x, N)) of the linearized closed loop at the points P, by the same
    Function the NLP differentiates; NaN rows where no equilibrium exists."""
    N = P.shape[1]
    x0 = model.equilibrium(theta, P)
    ok = np.isfinite(x0).all(axis=0)
    n = model.n_x
    out = np.full((N, n), np.nan + 0j)
    if ok.any():
        xs = np.where(ok, x0, 0.0)
        phi = model.local.map(N)(theta, P)
        A = np.asarray(model.linearization.map(N)(phi, xs, P)[0]).reshape(n, N, n).transpose(1, 0, 2)
        good = ok & np.isfinite(A).all(axis=(1, 2))
        out[good] = np.linalg.eigvals(A[good])
    return out, x0
