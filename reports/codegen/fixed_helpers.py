"""The C text of the fixed-point step's integer helpers (``static`` functions of the generated file).

Saturation, the integer square root, divisions by a proven-positive divisor, the exact 64-bit product
from 32-bit ones, the gain table's lookup, the CORDIC (atan2, and cos and sin of an atan2) and the
polynomial sine: each the C spelling of an operation of reports/codegen/fixed_ops.py (the model the
tests compare the C with, bit for bit), written for a Cortex-M0+ (32-bit multiplies only, unrolled
where a loop's counter and variable shifts cost a third of its cycles). :func:`helpers` returns those
that a step's text calls (an unused static function is a warning).
"""

from __future__ import annotations

import math
import re

from sensorless.reports.codegen.fixed_ops import ATAN2_STEPS, CORDIC_ANGLES, CORDIC_INV_GAIN, SIN_COEF, SIN_F

HELPERS = """static int32_t fx_sat(int64_t v) /* within int32 where the high word is the low one's sign */
{
    const int32_t lo = (int32_t)(uint32_t)(uint64_t)v;
    return (int64_t)lo == v ? lo : (v < 0 ? INT32_MIN : INT32_MAX);
}

static int32_t fx_wrap(int64_t v) /* modulo 2^32: binary angles */
{
    return (int32_t)(uint32_t)(uint64_t)v;
}

static int32_t fx_isqrt(int64_t v) /* floor(sqrt(v)), v clamped to [0, 2^32 - 1] */
{
    uint32_t x = v < 0 ? 0u : (v > (int64_t)UINT32_MAX ? UINT32_MAX : (uint32_t)v);
    uint32_t r = 0, t;
%(isqrt_steps)s
    return (int32_t)r;
}

static int32_t fx_div(int64_t n, int32_t d) /* floor(n / d), d > 0 */
{
    return (int32_t)(n >= 0 ? n / d : -((-n + d - 1) / d));
}

static int32_t fx_div32(int32_t n, int32_t d) /* floor(n / d), d > 0: a 32-bit unsigned division */
{
    if (n >= 0) {
        return (int32_t)((uint32_t)n / (uint32_t)d);
    }
    return (int32_t)(0u - ((0u - (uint32_t)n) + (uint32_t)d - 1u) / (uint32_t)d);
}

static int32_t fx_divc64(int64_t n, int32_t d, int32_t lim) /* floor(n / d), d > 0, clamped to [-lim, lim] */
{
    const int64_t q = n >= 0 ? n / d : -((-n + d - 1) / d);
    return q > lim ? lim : (q < -lim ? -lim : (int32_t)q);
}

static int64_t fx_mul64(int32_t a, int32_t b) /* a b exactly from four 32-bit products (no libgcc call) */
{
    const int32_t ah = a >> 16, bh = b >> 16, al = a & 0xFFFF, bl = b & 0xFFFF;
    return (int64_t)(ah * bh) * INT64_C(4294967296) + ((int64_t)(ah * bl) + (int64_t)(al * bh)) * 65536
        + (int64_t)((uint32_t)al * (uint32_t)bl);
}

static FX_NOINLINE int32_t fx_table(int32_t u, const int32_t *v, const int32_t *g, const uint16_t *r,
                                    const uint8_t *sh, int n)
{ /* v at the breakpoints g, linear in between (a Q15 fraction), held beyond the ends; bisection */
    int lo = 0, hi = n - 1;
    uint32_t d, t;
    int32_t dv;
    if (u <= g[0]) {
        return v[0];
    }
    if (u >= g[hi]) {
        return v[hi];
    }
    while (hi - lo > 1) { /* g[lo] <= u < g[hi] */
        const int mid = (lo + hi) >> 1;
        if (u < g[mid]) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    d = (uint32_t)u - (uint32_t)g[lo]; /* 0 <= d < g[hi] - g[lo] */
    if (sh[lo] >= 16) { /* floor(d r 2^-sh), exact in 32-bit products */
        t = (((d >> 16) * r[lo]) + (((d & 0xFFFF) * r[lo]) >> 16)) >> (sh[lo] - 16);
    } else {
        t = (d * r[lo]) >> sh[lo];
    }
    dv = v[hi] - v[lo];
    return v[lo] + (dv >> 16) * (int32_t)t * 2 + (int32_t)(((uint32_t)(dv & 0xFFFF) * t) >> 15);
}

static FX_NOINLINE int32_t fx_atan2(int32_t y0, int32_t x0) /* binary angle; vectoring CORDIC */
{
    int32_t x = x0 >> 2, y = y0 >> 2, xs;
    uint32_t z = 0;
    if (x == 0 && y == 0) {
        return 0;
    }
    if (x < 0) {
        x = -x;
        y = -y;
        z = 0x80000000ul;
    }
%(cordic_steps)s
    return (int32_t)z;
}

static FX_NOINLINE void fx_cossin(int32_t y0, int32_t x0, int32_t *cs) /* cos, sin of atan2(y0, x0) */
{ /* the vectoring CORDIC's rotations applied in reverse to (1/K, 0): it ends at the CORDIC's angle */
    int32_t x = x0 >> 2, y = y0 >> 2, c = %(inv_gain)d, s = 0, xs, t;
    if (x == 0 && y == 0) {
        cs[0] = %(one)d;
        cs[1] = 0;
        return;
    }
    if (x < 0) {
        x = -x;
        y = -y;
        c = -c;
    }
%(cossin_steps)s
    cs[0] = c;
    cs[1] = s;
}

static int32_t fx_sin(int32_t a) /* sin of a binary angle, Q%(sin_f)d; 32-bit products only */
{
    int32_t t = a, x, x2, p;
    if (t > 0x40000000l || t < -0x40000000l) { /* pi - t, or -pi - t: the same modulo 2^32 */
        t = (int32_t)(0x80000000ul - (uint32_t)t);
    }
    x = t >> %(sin_shift)d;
    x2 = %(x2)s;
%(horner)s
    return %(px)s;
}
"""


