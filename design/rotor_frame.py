"""The continuous-time linearization of any observer from its rotor-frame rate function: equilibrium, poles.

The twin of design/discrete.py (the sampled observer that runs) for the continuous observer of a
paper. A family declares a :class:`RotorFrameLoop`: the observer (with whatever plant it needs) in
steady state at an operating point, written in rotor coordinates where the steady state is a fixed
point, as one SX Function ``rates(x_r, w, torque, plant, p) -> f_r``, and a Function giving Newton's
start ``start(w, torque, plant, p) -> x_r``. This module builds, once per loop, Newton's method on
those SX expressions and the Jacobian at its end (:func:`equilibrium_function`), evaluates it over N
operating points at once (``Function.map`` through design/batch.py, :func:`equilibrium_points`) and returns
the eigenvalues of the Jacobians (:meth:`Equilibria.poles`). Nothing is re-typed: the family's SX
rates are differentiated by CasADi. ``plant`` is one vector for all points (e.g. the true motor's
parameters); ``p`` the observer's parameters, one vector or one column per point.

Where Newton's method from ``start`` misses the equilibrium (an observer whose steady angle error under
wrong estimates grows to tenths of a radian), the loop declares a :class:`Continuation`: the
parameters ``p0`` at which ``start`` is the equilibrium (e.g. exact estimates), and
:func:`continued_equilibria` follows the branch from there along p(tau) = p0 + tau (p - p0); where
``p`` is ``p0`` at every point, :func:`start_function` is the closed form, no Newton step.

At the equilibrium :func:`point_function` gives what the loop declares: its ``output``, the linear
model from the speed to it (``statespace``: B, C, D), the characteristic polynomial of A
(``charpoly``, for design/poles.py's batched roots), and :func:`disturbance_function` the model from a
:class:`Disturbance` input (e.g. current-sensor noise). A tuner differentiates the same Functions.

For an observer on a PMSM the plant is the motor in steady state at the operating point under ideal
current control: :func:`pmsm_steady` gives its MTPA current and steady voltage in rotor coordinates
from the shared PMSM model (symbolic/pmsm.py) for the plant vector :func:`pmsm_plant`, and
:func:`pmsm_steady_current` the current numerically (the samples of design/discrete.py
``pmsm_zoh_plant``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.batch import evaluate_batch, mapped
from sensorless.design.compiled import compiled
from sensorless.design.memo import kept_function
from sensorless.design.pmsm_schema import PmsmMotor
from sensorless.design.poles import eigvals_batched
from sensorless.symbolic.linalg import charpoly
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current, stator_voltage

NEWTON_STEPS = 12
RESIDUAL = 1e-9  # converged: |f_r|_inf at most this times max(|x_r|_inf, 1)
# the continuation: at rest where |f_r|_inf <= AT_REST (1 + |w| + |x_r(start)|_inf); a step that moves
# the loop's angle by JUMP or more lands on another branch; steps start at FIRST_STEP of tau, double
# after a success (at most MAX_STEP), halve after a failure; a point whose step falls below MIN_STEP
# has no equilibrium on the branch (a fold: e.g. the observer cannot hold the rotor's position)
AT_REST = 1e-6
JUMP = 0.3  # [rad]
FIRST_STEP, MAX_STEP, MIN_STEP = 0.25, 0.5, 1e-3
ROUNDS = 60


@dataclass(frozen=True, eq=False)
class Continuation:
    """How a :class:`RotorFrameLoop` reaches equilibria that Newton's method from its ``start`` misses:
    Newton's method continued from the parameters ``p0`` where ``start`` is the equilibrium."""

    anchor: ca.Function  # (plant[m], p[k]) -> p0[k]: the loop's ``p`` where ``start`` is exact
    angle: int  # index in x_r of the angle whose jump marks another branch (JUMP)


@dataclass(frozen=True, eq=False)
class Disturbance:
    """An input ``d`` of a :class:`RotorFrameLoop` that is zero in the loop itself (e.g. the current
    sensor's noise) and the outputs ``z`` it is judged by: :func:`disturbance_function` gives the loop's
    linear model from it."""

    rates: ca.Function  # (x_r, w, torque, plant, p, d) -> f_r: the loop's rates with d added
    output: ca.Function  # (x_r, w, torque, plant, p, d) -> z


