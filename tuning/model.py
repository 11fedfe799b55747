"""What the shared NLP needs from a tunable gain law on a drive: the TuningModel contract.

A tunable gain law (tuning/family.py) on a drive supplies one :class:`TuningModel`. The
generic NLP (tuning/nlp.py) and the verification only see this: a parameter vector theta with
bounds; ``local``, what the closed loop at one operating point needs of theta (phi: e.g. the gains
and their slopes there), so that per-point derivatives do not grow with the size of theta; the
linearized closed loop as a CasADi Function of (phi, state, operating point) built from the analysis
model in symbolic/ (never a second copy of the equations); numeric equilibria; and the gains to
write into the table. A tunable's ``build`` returns one (tuning/family.py).

Optional parts, each used by the shared pipeline where given:

- ``noise``: the linearization's input from current-measurement noise and its noise outputs (the
  estimates), for the noise figure (design/noise.py), ``--max-noise`` and the Pareto front;
- ``starts``: candidate parameter vectors of the global phase (a log grid of the law's parameters,
  tuning/search.py);
- ``pointwise``: a model of the free gains at one operating point (theta = what ``local`` gives, less
  the slopes), for the pointwise bound (tuning/bound.py), and ``from_pointwise`` to turn the
  per-speed optima into a start of this law;
- ``gain_size``: a dimensionless size of the gains theta gives over the speed range, for the
  tie-break among equally damped gains (tuning/tiebreak.py);
- ``smooth_box``: where a law is piecewise in its parameters, the piece around theta (the NLP's trust
  region stays within it).
- ``bounded``: per-point linear figures of the closed loop (phi, x, point) -> (k,) that the tuned gains
  must not make worse than the drive file's (|figure| <= |the drive file's| at each nominal point where
  the drive file's gains are stable; ``bounded_reference``): e.g. the angle lag under acceleration, which
  the damping does not see. Every step that judges the constraints (global phase, NLP, dense selection,
  tie-break) holds them.

Batched evaluation of many parameter vectors at once: :func:`evaluate`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch, settled
from sensorless.design.memo import OwnedMemo
from sensorless.design.noise import noise_rms
from sensorless.design.poles import batched_path, charpoly_ready, eigvals_batched, max_real, worst_damping


@dataclass(frozen=True, eq=False)  # identity-hashed: Functions are cached per model
class TuningModel:
    """A tunable law on one drive.

    Operating points are columns of a point matrix (rows: ``point_names``); each point carries the
    true speed and torque and the *estimated* parameters the observer uses there, so parameter-error
    scenarios are just more points.
    """

    law: str
    names: tuple[str, ...]  # tunable parameters, in theta order
    units: tuple[str, ...]
    theta0: np.ndarray  # the drive file's gains: the baseline (and the NLP's start if no ``start``)
    lower: np.ndarray  # box bounds of theta
    upper: np.ndarray
    typical: np.ndarray  # magnitudes that scale theta to O(1) for the NLP
    local: ca.Function  # (theta, point) -> phi: what the closed loop at the point needs of theta
    phi_typical: np.ndarray  # magnitudes of phi
    linearization: ca.Function  # (phi, x, point) -> (A [1/s], x_dot): the analysis model
    x_typical: np.ndarray  # magnitudes of the states (scale of the equilibrium unknowns)
    point_names: tuple[str, ...]
    make_points: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (w_m, T_e, est) -> P
    equilibrium: Callable[[np.ndarray, np.ndarray], np.ndarray]  # (theta, P) -> x0 (n_x, N); NaN: none
    regularizer: Callable[[ca.SX], ca.SX] | None  # dimensionless penalty of theta (x smoothing); None: none
    table_gains: Callable[[np.ndarray], dict[str, Any]]  # the gain table's "gains" entry
    point_gains: Callable[[np.ndarray, np.ndarray], dict[str, np.ndarray]]  # (theta, w_hat) -> columns
    nominal_estimate: np.ndarray  # the drive's own estimates (no error)
    estimate_names: tuple[str, ...]  # names of the estimate entries of a point, for error scenarios
    start: np.ndarray | None = None  # NLP start (e.g. the seed law's optimum); None: theta0
    start_label: str = ""  # what ``start`` is, for messages and the table's summary
    hessian: str = "exact"  # IPOPT hessian_approximation: "exact" or "limited-memory" (L-BFGS)
    # noise: (phi, x, point) -> (B_n, C_n, D_n): current-noise input and noise outputs (names, units)
    noise: ca.Function | None = None
    noise_outputs: tuple[str, ...] = ()
    noise_units: tuple[str, ...] = ()
    noise_sigma: float = 0.0  # current-sensor noise [A rms per axis and sample]
    T_s: float = 0.0  # sampling period of the noise convention [s]
    starts: Callable[[], np.ndarray] | None = None  # global phase: candidates (K, n_theta)
    pointwise: Callable[[], TuningModel] | None = None  # free gains at one point (the bound)
    from_pointwise: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None  # (speeds, optima) -> theta
    # (theta, speeds (S,)) -> (S, n) the free gains of the pointwise model that theta gives at each speed
    pointwise_gains: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    fixed_equilibrium: Callable[[np.ndarray], np.ndarray] | None = (
        None  # P -> (N,) bool: x0 not moved by theta
    )
    n_initial_active: int = 0  # exchange method: points in the first round (0: 3 n_theta, at least 4)
    # P -> (N,) labels of points that share their local gains (e.g. the same speed): the exchange method's
    # first round takes the worst point of each label and condition (a rich law binds at every speed);
    # None: the n_initial_active worst points overall
    point_group: Callable[[np.ndarray], np.ndarray] | None = None
    # (K, n_theta) -> (K,): how large the gains are over the speed range (smaller wins a tie)
    gain_size: Callable[[np.ndarray], np.ndarray] | None = None
    gain_size_unit: str = ""  # its unit, for the summary's row heading
    gain_size_meaning: str = ""  # what it measures, in a few words (the tie-break's line)
    # (theta, P) -> (lower, upper): the box around theta within which ``local`` at the points P is smooth,
    # for a law with kinks in its parameters (eq. (16): omega_lambda at a point's speed); None: smooth.
    # Each exchange round's trust region stays within it (tuning/nlp.py)
    smooth_box: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
    # the law's own remark for the table's summary: e.g. which parameters its box holds at one value, and why
    note: str = ""
    # (phi, x, point) -> (k,): figures that must not get worse than the drive file's gains' (module docstring)
    bounded: ca.Function | None = None
    bounded_names: tuple[str, ...] = ()  # what each figure is, for messages and the summary
    bounded_tolerance: float = 0.0  # relative: |figure| <= (1 + this) |the drive file's|

    @property
    def n_theta(self) -> int:
        """Number of tunable parameters."""
        return len(self.names)

    @property
    def n_x(self) -> int:
        """States of the linearized closed loop."""
        return int(self.linearization.size1_in(1))


def poles(model: TuningModel, theta: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(poles (N, n) complex, x0 (n_x, N)) of the linearized closed loop at the points P, by the same
    Function the NLP differentiates; NaN rows where no equilibrium exists. ``theta`` is one parameter
    vector (n_theta,) or one per point (n_theta, N)."""
    e = evaluate(model, theta, P)
    return e.poles, e.x0


