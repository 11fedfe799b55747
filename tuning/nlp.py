"""Max-min damping NLP (IPOPT via casadi.nlpsol) over an operating envelope, by an exchange method.

The problem and its smooth formulation (sector conditions, equilibria, noise figure, regularizer) are
tuning/slots.py; the conditions are the candidate points of tuning/candidates.py.

The envelope is a finite grid, but only a few points bind at a max-min optimum, so the NLP is solved
on an *active set* of points (fixed number of slots; unused slots are switched off through their
bounds): solve, evaluate every grid point numerically by eigenvalues, add the points that violate,
re-solve (a classical exchange method for semi-infinite programs). It stops when no grid point
violates, i.e. the solution is optimal for the whole grid, up to IPOPT's local optimality.

The reported damping is never the NLP's t: see tuning/tune.py (dense re-verification).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from sensorless.design.noise import lyapunov
from sensorless.tuning.bounded_rows import slot_bounds
from sensorless.tuning.candidates import DAMPING, NOISE, STABILITY, Candidates, fixed_points, margins
from sensorless.tuning.family import TuningError
from sensorless.tuning.model import TuningModel, evaluate
from sensorless.tuning.sector import factors_from_poles, n_quadratic
from sensorless.tuning.slots import SOLVER_OPTIONS, T_MAX, WHOLE_GRAPH_SLOTS, Layout, ipopt_solver, sizes

CREEP = 5e-4  # a round at the trust-region edge that gains less than this ends the method
# the smallest pole magnitude a slot's frequency scale counts, relative to its largest (_pole_scale)
SCALE_FLOOR = 1e-2
# IPOPT iterations of one exchange method in all: a good one takes 10-150 (a two-parameter law) or
# 100-300 (a schedule of 50 gains); beyond, the rounds only creep (a drone-class motor: 2890 iterations in
# 11 rounds, 227-413 s, for a result the dense grid refused)
MAX_ITERATIONS = 400
# The proximal term |L (theta/typical - the round's start)|^2 of the NLP's objective (tuning/slots.py), for
# a law without a regularizer: L^T L = HOLD N N^T, N the directions of theta that no active point sees
# (flat()). Along such a direction nothing in the NLP pulls but IPOPT's barrier (up to 1e-3 / the distance
# to the box), which walked eq. (16)'s parameters along the ray lambda'/omega_lambda = const (omega_lambda
# above every active speed, a drone-class motor) by 19 typical magnitudes in one iteration; HOLD keeps the
# round near its start there, and costs nothing in the directions the points see.
HOLD = 1.0
FLAT = 1e-9  # a direction whose gain through the points' local data is below this (relative) is flat
FEASIBLE_IPOPT = 1e-8  # a round out of iterations is kept where its constraint violation is below this


@dataclass(frozen=True)
class Solution:
    """Result of the exchange method."""

    theta: np.ndarray
    t: float  # the NLP's worst damping on the active set (not the verified value)
    active: tuple[int, ...]  # candidate indices in the final active set
    rounds: int
    iterations: int  # IPOPT iterations, all rounds
    verified: tuple[np.ndarray, ...] = ()  # theta of every round with no violated grid point, in order
    # IPOPT runs that failed and were retried with half the trust region (:func:`attempt_note`)
    failed_attempts: tuple[str, ...] = ()


def solve(
    model: TuningModel,
    cand: Candidates,
    theta_start: np.ndarray,
    scale: float,
    *,
    smoothing: float = 0.0,
    radius: float = 2.0,
    tol: float = 1e-5,
    max_noise: np.ndarray | None = None,
    n_initial: int | None = None,
    min_radius: float = 0.05,
    max_iterations: int = MAX_ITERATIONS,
    progress: Callable[[str], None] | None = None,
) -> Solution:
    """Maximize the worst damping t over ``cand`` (minus ``smoothing`` times the law's
    regularizer) by the exchange method above, inside a trust region.

    Each round's NLP keeps theta within ``radius`` typical magnitudes of the round's start (the
    sector conditions are polynomial: far from the start the Newton model of IPOPT is poor). A
    round whose solution touches the trust region is followed by another from there; a round
    that IPOPT cannot solve is retried with half the radius. The trust region stays within the piece of
    a law with kinks (``TuningModel.smooth_box``), and the directions no active point sees are held
    (:func:`flat`): IPOPT's barrier alone walked them across the kinks. The method ends when a round's
    solution is interior to the trust region and no grid point violates. Noise points (condition 2) need
    ``max_noise`` (per noise output of the model; inf: not limited). A failing round is retried with
    half the radius until it falls below ``min_radius``. The work has a bound: after ``max_iterations``
    IPOPT iterations in all, the method ends with its last verified round, or fails (its start stays
    the caller's candidate).
    """
    nth = model.n_theta
    radius0 = radius
    theta = np.clip(np.asarray(theta_start, float), model.lower, model.upper)
    n0 = n_initial or model.n_initial_active or max(4, 3 * nth)  # a rich parametrization binds at many
    m = margins(model, theta, cand, 0.0, scale, max_noise)
    t_now = _start_t(m, cand)
    m = m - np.where(cand.condition == DAMPING, t_now, 0.0)
    group = model.point_group
    active = _pick(m, cand, (), n0) if group is None else _spread(m, cand, group(cand.P))
    total_it = 0
    best: Solution | None = None  # last round with no violated grid point
    verified: list[np.ndarray] = []  # every such round's theta (the caller re-verifies them densely)
    fixed = fixed_points(model, cand.P)
    attempts: list[str] = []  # the failed IPOPT runs of the rounds (said, and kept with the solution)
    stalled = 0  # rounds since the last verified one (a model with bounded figures: STALL ends the method)
    bounded = model.bounded is not None

    def kept(sol: Solution) -> Solution:
        return dataclasses.replace(sol, iterations=total_it, failed_attempts=tuple(attempts))

    def round_end(where: str, keeping: str, budget: str) -> Solution | None:
        """The end of a round with grid points violated (the bounded figures broken at some, or the
        sector conditions): the round counts towards STALL where the model has bounded figures and a
        verified round exists; the method keeps that round when it has stalled or spent the iteration
        budget, and fails on the budget without one. None: the next round. ``where``, ``keeping`` and
        ``budget`` word its lines (the progress note's start, its "keeping" and the failure's tail)."""
        nonlocal stalled
        if bounded and best is not None:
            stalled += 1
        if best is not None and (stalled >= STALL or total_it >= max_iterations):
            if progress:
                stop = f"{stalled} rounds since a verified one" if stalled >= STALL else ""
                stop = stop or f"{total_it} IPOPT iterations (the budget)"
                progress(f"{where}{stop}: {keeping}{best.rounds}")
            return kept(best)
        if total_it >= max_iterations:
            raise TuningError(
                f"no round met every grid point within {max_iterations} IPOPT iterations{budget}"
            )
        return None

    for rnd in range(1, 100):
        # start each round feasible: below the worst damping of the active points at theta
        damp_act = [m[i] + t_now for i in active if cand.condition[i] == DAMPING and np.isfinite(m[i])]
        t_now = float(np.clip(min([t_now, *damp_act]) - 1e-3, 0.0, T_MAX - 0.01))
        while True:
            lo = np.maximum(model.lower, theta - radius * model.typical)
            hi = np.minimum(model.upper, theta + radius * model.typical)
            if model.smooth_box is not None:  # within the piece of a law with kinks at the active points
                s_lo, s_hi = model.smooth_box(theta, cand.P[:, active])
                lo, hi = np.maximum(lo, np.minimum(s_lo, theta)), np.minimum(hi, np.maximum(s_hi, theta))
            # a parameter the round's points and objective do not see is held (see flat())
            held, null = flat(model, theta, cand.P[:, active], smoothing)
            lo, hi = np.where(held, theta, lo), np.where(held, theta, hi)
            args = (model, cand, active, fixed, theta, t_now, scale, lo, hi, smoothing, max_noise)
            z, sol, start = _run(*args, null=null)
            total_it += sol.stats()["iter_count"]
            status = sol.stats()["return_status"]
            if sol.stats()["success"] or status == "Solved_To_Acceptable_Level" or _usable(sol.stats()):
                break
            # the budget holds across the retries of a large layout's round (1-2.5 s each) too: no
            # retry that could take the method beyond max_iterations (a drone-class motor's schedule
            # ran 417 and 708 iterations for a result its start beat); a small layout's (0.05-0.3 s,
            # law (16)) retries as before, whose last one may still find the presets' optimum
            spent = (
                len(active) > WHOLE_GRAPH_SLOTS
                and total_it + int(SOLVER_OPTIONS["ipopt.max_iter"]) > max_iterations
            )
            note = attempt_note(rnd, sol.stats(), start)
            attempts.append(note)
            if radius < min_radius or spent:
                if spent and best is None:
                    raise TuningError(
                        f"IPOPT {status} in round {rnd} with {total_it} of {max_iterations} iterations "
                        "(the budget) spent and no round meeting every grid point"
                    )
                if best is not None:  # a verified feasible solution exists: keep it
                    if progress:
                        progress(f"round {rnd}: IPOPT {status}; keeping round {best.rounds}")
                    return kept(best)
                raise TuningError(_failure(status, cand, active))
            if progress:
                progress(f"{note}; retrying with half the trust region")
            radius /= 2
        radius = min(2 * radius, radius0)  # a solved round restores the trust region
        new = np.asarray(z[:nth]).ravel() * model.typical
        at_edge = np.any(
            ~held
            & (
                (np.isclose(new, lo, rtol=0, atol=1e-6 * model.typical) & (lo > model.lower))
                | (np.isclose(new, hi, rtol=0, atol=1e-6 * model.typical) & (hi < model.upper))
            )
        )
        t_now = float(z[nth])
        step = _held_step(model, cand, theta, new, tol)
        if step < 1.0:
            # the round broke the family's bounded figures at grid points it did not see: the next round
            # adds them and starts where none is broken, on the way back to this one's start (which
            # met them), not from here: IPOPT from a start violating them by 90-100 % ran out of
            # iterations at every halved trust region (prius's law (16): 6 x 150 iterations per round)
            m = margins(model, new, cand, t_now, scale, max_noise)
            bad = np.flatnonzero(m < -tol)
            theta = theta + step * (new - theta)
            if progress:
                progress(
                    f"round {rnd}: {len(active)} active points, {sol.stats()['iter_count']} IPOPT "
                    f"iterations, t = {t_now:.4f}; {bad.size} grid points violate (worst: "
                    f"{cand.labels[int(np.argmin(m))]}), the bounded figures at some: the next round starts "
                    f"{step:.3g} of the way there"
                )
            active = _pick(m, cand, active, max(2, min(bad.size, n0)))
            done = round_end(f"round {rnd}: ", "keeping ", "")
            if done is not None:
                return done
            continue
        theta = new
        m = margins(model, theta, cand, t_now, scale, max_noise)
        bad = np.flatnonzero(m < -tol)
        if progress:
            worst = cand.labels[int(np.argmin(m))]
            progress(
                f"round {rnd}: {len(active)} active points, {sol.stats()['iter_count']} IPOPT iterations, "
                f"t = {t_now:.4f}; {bad.size} grid points violate (worst: {worst})"
                f"{'; at the trust-region edge' if at_edge else ''}"
            )
        if bad.size == 0:
            gain = t_now - best.t if best is not None else np.inf
            verified.append(theta)
            best = Solution(theta, t_now, tuple(active), rnd, total_it, tuple(verified), tuple(attempts))
            stalled = 0
            if not at_edge or gain < CREEP:  # creeping along a ridge: the worst damping barely moves
                return kept(best)
            if total_it >= max_iterations:
                if progress:
                    progress(f"{total_it} IPOPT iterations (the budget): keeping round {best.rounds}")
                return kept(best)
        else:
            worst = cand.labels[int(np.argmin(m))]
            done = round_end(
                "",
                "keeping round ",
                f" (the budget); {bad.size} grid points violate the last (worst: {worst})",
            )
            if done is not None:
                return done
            active = _pick(m, cand, active, max(2, min(bad.size, n0)))
    raise TuningError("the exchange method did not converge in 100 rounds")


# A model with bounded figures (tuning/model.py) ends its exchange method this many rounds after its last
# verified one: each round's slots carry the figures' rows (a 2-3x dearer IPOPT iteration), and on the
# README servo's schedule the four rounds after the first verified one (0.3885) met no grid (t 0.49-0.67,
# 5-20 points below it; 4.3 s of IPOPT) and the fifth ran out of iterations (5.6 s). (Judging those rounds
# on the dense grid too was tried: the third's 0.43 there lost the speed steps in the command's proof,
# ending 0.26 p.u. short of the reference, where the first's pass them.)
STALL = 2
# the steps tried back from a round's solution toward its start where it breaks the bounded figures
HELD_STEPS = (0.5, 0.25, 0.125, 0.0625, 0.0)


def _held_step(model: TuningModel, cand: Candidates, start: np.ndarray, new: np.ndarray, tol: float) -> float:
    """1 where the round's solution ``new`` meets the model's bounded figures at every damping point of
    ``cand`` (or the model has none), else the largest of HELD_STEPS whose point start + step (new - start)
    meets them (0: the start, which met them)."""
    if model.bounded is None:
        return 1.0
    damp = cand.condition == DAMPING
    P = cand.P[:, damp]
    for step in (1.0, *HELD_STEPS):
        if step == 0.0:
            return 0.0
        b = evaluate(model, start + step * (new - start), P).bounded
        if b is None or bool(np.all(b >= -tol)):
            return step
    return 0.0


def attempt_note(rnd: int, stats: dict, start: float) -> str:
    """A failed IPOPT run of round ``rnd``: its status, iterations and whether its start met the NLP's
    constraints (``start``: their largest violation there, as built; at most FEASIBLE_IPOPT: met), with
    IPOPT's own primal infeasibility at its first iterate (after its bound push): a feasible start that
    ends ``Infeasible_Problem_Detected`` is a fault of the formulation, not of the envelope, and is said."""
    inf_pr = (stats.get("iterations") or {}).get("inf_pr") or []
    met = "meeting" if start <= FEASIBLE_IPOPT else "violating"
    first = f"; IPOPT's first iterate {inf_pr[0]:.1g}" if inf_pr else ""
    return (
        f"round {rnd}: IPOPT {stats['return_status']} after {stats['iter_count']} iterations from a start "
        f"{met} its constraints (violation {start:.1g}{first})"
    )


def flat(
    model: TuningModel, theta: np.ndarray, P: np.ndarray, smoothing: float
) -> tuple[np.ndarray, np.ndarray]:
    """The directions of theta in which a round's NLP is flat at theta: (held (n_theta,) bool, the
    parameters that neither the local data of the points P (``model.local``: its derivative is exactly
    zero at every point) nor the regularizer depend on; N (n_theta, k), an orthonormal basis (in
    theta/typical) of the other directions that leave the points' local data unchanged to first order,
    for a law without a regularizer (else none)).

    A round holds the first at their start (their bounds) and the proximal term HOLD weighs the second.
    A gain law may be piecewise in its parameters: eq. (16)'s min(|w|/omega_lambda, 1) saturates where
    omega_lambda is below a point's speed (omega_lambda is then a held parameter), and where omega_lambda
    is above every active speed only lambda'/omega_lambda is seen (a flat direction). On such a piece
    nothing in the NLP pulls but IPOPT's barrier, which walked the parameters to the middle of the trust
    region, across the kinks of the active points, where the Newton model of the start no longer holds:
    IPOPT ended ``Infeasible_Problem_Detected`` or ran out of iterations from a start meeting every
    constraint (the README servo's law (16), omega_lambda below its lowest speed; a drone-class motor's,
    above its highest), and succeeded only once the trust region had been halved to within the piece."""
    nth, N = model.n_theta, P.shape[1]
    J = np.asarray(_map(_local_jacobian(model), N)(theta, P)).reshape(-1, N, nth)  # (n_phi, N, n_theta)
    J = (J / model.phi_typical[:, None, None] * model.typical[None, None, :]).reshape(-1, nth)
    seen = np.any(J != 0, axis=0)
    if model.regularizer is not None:
        if smoothing > 0:
            seen |= _regularized(model)
        return ~seen, np.zeros((nth, 0))
    idx = np.flatnonzero(seen)
    if idx.size == 0:
        return ~seen, np.zeros((nth, 0))
    _, sv, vt = np.linalg.svd(J[:, idx])
    rank = int(np.sum(sv > FLAT * sv[0])) if sv.size and sv[0] > 0 else 0
    null = np.zeros((nth, idx.size - rank))
    null[idx, :] = vt[rank:].T
    return ~seen, null


@functools.cache
def _local_jacobian(model: TuningModel) -> ca.Function:
    """(theta, point) -> d local / d theta (n_phi x n_theta), dense."""
    th = ca.SX.sym("theta", model.n_theta)
    pt = ca.SX.sym("point", len(model.point_names))
    return ca.Function("local_jacobian", [th, pt], [ca.densify(ca.jacobian(model.local(th, pt), th))])


@functools.cache
def _regularized(model: TuningModel) -> np.ndarray:
    """(n_theta,) bool: the parameters the law's regularizer depends on (structurally)."""
    th = ca.SX.sym("theta", model.n_theta)
    grad = ca.jacobian(model.regularizer(th), th)
    return np.isin(np.arange(model.n_theta), np.asarray(grad.sparsity().get_col(), int))


