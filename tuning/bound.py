"""The pointwise bound: at each envelope speed, the best worst-case damping that *any* gain reaches there.

A gain law gives at each speed some value of the observer's free gains at that speed (the parameters
of the law's pointwise model, ``TuningModel.pointwise``). At an operating point the closed
loop depends on the law only through that value (and its slope, which does not enter the
linearization at an equilibrium of exact estimates: tuning/model.py). So at each speed w no law does
better than

    bound(w) = max over the free gains g of  min over the envelope's torques T of  damping(w, T, g)
               subject to decay(w, T, g) >= the decay floor (and the noise limit) at every T,

and no law's worst damping over the envelope exceeds min_w bound(w): the certificate that a tuned
law is (near) optimal, and the measure of how far each law is from the best any law can do.
Where no gain meets the floor at some speed, the envelope is infeasible for every law, and those
speeds are the evidence.

Method (a few free gains, evaluated in batch): a log grid of the free gains (the pointwise model's
``starts``) at every ``coarse``-th speed and all torques; at each speed the best grid candidates of
the neighbouring coarse speeds, plus any gains the caller supplies (e.g. a tuned law's value there),
start a batched pattern search (all speeds at once, polls along the axes and diagonals in scaled
coordinates, step halved when no poll improves, down to 1e-3 of the typical magnitude). Ranking:
gains meeting the floor first, then the worst damping (ties on a plateau of damping 1 broken towards
the faster decay), infeasible ones by their worst decay margin. The result at each speed is a found
gain, so bound(w) is attained (a lower estimate of the true maximum that a denser search can only
raise); tests compare it with an independent brute-force search.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from sensorless.tuning.candidates import lowest_decay
from sensorless.tuning.model import TuningModel, evaluate

STEP_MIN = 0.05  # smallest pattern step of the basin search, in typical magnitudes (the NLP polishes)
NEAR_FEASIBLE = 0.05  # infeasible gains within this margin (relative to the pole scale) are polished
TIE = 1e-4  # weight of the decay tie-break (never changes a damping comparison by more than this)


@dataclass(frozen=True)
class Bound:
    """The pointwise bound on a grid of speeds (see the module docstring)."""

    speeds: np.ndarray  # (S,) [rad/s]
    torques: np.ndarray  # (NT,) [N m]
    damping: np.ndarray  # (S,) best worst-case damping over the torques (at the gains found)
    decay: np.ndarray  # (S,) slowest decay rate over the torques at those gains [1/s]
    feasible: np.ndarray  # (S,) the gains meet the decay floor (and noise limit) at every torque
    theta: np.ndarray  # (S, n) the gains found
    names: tuple[str, ...]  # names of the free gains
    units: tuple[str, ...]
    floor: float  # decay floor [1/s]
    noise: np.ndarray | None  # (S, n_out) worst noise over the torques at the gains found
    evaluations: int

    def worst(self) -> int:
        """Index of the speed where the bound is lowest (infeasible speeds first)."""
        key = np.where(
            self.feasible, self.damping, -10.0 + np.where(np.isfinite(self.decay), self.decay, -1e9)
        )
        return int(np.argmin(key))


def _score(
    z: np.ndarray,
    decay: np.ndarray,
    noise: np.ndarray | None,
    floor: float,
    limit: np.ndarray | None,
    scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(rank score, feasible) from per-candidate worst damping, slowest decay and worst noise."""
    z = np.where(np.isfinite(z), z, -1.0)
    d = np.where(np.isfinite(decay), decay, -1e3 * scale)
    margin = (d - floor) / scale if floor > 0 else np.where(d > 0, 0.0, d / scale)
    if noise is not None and limit is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(np.isfinite(limit), 1.0 - noise / limit, np.inf)
        nm = np.min(np.where(np.isnan(r), -1e3, r), axis=-1)
        margin = np.minimum(margin, nm)
    feas = (d >= floor) & (d > 0) & (margin >= 0)
    tie = TIE * np.maximum(d, 0) / (np.maximum(d, 0) + scale)
    return np.where(feas, z + tie, -10.0 + np.clip(margin, -1e3, 0)), feas