def mulw(a: str, b: str, s: int) -> str:
    """C of fixed_ops.mulw: a b 2^-s (16 <= s <= 32) from four 32-bit products of 16-bit halves."""
    hh = f"(({a} >> 16) * ({b} >> 16))" + (f" * {1 << (32 - s)}" if s < 32 else "")
    if a == b:  # a square: its two cross terms are one product, floored alike
        return (
            f"({hh} + ((({a} >> 16) * ({a} & 0xFFFF)) >> {s - 16}) * 2"
            f" + (int32_t)(((uint32_t)({a} & 0xFFFF) * (uint32_t)({a} & 0xFFFF)) >> {s}))"
        )
    return (
        f"({hh} + ((({a} >> 16) * ({b} & 0xFFFF)) >> {s - 16}) + ((({a} & 0xFFFF) * ({b} >> 16)) >> {s - 16})"
        f" + (int32_t)(((uint32_t)({a} & 0xFFFF) * (uint32_t)({b} & 0xFFFF)) >> {s}))"
    )


def _cordic_step(i: int, a: int) -> str:
    """Step i of the vectoring CORDIC (fixed_ops.cordic_atan2), unrolled: shifts and the angle are
    literals (a loop's variable shifts, table load and counter cost ~7 of its ~19 cycles a step on a
    Cortex-M0+)."""
    sx, sy = (f"x >> {i}", f"y >> {i}") if i else ("x", "y")
    return (
        f"    xs = {sx};\n    if (0 < y) {{\n        x += {sy};\n        y -= xs;\n        z += {a}ul;\n"
        f"    }} else {{\n        x -= {sy};\n        y += xs;\n        z -= {a}ul;\n    }}"
    )


def _cossin_step(i: int) -> str:
    """Step i of fixed_ops.cordic_cos_sin, unrolled: the vector's step and (c, s) rotated back."""
    x, y, c, s = (f"{v} >> {i}" if i else v for v in "xycs")
    rows = [f"xs = {x};", f"t = {c};", "if (0 < y) {", f"    x += {y};", "    y -= xs;", f"    c -= {s};"]
    rows += [
        "    s += t;",
        "} else {",
        f"    x -= {y};",
        "    y += xs;",
        f"    c += {s};",
        "    s -= t;",
        "}",
    ]
    return "\n".join("    " + r for r in rows)


def _isqrt_step(b: int) -> str:
    """The digit 2^(b/2) of the integer square root, unrolled (b a literal): kept where the root with it
    squared stays within x. One multiplication (single-cycle on a Cortex-M0+) in place of the digit by
    digit form's subtraction and shift (~8.8 -> ~6 cycles a digit there); the same floor."""
    return "\n".join(
        "    " + r for r in (f"t = r + {1 << (b // 2)}u;", "if (t * t <= x) {", "    r = t;", "}")
    )


def _isqrt(bits: int) -> str:
    """fx_isqrt<bits>(v) = floor(sqrt(v)), v clamped to [0, 2^(2 bits) - 1]: the root's top 4 bits
    from a 256-byte table of the roots of the radicand's top byte (floor(sqrt(x)) >> (bits - 4) =
    floor(sqrt(x >> (2 bits - 8)))), then one step per bit below (fx_isqrt's 16 steps for a 32-bit
    radicand)."""
    top = 2 ** (2 * bits) - 1
    tab = [math.isqrt(i) for i in range(256)]
    rows = [", ".join(str(v) for v in tab[i : i + 32]) for i in range(0, 256, 32)]
    return "\n".join(
        [
            f"static int32_t fx_isqrt{bits}(int32_t v) /* floor(sqrt(v)), v clamped to [0, {top}] */",
            "{",
            "    static const uint8_t root_of_top[256] = {",
            *(f"        {r}," for r in rows[:-1]),
            f"        {rows[-1]}}};",
            f"    uint32_t x = v < 0 ? 0u : (v > {lit(top)} ? {top}ul : (uint32_t)v);",
            f"    uint32_t r = (uint32_t)root_of_top[x >> {2 * bits - 8}] << {bits - 4}, t;",
            *(_isqrt_step(b) for b in range(2 * bits - 10, -1, -2)),
            "    return (int32_t)r;",
            "}",
        ]
    )