@dataclass(frozen=True)
class Evaluation:
    """Figures of a model at N points (each with its own parameter vector or a common one)."""

    poles: np.ndarray  # (N, n) complex [1/s]; NaN rows where no equilibrium
    x0: np.ndarray  # (n_x, N)
    noise: np.ndarray | None  # (N, n_out) RMS of the noise outputs; inf where unstable
    # (N,) min over the model's bounded figures of 1 - |figure| / reference (bounded_reference): >= 0 met;
    # inf where not bounded (no figures, estimate errors, the drive file's gains unstable there)
    bounded: np.ndarray | None = None

    @property
    def damping(self) -> np.ndarray:
        return worst_damping(self.poles)

    @property
    def decay(self) -> np.ndarray:
        return -max_real(self.poles)


@functools.cache
def _dense(fn: ca.Function) -> ca.Function:
    """``fn`` with dense outputs (what the batched evaluation needs)."""
    if all(fn.sparsity_out(j).is_dense() for j in range(fn.n_out())):
        return fn
    sx = fn.sx_in()
    return ca.Function(
        fn.name() + "_dense", sx, [ca.densify(o) for o in fn.call(sx)], fn.name_in(), fn.name_out()
    )


def _bucket(n: int) -> int:
    """Batch sizes rounded up to 1, 2 or 3 times a power of two (at most 50 % padding): a mapped
    Function is built once per size, and searches evaluate batches of ever-changing sizes."""
    p = 1
    while 3 * p < n:
        p *= 2
    return min(c for c in (p, 2 * p, 3 * p, 4 * p) if c >= n)


