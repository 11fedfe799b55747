"""Max-min damping NLP (IPOPT via casadi.nlpsol) over an operating envelope, by an exchange method.

Problem::

    maximize t - smoothing * regularizer(theta)  over theta (gains), t
    s.t. at every damping point i:  all poles of A_i(theta) have damping ratio >= t
         at every stability point j: all poles of A_j(theta) have Re <= -sigma_j
         at every noise point k:     A_k stable and the noise figure <= its limit
         theta in its box

The pole conditions are the exact smooth sector conditions of tuning/sector.py (the characteristic
polynomial factored into quadratics with a, b >= 0 and a^2 >= 4 t^2 b, the factor coefficients
being unknowns of the NLP), so IPOPT sees only smooth functions. Points with
parameter errors have an equilibrium that moves with the gains: there the equilibrium x_j is an
unknown of the NLP with the equality x_dot(x_j, theta) = 0, from the same closed-loop Function;
where the equilibrium does not move with the gains (``TuningModel.fixed_equilibrium``: the adaptive
observer with exact estimates) it is data, which makes the slots' derivatives several times cheaper.
The noise figure (design/noise.py) is constrained through the Lyapunov equation: the state
covariance is an unknown of the slot, tied to A and the noise input by the Lyapunov equalities, with
the slot's closed loop kept stable by the same sector factors (t = 0).

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
from sensorless.design.noise import lyapunov
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning.model import TuningModel, evaluate
from sensorless.tuning.sector import damping_inequalities, factor_equalities, factors_from_poles, n_quadratic


class TuningError(RuntimeError):
    """The tuning NLP failed or the envelope is infeasible (the message says which and where)."""


T_MAX = 0.995  # upper bound of the damping variable (asin is singular at 1)
CREEP = 5e-4  # a round at the trust-region edge that gains less than this ends the method
# Each round starts from a good primal point (the previous round's gains, the factors of their
# poles, the exact equilibria): a small bound push keeps IPOPT there instead of pushing the start
# into the interior, and the adaptive barrier update converges in far fewer iterations than the
# monotone one (law16 on the default envelope: 26 instead of 212 iterations, benchmarks/bench_tune.py).
# expand: the MX graph becomes SX, faster to evaluate for these small slots.
SOLVER_OPTIONS = {
    "expand": True,
    "ipopt.print_level": 0,
    "print_time": False,
    # near a degenerate optimum IPOPT can sit at a 1e-9-ish error and then jump away: accept a point
    # that meets the acceptable tolerance instead of iterating on
    "ipopt.tol": 1e-9,
    "ipopt.acceptable_tol": 1e-7,
    "ipopt.acceptable_iter": 1,
    "ipopt.max_iter": 150,  # a good round takes 10-40; a hopeless one is retried with a smaller radius
    "ipopt.mu_strategy": "adaptive",
    "ipopt.bound_push": 1e-6,
    "ipopt.bound_frac": 1e-6,
    "ipopt.sb": "yes",
}


DAMPING, STABILITY, NOISE = 1, 0, 2  # candidate kinds


@dataclass(frozen=True)
class Candidates:
    """The finite set of conditions: point data (n_p, N), kind (1: damping >= t, 0: Re <= -sigma,
    2: noise figure <= the limit), shift sigma [1/s], and a label per point for messages."""

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


def _sym(v: ca.SX, n: int) -> ca.SX:
    """Symmetric n x n matrix from its n(n+1)/2 upper-triangular entries (row by row)."""
    P = ca.SX(n, n)
    k = 0
    for i in range(n):
        for j in range(i, n):
            P[i, j] = v[k]
            P[j, i] = v[k]
            k += 1
    return P


def _upper(M: ca.SX) -> ca.SX:
    n = M.shape[0]
    return ca.vertcat(*[M[i, j] for i in range(n) for j in range(i, n)])


@functools.cache
def _slot_function(model: TuningModel, free_x: bool) -> ca.Function:
    """One damping/stability slot: (phi, t, x, point, kind, sigma, scale, f) -> (g_eq, g_damp).

    g_eq = [charpoly(A/scale + sigma/scale I) - product of factors f] (+ [x_dot / (scale x_typical)]
    where the equilibrium x is an unknown, ``free_x``), g_damp = [a_i^2 - 4 (kind t)^2 b_i] (>= 0),
    with f >= 0 by bounds: the exact sector conditions of tuning/sector.py. With ``free_x`` False the
    equilibrium is data (it does not move with the gains): fewer unknowns and far cheaper derivatives.
    """
    n, npt = model.n_x, len(model.point_names)
    th = ca.SX.sym("phi", model.phi_typical.size)
    t, kind, sigma, scale = (ca.SX.sym(k) for k in ("t", "kind", "sigma", "scale"))
    x = ca.SX.sym("x", n)
    pt = ca.SX.sym("point", npt)
    f = ca.SX.sym("f", n)
    A, xdot = model.linearization(th, x, pt)
    eq = factor_equalities(A / scale, f, sigma / scale)
    if free_x:
        eq = ca.vertcat(xdot / (scale * ca.DM(model.x_typical)), eq)
    damp = damping_inequalities(f, n, kind * t)
    names = ["phi", "t", "x", "point", "kind", "sigma", "scale", "f"]
    return ca.Function("slot", [th, t, x, pt, kind, sigma, scale, f], [eq, damp], names, ["g_eq", "g_damp"])


@functools.cache
def _noise_function(model: TuningModel) -> ca.Function:
    """One noise slot: (phi, x, point, scale, s, c1, c2, f, Pv) -> (g_eq, g_noise).

    The closed loop must be stable (factors f >= 0 of charpoly(A/scale)), and Pv (the upper triangle of
    P~) solves the scaled Lyapunov equation A^ P~ + P~ A^T + B^ B^T / scale = 0 with A^ = S^-1 A S / scale,
    B^ = S^-1 B, S = diag(s): the state covariance per unit noise density is S P~ S (design/noise.py),
    and s (the square roots of its diagonal at the round's start) makes P~ a correlation-like matrix
    of order one. g_noise_i = c1_i (C S P~ S C^T)_ii + c2_i (D D^T)_ii - 1 (<= 0) with
    c1_i = sigma^2 T_s / limit_i^2, c2_i = sigma^2 / limit_i^2 (0: output not limited).
    """
    n, npt, no = model.n_x, len(model.point_names), len(model.noise_outputs)
    th = ca.SX.sym("phi", model.phi_typical.size)
    x = ca.SX.sym("x", n)
    pt = ca.SX.sym("point", npt)
    scale = ca.SX.sym("scale")
    sv = ca.SX.sym("s", n)
    c1, c2 = ca.SX.sym("c1", no), ca.SX.sym("c2", no)
    f = ca.SX.sym("f", n)
    Pv = ca.SX.sym("P", n * (n + 1) // 2)
    A, _ = model.linearization(th, x, pt)
    B, C, D = model.noise(th, x, pt)
    S = ca.diag(sv)
    Si = ca.diag(1 / sv)
    Ah = Si @ A @ S / scale
    Bh = Si @ B
    P = _sym(Pv, n)
    lyap = _upper(Ah @ P + P @ Ah.T + Bh @ Bh.T / scale)
    CS = C @ S
    g_noise = c1 * ca.diag(CS @ P @ CS.T) + c2 * ca.diag(D @ D.T) - 1
    eq = ca.vertcat(factor_equalities(A / scale, f, 0.0), lyap)
    names = ["phi", "x", "point", "scale", "s", "c1", "c2", "f", "P"]
    return ca.Function(
        "noise_slot", [th, x, pt, scale, sv, c1, c2, f, Pv], [eq, g_noise], names, ["g_eq", "g_noise"]
    )


@dataclass(frozen=True)
class _Layout:
    """Slot counts of one solver: free-equilibrium, fixed-equilibrium and noise slots."""

    free: int
    fixed: int
    noise: int


def _sizes(model: TuningModel) -> tuple[int, int, int, int]:
    n = model.n_x
    nphi = model.phi_typical.size
    return n, nphi, len(model.point_names), n * (n + 1) // 2


@functools.cache
def _solver(model: TuningModel, L: _Layout) -> ca.Function:
    """IPOPT solver for the slot layout L. Variables z = [theta/typical, t, free slots (phi/phi_typ,
    x/x_typ, f), fixed slots (phi/phi_typ, f), noise slots (phi/phi_typ, f, P~)]; parameters
    p = [w_t, w_reg, free (point, kind, sigma, scale), fixed (point, kind, sigma, scale, x), noise
    (point, scale, s, x, c1, c2)]. Each slot's local data phi is a variable tied to theta by
    phi = local(theta, point): the slots' derivatives stay small and block-diagonal whatever the
    number of parameters."""
    nth = model.n_theta
    n, nphi, npt, nP = _sizes(model)
    no = len(model.noise_outputs)
    per_free, per_fixed, per_noise = nphi + 2 * n, nphi + n, nphi + n + nP
    nz = nth + 1 + per_free * L.free + per_fixed * L.fixed + per_noise * L.noise
    pf, px, pn = npt + 3, npt + 3 + n, npt + 1 + 2 * n + 2 * no
    npar = 2 + pf * L.free + px * L.fixed + pn * L.noise
    z = ca.MX.sym("z", nz)
    p = ca.MX.sym("p", npar)
    theta = z[:nth] * ca.DM(model.typical)
    t = z[nth]
    w_t, w_reg = p[0], p[1]
    g_phi, g_eq, g_ineq = [], [], []
    phi_typ = ca.DM(model.phi_typical)
    zi, pi = nth + 1, 2

    def take(v, k, rows, M):
        return ca.reshape(v[k : k + rows * M], rows, M), k + rows * M

    def tie(Vphi, S, M):
        Phi = Vphi * ca.repmat(phi_typ, 1, M)
        g_phi.append(ca.vec((model.local.map(M)(theta, S[:npt, :]) - Phi) / ca.repmat(phi_typ, 1, M)))
        return Phi

    if L.free:
        V, zi = take(z, zi, per_free, L.free)
        S, pi = take(p, pi, pf, L.free)
        Phi = tie(V[:nphi, :], S, L.free)
        X = V[nphi : nphi + n, :] * ca.repmat(ca.DM(model.x_typical), 1, L.free)
        e, d = _slot_function(model, True).map(L.free)(
            Phi, t, X, S[:npt, :], S[npt, :], S[npt + 1, :], S[npt + 2, :], V[nphi + n :, :]
        )
        g_eq.append(ca.vec(e))
        g_ineq.append(ca.vec(d))
    if L.fixed:
        V, zi = take(z, zi, per_fixed, L.fixed)
        S, pi = take(p, pi, px, L.fixed)
        Phi = tie(V[:nphi, :], S, L.fixed)
        e, d = _slot_function(model, False).map(L.fixed)(
            Phi, t, S[npt + 3 :, :], S[:npt, :], S[npt, :], S[npt + 1, :], S[npt + 2, :], V[nphi:, :]
        )
        g_eq.append(ca.vec(e))
        g_ineq.append(ca.vec(d))
    if L.noise:
        V, zi = take(z, zi, per_noise, L.noise)
        S, pi = take(p, pi, pn, L.noise)
        Phi = tie(V[:nphi, :], S, L.noise)
        o = npt + 1
        e, d = _noise_function(model).map(L.noise)(
            Phi,
            S[o + n : o + 2 * n, :],
            S[:npt, :],
            S[npt, :],
            S[o : o + n, :],
            S[o + 2 * n : o + 2 * n + no, :],
            S[o + 2 * n + no :, :],
            V[nphi : nphi + n, :],
            V[nphi + n :, :],
        )
        g_eq.append(ca.vec(e))
        g_ineq.append(ca.vec(-d))  # >= 0
    th_sx = ca.SX.sym("th", nth)
    r = model.regularizer(th_sx) if model.regularizer is not None else 0
    reg = ca.Function("reg", [th_sx], [r])
    f = -w_t * t + w_reg * reg(theta)
    g = ca.vertcat(*g_phi, *g_eq, *g_ineq)
    return ca.nlpsol(
        f"tune_{model.family}_{L.free}_{L.fixed}_{L.noise}",
        "ipopt",
        {"x": z, "p": p, "f": f, "g": g},
        {**SOLVER_OPTIONS, "ipopt.hessian_approximation": model.hessian},
    )


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
    nonoise = cand.kind != NOISE
    m = np.full(cand.size, -np.inf)
    e = evaluate(model, theta, cand.P[:, nonoise])
    p = e.poles
    m[nonoise] = np.where(
        cand.kind[nonoise] == DAMPING, worst_damping(p) - t, (-max_real(p) - cand.sigma[nonoise]) / scale
    )
    if (~nonoise).any():
        en = evaluate(model, theta, cand.P[:, ~nonoise], noise=True)
        m[~nonoise] = noise_margin(en.noise, max_noise)
    return np.where(np.isfinite(m), m, -np.inf)


def noise_margin(noise: np.ndarray, max_noise: np.ndarray | None) -> np.ndarray:
    """min over the limited outputs of 1 - noise/limit (inf: no limit); -inf where not finite."""
    if max_noise is None:
        return np.full(noise.shape[0], np.inf)
    lim = np.asarray(max_noise, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(np.isfinite(lim), 1.0 - noise / lim, np.inf)
    r = np.where(np.isnan(r), -np.inf, r)
    return r.min(axis=1)


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
    progress: Callable[[str], None] | None = None,
) -> Solution:
    """Maximize the worst damping t over ``cand`` (minus ``smoothing`` times the family's
    regularizer) by the exchange method above, inside a trust region.

    Each round's NLP keeps theta within ``radius`` typical magnitudes of the round's start (the
    sector conditions are polynomial: far from the start the Newton model of IPOPT is poor). A
    round whose solution touches the trust region is followed by another from there; a round
    that IPOPT cannot solve is retried with half the radius. The method ends when a round's
    solution is interior to the trust region and no grid point violates. Noise points (kind 2) need
    ``max_noise`` (per noise output of the model; inf: not limited). A failing round is retried with
    half the radius until it falls below ``min_radius``.
    """
    nth = model.n_theta
    radius0 = radius
    theta = np.clip(np.asarray(theta_start, float), model.lower, model.upper)
    n0 = n_initial or model.n_initial_active or max(4, 3 * nth)  # a rich parametrization binds at many
    m = margins(model, theta, cand, 0.0, scale, max_noise)
    t_now = _start_t(m, cand)
    m = m - np.where(cand.kind == DAMPING, t_now, 0.0)
    active = _pick(m, cand, (), n0)
    total_it = 0
    best: Solution | None = None  # last round with no violated grid point
    verified: list[np.ndarray] = []  # every such round's theta (the caller re-verifies them densely)
    fixed = fixed_points(model, cand.P)
    for rnd in range(1, 100):
        # start each round feasible: below the worst damping of the active points at theta
        damp_act = [m[i] + t_now for i in active if cand.kind[i] == DAMPING and np.isfinite(m[i])]
        t_now = float(np.clip(min([t_now, *damp_act]) - 1e-3, 0.0, T_MAX - 0.01))
        while True:
            lo = np.maximum(model.lower, theta - radius * model.typical)
            hi = np.minimum(model.upper, theta + radius * model.typical)
            z, sol = _run(model, cand, active, fixed, theta, t_now, scale, lo, hi, smoothing, max_noise)
            total_it += sol.stats()["iter_count"]
            status = sol.stats()["return_status"]
            if sol.stats()["success"] or status == "Solved_To_Acceptable_Level":
                break
            if radius < min_radius:
                if best is not None:  # a verified feasible solution exists: keep it
                    if progress:
                        progress(f"round {rnd}: IPOPT {status}; keeping round {best.rounds}")
                    return dataclasses.replace(best, iterations=total_it)
                raise TuningError(_failure(status, cand, active))
            radius /= 2
        radius = min(2 * radius, radius0)  # a solved round restores the trust region
        new = np.asarray(z[:nth]).ravel() * model.typical
        at_edge = np.any(
            (np.isclose(new, lo, rtol=0, atol=1e-6 * model.typical) & (lo > model.lower))
            | (np.isclose(new, hi, rtol=0, atol=1e-6 * model.typical) & (hi < model.upper))
        )
        theta = new
        t_now = float(z[nth])
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
            best = Solution(theta, t_now, tuple(active), rnd, total_it, tuple(verified))
            if not at_edge or gain < CREEP:  # creeping along a ridge: the worst damping barely moves
                return best
        if bad.size:
            active = _pick(m, cand, active, max(2, min(bad.size, n0)))
    raise TuningError("the exchange method did not converge in 100 rounds")


def _start_t(m: np.ndarray, cand: Candidates) -> float:
    """A feasible-as-possible start for t: just below the worst damping of the damping points."""
    d = m[cand.kind == DAMPING]
    d = d[np.isfinite(d)]
    return float(np.clip(d.min() - 1e-3, 0.0, T_MAX - 0.01)) if d.size else 0.0


def _pick(m: np.ndarray, cand: Candidates, active: tuple[int, ...] | list[int], k: int) -> list[int]:
    """Add the k most violated (smallest-margin) candidates not yet active; at least one of each kind."""
    out = list(active)
    order = [int(i) for i in np.argsort(m, kind="stable") if int(i) not in out]
    for kind in (DAMPING, STABILITY, NOISE):
        first = next((i for i in order if cand.kind[i] == kind), None)
        if first is not None and first not in out and (m[first] < 0 or not active):
            out.append(first)
    for i in order:
        if len(out) >= len(active) + k:
            break
        if i not in out:
            out.append(i)
    return out


def _slots(n: int, least: int = 4) -> int:
    """Slot counts are 0 or powers of two, at least ``least`` (a solver is built once per layout)."""
    if n == 0:
        return 0
    M = least
    while M < n:
        M *= 2
    return M


def _run(model, cand, active, fixed, theta, t_now, scale, lower, upper, smoothing, max_noise):
    n, nphi, _, nP = _sizes(model)
    groups = {
        "free": [i for i in active if cand.kind[i] != NOISE and not fixed[i]],
        "fixed": [i for i in active if cand.kind[i] != NOISE and fixed[i]],
        "noise": [i for i in active if cand.kind[i] == NOISE],
    }
    L = _Layout(_slots(len(groups["free"])), _slots(len(groups["fixed"]), 8), _slots(len(groups["noise"])))
    par, z0, lbx, ubx, lbg, ubg = [[1.0, smoothing]], [theta / model.typical, [t_now]], [], [], [], []
    lbx.append(np.concatenate([lower / model.typical, [0.0]]))
    ubx.append(np.concatenate([upper / model.typical, [T_MAX]]))
    g_phi_n = 0
    eqs, ineqs = [], []  # (count, lower bounds) of the equalities and inequalities, in solver order

    def slot_data(idx):
        P = cand.P[:, idx]
        x0 = model.equilibrium(theta, P)
        if not np.isfinite(x0).all():
            bad = [cand.labels[i] for i, ok in zip(idx, np.isfinite(x0).all(axis=0), strict=True) if not ok]
            raise TuningError(f"no observer equilibrium at {bad[0]} with the current gains")
        e = evaluate(model, theta, P)
        phi0 = _phi(model, theta, P)
        return P, x0, e.poles, phi0

    for name, M in (("free", L.free), ("fixed", L.fixed)):
        if not M:
            continue
        act = groups[name]
        idx = act + [act[0]] * (M - len(act))  # unused slots: copies, switched off
        P, x0, pl, phi0 = slot_data(idx)
        kind, sigma = cand.kind[idx], cand.sigma[idx]
        # Per-slot frequency scale: the geometric mean of the slot's pole magnitudes at the start, so
        # that the normalized characteristic polynomial has roots of order one.
        with np.errstate(divide="ignore"):
            gm = np.exp(np.mean(np.log(np.abs(pl + sigma[:, None])), axis=1))
        gm = np.where(np.isfinite(gm) & (gm > 0), gm, scale)
        xs = x0 / model.x_typical[:, None]
        for s in range(M):
            on = s < len(act)
            f0 = factors_from_poles((pl[s] + sigma[s]) / gm[s])  # start: the factors of the start poles
            flo = np.full(n, 0.0 if on else -np.inf)
            if name == "free":
                par.append(np.concatenate([P[:, s], [kind[s], sigma[s], gm[s]]]))
                z0.append(np.concatenate([phi0[:, s] / model.phi_typical, xs[:, s], f0]))
                # Equilibria within half a typical magnitude of the start (the equilibrium set is
                # periodic in the position error: stay on the branch the analysis follows).
                lbx.append(np.concatenate([np.full(nphi, -np.inf), xs[:, s] - 0.5, flo]))
                ubx.append(np.concatenate([np.full(nphi, np.inf), xs[:, s] + 0.5, np.full(n, np.inf)]))
            else:
                par.append(np.concatenate([P[:, s], [kind[s], sigma[s], gm[s]], x0[:, s]]))
                z0.append(np.concatenate([phi0[:, s] / model.phi_typical, f0]))
                lbx.append(np.concatenate([np.full(nphi, -np.inf), flo]))
                ubx.append(np.full(nphi + n, np.inf))
        g_phi_n += nphi * M
        eqs.append((n + (n if name == "free" else 0)) * M)
        nq = n_quadratic(n)
        lo_d = np.zeros((M, nq))
        lo_d[len(act) :, :] = -np.inf
        ineqs.append(lo_d.ravel())
    if L.noise:
        act = groups["noise"]
        M = L.noise
        idx = act + [act[0]] * (M - len(act))
        P, x0, pl, phi0 = slot_data(idx)
        with np.errstate(divide="ignore"):
            gm = np.exp(np.mean(np.log(np.abs(pl)), axis=1))
        gm = np.where(np.isfinite(gm) & (gm > 0), gm, scale)
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
    solver = _solver(model, L)
    sol = solver(
        x0=np.concatenate(z0),
        p=np.concatenate(par),
        lbx=np.concatenate(lbx),
        ubx=np.concatenate(ubx),
        lbg=lbg,
        ubg=ubg,
    )
    return np.asarray(sol["x"]).ravel(), solver


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
