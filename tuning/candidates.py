"""The conditions of the tuning NLP as data: the candidate points (damping, stability, noise) and their
numeric margins at given gains, by eigenvalues (the exchange method's check, tuning/nlp.py, and the
global phase's, tuning/search.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning.model import TuningModel, evaluate

DAMPING, STABILITY, NOISE = 1, 0, 2  # a candidate's condition


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
    damping points, (-max Re - sigma)/scale for stability points, min over the limited outputs of
    1 - noise/limit for noise points; -inf where no equilibrium."""
    nonoise = cand.condition != NOISE
    m = np.full(cand.size, -np.inf)
    e = evaluate(model, theta, cand.P[:, nonoise])
    p = e.poles
    m[nonoise] = np.where(
        cand.condition[nonoise] == DAMPING, worst_damping(p) - t, (-max_real(p) - cand.sigma[nonoise]) / scale
    )
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
