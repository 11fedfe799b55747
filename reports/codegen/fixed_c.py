"""C99 text of a fixed-point step (reports/codegen/fixed_program.py): integer only, no libm, no float.

Printed independently of the Python model (fixed_ops.py), which tests compare it with bit for bit. Every
slot is a ``const int32_t``; products and aligned sums that need it are computed in ``int64_t``;
saturation (``fx_sat``) only where the program says a worst case could overflow. Right shifts of
negative values are arithmetic (gcc, clang and arm-none-eabi-gcc define it so); conversions of
unsigned words to int32 are modulo 2^32 (the same compilers). The helpers (CORDIC atan2, polynomial
sine, integer square root, ...: reports/codegen/fixed_helpers.py) are ``static`` functions of the
generated file.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Literal, TypeAlias

from sensorless.reports.codegen.fixed_helpers import lit, mulw
from sensorless.reports.codegen.fixed_ops import INT_MAX, NOMINAL_BITS, Ins
from sensorless.reports.codegen.fixed_program import FixedStep


def _clamp(v: str, lo: int, hi: int) -> str:
    """v clamped to [lo, hi]; a symmetric range (the inputs' and products' clamps) by one unsigned
    comparison: v + hi within [0, 2 hi] modulo 2^32 exactly when |v| <= hi (hi < 2^31)."""
    if lo == -hi and 0 < hi < 2**31:
        full = (
            f"((uint32_t)((uint32_t){v} + UINT32_C({hi})) <= UINT32_C({2 * hi}) ? {v} : "
            f"({v} < 0 ? {lit(lo)} : {lit(hi)}))"
        )
        k = hi.bit_length() - 1
        if k < 1:
            return full
        # first within [-2^k, 2^k) (2^k <= hi): a shift and one comparison, no literal to load
        return f"((uint32_t)(({v} >> {k}) + 1) <= 1u ? {v} : {full})"
    return f"({v} < {lit(lo)} ? {lit(lo)} : ({v} > {lit(hi)} ? {lit(hi)} : {v}))"


def _sh(a: str, k: int, wide: bool) -> str:
    """a 2^k (floor), in int64 if ``wide``."""
    w = f"(int64_t){a}" if wide else a
    if k > 0:
        return f"({w} * INT64_C({1 << k}))" if wide else f"({a} * {1 << k})"
    if k < 0:
        return f"({w} >> {-k})"
    return w


def _rnd(a: str, k: int, ceil: int, wide: bool, neg32: bool = False) -> str:
    """a 2^k, rounded up where ``ceil`` (fixed_ops._rounded); ``neg32``: -a cannot overflow int32."""
    if ceil and k < 0:
        return f"(-((-{a}) >> {-k}))" if neg32 else f"(-((-(int64_t){a}) >> {-k}))"
    return _sh(a, k, wide)


def _q15(prog: list[Ins], wr: list[float], k: int, ins: Ins) -> tuple[int, str] | None:
    """(slot, literal) of a product by a 16-bit constant whose parts stay within int32, else None."""
    s = ins.imm[0]
    # s < 16: the high part shifted left is within |a c| 2^-s + 2^(31-s) (fixed_program.exact_q15)
    if ins.op != "MUL" or s < 1 or ins.sat or (s < 16 and wr[k] + 2.0 ** (32 - s) >= 2.0**31):
        return None
    a, b = ins.args
    for x, k in ((a, b), (b, a)):
        if wr[k] < 2**15 and prog[x].op not in ("CONST", "PARAM"):
            if wr[x] * wr[k] < INT_MAX:
                return None  # one 32-bit product holds it
            return x, lit(prog[k].imm[0]) if prog[k].op == "CONST" else f"s{k}"
    return None


def _wide(prog: list[Ins], wr: list[float], ins: Ins, ks: tuple[int, ...], args: tuple[int, ...]) -> bool:
    """Whether an aligned operation needs 64 bits: a saturation, or an operand shifted left beyond int32."""
    return ins.sat or any(k > 0 and wr[a] * 2.0**k > INT_MAX / 2 for a, k in zip(args, ks, strict=False))


def body(fx: FixedStep, x: str, inp: str, out: str, wr: list[float], prm: str = "obs->prm") -> list[str]:
    """The step's statements: slots s0.. from ``x``/``inp`` fields, then the state and outputs."""
    exprs: list[str] = []
    tables: list[str] = []  # a gain table's breakpoints and spacings: const data of the step
    for k, ins in enumerate(fx.prog):
        a = [f"s{j}" for j in ins.args]
        m, op = ins.imm, ins.op
        fin = "fx_sat" if ins.sat else "(int32_t)"
        if op == "IN":
            d = fx.inputs[m[0]]
            src = f"{x}.{d['name']}" if d["vector"] == "x" else f"{inp}->{d['name']}"
            e = src if len(m) == 1 else _clamp(src, m[1], m[2])
        elif op == "CONST":
            e = lit(m[0])
        elif op == "PARAM":
            e = f"{prm}.{fx.params[m[0]]['name']}"
        elif op == "TOANGP":  # as TOANG below, the factor a parameter of at most 15 bits
            v, c = f"s{ins.args[0]}", f"s{ins.args[1]}"
            if m[0] >= 16:
                e = f"((({v} >> 16) * {c}) + ((({v} & 0xFFFF) * {c}) >> 16)) >> {m[0] - 16}"
            else:
                e = (
                    f"(int32_t)(((uint32_t)(({v} >> 16) * {c}) << {16 - m[0]}) "
                    f"+ (uint32_t)((({v} & 0xFFFF) * {c}) >> {m[0]}))"
                )
        elif op == "CLAMP":
            e = _clamp(a[0], m[0], m[1])
        elif op == "MULW":
            e = mulw(a[0], a[1], m[0])
        elif op == "ALIGN":
            w = _wide(fx.prog, wr, ins, m, ins.args)
            e = f"{fin}({_sh(a[0], m[0], True)})" if w else _sh(a[0], m[0], False)
        elif op in ("ADD", "SUB", "MIN", "MAX"):
            w = _wide(fx.prog, wr, ins, m, ins.args)  # else the result is within int32 (not saturated)
            p, q = _sh(a[0], m[0], w), _sh(a[1], m[1], w)
            if op in ("ADD", "SUB"):
                e = f"({p} {'+' if op == 'ADD' else '-'} {q})"
            else:
                e = f"({p} {'<' if op == 'MIN' else '>'} {q} ? {p} : {q})"
            e = f"{fin}{e}" if w else e
        elif op == "MUL" and _q15(fx.prog, wr, k, ins) is not None:
            v, c = _q15(fx.prog, wr, k, ins)
            # exactly floor(x c 2^-s) for a 16-bit c: x = 2^16 xh + xl, two products of 32 bits
            # (a Cortex-M0+ multiplies 32 x 32 -> 32 in one cycle; a 64-bit product is a libgcc call)
            lo = f"(((s{v} & 0xFFFF) * {c}) >> {m[0]})"
            if m[0] >= 16:
                e = f"((((s{v} >> 16) * {c}) + (((s{v} & 0xFFFF) * {c}) >> 16)) >> {m[0] - 16})"
            else:
                e = f"(((s{v} >> 16) * {c} * {1 << (16 - m[0])}) + {lo})"
        elif op == "MUL":
            fits = wr[ins.args[0]] * wr[ins.args[1]] < INT_MAX
            small = fits and not ins.sat and m[0] < 31
            # a 32-bit product scaled up with saturation (a short product, fixed_lowering) needs no
            # 64-bit product, only a 64-bit shift
            prod = f"({a[0]} * {a[1]})" if small else f"fx_mul64({a[0]}, {a[1]})"
            if fits and not small and m[0] <= 0:
                prod = f"(int64_t)({a[0]} * {a[1]})"
            e = f"({prod} >> {m[0]})" if m[0] >= 0 else f"({prod} * {1 << -m[0]})"
            e = e if small else f"{fin}{e}"
        elif op in ("NEG", "ABS"):
            v = f"(-(int64_t){a[0]})" if ins.sat else f"(-{a[0]})"
            e = f"{fin}{v}" if op == "NEG" else f"{fin}({a[0]} < 0 ? {v} : (int64_t){a[0]})"
            if not ins.sat:
                e = f"(-{a[0]})" if op == "NEG" else f"({a[0]} < 0 ? -{a[0]} : {a[0]})"
        elif op in ("LT", "LE", "EQ", "NE"):
            w = any(kk > 0 for kk in m[:2])
            c = {"LT": "<", "LE": "<=", "EQ": "==", "NE": "!="}[op]
            p, q = (
                _rnd(x, k, r, w, wr[j] <= INT_MAX and k > -32)
                for x, k, r, j in ((a[0], m[0], m[2], ins.args[0]), (a[1], m[1], m[3], ins.args[1]))
            )
            e = f"({p} {c} {q})"
        elif op in ("AND", "OR"):
            e = f"({a[0]} {'&&' if op == 'AND' else '||'} {a[1]})"
        elif op == "NOT":
            e = f"(!{a[0]})"
        elif op == "SEL":
            w = _wide(fx.prog, wr, ins, m, ins.args[1:])
            e = f"({a[0]} ? {_sh(a[1], m[0], w)} : {_sh(a[2], m[1], w)})"
            e = f"{fin}{e}" if w else e
        elif op == "FLOOR":
            e = _sh(a[0], -m[0], False)
        elif op == "CEIL":
            e = f"(int32_t)(-({_sh('(-(int64_t)' + a[0] + ')', -m[0], False)}))"
        elif op == "DIV" and len(m) == 1 and wr[ins.args[0]] * 2.0 ** m[0] <= INT_MAX:  # within int32
            e = f"fx_div32({_sh(a[0], m[0], False)}, {a[1]})"
        elif op == "DIV" and len(m) > 1 and 0 <= m[0] < 31:
            # the numerator's magnitude shifted up as far as 32 bits hold it: those quotient bits come
            # from the one 32-bit division (libgcc's, ~3 cycles a bit), not a long-division step (~7)
            j = min(m[0], max(0, math.floor(math.log2((2.0**32 - 1) / max(wr[ins.args[0]], 1)))))
            e = f"fx_divc{m[0]}{f'_{j}' if j else ''}({a[0]}, {a[1]}, {lit(m[1])})"
        elif op == "DIV":
            n64 = _sh(a[0], m[0], True)
            e = f"fx_div({n64}, {a[1]})" if len(m) == 1 else f"fx_divc64({n64}, {a[1]}, {lit(m[1])})"
        elif op == "SQRT":
            e = f"fx_isqrt({_sh(a[0], m[0], True)})"
            if len(m) > 1 and m[0] <= 0:  # a 32-bit radicand: the root's bits by fx_isqrt<bits>
                e = f"fx_isqrt{m[1]}({_sh(a[0], m[0], False)})"
        elif op == "ATAN2":
            e = f"fx_atan2({_sh(a[0], m[0], False)}, {_sh(a[1], m[1], False)})"
        elif op == "TABLE":
            n = m[1]
            G, R, S = m[2 : 2 + n], m[2 + n : 1 + 2 * n], m[1 + 2 * n : 3 * n]
            tables += [
                f"static const int32_t fx_g{k}[{n}] = {{{', '.join(lit(g) for g in G)}}};",
                f"static const uint16_t fx_r{k}[{n - 1}] = {{{', '.join(str(r) for r in R)}}};",
                f"static const uint8_t fx_s{k}[{n - 1}] = {{{', '.join(str(v) for v in S)}}};",
            ]
            u = f"({a[0]} < 0 ? -{a[0]} : {a[0]})" if m[0] else a[0]
            v = f"(const int32_t[{n}]){{{', '.join(a[1:])}}}"
            e = f"fx_table({u}, {v}, fx_g{k}, fx_r{k}, fx_s{k}, {n})"
        elif op == "CSA":  # one call writes cos and sin (fx_cs<k>), SNA reads the sine
            e = f"(fx_cossin({_sh(a[0], m[0], False)}, {_sh(a[1], m[1], False)}, fx_cs{k}), fx_cs{k}[0])"
        elif op == "SNA":
            e = f"((void){a[0]}, fx_cs{ins.args[0]}[1])"
        elif op == "SIN":
            e = f"fx_sin({a[0]})"
        elif op == "COS":
            e = f"fx_sin((int32_t)((uint32_t){a[0]} + 0x40000000ul))"
        elif op in ("TOANG", "ANG2LIN") and abs(m[0]) < 2**15 and m[1] >= 16:
            # floor(a K 2^-s) from two 32-bit products; within int32 (|a K| < 2^46), so no wrap is needed
            v = f"s{ins.args[0]}"
            e = f"((((({v} >> 16) * {m[0]}) + ((({v} & 0xFFFF) * {m[0]}) >> 16)) >> {m[1] - 16}))"
        elif op == "TOANG" and abs(m[0]) < 2**15 and 0 <= m[1] < 16:
            # floor(a K 2^-s) modulo 2^32 from two 32-bit products: a K 2^-s = (a >> 16) K 2^(16-s)
            # + (a & 0xFFFF) K 2^-s, the first an integer; unsigned arithmetic wraps
            v = f"s{ins.args[0]}"
            e = (
                f"(int32_t)(((uint32_t)(({v} >> 16) * {m[0]}) << {16 - m[1]}) "
                f"+ (uint32_t)((({v} & 0xFFFF) * {m[0]}) >> {m[1]}))"
            )
        elif op == "TOANG":
            e = f"fx_wrap(((int64_t){a[0]} * INT64_C({m[0]})) >> {m[1]})"
        elif op in ("ANGADD", "ANGSUB"):
            e = f"(int32_t)((uint32_t){a[0]} {'+' if op == 'ANGADD' else '-'} (uint32_t){a[1]})"
        elif op == "ANG2LIN":
            e = f"(int32_t)(((int64_t){a[0]} * INT64_C({m[0]})) >> {m[1]})"
        else:
            raise NotImplementedError(f"fixed-point op {op} has no C spelling")
        exprs.append(e)
    need = guards(fx.prog, [*fx.state_out, *(o["slot"] for o in fx.outputs)])
    n_x = len(fx.state_out)
    stores = [f"{x}.{d['name']} = s{s};" for d, s in zip(fx.inputs[:n_x], fx.state_out, strict=True)]
    stores += [f"{out}->{o['name']} = s{o['slot']};" for o in fx.outputs]
    # a parameter field, and a state field that enters unclamped where the stores (which overwrite
    # the state) do not read it, is read from the struct where it is used, not held in a variable:
    # on a Cortex-M0+ (8 low registers) a held one was spilled to the stack and reloaded, a load
    # as the struct's (hubmotor48's step 1191 -> 1143 cycles with the parameters)
    held = {int(t) for t in re.findall(r"\bs(\d+)\b", "\n".join(stores))}
    field = {
        k: f"{prm}.{fx.params[ins.imm[0]]['name']}" for k, ins in enumerate(fx.prog) if ins.op == "PARAM"
    }
    field.update(
        {
            k: f"{x}.{fx.inputs[ins.imm[0]]['name']}"
            for k, ins in enumerate(fx.prog)
            if ins.op == "IN"
            and len(ins.imm) == 1
            and fx.inputs[ins.imm[0]]["vector"] == "x"
            and k not in held
        }
    )
    lines: list[str] = list(tables)
    lines += [
        f"int32_t fx_cs{k}[2];" for k, ins in enumerate(fx.prog) if ins.op == "CSA" and need[k] is not None
    ]
    # the constants first: a literal between two slots under one condition would split their block
    lines += [
        f"const int32_t s{k} = {exprs[k]};" + (f" /* {ins.what} */" if ins.what else "")
        for k, ins in enumerate(fx.prog)
        if ins.op == "CONST"
    ]
    k = 0
    while k < len(fx.prog):
        ins = fx.prog[k]
        if need[k] is None or ins.op == "CONST" or k in field:  # dead (a folded branch's leftovers), or above
            k += 1
            continue
        if need[k] == ALWAYS:
            decl = "int" if ins.kind == "bool" else "int32_t"
            note = f" /* {ins.what} */" if ins.what else ""
            lines.append(f"const {decl} s{k} = {exprs[k]};{note}")
            k += 1
            continue
        # a run of slots needed only under one condition: computed only when it holds (the coasting
        # branch's sin/cos on a rejected sample, not every sample); zero-initialized, never read else
        g, run = need[k], []
        while k < len(fx.prog) and (need[k] in (g, None) or fx.prog[k].op == "CONST" or k in field):
            if need[k] == g and fx.prog[k].op != "CONST" and k not in field:
                run.append(k)
            k += 1
        if len(run) == 1:  # one slot: a conditional expression (no zeroed variable to keep)
            j = run[0]
            decl = "int" if fx.prog[j].kind == "bool" else "int32_t"
            note = f" /* {fx.prog[j].what} */" if fx.prog[j].what else ""
            c = condition(g) if len(g) == 1 else f"({condition(g)})"
            lines.append(f"const {decl} s{j} = {c} ? {exprs[j]} : 0;{note}")
            continue
        lines.append(f"int32_t {', '.join(f's{j} = 0' for j in run)};")
        lines.append(f"if ({condition(g)}) {{")
        for j in run:
            note = f" /* {fx.prog[j].what} */" if fx.prog[j].what else ""
            lines.append(f"    s{j} = {exprs[j]};{note}")
        lines.append("}")
    lines += stores
    lines = [re.sub(r"\bs(\d+)\b", lambda m: field.get(int(m.group(1)), m.group(0)), ln) for ln in lines]
    # a constant that every reader spells as a literal (the 16-bit products) is not declared
    text = "\n".join(lines)
    counts: dict[str, int] = {}
    for t in re.findall(r"\bs(\d+)\b", text):
        counts[t] = counts.get(t, 0) + 1
    return [
        line
        for line in lines
        if not (
            (m := re.match(r"const int32_t s(\d+) = ", line))
            and fx.prog[int(m.group(1))].op == "CONST"
            and counts.get(m.group(1), 0) <= 1
        )
    ]