@dataclass(frozen=True, eq=False)
class RotorFrameLoop:
    """A family's continuous observer in rotor coordinates (module docstring); hashable by identity,
    so declare it once (e.g. in a ``functools.cache``d function). The Functions built from it are
    kept on disk by its content (design/memo.py ``kept_function``: its Functions pickle as their
    serialization; a ``disturbance`` builder must pickle too, a module-level function or a partial
    of one, else they are kept in the process only)."""

    name: str  # for the Functions built from it
    rates: ca.Function  # (x_r[n], w, torque, plant[m], p[k]) -> f_r[n]
    start: ca.Function  # (w, torque, plant[m], p[k]) -> x_r[n]: where Newton's method starts
    # what the family reads at the equilibrium (e.g. the observer's steady angle error): (x_r[n], w,
    # torque, plant[m], p[k]) -> y[l]; None: nothing
    output: ca.Function | None = None
    # where Newton's method from ``start`` misses the equilibrium: follow the branch from where it is
    # exact (:func:`continued_equilibria`); None: NEWTON_STEPS from ``start``
    continuation: Continuation | None = None
    # the linear model from the speed w to the ``output`` too (a transfer function such as G_c(s) of the
    # speed estimate): B = df_r/dw, C = dy/dx_r, D = dy/dw at the equilibrium
    statespace: bool = False
    # the characteristic polynomial of A in the same Function (design/poles.py ``eigvals_batched(A, c)``
    # takes its roots): its SX terms where A has structural zeros, not a numeric product afterwards,
    # which differs in the last bits (3e-15 relative)
    charpoly: bool = False
    # builds its :class:`Disturbance` where one is asked for (its SX expressions cost about as much to
    # build as the loop's own: not every command needs them); None: none
    disturbance: Callable[[], Disturbance] | None = None

    @property
    def n_x(self) -> int:
        return int(self.rates.size1_in(0))


def _symbols(loop: RotorFrameLoop) -> tuple[ca.SX, ...]:
    """Fresh symbols (x_r, w, torque, plant, p) of the loop's inputs."""
    sizes = (loop.n_x, 1, 1, loop.rates.size1_in(3), loop.rates.size1_in(4))
    return tuple(ca.SX.sym(k, m) for k, m in zip(("x_r", "w", "torque", "plant", "p"), sizes, strict=True))


@kept_function
def equilibrium_function(loop: RotorFrameLoop) -> ca.Function:
    """(w, torque, plant, p) -> (x_r*, A, res, f_r[, y, ...]): NEWTON_STEPS Newton steps on f_r(x_r) = 0
    from the loop's start, and :func:`point_function` where they end."""
    x_r, w, T, plant, p = _symbols(loop)
    G = loop.rates(x_r, w, T, plant, p)
    g_fn = ca.Function("G", [x_r, w, T, plant, p], [G, ca.jacobian(G, x_r)])
    xk = loop.start(w, T, plant, p)
    for _ in range(NEWTON_STEPS):
        Gk, Jk = g_fn(xk, w, T, plant, p)
        xk = xk - ca.solve(Jk, Gk)
    at = point_function(loop)
    return ca.Function(
        f"{loop.name}_equilibrium_c",
        [w, T, plant, p],
        [xk, *at.call([xk, w, T, plant, p])],
        ["w", "torque", "plant", "p"],
        ["x", *at.name_out()],
    )


@kept_function
def start_function(loop: RotorFrameLoop) -> ca.Function:
    """(w, torque, plant, p) -> (x_r, A, res, f_r[, y, ...]): :func:`point_function` at the loop's
    start, in one Function: where ``p`` is its continuation's anchor at every point the start is the
    equilibrium (a closed form), and a sweep of thousands of points needs no Newton step."""
    _, w, T, plant, p = _symbols(loop)
    x0 = loop.start(w, T, plant, p)
    at = point_function(loop)
    return ca.Function(
        f"{loop.name}_start_c",
        [w, T, plant, p],
        ca.cse([ca.densify(x0), *at.call([x0, w, T, plant, p])]),
        ["w", "torque", "plant", "p"],
        ["x", *at.name_out()],
    )


