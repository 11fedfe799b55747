"""The runtime contract: one discrete-time step per sampling period, the same for every observer family.

A family's observer, as it runs on a drive, is a :class:`RuntimeObserver`: named, unit-carrying fields
of its state, measurement, parameter and output vectors, a builder of its one-sampling-period step as a
``casadi.Function``, and a Function giving its initial state. The step's contract (docs/architecture.md):

    step(x[n_x], meas[n_m], p[n_p], lam[n_lam]) -> (x_next[n_x], y[n_y])

``meas`` is what the drive samples (currents, the applied voltage); ``p`` every parameter, gains
included, so firmware can change them at run time; ``lam`` carries gains scheduled outside the step
(the adaptive observer's lambda1, lambda2 of Piippo et al. (2008) eq. (7), evaluated by its gain law at
the speed estimate stored in the state field ``schedule_state``); observers without a schedule have
``n_lam = 0``. Simulation runs this step, ``sensorless codegen`` prints it as C, and the family's
analysis linearizes it: one expression graph for all three.

Every step is *guarded* (:func:`guarded`): a sample whose candidate state is not finite, lies beyond the
state's bounds (each state field's ``bound``, an expression of the parameters, e.g. ``4 * psi_pm``) or
fails the family's own condition is rejected, the output ``valid`` says so, and the observer coasts on
its previous state. The state's last field counts the rejected samples (:data:`REJECTS`): up by one
for each rejected sample, down by one for each accepted one, never below 0, so that a run of rejected
samples, or a state that gets more samples rejected than accepted, reaches its bound
(:data:`RESET_AFTER`). Then, or when coasting would leave the bounds, the step resets the state to
the initial state (what ``*_init`` does in C, the parameters kept) and the output ``reset`` says so.
Plausible samples afterwards bring the estimates back without any call from outside.
"""

from __future__ import annotations

import ast
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np
from sensorless.symbolic.frames import Sym

X_MAX = 1e30  # state fields without a bound of their own: a sum of magnitudes beyond this is rejected
RESET_AFTER = 100  # rejected samples (less the accepted ones since) after which the step resets itself


class Field(NamedTuple):
    """One element of a runtime vector: C-identifier name, SI unit, one-line meaning.

    ``check`` (parameters): "positive", "nonnegative", "flag" (0 or 1) or "any" (finite).
    ``bound`` (state fields): the largest magnitude the field may take, an expression of the parameter
    fields' names, numbers, ``pi``, + - * / ** and ``min``/``max`` (e.g. ``"4 * psi_pm"``,
    ``"min(2 * w_max, pi / (2 * T_s))"``); ``""``: finite, no bound of its own (see :func:`guarded`).
    """

    name: str
    unit: str
    doc: str
    check: str = "any"
    bound: str = ""


# The contract's own fields: every runtime observer's state ends with REJECTS, its outputs with VALID
# and RESET (RuntimeObserver checks it); guarded() computes all three.
REJECTS = Field(
    "rejects",
    "samples",
    f"rejected samples, less the accepted ones since (not below 0); at {RESET_AFTER} the step resets itself",
    bound=str(RESET_AFTER),
)
VALID = Field(
    "valid", "1", "1: sample used; 0: rejected (not finite, beyond the bounds), the observer coasted"
)
RESET = Field("reset", "1", "1: the step reset the state to its initial state this period (recovery)")


