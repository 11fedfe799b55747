"""The integer semantics of the fixed-point step: one definition, run on integer numpy or on CasADi SX.

A fixed-point program (reports/codegen/fixed_program.py) is a list of :class:`Ins`: SSA integer
operations on 32-bit words. :func:`run` executes it with an arithmetic *backend*:

- :data:`NUMPY` (int64 arrays): the bit-exact Python model of the generated C. Every operand is a
  32-bit word and every intermediate fits in 64 bits, so int64 numpy computes exactly what the C
  computes; tests compare the two on trajectories, 0 differences allowed;
- :class:`SxBackend` (CasADi SX, doubles holding integers): the same program as a CasADi Function,
  so that ``simulate`` runs the fixed-point step inside its compiled closed loop. A double holds an
  integer exactly below 2^53; the formats keep every nominal value below 2^26 and so every product of
  two below 2^52 (fixed_program.py), so on plausible samples it equals the numpy model bit for bit
  (tests check it; hostile inputs are the numpy model's and the C's business).

The C printer (reports/codegen/fixed_c.py) spells the same operations independently; this module is the
reference it is checked against. Shifts right are floors (arithmetic shifts), as gcc and clang do for
signed integers (implementation-defined in C99; both documented compilers define it so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeAlias

import casadi as ca
import numpy as np

INT_MAX = 2**31 - 1
INT_MIN = -(2**31)
NOMINAL_BITS = 26  # a signal at the top of its range is 2^26 (5 bits of headroom below 2^31)
# Error bounds matched to where the value goes: atan2's angle is an output read once per sample
# (ATAN2_STEPS below: 4.9e-4 rad = 0.028 deg, 1/7 of the 0.2 deg the fixed-point step may differ from
# the double one by); sin/cos rotate states that are integrated (the adaptive observer's frame), where
# a 1e-4 error biased piippo2008's angle by 0.27 deg (measured), so they keep 26 bits and degree 7 (1e-6),
# and cos/sin of an atan2 the CORDIC's 14 steps.
CORDIC_STEPS = 14  # cos and sin of an atan2 (they rotate states): error <= atan(2^-13) = 1.22e-4 rad
# atan2 alone (an output angle, the PLL's input): error <= atan(2^-11) = 4.9e-4 rad = 0.028 deg + rounding,
# 1/7 of the 0.2 deg budget; each step fewer is ~11 cycles on a Cortex-M0+ (docs/codegen.md, "Fixed point")
ATAN2_STEPS = 12
# binary angle: an int32 word, pi <-> 2^31 (wraps: angle arithmetic is modulo 2 pi for free)
CORDIC_ANGLES = tuple(round(math.atan(2.0**-i) * 2**31 / math.pi) for i in range(CORDIC_STEPS))
SIN_F = NOMINAL_BITS  # format of sin/cos results
SIN_TERMS = 4  # odd powers 1..7


def _sin_coefficients() -> tuple[int, ...]:
    """Odd polynomial c1 x + c3 x^3 + c5 x^5 + c7 x^7 ~ sin(pi x / 2) on [-1, 1] (least squares on
    Chebyshev nodes; with the products of :func:`mulw` the error is <= 1e-6), as Q26 integers."""
    x = np.cos(np.pi * (np.arange(400) + 0.5) / 400)
    a = np.stack([x ** (2 * k + 1) for k in range(SIN_TERMS)], axis=1)
    c = np.linalg.lstsq(a, np.sin(np.pi * x / 2), rcond=None)[0]
    return tuple(round(float(v) * 2**SIN_F) for v in c)


SIN_COEF = _sin_coefficients()
# 1/K of the CORDIC's CORDIC_STEPS rotations in Q26: (1/K, 0) rotated by them has magnitude 1
CORDIC_INV_GAIN = round(2**SIN_F / math.prod(math.sqrt(1 + 2.0 ** (-2 * i)) for i in range(CORDIC_STEPS)))

# a program's value: int64 words (the numpy backend) or doubles holding integers (the SX backend)
Word: TypeAlias = np.ndarray | ca.SX


@dataclass(frozen=True)
class Ins:
    """One operation: ``op`` over slots ``args``; result format: kind 'fix' (value = raw 2^-f),
    'bool' (0/1, f = 0) or 'ang' (binary angle, pi <-> 2^31); ``imm`` the op's integer constants;
    ``sat``: the result is saturated to int32 (a worst-case input could overflow it)."""

    op: str
    args: tuple[int, ...]
    kind: str
    f: int
    imm: tuple[int, ...] = ()
    sat: bool = False
    what: str = ""  # what it computes, for the C comment


class NumpyBackend:
    """int64 numpy arithmetic (exact for 32-bit operands)."""

    def const(self, v: int, like: Word) -> Word:
        return np.full_like(like, v, dtype=np.int64)

    def mul(self, a: Word, b: Word) -> Word:
        return a * b

    def shift(self, a: Word, k: int) -> Word:  # a 2^k, floored
        return a * (1 << k) if k >= 0 else a >> (-k)

    def clip(self, a: Word, lo: int, hi: int) -> Word:
        return np.clip(a, lo, hi)

    def where(self, c: Word, a: Word, b: Word) -> Word:
        return np.where(c != 0, a, b)

    def cmp(self, op: str, a: Word, b: Word) -> Word:
        return {"LT": a < b, "LE": a <= b, "EQ": a == b, "NE": a != b}[op].astype(np.int64)

    def logic(self, op: str, a: Word, b: Word | None = None) -> Word:
        if op == "NOT":
            return (a == 0).astype(np.int64)
        return (((a != 0) & (b != 0)) if op == "AND" else ((a != 0) | (b != 0))).astype(np.int64)

    def wrap(self, a: Word) -> Word:  # to int32, modulo 2^32
        return ((a + 2**31) & 0xFFFFFFFF) - 2**31

    def isqrt(self, v: Word) -> Word:  # floor(sqrt(v)), 0 <= v < 2^32
        r = np.floor(np.sqrt(v.astype(np.float64))).astype(np.int64)
        r = np.where(r * r > v, r - 1, r)
        return np.where((r + 1) * (r + 1) <= v, r + 1, r)

    def absval(self, a: Word) -> Word:
        return np.abs(a)

    def div(self, n: Word, d: Word) -> Word:  # floor division, d > 0
        return n // d

    def minmax(self, op: str, a: Word, b: Word) -> Word:
        return np.minimum(a, b) if op == "MIN" else np.maximum(a, b)


class SxBackend(NumpyBackend):
    """CasADi SX: doubles holding integers (exact below 2^53)."""

    def const(self, v: int, like: Word) -> Word:
        return ca.SX(float(v))

    def shift(self, a: Word, k: int) -> Word:
        return a * float(2**k) if k >= 0 else ca.floor(a * 2.0**k)

    def clip(self, a: Word, lo: int, hi: int) -> Word:
        return ca.fmin(ca.fmax(a, float(lo)), float(hi))

    def where(self, c: Word, a: Word, b: Word) -> Word:
        return ca.if_else(c, a, b)

    def cmp(self, op: str, a: Word, b: Word) -> Word:
        return {"LT": a < b, "LE": a <= b, "EQ": a == b, "NE": a != b}[op]

    def logic(self, op: str, a: Word, b: Word | None = None) -> Word:
        if op == "NOT":
            return ca.logic_not(a)
        return ca.logic_and(a, b) if op == "AND" else ca.logic_or(a, b)

    def wrap(self, a: Word) -> Word:
        return a - 2.0**32 * ca.floor((a + 2.0**31) * 2.0**-32)

    def isqrt(self, v: Word) -> Word:
        r = ca.floor(ca.sqrt(v))
        r = ca.if_else(r * r > v, r - 1, r)
        return ca.if_else((r + 1) * (r + 1) <= v, r + 1, r)

    def absval(self, a: Word) -> Word:
        return ca.fabs(a)

    def div(self, n: Word, d: Word) -> Word:  # exact for |n| < 2^53
        q = ca.floor(n / d)
        q = ca.if_else(q * d > n, q - 1, q)
        return ca.if_else((q + 1) * d <= n, q + 1, q)

    def minmax(self, op: str, a: Word, b: Word) -> Word:
        return ca.fmin(a, b) if op == "MIN" else ca.fmax(a, b)


NUMPY = NumpyBackend()


def _sat(B: NumpyBackend, v: Word, ins: Ins) -> Word:
    return B.clip(v, INT_MIN, INT_MAX) if ins.sat else v


def cordic_atan2(B: NumpyBackend, y: Word, x: Word, steps: int = ATAN2_STEPS) -> Word:
    """atan2(y, x) as a binary angle: vectoring CORDIC, ``steps`` steps (inputs int32 words)."""
    x, y = B.shift(x, -2), B.shift(y, -2)  # headroom for the CORDIC gain (1.65) and sqrt(2)
    zero = B.logic("AND", B.cmp("EQ", x, B.const(0, x)), B.cmp("EQ", y, B.const(0, y)))
    neg = B.cmp("LT", x, B.const(0, x))
    x, y = B.where(neg, -x, x), B.where(neg, -y, y)
    z = B.where(neg, B.const(2**31, x), B.const(0, x))
    for i, a in enumerate(CORDIC_ANGLES[:steps]):
        d = B.cmp("LT", B.const(0, y), y)
        xs, ys = B.shift(x, -i), B.shift(y, -i)
        x, y = B.where(d, x + ys, x - ys), B.where(d, y - xs, y + xs)
        z = B.where(d, z + a, z - a)
    return B.where(zero, B.const(0, z), B.wrap(z))


def cordic_cos_sin(B: NumpyBackend, y: Word, x: Word) -> tuple[Word, Word]:
    """(cos, sin) of atan2(y, x), Q26: the vectoring CORDIC of :func:`cordic_atan2`, its rotations
    applied in reverse to (1/K, 0), so that it ends at the angle the CORDIC found (its error: the
    atan2's, atan(2^-13) + 24 LSB / |v|, plus < 1e-6 of the shifts' floors), without the angle and
    the polynomial sine of it. (1, 0) for a zero vector, as cos and sin of atan2's 0."""
    x, y = B.shift(x, -2), B.shift(y, -2)
    zero = B.logic("AND", B.cmp("EQ", x, B.const(0, x)), B.cmp("EQ", y, B.const(0, y)))
    neg = B.cmp("LT", x, B.const(0, x))
    x, y = B.where(neg, -x, x), B.where(neg, -y, y)
    c = B.where(neg, B.const(-CORDIC_INV_GAIN, x), B.const(CORDIC_INV_GAIN, x))
    s = B.const(0, x)
    for i in range(CORDIC_STEPS):
        d = B.cmp("LT", B.const(0, y), y)
        xs, ys, cs, ss = B.shift(x, -i), B.shift(y, -i), B.shift(c, -i), B.shift(s, -i)
        x, y = B.where(d, x + ys, x - ys), B.where(d, y - xs, y + xs)
        c, s = B.where(d, c - ss, c + ss), B.where(d, s + cs, s - cs)
    return B.where(zero, B.const(2**SIN_F, c), c), B.where(zero, B.const(0, s), s)


