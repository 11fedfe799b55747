"""Smooth, exact damping conditions for tuning: "every pole has damping >= zeta" without eigenvalues.

The worst damping ratio min_i -Re(p_i)/|p_i| of a non-symmetric matrix A is not a smooth function of
A: eigenvalues lose differentiability where they coalesce (two real poles meeting and leaving as a
complex pair), which is exactly where damping optima tend to sit. The tuner therefore never
differentiates eigenvalues. It uses this exact equivalence instead:

    every pole of A (n x n, real) has damping ratio >= zeta, 0 <= zeta < 1
    <=> p(s) = det(sI - A) = prod_i (s^2 + a_i s + b_i) [* (s + r) if n is odd]
        for some real a_i >= 0, b_i >= 0, r >= 0 with a_i^2 >= 4 zeta^2 b_i.

(<=: a quadratic factor s^2 + a s + b with a, b >= 0 has either two real roots <= 0 (damping 1) or
a complex pair of damping a / (2 sqrt(b)) >= zeta. =>: every real polynomial factors into real
quadratics and linears; pair conjugate poles, and real poles among themselves.) The factor
coefficients are extra unknowns of the NLP, tied to A by n polynomial equalities (the coefficients of
the product equal those of the characteristic polynomial, symbolic/linalg.py). Everything
is a low-degree polynomial, hence smooth, and coalescing poles are just a quadratic factor whose
discriminant changes sign: nothing is singular there. A decay-rate condition (every Re(p_i) <=
-sigma) is the same with zeta = 0 on A + sigma I. See docs/tuning.md.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from sensorless.symbolic.linalg import charpoly


def n_quadratic(n: int) -> int:
    """Number of quadratic factors of a degree-n polynomial (plus one linear factor if n is odd)."""
    return n // 2


def product_coefficients(f: ca.SX, n: int) -> list[ca.SX]:
    """Coefficients [c_0..c_n] of prod (s^2 + a_i s + b_i) [* (s + r)], f = [a_1, b_1, ..., (r)]."""
    c: list = [1]
    factors = [[f[2 * i + 1], f[2 * i], 1] for i in range(n_quadratic(n))]
    if n % 2:
        factors.append([f[n - 1], 1])
    for fac in factors:
        out: list = [0] * (len(c) + len(fac) - 1)
        for i, ci in enumerate(c):
            for j, fj in enumerate(fac):
                out[i + j] = out[i + j] + ci * fj
        c = out
    return c


def factor_equalities(A: ca.SX, f: ca.SX, sigma: ca.SX | float = 0.0) -> ca.SX:
    """n expressions, all zero iff f factors det(sI - A - sigma I) as in the module docstring."""
    n = A.shape[0]
    c = charpoly(A + sigma * ca.SX.eye(n))[::-1]  # lowest power first
    prod = product_coefficients(f, n)
    return ca.vertcat(*[c[k] - prod[k] for k in range(n)])


def damping_inequalities(f: ca.SX, n: int, zeta: ca.SX | float) -> ca.SX:
    """a_i^2 - 4 zeta^2 b_i (>= 0 required), one per quadratic factor."""
    return ca.vertcat(*[f[2 * i] ** 2 - 4 * zeta**2 * f[2 * i + 1] for i in range(n_quadratic(n))])


def factors_from_poles(poles: np.ndarray) -> np.ndarray:
    """Factor coefficients [a_1, b_1, ..., (r)] of the polynomial with these roots (numeric start):
    conjugate pairs give s^2 - 2 Re(p) s + |p|^2; real roots are paired in sorted order."""
    p = np.asarray(poles, complex)
    n = p.size
    cplx = p[p.imag > 1e-9 * (1 + np.abs(p))]
    real = np.sort(p[np.abs(p.imag) <= 1e-9 * (1 + np.abs(p))].real)
    out = []
    for z in cplx:
        out += [-2 * z.real, abs(z) ** 2]
    for i in range(0, real.size - 1, 2):
        r1, r2 = real[i], real[i + 1]
        out += [-(r1 + r2), r1 * r2]
    if n % 2:
        out.append(-real[-1])
    return np.array(out[:n], float)
