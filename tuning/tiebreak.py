"""The tie-break of the shared pipeline: of the gains as well damped as the best (within TIE_TOL), keep
the smallest.

Maximizing the worst damping leaves directions the objective does not see: on a ridge (the worst point
does not move with a parameter) and wherever the worst damping saturates, gains far larger than
needed are exactly as good, and a tie-break by the faster slowest decay (the selection's) pushes
them to the box, where on one motor they lost the rotor position in a speed-step run the drive
file's gains rode through (docs/tuning.md "Tie-break"). So the pipeline is
lexicographic:

1. the best worst damping d* on the dense grid (global phase, NLP, dense selection: tuning/tune.py);
2. among gains that meet the same constraints and have dense worst damping >= d* - TIE_TOL, the
   smallest ``TuningModel.gain_size`` (the law's measure of its gains over the speed range, with
   ``gain_size_unit`` and ``gain_size_meaning`` for the summary).

A smaller gain generally decays slower, and a real pole creeping to the origin has damping 1: the
damping bound alone would not stop it. Stage 2 keeps the slowest decay at least KEEP_DECAY times
that of the gains stage 1 kept (and at least the tuning's floor).

Search (laws of up to search.MAX_PATTERN_PARAMETERS parameters): the stage-1 candidates and the
law's global grid that meet the stage-2 constraints on the optimization grid seed a batched
pattern search in the logarithms of the parameters that lowers the size while they keep meeting them;
its ends are checked on the dense grid (with the estimate-error scenarios). Where the smallest end
fails there, those dense points join the search's grid and it runs again (an exchange method, as the
NLP's); after EXCHANGE_ROUNDS the smallest end is pulled back along the segment to the stage-1 gains.
The result is never larger than the stage-1 gains and never below d* - TIE_TOL on the dense grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensorless.tuning import search
from sensorless.tuning.candidates import BOUNDED_SLACK, Candidates, lowest_decay, noise_margin
from sensorless.tuning.model import TuningModel, evaluate
from sensorless.tuning.result import Figures, figures
from sensorless.tuning.selection import TIE

TIE_TOL = TIE  # damping within this of the best is as good: the selection's tie (5e-4)
KEEP_DECAY = 0.5  # stage 2 keeps at least this fraction of stage 1's slowest decay (time constant x2)
N_SEEDS = 3  # pattern searches from the smallest grid-feasible candidates
STEP0, STEP_MIN = 0.5, 2e-3  # pattern steps in log(parameter): a factor 1.65 down to 0.2 %
N_LINE = 16  # points on the segment back to the stage-1 gains when an end fails on the dense grid
EXCHANGE_ROUNDS = 4  # searches, each on the grid plus the dense points where the last one failed
N_ADD = 8  # dense points added per round


@dataclass(frozen=True)
class Tie:
    """The kept gains, their dense figures, and what the tie-break did (``note``: the table's summary)."""

    theta: np.ndarray
    dense: Figures
    note: dict[str, Any]


@dataclass(frozen=True)
class Grids:
    """Where stage 2 is checked: the optimization grid (search), the dense grid (verification), the
    estimate-error scenarios (dense, stable with margin), the noise limits."""

    W: np.ndarray
    T: np.ndarray
    Wd: np.ndarray
    Td: np.ndarray
    errors: list[np.ndarray]  # estimate vectors of the error scenarios
    scale: float
    max_noise: np.ndarray | None
    robust_margin: float  # under errors: max Re <= -robust_margin * scale


def smallest_tie(
    model: TuningModel,
    theta1: np.ndarray,
    dense1: Figures,
    best: float,
    others: list[np.ndarray],
    grids: Grids,
    floor: float,
    candidates: Callable[[float, np.ndarray, np.ndarray], Candidates],
    say: Callable[[str], None],
    w_base: float,
) -> Tie:
    """Stage 2 (module docstring) from the stage-1 gains ``theta1`` (dense figures ``dense1``); ``best``
    is d*, ``others`` the other stage-1 candidates, ``candidates(floor, W, T)`` the conditions at the
    points (W, T) with that decay floor."""
    size = model.gain_size
    assert size is not None
    target = best - TIE_TOL
    floor2 = max(floor, KEEP_DECAY * float(np.min(dense1.decay)))
    pool = [np.asarray(theta1, float)[None], *(np.asarray(o, float)[None] for o in others)]
    if model.starts is not None:
        pool.append(np.asarray(model.starts(), float))
    thetas = np.unique(np.clip(np.vstack(pool), model.lower, model.upper), axis=0)
    W, T = grids.W, grids.T
    kept = None
    ends = np.zeros((0, model.n_theta))
    for _ in range(EXCHANGE_ROUNDS):
        cand = candidates(floor2, W, T)
        ok = _grid_ok(model, thetas, cand, grids, target)
        order = np.argsort(np.where(ok, size(thetas), np.inf), kind="stable")
        seeds = thetas[order[: min(N_SEEDS, int(ok.sum()))]]
        if seeds.size == 0:
            break
        ends = _pattern(model, seeds, cand, grids, target)
        ok, bad = _dense_ok(model, ends, grids, target, floor2)
        if ok.any():
            kept = ends[int(np.argmax(ok))]  # ends are sorted by size
            break
        if bad.size == 0:  # fails only under estimate errors: more points would not help
            break
        # exchange: the dense points where the smallest end fails join the search's grid
        W, T = np.concatenate([W, grids.Wd[bad]]), np.concatenate([T, grids.Td[bad]])
    if kept is None:
        kept = _pull_back(model, theta1, ends, grids, target, floor2)
    s1 = float(size(theta1[None])[0])
    s2 = float(size(kept[None])[0])
    moved = s2 < s1 * (1 - 1e-6)
    if not moved:
        kept, s2 = np.asarray(theta1, float), s1
    dense2 = figures(model, kept, grids.Wd, grids.Td, noise=model.noise is not None) if moved else dense1
    note = _note(model, theta1, dense1, s1, kept, dense2, s2, best, floor2, w_base, moved)
    say(note["text"])
    return Tie(kept, dense2, note)


def _grid_ok(model, thetas, cand, grids, target) -> np.ndarray:
    """(K,) the candidates meet stage 2's conditions on the optimization grid (estimate-error points,
    whose equilibria move with the gains, are left to the dense check)."""
    z, m, _ = search._margins(model, thetas, cand, grids.scale, grids.max_noise)
    return (m >= -search.FEASIBILITY_TOL) & (z >= target)


def _pattern(model, seeds, cand, grids, target) -> np.ndarray:
    """Batched pattern search from each seed: the poll point of smallest size that still meets the
    conditions on the optimization grid, else half the step. Returns the ends (one per seed)."""
    n = model.n_theta
    lo = np.log(np.maximum(model.lower, 1e-9 * model.typical))
    hi = np.log(model.upper)
    D = search.poll_directions(n)
    u = np.clip(np.log(np.maximum(seeds, 1e-9 * model.typical)), lo, hi)
    f = model.gain_size(np.exp(u))
    h = np.full(u.shape[0], STEP0)
    for _ in range(300):
        act = np.flatnonzero(h >= STEP_MIN)
        if act.size == 0:
            break
        polls = np.clip(u[act, None, :] + h[act, None, None] * D[None], lo, hi).reshape(-1, n)
        th = np.exp(polls)
        # only a poll smaller than its seed's point can be the move: the grid (the dear part) judges those
        size = model.gain_size(th)
        small = size < np.repeat(f[act], D.shape[0]) * (1 - 1e-9)
        ok = np.zeros(size.size, bool)
        if small.any():
            ok[small] = _grid_ok(model, th[small], cand, grids, target)
        fp = np.where(ok, size, np.inf).reshape(act.size, -1)
        k = np.argmin(fp, axis=1)
        better = fp[np.arange(act.size), k] < f[act] * (1 - 1e-9)
        u[act[better]] = polls.reshape(act.size, -1, n)[better, k[better]]
        f[act[better]] = fp[better, k[better]]
        h[act[~better]] /= 2
    return np.exp(u[np.argsort(f, kind="stable")])


def _dense_ok(model, thetas, grids, target, floor2) -> tuple[np.ndarray, np.ndarray]:
    """(K,) the candidates meet stage 2's conditions on the dense grid, and under every estimate-error
    scenario they are stable with the NLP's margin; and the dense points where the first one fails
    (nominal estimates, at most N_ADD, worst first)."""
    K = thetas.shape[0]
    N = grids.Wd.size
    P = model.make_points(grids.Wd, grids.Td, model.nominal_estimate)
    e = evaluate(model, np.repeat(thetas, N, axis=0).T, np.tile(P, (1, K)), noise=grids.max_noise is not None)
    z = np.where(np.isfinite(e.damping), e.damping, -np.inf).reshape(K, N)
    dec = np.where(np.isfinite(e.decay), e.decay, -np.inf).reshape(K, N)
    margin = np.minimum(z - target, (dec - lowest_decay(floor2, grids.scale)) / grids.scale)
    margin = np.where(dec > 0, margin, np.minimum(margin, -1.0))
    if e.bounded is not None:  # the family's bounded figures (tuning/model.py)
        margin = np.minimum(margin, e.bounded.reshape(K, N) + BOUNDED_SLACK)
    if grids.max_noise is not None:
        margin = np.minimum(margin, noise_margin(e.noise.reshape(K, N, -1), grids.max_noise))
    ok = margin.min(axis=1) >= 0
    bad = np.argsort(margin[0], kind="stable")
    bad = bad[margin[0, bad] < 0][:N_ADD]
    for est in grids.errors:
        Pe = model.make_points(grids.Wd, grids.Td, est)
        ee = evaluate(model, np.repeat(thetas, N, axis=0).T, np.tile(Pe, (1, K)))
        de = np.where(np.isfinite(ee.decay), ee.decay, -np.inf).reshape(K, N).min(axis=1)
        ok &= de >= grids.robust_margin * grids.scale
    return ok, bad


def _pull_back(model, theta1, ends, grids, target, floor2) -> np.ndarray:
    """The smallest point of the segment (in log parameters) from the stage-1 gains to the smallest
    end that meets the conditions on the dense grid; the stage-1 gains if none does."""
    if ends.size == 0:
        return np.asarray(theta1, float)
    u1, ue = np.log(np.maximum(theta1, 1e-9 * model.typical)), np.log(ends[0])
    s = np.linspace(0.0, 1.0, N_LINE + 1)[1:][::-1]
    line = np.clip(np.exp(u1[None] + s[:, None] * (ue - u1)[None]), model.lower, model.upper)
    ok, _ = _dense_ok(model, line, grids, target, floor2)
    return line[int(np.argmax(ok))] if ok.any() else np.asarray(theta1, float)


def _fmt(model: TuningModel, theta: np.ndarray, w_base: float) -> list[str]:
    return [
        f"{n} {v / w_base:.4g} p.u." if u == "rad/s" else f"{n} {v:.4g} {u}"
        for n, u, v in zip(model.names, model.units, theta, strict=True)
    ]


def _note(model, theta1, dense1, s1, theta2, dense2, s2, best, floor2, w_base, moved) -> dict[str, Any]:
    z1, z2 = dense1.worst_damping(), dense2.worst_damping()
    d1, d2 = float(np.min(dense1.decay)), float(np.min(dense2.decay))
    head = (
        f"tie-break (of the gains within {TIE_TOL:g} of the best worst damping {best:.4f}, decaying at "
        f">= {floor2:.4g} 1/s, the smallest; gain size = {model.gain_size_meaning}): "
    )
    if moved:
        a, b = _fmt(model, theta1, w_base), _fmt(model, theta2, w_base)
        changes = ", ".join(f"{x} -> {y.split(' ', 1)[1]}" for x, y in zip(a, b, strict=True))
        text = (
            head + f"moved the gains: size {s1:.4g} -> {s2:.4g}; {changes}; worst damping {z1:.4f} -> "
            f"{z2:.4f} ({z2 - z1:+.4f}), slowest decay {d1:.4g} -> {d2:.4g} 1/s"
        )
    else:
        text = head + f"the best gains are the smallest found (size {s1:.4g})"
    return {
        "tolerance": TIE_TOL,
        "decay_keep": KEEP_DECAY,
        "floor_1_s": floor2,
        "best_worst_damping": best,
        "moved": moved,
        "before": {
            "parameters": {n: float(v) for n, v in zip(model.names, theta1, strict=True)},
            "worst_damping": z1,
            "min_decay_rate": d1,
            "gain_size": s1,
        },
        "after": {
            "parameters": {n: float(v) for n, v in zip(model.names, theta2, strict=True)},
            "worst_damping": z2,
            "min_decay_rate": d2,
            "gain_size": s2,
        },
        "damping_change": z2 - z1,
        "text": text,
    }