def _call(fn: ca.Function, n: int, args: list[np.ndarray]) -> list[np.ndarray]:
    """Outputs of ``fn`` at n points as arrays (n, rows, cols): the batched path of design/batch.py
    (numpy buffers, JIT for large batches, maps of a few bucket sizes). Padded to a bucket size by
    repeating the last point until ``fn`` is compiled for good (design/batch.py ``settled``): the padding
    counts towards the points that switch it from CasADi's VM to the compiled library, whose last bits
    may differ; from then on a point's bits do not depend on its batch, and padding is only work."""
    fn = _dense(fn)
    m = _bucket(n)
    if m == n or settled(fn):
        return evaluate_batch(fn, n, args)
    padded = []
    for i, a in enumerate(args):
        a = np.asarray(a, float)
        rows = fn.size1_in(i)
        if a.size != rows:  # one column per point: repeat the last
            a = a.reshape(rows, n)
            a = np.concatenate([a, np.repeat(a[:, -1:], m - n, axis=1)], axis=1)
        padded.append(a)
    return [o[:n] for o in evaluate_batch(fn, m, padded)]


# The equilibria of points where they do not move with the gains (``TuningModel.fixed_equilibrium``),
# solved once a point per model: such a point's equilibrium is the same whatever the gains or the batch it
# is solved in (the closed form at exact estimates, on CasADi's VM or compiled alike), and the tuner asks
# for the same points again and again: a tune the same envelope and dense grids for hundreds of candidate
# gains (a batch of K candidates on the same points, ``np.tile``), the pointwise bound (tuning/bound.py)
# thousands of gains at each of a few hundred points, in ever-changing subsets of its speeds x torques (a
# fifth of its evaluation's CPU went to the same equilibria again). Only those points: elsewhere
# (estimate errors) the equilibrium is solved for and moves with the gains. Per model: the points solved
# (their bytes as one item each, sorted) and their equilibria (n_x, K) in that order, replaced whole when
# it grows, never changed in place (a threaded scheduler may tune in several threads); up to
# FIXED_X0_POINTS points a model (6 rows and 4 states: 5 MB; a tune's models hold a few thousand each)
_FIXED_X0: OwnedMemo[tuple[np.ndarray, np.ndarray]] = OwnedMemo(16)
FIXED_X0_POINTS = 1 << 16


def _point_keys(P: np.ndarray) -> np.ndarray:
    """(N,) the columns of P as single items of their bytes (np.void): sortable, comparable whole."""
    cols = np.ascontiguousarray(P.T, dtype=float)
    return cols.view(np.dtype((np.void, cols.shape[1] * cols.itemsize))).ravel()


def fixed_equilibria(model: TuningModel, P: np.ndarray) -> np.ndarray | None:
    """(n_x, N) the equilibria at the points P where none moves with the gains (``fixed_equilibrium``
    true at all of them), else None: those the model has solved from its table (above), the others solved
    once each (at the drive file's gains, which they do not depend on) and added to it."""
    if model.fixed_equilibrium is None or not np.all(model.fixed_equilibrium(P)):
        return None
    q = _point_keys(P)
    kept = _FIXED_X0.get(model, b"")
    keys, x = kept if kept is not None else (q[:0], np.zeros((model.n_x, 0)))
    at = np.searchsorted(keys, q)
    found = np.zeros(q.size, bool)
    inside = at < keys.size
    found[inside] = keys[at[inside]] == q[inside]
    if found.all():
        return x[:, at]
    new, first = np.unique(q[~found], return_index=True)
    solved = np.asarray(model.equilibrium(model.theta0, P[:, np.flatnonzero(~found)[first]]), float)
    keys, x = np.concatenate([keys, new]), np.concatenate([x, solved], axis=1)
    order = np.argsort(keys, kind="stable")
    keys, x = keys[order], x[:, order]
    if keys.size <= FIXED_X0_POINTS:
        _FIXED_X0.put(model, b"", (keys, x))
    return x[:, np.searchsorted(keys, q)]


