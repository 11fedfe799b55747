"""Linear algebra on symbolic matrices: the characteristic polynomial, once for every consumer."""

from __future__ import annotations

import casadi as ca


def charpoly(A: ca.SX) -> list[ca.SX]:
    """Coefficients [1, c_(n-1), ..., c_0] of det(sI - A), highest power first (Faddeev-LeVerrier).

    Polynomial in the entries of A (no division but by the integers k), hence smooth: the linearization
    Functions evaluate it for the batched pole solver, and the tuner's sector conditions differentiate it.
    """
    n = A.size1()
    c: list[ca.SX] = [ca.SX(1)]
    M = ca.SX.eye(n)
    for k in range(1, n + 1):
        AM = A @ M
        c.append(-ca.trace(AM) / k)
        M = AM + c[-1] * ca.SX.eye(n)
    return c