@dataclass(frozen=True)
class RuntimeObserver:
    """A registered discrete-time observer (see the module docstring)."""

    name: str  # short identifier, e.g. "ipmsm_adaptive"
    title: str  # one line for generated headers
    state: tuple[Field, ...]
    meas: tuple[Field, ...]
    params: tuple[Field, ...]
    outputs: tuple[Field, ...]
    lam: tuple[Field, ...]  # scheduled gains input (may be empty)
    schedule_state: str | None  # state field at which the gain schedule is evaluated
    core: Callable[[str], ca.Function]  # discretization -> step Function with ``lam`` as an input
    initial_state: Callable[[], ca.Function]  # Function p -> x0
    discretizations: tuple[str, ...] = ()  # schemes ``core`` accepts; the first is the default
    # Function (p, op) -> x: the observer converged at an operating point ``op`` of the drive loop it
    # runs in (for a PMSM: symbolic/pmsm_drive.OPERATING_POINT); None if it has none
    steady_state: Callable[[], ca.Function] | None = None
    # one-line texts for the generated C API (what init resets to; what the step takes and gives)
    doc_init: str = "the state of ``initial_state``"
    doc_in: str = "the measurements of this sampling period"
    doc_out: str = "the estimates of this sampling period"

    def __post_init__(self) -> None:
        """The contract's fields are where guarded() puts them, and every bound is an expression of p."""
        if not self.state or self.state[-1].name != REJECTS.name or not self.state[-1].bound:
            raise ValueError(f"{self.name}: the last state field must be the contract's {REJECTS.name!r}")
        if tuple(f.name for f in self.outputs[-2:]) != (VALID.name, RESET.name):
            raise ValueError(f"{self.name}: the outputs must end with {VALID.name!r}, {RESET.name!r}")
        p = ca.SX.sym("p", len(self.params))
        for f in self.state:
            try:
                bound_expression(f.bound, self.params, p)
            except ValueError as e:
                raise ValueError(f"{self.name}: state field {f.name}: {e}") from None

    def index(self, vector: str, name: str) -> int:
        """Position of field ``name`` in ``vector`` ('state', 'meas', 'params', 'outputs', 'lam')."""
        fields = getattr(self, vector)
        for k, f in enumerate(fields):
            if f.name == name:
                return k
        raise KeyError(f"{self.name}: no {vector} field {name!r}")

    def pack_params(self, values: dict[str, float]) -> np.ndarray:
        """Parameter vector from a dict keyed by field name; every field required, no extras."""
        names = [f.name for f in self.params]
        missing = [n for n in names if n not in values]
        extra = [n for n in values if n not in names]
        if missing or extra:
            raise KeyError(f"{self.name} parameters: missing {missing}, unknown {extra}")
        return np.array([float(values[n]) for n in names])

    def check_params(self, values: dict[str, float]) -> None:
        """Raise ValueError naming the first parameter that violates its field's check."""
        for f in self.params:
            v = float(values[f.name])
            ok = {
                "positive": v > 0,
                "nonnegative": v >= 0,
                "flag": v in (0.0, 1.0),
                "any": math.isfinite(v),
            }[f.check]
            if not (ok and math.isfinite(v)):
                raise ValueError(f"{self.name} parameter {f.name} = {v!r}: must be {f.check} and finite")

    def bounds(self) -> ca.Function:
        """Function p -> b[n_x]: the bound of each state field (X_MAX where a field has none)."""
        return _bounds_function(self.name, self.state, self.params)

    def unpack(self, vector: str, v: Sym) -> dict[str, Sym]:
        """Dict field name -> element (or row, for a matrix with one column per sample)."""
        a = np.asarray(v)
        if a.ndim == 2 and a.shape[0] == len(getattr(self, vector)):
            return {f.name: a[k] for k, f in enumerate(getattr(self, vector))}
        return {f.name: v[k] for k, f in enumerate(getattr(self, vector))}


def core_function(
    name: str,
    step: Callable[..., tuple[Sym, Sym]],
    state: tuple[Field, ...],
    meas: tuple[Field, ...],
    params: tuple[Field, ...],
    lam: tuple[Field, ...] = (),
) -> ca.Function:
    """A family's step as the contract's Function ``name``: (x, meas, p, lam) -> (x_next, y) (module
    docstring), from ``step(x, meas, p) -> (x_next, y)`` on symbols of the vectors' sizes, or
    ``step(x, meas, p, lam)`` where the observer has scheduled gains (``lam`` fields). x_next and y
    are one graph, so that the outputs share the step's work (what ``RuntimeObserver.core`` returns)."""
    x = ca.SX.sym("x", len(state))
    m = ca.SX.sym("meas", len(meas))
    p = ca.SX.sym("p", len(params))
    g = ca.SX.sym("lam", len(lam))
    x_next, y = step(x, m, p, g) if lam else step(x, m, p)
    return ca.Function(name, [x, m, p, g], ca.cse([x_next, y]), ["x", "meas", "p", "lam"], ["x_next", "y"])


@functools.cache
def _bounds_function(name: str, state: tuple[Field, ...], params: tuple[Field, ...]) -> ca.Function:
    p = ca.SX.sym("p", len(params))
    b = [bound_expression(f.bound, params, p) for f in state]
    return ca.Function(
        f"{name}_bounds", [p], [ca.vertcat(*[X_MAX if v is None else v for v in b])], ["p"], ["b"]
    )


_BINARY = {ast.Add: lambda a, b: a + b, ast.Sub: lambda a, b: a - b, ast.Mult: lambda a, b: a * b}
_BINARY |= {ast.Div: lambda a, b: a / b, ast.Pow: lambda a, b: a**b}
_CALLS = {"min": ca.fmin, "max": ca.fmax}


