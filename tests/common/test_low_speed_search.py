"""The low-speed search's shortcuts (design/low_speed_search.py ``search``) against the full-grid search.

``search`` walks the grid from the top speed down and leaves a torque at its first failure below its
first pass, and, given a bound, once its w_min is shown to be at or below it. Here a synthetic analysis
(damping a function of speed and torque with several failing bands, bias NaN in some blocks) is searched
both ways: the reference evaluates every grid point (the search as it was before the shortcuts, typed
here from its definition), so both must give the same w_min, limiting criterion and criteria applied;
with a bound, the max and the argmax over (reference, bounded search) equal those of the references.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from sensorless.design.low_speed_search import CRITERIA, failing, search

CRIT = {"damping": 0.5, "decay": 0.0, "bias": 0.5, "noise": 0.2}


@dataclass(frozen=True)
class Synthetic:
    """Damping from a seeded pattern of bands in (log w, T); bias NaN below ``nan_below`` (negative: NaN
    above -nan_below, given only at low speed, which the top-down walk may never reach)."""

    w: np.ndarray
    T: np.ndarray
    seed: int
    nan_below: float

    @property
    def worst_damping(self) -> np.ndarray:
        x, t = np.log10(self.w), self.T
        c = np.random.default_rng(self.seed).uniform(-3, 0, 3)
        z = 0.55 + 0.4 * np.tanh(4 * (x - c[0] - 0.3 * t))
        for cc in c[1:]:  # failing bands above the edge
            z = z - 0.3 * np.exp(-(((x - cc) / 0.08) ** 2)) * (1 + 0.5 * t)
        return z.ravel()

    def low_speed_decay(self) -> np.ndarray:
        return np.ones(self.w.size)

    def angle_bias(self) -> np.ndarray:
        b = 0.01 / self.w
        out = self.w > -self.nan_below if self.nan_below < 0 else self.w < self.nan_below
        return np.where(out, np.nan, b).ravel()

    def angle_noise(self) -> None:
        return None


def analysis(seed: int, nan_below: float):
    calls = []

    def analyse(w, T):
        W, TT = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(w, T))
        calls.append(W.size)
        return Synthetic(W, TT, seed, nan_below)

    return analyse, calls


def reference(analyse, w, T, bisections):
    """Every grid point, then bisection of the highest failing interval below the highest pass."""
    first, given = failing(analyse(w[:, None], T[None, :]), CRIT)
    first = first.reshape(w.size, T.size)
    bad = first >= 0
    idx = np.arange(w.size)[:, None]
    k_pass = np.where(~bad, idx, -1).max(axis=0)
    k = np.where(bad & (idx < k_pass), idx, -1).max(axis=0)
    w_min, cause = np.zeros(T.size), np.full(T.size, -1)
    for j in range(T.size):
        if k_pass[j] < 0:
            w_min[j], cause[j] = w[-1], first[-1, j]
        elif k[j] >= 0:
            lo, hi, c = np.log(w[k[j]]), np.log(w[k[j] + 1]), first[k[j], j]
            for _ in range(bisections):
                mid = 0.5 * (lo + hi)
                f, _ = failing(analyse(np.exp(np.array([mid])), T[j : j + 1]), CRIT)
                lo, hi, c = (mid, hi, f[0]) if f[0] >= 0 else (lo, mid, c)
            w_min[j], cause[j] = np.exp(hi), c
    return w_min, cause, set(given)


W = np.logspace(-3, 0, 16)
TQ = np.linspace(-1, 1, 5)


@pytest.mark.parametrize("seed", range(12))
def test_top_down_search_is_the_full_grid_search(seed):
    nan_below = (0.0, 0.5, -0.003)[seed % 3]  # bias given everywhere, at high speed, at low speed only
    ref = reference(analysis(seed, nan_below)[0], W, TQ, 6)
    analyse, calls = analysis(seed, nan_below)
    w_min, cause, given = search(analyse, W, TQ, CRIT, 6)
    assert np.array_equal(w_min, ref[0]) and np.array_equal(cause, ref[1]) and given == ref[2]
    assert given <= set(CRITERIA)
    assert sum(calls) <= W.size * TQ.size + 6 * TQ.size  # never more points than the full grid's


@pytest.mark.parametrize("seed", range(12))
def test_a_bounded_search_keeps_the_max_and_what_limits_it(seed):
    base = reference(analysis(seed + 100, 0.0)[0], W, TQ, 6)
    full = reference(analysis(seed, 0.0)[0], W, TQ, 6)
    w_min, cause, _ = search(analysis(seed, 0.0)[0], W, TQ, CRIT, 6, bound=base[0])
    got, want = np.stack([base[0], w_min]), np.stack([base[0], full[0]])
    assert np.array_equal(got.max(axis=0), want.max(axis=0))
    worst = np.argmax(want, axis=0)
    assert np.array_equal(np.argmax(got, axis=0), worst)
    assert np.array_equal(cause[worst == 1], full[1][worst == 1])