ALWAYS: Literal["always"] = "always"
# when a slot is needed: ALWAYS, None (never: dead) or a conjunction of literals ((c, pol), ...) in
# slot order: only when each slot c is nonzero (pol True) or zero (pol False)
Guard: TypeAlias = Literal["always"] | tuple[tuple[int, bool], ...] | None


def guards(prog: list[Ins], roots: list[int]) -> list[Guard]:
    """When each slot is needed: ALWAYS, None (never: dead), or a conjunction of conditions on slots
    computed before it. A branch of a selection on c, or the second operand of ``c && x`` (C's &&
    does not read x when c is 0), is needed under that condition and the selection's own; a slot
    needed under two conditions is needed under what both imply (always if nothing). A condition on
    a slot that is itself needed under a condition the guard does not contain is dropped."""
    banned: set[tuple[int, bool]] = set()
    while True:
        need = _needs(prog, roots, banned)
        bad = {
            lit
            for g in need
            if g not in (None, ALWAYS)
            for lit in g
            if need[lit[0]] != ALWAYS and not set(need[lit[0]]) <= set(g)
        }
        if not bad:  # a constant is a literal wherever it is read
            return [ALWAYS if g is not None and prog[k].op == "CONST" else g for k, g in enumerate(need)]
        banned |= bad


