"""design/discrete.py ``newton``'s shortcut: a point of the damped iteration whose state repeats the one
of two iterations before leaves the batch with the last state its cycle reaches, the same bits as
iterating to the end (checked against the same iteration without the shortcut: a Function evaluated
below the JIT threshold, where ``batch.settled`` is False)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import sensorless.design.discrete as discrete
from sensorless.design import batch

A = 3.0 * 2**18 + 1  # y_next = A y + b: its fixed point -b / (A - 1) is no float


def stuck_map(name: str) -> ca.Function:
    """y -> (A y + b, A) per coordinate, its fixed point between two floats: the residual at either is
    ~(A - 1) 2^-53 (above the 1e-13 that stops Newton's method) and the step rounds to the same float
    or the other one, so the iteration never settles and its state repeats."""
    y, b = ca.SX.sym("y", 2), ca.SX.sym("b", 2)
    J = ca.SX(ca.DM([[A, 0.0], [0.0, A]]))
    return ca.Function(name, [y, b], [J @ y + b, ca.densify(J)], ["y", "b"], ["y_next", "Jy"])


def test_a_cycling_point_ends_where_iterating_on_ends():
    n = 16
    b = np.full((2, n), -1.0 - 1e6 * np.arange(n))
    y0 = -b.T / (A - 1) * (1 + 1e-9)
    calls: list[int] = []
    orig = discrete.evaluate_batch

    def counted(fn, m, args, jit=None):
        calls.append(m)
        return orig(fn, m, args, jit)

    for iterations in (30, 31):  # both parities
        plain, short = stuck_map(f"plain{iterations}"), stuck_map(f"short{iterations}")
        assert not batch.settled(plain)  # never evaluated: no shortcut (the VM below the JIT threshold)
        calls.clear()
        discrete.evaluate_batch = counted
        try:
            y_plain = discrete.newton(plain, [b], y0, iterations=iterations, damped=True)[0]
            plain_calls = len(calls)
            calls.clear()
            y_short = discrete.newton(short, [b], y0, iterations=iterations, damped=True, jit=False)[0]
        finally:
            discrete.evaluate_batch = orig
        assert plain_calls == iterations + 1  # every point iterated to the end (and the final evaluation)
        assert len(calls) < 10  # the shortcut left them once their states repeated
        assert np.array_equal(y_plain.view(np.int64), y_short.view(np.int64), equal_nan=False)
        assert np.isfinite(y_plain).all()
