"""Q formats of the fixed-point step: a signal's format from its range, and the program's container.

``format_of`` gives the fractional bits of a signal of a given range (26 bits of precision, 5 of
headroom); :class:`FixedStep` holds a lowered program (reports/codegen/fixed_program.py) with its
inputs, outputs and formats, and converts between SI values and raw words.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sensorless.reports.codegen.fixed_ops import INT_MAX, NOMINAL_BITS, Ins

Q15_FACTORS = True  # constant factors of products in 16 bits (see fixed_lowering.Lowering.factor)
COEF_BITS = 15
RANGE_FLOOR = 2.0**-24  # smallest range given a format (a signal that stays below it reads as 0 in steps)
_PI = math.pi


def format_of(r: float) -> int:
    """Fractional bits of a signal of range ``r``: the largest f with r 2^f <= 2^26."""
    r = max(r, RANGE_FLOOR)
    return NOMINAL_BITS - math.ceil(math.log2(r))


@dataclass
class FixedStep:
    """A fixed-point step: program, inputs (state then measurements), outputs and formats."""

    prog: list[Ins]
    inputs: list[dict[str, Any]]  # name, vector ("x" or "meas"), kind, f, range, reason
    state_out: list[int]  # slot of each next-state field
    outputs: list[dict[str, Any]]  # name, kind, f, slot
    x0: list[int]  # raw initial state
    wr: list[float]  # worst-case raw magnitude of each slot (what decides 64-bit work and saturation)
    node_slot: dict[int, int] = field(default_factory=dict)  # graph node -> its linear slot (diagnostics)
    stored: dict[int, float] = field(default_factory=dict)  # constant node -> its stored value (poles)
    signals: list[dict[str, Any]] = field(default_factory=list)  # every slot's format and range
    params: list[dict[str, Any]] = field(default_factory=list)  # the parameter struct's fields

    def to_raw(self, values: np.ndarray, which: str) -> np.ndarray:
        """SI values (rows: the fields of ``which`` = "x" or "meas") as raw words (round to nearest)."""
        fmts = [i for i in self.inputs if i["vector"] == which]
        return np.stack(
            [_raw(np.asarray(v, float), i["kind"], i["f"]) for v, i in zip(values, fmts, strict=True)]
        )

    def outputs_si(self, slots: list[Any]) -> np.ndarray:
        """The outputs in SI from the program's slot values."""
        return np.stack([_si(np.asarray(slots[o["slot"]]), o["kind"], o["f"]) for o in self.outputs])

    def state_si(self, raw: np.ndarray) -> np.ndarray:
        """The state in SI from raw words (rows: state fields)."""
        fmts = [i for i in self.inputs if i["vector"] == "x"]
        return np.stack([_si(r, i["kind"], i["f"]) for r, i in zip(raw, fmts, strict=True)])


def word(c: float, kind: str, f: int) -> int:
    """The raw word of the value ``c`` in format Qf (``kind`` "fix") or as a binary angle ("ang"):
    rounded half up, floor(c 2^f + 0.5), angles modulo 2^32. The one rounding of every value the
    program stores (constants, parameter fields, the initial state) and of the samples it is given
    (:meth:`FixedStep.to_raw`; fixed_model's SX twin spells the same floor); not clipped."""
    if kind == "ang":
        return ((math.floor(c * (2.0**31 / _PI) + 0.5) + 2**31) & 0xFFFFFFFF) - 2**31
    return math.floor(c * 2.0**f + 0.5)


def _raw(v: np.ndarray, kind: str, f: int) -> np.ndarray:
    """:func:`word` of every element, fixed-point words clipped to int32."""
    scale = 2.0**31 / _PI if kind == "ang" else 2.0**f
    r = np.floor(v * scale + 0.5)
    if kind == "ang":
        return (((r.astype(np.int64) + 2**31) & 0xFFFFFFFF) - 2**31).astype(np.int64)
    return np.clip(r, -(2**31), INT_MAX).astype(np.int64)


def _si(r: np.ndarray, kind: str, f: int) -> np.ndarray:
    return r * (_PI / 2.0**31) if kind == "ang" else r * 2.0**-f


def _close(v: float | None, target: float) -> bool:
    return v is not None and abs(v - target) < 1e-9 * max(1.0, abs(target))
