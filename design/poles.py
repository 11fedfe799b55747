"""Poles of many small real matrices at once, and the pole metrics every family reports.

Metrics: damping ratio -Re(p)/|p| per pole, the worst per point, the largest real part and the decay
rate -max Re(p); NaN (no equilibrium at a point) stays NaN. One module so that analysis, tuning and
reports compute them the same way.

Eigenvalues: for 4x4 matrices (the adaptive observer's closed loop) the poles are the roots of the
characteristic polynomial (symbolic/linalg.py, evaluated in batch), found in closed form (Ferrari's
method with complex arithmetic, all points at once) and polished by Newton steps on the polynomial.
Every root is then checked by its backward error; rows that fail the check (near-multiple roots,
extreme scaling) are recomputed by LAPACK, as are all other matrix sizes. Tests compare with
numpy.linalg.eigvals.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from sensorless.design.batch import CORES, JIT_MIN_POINTS, evaluate_batch, settled
from sensorless.symbolic.linalg import charpoly as charpoly_sx

if TYPE_CHECKING:  # imported where the pool starts: most commands never split a batch (its logging too)
    from concurrent.futures import ThreadPoolExecutor

# The damping ratio a stability report requires by default (``sensorless report --min-damping``, every
# family's report); ``sensorless tune`` warns (exit status 3) when the best gains it finds stay below it.
MIN_DAMPING = 0.2


# --------------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------------
def damping_ratio(poles: np.ndarray) -> np.ndarray:
    """Damping ratio -Re(p)/|p| of each pole; a pole at the origin counts as 0, NaN stays NaN."""
    mag = np.abs(poles)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(mag > 0, -poles.real / np.where(mag > 0, mag, 1), 0.0)
    return np.where(np.isnan(poles), np.nan, z)


def nan_reduce(fn: Callable[..., np.ndarray], a: np.ndarray) -> np.ndarray:
    """Row-wise nanmin/nanmax that returns NaN (silently) for all-NaN rows."""
    out = np.full(a.shape[0], np.nan)
    has = ~np.isnan(a).all(axis=1)
    if has.any():
        out[has] = fn(a[has], axis=1)
    return out


def worst_damping(poles: np.ndarray) -> np.ndarray:
    """Smallest damping ratio of each row of poles (negative: unstable; NaN: no poles there)."""
    return nan_reduce(np.nanmin, damping_ratio(poles))


def max_real(poles: np.ndarray) -> np.ndarray:
    """Largest real part of each row of poles [1/s]; > 0 means unstable."""
    return nan_reduce(np.nanmax, poles.real)


def sort_poles(poles: np.ndarray) -> np.ndarray:
    """Sort each row by (imag, real), a stable order for tables and plots."""
    order = np.lexsort((poles.real, poles.imag), axis=-1)
    return np.take_along_axis(poles, order, axis=-1)


# --------------------------------------------------------------------------------------------------
# Eigenvalues in batch
# --------------------------------------------------------------------------------------------------
@functools.cache
def _charpoly_function(n: int) -> ca.Function:
    A = ca.SX.sym("A", n, n)
    return ca.Function("charpoly", [ca.vec(A)], [ca.vertcat(*charpoly_sx(A))], ["A"], ["c"])


def charpoly(A: np.ndarray) -> np.ndarray:
    """Characteristic polynomial coefficients [1, c_{n-1}, ..., c_0] of each matrix in (N, n, n)."""
    N, n, _ = A.shape
    cols = np.ascontiguousarray(A.transpose(0, 2, 1).reshape(N, n * n).T)  # column-major vec per point
    return evaluate_batch(_charpoly_function(n), N, [cols])[0][:, :, 0]


def _cbrt(z: np.ndarray) -> np.ndarray:
    return np.where(z == 0, 0, np.exp(np.log(np.where(z == 0, 1, z)) / 3))


def quartic_roots(c: np.ndarray) -> np.ndarray:
    """Roots of monic quartics x^4 + a x^3 + b x^2 + c x + d (rows of c[:, 1:]); (N, 4) complex."""
    a, b, cc, d = (c[:, k].astype(complex) for k in range(1, 5))
    # depressed quartic y^4 + p y^2 + q y + r, x = y - a/4
    p = b - 3 * a**2 / 8
    q = cc - a * b / 2 + a**3 / 8
    r = d - a * cc / 4 + a**2 * b / 16 - 3 * a**4 / 256
    # resolvent cubic 8 m^3 + 8 p m^2 + (2 p^2 - 8 r) m - q^2 = 0, by Cardano; take the root of
    # largest magnitude (never zero unless the quartic is y^4 = 0)
    A2, A1, A0 = p, (p**2 / 4 - r), -(q**2) / 8
    P = A1 - A2**2 / 3
    Q = 2 * A2**3 / 27 - A2 * A1 / 3 + A0
    disc = np.sqrt(Q**2 / 4 + P**3 / 27)
    u = _cbrt(-Q / 2 + disc)
    u2 = _cbrt(-Q / 2 - disc)
    u = np.where(np.abs(u) >= np.abs(u2), u, u2)
    w = np.exp(2j * np.pi / 3)
    best = np.zeros_like(a)
    for k in range(3):
        uk = u * w**k
        mk = uk - np.where(uk == 0, 0, P / (3 * np.where(uk == 0, 1, uk))) - A2 / 3
        best = np.where(np.abs(mk) > np.abs(best), mk, best)
    m = best
    s = np.sqrt(2 * m)
    t = np.where(s == 0, 0, q / (2 * np.where(s == 0, 1, s)))
    roots = []
    for sign in (1, -1):
        # y^2 + sign*s*y + (p/2 + m - sign*t) = 0
        B, C = sign * s, p / 2 + m - sign * t
        D = np.sqrt(B**2 - 4 * C)
        roots += [(-B + D) / 2, (-B - D) / 2]
    return np.stack(roots, axis=1) - a[:, None] / 4


def _polish(c: np.ndarray, x: np.ndarray, steps: int = 2) -> np.ndarray:
    """Newton steps on the polynomial, kept only where they reduce the residual."""
    coef = c.astype(complex)[:, :, None]
    n = c.shape[1] - 1
    for _ in range(steps):
        P = np.zeros_like(x)
        dP = np.zeros_like(x)
        for k in range(n + 1):
            dP = dP * x + P
            P = P * x + coef[:, k]
        with np.errstate(all="ignore"):
            xn = x - P / dP
            Pn = np.zeros_like(x)
            for k in range(n + 1):
                Pn = Pn * xn + coef[:, k]
        better = np.isfinite(xn) & (np.abs(Pn) < np.abs(P))
        x = np.where(better, xn, x)
    return x


def backward_error(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """|p(x)| / sum |c_k| |x|^k for each root: the relative polynomial residual."""
    n = c.shape[1] - 1
    P = np.zeros_like(x)
    S = np.zeros(x.shape)
    ax = np.abs(x)
    for k in range(n + 1):
        P = P * x + c[:, k, None]
        S = S * ax + np.abs(c[:, k, None])
    return np.abs(P) / np.where(S > 0, S, 1)


_POOL: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    """In a forked child (design/forked.py): the parent's pool threads do not exist here, and a map on
    its executor would wait for them forever; the child starts its own."""
    global _POOL
    _POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def eigvals_finite(A: np.ndarray) -> np.ndarray:
    """Eigenvalues of each matrix in (..., n, n), complex; NaN for a matrix that is not finite (a
    linearization or a product of exponentials that overflowed: numpy would raise LinAlgError)."""
    A = np.asarray(A)
    ok = np.isfinite(A).all(axis=(-2, -1))
    out = np.full(A.shape[:-1], np.nan, complex)
    if ok.any():
        out[ok] = np.linalg.eigvals(A[ok])
    return out


def eigvals_batched(A: np.ndarray, c: np.ndarray | None = None, tol: float = 1e-12) -> np.ndarray:
    """Eigenvalues of each matrix in (N, n, n); unsorted, shape (N, n) complex.

    Large batches are split over the machine's cores (numpy's array loops release the GIL).
    """
    global _POOL
    N = A.shape[0]
    k = CORES
    if N >= 8192 and k > 1:
        if _POOL is None:
            from concurrent.futures import ThreadPoolExecutor

            _POOL = ThreadPoolExecutor(k, thread_name_prefix="sensorless-poles")
        cs = [None] * k if c is None else np.array_split(c, k)
        parts = _POOL.map(_eigvals_serial, np.array_split(A, k), cs)
        return np.concatenate(list(parts))
    return _eigvals_serial(A, c, tol)


def batched_path(n: int, N: int) -> bool:
    """Whether :func:`eigvals_batched` of ``N`` (n, n) matrices takes the quartic formula's path (whose
    results differ in the last bits from LAPACK's, which it takes otherwise, matrix by matrix)."""
    return n == 4 and N >= 64