def _directions(n: int, fine: bool = True) -> np.ndarray:
    """Poll directions: 16 around the circle for two gains (``fine``); the axes and diagonals otherwise."""
    if n == 2 and fine:
        a = np.arange(16) * np.pi / 8
        return np.column_stack([np.cos(a), np.sin(a)])
    dirs = [np.eye(n)[i] * s for i in range(n) for s in (1, -1)]
    for i in range(n):
        for j in range(i + 1, n):
            for a in (1, -1):
                for b in (1, -1):
                    dirs.append((np.eye(n)[i] * a + np.eye(n)[j] * b) / np.sqrt(2))
    return np.array(dirs)


def _pattern_search(
    score,
    x,
    idx,
    f,
    lo,
    hi,
    typ,
    step: float = 0.5,
    step_min: float = STEP_MIN,
    fine: bool = True,
    upper=None,
    least: int = 1,
):
    """Batched pattern search: one search per row of x (scaled), at speed index idx; maximizes score.
    ``fine``: 16 poll directions (two gains) instead of the axes and diagonals. ``upper``: a cheaper
    score never below ``score`` (the same figures over a subset of the torques: the minimum over fewer
    torques is never lower, and the rank is monotone in it); a poll it does not place above its row's
    score cannot be better, and only the others (at least ``least`` of them, see :func:`_pruned`) are
    scored: the same moves as scoring every poll."""
    x, f = x.copy(), f.copy()
    D = _directions(x.shape[1], fine)
    h = np.full(x.shape[0], step)
    for _ in range(400):
        act = np.flatnonzero(h >= step_min)
        if act.size == 0:
            break
        polls = np.clip(x[act, None, :] + h[act, None, None] * D[None], lo, hi)  # (a, nd, n)
        th, at = (polls * typ).reshape(-1, x.shape[1]), np.repeat(idx[act], D.shape[0])
        if upper is None:
            fp = score(th, at).reshape(act.size, -1)
        else:
            fp = _pruned(score, upper(th, at).reshape(act.size, -1), th, at, f[act], least)
        k = np.argmax(fp, axis=1)
        better = fp[np.arange(act.size), k] > f[act] + 1e-12
        ia = act[better]
        x[ia] = polls[better, k[better]]
        f[ia] = fp[better, k[better]]
        h[act[~better]] /= 2
    return x, f


def _pruned(score, fu: np.ndarray, th: np.ndarray, at: np.ndarray, f: np.ndarray, least: int) -> np.ndarray:
    """(a, nd) the polls' scores where their upper score ``fu`` (a, nd) exceeds their row's score f (a,)
    (the only ones that can be better), -inf or their own score elsewhere. At least ``least`` polls (the
    first) are scored: a batch of fewer points than the full one would take the LAPACK path of the
    eigenvalues (design/poles.py: below 64 matrices) instead of the closed form, whose last bits differ."""
    go = (fu > f[:, None] + 1e-12).ravel()
    if go.sum() < least:
        go[: min(least, go.size)] = True
    out = np.full(go.size, -np.inf)
    if go.any():
        out[go] = score(th[go], at[go])
    return out.reshape(fu.shape)


