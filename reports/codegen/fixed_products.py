"""Products of two signals in the fixed-point lowering: which form each takes, and its precision.

A mixin of the lowering (reports/codegen/fixed_lowering.py). Forms, cheapest first on a Cortex-M0+:
a product by a Q15 constant or a signal of at most 15 bits, two 32-bit products (exact,
:meth:`ProductLowering.exact_q15`); a short product, one 32-bit product of operands rounded to 15
bits (:meth:`ProductLowering.short_product`), where the result only reaches a division or a square
root (fixed_program.coarse_nodes); a limited operand (at most LIMITED_BITS significant bits,
:meth:`ProductLowering.sig_bits`) rounded to 15 bits, then exact; else fixed_ops.mulw's four
products. Operands are clamped at twice their range where a glitch could overflow
(:meth:`ProductLowering.clamped`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from sensorless.reports.codegen.c_graph import Node
from sensorless.reports.codegen.fixed_format import _PI, COEF_BITS
from sensorless.reports.codegen.fixed_ops import INT_MAX, NOMINAL_BITS, Ins

# products of two signals as one 32-bit product of SHORT_BITS-bit operands (Lowering.short_product);
# False: fixed_ops.mulw's four products (within 3 LSB). Off: with the presets' own formats (every
# scenario's and check's ranges) short products and 16-bit quotients left piippo2008's fig6b 3.9 deg
# and deangelo2006's fig2 0.70 deg off the double step at steady state (limit 0.2; long: 0.066 and
# 0.042 deg), for ~250 of hubmotor48's M0+ cycles (docs/codegen.md "Verification")
SHORT_PRODUCTS = False
SHORT_BITS = 15  # each short operand below 2^15: their product within int32
SHORT_SPAN = 4  # a short operand's median magnitude at least 2^-SHORT_SPAN of its range
COARSE_QUOT_BITS = 18  # a quotient of short products: bits at its median magnitude
COARSE_ROOT_BITS = 12  # a root of short products
# an operand carrying at most these bits (a 12-bit root's, Lowering.sig_bits) is rounded to 15 bits
# (Lowering.limited_product); at 16, with a Q15 factor counted as 16 bits, deangelo2006's fig2 went
# 0.073 -> 0.228 deg off the double step
LIMITED_BITS = 12


class ProductLowering:
    """The product methods of the lowering (its state: prog, wr, nom, nodes, rng, sim_typ, coarse,
    bits, ...)."""

    prog: list[Ins]
    wr: list[float]
    nom: list[float]
    nodes: list[Node]
    rng: dict[int, float]
    sim_typ: dict[int, float]
    coarse: set[int]
    bits: dict[int, float]
    rt: set[int]
    stored: dict[int, float]
    lin_c: dict[int, int]
    # the host's methods (fixed_lowering.Lowering, fixed_angles.AngleLowering)
    add: Callable[..., int]  # (ins, wr, nom=None)
    fmt: Callable[[int], tuple[str, int]]
    cval: Callable[[int], float | None]
    fixed_val: Callable[[int], float | None]
    const_slot: Callable[..., int]  # (c, f=None, kind="fix")
    param_slot: Callable[..., int]
    expr: Callable[[int], str]
    is_angle: Callable[[int], bool]
    ang: Callable[[int], int]

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
            self.wr[c] < 2**15
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

    def fills_range(self, n: int) -> bool:
        """Whether node n's median magnitude over the runs is within 2^SHORT_SPAN of its range: an
        operand that a short product may round to SHORT_BITS bits of its range and keep at least
        SHORT_BITS - 1 - SHORT_SPAN bits where it typically is. A signal that is mostly near zero
        (an estimation error, whose range its transients set) keeps the four-product mulw: rounded
        short, the adaptive observer's speed drifted 0.27 deg off the double step."""
        typ, r = self.sim_typ.get(n, 0.0), self.rng.get(n, 0.0)
        return SHORT_PRODUCTS and r > 0 and typ >= r * 2.0**-SHORT_SPAN

    def short_product(self, a: int, b: int, same: bool, fo: int, s: int) -> int:
        """a b 2^-s of two signals as one 32 x 32 -> 32-bit product: both clamped at twice their range
        (as for fixed_ops.mulw), each rounded to SHORT_BITS bits of that worst case (at least
        SHORT_BITS - 1 bits of its range, a Q15 constant factor's precision; an operand already
        shorter leaves its bits to the other), the product then within int32. Relative error <=
        2^(2 - SHORT_BITS) per operand at its range; one multiplication where fixed_ops.mulw takes
        four and their sums (~12 cycles less per product on a Cortex-M0+). Rounded to nearest, not
        floored: a floor's bias of half the dropped bits, carried by an integrator (the adaptive
        observer's speed), moved its angle by 1.3 deg."""
        a = self.clamped(a)
        b = a if same else self.clamped(b)
        bits = [math.ceil(math.log2(self.wr[x] + 1)) for x in (a, b)]
        k = [max(0, bits[0] - SHORT_BITS), max(0, bits[1] - SHORT_BITS)]
        if not same and 0 in k:  # the short one leaves its bits to the other
            j = k.index(0)
            k[1 - j] = max(0, bits[1 - j] - (2 * SHORT_BITS - bits[j]))
        sh = []
        for x, kx in zip((a, b), k, strict=True):
            if kx == 0:
                sh.append(x)
                continue
            fx = self.fmt(x)[1]
            half = self.const_slot(2.0 ** (kx - 1 - fx), fx)
            xr = self.add(Ins("ADD", (x, half), "fix", fx, (0, 0)), self.wr[x] + 2.0 ** (kx - 1), self.nom[x])
            sh.append(
                self.add(
                    Ins("ALIGN", (xr,), "fix", fx - kx, (-kx,), what="product operand, short"),
                    self.wr[xr] * 2.0**-kx + 1,
                    self.nom[x] * 2.0**-kx,
                )
            )
        sa, sb = sh[0], sh[0] if same else sh[1]
        s2 = s - k[0] - k[1]
        return self.add(Ins("MUL", (sa, sb), "fix", fo, (s2,)), self.wr[sa] * self.wr[sb] * 2.0**-s2)

    def short_made(self, n: int) -> bool:
        """Whether node n is a short product by the coarse rule (fixed_program.coarse_nodes: a product of
        signals whose result only reaches a division's operands or a square root), or a sum of them."""
        nd = self.nodes[n]
        if n not in self.coarse or any(self.fixed_val(a) is not None for a in nd.args):
            return False
        return nd.op in ("MUL", "SQ") or all(self.short_made(a) for a in nd.args)

    def sig_bits(self, n: int) -> float:
        """The significant bits node n's value carries at its range: a root's or a quotient's, through
        products and quotients by constants, bounds by constants and products with other signals;
        else NOMINAL_BITS (a signal as precise as its word)."""
        nd = self.nodes[n]
        if n in self.bits:
            return self.bits[n]
        cv = [self.cval(a) is not None for a in nd.args]
        if nd.op == "SELECT" and self.fixed_val(nd.args[0]) is not None:  # a flag's branch
            return self.sig_bits(nd.args[1] if self.fixed_val(nd.args[0]) != 0 else nd.args[2])
        if nd.op == "ASSIGN":
            return self.sig_bits(nd.args[0])
        # (a constant factor's rounding is a fixed scale, not noise: the signal keeps its bits)
        if nd.op in ("MUL", "DIV", "FMAX", "FMIN") and len(cv) == 2 and sum(cv) == 1:
            return self.sig_bits(nd.args[cv.index(False)])
        if nd.op == "MUL" and not any(cv):  # a product is as precise as its coarser factor
            return min(self.sig_bits(nd.args[0]), self.sig_bits(nd.args[1]))
        return NOMINAL_BITS

    def limited_product(self, a: int, b: int, fo: int, s: int) -> int | None:
        """a b 2^-s where a carries at most LIMITED_BITS bits (sig_bits): a clamped at twice its range
        and rounded to nearest to 15 bits of that (at least 14 bits at its range), then multiplied
        with b exactly by two 32-bit products (a Q15 factor's form, fixed_c._q15). None where the
        product would not stay within int32."""
        a = self.clamped(a)
        bits = math.ceil(math.log2(self.wr[a] + 1))
        ka = max(0, bits - 15)
        if ka:
            fa = self.fmt(a)[1]
            half = self.const_slot(2.0 ** (ka - 1 - fa), fa)
            ar = self.add(Ins("ADD", (a, half), "fix", fa, (0, 0)), self.wr[a] + 2.0 ** (ka - 1), self.nom[a])
            a = self.add(
                Ins("ALIGN", (ar,), "fix", fa - ka, (-ka,), what="product operand, 15 bits"),
                self.wr[ar] * 2.0**-ka + 1,
                self.nom[a] * 2.0**-ka,
            )
        s -= ka
        wr = self.wr[a] * self.wr[b] * 2.0**-s
        if not self.exact_q15(a, b, s, wr):
            b = self.clamped(b)
            wr = self.wr[a] * self.wr[b] * 2.0**-s
            if not self.exact_q15(a, b, s, wr):
                return None
        return self.add(Ins("MUL", (a, b), "fix", fo, (s,)), wr)

    def angle_times_constant(self, m: int, c: int, fo: int) -> int | None:
        """m c with m an angle (a binary angle read as rad) and c a constant or parameter, as the binary
        angle's word times c pi / 2^31 in Q15 (two 32-bit products), not the word converted to rad
        first (ANG2LIN's product, then c's); None where m is no angle, its rad value is lowered
        already, or the product does not hold that form."""
        cv = self.cval(c)
        if cv is None or cv == 0 or not self.is_angle(m) or m in self.lin_c:
            return None
        v = cv * _PI * 2.0**-31
        f = COEF_BITS - math.ceil(math.log2(abs(v) * (1 + 2.0**-20)))
        if c in self.rt:
            name = f"{self.expr(c)} * pi / 2^31"
            k = self.param_slot(("ang", c), v, name, f - 1, recipe=(c, _PI * 2.0**-31, False))
        else:
            k = self.const_slot(v, f)
        self.stored.setdefault(c, self.prog[k].imm[-1] * 2.0 ** -self.prog[k].f / (_PI * 2.0**-31))
        a = self.ang(m)
        s = self.fmt(k)[1] - fo
        wr = self.wr[a] * self.wr[k] * 2.0**-s
        if not self.exact_q15(k, a, s, wr):
            return None
        return self.add(Ins("MUL", (a, k), "fix", fo, (s,)), wr)
