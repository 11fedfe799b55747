"""The runtime step as a fixed-point program: formats from ranges, integer operations, saturation.

``fixed_step(setup, x, meas)`` lowers the family's registered step (``RuntimeSetup.step_function()``,
the graph the double and float C are printed from; parameters and gains become constants) into a list
of integer operations (reports/codegen/fixed_ops.py) on 32-bit words:

- **formats**: a signal of range R (fixed_ranges.py) is stored as raw = value 2^f with the largest f
  such that R 2^f <= 2^26: 26 bits of precision, 5 bits of headroom. Products by a constant (Q15)
  are two 32-bit products (exact); products of two signals four 32-bit products of their 16-bit
  halves (fixed_ops.mulw, within 3 LSB; operands clamped at twice their range where a glitch could
  overflow), 64-bit only where neither form holds; sums are aligned by shifts; comparisons are exact;
- **folded and shared**: a variant's flags select their branch in the program (a product by 0, a
  sum with 0, |binary angle| <= pi are constants); an operation on the same slots is computed once;
- **saturation** where a worst-case input (measurements and unbounded state fields clamped at twice
  their range where they enter, bounded state fields within their bounds, angles anything) could take
  a result beyond int32: there the result is clamped, elsewhere no check is spent;
- **angles** (state fields bounded by pi, atan2, the runtime contract's ``wrap_angle``/``half_open``,
  symbolic/frames.py, recognised in the graph) are binary angles: int32 with pi <-> 2^31, so wrapping
  is the integer's own overflow. ``wrap_angle(a + b)`` becomes a wrapping sum of the operands
  converted to binary angles (one multiplication by a constant for a product such as T_s w);
- **atan2** by CORDIC (14 steps), **sin/cos** by an odd polynomial of degree 7 on the folded angle,
  **sqrt** as an integer square root of a 32-bit word: bounds in docs/codegen.md ("Fixed point");
- no division: the graph's divisions by parameters are multiplications by constants already (c_graph);
  a division by a runtime value is refused (NotImplementedError) until it is proven non-zero.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sensorless.design.runtime import scheduled_step
from sensorless.reports.codegen.c_emit import build_graph
from sensorless.reports.codegen.c_graph import Node, live_nodes
from sensorless.reports.codegen.fixed_ops import INT_MAX, NOMINAL_BITS, NUMPY, SIN_F, Ins, run
from sensorless.reports.codegen.fixed_ranges import MARGIN, evaluate, interval

Q15_FACTORS = True  # constant factors of products in 16 bits (see _Lowering.factor)
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


def _raw(v: np.ndarray, kind: str, f: int) -> np.ndarray:
    scale = 2.0**31 / _PI if kind == "ang" else 2.0**f
    r = np.floor(v * scale + 0.5)
    if kind == "ang":
        return (((r.astype(np.int64) + 2**31) & 0xFFFFFFFF) - 2**31).astype(np.int64)
    return np.clip(r, -(2**31), INT_MAX).astype(np.int64)


def _si(r: np.ndarray, kind: str, f: int) -> np.ndarray:
    return r * (_PI / 2.0**31) if kind == "ang" else r * 2.0**-f


def _close(v: float | None, target: float) -> bool:
    return v is not None and abs(v - target) < 1e-9 * max(1.0, abs(target))


class _Lowering:
    """Lowers the graph's nodes on demand (memoized), tracking each slot's format and worst case."""

    def __init__(
        self, nodes: list[Node], const: dict[int, float], rng: dict[int, float], angle_fields: set[int]
    ):
        self.nodes, self.const, self.rng = nodes, const, rng
        self.prog: list[Ins] = []
        self.wr: list[float] = []  # worst-case raw magnitude of each slot
        self.nom: list[float] = []  # nominal raw magnitude (the signal's range) of each slot
        self.cse: dict[tuple, int] = {}  # an operation already in the program -> its slot
        self.lin_c: dict[int, int] = {}
        self.ang_c: dict[int, int] = {}
        self.ang_of_c: dict[int, int] = {}  # node -> its value as a binary angle (one conversion each)
        self.in_slot: dict[int, int] = {}  # input node -> slot (filled by the caller)
        self.angle_fields = angle_fields
        self.angle: dict[int, bool] = {}
        self.stored: dict[int, float] = {}  # constant node -> the value the program stores
        self.rt: set[int] = set()  # parameter-derived nodes read from the parameter struct at run time
        self.expr: Any = str  # node -> its expression in the parameters' names (the header's comment)
        self.params: list[dict[str, Any]] = []  # the parameter struct's fields
        self.param_c: dict[tuple, int] = {}
        self.sim_lo: dict[int, float] = {}  # smallest and largest simulated value of each node
        self.sim_hi: dict[int, float] = {}

    # ----------------------------------------------------------------------------------- helpers
    def add(self, ins: Ins, wr: float, nom: float | None = None) -> int:
        if ins.kind == "ang":
            wr = min(wr, 2.0**31)  # wraps: never saturated
        elif ins.sat or wr > INT_MAX:
            ins = Ins(ins.op, ins.args, ins.kind, ins.f, ins.imm, True, ins.what)
            wr = min(wr, 2.0**31)
        folded = self.fold(ins)
        if folded is not None:
            return folded
        key = (ins.op, ins.args, ins.kind, ins.f, ins.imm, ins.sat)
        if key in self.cse and ins.op != "IN":  # the same operation on the same slots: computed once
            return self.cse[key]
        self.prog.append(ins)
        self.wr.append(wr)
        self.nom.append(min(wr, 2.0**NOMINAL_BITS if nom is None else nom))
        self.cse[key] = len(self.prog) - 1
        return len(self.prog) - 1

    def fold(self, ins: Ins) -> int | None:
        """The slot of ``ins`` where constant operands decide it: all constant (evaluated now, by the
        model's own arithmetic), a product by 0, a selection on a constant; else None."""
        P = self.prog
        if ins.op in ("IN", "CONST") or not ins.args:
            return None
        is_c = [P[a].op == "CONST" for a in ins.args]
        if all(is_c):
            alone = Ins(ins.op, tuple(range(len(ins.args))), ins.kind, ins.f, ins.imm, ins.sat)
            prog = [P[a] for a in ins.args] + [alone]
            v = int(run(prog, NUMPY, [np.zeros(1, np.int64)])[-1][0])
            return self.add(Ins("CONST", (), ins.kind, ins.f, (v,), what="folded"), abs(v))
        if ins.op == "MUL" and any(c and P[a].imm[0] == 0 for a, c in zip(ins.args, is_c, strict=True)):
            return self.add(Ins("CONST", (), ins.kind, ins.f, (0,), what="0"), 0)
        if ins.op in ("ADD", "SUB") and is_c[1] and P[ins.args[1]].imm[0] == 0:  # x + 0
            src, k = ins.args[0], ins.imm[0]
            if k == 0 and P[src].f == ins.f and P[src].kind == ins.kind:
                return src
            return self.add(Ins("ALIGN", (src,), ins.kind, ins.f, (k,), ins.sat), self.wr[src] * 2.0**k)
        is_p = [P[a].op == "PARAM" for a in ins.args]
        if ins.op == "MUL" and sorted(is_c) == [False, True] and sorted(is_p) == [False, True]:
            # a parameter times a literal (k_0 / 2 once the flags have chosen k_0): itself a parameter
            q, c = (P[a] for a in (ins.args if is_p[0] else ins.args[::-1]))
            d = self.params[q.imm[0]]
            v = d["value"] * c.imm[0] * 2.0**-c.f
            node, scale, inv = d["recipe"]
            return self.param_slot(
                ("mul", q.imm[0], c.imm[0], c.f),
                v,
                f"{d['expr']} * {c.imm[0] * 2.0**-c.f:.6g}",
                recipe=(node, scale * c.imm[0] * 2.0**-c.f, inv),
            )
        if ins.op == "SEL" and is_c[0]:
            j = 1 if P[ins.args[0]].imm[0] != 0 else 2
            src, k = ins.args[j], ins.imm[j - 1] if ins.imm else 0
            if k == 0 and P[src].f == ins.f and P[src].kind == ins.kind:
                return src
            return self.add(Ins("ALIGN", (src,), ins.kind, ins.f, (k,), ins.sat), self.wr[src] * 2.0**k)
        if ins.op in ("AND", "OR") and any(is_c):
            k = 0 if is_c[0] else 1
            if (P[ins.args[k]].imm[0] != 0) == (ins.op == "OR"):
                return self.add(Ins("CONST", (), "bool", 0, (int(ins.op == "OR"),)), 1)
            other = ins.args[1 - k]
            return other if P[other].kind == "bool" else None
        return None

    def clamped(self, s: int) -> int:
        """Slot ``s`` clamped at twice its nominal range (four times its simulated one), where a worst
        case goes beyond: a product's operand, so that the product stays within int32 without a
        64-bit saturation (a glitch is clamped, as at the inputs; the guard then rejects it)."""
        lim = math.ceil(2 * self.nom[s])
        if self.wr[s] <= lim or self.prog[s].kind != "fix":
            return s
        return self.add(
            Ins("CLAMP", (s,), "fix", self.fmt(s)[1], (-lim, lim), what="product operand"), lim, self.nom[s]
        )

    def exact_q15(self, c: int, x: int, s: int, wr: float) -> bool:
        """Whether a product of the Q15 constant ``c`` and the word ``x`` shifted by ``s`` is the exact
        two-32-bit-product form of reports/codegen/fixed_c.py (``_q15``): no saturation, and the
        high part within int32."""
        return (
            self.prog[c].op in ("CONST", "PARAM")
            and self.wr[c] < 2**15
            and s >= 1
            and wr <= INT_MAX
            and (s >= 16 or wr + 2.0 ** (32 - s) < 2.0**31)  # (x >> 16) c 2^(16-s) within int32
        )

    def mulw_fits(self, a: int, b: int, s: int) -> bool:
        """Whether fixed_ops.mulw of slots a, b (shift s) stays within int32 in every partial sum: the
        high term is within |a b| 2^-s + (|a| + |b|) 2^(16-s) + 2^(32-s), each cross term within
        |a| 2^(16-s) (or |b|), the low one below 2^(32-s); doubled for safety."""
        wa, wb = self.wr[a], self.wr[b]
        return 16 <= s <= 32 and wa * wb * 2.0**-s + (wa + wb) * 2.0 ** (17 - s) + 2.0 ** (34 - s) < 2.0**31

    def fmt(self, s: int) -> tuple[str, int]:
        return self.prog[s].kind, self.prog[s].f

    def cval(self, n: int) -> float | None:
        nd = self.nodes[n]
        if nd.op == "CONST":
            return nd.const
        return self.const.get(n)

    def fixed_val(self, n: int) -> float | None:
        """The value of node n where it is fixed when the C is generated (a literal, or derived from
        the variant's flags only); None for a runtime value or parameter."""
        return None if n in self.rt else self.cval(n)

    def param_slot(
        self,
        key: Any,
        c: float,
        name: str,
        f: int | None = None,
        kind: str = "fix",
        recipe: tuple[int, float, bool] | None = None,
    ) -> int:
        """A field of the parameter struct of value ``c`` (the drive's), read at run time. Its format
        holds twice its magnitude; init accepts it from 0 to twice the drive's value (the worst cases
        and saturation of the program are proven for that range; beyond, regenerate). ``recipe`` =
        (node, scale, inverse): the field is scale * node (or scale / node) of the graph's parameter
        nodes (default: ``key`` itself, scale 1), what fixed_params recomputes from SI values."""
        f = 31 if kind == "ang" else format_of(2 * abs(c)) if f is None else f
        if (key, f) in self.param_c:
            return self.param_c[(key, f)]
        raw = round(c * 2.0**f) if kind == "fix" else ((round(c * 2**31 / _PI) + 2**31) & 0xFFFFFFFF) - 2**31
        if kind == "fix" and 2 * abs(raw) > INT_MAX:
            raise ValueError(f"parameter {name} = {c!r} does not fit format Q{f}")
        j = len(self.params)
        field_name = name if re.fullmatch(r"[A-Za-z_]\w*", name) and name not in self.names() else f"c{j}"
        lo, hi = (min(0, 2 * raw), max(0, 2 * raw)) if kind == "fix" else (-(2**31), INT_MAX)  # angles wrap
        self.params.append(
            {
                "name": field_name,
                "kind": kind,
                "expr": name,
                "f": f,
                "value": c,
                "raw": raw,
                "lo": lo,
                "hi": hi,
                "recipe": recipe if recipe is not None else (key, 1.0, False),
            }
        )
        wr = 2.0**31 if kind == "ang" else max(1, 2 * abs(raw))
        s = self.add(Ins("PARAM", (), kind, f, (j, raw), what=f"{name} (parameter)"), wr)
        self.param_c[(key, f)] = s
        return s

    def names(self) -> set[str]:
        return {d["name"] for d in self.params}

    def const_slot(self, c: float, f: int | None = None, kind: str = "fix") -> int:
        if kind == "ang":
            raw = ((round(c * 2**31 / _PI) + 2**31) & 0xFFFFFFFF) - 2**31
            return self.add(Ins("CONST", (), "ang", 31, (raw,), what=f"{c:.9g} rad"), abs(raw))
        f = format_of(abs(c)) if f is None else f
        raw = round(c * 2.0**f)
        if abs(raw) > INT_MAX:
            raise ValueError(f"constant {c!r} does not fit format Q{f}")
        return self.add(Ins("CONST", (), "fix", f, (raw,), what=f"{c:.9g}"), abs(raw))

    def factor(self, n: int) -> int:
        """A product's operand: a constant factor is stored in Q15 (16 significant bits), so that a
        Cortex-M0+ multiplies by it with two 16 x 16 products instead of a 64-bit multiply (fixed_c)."""
        c = self.cval(n)
        if c is None or c == 0 or not Q15_FACTORS:
            return self.lin(n)
        f = COEF_BITS - math.ceil(math.log2(abs(c) * (1 + 2.0**-20)))
        if n in self.rt:  # a run-time parameter: one bit less, so that twice it stays below 2^15
            s = self.param_slot(n, c, self.expr(n), f - 1)
        else:
            s = self.const_slot(c, f)
        self.stored[n] = self.prog[s].imm[-1] * 2.0 ** -self.prog[s].f  # the coarser storage
        return s

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
            if nd.op == "ASIN":  # asin v = atan2(v, sqrt(1 - v^2)), |v| <= 1 (the graph clamps it)
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
            s = self.add(Ins("ATAN2", (y, x), "ang", 31, (ky, kx), what="atan2 (CORDIC)"), 2**31)
            if self.wr[y] * 2.0**ky > 2.0**31 or self.wr[x] * 2.0**kx > 2.0**31:
                raise ValueError("atan2 operands of different formats beyond int32")
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

    def compare(self, op: str, args: tuple[int, ...]) -> tuple[tuple[int, int], str, int, tuple[int, ...]]:
        """Operands and rounding of an exact comparison in 32 bits: the finer operand is rounded to the
        coarser format, down or up as the comparison needs (x < y 2^k iff floor(x 2^-k) < y; x <= y 2^k
        iff ceil(x 2^-k) <= y; and mirrored); equality aligns up in 64 bits."""
        a, b = self.lin(args[0]), self.lin(args[1])
        fa, fb = self.fmt(a)[1], self.fmt(b)[1]
        if op in ("EQ", "NE"):
            F = max(fa, fb)
            if F - min(fa, fb) > 30:
                raise ValueError(f"equality of formats Q{fa} and Q{fb}: too far apart")
            return (a, b), "bool", 0, (F - fa, F - fb, 0, 0)
        # a word shifted right by 31 (floor) or 32 (ceil, in 64 bits) is already -1, 0 or 1.
        # A threshold (a constant or parameter) finer than the signal is rounded away from it: the
        # comparison holds within one LSB of the signal's format, so that a signal that reaches a stored
        # value by its own rounding (an I-f ramp at w_on, compared with w_on (1 - 1e-9)) reaches it
        thr = {"CONST", "PARAM"}
        if fa >= fb:
            up = 0 if self.prog[a].op in thr else int(op == "LE")
            return (a, b), "bool", 0, (max(fb - fa, -31 - up), 0, up, 0)
        up = 1 if self.prog[b].op in thr else int(op == "LT")
        return (a, b), "bool", 0, (0, max(fa - fb, -31 - up), 0, up)

    def divide(self, n: int, fo: int) -> int:
        """a / b by a divisor proven positive: clamped to half its smallest simulated value (what the
        checks' runs show it never goes below; a hostile sample is clamped, as a glitch is). A divisor
        whose runs change sign is refused."""
        an, bn = self.nodes[n].args
        c = self.cval(bn)
        if c is not None:  # by a constant: a product with its reciprocal
            a = self.lin(an)
            r = (
                self.param_slot(("inv", bn), 1.0 / c, f"1 / ({self.expr(bn)})", recipe=(bn, 1.0, True))
                if bn in self.rt
                else self.const_slot(1.0 / c)
            )
            s = self.fmt(a)[1] + self.fmt(r)[1] - fo
            return self.add(Ins("MUL", (a, r), "fix", fo, (s,)), self.wr[a] * self.wr[r] * 2.0**-s)
        lo, hi = self.sim_lo.get(bn, 0.0), self.sim_hi.get(bn, 0.0)
        if not lo > 0:
            raise NotImplementedError(
                f"fixed point: division by a runtime value that is not positive in every run (node {bn}, "
                f"{self.nodes[bn].op} in [{lo:.3g}, {hi:.3g}])"
            )
        a, b = self.lin(an), self.lin(bn)
        fa, fb = self.fmt(a)[1], self.fmt(b)[1]
        floor_raw = max(1, math.floor(lo / MARGIN * 2.0**fb))
        bc = self.add(
            Ins("MAX", (b, self.const_slot(floor_raw * 2.0**-fb, fb)), "fix", fb, (0, 0)), self.wr[b]
        )
        k = fo - fa + fb
        while self.wr[a] * 2.0**k > 2.0**52 or self.wr[a] * 2.0**k / floor_raw > INT_MAX:
            k, fo = k - 1, fo - 1  # the numerator within 53 bits, the quotient within int32
        return self.add(Ins("DIV", (a, bc), "fix", fo, (k,), what="divisor clamped positive"), 2.0**26)

    # ------------------------------------------------------------------------------- linear values
    def lin(self, n: int) -> int:
        if n in self.lin_c:
            return self.lin_c[n]
        s = self._lin(n)
        if self.prog[s].kind == "fix" and self.prog[s].op not in ("CONST", "IN") and n in self.rng:
            self.nom[s] = min(self.nom[s], max(self.rng[n], RANGE_FLOOR) * 2.0 ** self.prog[s].f)
        self.lin_c[n] = s
        return s

    def folded(self, n: int) -> int | None:
        """The slot of node n where a constant operand decides it (a flag of the variant selects a
        branch, a product by 0, a sum with 0, |angle| <= pi of a binary angle), else None."""
        nd, op = self.nodes[n], self.nodes[n].op
        cv = [self.fixed_val(a) for a in nd.args]
        if op in ("SELECT", "IF_ELSE_ZERO") and cv[0] is not None:
            if cv[0] != 0:
                return self.lin(nd.args[1])
            return self.lin(nd.args[2]) if op == "SELECT" else self.const_slot(0.0, 0)
        if op in ("ADD", "SUB") and cv[1] == 0:
            return self.lin(nd.args[0])
        if op == "ADD" and cv[0] == 0:
            return self.lin(nd.args[1])
        if op in ("AND", "OR") and any(v is not None for v in cv):
            k = 0 if cv[0] is not None else 1
            if (cv[k] != 0) == (op == "OR"):  # true OR x, false AND x
                return self.const_slot(float(op == "OR"), 0)
            return self.lin(nd.args[1 - k])
        if op in ("LE", "LT") and cv[1] is not None and cv[1] >= _PI:
            a = self.nodes[nd.args[0]]
            if a.op == "FABS" and self.is_angle(a.args[0]):  # a binary angle read as rad is below pi
                return self.const_slot(1.0, 0)
        return None

    def _lin(self, n: int) -> int:
        nd = self.nodes[n]
        c = self.cval(n)
        if c is not None:
            s = self.param_slot(n, c, self.expr(n)) if n in self.rt else self.const_slot(c)
            self.stored.setdefault(n, self.prog[s].imm[-1] * 2.0 ** -self.prog[s].f)
            return s
        if self.is_angle(n):
            a = self.ang(n)
            fo = format_of(_PI)
            # K in 15 bits (two 32-bit products; relative error 4e-5), rounded down so that an angle
            # read as rad never exceeds pi (the guard's bound |theta| <= pi stays true)
            sh = 13 + 31 - fo
            K = math.floor(_PI * 2.0 ** (fo - 31 + sh))
            return self.add(
                Ins("ANG2LIN", (a,), "fix", fo, (K, sh), what="binary angle to rad"), 2.0**31 * K / 2**sh
            )
        if nd.op == "INPUT":
            return self.in_slot[n]
        op = nd.op
        fo = format_of(self.rng.get(n, 0.0))
        fold = self.folded(n)
        if fold is not None:
            return fold
        if op == "ASSIGN":
            return self.lin(nd.args[0])
        if op in ("LT", "LE", "EQ", "NE"):
            return self.add(Ins(op, *self.compare(op, nd.args)), 1)
        if op in ("AND", "OR"):
            return self.add(Ins(op, (self.lin(nd.args[0]), self.lin(nd.args[1])), "bool", 0), 1)
        if op == "NOT":
            return self.add(Ins(op, (self.lin(nd.args[0]),), "bool", 0), 1)
        if op in ("ADD", "SUB", "TWICE", "FMIN", "FMAX"):
            a = self.lin(nd.args[0])
            b = a if op == "TWICE" else self.lin(nd.args[1])
            ka, kb = max(fo - self.fmt(a)[1], -31), max(fo - self.fmt(b)[1], -31)
            wr = self.wr[a] * 2.0**ka + self.wr[b] * 2.0**kb
            name = {"TWICE": "ADD", "FMIN": "MIN", "FMAX": "MAX"}.get(op, op)
            if name in ("MIN", "MAX"):
                wr = max(self.wr[a] * 2.0**ka, self.wr[b] * 2.0**kb)
            return self.add(Ins(name, (a, b), "fix", fo, (ka, kb)), wr)
        if op in ("MUL", "SQ"):
            if any(self.fixed_val(x) == 0 for x in nd.args):
                return self.const_slot(0.0, fo)
            same = op == "SQ" or nd.args[0] == nd.args[1]
            consts = [self.cval(x) is not None for x in nd.args[: 1 if same else 2]]
            a = self.factor(nd.args[0])
            b = a if same else self.factor(nd.args[1])
            s = self.fmt(a)[1] + self.fmt(b)[1] - fo
            wr = self.wr[a] * self.wr[b] * 2.0**-s
            c, x = (a, b) if consts[0] else (b, a)
            if any(consts) and self.exact_q15(c, x, s, wr):
                return self.add(Ins("MUL", (a, b), "fix", fo, (s,)), wr)
            if 16 <= s <= 32 and not self.mulw_fits(a, b, s):
                a, b = self.clamped(a), self.clamped(b)
                b = a if same else b
                wr = self.wr[a] * self.wr[b] * 2.0**-s
            if self.mulw_fits(a, b, s) and self.wr[a] * self.wr[b] >= INT_MAX:
                return self.add(Ins("MULW", (a, b), "fix", fo, (s,)), wr + 4)
            if not -30 <= s <= 62:
                raise ValueError(f"product shift {s} out of range (node {n})")
            return self.add(Ins("MUL", (a, b), "fix", fo, (s,)), wr)
        if op in ("NEG", "FABS"):
            a = self.lin(nd.args[0])
            return self.add(Ins("NEG" if op == "NEG" else "ABS", (a,), "fix", self.fmt(a)[1]), self.wr[a] + 1)
        if op in ("SELECT", "IF_ELSE_ZERO"):
            cond = self.lin(nd.args[0])
            a = self.lin(nd.args[1])
            b = self.lin(nd.args[2]) if op == "SELECT" else self.const_slot(0.0, fo)
            ka, kb = max(fo - self.fmt(a)[1], -31), max(fo - self.fmt(b)[1], -31)
            wr = max(self.wr[a] * 2.0**ka, self.wr[b] * 2.0**kb)
            return self.add(Ins("SEL", (cond, a, b), "fix", fo, (ka, kb)), wr)
        if op in ("CEIL", "FLOOR"):
            a = self.lin(nd.args[0])
            fa = self.fmt(a)[1]
            fa = min(fa, 31 if op == "FLOOR" else 32)  # beyond, the result is -1, 0 or 1 already
            return self.add(Ins(op, (a,), "fix", 0, (fa,)), self.wr[a] * 2.0**-fa + 1)
        if op == "SQRT":
            a = self.lin(nd.args[0])
            fa = self.fmt(a)[1]
            k = 6 if (fa + 6) % 2 == 0 else 5  # the radicand below 2^32 at the top of its range
            return self.add(Ins("SQRT", (a,), "fix", (fa + k) // 2, (k,)), 2.0**16)
        if op == "DIV":
            return self.divide(n, fo)
        if op == "SIGN":  # (0 < x) - (x < 0)
            x, zero = self.lin(nd.args[0]), self.const_slot(0.0, 0)
            pos = self.add(Ins("LT", (zero, x), "bool", 0, (0, 0, 0, 0)), 1)  # 0 is 0 in any format
            neg = self.add(Ins("LT", (x, zero), "bool", 0, (0, 0, 0, 0)), 1)
            return self.add(Ins("SUB", (pos, neg), "fix", 0, (0, 0)), 1)
        if op in ("SIN", "COS"):
            a = self.ang_of(nd.args[0])
            return self.add(Ins(op, (a,), "fix", SIN_F, what=f"{op.lower()} (polynomial)"), 2.0**SIN_F + 64)
        raise NotImplementedError(
            f"fixed point: operation {op} on runtime values (node {n}) is not supported"
        )


def step_graph(setup: Any) -> tuple[list[Node], list[tuple[tuple[int, int], int]]]:
    """The graph of ``setup``'s double step (its parameters and gains inputs 2 and 3)."""
    obs = setup.observer
    # the double step itself (not a variant installed by design/runtime.step_variant: that may be us)
    f = scheduled_step(obs, setup.discretization, setup.schedule.law if setup.schedule is not None else None)
    return build_graph(f, {2, 3})


def fixed_step(setup: Any, x: np.ndarray, meas: np.ndarray) -> FixedStep:
    """The fixed-point program of ``setup``'s step, its formats from the observer inputs ``x``, ``meas``
    (columns: samples of the checks' closed-loop runs, fixed_ranges.probe_runs) and the state bounds."""
    obs = setup.observer
    nodes, outs = step_graph(setup)
    p, g = setup.p, setup.gain
    param_used = {a for i, nd in enumerate(nodes) if not nd.param for a in nd.args if nodes[a].param}
    param_used |= {n for _, n in outs if nodes[n].param}
    pv = evaluate(nodes, {2: p, 3: g}, param_used) if param_used else {}
    const = {i: float(v) for i, v in pv.items() if nodes[i].param}
    live = live_nodes(nodes, [n for _, n in outs])
    runtime = sorted(i for i in live if not nodes[i].param)
    # the runs seldom reject a sample: the guard's counter (the state's last field, the runtime
    # contract) is also taken at its bound and one below, on a few of the runs' samples, so that the
    # signals it feeds get the ranges of a counting guard
    cols = np.linspace(0, x.shape[1] - 1, min(x.shape[1], 64)).astype(int)
    bound_n = float(np.asarray(obs.bounds()(p)).ravel()[-1])
    xa, ma = np.hstack([x[:, cols], x[:, cols]]), np.hstack([meas[:, cols], meas[:, cols]])
    xa[-1, : len(cols)], xa[-1, len(cols) :] = bound_n, bound_n - 1
    x, meas = np.hstack([x, xa]), np.hstack([meas, ma])
    sim = evaluate(nodes, {0: x, 1: meas, 2: p, 3: g}, {n for _, n in outs})
    sim_max = {
        i: float(np.nanmax(np.abs(np.broadcast_to(v, x.shape[1:])))) for i, v in sim.items() if i in runtime
    }

    bounds = np.asarray(obs.bounds()(p)).ravel()
    inputs: list[dict[str, Any]] = []
    seeds: dict[int, tuple[float, float]] = {}
    input_node = {(nodes[i].source): i for i in runtime if nodes[i].op == "INPUT"}
    angle_fields = set()
    for vec, fields in ((0, obs.state), (1, obs.meas)):
        for j, fl in enumerate(fields):
            n = input_node.get((vec, j))
            sim_r = float(np.max(np.abs((x if vec == 0 else meas)[j])))
            if vec == 0 and fl.bound.strip() == "pi":
                kind, r, why = "ang", _PI, "angle (bound pi): binary angle, wraps"
                if n is not None:
                    angle_fields.add(n)
            elif vec == 0 and fl.bound:
                kind, r, why = "fix", float(bounds[j]), f"bound {fl.bound} (guard)"
            else:
                kind, r, why = "fix", MARGIN * sim_r, f"simulated max {sim_r:.6g} x {MARGIN:g}"
            r = max(r, RANGE_FLOOR)
            fm = 31 if kind == "ang" else format_of(r)
            inputs.append(
                {
                    "name": fl.name,
                    "vector": "x" if vec == 0 else "meas",
                    "kind": kind,
                    "f": fm,
                    "range": r,
                    "reason": why,
                    "node": n,
                }
            )
            if n is not None:
                seeds[n] = (-r, r)
    iv = interval(nodes, seeds, const)
    rng: dict[int, float] = {}
    for i in runtime:
        ia = max(abs(iv[i][0]), abs(iv[i][1]))
        sm = MARGIN * sim_max.get(i, math.inf)
        # a signal that never moved in the runs (the guard's counter) keeps its sound interval bound
        rng[i] = min(ia, sm) if sm > 0 or not math.isfinite(ia) else ia
        if not math.isfinite(rng[i]):
            raise ValueError(f"{obs.name}: no range for a signal (node {i}, {nodes[i].op})")
    low = _Lowering(nodes, const, rng, angle_fields)
    low.rt, low.expr = runtime_parameters(nodes, obs)
    for i, v in sim.items():
        if i in runtime:
            v = np.broadcast_to(v, x.shape[1:])
            low.sim_lo[i], low.sim_hi[i] = float(np.nanmin(v)), float(np.nanmax(v))
    for j, d in enumerate(inputs):
        imm = (j,) if d["kind"] == "ang" else (j, -(2 ** (NOMINAL_BITS + 1)), 2 ** (NOMINAL_BITS + 1))
        wr = 2.0**31 if d["kind"] == "ang" else 2.0 ** (NOMINAL_BITS + 1)
        s = low.add(Ins("IN", (), d["kind"], d["f"], imm, what=f"{d['vector']}.{d['name']}"), wr)
        if d["node"] is not None:
            low.in_slot[d["node"]] = s
    out_node = dict(outs)
    state_out = []
    for j, d in enumerate(inputs[: len(obs.state)]):
        n = out_node[(0, j)]
        if d["kind"] == "ang":
            state_out.append(low.ang(n))
            continue
        s = low.lin(n)
        k = d["f"] - low.fmt(s)[1]
        k = max(k, -31)
        if k != 0 or low.prog[s].kind != "fix":
            s = low.add(Ins("ALIGN", (s,), "fix", d["f"], (k,)), low.wr[s] * 2.0**k)
        state_out.append(s)
    outputs = []
    for j, fl in enumerate(obs.outputs):
        n = out_node[(1, j)]
        s = low.ang(n) if low.is_angle(n) else low.lin(n)
        kind, fm = low.fmt(s)
        outputs.append({"name": fl.name, "kind": kind, "f": fm, "slot": s, "unit": fl.unit})
    x0 = _raw_list(setup.initial_state(), inputs[: len(obs.state)])
    signals = [
        {"slot": k, "op": ins.op, "kind": ins.kind, "f": ins.f, "saturates": ins.sat, "what": ins.what}
        for k, ins in enumerate(low.prog)
    ]
    return FixedStep(
        low.prog,
        inputs,
        state_out,
        outputs,
        x0,
        low.wr,
        dict(low.lin_c),
        dict(low.stored),
        signals,
        low.params,
    )


_INFIX = {"ADD": "+", "SUB": "-", "MUL": "*", "DIV": "/"}


def runtime_parameters(nodes: list[Node], obs: Any) -> tuple[set[int], Any]:
    """(the parameter-derived nodes that depend on a parameter or gain other than the variant's flags:
    the step reads them from the parameter struct at run time; a function giving a node's expression
    in the parameters' names). Flags (``Field.check == "flag"``) select the variant's code, so what
    derives from them alone stays a literal (and folds)."""
    flags = {(2, j) for j, f in enumerate(obs.params) if f.check == "flag"}
    deps: dict[int, frozenset] = {}

    def dep(i: int) -> frozenset:
        if i not in deps:
            nd = nodes[i]
            deps[i] = (
                frozenset([nd.source]) if nd.op == "INPUT" else frozenset().union(*(dep(a) for a in nd.args))
            )
        return deps[i]

    rt = {i for i, nd in enumerate(nodes) if nd.param and nd.op != "CONST" and not dep(i) <= flags}

    def expr(i: int, depth: int = 0) -> str:
        nd = nodes[i]
        if nd.op == "CONST":
            return f"{nd.const:.6g}"
        if nd.op == "INPUT":
            v, j = nd.source
            return (obs.params if v == 2 else obs.lam)[j].name
        if depth > 6:
            return "..."
        a = [expr(x, depth + 1) for x in nd.args]
        if nd.op in _INFIX and len(a) == 2:
            return f"({a[0]} {_INFIX[nd.op]} {a[1]})" if depth else f"{a[0]} {_INFIX[nd.op]} {a[1]}"
        return {"NEG": f"-{a[0]}", "SQ": f"{a[0]}^2", "TWICE": f"2 {a[0]}", "INV": f"1/{a[0]}"}.get(
            nd.op, f"{nd.op.lower()}({', '.join(a)})"
        )

    return rt, expr


def _raw_list(x0: np.ndarray, fmts: list[dict[str, Any]]) -> list[int]:
    return [int(_raw(np.asarray([v]), d["kind"], d["f"])[0]) for v, d in zip(x0, fmts, strict=True)]