def _eigvals(n: int, A: np.ndarray, extra: int) -> np.ndarray:
    """Eigenvalues of A (N, n, n) as a batch with ``extra`` copies of its last matrix gives them
    (evaluate's padding): without the copies where that runs the same code (design/poles.py: the same
    path either way, and on the batched one the characteristic polynomials compiled for good)."""
    N = A.shape[0]
    batched = batched_path(n, N)
    if extra and (batched != batched_path(n, N + extra) or (batched and not charpoly_ready(n))):
        return eigvals_batched(np.concatenate([A, np.repeat(A[-1:], extra, axis=0)]))[:N]
    return eigvals_batched(A)


def evaluate(model: TuningModel, theta: np.ndarray, P: np.ndarray, noise: bool = False) -> Evaluation:
    """Poles (and, with ``noise``, the noise figure) at the points P (n_p, N) for ``theta`` (n_theta,)
    or one parameter vector per point (n_theta, N): many candidate gains in one batched call."""
    N = P.shape[1]
    theta = np.asarray(theta, float)
    if N == 0:
        n_out = len(model.noise_outputs)
        return Evaluation(
            np.zeros((0, model.n_x), complex),
            np.zeros((model.n_x, 0)),
            np.zeros((0, n_out)) if noise else None,
        )
    # A batch of points where the equilibria do not move with the gains is evaluated as if padded to a
    # bucket size (repeating the last point, results cut back to N), as it was when every batched call
    # built a mapped Function per size: the same paths (VM or compiled, eigenvalue method), so the same
    # bits; the copies themselves only where they change a path (_call, _eigvals) or the noise figure is
    # asked for. Not where an equilibrium must be solved for (estimate errors): no padding there.
    M = _bucket(N)
    x0 = fixed_equilibria(model, P)
    closed = x0 is not None
    if x0 is None:
        x0 = model.equilibrium(theta, P)
    if M > N and closed and noise:
        P = np.concatenate([P, np.repeat(P[:, -1:], M - N, axis=1)], axis=1)
        if theta.ndim == 2:
            theta = np.concatenate([theta, np.repeat(theta[:, -1:], M - N, axis=1)], axis=1)
        x0 = np.concatenate([x0, np.repeat(x0[:, -1:], M - N, axis=1)], axis=1)
        e = _evaluate(model, theta, P, x0, noise, 0)
        return Evaluation(
            e.poles[:N],
            e.x0[:, :N],
            None if e.noise is None else e.noise[:N],
            None if e.bounded is None else e.bounded[:N],
        )
    return _evaluate(model, theta, P, x0, noise, M - N if closed else 0)


def _evaluate(
    model: TuningModel, theta: np.ndarray, P: np.ndarray, x0: np.ndarray, noise: bool, extra: int
) -> Evaluation:
    """:func:`evaluate` at the equilibria x0, as a batch with ``extra`` copies of its last point gives it."""
    N = P.shape[1]
    ok = np.isfinite(x0).all(axis=0)
    n = model.n_x
    out = np.full((N, n), np.nan + 0j)
    nz = None
    bm = None
    if model.bounded is not None:
        bm = np.full(N, np.inf)
    if noise:
        if model.noise is None:
            raise ValueError(f"gain law {model.law} has no noise model")
        nz = np.full((N, len(model.noise_outputs)), np.nan)
    if ok.any():
        xs = np.where(ok, x0, 0.0)
        th = theta if theta.ndim == 1 else np.ascontiguousarray(theta)
        phi = _call(model.local, N, [th, P])[0][:, :, 0].T
        A = _call(model.linearization, N, [phi, xs, P])[0]
        good = ok & np.isfinite(A).all(axis=(1, 2))
        if good.any():
            out[good] = _eigvals(n, A[good], extra if good[-1] else 0)
        if noise and good.any():
            B, C, D = _call(model.noise, N, [phi, xs, P])
            nz[good] = noise_rms(
                A[good], B[good], C[good], D[good], model.noise_sigma, model.T_s, poles=out[good]
            )
        if bm is not None:
            bm = bounded_margin(model, _call(model.bounded, N, [phi, xs, P])[0][:, :, 0], P, good)
    return Evaluation(out, x0, nz, bm)


