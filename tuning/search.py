"""The global phase of the shared pipeline: gains that meet the constraints everywhere, before the NLP.

The max-min NLP (tuning/nlp.py) is local: IPOPT starts from one point, and where the drive file's gains
are unstable it may find no feasible gains at all, or stop in a poor local optimum. The global phase
evaluates many candidate parameter vectors at once (the law's ``starts``: a log grid of its
parameters, plus the drive file's gains and any start of its own) on every envelope point, in one
batched call of the compiled linearization (tuning/model.py ``evaluate``), and ranks them:

1. candidates that meet every constraint (decay floor, stability, noise limit) first, by their worst
   damping;
2. the others by their worst constraint margin (the slowest decay against the floor, relative to
   the problem's pole scale, or the noise against its limit).

If no candidate is feasible, the worst margin is maximized from the best few by a batched pattern
search in the scaled parameters (laws with a few parameters); with a noise limit, the best
feasible ones are also refined by the worst damping (the noise-constrained NLP is multimodal). The
NLP then starts from the best distinct feasible candidates. If none is found, the caller reports the
envelope as infeasible only with evidence: the envelope speeds where no gain at all (the pointwise
model, tuning/bound.py) meets the constraints.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from sensorless.design.batch import JIT_MIN_POINTS
from sensorless.design.memo import OwnedMemo
from sensorless.design.poles import batched_path, charpoly_ready, charpoly_settled, max_real, worst_damping
from sensorless.tuning.candidates import (
    DAMPING,
    FEASIBILITY_TOL,
    NOISE,
    Candidates,
    fixed_points,
    noise_margin,
)
from sensorless.tuning.model import TuningModel, evaluate

MAX_PATTERN_PARAMETERS = 4  # the margin search runs for laws with at most this many parameters


@dataclass(frozen=True)
class Ranked:
    """Candidates of the global phase, best first."""

    thetas: np.ndarray  # (K, n_theta)
    feasible: np.ndarray  # (K,) bool
    damping: np.ndarray  # (K,) worst damping over the envelope's damping points
    margin: np.ndarray  # (K,) worst constraint margin (>= 0: feasible)
    worst_point: np.ndarray  # (K,) index of the candidate point with the worst margin
    evaluated: int  # candidates evaluated

    def starts(self, k: int, typical: np.ndarray, distinct: float = 0.25) -> list[np.ndarray]:
        """Up to k feasible candidates, best first, at least ``distinct`` typical magnitudes apart."""
        out: list[np.ndarray] = []
        for th, ok in zip(self.thetas, self.feasible, strict=True):
            if not ok:
                break
            if all(np.max(np.abs(th - o) / typical) > distinct for o in out):
                out.append(th)
            if len(out) == k:
                break
        return out


def poll_directions(n: int) -> np.ndarray:
    """Poll directions of the batched pattern searches (here and tuning/tiebreak.py), unit length: the
    axes (all +, then all -), then for each pair of axes its four diagonals."""
    eye = np.eye(n)
    D = [eye, -eye]
    for i in range(n):
        for j in range(i + 1, n):
            D += [np.array([(eye[i] * a + eye[j] * b) / np.sqrt(2) for a in (1, -1) for b in (1, -1)])]
    return np.vstack(D)


def _margins(
    model: TuningModel, thetas: np.ndarray, cand: Candidates, scale: float, max_noise: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each theta (K, n): worst damping (K,), worst constraint margin (K,), its point (K,).

    Only the points whose equilibrium does not move with the gains are evaluated (the others, e.g.
    estimate-error scenarios, are left to the NLP)."""
    K = thetas.shape[0]
    fixed = fixed_points(model, cand.P)
    sel = np.flatnonzero(fixed)
    cols = sel[cand.condition[sel] != NOISE]
    # the damping and stability points share their point data: evaluate each distinct point once
    Pu, inv = np.unique(cand.P[:, cols], axis=1, return_inverse=True)
    N = Pu.shape[1]
    p, bounded = _poles(model, thetas, Pu)
    z = worst_damping(p.reshape(K * N, -1)).reshape(K, N)[:, inv]
    mr = max_real(p.reshape(K * N, -1)).reshape(K, N)[:, inv]
    condition, sigma = cand.condition[cols], cand.sigma[cols]
    m = np.full((K, cand.size), np.inf)
    damp = condition == DAMPING
    # damping points: stable (Re < 0) required; stability points: Re <= -sigma
    m[:, cols[damp]] = np.where(np.isfinite(mr[:, damp]), -mr[:, damp] / scale - 1e-9, -np.inf)
    if bounded is not None:  # the family's bounded figures (tuning/model.py), held at the damping points
        bm = bounded[:, inv]
        m[:, cols[damp]] = np.minimum(m[:, cols[damp]], bm[:, damp])
    m[:, cols[~damp]] = np.where(np.isfinite(mr[:, ~damp]), (-mr[:, ~damp] - sigma[~damp]) / scale, -np.inf)
    ncols = sel[cand.condition[sel] == NOISE]
    if ncols.size and max_noise is not None:
        Pn = cand.P[:, ncols]
        en = evaluate(model, np.repeat(thetas, ncols.size, axis=0).T, np.tile(Pn, (1, K)), noise=True)
        m[:, ncols] = noise_margin(en.noise, max_noise).reshape(K, ncols.size)
    zd = np.where(np.isfinite(z[:, damp]), z[:, damp], -np.inf)
    worst_z = zd.min(axis=1) if damp.any() else np.zeros(K)
    k = np.argmin(m, axis=1)
    return worst_z, m[np.arange(K), k], k


