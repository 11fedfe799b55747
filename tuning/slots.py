"""The max-min damping NLP as IPOPT sees it: the slot Functions of the sector conditions and of the noise
figure, the smoothing regularizer, and the IPOPT solver of one slot layout.

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
where the equilibrium does not move with the gains (``TuningModel.fixed_equilibrium``, e.g. with exact
estimates) it is data, which makes the slots' derivatives several times cheaper.
The noise figure (design/noise.py) is constrained through the Lyapunov equation: the state
covariance is an unknown of the slot, tied to A and the noise input by the Lyapunov equalities, with
the slot's closed loop kept stable by the same sector factors (t = 0).

The solver has a fixed number of slots of each type (free, fixed, noise); tuning/nlp.py fills them
with the active points of each exchange round. The law's regularizer (``TuningModel.regularizer``, if
it has one) is weighted by the ``smoothing`` setting.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import casadi as ca
from sensorless.tuning.model import TuningModel
from sensorless.tuning.sector import damping_inequalities, factor_equalities
from sensorless.tuning.slot_derivatives import assemble, regularizer_hessian, slot_kind

T_MAX = 0.995  # upper bound of the damping variable (asin is singular at 1)
# Each round starts from a good primal point (the previous round's gains, the factors of their
# poles, the exact equilibria): a small bound push keeps IPOPT there instead of pushing the start
# into the interior, and the adaptive barrier update converges in far fewer iterations than the
# monotone one (26 instead of 212 iterations on a two-parameter law, benchmarks/bench_tune.py).
# expand off for an assembled solver: its constraints' Jacobian and Lagrangian's Hessian are one slot's
# mapped over the slots (tuning/slot_derivatives.py), the graph is not expanded and differentiated as a
# whole (an expanded 128-slot layout took 4.1 s to build, against 0.05 s; IPOPT iterations cost the
# same); on for a small layout's (ipopt_solver): the MX graph becomes SX, faster for these small slots.
SOLVER_OPTIONS = {
    "expand": False,
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
    """One damping/stability slot: (phi, t, x, point, condition, sigma, scale, f) -> (g_eq, g_damp).

    g_eq = [charpoly(A/scale + sigma/scale I) - product of factors f] (+ [x_dot / (scale x_typical)]
    where the equilibrium x is an unknown, ``free_x``), g_damp = [a_i^2 - 4 (condition t)^2 b_i] (>= 0),
    with f >= 0 by bounds: the exact sector conditions of tuning/sector.py. With ``free_x`` False the
    equilibrium is data (it does not move with the gains): fewer unknowns and far cheaper derivatives.
    """
    n, npt = model.n_x, len(model.point_names)
    th = ca.SX.sym("phi", model.phi_typical.size)
    t, condition, sigma, scale = (ca.SX.sym(k) for k in ("t", "kind", "sigma", "scale"))
    x = ca.SX.sym("x", n)
    pt = ca.SX.sym("point", npt)
    f = ca.SX.sym("f", n)
    b = ca.SX.sym("bound", n_bounded(model))
    A, xdot = model.linearization(th, x, pt)
    eq = factor_equalities(A / scale, f, sigma / scale)
    if free_x:
        eq = ca.vertcat(xdot / (scale * ca.DM(model.x_typical)), eq)
    damp = ca.vertcat(damping_inequalities(f, n, condition * t), bounded_inequalities(model, th, x, pt, b))
    names = ["phi", "t", "x", "point", "kind", "sigma", "scale", "f", "bound"]
    return ca.Function(
        "slot", [th, t, x, pt, condition, sigma, scale, f, b], [eq, damp], names, ["g_eq", "g_damp"]
    )


def n_bounded(model: TuningModel) -> int:
    """How many bounded figures the model declares (``TuningModel.bounded``; 0: none)."""
    return 0 if model.bounded is None else int(model.bounded.size1_out(0))


def bounded_inequalities(model: TuningModel, phi: ca.SX, x: ca.SX, pt: ca.SX, b: ca.SX) -> ca.SX:
    """The rows 1 - figure/b and 1 + figure/b (>= 0: |figure| <= b) of the model's bounded figures at a
    slot, b > 0 their bounds (tuning/model.py ``bounded_reference``); none without. A slot whose figures
    are not bounded there has the rows switched off by their lower bounds (tuning/nlp.py)."""
    if model.bounded is None:
        return ca.SX(0, 1)
    r = model.bounded(phi, x, pt) / b
    return ca.vertcat(1 - r, 1 + r)


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


def proximal(z: ca.MX, q: ca.MX, nth: int) -> ca.MX:
    """The proximal term |L (z - c)|^2 of a law without a regularizer (tuning/nlp.py HOLD): z =
    theta/typical, q = [L (n_theta x n_theta, column-major), c (the round's start)]."""
    Lm = ca.reshape(q[: nth * nth], nth, nth)
    return ca.sumsqr(ca.mtimes(Lm, z - q[nth * nth :]))


@dataclass(frozen=True)
class Layout:
    """Slot counts of one solver: free-equilibrium, fixed-equilibrium and noise slots."""

    free: int
    fixed: int
    noise: int


def sizes(model: TuningModel) -> tuple[int, int, int, int]:
    """(n_x, local data, point, covariance upper triangle) sizes of the model's slots."""
    n = model.n_x
    nphi = model.phi_typical.size
    return n, nphi, len(model.point_names), n * (n + 1) // 2


# IPOPT's linear solver (MUMPS on the OpenBLAS that CasADi bundles) runs in one thread: OpenBLAS splits a
# product over as many threads as its environment says when it is loaded, and the sums' order, hence
# their last bits, follows. A Dask worker (one thread: OMP_NUM_THREADS=1 and OPENBLAS_NUM_THREADS=1 by
# Dask's default) and the command in a shell (two threads on two cores) then ran different IPOPT paths
# from the same inputs: `tune DIR` and `tune FILE` gave a drone-class motor different gains (lambda1
# at the lowest breakpoints 0.0074 vs 0.088). The libraries read these when the IPOPT plugin is loaded,
# at the first solver; the process's own values are restored after it.
THREADS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def _nlpsol_one_thread(*args: object) -> ca.Function:
    """``casadi.nlpsol(*args)`` with IPOPT's linear algebra loaded single-threaded (see THREADS_ENV)."""
    before = {k: os.environ.get(k) for k in THREADS_ENV}
    os.environ.update(dict.fromkeys(THREADS_ENV, "1"))
    try:
        return ca.nlpsol(*args)
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@functools.cache
def slot_rows(model: TuningModel, kind: str) -> ca.Function:
    """One slot of ``kind`` (free, fixed or noise) as the NLP sees it: (shared, v, s) -> (g_phi, g_eq,
    g_ineq), with shared = [theta/typical, t] (the variables every slot shares), v the slot's own
    variables (phi/phi_typ, then x/x_typ for a free slot, f, then P~ for a noise slot) and s its
    parameters (point, condition, sigma, scale, then x for a fixed slot; for a noise slot point, scale,
    s, x, c1, c2). g_phi ties phi to local(theta, point); g_ineq >= 0."""
    nth = model.n_theta
    n, nphi, npt, nP = sizes(model)
    no = len(model.noise_outputs)
    nb = n_bounded(model)
    per = {"free": nphi + 2 * n, "fixed": nphi + n, "noise": nphi + n + nP}[kind]
    width = {"free": npt + 3 + nb, "fixed": npt + 3 + n + nb, "noise": npt + 1 + 2 * n + 2 * no}[kind]
    sh, v, s = ca.SX.sym("shared", nth + 1), ca.SX.sym("v", per), ca.SX.sym("s", width)
    theta, t = sh[:nth] * ca.DM(model.typical), sh[nth]
    phi_typ = ca.DM(model.phi_typical)
    Phi = v[:nphi] * phi_typ
    g_phi = (model.local(theta, s[:npt]) - Phi) / phi_typ
    if kind == "noise":
        o = npt + 1
        e, d = _noise_function(model)(
            Phi,
            s[o + n : o + 2 * n],
            s[:npt],
            s[npt],
            s[o : o + n],
            s[o + 2 * n : o + 2 * n + no],
            s[o + 2 * n + no :],
            v[nphi : nphi + n],
            v[nphi + n :],
        )
        d = -d  # >= 0
    else:
        free = kind == "free"
        # the equilibrium: unknowns of the slot (scaled) where it moves with the gains, else data
        X = v[nphi : nphi + n] * ca.DM(model.x_typical) if free else s[npt + 3 : npt + 3 + n]
        e, d = _slot_function(model, free)(
            Phi,
            t,
            X,
            s[:npt],
            s[npt],
            s[npt + 1],
            s[npt + 2],
            v[nphi + (n if free else 0) :],
            s[width - nb :],
        )
    return ca.Function(
        f"slot_{kind}", [sh, v, s], [g_phi, e, d], ["shared", "v", "s"], ["g_phi", "g_eq", "g_ineq"]
    )


# Layouts of at most this many slots in all keep the solver CasADi builds by differentiating the whole
# expanded graph (0.05-0.15 s to build): the same derivatives to the last bit as before, hence the same
# tables (law (16) of the presets runs 8-16 slots; its optimum lies on a ridge, where rounding moves the
# point found). Larger ones (a 50-gain schedule: 46-128 slots, 1.4-4.1 s each) are assembled.
WHOLE_GRAPH_SLOTS = 16


@functools.cache
def ipopt_solver(model: TuningModel, L: Layout) -> ca.Function:
    """IPOPT solver for the slot layout L. Variables z = [theta/typical, t, free slots (phi/phi_typ,
    x/x_typ, f), fixed slots (phi/phi_typ, f), noise slots (phi/phi_typ, f, P~)]; parameters
    p = [w_t, w_reg, free (point, condition, sigma, scale), fixed (point, condition, sigma, scale, x), noise
    (point, scale, s, x, c1, c2)]. Each slot's local data phi is a variable tied to theta by
    phi = local(theta, point): the slots' derivatives stay small and block-diagonal whatever the
    number of parameters."""
    if L.free + L.fixed + L.noise <= WHOLE_GRAPH_SLOTS:
        return _whole_graph_solver(model, L)
    return _assembled_solver(model, L)


def _assembled_solver(model: TuningModel, L: Layout) -> ca.Function:
    """The solver of :func:`_whole_graph_solver`'s NLP (same variables, parameters and constraints in
    the same order) whose constraints' Jacobian and Lagrangian's Hessian are one slot's, mapped over
    the slots (tuning/slot_derivatives.py): built in milliseconds whatever the layout."""
    nth = model.n_theta
    zi, pi = nth + 1, 2
    kinds = []
    for kind, M in (("free", L.free), ("fixed", L.fixed), ("noise", L.noise)):
        if not M:
            continue
        sk = slot_kind(slot_rows(model, kind))
        kinds.append((sk, M, zi, pi))
        zi, pi = zi + sk.per * M, pi + sk.width * M
    th_sx = ca.SX.sym("th", nth)
    r = model.regularizer(th_sx) if model.regularizer is not None else 0
    reg = ca.Function("reg", [th_sx], [r])
    k = pi  # the proximal term's matrix and centre follow the slots' parameters
    own = model.regularizer is None

    def objective(z: ca.MX, p: ca.MX) -> ca.MX:
        f = -p[0] * z[nth] + p[1] * reg(z[:nth] * ca.DM(model.typical))
        return f + proximal(z[:nth], p[k : k + nth * nth + nth], nth) if own else f

    nlp, jac_g, hess_lag = assemble(
        kinds,
        nth + 1,
        zi,
        pi + nth * nth + nth,
        objective,
        regularizer_hessian(model),
        proximal=k if own else None,
    )
    exact = model.hessian == "exact"
    return _nlpsol_one_thread(
        f"tune_{model.law.replace('-', '_')}_{L.free}_{L.fixed}_{L.noise}",
        "ipopt",
        nlp,
        {
            **SOLVER_OPTIONS,
            "ipopt.hessian_approximation": model.hessian,
            "jac_g": jac_g,
            **({"hess_lag": hess_lag} if exact else {}),
        },
    )


def _whole_graph_solver(model: TuningModel, L: Layout) -> ca.Function:
    """IPOPT solver for the slot layout L. Variables z = [theta/typical, t, free slots (phi/phi_typ,
    x/x_typ, f), fixed slots (phi/phi_typ, f), noise slots (phi/phi_typ, f, P~)]; parameters
    p = [w_t, w_reg, free (point, condition, sigma, scale), fixed (point, condition, sigma, scale, x), noise
    (point, scale, s, x, c1, c2)]. Each slot's local data phi is a variable tied to theta by
    phi = local(theta, point): the slots' derivatives stay small and block-diagonal whatever the
    number of parameters. The graph is expanded and CasADi differentiates it whole (the solver of a
    small layout, as before :func:`_assembled_solver`: the same results to the last bit)."""
    nth = model.n_theta
    n, nphi, npt, nP = sizes(model)
    no = len(model.noise_outputs)
    per_free, per_fixed, per_noise = nphi + 2 * n, nphi + n, nphi + n + nP
    nz = nth + 1 + per_free * L.free + per_fixed * L.fixed + per_noise * L.noise
    nb = n_bounded(model)
    pf, px, pn = npt + 3 + nb, npt + 3 + n + nb, npt + 1 + 2 * n + 2 * no
    npar = 2 + pf * L.free + px * L.fixed + pn * L.noise + nth * nth + nth  # + the proximal term's
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

    for free, M, per, width in ((True, L.free, per_free, pf), (False, L.fixed, per_fixed, px)):
        if not M:
            continue
        V, zi = take(z, zi, per, M)
        S, pi = take(p, pi, width, M)
        Phi = tie(V[:nphi, :], S, M)
        # the equilibrium: unknowns of the slot (scaled) where it moves with the gains, else data
        X = (
            V[nphi : nphi + n, :] * ca.repmat(ca.DM(model.x_typical), 1, M)
            if free
            else S[npt + 3 : npt + 3 + n, :]
        )
        e, d = _slot_function(model, free).map(M)(
            Phi,
            t,
            X,
            S[:npt, :],
            S[npt, :],
            S[npt + 1, :],
            S[npt + 2, :],
            V[nphi + (n if free else 0) :, :],
            S[width - nb :, :],
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
    if model.regularizer is None:
        f = f + proximal(z[:nth], p[npar - nth * nth - nth :], nth)
    g = ca.vertcat(*g_phi, *g_eq, *g_ineq)
    return _nlpsol_one_thread(
        f"tune_{model.law.replace('-', '_')}_{L.free}_{L.fixed}_{L.noise}",
        "ipopt",
        {"x": z, "p": p, "f": f, "g": g},
        {**SOLVER_OPTIONS, "expand": True, "ipopt.hessian_approximation": model.hessian},
    )