def bound_expression(text: str, params: tuple[Field, ...], p: Sym) -> Sym | None:
    """The SX value of a state field's ``bound`` (Field) with the parameter vector ``p``; None if empty.

    A small, closed grammar (no ``eval``): numbers, parameter names, ``pi``, + - * / **, unary minus,
    ``min(a, b)``, ``max(a, b)``. Anything else is a ValueError naming what is not understood.
    """
    if not text.strip():
        return None
    names = {f.name: p[k] for k, f in enumerate(params)}

    def ev(node: ast.AST) -> Sym:
        if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
            return float(node.value)
        if isinstance(node, ast.Name):
            if node.id == "pi":
                return math.pi
            if node.id in names:
                return names[node.id]
            raise ValueError(f"bound {text!r}: {node.id!r} is not a parameter")
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return _BINARY[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -ev(node.operand)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _CALLS:
            if len(node.args) != 2 or node.keywords:
                raise ValueError(f"bound {text!r}: {node.func.id} takes two arguments")
            return _CALLS[node.func.id](ev(node.args[0]), ev(node.args[1]))
        raise ValueError(f"bound {text!r}: {ast.dump(node)} is not understood")

    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise ValueError(f"bound {text!r} is not an expression") from None
    return ev(tree.body)


def all_within(v: Sym, bound: float = X_MAX) -> Sym:
    """1 if sum_j |v_j| <= bound (so every element is finite and bounded), else 0.

    NaN and Inf propagate into the sum and compare false; one comparison, no branches.
    """
    return ca.sum1(ca.fabs(v)) <= bound


def guarded(
    x: Sym,
    p: Sym,
    state: tuple[Field, ...],
    params: tuple[Field, ...],
    *,
    cand: tuple[Sym, Sym],
    coast: tuple[Sym, Sym],
    reset: Sym,
    ok: Sym | None = None,
) -> tuple[Sym, Sym]:
    """(x_next, y) of a guarded step: accept, coast, or reset (the module docstring).

    ``x`` is the state (its last element the counter :data:`REJECTS`), ``p`` the parameters; ``state``
    and ``params`` their fields. ``cand`` = (x, y) of the step as computed, ``coast`` = (x, y) from the
    previous state alone (what the observer does with a rejected sample), both without the contract's
    fields (the counter; ``valid`` and ``reset``); ``reset`` the initial state for ``p`` (all of it; the
    counter restarts at 0 whatever its last element). ``ok`` is an optional further condition of the
    family for accepting the step.

    A candidate is accepted when its fields with a bound lie within it and the others' sum of
    magnitudes is at most X_MAX (so everything is finite: NaN and Inf compare false), and ``ok`` holds.
    Otherwise the observer coasts. The counter goes up by one with a rejected sample and down by one
    (not below 0) with an accepted one; at its bound, or if the coasting state leaves the bounds, the
    state becomes ``reset`` (``reset`` output 1). ``if_else`` selects without arithmetic on the
    rejected values, so nothing non-finite enters the state. Returns x_next = [state, counter] and
    y = [outputs, valid, reset].
    """
    x_cand, y_cand = cand
    x_coast, y_coast = coast
    n_x = len(state) - 1
    if x_cand.numel() != n_x or x_coast.numel() != n_x or reset.numel() != n_x + 1:
        raise ValueError(f"guarded: candidate, coasting and reset states must have {n_x} (+1) elements")
    bounds = [bound_expression(f.bound, params, p) for f in state]
    counter, limit = x[n_x], bounds[n_x]

    def within(v: Sym, skip: Callable[[int], bool] = lambda j: False) -> Sym:
        tests = [ca.fabs(v[j]) <= bounds[j] for j in range(n_x) if bounds[j] is not None and not skip(j)]
        free = [v[j] for j in range(n_x) if bounds[j] is None and not skip(j)]
        if free:
            tests.append(all_within(ca.vertcat(*free)))
        return functools.reduce(ca.logic_and, tests) if tests else ca.SX(1)

    valid = within(x_cand)
    if ok is not None:
        valid = ca.logic_and(valid, ok)
    # the coasting state is checked where it changes (a held field is within its bounds already)
    coast_ok = within(x_coast, lambda j: ca.is_equal(x_coast[j], x[j]))
    count = counter + 1
    do_reset = ca.logic_and(ca.logic_not(valid), ca.logic_or(count >= limit, ca.logic_not(coast_ok)))
    x_sel = ca.if_else(valid, x_cand, x_coast)
    counter_next = ca.if_else(valid, ca.if_else(counter > 0, counter - 1, counter), count)
    x_next = ca.if_else(do_reset, ca.vertcat(reset[0:n_x], 0), ca.vertcat(x_sel, counter_next))
    y = ca.vertcat(ca.if_else(valid, y_cand, y_coast), valid, do_reset)
    return x_next, y
