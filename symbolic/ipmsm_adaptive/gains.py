"""Gain laws of the adaptive observer: lambda = lambda1 I + lambda2 J, eq. (7), and its schedules (16).

Piippo, Hinkkanen, Luomi (2008).

A gain law maps the speed estimate w_hat (electrical rad/s) and a parameter vector to (lambda1,
lambda2) in ohm. Laws are plain functions so that every consumer (linearization, tuning, C code)
evaluates the very same expression; the table of laws below is what a drive TOML can name.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, SupportsIndex

import casadi as ca
from sensorless.symbolic.frames import I2, J, Sym


def gain_matrix(lambda1: Sym, lambda2: Sym) -> Sym:
    """lambda = lambda1 I + lambda2 J, eq. (7)."""
    return lambda1 * I2 + lambda2 * J


def zero_gain(w_hat: Sym, params: Sym) -> tuple[Sym, Sym]:
    """lambda1 = lambda2 = 0 (Section III; Fig. 4(a))."""
    return 0 * w_hat, 0 * w_hat


def constant_gain(w_hat: Sym, params: Sym) -> tuple[Sym, Sym]:
    """Constant lambda1 = params[0], lambda2 = params[1] (Section IV-B; Fig. 4(b))."""
    return params[0] + 0 * w_hat, params[1] + 0 * w_hat


def speed_gain(w_hat: Sym, params: Sym) -> tuple[Sym, Sym]:
    """Speed-dependent gain, eq. (16), params = [lambda' (ohm), omega_lambda (rad/s)].

    (16a) lambda1 = lambda' min(|w_hat| / omega_lambda, 1)
    (16b) lambda2 = lambda' clip(w_hat / omega_lambda, -1, 1)  (= lambda' sign(w_hat) beyond)
    """
    lambda_p, w_lambda = params[0], params[1]
    ratio = w_hat / w_lambda
    lambda1 = lambda_p * ca.fmin(ca.fabs(ratio), 1)  # eq. (16a)
    lambda2 = lambda_p * ca.fmax(ca.fmin(ratio, 1), -1)  # eq. (16b)
    return lambda1, lambda2


@dataclass(frozen=True)
class GainLaw:
    """A named gain law: its expression and the names/units of its parameters."""

    name: str
    expr: Callable[[Sym, Sym], tuple[Sym, Sym]]
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    grid: tuple[float, ...] = ()  # breakpoints of a schedule law [rad/s]

    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return len(self.param_names)

    @property
    def width(self) -> int:
        """Width of the 'gain' input of the CasADi functions: max(n_params, 2); extra entries unused."""
        return max(self.n_params, 2)

    def __reduce_ex__(self, protocol: SupportsIndex) -> str | tuple[Any, ...]:
        """A schedule pickles as its breakpoints (its expression is a closure over them, which pickle
        cannot store) and unpickles as :func:`schedule_law` of them, the same law: a schedule is then
        content to key on, e.g. for the Functions built from it that design/memo.py keeps on disk."""
        if self.grid:
            return (schedule_law, (self.grid,))
        return super().__reduce_ex__(protocol)


@functools.cache
def schedule_law(w_grid: tuple[float, ...]) -> GainLaw:
    """A free gain schedule: lambda1(w_hat), lambda2(w_hat) piecewise linear over the speed grid.

    ``w_grid`` (a tuple; the law is cached per grid so analysis Functions are built once) are
    strictly increasing breakpoints (electrical rad/s); params =
    [lambda1 at each breakpoint..., lambda2 at each breakpoint...] (ohm). Between breakpoints the
    gains are interpolated linearly; beyond the ends they are held constant. The expression is a sum
    of hat functions, so it is one SX expression for analysis, tuning and C generation alike.
    """
    w = tuple(float(v) for v in w_grid)
    if len(w) < 2 or any(b <= a for a, b in itertools.pairwise(w)):
        raise ValueError("schedule breakpoints must be at least two, strictly increasing")
    K = len(w)

    def expr(w_hat: Sym, params: Sym) -> tuple[Sym, Sym]:
        x = ca.fmin(ca.fmax(w_hat, w[0]), w[-1])  # hold the end values beyond the grid
        l1, l2 = 0 * w_hat, 0 * w_hat
        for k in range(K):
            # hat function of breakpoint k: 1 at w[k], 0 at the neighbours, linear between
            up = (x - w[k - 1]) / (w[k] - w[k - 1]) if k > 0 else 1
            down = (w[k + 1] - x) / (w[k + 1] - w[k]) if k < K - 1 else 1
            h = ca.fmax(0, ca.fmin(up, down))
            l1 = l1 + params[k] * h
            l2 = l2 + params[K + k] * h
        return l1, l2

    names = tuple(f"lambda1[{k}]" for k in range(K)) + tuple(f"lambda2[{k}]" for k in range(K))
    return GainLaw(f"schedule{K}", expr, names, ("ohm",) * (2 * K), w)


LAWS: dict[str, GainLaw] = {
    "zero": GainLaw("zero", zero_gain, (), ()),
    "constant": GainLaw("constant", constant_gain, ("lambda1", "lambda2"), ("ohm", "ohm")),
    "speed": GainLaw("speed", speed_gain, ("lambda_p", "w_lambda"), ("ohm", "rad/s")),
}


def get_law(law: str | GainLaw) -> GainLaw:
    """A law by name (``zero``, ``constant``, ``speed``) or the law itself."""
    if isinstance(law, GainLaw):
        return law
    try:
        return LAWS[law]
    except KeyError:
        raise KeyError(f"unknown gain law {law!r} (known: {', '.join(LAWS)})") from None


def taylor_law() -> GainLaw:
    """First-order expansion of a gain law at a speed w0: params [lambda1, lambda2, dlambda1/dw_hat,
    dlambda2/dw_hat, w0] (ohm, ohm, ohm s/rad, ohm s/rad, rad/s).

    At any equilibrium of the coupled system the speed estimate equals the true speed (theta_tilde
    is at rest), so the residual and the Jacobian of the closed loop at an operating point depend on
    the gain law only through its value and slope there. Tuning evaluates the real law (and its
    slope, by AD of the same expression) at each operating point and passes them through this law:
    the linearization is identical and its cost no longer grows with the number of law parameters.
    """
    return _TAYLOR


def _taylor_gain(w_hat: Sym, params: Sym) -> tuple[Sym, Sym]:
    dw = w_hat - params[4]
    return params[0] + params[2] * dw, params[1] + params[3] * dw


_TAYLOR = GainLaw(
    "taylor",
    _taylor_gain,
    ("lambda1", "lambda2", "dlambda1", "dlambda2", "w0"),
    ("ohm", "ohm", "ohm s/rad", "ohm s/rad", "rad/s"),
)