def pointwise_bound(
    model: TuningModel,
    speeds: np.ndarray,
    torques: np.ndarray,
    floor: float,
    scale: float,
    max_noise: np.ndarray | None = None,
    extra: np.ndarray | None = None,
    coarse: int = 4,
    starts_per_speed: int = 2,
    near: float = 0.003,
    progress: Callable[[str], None] | None = None,
) -> Bound:
    """The bound at ``speeds`` over ``torques`` for the pointwise model ``model`` (free gains at a point).

    ``scale`` [1/s] normalizes decay margins; ``max_noise`` (per noise output, inf: none) adds the
    noise limit; ``extra`` (k, S, n) are more starts per speed (e.g. tuned laws' gains there). The
    grid and the NLP run at every ``coarse``-th speed (and the last); the speeds between start from
    their neighbours' optima, and those within ``near`` of the lowest bound are polished by the NLP
    too (the certificate depends on them)."""
    S, NT, n = speeds.size, torques.size, model.n_theta
    est = model.nominal_estimate
    use_noise = max_noise is not None and model.noise is not None and bool(np.isfinite(max_noise).any())
    limit = np.asarray(max_noise, float) if use_noise else None
    evals = 0

    def figures(
        th: np.ndarray, sp: np.ndarray, tq: np.ndarray = torques
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Worst damping, slowest decay, worst noise over the torques tq, for gains th (m, n) at speeds
        sp (m,)."""
        nonlocal evals
        m, nt = sp.size, tq.size
        P = model.make_points(np.repeat(sp, nt), np.tile(tq, m), est)
        e = evaluate(model, np.repeat(th, nt, axis=0).T, P, noise=use_noise)
        evals += m * nt
        z = e.damping.reshape(m, nt)
        d = e.decay.reshape(m, nt)
        z = np.where(np.isfinite(z), z, -np.inf).min(axis=1)
        d = np.where(np.isfinite(d), d, -np.inf).min(axis=1)
        nz = None
        if use_noise:
            nz = np.where(np.isnan(e.noise), np.inf, e.noise).reshape(m, nt, -1).max(axis=1)
        return z, d, nz

    def score(th: np.ndarray, idx: np.ndarray) -> np.ndarray:
        z, d, nz = figures(th, speeds[idx])
        return _score(z, d, nz, floor, limit, scale)[0]

    # the basin search sees the extreme and middle torques only; the NLP and the rest see them all
    few = torques[np.unique([0, NT // 2, NT - 1])]

    def score_few(th: np.ndarray, idx: np.ndarray) -> np.ndarray:
        z, d, nz = figures(th, speeds[idx], few)
        return _score(z, d, nz, floor, limit, scale)[0]

    lo, hi, typ = model.lower, model.upper, model.typical
    los, his = lo / typ, hi / typ
    grid = (
        np.clip(np.asarray(model.starts(), float), lo, hi) if model.starts is not None else model.theta0[None]
    )
    ex = None if extra is None else np.clip(np.asarray(extra, float), lo, hi)  # (k, S, n)
    x = np.zeros((S, n))
    f = np.full(S, -np.inf)

    def offer(th: np.ndarray, idx: np.ndarray) -> None:
        """Keep th (scaled) at speed idx where it scores better."""
        if idx.size == 0:
            return
        fs = score(th * typ, idx)
        for r in np.argsort(fs):
            if fs[r] > f[idx[r]]:
                f[idx[r]], x[idx[r]] = fs[r], th[r]

    # 1. the grid at every other coarse speed: the best distinct candidates start pattern searches
    ci = np.unique(np.r_[np.arange(0, S, max(1, coarse)), S - 1])
    gi = np.unique(np.r_[ci[::2], ci[-1]])
    K = grid.shape[0]
    sc = score_few(np.tile(grid, (gi.size, 1)), np.repeat(gi, K)).reshape(gi.size, K)
    if progress:
        progress(f"pointwise bound: {K} gain candidates at {gi.size} speeds x {few.size} torques")
    rows, at = [], []
    for r, j in enumerate(gi):
        seen: list[np.ndarray] = []
        for k in np.argsort(-sc[r]):
            if len(seen) == starts_per_speed:
                break
            if not any(np.allclose(grid[k], q) for q in seen):
                seen.append(grid[k])
                rows.append(grid[k] / typ)
                at.append(j)
    X0, I0 = np.array(rows), np.array(at)
    xs, _ = _pattern_search(score_few, X0, I0, score_few(X0 * typ, I0), los, his, typ, fine=False)
    offer(xs, I0)
    if ex is not None:  # e.g. tuned laws' gains: the bound is never below what they reach
        for e in ex:
            offer(e / typ, np.arange(S))
    # 2. the NLP at every other coarse speed, each from the best of its own and its neighbours' gains
    _neighbours(gi, x, offer, f)
    _polish(model, speeds, torques, gi, x, f, floor, scale, limit, typ, figures)
    _neighbours(gi, x, offer, f)
    _polish(model, speeds, torques, gi[f[gi] < 0], x, f, floor, scale, limit, typ, figures)
    # 3. the speeds between: from the neighbouring optima (and their interpolation), a short pattern
    # search; the NLP where the bound is lowest (what the certificate depends on) or infeasible
    mid = np.setdiff1d(np.arange(S), gi)
    if mid.size:
        pos = np.searchsorted(gi, mid)
        left, right = gi[np.clip(pos - 1, 0, gi.size - 1)], gi[np.clip(pos, 0, gi.size - 1)]
        w = (speeds[mid] - speeds[left]) / np.where(right > left, speeds[right] - speeds[left], 1.0)
        th = np.vstack([x[left], x[right], x[left] + w[:, None] * (x[right] - x[left])])
        offer(th, np.tile(mid, 3))
        # the short search sees the extreme and middle torques only, as the basin search does (its gains
        # kept where they score better on every torque); the NLP (every torque) polishes the speeds near
        # the lowest bound after it, the search on every torque the others. On every torque at every
        # speed it was a fifth of prius's tune (8.4 of 32 s CPU), whose NLP polishes 107 of the 133.
        f_few = score_few(x[mid] * typ, mid)
        xs, _ = _pattern_search(
            score_few, x[mid], mid, f_few, los, his, typ, step=0.02, step_min=0.004, fine=False
        )
        offer(xs, mid)
        ok = f[gi] >= 0
        low = mid[(f[mid] < (np.min(f[gi][ok]) if ok.any() else 1.0) + near) | (f[mid] < 0)]
        rest = np.setdiff1d(mid, low)  # no NLP there: the search on every torque finishes them
        # the polls that the extreme and middle torques already place no higher than their speed's score
        # are not scored on every torque (ind5k5: most of them, 6 of its 30 s CPU before)
        x[rest], f[rest] = _pattern_search(
            score,
            x[rest],
            rest,
            f[rest],
            los,
            his,
            typ,
            step=0.02,
            step_min=0.004,
            fine=False,
            upper=score_few,
            least=-(-64 // NT),
        )
        _polish(model, speeds, torques, low, x, f, floor, scale, limit, typ, figures)
    theta = x * typ
    z, d, nz = figures(theta, speeds)
    _, feas = _score(z, d, nz, lowest_decay(floor, scale), limit, scale)
    if progress:
        progress(f"pointwise bound: {evals} evaluations")
    return Bound(
        speeds=np.asarray(speeds, float),
        torques=np.asarray(torques, float),
        damping=z,
        decay=d,
        feasible=feas,
        theta=theta,
        names=model.names,
        units=model.units,
        floor=floor,
        noise=nz,
        evaluations=evals,
    )


def with_witness(
    bound: Bound, model: TuningModel, gains: np.ndarray, scale: float, max_noise: np.ndarray | None = None
) -> Bound:
    """The bound raised, speed by speed, to what ``gains`` (S, n: e.g. a tuned law's free gains at each
    of the bound's speeds) reach there where they score better (meeting the floor first, then the
    worst damping). A bound computed before a law was tuned (its seed's, reused by a seeded law)
    did not have the tuned gains among its starts; they are found gains too, so the bound is never
    below them."""
    use_noise = max_noise is not None and model.noise is not None and bool(np.isfinite(max_noise).any())
    limit = np.asarray(max_noise, float) if use_noise else None
    S, NT = bound.speeds.size, bound.torques.size
    th = np.clip(np.asarray(gains, float), model.lower, model.upper)
    P = model.make_points(np.repeat(bound.speeds, NT), np.tile(bound.torques, S), model.nominal_estimate)
    e = evaluate(model, np.repeat(th, NT, axis=0).T, P, noise=use_noise)
    z = np.where(np.isfinite(e.damping), e.damping, -np.inf).reshape(S, NT).min(axis=1)
    d = np.where(np.isfinite(e.decay), e.decay, -np.inf).reshape(S, NT).min(axis=1)
    nz = np.where(np.isnan(e.noise), np.inf, e.noise).reshape(S, NT, -1).max(axis=1) if use_noise else None
    fl = lowest_decay(bound.floor, scale)
    new, feas = _score(z, d, nz, fl, limit, scale)
    old, _ = _score(bound.damping, bound.decay, bound.noise if use_noise else None, fl, limit, scale)
    up = new > old
    if not up.any():
        return bound
    pick = up[:, None]
    return dataclasses.replace(
        bound,
        damping=np.where(up, z, bound.damping),
        decay=np.where(up, d, bound.decay),
        feasible=np.where(up, feas, bound.feasible),
        theta=np.where(pick, th, bound.theta),
        noise=None if bound.noise is None or nz is None else np.where(pick, nz, bound.noise),
    )


def _neighbours(ci: np.ndarray, x: np.ndarray, offer, f: np.ndarray) -> None:
    """Offer each of the speeds ci its neighbours' gains, until none is better (a basin found at one
    speed reaches the others)."""
    for _ in range(ci.size):
        old = f[ci].copy()
        offer(np.vstack([x[ci[1:]], x[ci[:-1]]]), np.r_[ci[:-1], ci[1:]])
        if np.all(f[ci] <= old + 1e-12):
            break


def _polish(model, speeds, torques, idx, x, f, floor, scale, limit, typ, figures) -> None:
    """The sector NLP (exact max-min with the floor and noise limit as constraints) at speeds idx,
    from the current gains, where the damping is below T_MAX; at a speed where the search found no
    gains meeting the constraints, IPOPT's own feasibility restoration may still find some."""
    from sensorless.tuning import nlp
    from sensorless.tuning.candidates import Candidates
    from sensorless.tuning.slots import T_MAX

    NT = torques.size
    est = model.nominal_estimate
    for j in idx:
        if f[j] >= T_MAX or f[j] < -10.0 - NEAR_FEASIBLE:  # plateau of damping 1, or far from feasible
            continue
        P = model.make_points(np.full(NT, speeds[j]), torques, est)
        parts = [(P, np.ones(NT), np.zeros(NT))]
        if floor > 0:
            parts.append((P, np.zeros(NT), np.full(NT, floor)))
        if limit is not None:
            parts.append((P, np.full(NT, 2.0), np.zeros(NT)))
        cand = Candidates(
            np.hstack([q[0] for q in parts]),
            np.concatenate([q[1] for q in parts]),
            np.concatenate([q[2] for q in parts]),
            tuple(f"T = {tq:+.4g} N m" for _ in parts for tq in torques),
        )
        try:
            # infeasible start: one retry (IPOPT's restoration either finds gains quickly or not)
            sol = nlp.solve(
                model,
                cand,
                x[j] * typ,
                scale,
                max_noise=limit,
                n_initial=4,
                min_radius=1.0 if f[j] < 0 else 0.05,
            )
        except nlp.TuningError:
            continue
        # accept within the NLP's tolerance on the floor (the score would reject 1e-7 1/s below it)
        zj, dj, nj = figures(sol.theta[None], speeds[j : j + 1])
        _, ok = _score(zj, dj, nj, lowest_decay(floor, scale), limit, scale)
        if ok[0] and zj[0] > f[j]:
            x[j], f[j] = sol.theta / typ, zj[0]
