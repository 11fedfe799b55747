"""Angles in the fixed-point lowering: binary angles (int32, pi <-> 2^31) that wrap by overflow.

A mixin of the lowering (reports/codegen/fixed_lowering.py): which graph nodes are angles (state
fields bounded by pi, atan2, the runtime contract's ``wrap_angle``/``half_open``), their conversion
to binary angles (one multiplication by a constant, or by a parameter field, for a product such as
T_s w) and the cosine of an arcsine.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from sensorless.reports.codegen.c_graph import Node
from sensorless.reports.codegen.fixed_format import _PI, COEF_BITS, _close
from sensorless.reports.codegen.fixed_ops import NOMINAL_BITS, Ins


class AngleLowering:
    """The angle methods of the lowering (its state: nodes, const, angle, ang_c, ang_of_c, rt...)."""

    nodes: list[Node]
    prog: list[Ins]
    angle: dict[int, bool]
    ang_c: dict[int, int]
    ang_of_c: dict[int, int]
    rt: set[int]
    expr: Callable[[int], str]  # node -> its expression in the parameters' names
    angle_fields: set[int]
    in_slot: dict[int, int]
    wr: list[float]

    def is_angle(self, n: int) -> bool:
        if n not in self.angle:
            nd = self.nodes[n]
            r = False
            if nd.op == "INPUT" and n in self.angle_fields:
                r = True
            elif nd.op in ("ATAN2", "ASIN") or self.wrap_arg(n) is not None or self.half_arg(n) is not None:
                r = True
            elif nd.op in ("SELECT", "IF_ELSE_ZERO") and n not in self.const:
                vals = [a for a in nd.args[1:] if self.cval(a) is None]
                r = bool(vals) and all(self.is_angle(a) for a in vals)
            self.angle[n] = r
        return self.angle[n]

    def wrap_arg(self, n: int) -> int | None:
        """theta if node n is symbolic/frames.wrap_angle(theta), else None."""
        N, nd = self.nodes, self.nodes[n]
        if nd.op != "SELECT":
            return None
        c, a, b = nd.args
        if N[c].op != "LT" or not _close(self.cval(N[c].args[0]), _PI) or N[c].args[1] != b:
            return None
        if N[a].op != "SUB" or N[a].args[0] != b or not _close(self.cval(N[a].args[1]), 2 * _PI):
            return None
        if N[b].op != "SUB":
            return None
        theta, m = N[b].args
        if N[m].op != "MUL":
            return None
        k = [x for x in N[m].args if self.cval(x) is not None]
        ce = [x for x in N[m].args if N[x].op == "CEIL"]
        if not (k and ce and _close(self.cval(k[0]), 2 * _PI)):
            return None
        q = N[ce[0]].args[0]
        if N[q].op != "MUL":
            return None
        s = [x for x in N[q].args if N[x].op == "SUB"]
        if not s or N[s[0]].args[0] != theta or not _close(self.cval(N[s[0]].args[1]), _PI):
            return None
        return theta

    def half_arg(self, n: int) -> int | None:
        """theta if node n is symbolic/frames.half_open(theta), else None."""
        N, nd = self.nodes, self.nodes[n]
        if nd.op != "SELECT":
            return None
        c, a, b = nd.args
        if N[c].op == "LT" and _close(self.cval(N[c].args[0]), -_PI) and N[c].args[1] == a:
            if _close(self.cval(b), _PI):
                return a
        return None

    # ------------------------------------------------------------------------------ binary angles
    def ang(self, n: int) -> int:
        if n in self.ang_c:
            return self.ang_c[n]
        nd = self.nodes[n]
        c = self.cval(n)
        if c is not None:
            s = (
                self.param_slot(n, c, self.expr(n), kind="ang")
                if n in self.rt
                else self.const_slot(c, kind="ang")
            )
        elif nd.op == "INPUT":
            s = self.in_slot[n]
        elif self.wrap_arg(n) is not None:
            s = self.ang_of(self.wrap_arg(n))
        elif self.half_arg(n) is not None:
            s = self.ang(self.half_arg(n))
        elif nd.op in ("ATAN2", "ASIN"):
            y, x, ky, kx = self.atan2_operands(n)
            s = self.add(Ins("ATAN2", (y, x), "ang", 31, (ky, kx), what="atan2 (CORDIC)"), 2**31)
        elif nd.op in ("SELECT", "IF_ELSE_ZERO") and self.fixed_val(nd.args[0]) is not None:
            on = self.fixed_val(nd.args[0]) != 0
            if on or nd.op == "SELECT":
                s = self.ang(nd.args[1 if on else 2])
            else:
                s = self.const_slot(0.0, kind="ang")
        elif nd.op in ("SELECT", "IF_ELSE_ZERO") and self.is_angle(n):
            cond = self.lin(nd.args[0])
            a = self.ang(nd.args[1])
            b = self.ang(nd.args[2]) if nd.op == "SELECT" else self.const_slot(0.0, kind="ang")
            s = self.add(Ins("SEL", (cond, a, b), "ang", 31, (0, 0)), 2**31)
        elif nd.op in ("ADD", "SUB") and not self.is_angle(n):
            s = self.ang_of(n)
        else:
            s = self.ang_of(n)
        self.ang_c[n] = s
        return s

    def atan2_operands(self, n: int) -> tuple[int, int, int, int]:
        """(y, x, ky, kx) of node n = atan2(y, x) (or asin v = atan2(v, sqrt(1 - v^2)), |v| <= 1, the
        graph clamps it): the operands' slots and their shifts to a common format."""
        nd = self.nodes[n]
        if nd.op == "ASIN":
            y, x = self.lin(nd.args[0]), self.asin_cos(nd.args[0])
        else:
            y, x = self.lin(nd.args[0]), self.lin(nd.args[1])
        F = max(self.fmt(y)[1], self.fmt(x)[1])
        while (
            F > min(self.fmt(y)[1], self.fmt(x)[1])
            and max(self.wr[y] * 2.0 ** (F - self.fmt(y)[1]), self.wr[x] * 2.0 ** (F - self.fmt(x)[1]))
            > 2.0**31
        ):
            F -= 1  # the common format as fine as int32 holds both operands in
        ky, kx = max(F - self.fmt(y)[1], -31), max(F - self.fmt(x)[1], -31)
        if self.wr[y] * 2.0**ky > 2.0**31 or self.wr[x] * 2.0**kx > 2.0**31:
            raise ValueError("atan2 operands of different formats beyond int32")
        return y, x, ky, kx

    def ang_of(self, n: int) -> int:
        """Node n (any real signal) as a binary angle, modulo 2 pi: sums stay sums of angles."""
        if n not in self.ang_of_c:
            self.ang_of_c[n] = self._ang_of(n)
        return self.ang_of_c[n]

    def _ang_of(self, n: int) -> int:
        nd = self.nodes[n]
        if self.is_angle(n) or self.cval(n) is not None:
            return self.ang(n)
        if nd.op in ("ADD", "SUB"):
            a, b = (self.ang_of(x) for x in nd.args)
            op = "ANGADD" if nd.op == "ADD" else "ANGSUB"
            return self.add(Ins(op, (a, b), "ang", 31), 2**31)
        k, x, kn = 1.0, n, None
        if nd.op == "MUL":
            cs = [a for a in nd.args if self.cval(a) is not None]
            if cs:
                k, kn = self.cval(cs[0]), cs[0]
                x = next(a for a in nd.args if a != cs[0]) if nd.args[0] != nd.args[1] else nd.args[0]
        if kn in self.rt:  # a run-time factor such as T_s k_p: TOANGP, its factor a parameter
            if self.is_angle(x):  # k e of a wrapped angle e: the word times k (|k| < 1 here)
                xs, ratio, unit = self.ang(x), k, ""
            else:
                xs = self.lin(x)
                ratio = k * 2.0 ** (31 - self.fmt(xs)[1]) / _PI
                unit = f" * 2^{31 - self.fmt(xs)[1]} / pi"
            sh = COEF_BITS - 2 - math.floor(math.log2(abs(ratio)))
            name = f"({self.expr(kn)}){unit}" if unit else self.expr(kn)
            K = self.param_slot(("ang", kn, self.fmt(xs)), ratio, name, sh, recipe=(kn, ratio / k, False))
            return self.add(Ins("TOANGP", (xs, K), "ang", 31, (sh,), what="to binary angle"), 2**31)
        if self.is_angle(x):  # k theta of a binary angle: exact modulo 2 pi for an integer k
            xs, ratio = self.ang(x), k
        else:
            xs = self.lin(x)
            ratio = k * 2.0 ** (31 - self.fmt(xs)[1]) / _PI
        # K in 15 bits (Q15, as the factors of products): two 32-bit products on a Cortex-M0+
        sh = COEF_BITS - 1 - math.floor(math.log2(abs(ratio))) if ratio else 0
        K = round(ratio * 2.0**sh)
        return self.add(Ins("TOANG", (xs,), "ang", 31, (K, sh), what="to binary angle"), 2**31)

    def asin_cos(self, n: int) -> int:
        """sqrt(1 - v^2) of node n's value v (|v| <= 1): the cosine of asin v, by the integer square root
        (16 significant bits: asin's error stays the CORDIC's, 1.2e-4 rad, plus 2^-16 rad)."""
        v = self.lin(n)
        f = NOMINAL_BITS - 1  # |v| <= 1 within 2^25: v^2 and 1 - v^2 in the same Q25
        va = self.add(
            Ins("ALIGN", (v,), "fix", f, (f - self.fmt(v)[1],)),
            min(self.wr[v] * 2.0 ** (f - self.fmt(v)[1]), 2.0**31),
        )
        vc = self.add(Ins("CLAMP", (va,), "fix", f, (-(2**f), 2**f)), 2.0**f)
        sq = self.add(Ins("MULW", (vc, vc), "fix", f, (f,)), 2.0**f + 4)
        one = self.const_slot(1.0, f)
        d = self.add(Ins("SUB", (one, sq), "fix", f, (0, 0)), 2.0**f + 4)
        k = 6 if (f + 6) % 2 == 0 else 5
        return self.add(Ins("SQRT", (d,), "fix", (f + k) // 2, (k,), what="cos of asin"), 2.0**16)