def mulw(B: NumpyBackend, a: Word, b: Word, s: int) -> Word:
    """a b 2^-s (16 <= s <= 32) from four 32 x 32 -> 32-bit products of the words' 16-bit halves,
    each term floored on its own (within 3 LSB of the exact floor): what a Cortex-M0+ computes in
    ~16 cycles where a 64-bit product is a libgcc call of ~45. ``ah bh`` and the cross terms fit int32
    for any int32 words; ``al bl`` is unsigned."""
    ah, bh = B.shift(a, -16), B.shift(b, -16)
    al, bl = a - B.shift(ah, 16), b - B.shift(bh, 16)
    return (
        B.shift(B.mul(ah, bh), 32 - s)
        + B.shift(B.mul(ah, bl), 16 - s)
        + B.shift(B.mul(al, bh), 16 - s)
        + B.shift(B.mul(al, bl), -s)
    )


def sin_binary(B: NumpyBackend, a: Word) -> Word:
    """sin of a binary angle (int32), Q26: folded to [-pi/2, pi/2], odd polynomial of degree 7, its
    products by :func:`mulw` (no 64-bit product)."""
    half = 2**30
    a = B.where(B.cmp("LT", B.const(half, a), a), B.const(2**31, a) - a, a)
    a = B.where(B.cmp("LT", a, B.const(-half, a)), B.const(-(2**31), a) - a, a)
    x = B.shift(a, SIN_F - 30)  # Q26, |x| <= 1
    x2 = mulw(B, x, x, SIN_F)
    p = B.const(SIN_COEF[-1], x)
    for c in reversed(SIN_COEF[:-1]):
        p = mulw(B, p, x2, SIN_F) + c
    return mulw(B, p, x, SIN_F)


