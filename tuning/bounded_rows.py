"""The NLP's rows of a family's bounded figures (``TuningModel.bounded``): each slot's bounds and the rows'
lower bounds, beside the sector conditions of tuning/slots.py.

A damping slot at a point where the drive file's gains are stable holds |figure| <= its bound there
(tuning/model.py ``bounded_reference``: the drive file's gains' figure, e.g. their angle lag under
acceleration); every other slot (a decay-floor or estimate-error slot, an unused one, a point where the
drive file's gains are unstable) has the rows switched off (lower bound -inf) and a bound of 1.
"""

from __future__ import annotations

import numpy as np
from sensorless.tuning.candidates import DAMPING
from sensorless.tuning.model import TuningModel, bounded_reference
from sensorless.tuning.slots import n_bounded


def slot_bounds(
    model: TuningModel, P: np.ndarray, condition: np.ndarray, used: int
) -> tuple[np.ndarray, np.ndarray]:
    """(bounds (M, k), lower bounds of the slots' 2k rows (M, 2k)) for the M slots at the points P
    (n_p, M) of ``condition`` (M,), of which the first ``used`` are on."""
    M, k = P.shape[1], n_bounded(model)
    if k == 0:
        return np.zeros((M, 0)), np.zeros((M, 0))
    ref = bounded_reference(model, P)
    on = np.isfinite(ref) & (ref > 0) & (condition == DAMPING)[:, None]
    on[used:] = False
    bounds = np.where(on, ref, 1.0)
    lower = np.where(np.hstack([on, on]), 0.0, -np.inf)
    return bounds, lower
