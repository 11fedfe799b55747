"""Noise gains of linearized observers: the RMS of the estimates driven by current-measurement noise.

Convention (used by every family, stated in docs/tuning.md). The current sensor adds to each sample,
every T_s, independent zero-mean noise of ``sigma`` A rms on each axis (the drive file's
current-sensor noise). Through a continuous-time linearization this is white noise of two-sided
spectral density ``sigma^2 T_s`` [A^2 s] per axis (a sample held over T_s has that density at
frequencies well below 1/T_s). For ``x' = A x + B n, y = C x + D n`` with A stable the state
covariance P solves the Lyapunov equation

    A P + P A^T + sigma^2 T_s B B^T = 0

and each output, read at the samples, has the variance ``C P C^T + sigma^2 D D^T`` (its direct
feedthrough of the sample's own noise). The RMS *gain* is that RMS per A of ``sigma``. For a
discrete-time linearization ``y_(k+1) = F_k y_k + G_k n_k`` the per-sample variance propagates
exactly, ``P_(k+1) = F_k P_k F_k^T + sigma^2 G_k G_k^T`` (periodic steady state over a window).
"""

from __future__ import annotations

import numpy as np
from sensorless.design.poles import eigvals_finite


def lyapunov(A: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """P with A P + P A^T + Q = 0 for each of the (N, n, n) matrices (Kronecker form, batched).

    Unique when no two eigenvalues of A sum to zero; a covariance only for a stable A."""
    N, n, _ = A.shape
    eye = np.eye(n)
    K = np.einsum("nij,kl->nikjl", A, eye) + np.einsum("ij,nkl->nikjl", eye, A)
    K = K.reshape(N, n * n, n * n)
    p = np.linalg.solve(K, -Q.reshape(N, n * n, 1))
    P = p.reshape(N, n, n)
    return 0.5 * (P + P.transpose(0, 2, 1))


# poles given to noise_rms decide a matrix's stability where their largest real part is this far (relative
# to their largest magnitude) from zero: far beyond the error of any eigenvalue method (a triple root from
# a characteristic polynomial with 1e-12 backward error: ~1e-4); LAPACK decides the others, as it did all
CLEAR = 1e-2


def noise_rms(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    sigma: float,
    T_s: float,
    poles: np.ndarray | None = None,
) -> np.ndarray:
    """(N, n_y) RMS of each output for current noise of ``sigma`` A rms per axis and sample at T_s
    (module docstring). inf where A is not stable (no stationary variance), NaN where A is NaN.
    ``poles`` (N, n): A's eigenvalues where the caller has them (design/poles.py ``eigvals_batched``):
    where they are clearly stable or unstable (CLEAR) they decide, without LAPACK's (the tuner's dense
    grids: 0.1 s CPU of the README servo's tune); the same decision."""
    N = A.shape[0]
    out = np.full((N, C.shape[1]), np.nan)
    ok = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(B).all(axis=(1, 2))
    if not ok.any():
        return out
    stable = np.zeros(N, bool)
    ask = ok.copy()
    if poles is not None:
        with np.errstate(invalid="ignore"):
            top = poles.real.max(axis=1)
            size = np.abs(poles).max(axis=1)
            clear = ok & np.isfinite(top) & np.isfinite(size) & (np.abs(top) > CLEAR * size)
        stable[clear] = top[clear] < 0
        ask &= ~clear
    if ask.any():
        stable[ask] = np.linalg.eigvals(A[ask]).real.max(axis=1) < 0
    out[ok & ~stable] = np.inf
    if stable.any():
        a, b, c, d = A[stable], B[stable], C[stable], D[stable]
        P = lyapunov(a, sigma**2 * T_s * b @ b.transpose(0, 2, 1))
        var = np.einsum("nij,njk,nik->ni", c, P, c) + sigma**2 * np.einsum("nij,nij->ni", d, d)
        out[stable] = np.sqrt(np.maximum(var, 0.0))
    return out


def noise_rms_periodic(
    F: np.ndarray,
    G: np.ndarray,
    C: np.ndarray,
    sigma: float,
    steps: np.ndarray | None = None,
    rho: np.ndarray | None = None,
) -> np.ndarray:
    """(N, n_y) RMS over one period of ``y_k = C x_k`` for ``x_(k+1) = F_k x_k + G_k n_k`` with
    independent per-sample noise of ``sigma`` per input: F (N, M, n, n), G (N, M, n, m), C (n_y, n).

    The covariance at the window's start solves P0 = Phi P0 Phi^T + W (Phi the product of the F_k,
    W the noise accumulated over the window), then propagates through the window; the variance is
    the mean over its M samples. inf where the monodromy Phi is not stable (|z| >= 1).
    ``steps`` (N,): each point's period, its first ``steps`` samples (the rest padding: F = I, G = 0,
    left out of the mean); default M for all. ``rho`` (N,): the monodromy's spectral radius where the
    caller has computed it with the same eigenvalue routine (a one-step window, M = 1: the largest |z| of
    design/discrete.py ``eigenvalues_by_size`` of the same F), instead of computing it again."""
    N, M, n, _ = F.shape
    steps = np.full(N, M) if steps is None else np.asarray(steps)
    out = np.full((N, C.shape[0]), np.nan)
    ok = np.isfinite(F).all(axis=(1, 2, 3)) & np.isfinite(G).all(axis=(1, 2, 3))
    Phi = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    W = np.zeros((N, n, n))
    f = np.where(ok[:, None, None, None], F, 0.0)
    g = np.where(ok[:, None, None, None], G, 0.0)
    for k in range(M):
        Phi = f[:, k] @ Phi
        W = f[:, k] @ W @ f[:, k].transpose(0, 2, 1) + sigma**2 * g[:, k] @ g[:, k].transpose(0, 2, 1)
    rho = np.abs(eigvals_finite(Phi)).max(axis=1) if rho is None else np.where(ok, rho, 0.0)
    ok &= np.isfinite(rho)  # the product overflowed: no noise figure
    stable = ok & (rho < 1)
    out[ok & ~stable] = np.inf
    if not stable.any():
        return out
    ph, w = Phi[stable], W[stable]
    # discrete Lyapunov P0 = Phi P0 Phi^T + W by the Kronecker form
    m = ph.shape[0]
    K = np.eye(n * n)[None] - np.einsum("nij,nkl->nikjl", ph, ph).reshape(m, n * n, n * n)
    P = np.linalg.solve(K, w.reshape(m, n * n, 1)).reshape(m, n, n)
    acc = np.zeros((m, C.shape[0]))
    fs, gs, ms = f[stable], g[stable], steps[stable]
    for k in range(M):
        acc += np.where((k < ms)[:, None], np.einsum("ij,njk,ik->ni", C, P, C), 0.0)
        P = fs[:, k] @ P @ fs[:, k].transpose(0, 2, 1) + sigma**2 * gs[:, k] @ gs[:, k].transpose(0, 2, 1)
    out[stable] = np.sqrt(np.maximum(acc / ms[:, None], 0.0))
    return out
