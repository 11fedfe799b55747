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
  branch again (nesting at most ``_MAX_DEPTH``). The values are the same as with the selects;
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
class _Node:
    op: str
    args: tuple[int, ...] = ()
    const: float = 0.0
    source: tuple[int, int] | None = None  # (input index, nonzero) of an INPUT node
    param: bool = False  # depends on the parameters (and constants) only


@dataclass
class Emitted:
    """C text of one Function: coefficient code for ``*_init`` and the step body."""

    init: list[str] = field(default_factory=list)  # computes coefficients into {coef}[offset + j]
    body: list[str] = field(default_factory=list)  # reads inputs, computes, writes outputs
    n_coef: int = 0


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

    nodes: list[_Node] = []
    work: dict[int, int] = {}
    outputs: list[tuple[tuple[int, int], int]] = []
    for k in range(f.n_instructions()):
        op = _OPS[f.instruction_id(k)]
        ins, outs = f.instruction_input(k), f.instruction_output(k)
        if op == "OUTPUT":
            outputs.append(((outs[0], outs[1]), work[ins[0]]))
            continue
        if op == "CONST":
            node = _Node("CONST", const=float(f.instruction_constant(k)), param=True)
        elif op == "INPUT":
            node = _Node("INPUT", source=(ins[0], ins[1]), param=ins[0] in param_in)
        elif op in _BINARY or op in _UNARY:
            args = tuple(work[j] for j in ins[: 2 if op in _BINARY else 1])
            node = _Node(op, args, param=all(nodes[a].param for a in args))
        else:
            raise NotImplementedError(f"{f.name()}: CasADi operation OP_{op} has no C spelling here")
        nodes.append(node)
        work[outs[0]] = len(nodes) - 1

    _strength_reduce(nodes)
    _fold_parameter_products(nodes)
    _fuse_selects(nodes)
    alias = _forward_trivial_selects(nodes)
    outputs = [(o, alias.get(n, n)) for o, n in outputs]

    # coefficients: parameter-only, non-constant values that runtime values or outputs read
    used_by_runtime: list[int] = []
    seen: set[int] = set()

    def need(a: int) -> None:
        if nodes[a].param and nodes[a].op != "CONST" and a not in seen:
            seen.add(a)
            used_by_runtime.append(a)

    live = _live(nodes, [n for _, n in outputs])
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
    init_live = _live(nodes, list(coef_of))
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
        need = _runtime(nodes, [n for _, n in outs]) - available
        split = _best_branch(nodes, [n for _, n in outs], need, available) if depth < _MAX_DEPTH else None
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


def _live(nodes: list[_Node], roots: list[int]) -> set[int]:
    """Indices of the nodes the roots depend on (roots included)."""
    live: set[int] = set()
    stack = list(roots)
    while stack:
        n = stack.pop()
        if n in live:
            continue
        live.add(n)
        stack.extend(nodes[n].args)
    return live


def _strength_reduce(nodes: list[_Node]) -> None:
    """runtime / parameter-only  ->  runtime * (1 / parameter-only), the reciprocal hoisted;
    x / 2^n  ->  x * 2^-n (exact)."""
    recip: dict[int, int] = {}
    for idx, nd in enumerate(list(nodes)):
        if nd.op == "DIV" and nodes[nd.args[1]].op == "CONST":
            c = nodes[nd.args[1]].const
            m, _ = math.frexp(c)
            if c != 0 and abs(m) == 0.5:  # a power of two: the reciprocal is exact
                nodes.append(_Node("CONST", const=1.0 / c, param=True))
                nodes[idx] = _Node("MUL", (nd.args[0], len(nodes) - 1), param=nd.param)
        elif nd.op == "DIV" and not nd.param:
            a, b = nd.args
            if nodes[b].param and nodes[b].op != "CONST":
                if b not in recip:
                    nodes.append(_Node("INV", (b,), param=True))
                    recip[b] = len(nodes) - 1
                nodes[idx] = _Node("MUL", (a, recip[b]), param=False)


def _fold_parameter_products(nodes: list[_Node]) -> None:
    """MUL(p, MUL(q, x)) -> MUL(MUL(p, q), x) for parameter-only p, q and a runtime x (either order).

    In instruction order, so a chain p * (q * (r * x)) folds into one product of the three; a folded
    inner product that nothing else reads is no longer printed. One product node per pair (p, q)."""
    products: dict[tuple[int, int], int] = {}

    def split(nd: _Node) -> tuple[int, int] | None:
        """(parameter-only factor, runtime factor) of a runtime MUL with exactly one of each."""
        if nd.op != "MUL" or nd.param:
            return None
        a, b = nd.args
        if nodes[a].param != nodes[b].param:
            return (a, b) if nodes[a].param else (b, a)
        return None

    for idx in range(len(nodes)):
        outer = split(nodes[idx])
        inner = split(nodes[outer[1]]) if outer else None
        if outer is None or inner is None:
            continue
        key = (min(outer[0], inner[0]), max(outer[0], inner[0]))
        if key not in products:
            p, q = (nodes[k] for k in key)
            if p.op == "CONST" and q.op == "CONST":
                nodes.append(_Node("CONST", const=p.const * q.const, param=True))
            else:
                nodes.append(_Node("MUL", key, param=True))
            products[key] = len(nodes) - 1
        nodes[idx] = _Node("MUL", (products[key], inner[1]), param=False)


