"""Numerical integration of continuous plants between samples, unrolled in SX."""

from __future__ import annotations

from collections.abc import Callable

from sensorless.symbolic.frames import Sym


def rk4(f: Callable[[Sym], Sym], x: Sym, h: Sym, n_sub: int) -> Sym:
    """x advanced by n_sub classical RK4 steps of length h/n_sub for the autonomous dx/dt = f(x).

    Unrolled: a whole sampling period becomes one expression, so a simulation is one compiled loop.
    """
    dt = h / n_sub
    for _ in range(n_sub):
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x