@dataclass(frozen=True)
class Equilibria:
    """The equilibria of a :class:`RotorFrameLoop` at N operating points (NaN rows where Newton's method
    does not converge) and what the loop declares there."""

    x: np.ndarray  # (N, n) the rotor-frame state
    A: np.ndarray  # (N, n, n) the Jacobian df_r/dx_r
    ok: np.ndarray  # (N,) converged
    y: np.ndarray | None  # (N, l) the loop's ``output`` there, None without one
    # the linear model from w to the output (N, n, 1), (N, l, n), (N, l, 1) where the loop is ``statespace``
    B: np.ndarray | None = None
    C: np.ndarray | None = None
    D: np.ndarray | None = None
    c: np.ndarray | None = None  # (N, n+1) the characteristic polynomials of A (``charpoly``)

    def poles(self, rows: np.ndarray | None = None) -> np.ndarray:
        """(N, n) the eigenvalues of A (the roots of ``c`` where the loop gives it) at the points in
        ``rows`` (a mask; default: every point with an equilibrium), NaN elsewhere."""
        sel = self.ok if rows is None else self.ok & rows
        out = np.full(self.x.shape, np.nan + 0j)
        if sel.any():
            out[sel] = eigvals_batched(self.A[sel], None if self.c is None else self.c[sel])
        return out


@kept_function
def point_function(loop: RotorFrameLoop) -> ca.Function:
    """(x_r, w, torque, plant, p) -> (A, res, f_r[, y][, B, C, D][, c]) at a given state: the Jacobian
    df_r/dx_r, the residual |f_r|_inf, the rates, the loop's ``output``, its linear model from w
    (``statespace``) and the characteristic polynomial of A (``charpoly``)."""
    x_r, w, T, plant, p = _symbols(loop)
    G = loop.rates(x_r, w, T, plant, p)
    A = ca.jacobian(G, x_r)
    outs = {"A": A, "res": ca.norm_inf(G), "f_r": G}
    if loop.output is not None:
        outs["y"] = y = loop.output(x_r, w, T, plant, p)
        if loop.statespace:
            outs |= {"B": ca.jacobian(G, w), "C": ca.jacobian(y, x_r), "D": ca.jacobian(y, w)}
    if loop.charpoly:
        outs["c"] = ca.vertcat(*charpoly(A))
    return ca.Function(
        f"{loop.name}_point_c",
        [x_r, w, T, plant, p],
        ca.cse([ca.densify(v) for v in outs.values()]),  # dense: evaluate_batch
        ["x_r", "w", "torque", "plant", "p"],
        list(outs),
    )


@kept_function
def disturbance_function(loop: RotorFrameLoop) -> ca.Function:
    """(x_r, w, torque, plant, p) -> (B_d, C_d, D_d): the linear model of the loop's :class:`Disturbance`
    at d = 0, B_d = df_r/dd, C_d = dz/dx_r, D_d = dz/dd (e.g. design/noise.py's noise gain)."""
    if loop.disturbance is None:
        raise ValueError(f"the loop {loop.name} declares no disturbance")
    dist = loop.disturbance()
    x_r, w, T, plant, p = _symbols(loop)
    d = ca.SX.sym("d", dist.rates.size1_in(5))
    G, z = (fn(x_r, w, T, plant, p, d) for fn in (dist.rates, dist.output))
    outs = [ca.jacobian(G, d), ca.jacobian(z, x_r), ca.jacobian(z, d)]
    return ca.Function(
        f"{loop.name}_disturbance_c",
        [x_r, w, T, plant, p],
        ca.cse([ca.densify(ca.substitute(o, d, ca.DM.zeros(d.shape))) for o in outs]),
        ["x_r", "w", "torque", "plant", "p"],
        ["B_d", "C_d", "D_d"],
    )