def condition(g: tuple[tuple[int, bool], ...]) -> str:
    """The C condition of a guard."""
    return " && ".join(f"{'' if pol else '!'}s{c}" for c, pol in g)


def _needs(prog: list[Ins], roots: list[int], banned: set[tuple[int, bool]]) -> list[Guard]:
    need: list[Guard] = [None] * len(prog)

    def holds(g: tuple[tuple[int, bool], ...], lit: tuple[int, bool]) -> bool:
        """Conjunction g implies the literal: it contains it, or (a && ...) true with lit among its terms."""
        return any(x == lit or (x[1] and prog[x[0]].op == "AND" and _and_holds(x[0], lit)) for x in g)

    def _and_holds(a: int, lit: tuple[int, bool]) -> bool:
        return any((b, True) == lit or (prog[b].op == "AND" and _and_holds(b, lit)) for b in prog[a].args)

    def merge(k: int, g: Guard) -> None:
        h = need[k]
        if h is None or h == g:
            need[k] = g
        elif h == ALWAYS or g == ALWAYS:
            need[k] = ALWAYS
        else:  # what both imply
            both = {x for x in h if holds(g, x)} | {x for x in g if holds(h, x)}
            need[k] = tuple(sorted(both)) if both else ALWAYS

    def cond(c: int, pol: bool, outer: Guard) -> Guard:
        if prog[c].op == "NOT":
            c, pol = prog[c].args[0], not pol
        if (c, pol) in banned:
            return outer
        return tuple(sorted({*(outer if outer != ALWAYS else ()), (c, pol)}))

    for r in roots:
        merge(r, ALWAYS)
    for k in reversed(range(len(prog))):
        g = need[k]
        if g is None:
            continue
        if g != ALWAYS and any(c >= k for c, _ in g):
            need[k] = ALWAYS  # a condition computed after it
        ins = prog[k]
        for pos, a in enumerate(ins.args):
            g = need[k]
            if ins.op == "SEL" and pos > 0 and ins.args[1] != ins.args[2]:
                g = cond(ins.args[0], pos == 1, g)
            elif ins.op == "AND" and pos == 1 and ins.args[0] != a:
                g = cond(ins.args[0], True, g)
            merge(a, g)
    return need


def format_text(kind: str, f: int) -> str:
    return (
        "binary angle (pi = 2^31)"
        if kind == "ang"
        else ("0/1" if kind == "bool" else f"Q{f} (value = raw * 2^-{f})")
    )


def formats_json(fx: FixedStep, header: Mapping[str, object]) -> str:
    """The machine-readable formats (beside the C): every field's format, range and reason."""
    data = {
        **header,
        "nominal_bits": NOMINAL_BITS,
        "inputs": [{k: v for k, v in d.items() if k != "node"} for d in fx.inputs],
        "outputs": [{k: v for k, v in d.items() if k != "slot"} for d in fx.outputs],
        "signals": fx.signals,
    }
    return json.dumps(data, indent=1, sort_keys=True) + "\n"
