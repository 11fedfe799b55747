"""Max-min damping NLP (IPOPT via casadi.nlpsol) over an operating envelope, by an exchange method.

Problem::

    maximize t - smoothing * regularizer(theta)  over theta (gains), t
    s.t. at every damping point i:  all poles of A_i(theta) have damping ratio >= t
         at every stability point j: all poles of A_j(theta) have Re <= -sigma_j
         theta in its box

The pole conditions are the exact smooth sector conditions of tuning/sector.py (the characteristic
polynomial factored into quadratics with a, b >= 0 and a^2 >= 4 t^2 b, the factor coefficients
being unknowns of the NLP), so IPOPT sees only smooth functions. Points with
parameter errors have an equilibrium that moves with the gains: there the equilibrium x_j is an
unknown of the NLP with the equality x_dot(x_j, theta) = 0, from the same closed-loop Function.

The envelope is a finite grid, but only a few points bind at a max-min optimum, so the NLP is solved
on an *active set* of points (fixed number of slots; unused slots are switched off through their
bounds): solve, evaluate every grid point numerically by eigenvalues, add the points that violate,
re-solve (a classical exchange method for semi-infinite programs). It stops when no grid point
violates, i.e. the solution is optimal for the whole grid, up to IPOPT's local optimality.

The regularizer (a schedule's roughness and gain size; none for law16) is weighted by the
``smoothing`` setting. The reported damping is never the NLP's t: see tuning/tune.py (dense
re-verification).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning.model import TuningModel, poles
from sensorless.tuning.sector import damping_inequalities, factor_equalities, factors_from_poles, n_quadratic


class TuningError(RuntimeError):
    """The tuning NLP failed or the envelope is infeasible (the message says which and where)."""


T_MAX = 0.995  # upper bound of the damping variable (asin is singular at 1)
# Each round starts from a good primal point (the previous round's gains, the factors of their
# poles, the exact equilibria): a small bound push keeps IPOPT there instead of pushing the start
# into the interior, and the adaptive barrier update converges in far fewer iterations than the
# monotone one (law16 on the default envelope: 26 instead of 212 iterations, benchmarks/bench_tune.py).
# expand: the MX graph becomes SX, faster to evaluate for these small slots.
SOLVER_OPTIONS = {
    "expand": True,
    "ipopt.print_level": 0,
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.acceptable_tol": 1e-7,
    "ipopt.max_iter": 500,
    "ipopt.mu_strategy": "adaptive",
    "ipopt.bound_push": 1e-6,
    "ipopt.bound_frac": 1e-6,
    "ipopt.sb": "yes",
}


@dataclass(frozen=True)
class Candidates:
    """The finite set of conditions: point data (n_p, N), kind (1: damping >= t, 0: Re <= -sigma),
    shift sigma [1/s], and a label per point for messages."""

    P: np.ndarray
    kind: np.ndarray
    sigma: np.ndarray
    labels: tuple[str, ...]

    @property
    def size(self) -> int:
        return self.P.shape[1]


@dataclass(frozen=True)
class Solution:
    """Result of the exchange method."""

    theta: np.ndarray
    t: float  # the NLP's worst damping on the active set (not the verified value)
    active: tuple[int, ...]  # candidate indices in the final active set
    rounds: int
    iterations: int  # IPOPT iterations, all rounds
    verified: tuple[np.ndarray, ...] = ()  # theta of every round with no violated grid point, in order


@functools.cache
def _slot_function(model: TuningModel) -> ca.Function:
    """One slot: (phi, t, x, point, kind, sigma, scale, f) -> (g_eq, g_damp).

    g_eq = [x_dot / (scale x_typical); charpoly(A/scale + sigma/scale I) - product of factors f]
    (equalities), g_damp = [a_i^2 - 4 (kind t)^2 b_i] (>= 0), with the factor coefficients f >= 0
    by bounds: the exact sector conditions of tuning/sector.py for the slot's closed loop.
    """
    n, npt = model.n_x, len(model.point_names)
    th = ca.SX.sym("phi", model.phi_typical.size)
    t, kind, sigma, scale = (ca.SX.sym(k) for k in ("t", "kind", "sigma", "scale"))
    x = ca.SX.sym("x", n)
    pt = ca.SX.sym("point", npt)
    f = ca.SX.sym("f", n)
    A, xdot = model.linearization(th, x, pt)
    res = xdot / (scale * ca.DM(model.x_typical))
    eq = factor_equalities(A / scale, f, sigma / scale)
    damp = damping_inequalities(f, n, kind * t)
    names = ["phi", "t", "x", "point", "kind", "sigma", "scale", "f"]
    return ca.Function(
        "slot", [th, t, x, pt, kind, sigma, scale, f], [ca.vertcat(res, eq), damp], names, ["g_eq", "g_damp"]
    )


@functools.cache
def _solver(model: TuningModel, M: int) -> ca.Function:
    """IPOPT solver with M slots. Variables z = [theta/typical, t, per slot (phi/phi_typ, x/x_typ, f)];
    parameters p = [w_t, w_reg, (point, kind, sigma, scale) per slot]. Each slot's local data phi
    is a variable tied to theta by phi = local(theta, point): the slots' derivatives stay small and
    block-diagonal whatever the number of parameters."""
    nth, n, npt = model.n_theta, model.n_x, len(model.point_names)
    nphi = model.phi_typical.size
    per = nphi + 2 * n
    z = ca.MX.sym("z", nth + 1 + per * M)
    p = ca.MX.sym("p", 2 + (npt + 3) * M)
    theta = z[:nth] * ca.DM(model.typical)
    t = z[nth]
    V = ca.reshape(z[nth + 1 :], per, M)
    Phi = V[:nphi, :] * ca.repmat(ca.DM(model.phi_typical), 1, M)
    X = V[nphi : nphi + n, :] * ca.repmat(ca.DM(model.x_typical), 1, M)
    w_t, w_reg = p[0], p[1]
    S = ca.reshape(p[2:], npt + 3, M)
    g_eq, g_damp = _slot_function(model).map(M)(
        Phi, t, X, S[:npt, :], S[npt, :], S[npt + 1, :], S[npt + 2, :], V[nphi + n :, :]
    )
    g_phi = (model.local.map(M)(theta, S[:npt, :]) - Phi) / ca.repmat(ca.DM(model.phi_typical), 1, M)
    th_sx = ca.SX.sym("th", nth)
    r = model.regularizer(th_sx) if model.regularizer is not None else 0
    reg = ca.Function("reg", [th_sx], [r])
    f = -w_t * t + w_reg * reg(theta)
    g = ca.vertcat(ca.vec(g_phi), ca.vec(g_eq), ca.vec(g_damp))
    return ca.nlpsol(
        f"tune_{model.family}_{M}",
        "ipopt",
        {"x": z, "p": p, "f": f, "g": g},
        {**SOLVER_OPTIONS, "ipopt.hessian_approximation": model.hessian},
    )


def margins(model: TuningModel, theta: np.ndarray, cand: Candidates, t: float, scale: float) -> np.ndarray:
    """Numeric margin of every candidate at theta by eigenvalues (>= 0: satisfied): damping - t for
    damping points, (-max Re - sigma)/scale for stability points; -inf where no equilibrium."""
    p, _ = poles(model, theta, cand.P)
    m = np.where(cand.kind == 1, worst_damping(p) - t, (-max_real(p) - cand.sigma) / scale)
    return np.where(np.isfinite(m), m, -np.inf)


def solve(
    model: TuningModel,
    cand: Candidates,
    theta_start: np.ndarray,
    scale: float,
    *,
    smoothing: float = 0.0,
    radius: float = 2.0,
    tol: float = 1e-5,
    progress: Callable[[str], None] | None = None,
) -> Solution:
    """Maximize the worst damping t over ``cand`` (minus ``smoothing`` times the family's
    regularizer) by the exchange method above, inside a trust region.

    Each round's NLP keeps theta within ``radius`` typical magnitudes of the round's start (the
    sector conditions are polynomial: far from the start the Newton model of IPOPT is poor). A
    round whose solution touches the trust region is followed by another from there; a round
    that IPOPT cannot solve is retried with half the radius. The method ends when a round's
    solution is interior to the trust region and no grid point violates.
    """
    nth = model.n_theta
    theta = np.clip(np.asarray(theta_start, float), model.lower, model.upper)
    n0 = max(4, 3 * nth)  # a rich parametrization binds at many points: start with many
    m = margins(model, theta, cand, 0.0, scale)
    t_now = _start_t(m, cand)
    m = m - np.where(cand.kind == 1, t_now, 0.0)
    active = _pick(m, cand, (), n0)
    total_it = 0
    best: Solution | None = None  # last round with no violated grid point
    verified: list[np.ndarray] = []  # every such round's theta (the caller re-verifies them densely)
    for rnd in range(1, 100):
        M = _slots(len(active))
        # start each round feasible: below the worst damping of the active points at theta
        damp_act = [m[i] + t_now for i in active if cand.kind[i] == 1 and np.isfinite(m[i])]
        t_now = float(np.clip(min([t_now, *damp_act]) - 1e-3, 0.0, T_MAX - 0.01))
        while True:
            lo = np.maximum(model.lower, theta - radius * model.typical)
            hi = np.minimum(model.upper, theta + radius * model.typical)
            z, sol = _run(model, cand, active, M, theta, t_now, scale, lo, hi, smoothing)
            total_it += sol.stats()["iter_count"]
            status = sol.stats()["return_status"]
            if sol.stats()["success"] or status == "Solved_To_Acceptable_Level":
                break
            if radius < 0.05:
                if best is not None:  # a verified feasible solution exists: keep it
                    if progress:
                        progress(f"round {rnd}: IPOPT {status}; keeping round {best.rounds}")
                    return dataclasses.replace(best, iterations=total_it)
                raise TuningError(_failure(status, cand, active))
            radius /= 2
        new = np.asarray(z[:nth]).ravel() * model.typical
        at_edge = np.any(
            (np.isclose(new, lo, rtol=0, atol=1e-6 * model.typical) & (lo > model.lower))
            | (np.isclose(new, hi, rtol=0, atol=1e-6 * model.typical) & (hi < model.upper))
        )
        theta = new
        t_now = float(z[nth])
        m = margins(model, theta, cand, t_now, scale)
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
            best = Solution(theta, t_now, tuple(active), rnd, total_it, tuple(verified))
            if not at_edge or gain < 1e-4:
                return best
        if bad.size:
            active = _pick(m, cand, active, max(2, min(bad.size, n0)))
    raise TuningError("the exchange method did not converge in 100 rounds")


def _start_t(m: np.ndarray, cand: Candidates) -> float:
    """A feasible-as-possible start for t: just below the worst damping of the damping points."""
    d = m[cand.kind == 1]
    d = d[np.isfinite(d)]
    return float(np.clip(d.min() - 1e-3, 0.0, T_MAX - 0.01)) if d.size else 0.0


def _pick(m: np.ndarray, cand: Candidates, active: tuple[int, ...] | list[int], k: int) -> list[int]:
    """Add the k most violated (smallest-margin) candidates not yet active; at least one of each kind."""
    out = list(active)
    order = [int(i) for i in np.argsort(m, kind="stable") if int(i) not in out]
    for kind in (1, 0):
        first = next((i for i in order if cand.kind[i] == kind), None)
        if first is not None and first not in out and (m[first] < 0 or not active):
            out.append(first)
    for i in order:
        if len(out) >= len(active) + k:
            break
        if i not in out:
            out.append(i)
    return out


def _slots(n: int) -> int:
    """Slot counts are powers of two (a solver is built once per count)."""
    M = 8
    while M < n:
        M *= 2
    return M


def _run(model, cand, active, M, theta, t_now, scale, lower, upper, smoothing):
    n = model.n_x
    idx = list(active) + [active[0]] * (M - len(active))  # unused slots: copies, switched off
    P = cand.P[:, idx]
    x0 = model.equilibrium(theta, P)
    if not np.isfinite(x0).all():
        bad = [cand.labels[i] for i, ok in zip(idx, np.isfinite(x0).all(axis=0), strict=True) if not ok]
        raise TuningError(f"no observer equilibrium at {bad[0]} with the current gains")
    pl, _ = poles(model, theta, P)
    kind, sigma = cand.kind[idx], cand.sigma[idx]
    # Per-slot frequency scale: the geometric mean of the slot's pole magnitudes at the start, so
    # that the normalized characteristic polynomial has roots of order one.
    with np.errstate(divide="ignore"):
        gm = np.exp(np.mean(np.log(np.abs(pl + sigma[:, None])), axis=1))
    gm = np.where(np.isfinite(gm) & (gm > 0), gm, scale)
    slot_p = np.vstack([P, kind[None, :], sigma[None, :], gm[None, :]])
    w_t, w_reg = 1.0, smoothing
    p = np.concatenate([[w_t, w_reg], slot_p.T.ravel()])
    xs = x0 / model.x_typical[:, None]
    nphi = model.phi_typical.size
    phi0 = np.asarray(model.local.map(M)(theta, P))
    slots, lo, hi = [], [], []
    for s in range(M):
        on = s < len(active)
        f0 = factors_from_poles((pl[s] + sigma[s]) / gm[s])  # start: the factors of the start poles
        slots.append(np.concatenate([phi0[:, s] / model.phi_typical, xs[:, s], f0]))
        # Equilibria within half a typical magnitude of the start (the equilibrium set is periodic
        # in the position error: stay on the branch the analysis follows). Factors >= 0 if active.
        half = 0.5
        lo.append(
            np.concatenate([np.full(nphi, -np.inf), xs[:, s] - half, np.full(n, 0.0 if on else -np.inf)])
        )
        hi.append(np.concatenate([np.full(nphi, np.inf), xs[:, s] + half, np.full(n, np.inf)]))
    z0 = np.concatenate([theta / model.typical, [t_now], *slots])
    lbx = np.concatenate([lower / model.typical, [0.0], *lo])
    ubx = np.concatenate([upper / model.typical, [T_MAX], *hi])
    nq = n_quadratic(n)
    lbg_damp = np.zeros((M, nq))
    lbg_damp[len(active) :, :] = -np.inf
    n_eq = (nphi + 2 * n) * M
    lbg = np.concatenate([np.zeros(n_eq), lbg_damp.ravel()])
    ubg = np.concatenate([np.zeros(n_eq), np.full(nq * M, np.inf)])
    solver = _solver(model, M)
    sol = solver(x0=z0, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    return np.asarray(sol["x"]).ravel(), solver


def _failure(status: str, cand: Candidates, active) -> str:
    where = ", ".join(cand.labels[i] for i in list(active)[:4])
    if status in ("Infeasible_Problem_Detected", "Restoration_Failed", "Local_Infeasibility"):
        return (
            f"the envelope is infeasible: IPOPT found no gains meeting the constraints ({status}); "
            f"binding points include {where}"
        )
    return f"IPOPT failed ({status}); active points include {where}"