def equilibrium_points(
    loop: RotorFrameLoop, w: ArrayLike, torque: ArrayLike, plant: ArrayLike, p: ArrayLike
) -> Equilibria:
    """The equilibria at the N points (w, torque), batched: ``plant`` one vector or one column per
    point, ``p`` likewise (continued where the loop declares a :class:`Continuation`; its start where
    ``p`` is the continuation's anchor at every point)."""
    W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
    n, cont = W.size, loop.continuation
    P, Q = _columns(plant, n), _columns(p, n)
    if cont is None:
        out = _named(equilibrium_function(loop), n, [W, T, P, Q])
        x = out["x"][:, :, 0]
        ok = np.isfinite(out["A"]).all(axis=(1, 2))
        ok &= out["res"][:, 0, 0] <= RESIDUAL * np.maximum(np.abs(x).max(axis=1), 1.0)
    elif np.array_equal(_anchor(cont, P, Q), Q):  # the start is the equilibrium: no Newton step
        out = _named(start_function(loop), n, [W, T, P, Q])
        ok = np.isfinite(out["A"]).all(axis=(1, 2))
    else:
        x = continued_equilibria(loop, W, T, P, Q)
        found = np.isfinite(x).all(axis=0)
        out = _named(point_function(loop), n, [np.where(found, x, 0.0), W[None, :], T[None, :], P, Q])
        out["x"] = x.T[:, :, None]
        ok = found & np.isfinite(out["A"]).all(axis=(1, 2))
    return _equilibria(out, ok)


def _named(fn: ca.Function, n: int, args: list[np.ndarray]) -> dict[str, np.ndarray]:
    """evaluate_batch of ``fn`` at n points, by output name."""
    return dict(zip(fn.name_out(), evaluate_batch(fn, n, args), strict=True))


def _equilibria(out: dict[str, np.ndarray], ok: np.ndarray) -> Equilibria:
    """The :class:`Equilibria` of a batch's outputs, NaN where not ``ok``."""

    def masked(k: str) -> np.ndarray | None:
        a = out.get(k)
        if a is None:
            return None
        a = a[:, :, 0] if k in ("x", "y", "c") else a  # vectors per point; matrices stay (N, r, c)
        return np.where(ok.reshape(-1, *[1] * (a.ndim - 1)), a, np.nan)

    x, A, y, B, C, D, c = map(masked, ("x", "A", "y", "B", "C", "D", "c"))
    assert x is not None and A is not None
    return Equilibria(x, A, ok, y, B, C, D, c)


@functools.cache
def _rootfinder(loop: RotorFrameLoop) -> ca.Function:
    """Newton's method on the loop's rates: (x_r guess, w, torque, plant, p) -> x_r."""
    f = loop.rates
    # Newton's steps evaluate the Jacobian the rootfinder would generate itself, compiled (cached on
    # disk, design/compiled.py): the same operations as on CasADi's VM, so the same bits, ~3x faster.
    jac = compiled(f.factory("jac_f_z", f.name_in(), [f"jac:{f.name_out(0)}:{f.name_in(0)}", f.name_out(0)]))
    return ca.rootfinder(
        f"{loop.name}_equilibrium",
        "newton",
        f,
        # plain Newton: a backtracking line search stalls on badly scaled rates (rows in V and
        # rad/s^2); the continuation keeps the starting points close instead
        {
            "abstol": 1e-12,
            "max_iter": 30,
            "error_on_fail": False,
            "line_search": False,
            "show_eval_warnings": False,
            "jacobian_function": jac,
        },
    )


def _columns(a: ArrayLike, n: int) -> np.ndarray:
    """One vector, or one column per point, as (rows, n)."""
    a = np.asarray(a, float)
    return np.broadcast_to(a.reshape(-1, 1), (a.size, n)) if a.ndim <= 1 else a.reshape(a.shape[0], n)


