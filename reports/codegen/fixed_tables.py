"""Tabulated gain schedules in the fixed-point lowering: one table lookup instead of the law's graph.

A mixin of the lowering (reports/codegen/fixed_lowering.py). ``tables`` (filled by
fixed_program.table_nodes, which checks the law numerically) maps a scheduled gain's node to its
table; :meth:`TableLowering.table` emits the op TABLE (fixed_ops.table_lerp; the C bisects,
fixed_helpers ``fx_table``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from sensorless.reports.codegen.fixed_format import RANGE_FLOOR, format_of, word
from sensorless.reports.codegen.fixed_ops import INT_MAX, Ins


class TableLowering:
    """The table method of the lowering (its state: prog, wr, rng, stored, tables, ...)."""

    prog: list[Ins]
    wr: list[float]
    rng: dict[int, float]
    stored: dict[int, float]
    tables: dict[int, tuple[int, tuple[float, ...], tuple[int, ...], tuple[float, ...], bool]]
    lin: Any
    fmt: Any
    add: Any
    param_slot: Any
    expr: Any

    def table(self, n: int) -> int | None:
        """A tabulated schedule's gain (fixed_ops.table_lerp; the C bisects): the values at the
        breakpoints are parameter fields in one format that holds twice the largest; the breakpoints
        literals in the schedule state's format; one Q15 reciprocal of each spacing. None where the
        state is no bounded fixed-point word or the breakpoints do not fit its format 2 LSB apart."""
        src, grid, gnodes, vals, ab = self.tables[n]
        a = self.lin(src)
        fa = self.fmt(a)[1]
        G = [word(g, "fix", fa) for g in grid]
        if (
            self.prog[a].kind != "fix"
            or self.wr[a] >= INT_MAX
            or any(abs(g) > INT_MAX for g in G)
            or any(h < 2 for h in np.diff(G))
        ):
            return None  # the state is no bounded word, or the breakpoints do not fit it: the law's graph
        top = max(abs(v) for v in vals)
        fo = format_of(max(self.rng.get(n, 0.0), 2 * top, RANGE_FLOOR))
        R, S = [], []
        for h in np.diff(G).tolist():
            s = math.floor(math.log2(h))
            if round(2.0 ** (15 + s) / h) >= 2**15:
                s -= 1
            R.append(round(2.0 ** (15 + s) / h))
            S.append(s)
        V = []
        for g, v in zip(gnodes, vals, strict=True):
            V.append(self.param_slot(("table", g), v, self.expr(g), fo, recipe=(g, 1.0, False)))
            self.stored[g] = self.prog[V[-1]].imm[-1] * 2.0**-fo
        wr = max(self.wr[v] for v in V) * (1 + 2.0**-12) + 2
        imm = (int(ab), len(G), *G, *R, *S)
        return self.add(Ins("TABLE", (a, *V), "fix", fo, imm, what="gain table (bisection)"), wr)
