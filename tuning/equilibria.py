"""The equilibria of operating points where they do not move with the gains, solved once per point.

Where a model's equilibrium does not move with the gains (``TuningModel.fixed_equilibrium``: the closed
form at exact estimates), a point's equilibrium is the same whatever the gains or the batch it is
solved in: the closed form at exact estimates, on CasADi's VM or compiled alike
(tests/ipmsm_adaptive/test_tune_reuse_bits.py). So each model keeps a table of the points it has solved
there, and :func:`fixed_equilibria` looks a batch's points up in it, solving only those it has not
seen, once each (at the drive file's gains, which they do not depend on). The tuner evaluates the same
points again and again: a tune the same envelope and dense grids for hundreds of candidate gains (a
batch of K candidates on the same points, ``np.tile``, solves them once), the pointwise bound
(tuning/bound.py) thousands of gains at each of a few hundred points, in ever-changing subsets of its
speeds x torques (a fifth of its evaluation's CPU went to the same equilibria again).

Only those points: elsewhere (estimate errors) the equilibrium is solved for and moves with the gains,
and :func:`tuning.model.evaluate` leaves it to the model's ``equilibrium``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.memo import OwnedMemo

if TYPE_CHECKING:  # typed by name only
    from sensorless.tuning.model import TuningModel

# per model: the points solved (their bytes as one item each, sorted) and their equilibria (n_x, K) in
# that order; replaced whole when it grows, never changed in place (a threaded scheduler may tune in
# several threads). Up to TABLE_POINTS points a model (6 rows and 4 states: 10 MB)
_TABLES: OwnedMemo[tuple[np.ndarray, np.ndarray]] = OwnedMemo(32)
TABLE_POINTS = 1 << 17


def _keys(P: np.ndarray) -> np.ndarray:
    """(N,) the columns of P as single items of their bytes (np.void): sortable, comparable whole."""
    cols = np.ascontiguousarray(P.T, dtype=float)
    return cols.view(np.dtype((np.void, cols.shape[1] * cols.itemsize))).ravel()


def fixed_equilibria(model: TuningModel, P: np.ndarray) -> np.ndarray:
    """(n_x, N) the equilibria at the points P, none of which moves with the gains (``fixed_equilibrium``
    true at all of them): from the model's table, the points it has not seen solved and added to it."""
    q = _keys(P)
    kept = _TABLES.get(model, b"")
    keys, x = kept if kept is not None else (q[:0], np.zeros((model.n_x, 0)))
    at = np.searchsorted(keys, q)
    found = np.zeros(q.size, bool)
    inside = at < keys.size
    found[inside] = keys[at[inside]] == q[inside]
    if found.all():
        return x[:, at]
    new, first = np.unique(q[~found], return_index=True)
    solved = np.asarray(model.equilibrium(model.theta0, P[:, np.flatnonzero(~found)[first]]), float)
    keys, x = np.concatenate([keys, new]), np.concatenate([x, solved], axis=1)
    order = np.argsort(keys, kind="stable")
    keys, x = keys[order], x[:, order]
    if keys.size <= TABLE_POINTS:
        _TABLES.put(model, b"", (keys, x))
    return x[:, np.searchsorted(keys, q)]