def table_lerp(B: NumpyBackend, u: Word, vals: list[Word], imm: tuple[int, ...]) -> Word:
    """A tabulated schedule (op TABLE): ``vals`` at the breakpoints G (raw words in u's format),
    linear in between, held beyond the ends. ``imm`` = (abs, n, G_0..G_n-1, R_0..R_n-2, S_0..S_n-2):
    u taken as |u| where ``abs``; on the segment G_k <= u < G_k+1, t = floor(d R_k 2^-S_k) with
    d = u - G_k (R_k 2^-S_k ~ 2^15 / (G_k+1 - G_k), R_k in [2^14, 2^15): t a Q15 fraction, within
    2^-13 of the exact one) and the value V_k + floor((V_k+1 - V_k) t 2^-15), 32-bit products only.
    The C finds the segment by bisection; the model evaluates every segment and selects one."""
    ab, n = imm[0], imm[1]
    G, R, S = imm[2 : 2 + n], imm[2 + n : 1 + 2 * n], imm[1 + 2 * n : 3 * n]
    u = B.absval(u) if ab else u
    out = vals[0]
    for k in range(n - 1):
        inside = B.logic("AND", B.cmp("LE", B.const(G[k], u), u), B.cmp("LT", u, B.const(G[k + 1], u)))
        d = B.clip(u - G[k], 0, G[k + 1] - G[k])
        t = B.shift(B.mul(d, B.const(R[k], u)), -S[k])
        out = B.where(inside, vals[k] + B.shift(B.mul(vals[k + 1] - vals[k], t), -15), out)
    return B.where(B.cmp("LE", B.const(G[n - 1], u), u), vals[n - 1], out)