# _poles' rows, per model and distinct points: each candidate's (poles (N, n), bounded margins (N,) or
# None), keyed on its bytes. The tie-break (tuning/tiebreak.py) starts from the global phase's candidates
# on the same points (20 400 of its 33 200 points on the README servo's seed law: 0.17 s CPU; 0.25 s on
# the traction test motor's)
_ROWS: OwnedMemo[dict[bytes, tuple[np.ndarray, np.ndarray | None]]] = OwnedMemo(4)
ROWS_POINTS = 100_000  # candidates x points kept per model and points (6.4 MB of poles)


def _poles(model: TuningModel, thetas: np.ndarray, Pu: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(K, N, n) the poles and (K, N) the bounded margins (None: the model has no bounded figures) of
    each theta (K, n_theta) at the points Pu (whose equilibria do not move with the gains), as one batch
    gives them. A row kept from an earlier batch is reused where it has the bits this batch would give
    it: computed by the code every later batch runs (a batch of JIT_MIN_POINTS points at least: design/
    batch.py's compiled library; and the eigenvalues' too: design/poles.py ``charpoly_settled``), on the
    eigenvalue path (design/poles.py ``batched_path``) this batch takes."""
    K, N, n = thetas.shape[0], Pu.shape[1], model.n_x
    key = repr(Pu.shape).encode() + Pu.tobytes()
    rows = _ROWS.get(model, key)
    names = [th.tobytes() for th in thetas]
    miss = [k for k, b in enumerate(names) if rows is None or b not in rows]

    def batch(ks: list[int]) -> tuple[np.ndarray, np.ndarray | None, int]:
        th = thetas[ks]
        e = evaluate(model, np.repeat(th, N, axis=0).T, np.tile(Pu, (1, len(ks))))
        p = e.poles.reshape(len(ks), N, -1)
        good = int(np.isfinite(p).all(axis=2).sum())  # the matrices whose eigenvalues were computed
        return p, None if e.bounded is None else e.bounded.reshape(len(ks), N), good

    if rows is None or len(miss) == K:
        ready = charpoly_ready(n)
        p, bm, good = batch(list(range(K)))
        if K * N >= JIT_MIN_POINTS and batched_path(n, good) and charpoly_settled(n, good, ready):
            p.flags.writeable = False  # (its rows are kept)
            if bm is not None:
                bm.flags.writeable = False
            keep = rows if rows is not None and (len(rows) + K) * N <= ROWS_POINTS else {}
            if K * N > ROWS_POINTS:
                return p, bm
            keep.update((b, (p[k], None if bm is None else bm[k])) for k, b in enumerate(names))
            _ROWS.put(model, key, keep)
        return p, bm
    new = set(miss)
    kept_good = sum(
        int(np.isfinite(rows[b][0]).all(axis=1).sum()) for k, b in enumerate(names) if k not in new
    )
    pm, bm, good = batch(miss) if miss else (None, None, 0)
    if not batched_path(n, kept_good + good) or (good and not batched_path(n, good)):
        # in one batch every row would take another eigenvalue path than the kept ones or the new ones took
        p, bm, _ = batch(list(range(K)))
        return p, bm
    out = {b: rows[b] for b in names if b in rows}
    for j, k in enumerate(miss):
        assert pm is not None
        out[names[k]] = (pm[j], None if bm is None else bm[j])
    poles = np.stack([out[b][0] for b in names])
    bounded = [out[b][1] for b in names]
    return poles, None if bounded[0] is None else np.stack(bounded)  # type: ignore[arg-type]


def rank(
    model: TuningModel,
    thetas: np.ndarray,
    cand: Candidates,
    scale: float,
    max_noise: np.ndarray | None = None,
) -> Ranked:
    """Evaluate and rank the candidates ``thetas`` (K, n_theta) on ``cand`` (module docstring)."""
    thetas = np.clip(np.atleast_2d(np.asarray(thetas, float)), model.lower, model.upper)
    z, m, k = _margins(model, thetas, cand, scale, max_noise)
    feas = m >= -FEASIBILITY_TOL
    key = np.where(feas, z, -10.0 + np.clip(m, -1e6, 0))
    order = np.argsort(-key, kind="stable")
    return Ranked(thetas[order], feas[order], z[order], m[order], k[order], thetas.shape[0])


def global_phase(
    model: TuningModel,
    cand: Candidates,
    scale: float,
    max_noise: np.ndarray | None = None,
    extra: list[np.ndarray] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Ranked:
    """The law's candidates (``starts``), the drive file's gains and ``extra`` starts, ranked; if
    none is feasible, the worst margin is maximized from the best few (module docstring)."""
    say = progress or (lambda s: None)
    pool = [model.theta0[None]]
    if model.start is not None:
        pool.append(np.asarray(model.start, float)[None])
    if extra:
        pool += [np.asarray(e, float)[None] for e in extra]
    if model.starts is not None:
        pool.append(np.asarray(model.starts(), float))
    thetas = np.vstack(pool)
    r = rank(model, thetas, cand, scale, max_noise)
    nf = int(r.feasible.sum())
    say(
        f"global phase: {r.evaluated} candidate gains on {cand.size} conditions, {nf} meet them all"
        + (f"; best worst damping {r.damping[0]:.4f}" if nf else f"; best worst margin {r.margin[0]:.3g}")
    )
    if model.n_theta > MAX_PATTERN_PARAMETERS or (nf and max_noise is None):
        return r
    # none feasible: maximize the worst margin from the best few; with a noise limit (a multimodal
    # problem for the NLP): also refine the best feasible ones by the worst damping
    x = r.thetas[:5] / model.typical
    f = np.where(r.feasible[:5], r.damping[:5], -10.0 + np.clip(r.margin[:5], -1e6, 0))
    lo, hi = model.lower / model.typical, model.upper / model.typical
    n = model.n_theta
    D = poll_directions(n)
    h = np.full(x.shape[0], 0.5)
    step_min = 0.02 if nf else 1e-3
    for _ in range(200):
        act = np.flatnonzero(h >= step_min)
        if act.size == 0:
            break
        polls = np.clip(x[act, None, :] + h[act, None, None] * D[None], lo, hi)
        zp, mp, _ = _margins(model, (polls * model.typical).reshape(-1, n), cand, scale, max_noise)
        fp = np.where(mp >= -FEASIBILITY_TOL, zp, -10.0 + np.clip(mp, -1e6, 0)).reshape(act.size, -1)
        k = np.argmax(fp, axis=1)
        better = fp[np.arange(act.size), k] > f[act] + 1e-12
        x[act[better]] = polls[better, k[better]]
        f[act[better]] = fp[better, k[better]]
        h[act[~better]] /= 2
    r2 = rank(model, np.vstack([x * model.typical, r.thetas]), cand, scale, max_noise)
    say(
        "global phase: pattern search from the 5 best: "
        + (
            f"feasible gains (worst damping {r2.damping[0]:.4f})"
            if r2.feasible[0]
            else f"none feasible, best worst margin {r2.margin[0]:.3g}"
        )
    )
    return r2