def _usable(stats: dict) -> bool:
    """Whether a round that ran out of iterations ended on a point that meets its constraints (IPOPT's
    primal infeasibility below FEASIBLE_IPOPT) and improved the objective: a round like any other (its
    gains are checked by eigenvalues on the whole grid next, as every round's). Re-solving it with half
    the radius from the same start, as before, cost the drone-class motor's schedule 3 x 150
    iterations per round for nothing."""
    if stats["return_status"] != "Maximum_Iterations_Exceeded":
        return False
    it = stats.get("iterations") or {}
    inf_pr, obj = it.get("inf_pr") or [], it.get("obj") or []
    return bool(inf_pr) and inf_pr[-1] <= FEASIBLE_IPOPT and len(obj) > 1 and obj[-1] <= obj[0]


def _start_t(m: np.ndarray, cand: Candidates) -> float:
    """A feasible-as-possible start for t: just below the worst damping of the damping points."""
    d = m[cand.condition == DAMPING]
    d = d[np.isfinite(d)]
    return float(np.clip(d.min() - 1e-3, 0.0, T_MAX - 0.01)) if d.size else 0.0


def _pick(m: np.ndarray, cand: Candidates, active: tuple[int, ...] | list[int], k: int) -> list[int]:
    """Add the k most violated (smallest-margin) candidates not yet active; at least one of each condition."""
    out = list(active)
    order = [int(i) for i in np.argsort(m, kind="stable") if int(i) not in out]
    for condition in (DAMPING, STABILITY, NOISE):
        first = next((i for i in order if cand.condition[i] == condition), None)
        if first is not None and first not in out and (m[first] < 0 or not active):
            out.append(first)
    for i in order:
        if len(out) >= len(active) + k:
            break
        if i not in out:
            out.append(i)
    return out


