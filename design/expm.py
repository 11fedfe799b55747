"""Matrix exponentials of many small matrices at once (scaling and squaring with Padé approximants).

For a stack (N, n, n) of small matrices, e.g. the zero-order-hold sampling of a motor at every
operating point of a sweep (design/discrete.py). The degree and scaling of each
matrix follow the rules of scipy.linalg.expm (Al-Mohy and Higham 2009), so the results agree with it
to rounding; but each step is one numpy operation on the whole stack, where scipy.linalg.expm goes
matrix by matrix through BLAS calls on n x n blocks: with threaded OpenBLAS each such call waits for
worker threads, ~10 ms per 5x5 matrix on a busy machine (seconds per sweep of a few hundred points).
"""

from __future__ import annotations

import numpy as np

# Padé (m, m) coefficients b_0..b_m and the 1-norm bounds theta_m up to which each is accurate
# (Higham 2005; Al-Mohy and Higham 2009): the choices scipy.linalg.expm makes
_PADE = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (
        17643225600.0,
        8821612800.0,
        2075673600.0,
        302702400.0,
        30270240.0,
        2162160.0,
        110880.0,
        3960.0,
        90.0,
        1.0,
    ),
    13: (
        64764752532480000.0,
        32382376266240000.0,
        7771770303897600.0,
        1187353796428800.0,
        129060195264000.0,
        10559470521600.0,
        670442572800.0,
        33522128640.0,
        1323241920.0,
        40840800.0,
        960960.0,
        16380.0,
        182.0,
        1.0,
    ),
}
_THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1, 9: 2.097847961257068}
_THETA13 = 4.25
# the backward-error bounds' coefficients of the |A|^(2m+1) test (Al-Mohy and Higham 2009, as scipy)
_ELL = {3: 1.1191048088221578e-11, 5: 1.1167770708198077e-06, 7: 4.9826124310493469e-01}
_ELL.update({9: 6.5662862500000000e05, 13: 1.2573361865339437e19})


def expm_batched(A: np.ndarray) -> np.ndarray:
    """Matrix exponentials of a stack (N, n, n), every matrix at once: scaling and squaring with the
    Padé degree each matrix needs, chosen by the rules of scipy.linalg.expm.

    As in scipy, exp(A) = I + 2 (V - U)^-1 U from the approximant's odd and even parts U, V, not
    (V - U)^-1 (V + U): the small entries of exp(A) - I (what a zero-order hold needs) keep their
    relative accuracy.
    """
    A = np.array(A, float)
    N, n, _ = A.shape
    eye = np.broadcast_to(np.eye(n), A.shape)

    def norm(X: np.ndarray) -> np.ndarray:
        return np.abs(X).sum(axis=-1).max(axis=-1)  # scipy's norm, of the transposed storage

    A2 = A @ A
    A4 = A2 @ A2
    A6 = A4 @ A2
    A8 = A4 @ A4
    absA = np.abs(A)
    norm_a = norm(A)
    ok = norm_a > 0
    # |A|^k 1 for the backward-error test, k = 1, 3, 5, ... (powers 2m + 1)
    v = absA @ np.ones((N, n, 1))
    spins = {}
    for k in range(2, 28):
        v = absA @ v
        spins[k] = v[:, :, 0].max(axis=1)

    def ell(m: int, scale: np.ndarray | float = 1.0) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            r = spins[2 * m + 1] * scale ** (2 * m + 1) / (norm_a * scale) / _ELL[m]
            lm = np.ceil(np.log2(r) / (2 * m))
        return np.where(ok & np.isfinite(lm), np.maximum(lm, 0), 0).astype(int)

    with np.errstate(divide="ignore"):
        d4, d6, d8 = norm(A4) ** 0.25, norm(A6) ** (1 / 6), norm(A8) ** 0.125
        d10 = norm(A6 @ A4) ** 0.1
    eta1, eta2 = np.maximum(d4, d6), np.maximum(d6, d8)
    m = np.full(N, 13)
    for deg, eta in ((9, eta2), (7, eta2), (5, eta1), (3, eta1)):  # the smallest degree that fits
        m = np.where((eta < _THETA[deg]) & (ell(deg) == 0), deg, m)
    s = np.zeros(N, int)
    big = m == 13
    if big.any():
        with np.errstate(divide="ignore"):
            s0 = np.ceil(np.log2(np.minimum(eta2, np.maximum(d8, d10)) / _THETA13))
        s0 = np.where(np.isfinite(s0), np.maximum(s0, 0), 0).astype(int)
        s = np.where(big, s0 + ell(13, 2.0 ** -s0.astype(float)), 0)
    E = np.empty_like(A)
    for deg in np.unique(m):
        k = m == deg
        b = _PADE[int(deg)]
        X, I = A[k] / (2.0 ** s[k])[:, None, None], eye[k]
        X2 = X @ X
        P = [I, X2]  # the even powers the approximant needs
        for _ in range(2, 4 if deg == 13 else deg // 2 + 1):
            P.append(P[-1] @ X2)
        if deg == 13:  # Higham's evaluation: fewer products
            X4, X6 = P[2], P[3]
            U = X @ (
                X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2) + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * I
            )
            V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * I
        else:
            U = X @ sum(b[2 * j + 1] * P[j] for j in range(deg // 2 + 1))
            V = sum(b[2 * j] * P[j] for j in range(deg // 2 + 1))
        R = I + 2 * np.linalg.solve(V - U, U)
        for j in range(int(s[k].max(initial=0))):
            sq = j < s[k]
            R[sq] = R[sq] @ R[sq]
        E[k] = R
    return E