# bounded_reference's caches (a tune evaluates the same grids often): the references of the distinct
# points, keyed on theta0's and those points' bytes; and, for the points as asked (not made distinct,
# which sorts them: np.unique along an axis, 0.1-0.2 s of the README servo's tune), their references
_REFERENCES: OwnedMemo[np.ndarray] = OwnedMemo(256)
_SEEN: OwnedMemo[np.ndarray] = OwnedMemo(32)


def bounded_reference(model: TuningModel, P: np.ndarray) -> np.ndarray:
    """(N, k) the bound of each of the model's ``bounded`` figures at the points P: (1 + tolerance) x
    |the figure of the drive file's gains (theta0)|, at the points with the drive's own estimates where
    those gains are stable; inf elsewhere (no bound: estimate-error points, or where the drive file's
    gains are unstable, whose figure bounds nothing)."""
    assert model.bounded is not None
    k = int(model.bounded.size1_out(0))
    N = P.shape[1]
    out = np.full((N, k), np.inf)
    if N == 0:
        return out
    nominal = np.all(P == model.make_points(P[0], P[1], model.nominal_estimate), axis=0)
    if not nominal.any():
        return out
    Pn = np.ascontiguousarray(P[:, nominal])
    theta0_bytes = np.asarray(model.theta0, float).tobytes()
    seen_key = theta0_bytes + repr(Pn.shape).encode() + Pn.tobytes()
    seen = _SEEN.get(model, seen_key)
    if seen is not None:  # the same points again: their references as before
        out[nominal] = seen
        return out
    Pu, inv = np.unique(Pn, axis=1, return_inverse=True)
    key = theta0_bytes + Pu.tobytes()
    ref = _REFERENCES.get(model, key)
    if ref is None:
        theta0 = np.asarray(model.theta0, float)
        x0 = fixed_equilibria(model, Pu)
        if x0 is None:
            x0 = model.equilibrium(theta0, Pu)
        ok = np.isfinite(x0).all(axis=0)
        ref = np.full((Pu.shape[1], k), np.inf)
        if ok.any():
            xs = np.where(ok, x0, 0.0)
            phi = _call(model.local, Pu.shape[1], [theta0, Pu])[0][:, :, 0].T
            A = _call(model.linearization, Pu.shape[1], [phi, xs, Pu])[0]
            f = _call(model.bounded, Pu.shape[1], [phi, xs, Pu])[0][:, :, 0]
            good = ok & np.isfinite(A).all(axis=(1, 2)) & np.isfinite(f).all(axis=1)
            stable = np.zeros_like(good)
            stable[good] = max_real(eigvals_batched(A[good])) < 0
            ref[stable] = (1.0 + model.bounded_tolerance) * np.abs(f[stable])
        _REFERENCES.put(model, key, ref)
    out[nominal] = _SEEN.put(model, seen_key, ref[np.asarray(inv).ravel()])
    return out


def bounded_margin(model: TuningModel, values: np.ndarray, P: np.ndarray, good: np.ndarray) -> np.ndarray:
    """(N,) min over the figures of 1 - |value| / bound at the points P (``values`` (N, k) of the gains
    judged; ``good``: where they have a finite linearization): >= 0 where every figure is within its
    bound, inf where none is bounded, -inf where a bounded figure is not finite."""
    ref = bounded_reference(model, P)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.isfinite(ref), 1.0 - np.abs(values) / ref, np.inf)
    r = np.where(np.isnan(r), -np.inf, r)
    r = r.min(axis=1) if r.shape[1] else np.full(P.shape[1], np.inf)
    return np.where(good, r, np.inf)
