"""The conditions of the tuning NLP as data: the candidate points (damping, stability, noise) and their
numeric margins at given gains, by eigenvalues (the exchange method's check, tuning/nlp.py, and the
global phase's, tuning/search.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning.model import TuningModel, evaluate

DAMPING, STABILITY, NOISE = 1, 0, 2  # a candidate's condition
# Margins (relative to the pole scale) down to -this count as met: the NLP's tolerance. The one rule of
# every step that judges a decay floor (global phase, selection, certificate, tie-break, bound): with a
# tighter one in the selection than in the global phase, the schedule's best start on prius (worst damping
# 0.4519, slowest decay 4e-4 1/s under the seed's 2.0889 1/s, the global phase's tolerance 8.8e-4 1/s) was
# refused for the seed's 0.0998.
FEASIBILITY_TOL = 1e-7
# A family's bounded figures (tuning/model.py ``TuningModel.bounded``) are held exactly at the points the
# NLP and the global phase see; between them, on the dense grid, up to this much above (relative): the NLP
# binds them at its grid points, and an optimum tight there ran 1-3 % above between them (ind5k5's schedule
# with its angle lag under acceleration)
BOUNDED_SLACK = 0.05


@dataclass(frozen=True)
class Candidates:
    """The finite set of conditions: point data (n_p, N), condition (1: damping >= t, 0: Re <= -sigma,
    2: noise figure <= the limit), shift sigma [1/s], and a label per point for messages."""

    P: np.ndarray
    condition: np.ndarray
    sigma: np.ndarray
    labels: tuple[str, ...]

    @property
    def size(self) -> int:
        return self.P.shape[1]


def lowest_decay(floor: float, scale: float) -> float:
    """The slowest decay rate [1/s] that meets the decay floor ``floor`` [1/s] (FEASIBILITY_TOL x the
    pole scale ``scale`` below it); 0 without a floor (then stable means a decay above 0)."""
    return max(floor - FEASIBILITY_TOL * scale, 0.0) if floor > 0 else 0.0


def meets_floor(decay: np.ndarray | float, floor: float, scale: float) -> np.ndarray:
    """Whether the decay rates ``decay`` [1/s] meet the decay floor ``floor`` (lowest_decay) and are
    stable (> 0; NaN: no equilibrium, not met)."""
    d = np.asarray(decay, float)
    with np.errstate(invalid="ignore"):
        return (d >= lowest_decay(floor, scale)) & (d > 0)


def fixed_points(model: TuningModel, P: np.ndarray) -> np.ndarray:
    """(N,) bool: the point's equilibrium does not move with the gains (it is data for the NLP)."""
    if model.fixed_equilibrium is None:
        return np.zeros(P.shape[1], bool)
    return np.asarray(model.fixed_equilibrium(P), bool)


def margins(
    model: TuningModel,
    theta: np.ndarray,
    cand: Candidates,
    t: float,
    scale: float,
    max_noise: np.ndarray | None = None,
) -> np.ndarray:
    """Numeric margin of every candidate at theta by eigenvalues (>= 0: satisfied): damping - t for
    damping points (and the model's bounded figures' 1 - |figure|/bound there, the smaller),
    (-max Re - sigma)/scale for stability points, min over the limited outputs of
    1 - noise/limit for noise points; -inf where no equilibrium."""
    nonoise = cand.condition != NOISE
    m = np.full(cand.size, -np.inf)
    e = evaluate(model, theta, cand.P[:, nonoise])
    p = e.poles
    damp = cand.condition[nonoise] == DAMPING
    m[nonoise] = np.where(damp, worst_damping(p) - t, (-max_real(p) - cand.sigma[nonoise]) / scale)
    if e.bounded is not None:  # the family's bounded figures, held at the damping points (model.py)
        m[nonoise] = np.where(damp, np.minimum(m[nonoise], e.bounded), m[nonoise])
    if (~nonoise).any():
        en = evaluate(model, theta, cand.P[:, ~nonoise], noise=True)
        m[~nonoise] = noise_margin(en.noise, max_noise)
    return np.where(np.isfinite(m), m, -np.inf)


def noise_margin(noise: np.ndarray, max_noise: np.ndarray | None) -> np.ndarray:
    """min over the limited outputs (the last axis of ``noise``) of 1 - noise/limit (inf: no limit); -inf
    where not finite."""
    if max_noise is None:
        return np.full(noise.shape[:-1], np.inf)
    lim = np.asarray(max_noise, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(np.isfinite(lim), 1.0 - noise / lim, np.inf)
    r = np.where(np.isnan(r), -np.inf, r)
    return r.min(axis=-1)