def _fuse_selects(nodes: list[_Node]) -> None:
    """ADD(IF_ELSE_ZERO(c, a), IF_ELSE_ZERO(NOT(c), b))  ->  SELECT(c, a, b)."""
    for idx, nd in enumerate(nodes):
        if nd.op != "ADD" or nd.param:
            continue
        p, q = (nodes[a] for a in nd.args)
        if p.op == "IF_ELSE_ZERO" and q.op == "IF_ELSE_ZERO":
            c = p.args[0]
            nq = nodes[q.args[0]]
            if nq.op == "NOT" and nq.args[0] == c:
                nodes[idx] = _Node("SELECT", (c, p.args[1], q.args[1]), param=False)


def _forward_trivial_selects(nodes: list[_Node]) -> dict[int, int]:
    """SELECT(c, a, a) -> a: users are rewired to ``a``; returns the map for the outputs."""
    alias: dict[int, int] = {}
    for idx, nd in enumerate(nodes):
        nd.args = tuple(alias.get(a, a) for a in nd.args)
        if nd.op == "SELECT" and nd.args[1] == nd.args[2]:
            alias[idx] = nd.args[1]
    return alias


_MAX_DEPTH = 3  # nesting of the step's branches
_CHOICE = ("SELECT", "IF_ELSE_ZERO")  # operations that read one of their operands by a condition


def _runtime(nodes: list[_Node], roots: list[int]) -> set[int]:
    """The runtime (not parameter-only) nodes the roots depend on."""
    return {i for i in _live(nodes, roots) if not nodes[i].param}


def _weight(nodes: list[_Node], idxs: set[int]) -> int:
    """Work of computing ``idxs``: one per operation (reading an input or a constant is free)."""
    return sum(nodes[i].op not in ("INPUT", "CONST") for i in idxs)


def _truth_of(nd: _Node) -> bool | None:
    """The truth value of a constant node, None for any other."""
    return nd.const != 0 if nd.op == "CONST" else None


def _specialize(nodes: list[_Node], roots: list[int], available: set[int], c: int, value: bool) -> list[int]:
    """``roots`` with condition node ``c`` known to be ``value``: the replacement of each root.

    A select or ``IF_ELSE_ZERO`` on a known condition becomes the operand it reads; ``NOT``, ``AND``,
    ``OR`` of known values become constants (``c && d`` with ``c`` true: ``d``); a node whose operands
    changed becomes a copy (appended to ``nodes``) reading the replacements, unless it is ``available``
    (computed already: its value holds). Runtime nodes are in topological order of their indices
    (parameter-only ones do not depend on ``c``)."""
    consts: dict[float, int] = {}

    def const(v: float) -> int:
        if v not in consts:
            nodes.append(_Node("CONST", const=v, param=True))
            consts[v] = len(nodes) - 1
        return consts[v]

    sub = {c: const(float(value))}
    for idx in sorted(_runtime(nodes, roots) - {c}):
        nd = nodes[idx]
        args = tuple(sub.get(a, a) for a in nd.args)
        known = [_truth_of(nodes[a]) for a in args]
        new: int | None = None
        if nd.op == "NOT" and known[0] is not None:
            new = const(float(not known[0]))
        elif nd.op in ("AND", "OR"):
            decisive = nd.op == "OR"  # the operand value that decides the result alone
            if decisive in known:
                new = const(float(decisive))
            elif None not in known:
                new = const(float(not decisive))
            elif known != [None, None]:
                other = args[1] if known[0] is not None else args[0]
                if nodes[other].op in _LOGIC:  # a truth value already: the result itself
                    new = other
        elif nd.op == "SELECT" and known[0] is not None:
            new = args[1] if known[0] else args[2]
        elif nd.op == "IF_ELSE_ZERO" and known[0] is not None:
            new = args[1] if known[0] else const(0.0)
        if new is None and args != nd.args and idx not in available:
            nodes.append(_Node(nd.op, args, nd.const, nd.source, param=False))
            new = len(nodes) - 1
        if new is not None:
            sub[idx] = new
    return [sub.get(n, n) for n in roots]


def _best_branch(
    nodes: list[_Node], roots: list[int], need: set[int], available: set[int]
) -> tuple[int, set[int], tuple[list[int], list[int]]] | None:
    """The condition to branch on for computing ``roots`` (``need``: the nodes still to compute), or None.

    Candidates are the runtime conditions of the selects in ``need``. For each, the two sides are
    specialized (:func:`_specialize`); the work common to both (and the condition) comes first. The
    choice shortens the longer path the most, by at least 4 operations, and duplicates no more work
    than it saves. Returns (condition, common nodes, (roots if true, roots if false))."""
    conds: set[int] = set()
    for i in need:
        if nodes[i].op in _CHOICE and not nodes[nodes[i].args[0]].param:
            c = nodes[i].args[0]
            while nodes[c].op == "NOT":  # !c ? a : b reads c
                c = nodes[c].args[0]
            conds.add(c)
    total = _weight(nodes, need)
    best, best_gain = None, 3
    for c in sorted(conds):
        n_before = len(nodes)
        sides = tuple(_specialize(nodes, roots, available, c, v) for v in (True, False))
        live = [_runtime(nodes, side) - available for side in sides]
        common = (live[0] & live[1]) | (_runtime(nodes, [c]) - available)
        w_common, w_sides = _weight(nodes, common), [_weight(nodes, s - common) for s in live]
        gain = total - w_common - max(w_sides)
        if gain > best_gain and w_common + sum(w_sides) - total <= gain:
            best, best_gain = (c, common, sides), gain
        else:
            del nodes[n_before:]  # the copies of a candidate not chosen
    return best