def _anchor(cont: Continuation, P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """(k, n) the continuation's p0 at the n points of the columns P, Q, on CasADi's VM and one thread (a
    selection: not worth a compiled library): once where every point has the same columns (one drive,
    one gain); else padded to a power of two, so that a tuner's searches, which call this with
    ever-changing sizes, reuse a few maps (one costs ~5 ms to build)."""
    n = P.shape[1]
    if n == 0:
        return Q  # (k, 0)
    if (P == P[:, :1]).all() and (Q == Q[:, :1]).all():
        p0 = evaluate_batch(cont.anchor, 1, [P[:, 0], Q[:, 0]], jit=False)[0][0]
        return np.broadcast_to(p0, Q.shape)
    idx = np.minimum(np.arange(1 << (n - 1).bit_length()), n - 1)  # padded with the last point
    return evaluate_batch(cont.anchor, idx.size, [P[:, idx], Q[:, idx]], jit=False)[0][:n, :, 0].T


def continued_equilibria(
    loop: RotorFrameLoop, w: ArrayLike, torque: ArrayLike, plant: ArrayLike, p: ArrayLike
) -> np.ndarray:
    """(n_x, N) equilibria of a loop with a :class:`Continuation` at the N points (w, torque); NaN
    columns where the branch ends. ``plant`` and ``p`` are one vector or one column per point.

    Newton's method is continued along p(tau) = p0 + tau (p - p0) from tau = 0 (``start``, exact there)
    to tau = 1, each point with its own step (halved after a failed solve, doubled after a success),
    the points still under way advanced together in one mapped call per round (most finish in three
    rounds, a few near a fold take dozens). A solve counts where the rates are at rest (AT_REST) and the
    angle moved less than JUMP (farther is another branch, not a continuation step)."""
    cont = loop.continuation
    if cont is None:
        raise ValueError(f"the loop {loop.name} declares no continuation")
    W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
    n = W.size
    P, Q = _columns(plant, n), _columns(p, n)
    Q0 = _anchor(cont, P, Q)
    x = np.ascontiguousarray(evaluate_batch(loop.start, n, [W[None, :], T[None, :], P, Q])[0][:, :, 0].T)
    if np.array_equal(Q0, Q):  # every point at the anchor: the start is the equilibrium
        return x
    root = _rootfinder(loop)
    scale = 1.0 + np.abs(W) + np.abs(x).max(axis=0)
    tau = np.zeros(n)
    h = np.full(n, FIRST_STEP)
    lost = np.zeros(n, bool)
    for _ in range(ROUNDS):
        act = np.flatnonzero((tau < 1) & ~lost)  # not the points done: the late rounds are a few points
        if act.size == 0:
            break
        t_try = np.minimum(1.0, tau[act] + h[act])
        ins = [W[None, act], T[None, act], P[:, act], Q0[:, act] + t_try * (Q[:, act] - Q0[:, act])]
        x_try = np.asarray(mapped(root, act.size)(x[:, act], *ins))
        # the rootfinder does not raise on failure (error_on_fail=False): the residual says
        res = evaluate_batch(loop.rates, act.size, [x_try, *ins])[0][:, :, 0]
        ok = np.isfinite(res).all(axis=1) & (np.abs(res).max(axis=1) <= AT_REST * scale[act])
        ok &= np.abs(x_try[cont.angle] - x[cont.angle, act]) < JUMP
        x[:, act[ok]] = x_try[:, ok]
        tau[act[ok]] = t_try[ok]
        h[act] = np.where(ok, np.minimum(2 * h[act], MAX_STEP), h[act] / 2)
        lost[act] |= ~ok & (h[act] < MIN_STEP)
    x[:, lost | (tau < 1)] = np.nan
    return x


def pmsm_plant(motor: PmsmMotor) -> np.ndarray:
    """[R_s, L_d, L_q, psi_pm, p] of the true motor: the ``plant`` of :func:`pmsm_steady`."""
    return np.array([*motor.vector(), float(motor.p)])


def pmsm_steady(w: ca.SX, T_e: ca.SX, plant: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(i_r, u_r): the rotor-frame MTPA current for torque T_e and the steady stator voltage at speed w
    of the motor ``plant`` = [R_s, L_d, L_q, psi_pm, p] (symbolic/pmsm.py)."""
    motor = PmsmParams(plant[0], plant[1], plant[2], plant[3])
    i_r = mtpa_current(T_e, motor, plant[4])
    return i_r, stator_voltage(i_r, 0, flux_from_current(i_r, motor), w, motor.R_s)


@functools.cache
def steady_current_function() -> ca.Function:
    """casadi.Function (T_e [N m], plant) -> the rotor-frame MTPA current [i_d, i_q] of
    :func:`pmsm_steady`. Built once: design/motor_data.py evaluates it point by point (80 times on each
    load of a drive file), :func:`pmsm_steady_current` in batches."""
    T_e, plant = ca.SX.sym("T_e"), ca.SX.sym("plant", 5)
    return ca.Function("pmsm_steady_current", [T_e, plant], [pmsm_steady(0, T_e, plant)[0]])


def pmsm_steady_current(torque: np.ndarray, plant: np.ndarray) -> np.ndarray:
    """(N, 2) rotor-frame MTPA currents for the torques (N,) [N m] of the motor ``plant`` (one vector,
    or one column per point: e.g. a Monte-Carlo draw's motor)."""
    T = np.ravel(torque).astype(float)
    return evaluate_batch(steady_current_function(), T.size, [T, plant])[0][:, :, 0]