def _divc(k: int, j: int = 0) -> str:
    """fx_divc<k>[_<j>](n, d, lim) = floor(n 2^k / d) clamped to [-lim, lim], d > 0 (op DIV with a
    clamp): |n| 2^j / d by one 32-bit division (|n| 2^j within 32 bits: fixed_c proves it from the
    numerator's worst case), then the k - j bits below by long division, unrolled (32-bit words; no
    64-bit division, which libgcc does in ~250 cycles on a Cortex-M0+)."""
    n_bits = k - j

    def bit(b: int) -> list[str]:  # the quotient's bit 2^b: added to q, which holds its place already
        return ["r <<= 1;", "if (r >= ud) {", "    r -= ud;", f"    q += {1 << b}u;", "}"]

    rows = [
        f"static int32_t fx_divc{k}{f'_{j}' if j else ''}(int32_t n, int32_t d, int32_t lim)"
        f" /* floor(n 2^{k} / d), in +-lim */",
        "{",
        "    const uint32_t u = (n < 0 ? 0u - (uint32_t)n : (uint32_t)n)"
        + (f" << {j}" if j else "")
        + ", ud = (uint32_t)d;",
        "    uint32_t q = u / ud, r = u - q * ud;",
        f"    if (q > ((uint32_t)lim >> {n_bits})) {{",
        "        return n < 0 ? -lim : lim;",
        "    }",
        f"    q <<= {n_bits};",
        "    /* one quotient bit each: r < d < 2^31, so 2 r fits */",
        *("    " + row for b in range(n_bits - 1, -1, -1) for row in bit(b)),
        "    if (n < 0 && r != 0) { /* floor of a negative quotient */",
        "        q += 1u;",
        "    }",
        "    if (q > (uint32_t)lim) {",
        "        return n < 0 ? -lim : lim;",
        "    }",
        "    return n < 0 ? -(int32_t)q : (int32_t)q;",
        "}",
    ]
    return "\n".join(rows)


def lit(v: int) -> str:
    """An int32 literal (INT32_MIN spelled without overflow)."""
    if v == -(2**31):
        return "INT32_MIN"
    return f"INT32_C({v})" if abs(v) > 32767 else str(v)


def helpers(used: str) -> str:
    """The helper functions that the step text ``used`` calls (an unused static function is a warning)."""
    text = HELPERS % {
        "n_cordic": len(CORDIC_ANGLES),
        "x2": mulw("x", "x", SIN_F),
        "px": mulw("p", "x", SIN_F),
        "cordic_steps": "\n".join(_cordic_step(i, a) for i, a in enumerate(CORDIC_ANGLES[:ATAN2_STEPS])),
        "inv_gain": CORDIC_INV_GAIN,
        "one": 2**SIN_F,
        "cossin_steps": "\n".join(_cossin_step(i) for i in range(len(CORDIC_ANGLES))),
        "isqrt_steps": "\n".join(_isqrt_step(b) for b in range(30, -1, -2)),
        "sin_f": SIN_F,
        "sin_shift": 30 - SIN_F,
        "horner": "\n".join(
            [f"    p = {lit(SIN_COEF[-1])};"]
            + [f"    p = {mulw('p', 'x2', SIN_F)} + {lit(c)};" for c in reversed(SIN_COEF[:-1])]
        ),
    }
    blocks = ["static " + b if k else b for k, b in enumerate(text.split("\n\nstatic "))]
    blocks += [_isqrt(int(b)) for b in sorted(set(re.findall(r"\bfx_isqrt(\d+)\(", used)))]
    blocks += [
        _divc(int(k), int(j or 0)) for k, j in sorted(set(re.findall(r"\bfx_divc(\d+)(?:_(\d+))?\(", used)))
    ]
    keep = []
    for b in blocks:
        name = re.match(r"static (?:const )?(?:FX_NOINLINE )?(?:int32_t|int64_t|void) (\w+)", b).group(1)
        if re.search(rf"\b{name}\b", used):
            keep.append(b)
    if re.search(r"\b(fx_atan2|fx_table|fx_cossin)\(", used):
        # the CORDIC as a call, not inlined: inlined into the step (GCC at -Os), its loop's registers
        # spilled the step's around it and cost outrunner270 ~60 cycles more than the call (M0+)
        keep.insert(0, NOINLINE)
    return "\n\n".join(keep).rstrip() + "\n"


NOINLINE = """#if defined(__GNUC__)
#define FX_NOINLINE __attribute__((noinline))
#else
#define FX_NOINLINE
#endif"""
