"""C statements from a CasADi SX Function's algorithm, with parameter-only work hoisted out of the step.

This is a printer of the expression graph CasADi already built (its instruction list: one operation per
instruction), in the style of CasADi's own code generator but targeted at an embedded step function:

- **typed for one precision**: ``float`` code uses ``sinf``-style libm calls and ``f``-suffixed literals
  only, so the float build contains no double operation (docs/codegen.md);
- **hoisting**: every value that depends on the parameters alone (gains (10), (22), filter coefficients,
  reciprocals of inductances, ...) is computed once by the ``*_init`` code into a coefficient array; the
  step computes only what depends on the state and the measurements. A division of a runtime value by a
  parameter-only value becomes a multiplication by a hoisted reciprocal;
- **products of parameter-only factors**: ``p * (q * x)`` with ``p``, ``q`` parameter-only becomes
  ``(p q) * x``, the product hoisted (a gain times an inductance times a current error: one
  multiplication in the step instead of two; the result differs by rounding only);
- **selects**: CasADi's ``if_else`` (``c ? a : 0`` + ``!c ? b : 0``) is printed as one ``c ? a : b``
  (the two differ only in the sign of a zero result);
- **branches**: where many selects share a condition (the runtime guard's ``valid``: accept, or coast
  and maybe reset), the step branches on it, ``if (c) {...} else {...}``: what only one side reads
  is computed only there (the coasting state only for a rejected sample), the selects on ``c``
  vanish, and the condition's value simplifies the logic inside (``!c``, ``c && d``, ...). A branch is
  taken only where it shortens the longer path and duplicates no more than it saves; each side may
  branch again (nesting at most c_graph ``MAX_DEPTH``). The values are the same as with the selects;
- **truth values**: a comparison or logical operation of the step is an ``int`` temporary (what C's
  operators give), converted to the precision only where arithmetic or an output reads it, so that
  the guard's tests and selects cost no float conversions;
- SSA style (``const`` temporaries, one per instruction); all inputs are read before any output is
  written (the branches included), so a state struct may be updated in place.

Operations outside the table below raise ``NotImplementedError`` at generation time, never silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from sensorless.reports.codegen.c_graph import (
    LOGIC_OPS,
    MAX_DEPTH,
    Node,
    best_branch,
    fold_parameter_products,
    forward_trivial_selects,
    fuse_selects,
    live_nodes,
    runtime_nodes,
    strength_reduce,
)

_OPS = {getattr(ca, n): n[3:] for n in dir(ca) if n.startswith("OP_")}

# op -> (C template over a, b; libm function or None). "{f}" is the precision-specific function name.
_BINARY = {
    "ADD": "({a} + {b})",
    "SUB": "({a} - {b})",
    "MUL": "({a} * {b})",
    "DIV": "({a} / {b})",
    "LT": "(({r})({a} < {b}))",
    "LE": "(({r})({a} <= {b}))",
    "EQ": "(({r})({a} == {b}))",
    "NE": "(({r})({a} != {b}))",
    "AND": "(({r})({a} && {b}))",
    "OR": "(({r})({a} || {b}))",
    "IF_ELSE_ZERO": "({a} ? {b} : {zero})",
    "FMIN": "{f}({a}, {b})",
    "FMAX": "{f}({a}, {b})",
    "POW": "{f}({a}, {b})",
    "CONSTPOW": "{f}({a}, {b})",
    "ATAN2": "{f}({a}, {b})",
    "FMOD": "{f}({a}, {b})",
    "COPYSIGN": "{f}({a}, {b})",
    "HYPOT": "{f}({a}, {b})",
}
_UNARY = {
    "NEG": "(-{a})",
    "TWICE": "({a} + {a})",
    "SQ": "({a} * {a})",
    "INV": "({one} / {a})",
    "NOT": "(({r})(!{a}))",
    "ASSIGN": "{a}",
    "SIGN": "({a} < {zero} ? -{one} : ({a} > {zero} ? {one} : {a}))",
    **{
        op: "{f}({a})"
        for op in (
            "SQRT SIN COS TAN ASIN ACOS ATAN EXP LOG SINH COSH TANH FABS FLOOR CEIL ERF EXPM1 LOG1P"
        ).split()
    },
}
_LOGIC = {  # the same operations as truth values (int), for the step's temporaries
    "LT": "({a} < {b})",
    "LE": "({a} <= {b})",
    "EQ": "({a} == {b})",
    "NE": "({a} != {b})",
    "AND": "({a} && {b})",
    "OR": "({a} || {b})",
    "NOT": "(!{a})",
}
assert set(_LOGIC) == LOGIC_OPS  # c_graph decides what is a truth value; this prints them
_LIBM = {
    "FMIN": "fmin",
    "FMAX": "fmax",
    "POW": "pow",
    "CONSTPOW": "pow",
    "ATAN2": "atan2",
    "FMOD": "fmod",
    "COPYSIGN": "copysign",
    "HYPOT": "hypot",
    "ERF": "erf",
    "EXPM1": "expm1",
    "LOG1P": "log1p",
}


@dataclass(frozen=True)
class Precision:
    """C spelling of one floating-point precision."""

    real: str  # "float" or "double"

    @property
    def single(self) -> bool:
        """True for float."""
        return self.real == "float"

    def lit(self, v: float) -> str:
        """A literal of exactly the value the precision holds: shortest round-trip digits."""
        if not math.isfinite(v):
            raise ValueError(f"non-finite constant {v!r} in an expression to be generated as C")
        if self.single:
            v32 = np.float32(v) if abs(v) <= np.finfo(np.float32).max else np.float32(np.inf)
            if not np.isfinite(v32):
                raise ValueError(f"constant {v!r} is beyond the range of float")
            text = str(v32)
            suffix = "f"
        else:
            text = repr(float(v))
            suffix = ""
        if "e" not in text and "." not in text:
            text += ".0"
        return f"({text}{suffix})" if text.startswith("-") else f"{text}{suffix}"

    def fn(self, name: str) -> str:
        """libm function of this precision: sin -> sinf for float."""
        return name + "f" if self.single else name


@dataclass
class Emitted:
    """C text of one Function: coefficient code for ``*_init`` and the step body."""

    init: list[str] = field(default_factory=list)  # computes coefficients into {coef}[offset + j]
    body: list[str] = field(default_factory=list)  # reads inputs, computes, writes outputs
    n_coef: int = 0


def build_graph(
    f: ca.Function, param_inputs: set[int]
) -> tuple[list[Node], list[tuple[tuple[int, int], int]]]:
    """The simplified operation graph of ``f`` (c_graph's passes applied) and its outputs
    [((output index, nonzero), node)]; the inputs in ``param_inputs`` are parameter-only."""
    param_in = param_inputs
    nodes: list[Node] = []
    work: dict[int, int] = {}
    outputs: list[tuple[tuple[int, int], int]] = []
    for k in range(f.n_instructions()):
        op = _OPS[f.instruction_id(k)]
        ins, outs = f.instruction_input(k), f.instruction_output(k)
        if op == "OUTPUT":
            outputs.append(((outs[0], outs[1]), work[ins[0]]))
            continue
        if op == "CONST":
            node = Node("CONST", const=float(f.instruction_constant(k)), param=True)
        elif op == "INPUT":
            node = Node("INPUT", source=(ins[0], ins[1]), param=ins[0] in param_in)
        elif op in _BINARY or op in _UNARY:
            args = tuple(work[j] for j in ins[: 2 if op in _BINARY else 1])
            node = Node(op, args, param=all(nodes[a].param for a in args))
        else:
            raise NotImplementedError(f"{f.name()}: CasADi operation OP_{op} has no C spelling here")
        nodes.append(node)
        work[outs[0]] = len(nodes) - 1

    strength_reduce(nodes)
    fold_parameter_products(nodes)
    fuse_selects(nodes)
    alias = forward_trivial_selects(nodes)
    outputs = [(o, alias.get(n, n)) for o, n in outputs]

    return nodes, outputs


def emit(
    f: ca.Function,
    *,
    prec: Precision,
    runtime_in: dict[int, list[str]],
    param_in: dict[int, list[str]],
    out: dict[int, list[str]],
    coef: str,
    coef_offset: int = 0,
    prefix: str = "t",
) -> Emitted:
    """Print ``f`` (an SX Function) as C.

    ``runtime_in[i][nz]`` is the C expression reading nonzero ``nz`` of input ``i`` in the step;
    ``param_in[i][nz]`` the expression reading a parameter in the init code; every input of ``f`` is in
    exactly one of the two. ``out[i][nz]`` is the C lvalue receiving an output nonzero. Coefficients
    are ``{coef}[coef_offset + j]`` (an array expression valid in both the init code and the step).
    """
    if not f.is_a("SXFunction"):
        raise TypeError(f"{f.name()}: only SX Functions can be printed as C")
    for i in range(f.n_in()):
        if (i in runtime_in) == (i in param_in):
            raise ValueError(f"{f.name()}: input {f.name_in(i)} must be either runtime or parameter")

    nodes, outputs = build_graph(f, set(param_in))

    # coefficients: parameter-only, non-constant values that runtime values or outputs read
    used_by_runtime: list[int] = []
    seen: set[int] = set()

    def need(a: int) -> None:
        if nodes[a].param and nodes[a].op != "CONST" and a not in seen:
            seen.add(a)
            used_by_runtime.append(a)

    live = live_nodes(nodes, [n for _, n in outputs])
    for idx in sorted(live):
        if not nodes[idx].param:
            for a in nodes[idx].args:
                need(a)
    for _, n in outputs:
        need(n)
    coef_of = {n: coef_offset + j for j, n in enumerate(sorted(used_by_runtime))}

    r = prec.real
    zero, one = prec.lit(0.0), prec.lit(1.0)

    def truth(a: int, in_init: bool) -> bool:
        """An int temporary of the step (a comparison or logical operation)."""
        return not in_init and not nodes[a].param and nodes[a].op in _LOGIC

    def ref(a: int, in_init: bool, cond: bool = False) -> str:
        """How an operand reads node ``a``; ``cond``: as a truth value (condition, logical operand)."""
        nd = nodes[a]
        if nd.op == "CONST":
            return prec.lit(nd.const)
        if not in_init and nd.param:
            return f"{coef}[{coef_of[a]}]"
        if truth(a, in_init) and not cond:
            return f"(({r}){prefix}{a})"
        return f"{prefix}{a}"

    def expr(idx: int, in_init: bool) -> str:
        nd = nodes[idx]
        if nd.op == "INPUT":
            i, nz = nd.source
            return (param_in if nd.param else runtime_in)[i][nz]
        if nd.op == "SELECT":
            c = ref(nd.args[0], in_init, cond=True)
            a, b = (ref(x, in_init) for x in nd.args[1:])
            return f"({c} ? {a} : {b})"
        logical = nd.op in ("AND", "OR", "NOT", "IF_ELSE_ZERO")  # operands read as truth values
        a = ref(nd.args[0], in_init, cond=logical)
        b = ref(nd.args[1], in_init, cond=logical and nd.op != "IF_ELSE_ZERO") if len(nd.args) > 1 else ""
        if truth(idx, in_init):
            return _LOGIC[nd.op].format(a=a, b=b)
        fname = prec.fn(_LIBM.get(nd.op, nd.op.lower()))
        tmpl = _BINARY.get(nd.op) or _UNARY[nd.op]
        return tmpl.format(a=a, b=b, f=fname, r=r, zero=zero, one=one)

    def decl(idx: int, in_init: bool) -> str:
        return "int" if truth(idx, in_init) else r

    res = Emitted(n_coef=len(coef_of))
    init_live = live_nodes(nodes, list(coef_of))
    for idx in sorted(init_live):
        if nodes[idx].op != "CONST":
            res.init.append(f"const {r} {prefix}{idx} = {expr(idx, True)};")
    for n, j in coef_of.items():
        res.init.append(f"{coef}[{j}] = {prefix}{n};")

    def compute(idxs: set[int], indent: str) -> list[str]:
        return [f"{indent}const {decl(i, False)} {prefix}{i} = {expr(i, False)};" for i in sorted(idxs)]

    def block(outs: list[tuple[str, int]], available: set[int], depth: int, indent: str) -> list[str]:
        """Lines computing ``outs`` (lvalue, node) from the ``available`` temporaries: the nodes they
        need, then the assignments, or a branch on a select condition (the module docstring)."""
        need = runtime_nodes(nodes, [n for _, n in outs]) - available
        split = best_branch(nodes, [n for _, n in outs], need, available) if depth < MAX_DEPTH else None
        if split is None:
            return compute(need, indent) + [f"{indent}{lv} = {ref(n, False)};" for lv, n in outs]
        c, common, sides = split
        lines = compute(common, indent)
        available = available | common
        both = [(lv, n) for (lv, n), t, f in zip(outs, *sides, strict=True) if t == f == n]
        lines += [f"{indent}{lv} = {ref(n, False)};" for lv, n in both]  # the same on either side
        rest = [k for k, o in enumerate(outs) if o not in both]
        for side, head in zip(sides, (f"if ({ref(c, False, cond=True)}) {{", "} else {"), strict=True):
            lines.append(indent + head)
            lines += block([(outs[k][0], side[k]) for k in rest], available, depth + 1, indent + "    ")
        return [*lines, indent + "}"]

    # every input first (in-place state update is safe, whichever branch runs), then the arithmetic
    inputs = {i for i in live if nodes[i].op == "INPUT" and not nodes[i].param}
    res.body = compute(inputs, "") + block([(out[i][nz], n) for (i, nz), n in outputs], inputs, 0, "")
    return res
