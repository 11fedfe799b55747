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

Every step is *guarded* (:func:`guarded`): a sample whose result is not finite is rejected, the output
``valid`` says so, and the observer coasts on its previous state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np
from sensorless.symbolic.frames import Sym

X_MAX = 1e30  # a state whose sum of magnitudes exceeds this (or NaN/Inf) is rejected


class Field(NamedTuple):
    """One element of a runtime vector: C-identifier name, SI unit, one-line meaning."""

    name: str
    unit: str
    doc: str
    check: str = "any"  # parameters: "positive", "nonnegative", "flag" (0 or 1) or "any"


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

    def unpack(self, vector: str, v: Sym) -> dict[str, Sym]:
        """Dict field name -> element (or row, for a matrix with one column per sample)."""
        a = np.asarray(v)
        if a.ndim == 2 and a.shape[0] == len(getattr(self, vector)):
            return {f.name: a[k] for k, f in enumerate(getattr(self, vector))}
        return {f.name: v[k] for k, f in enumerate(getattr(self, vector))}


def all_within(v: Sym, bound: float = X_MAX) -> Sym:
    """1 if sum_j |v_j| <= bound (so every element is finite and bounded), else 0.

    NaN and Inf propagate into the sum and compare false; one comparison, no branches.
    """
    return ca.sum1(ca.fabs(v)) <= bound


def guarded(
    x_coast: Sym, x_cand: Sym, y_cand: Sym, y_coast: Sym, ok: Sym | None = None
) -> tuple[Sym, Sym, Sym]:
    """Accept a step only if its new state is finite: (x_next, y, valid).

    An invalid step (NaN/Inf/absurdly large result, e.g. from a NaN sample) gives ``x_coast`` and
    ``y_coast`` instead, computed from the previous (finite) state alone;
    ``if_else`` selects without arithmetic, so no NaN leaks into the state. ``ok`` is an optional
    further condition of the family for accepting the step (e.g. a speed estimate within the range
    its discretization is valid in); False (or NaN) rejects the step as well.
    """
    valid = all_within(x_cand)
    if ok is not None:
        valid = ca.logic_and(valid, ok)
    return ca.if_else(valid, x_cand, x_coast), ca.if_else(valid, y_cand, y_coast), valid