def _rounded(B: NumpyBackend, a: Word, k: int, ceil: int) -> Word:
    """a 2^k, floored (or, with ``ceil``, rounded up: x <= y 2^k exactly when ceil(x 2^-k) <= y)."""
    return -B.shift(-a, k) if ceil and k < 0 else B.shift(a, k)


def run(prog: list[Ins], B: NumpyBackend, inputs: list[Word], params: list[int] | None = None) -> list[Word]:
    """Execute ``prog``; ``inputs[j]`` is the value of input j (an 'IN' op with imm (j,)); ``params``
    the parameter struct's raw words (default: the drive's, each 'PARAM' op's imm (j, raw)). Returns
    every slot's value (outputs are slots named by the program)."""
    v: list[Word] = []
    for ins in prog:
        a = [v[j] for j in ins.args]
        op, m = ins.op, ins.imm
        if op == "IN":
            r = inputs[m[0]]
            if len(m) == 3:  # clamped where it enters: a glitch beyond twice its range is clamped
                r = B.clip(r, m[1], m[2])
        elif op == "CONST":
            r = B.const(m[0], inputs[0])
        elif op == "PARAM":
            r = B.const(m[1] if params is None else params[m[0]], inputs[0])
        elif op == "TOANGP":  # a K 2^-s modulo 2^32, K a parameter
            r = B.wrap(B.shift(B.mul(a[0], a[1]), -m[0]))
        elif op == "ALIGN":
            r = _sat(B, B.shift(a[0], m[0]), ins)
        elif op == "CLAMP":
            r = B.clip(a[0], m[0], m[1])
        elif op == "MULW":  # a b 2^-s by four 32-bit products (mulw)
            r = mulw(B, a[0], a[1], m[0])
        elif op in ("ADD", "SUB"):
            p, q = B.shift(a[0], m[0]), B.shift(a[1], m[1])
            r = _sat(B, p + q if op == "ADD" else p - q, ins)
        elif op == "MUL":
            r = _sat(B, B.shift(B.mul(a[0], a[1]), -m[0]), ins)
        elif op == "NEG":
            r = _sat(B, -a[0], ins)
        elif op == "ABS":
            r = _sat(B, B.absval(a[0]), ins)
        elif op in ("MIN", "MAX"):
            r = _sat(B, B.minmax(op, B.shift(a[0], m[0]), B.shift(a[1], m[1])), ins)
        elif op in ("LT", "LE", "EQ", "NE"):  # the finer operand rounded to the coarser format
            r = B.cmp(op, _rounded(B, a[0], m[0], m[2]), _rounded(B, a[1], m[1], m[3]))
        elif op in ("AND", "OR"):
            r = B.logic(op, a[0], a[1])
        elif op == "NOT":
            r = B.logic(op, a[0])
        elif op == "SEL":
            r = _sat(B, B.where(a[0], B.shift(a[1], m[0]), B.shift(a[2], m[1])), ins)
        elif op == "FLOOR":
            r = B.shift(a[0], -m[0])
        elif op == "CEIL":
            r = -B.shift(-a[0], -m[0])
        elif op == "DIV":  # floor(a 2^k / b), b > 0; clamped to +-m[1] where given
            r = B.div(B.shift(a[0], m[0]), a[1])
            r = B.clip(r, -m[1], m[1]) if len(m) > 1 else r
        elif op == "SQRT":
            bits = m[1] if len(m) > 1 else 16  # the root's bits: the radicand within 2^(2 bits) - 1
            r = B.isqrt(B.clip(B.shift(a[0], m[0]), 0, 2 ** (2 * bits) - 1))
        elif op == "ATAN2":
            r = cordic_atan2(B, B.shift(a[0], m[0]), B.shift(a[1], m[1]))
        elif op == "TABLE":
            r = table_lerp(B, a[0], a[1:], m)
        elif op in ("CSA", "SNA"):  # cos, sin of atan2(y, x): SNA's first operand is the CSA it shares
            y, x = (a[0], a[1]) if op == "CSA" else (a[1], a[2])
            r = cordic_cos_sin(B, B.shift(y, m[0]), B.shift(x, m[1]))[op == "SNA"]
        elif op == "SIN":
            r = sin_binary(B, a[0])
        elif op == "COS":
            r = sin_binary(B, B.wrap(a[0] + 2**30))
        elif op == "TOANG":
            r = B.wrap(B.shift(B.mul(a[0], B.const(m[0], a[0])), -m[1]))
        elif op in ("ANGADD", "ANGSUB"):
            r = B.wrap(a[0] + a[1] if op == "ANGADD" else a[0] - a[1])
        elif op == "ANG2LIN":
            r = B.shift(B.mul(a[0], B.const(m[0], a[0])), -m[1])
        else:
            raise NotImplementedError(f"fixed-point op {op}")
        v.append(r)
    return v
