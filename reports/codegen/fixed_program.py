"""The runtime step as a fixed-point program: formats from ranges, integer operations, saturation.

``fixed_step(setup, x, meas)`` lowers the family's registered step (``RuntimeSetup.step_function()``,
the graph the double and float C are printed from; parameters and gains become constants) into a list
of integer operations (reports/codegen/fixed_ops.py) on 32-bit words:

- **formats**: a signal of range R (fixed_ranges.py) is stored as raw = value 2^f with the largest f
  such that R 2^f <= 2^26: 26 bits of precision, 5 bits of headroom. Products by a constant (Q15)
  are two 32-bit products (exact); products of two signals that only reach a division or a square
  root (coarse_nodes) one 32-bit product of operands rounded to 15 bits (Lowering.short_product), a
  signal of at most 12 bits (a 12-bit root's) times another rounded to 15 bits and exact by two,
  the others four 32-bit products of their 16-bit halves (fixed_ops.mulw, within 3 LSB); operands
  clamped at twice their range where a glitch could overflow; 64-bit only where no form holds;
  quotients to 26 significant bits (a quotient of short products 18 at its median); sums are
  aligned by shifts; comparisons are exact;
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
  **sqrt** as an integer square root of a 32-bit word (of a radicand of short products a 24-bit
  one: 12 bits): bounds in docs/codegen.md ("Fixed point");
- no division: the graph's divisions by parameters are multiplications by constants already (c_graph);
  a division by a runtime value is refused (NotImplementedError) until it is proven non-zero.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.runtime import scheduled_step
from sensorless.reports.codegen.c_emit import build_graph
from sensorless.reports.codegen.c_graph import Node, live_nodes
from sensorless.reports.codegen.fixed_format import _PI, RANGE_FLOOR, FixedStep, _raw, format_of
from sensorless.reports.codegen.fixed_lowering import Lowering
from sensorless.reports.codegen.fixed_ops import NOMINAL_BITS, Ins
from sensorless.reports.codegen.fixed_ranges import MARGIN, evaluate, interval

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.symbolic.runtime import RuntimeObserver

__all__ = ["FixedStep", "fixed_step", "format_of", "runtime_parameters", "step_graph", "table_nodes"]


def step_graph(setup: RuntimeSetup) -> tuple[list[Node], list[tuple[tuple[int, int], int]]]:
    """The graph of ``setup``'s double step (its parameters and gains inputs 2 and 3). With a
    tabulated schedule, the schedule's gains are a third output (their nodes: what the lowering
    replaces by a table lookup, :func:`table_nodes`)."""
    obs = setup.observer
    sch = setup.schedule
    if sch is None or not sch.grid:
        # the double step itself (not a variant installed by design/runtime.step_variant: that may be us)
        return build_graph(
            scheduled_step(obs, setup.discretization, sch.law if sch is not None else None), {2, 3}
        )
    # the same step as design/runtime.scheduled_step, the gains' node shared with the step's use of it
    x, m = ca.SX.sym("x", len(obs.state)), ca.SX.sym("meas", len(obs.meas))
    p, g = ca.SX.sym("p", len(obs.params)), ca.SX.sym("gain", sch.law.size1_in(1))
    lam = sch.law(x[obs.index("state", obs.schedule_state)], g)
    x_next, y = obs.core(setup.discretization)(x, m, p, lam)
    return build_graph(ca.Function("step_table", [x, m, p, g], [x_next, y, lam]), {2, 3})


def table_nodes(setup: Any, nodes: list[Node], outs: list[tuple[tuple[int, int], int]]) -> dict[int, Any]:
    """{node of a scheduled gain: (schedule state's node, grid, gain value nodes, values, over |value|)}
    where the schedule is tabulated and its law is, checked here numerically on both signs and
    beyond the ends, the linear interpolation of its values over the state's value or its magnitude,
    held beyond the ends (design/runtime.GainSchedule); else {} (the law's graph is lowered as is)."""
    obs, sch = setup.observer, setup.schedule
    if sch is None or not sch.grid:
        return {}
    grid = np.asarray(sch.grid, float)
    n, n_lam = grid.size, len(obs.lam)
    vals = np.asarray(setup.gain, float).reshape(n_lam, n)
    ab = sch.interpolation()
    state = next(
        (
            i
            for i, nd in enumerate(nodes)
            if nd.op == "INPUT" and nd.source == (0, obs.index("state", obs.schedule_state))
        ),
        None,
    )
    inputs = {nd.source: i for i, nd in enumerate(nodes) if nd.op == "INPUT" and nd.source[0] == 3}
    out = dict(outs)
    if ab is None or state is None or any((3, k) not in inputs for k in range(n * n_lam)):
        return {}
    return {
        out[(2, j)]: (
            state,
            tuple(grid.tolist()),
            tuple(inputs[(3, j * n + k)] for k in range(n)),
            tuple(vals[j].tolist()),
            ab,
        )
        for j in range(n_lam)
        if (2, j) in out
    }


def fixed_step(setup: RuntimeSetup, x: np.ndarray, meas: np.ndarray) -> FixedStep:
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
    low = Lowering(nodes, const, rng, angle_fields)
    low.tables = table_nodes(setup, nodes, outs)
    low.coarse = coarse_nodes(nodes, live, {n for _, n in outs})
    low.rt, low.expr = runtime_parameters(nodes, obs, setup.schedule.fields if setup.schedule else ())
    for i, v in sim.items():
        if i in runtime:
            v = np.broadcast_to(v, x.shape[1:])
            low.sim_lo[i], low.sim_hi[i] = float(np.nanmin(v)), float(np.nanmax(v))
            low.sim_typ[i] = float(np.nanmedian(np.abs(v)))
    for j, d in enumerate(inputs):
        imm = (j,) if d["kind"] == "ang" else (j, -(2 ** (NOMINAL_BITS + 1)), 2 ** (NOMINAL_BITS + 1))
        wr = 2.0**31 if d["kind"] == "ang" else 2.0 ** (NOMINAL_BITS + 1)
        if d["kind"] == "fix" and d["vector"] == "x" and d["reason"].endswith("(guard)"):
            # a bounded state field is the step's own output: init writes x0 and the step only what
            # the guard accepted within the bound (or the coasting state it checked, or x0), so it
            # enters unclamped. Its word is within the bound's, at most twice the drive's value with
            # the parameters init accepts, plus the roundings of the bound's parameter and of the
            # stored format (the fuzz test checks the stored state within the bound + 1 LSB)
            imm, wr = (j,), math.ceil(2 * d["range"] * 2.0 ** d["f"]) + 2
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


COARSE_OPS = ("MUL", "SQ", "ADD", "SUB", "TWICE")


def coarse_nodes(nodes: list[Node], live: set[int], roots: set[int]) -> set[int]:
    """The live nodes whose every use is a division's operand, a square root's radicand, or a sum or
    product that is itself coarse (and none is an output)."""
    users: dict[int, set[int]] = {}
    for u in live:
        for a in nodes[u].args:
            users.setdefault(a, set()).add(u)
    memo: dict[int, bool] = {}

    def coarse(n: int) -> bool:
        if n not in memo:
            memo[n] = False  # (acyclic; a guard against recursion through itself)
            us = users.get(n, set())
            memo[n] = (
                n not in roots
                and bool(us)
                and all(
                    nodes[u].op in ("SQRT", "DIV")
                    or (nodes[u].op in ("MUL", "SQ", "ADD", "SUB", "TWICE") and coarse(u))
                    for u in us
                )
            )
        return memo[n]

    return {n for n in live if not nodes[n].param and nodes[n].op in COARSE_OPS and coarse(n)}


_INFIX = {"ADD": "+", "SUB": "-", "MUL": "*", "DIV": "/"}


def runtime_parameters(
    nodes: list[Node], obs: RuntimeObserver, gain_fields: tuple = ()
) -> tuple[set[int], Callable[[int], str]]:
    """(the parameter-derived nodes that depend on a parameter or gain other than the variant's flags:
    the step reads them from the parameter struct at run time; a function giving a node's expression
    in the parameters' names, the gain vector's by ``gain_fields``: the schedule's, a tabulated
    schedule's values at its breakpoints included). Flags (``Field.check == "flag"``) select the
    variant's code, so what derives from them alone stays a literal (and folds)."""
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
            return (obs.params if v == 2 else gain_fields)[j].name
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
