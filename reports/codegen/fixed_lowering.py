"""The fixed-point lowering: graph nodes to integer operations, each slot's format and worst case.

:class:`Lowering` lowers the double step's graph node by node (memoized): constants and parameter
fields in Q15 where they are product factors, sums aligned by shifts, exact comparisons,
saturation where a worst case could exceed int32, divisions by proven-positive values; products of
two signals are its :class:`~fixed_products.ProductLowering` mixin, angles its
:class:`~fixed_angles.AngleLowering`, gain tables its :class:`~fixed_tables.TableLowering`. The module
docstring of reports/codegen/fixed_program.py states the rules.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
from sensorless.reports.codegen.c_graph import Node
from sensorless.reports.codegen.fixed_angles import AngleLowering
from sensorless.reports.codegen.fixed_format import _PI, COEF_BITS, Q15_FACTORS, RANGE_FLOOR, format_of, word
from sensorless.reports.codegen.fixed_ops import INT_MAX, NOMINAL_BITS, NUMPY, SIN_F, Ins, run
from sensorless.reports.codegen.fixed_products import (
    COARSE_QUOT_BITS,
    COARSE_ROOT_BITS,
    LIMITED_BITS,
    ProductLowering,
)
from sensorless.reports.codegen.fixed_ranges import MARGIN
from sensorless.reports.codegen.fixed_tables import TableLowering

QUOT_BITS = 26  # significant bits of a quotient by a runtime divisor at the top of its range


class Lowering(AngleLowering, TableLowering, ProductLowering):
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
        self.expr: Callable[[int], str] = (
            str  # node -> its expression in the parameters' names (the header's comment)
        )
        self.params: list[dict[str, Any]] = []  # the parameter struct's fields
        self.param_c: dict[tuple, int] = {}
        self.sim_lo: dict[int, float] = {}  # smallest and largest simulated value of each node
        self.sim_hi: dict[int, float] = {}
        self.sim_typ: dict[int, float] = {}  # median magnitude of each node over the runs
        # a tabulated schedule's output node -> (schedule state's node, grid, gain nodes, their
        # values, over |value|)
        self.tables: dict[int, tuple[int, tuple[float, ...], tuple[int, ...], tuple[float, ...], bool]] = {}
        # products whose result only reaches a division's operands or a square root's radicand
        # (coarse_nodes): short products (their consumers' results carry fewer bits anyway)
        self.coarse: set[int] = set()
        self.bits: dict[int, float] = {}  # node -> significant bits its value carries (a root, a quotient)

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
        # x + 0, also where the constant is below the sum's LSB (CURRENT_EPS in A^2 added to a
        # square of currents: it shifts to 0, and the sum is the other operand aligned)
        zero = [False, False]
        if ins.op in ("ADD", "SUB"):
            zero = [
                c and _shifted(P[a].imm[0], k) == 0 for a, c, k in zip(ins.args, is_c, ins.imm, strict=True)
            ]
        if zero[1] or (ins.op == "ADD" and zero[0]):
            j = 0 if zero[1] else 1
            src, k = ins.args[j], ins.imm[j]
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

    def and_terms(self, n: int) -> list[int]:
        """The terms of the && chain at node n, in the graph's order."""
        nd = self.nodes[n]
        if nd.op != "AND" or self.folded(n) is not None:
            return [n]
        return self.and_terms(nd.args[0]) + self.and_terms(nd.args[1])

    def on_inputs(self, n: int, depth: int = 3) -> bool:
        """Whether node n is a comparison, |.| or sign of step inputs and parameters within ``depth``
        operations (no product, no call)."""
        nd = self.nodes[n]
        if nd.op == "INPUT" or nd.param:
            return True
        if depth == 0 or nd.op not in ("LE", "LT", "FABS", "NEG", "NOT"):
            return False
        return all(self.on_inputs(a, depth - 1) for a in nd.args)

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
        key: Hashable,
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
        raw = word(c, kind, f)
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
            raw = word(c, "ang", 31)
            return self.add(Ins("CONST", (), "ang", 31, (raw,), what=f"{c:.9g} rad"), abs(raw))
        f = format_of(abs(c)) if f is None else f
        raw = word(c, "fix", f)
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
        # the quotient to QUOT_BITS at its range (a Q15 constant factor's precision): each bit is
        # one step of the C's long division (~7 cycles on a Cortex-M0+); no fewer than none (a
        # negative step count is a 64-bit division: deangelo2006's went from ~490 to ~1100 cycles)
        # a quotient of short products (their precision): COARSE_QUOT_BITS at its median magnitude
        # over the runs (deangelo2006's, at 1/10 of their range, held 16 bits at the range badly:
        # 0.47 deg off the double step on fig2)
        bits = QUOT_BITS
        typ, r = self.sim_typ.get(n, 0.0), self.rng.get(n, 0.0)
        if (self.short_made(an) or self.short_made(bn)) and 0 < typ <= r:
            bits = min(QUOT_BITS, COARSE_QUOT_BITS + math.ceil(math.log2(r / typ)))
        cut = min(NOMINAL_BITS - bits, max(0, fo - fa + fb))
        fo -= cut
        self.bits[n] = NOMINAL_BITS - cut
        floor_raw = max(1, math.floor(lo / MARGIN * 2.0**fb))
        bc = self.add(
            Ins("MAX", (b, self.const_slot(floor_raw * 2.0**-fb, fb)), "fix", fb, (0, 0)), self.wr[b]
        )
        k = fo - fa + fb
        while self.wr[a] * 2.0**k > 2.0**52:
            k, fo, cut = k - 1, fo - 1, cut + 1  # the numerator within 53 bits
        # the quotient in its range's format (a hostile sample near the divisor's floor saturates at
        # twice the range, as a product's operand is clamped): a format that held the worst case
        # instead left hubmotor48's inductance share (within 0..1) two bits, 0.35 deg off the double step
        worst = self.wr[a] * 2.0**k / floor_raw
        lim = min(INT_MAX, math.ceil(2 * 2.0 ** (NOMINAL_BITS - cut)))  # twice the range, in format fo
        # with its bound given, the C divides by fixed_c's 32-bit long division (fx_divc<k>) where the
        # shifted numerator exceeds int32, not by a 64-bit division (libgcc, ~3x the cycles)
        wide = self.wr[a] * 2.0**k > INT_MAX and 0 <= k < 31
        imm = (k, lim) if worst > lim or wide else (k,)
        return self.add(Ins("DIV", (a, bc), "fix", fo, imm, what="divisor clamped positive"), min(worst, lim))

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
        t = self.table(n) if n in self.tables else None
        if t is not None:
            return t
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
        if op == "AND":
            # a chain of && with the terms on the sample's own words first (a glitch's first
            # victims, and a few instructions each): the C computes what the later terms read only
            # when the first hold (fixed_c.guards), so a rejected sample skips the candidate
            terms = sorted(self.and_terms(n), key=lambda t: not self.on_inputs(t))
            s = self.lin(terms[0])
            for t in terms[1:]:
                s = self.add(Ins("AND", (s, self.lin(t)), "bool", 0), 1)
            return s
        if op == "OR":
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
            if not same and sum(consts) == 1:
                p = self.angle_times_constant(nd.args[consts.index(False)], nd.args[consts.index(True)], fo)
                if p is not None:
                    return p
            a = self.factor(nd.args[0])
            b = a if same else self.factor(nd.args[1])
            s = self.fmt(a)[1] + self.fmt(b)[1] - fo
            wr = self.wr[a] * self.wr[b] * 2.0**-s
            c, x = (a, b) if consts[0] else (b, a)
            p = self.prog[c].imm[-1] if any(consts) and not same and self.prog[c].op == "CONST" else 0
            if p > 0 and p & (p - 1) == 0 and wr <= INT_MAX and self.prog[x].op != "PARAM":
                # a signal by a power of two (k_obs / 2): the same floor as a shift, no product (a
                # parameter times a literal is a parameter field of its own: Lowering.fold)
                k = p.bit_length() - 1 - s
                return self.add(Ins("ALIGN", (x,), "fix", fo, (k,)), self.wr[x] * 2.0**k)
            if any(consts) and self.exact_q15(c, x, s, wr):
                return self.add(Ins("MUL", (a, b), "fix", fo, (s,)), wr)
            lim = min(self.wr[x], math.ceil(2 * self.nom[x]))
            if any(consts) and not same and self.exact_q15(c, x, s, self.wr[c] * lim * 2.0**-s):
                # the signal clamped at twice its range, as a product's operand below: the product by a
                # Q15 constant is then two 32-bit products, not a 64-bit one and a saturation
                x = self.clamped(x)
                return self.add(Ins("MUL", (c, x), "fix", fo, (s,)), self.wr[c] * self.wr[x] * 2.0**-s)
            lb = [self.sig_bits(x) for x in nd.args[:2]]
            if not any(consts) and not same and min(lb) <= LIMITED_BITS and not self.short_made(n):
                j = lb.index(min(lb))
                p = self.limited_product(*((a, b) if j == 0 else (b, a)), fo, s)
                if p is not None:
                    return p
            if not any(consts) and (
                self.short_made(n) or all(self.fills_range(x) for x in nd.args[: 1 if same else 2])
            ):
                return self.short_product(a, b, same, fo, s)
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
            if self.short_made(nd.args[0]):
                # a radicand of short products (within 2^-13 of its range): a 24-bit radicand and a
                # 12-bit root, 4 steps fewer (floor; within 1 LSB of the root at 2^12, 2^-12 of its range)
                k -= 2 * (16 - COARSE_ROOT_BITS)
                self.bits[n] = COARSE_ROOT_BITS
                return self.add(
                    Ins("SQRT", (a,), "fix", (fa + k) // 2, (k, COARSE_ROOT_BITS)), 2.0**COARSE_ROOT_BITS
                )
            return self.add(Ins("SQRT", (a,), "fix", (fa + k) // 2, (k,)), 2.0**16)
        if op == "DIV":
            return self.divide(n, fo)
        if op == "SIGN":  # (0 < x) - (x < 0)
            x, zero = self.lin(nd.args[0]), self.const_slot(0.0, 0)
            pos = self.add(Ins("LT", (zero, x), "bool", 0, (0, 0, 0, 0)), 1)  # 0 is 0 in any format
            neg = self.add(Ins("LT", (x, zero), "bool", 0, (0, 0, 0, 0)), 1)
            return self.add(Ins("SUB", (pos, neg), "fix", 0, (0, 0)), 1)
        if op in ("SIN", "COS") and self.nodes[nd.args[0]].op == "ATAN2":
            # cos and sin of an atan2: the CORDIC's rotations applied to (1/K, 0) (fixed_ops.
            # cordic_cos_sin), one call for both, no angle and no polynomial
            y, x, ky, kx = self.atan2_operands(nd.args[0])
            wr = 2.0**SIN_F + 64
            cs = self.add(Ins("CSA", (y, x), "fix", SIN_F, (ky, kx), what="cos of atan2 (CORDIC)"), wr)
            if op == "COS":
                return cs
            return self.add(Ins("SNA", (cs, y, x), "fix", SIN_F, (ky, kx), what="sin of atan2 (CORDIC)"), wr)
        if op in ("SIN", "COS"):
            a = self.ang_of(nd.args[0])
            return self.add(Ins(op, (a,), "fix", SIN_F, what=f"{op.lower()} (polynomial)"), 2.0**SIN_F + 64)
        raise NotImplementedError(
            f"fixed point: operation {op} on runtime values (node {n}) is not supported"
        )


def _shifted(raw: int, k: int) -> int:
    """raw 2^k floored, as the model's shift (fixed_ops.NumpyBackend.shift)."""
    return raw * (1 << k) if k >= 0 else raw >> (-k)