def charpoly_settled(n: int, N: int, before: bool) -> bool:
    """Whether :func:`eigvals_batched` of ``N`` (n, n) matrices computed (or computes) every matrix's
    characteristic polynomial with the code every later call uses (design/batch.py's compiled library,
    not CasADi's virtual machine first): ``before``, whether that code was settled before the call
    (:func:`charpoly_ready`), or else each part the call evaluates is large enough to settle it. A caller
    that keeps eigenvalues to reuse them for later calls' asks (tuning/search.py)."""
    if not batched_path(n, N) or before:
        return True
    part = N // CORES if N >= 8192 and CORES > 1 else N  # eigvals_batched's smallest part
    return part >= JIT_MIN_POINTS


def charpoly_ready(n: int) -> bool:
    """Whether the characteristic polynomials of (n, n) matrices run the code every later call runs."""
    return n != 4 or settled(_charpoly_function(n))


def _eigvals_serial(A: np.ndarray, c: np.ndarray | None = None, tol: float = 1e-12) -> np.ndarray:
    """Eigenvalues of each matrix in (N, n, n); unsorted, shape (N, n) complex.

    ``c`` may pass the characteristic polynomials (N, n+1) when they are already known (the
    linearization Functions compute them symbolically, which is cheaper than batched numpy products).
    """
    N, n, _ = A.shape
    if n != 4 or N < 64:
        return np.linalg.eigvals(A)
    if c is None:
        c = charpoly(A)
    with np.errstate(all="ignore"):
        x = _polish(c, quartic_roots(c))
        ok = np.isfinite(x).all(axis=1) & (backward_error(c, x).max(axis=1) < tol)
    # conjugate symmetry of real matrices: make pairs exact so sorting and damping are consistent
    x = np.where(np.abs(x.imag) <= 1e-14 * (1 + np.abs(x.real)), x.real + 0j, x)
    if not ok.all():
        x[~ok] = np.linalg.eigvals(A[~ok])
    return x