def _spread(m: np.ndarray, cand: Candidates, group: np.ndarray) -> list[int]:
    """The first active set of a law whose gains are local (a schedule): the smallest-margin candidate of
    every group (points sharing their local gains) and condition. Started from the few worst points
    overall, the schedule's first round moved the gains of the speeds it did not see, and the exchange
    method took 11 rounds of ever larger layouts to collect them (drone-class motor: 2890 IPOPT
    iterations, 227-413 s)."""
    out: list[int] = []
    keys = np.stack([np.asarray(group, float), cand.condition.astype(float)])
    for key in np.unique(keys, axis=1).T:
        idx = np.flatnonzero((keys[0] == key[0]) & (keys[1] == key[1]))
        out.append(int(idx[np.argmin(m[idx])]))
    return sorted(out)


def _slots(n: int, least: int = 4) -> int:
    """Slot counts are 0, powers of two from ``least`` up to WHOLE_GRAPH_SLOTS (the small layouts, as
    before: the same solvers, tuning/slots.py), then multiples of 8: a larger layout's solver is
    assembled in milliseconds (tuning/slot_derivatives.py), so its slots follow the active set closely.
    Powers of two, as before, left up to half of them switched off but evaluated and factorized in every
    IPOPT iteration (67 active points in 128 slots on a drone-class motor)."""
    if n == 0:
        return 0
    M = least
    while M < n and M < WHOLE_GRAPH_SLOTS:
        M *= 2
    return M if M >= n else 8 * -(-n // 8)


def _run(model, cand, active, fixed, theta, t_now, scale, lower, upper, smoothing, max_noise, null=None):
    n, nphi, _, nP = sizes(model)
    groups = {
        "free": [i for i in active if cand.condition[i] != NOISE and not fixed[i]],
        "fixed": [i for i in active if cand.condition[i] != NOISE and fixed[i]],
        "noise": [i for i in active if cand.condition[i] == NOISE],
    }
    L = Layout(_slots(len(groups["free"])), _slots(len(groups["fixed"]), 8), _slots(len(groups["noise"])))
    par, z0, lbx, ubx, lbg, ubg = [[1.0, smoothing]], [theta / model.typical, [t_now]], [], [], [], []
    lbx.append(np.concatenate([lower / model.typical, [0.0]]))
    ubx.append(np.concatenate([upper / model.typical, [T_MAX]]))
    g_phi_n = 0
    eqs, ineqs = [], []  # (count, lower bounds) of the equalities and inequalities, in solver order

    def slot_data(act, M):
        idx = act + [act[0]] * (M - len(act))  # unused slots: copies, switched off
        P = cand.P[:, idx]
        x0 = model.equilibrium(theta, P)
        if not np.isfinite(x0).all():
            bad = [cand.labels[i] for i, ok in zip(idx, np.isfinite(x0).all(axis=0), strict=True) if not ok]
            raise TuningError(f"no observer equilibrium at {bad[0]} with the current gains")
        e = evaluate(model, theta, P)
        phi0 = _phi(model, theta, P)
        return idx, P, x0, e.poles, phi0

    for name, M in (("free", L.free), ("fixed", L.fixed)):
        if not M:
            continue
        act = groups[name]
        idx, P, x0, pl, phi0 = slot_data(act, M)
        condition, sigma = cand.condition[idx], cand.sigma[idx]
        gm = _pole_scale(pl + sigma[:, None], scale)
        xs = x0 / model.x_typical[:, None]
        bounds, lo_b = slot_bounds(model, P, condition, len(act))  # the family's bounded figures
        for s in range(M):
            on = s < len(act)
            f0 = factors_from_poles((pl[s] + sigma[s]) / gm[s])  # start: the factors of the start poles
            flo = np.full(n, 0.0 if on else -np.inf)
            if name == "free":
                par.append(np.concatenate([P[:, s], [condition[s], sigma[s], gm[s]], bounds[s]]))
                z0.append(np.concatenate([phi0[:, s] / model.phi_typical, xs[:, s], f0]))
                # Equilibria within half a typical magnitude of the start (the equilibrium set is
                # periodic in the position error: stay on the branch the analysis follows).
                lbx.append(np.concatenate([np.full(nphi, -np.inf), xs[:, s] - 0.5, flo]))
                ubx.append(np.concatenate([np.full(nphi, np.inf), xs[:, s] + 0.5, np.full(n, np.inf)]))
            else:
                par.append(np.concatenate([P[:, s], [condition[s], sigma[s], gm[s]], x0[:, s], bounds[s]]))
                z0.append(np.concatenate([phi0[:, s] / model.phi_typical, f0]))
                lbx.append(np.concatenate([np.full(nphi, -np.inf), flo]))
                ubx.append(np.full(nphi + n, np.inf))
        g_phi_n += nphi * M
        eqs.append((n + (n if name == "free" else 0)) * M)
        nq = n_quadratic(n)
        lo_d = np.zeros((M, nq))
        lo_d[len(act) :, :] = -np.inf
        ineqs.append(np.hstack([lo_d, lo_b]).ravel())
    if L.noise:
        act = groups["noise"]
        M = L.noise
        _, P, x0, pl, phi0 = slot_data(act, M)
        gm = _pole_scale(pl, scale)
        B = _noise_matrices(model, theta, P, x0)[0]
        A = _A(model, theta, P, x0)
        with np.errstate(all="ignore"):
            Pc = lyapunov(A / gm[:, None, None], B @ B.transpose(0, 2, 1) / gm[:, None, None])
        ok = np.isfinite(Pc).all(axis=(1, 2)) & (np.diagonal(Pc, axis1=1, axis2=2) > 0).all(axis=1)
        sv = np.where(
            ok[:, None], np.sqrt(np.abs(np.diagonal(Pc, axis1=1, axis2=2))), model.x_typical[None, :]
        )
        lim = (
            np.asarray(max_noise, float)
            if max_noise is not None
            else np.full(len(model.noise_outputs), np.inf)
        )
        s2 = model.noise_sigma**2
        iu = np.triu_indices(n)
        c1 = np.where(np.isfinite(lim), s2 * model.T_s / lim**2, 0.0)
        c2 = np.where(np.isfinite(lim), s2 / lim**2, 0.0)
        for s in range(M):
            on = s < len(act)
            par.append(np.concatenate([P[:, s], [gm[s]], sv[s], x0[:, s], c1, c2]))
            f0 = factors_from_poles(pl[s] / gm[s])
            p0 = (Pc[s] / np.outer(sv[s], sv[s]))[iu] if ok[s] else np.zeros(nP)
            z0.append(np.concatenate([phi0[:, s] / model.phi_typical, f0, p0]))
            lbx.append(
                np.concatenate(
                    [np.full(nphi, -np.inf), np.full(n, 0.0 if on else -np.inf), np.full(nP, -np.inf)]
                )
            )
            ubx.append(np.full(nphi + n + nP, np.inf))
        g_phi_n += nphi * M
        eqs.append((n + nP) * M)
        lo_n = np.zeros((M, len(model.noise_outputs)))
        lo_n[len(act) :, :] = -np.inf
        ineqs.append(lo_n.ravel())
    n_eq = g_phi_n + sum(eqs)
    lbg = np.concatenate([np.zeros(n_eq), *ineqs])
    ubg = np.concatenate([np.zeros(n_eq), np.full(sum(a.size for a in ineqs), np.inf)])
    solver = ipopt_solver(model, L)
    # the proximal term (a law without a regularizer; see HOLD): L = sqrt(L^T L), column-major
    nth = model.n_theta
    NN = np.zeros((nth, nth)) if null is None else null @ null.T  # a projector
    Lp = np.sqrt(HOLD) * NN
    par.append(np.concatenate([Lp.ravel(order="F"), theta / model.typical]))
    x0, p = np.concatenate(z0), np.concatenate(par)
    sol = solver(x0=x0, p=p, lbx=np.concatenate(lbx), ubx=np.concatenate(ubx), lbg=lbg, ubg=ubg)
    start = float("nan")  # where IPOPT failed: the start's violation of the constraints, as built
    if not solver.stats()["success"]:
        g = np.asarray(solver.get_function("nlp_g")(x0, p)).ravel()
        start = float(np.max(np.maximum(lbg - g, 0.0) + np.maximum(g - ubg, 0.0), initial=0.0))
    return np.asarray(sol["x"]).ravel(), solver, start


def _pole_scale(poles: np.ndarray, scale: float) -> np.ndarray:
    """Per-slot frequency scale: the geometric mean of the slot's pole magnitudes at the start, so that
    the normalized characteristic polynomial has roots of order one (``scale`` where it has none).

    Each magnitude counts as at least SCALE_FLOOR times the slot's largest: a stability slot's shifted
    poles (p + sigma) have a root at zero where the start decays exactly at the floor, which every NLP
    keeps as its own floor, so the point that sets it is always such a slot. The plain geometric mean
    then collapsed (0.26 1/s against poles of 5700 1/s on the README servo), the normalized roots were
    of order 1e4 and the coefficients of order 1e16: the start violated the factor equalities by up
    to 13 in absolute terms, and IPOPT ended ``Infeasible_Problem_Detected`` from gains that meet
    every constraint."""
    mag = np.abs(poles)
    with np.errstate(divide="ignore", invalid="ignore"):
        top = np.max(mag, axis=1, keepdims=True)
        gm = np.exp(np.mean(np.log(np.maximum(mag, SCALE_FLOOR * top)), axis=1))
    return np.where(np.isfinite(gm) & (gm > 0), gm, scale)


@functools.lru_cache(maxsize=64)
def _map(fn: ca.Function, n: int) -> ca.Function:
    return fn.map(n)


def _phi(model: TuningModel, theta: np.ndarray, P: np.ndarray) -> np.ndarray:
    return np.asarray(_map(model.local, P.shape[1])(theta, P))


def _A(model: TuningModel, theta: np.ndarray, P: np.ndarray, x0: np.ndarray) -> np.ndarray:
    N, n = P.shape[1], model.n_x
    A = np.asarray(_map(model.linearization, N)(_phi(model, theta, P), x0, P)[0])
    return A.reshape(n, N, n).transpose(1, 0, 2)


def _noise_matrices(model: TuningModel, theta: np.ndarray, P: np.ndarray, x0: np.ndarray):
    N, n = P.shape[1], model.n_x
    B, C, D = (np.asarray(a) for a in _map(model.noise, N)(_phi(model, theta, P), x0, P))
    no = len(model.noise_outputs)
    return (
        B.reshape(n, N, -1).transpose(1, 0, 2),
        C.reshape(no, N, n).transpose(1, 0, 2),
        D.reshape(no, N, -1).transpose(1, 0, 2),
    )


def _failure(status: str, cand: Candidates, active) -> str:
    where = ", ".join(cand.labels[i] for i in list(active)[:4])
    if status in ("Infeasible_Problem_Detected", "Restoration_Failed", "Local_Infeasibility"):
        return (
            f"IPOPT found no gains meeting the constraints from this start ({status}); "
            f"binding points include {where}"
        )
    return f"IPOPT failed ({status}); active points include {where}"
