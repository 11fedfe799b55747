"""The step's operation graph (one node per CasADi instruction) and the passes that simplify it.

reports/codegen/c_emit.py builds the graph from a Function's algorithm and prints it as C; the passes
here work on the graph alone: liveness, strength reduction, folding products of parameter-only factors,
fusing CasADi's ``if_else`` selects, and choosing where the step branches on a condition (c_emit's
module docstring says what each buys the generated C).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# the comparisons and logical operations: truth values (C ints) in the step (c_emit prints them)
LOGIC_OPS = frozenset({"LT", "LE", "EQ", "NE", "AND", "OR", "NOT"})


@dataclass
class Node:
    """One operation of the step: its op name, argument node indices and what it depends on."""

    op: str
    args: tuple[int, ...] = ()
    const: float = 0.0
    source: tuple[int, int] | None = None  # (input index, nonzero) of an INPUT node
    param: bool = False  # depends on the parameters (and constants) only


def live_nodes(nodes: list[Node], roots: list[int]) -> set[int]:
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


def strength_reduce(nodes: list[Node]) -> None:
    """runtime / parameter-only  ->  runtime * (1 / parameter-only), the reciprocal hoisted;
    x / 2^n  ->  x * 2^-n (exact)."""
    recip: dict[int, int] = {}
    for idx, nd in enumerate(list(nodes)):
        if nd.op == "DIV" and nodes[nd.args[1]].op == "CONST":
            c = nodes[nd.args[1]].const
            m, _ = math.frexp(c)
            if c != 0 and abs(m) == 0.5:  # a power of two: the reciprocal is exact
                nodes.append(Node("CONST", const=1.0 / c, param=True))
                nodes[idx] = Node("MUL", (nd.args[0], len(nodes) - 1), param=nd.param)
        elif nd.op == "DIV" and not nd.param:
            a, b = nd.args
            if nodes[b].param and nodes[b].op != "CONST":
                if b not in recip:
                    nodes.append(Node("INV", (b,), param=True))
                    recip[b] = len(nodes) - 1
                nodes[idx] = Node("MUL", (a, recip[b]), param=False)


def fold_parameter_products(nodes: list[Node]) -> None:
    """MUL(p, MUL(q, x)) -> MUL(MUL(p, q), x) for parameter-only p, q and a runtime x (either order).

    In instruction order, so a chain p * (q * (r * x)) folds into one product of the three; a folded
    inner product that nothing else reads is no longer printed. One product node per pair (p, q)."""
    products: dict[tuple[int, int], int] = {}

    def split(nd: Node) -> tuple[int, int] | None:
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
                nodes.append(Node("CONST", const=p.const * q.const, param=True))
            else:
                nodes.append(Node("MUL", key, param=True))
            products[key] = len(nodes) - 1
        nodes[idx] = Node("MUL", (products[key], inner[1]), param=False)


def fuse_selects(nodes: list[Node]) -> None:
    """ADD(IF_ELSE_ZERO(c, a), IF_ELSE_ZERO(NOT(c), b))  ->  SELECT(c, a, b)."""
    for idx, nd in enumerate(nodes):
        if nd.op != "ADD" or nd.param:
            continue
        p, q = (nodes[a] for a in nd.args)
        if p.op == "IF_ELSE_ZERO" and q.op == "IF_ELSE_ZERO":
            c = p.args[0]
            nq = nodes[q.args[0]]
            if nq.op == "NOT" and nq.args[0] == c:
                nodes[idx] = Node("SELECT", (c, p.args[1], q.args[1]), param=False)


def forward_trivial_selects(nodes: list[Node]) -> dict[int, int]:
    """SELECT(c, a, a) -> a: users are rewired to ``a``; returns the map for the outputs."""
    alias: dict[int, int] = {}
    for idx, nd in enumerate(nodes):
        nd.args = tuple(alias.get(a, a) for a in nd.args)
        if nd.op == "SELECT" and nd.args[1] == nd.args[2]:
            alias[idx] = nd.args[1]
    return alias


MAX_DEPTH = 3  # nesting of the step's branches
_CHOICE = ("SELECT", "IF_ELSE_ZERO")  # operations that read one of their operands by a condition


def runtime_nodes(nodes: list[Node], roots: list[int]) -> set[int]:
    """The runtime (not parameter-only) nodes the roots depend on."""
    return {i for i in live_nodes(nodes, roots) if not nodes[i].param}


def _weight(nodes: list[Node], idxs: set[int]) -> int:
    """Work of computing ``idxs``: one per operation (reading an input or a constant is free)."""
    return sum(nodes[i].op not in ("INPUT", "CONST") for i in idxs)


def _truth_of(nd: Node) -> bool | None:
    """The truth value of a constant node, None for any other."""
    return nd.const != 0 if nd.op == "CONST" else None


def _specialize(nodes: list[Node], roots: list[int], available: set[int], c: int, value: bool) -> list[int]:
    """``roots`` with condition node ``c`` known to be ``value``: the replacement of each root.

    A select or ``IF_ELSE_ZERO`` on a known condition becomes the operand it reads; ``NOT``, ``AND``,
    ``OR`` of known values become constants (``c && d`` with ``c`` true: ``d``); a node whose operands
    changed becomes a copy (appended to ``nodes``) reading the replacements, unless it is ``available``
    (computed already: its value holds). Runtime nodes are in topological order of their indices
    (parameter-only ones do not depend on ``c``)."""
    consts: dict[float, int] = {}

    def const(v: float) -> int:
        if v not in consts:
            nodes.append(Node("CONST", const=v, param=True))
            consts[v] = len(nodes) - 1
        return consts[v]

    sub = {c: const(float(value))}
    for idx in sorted(runtime_nodes(nodes, roots) - {c}):
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
                if nodes[other].op in LOGIC_OPS:  # a truth value already: the result itself
                    new = other
        elif nd.op == "SELECT" and known[0] is not None:
            new = args[1] if known[0] else args[2]
        elif nd.op == "IF_ELSE_ZERO" and known[0] is not None:
            new = args[1] if known[0] else const(0.0)
        if new is None and args != nd.args and idx not in available:
            nodes.append(Node(nd.op, args, nd.const, nd.source, param=False))
            new = len(nodes) - 1
        if new is not None:
            sub[idx] = new
    return [sub.get(n, n) for n in roots]


def best_branch(
    nodes: list[Node], roots: list[int], need: set[int], available: set[int]
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
        live = [runtime_nodes(nodes, side) - available for side in sides]
        common = (live[0] & live[1]) | (runtime_nodes(nodes, [c]) - available)
        w_common, w_sides = _weight(nodes, common), [_weight(nodes, s - common) for s in live]
        gain = total - w_common - max(w_sides)
        if gain > best_gain and w_common + sum(w_sides) - total <= gain:
            best, best_gain = (c, common, sides), gain
        else:
            del nodes[n_before:]  # the copies of a candidate not chosen
    return best
