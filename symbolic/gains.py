"""Observer gain laws of paper 000: lambda = lambda1 I + lambda2 J, eq. (7), and its schedules (16).

A gain law maps the speed estimate w_hat (electrical rad/s) and a parameter vector to (lambda1,
lambda2) in ohm. Laws are plain functions so that every consumer (linearization, tuning, C code)
evaluates the very same expression; the table of laws below is what a drive TOML can name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
from sensorless.symbolic.pmsm import I2, J, Sym


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

    @property
    def n_params(self) -> int:
        """Number of parameters; the CasADi functions take a vector of max(n, 1) entries."""
        return len(self.param_names)


LAWS: dict[str, GainLaw] = {
    "zero": GainLaw("zero", zero_gain, (), ()),
    "constant": GainLaw("constant", constant_gain, ("lambda1", "lambda2"), ("ohm", "ohm")),
    "speed": GainLaw("speed", speed_gain, ("lambda_p", "w_lambda"), ("ohm", "rad/s")),
}

N_GAIN_PARAMS = 2  # width of the 'gain' input of the analysis functions (unused entries ignored)
