"""What storing the constants in fixed point does to the observer's poles (docs/codegen.md, "Fixed point").

The step's graph (the same one the C is printed from) is rebuilt as a CasADi Function twice: with the
constants (gains, filter and discretization coefficients, reciprocals) as computed in double, and with
the values the fixed-point program stores (Q15 for factors of products, 26 bits elsewhere). The
observer's discrete-time poles, the eigenvalues of d x_next / d x, are compared at samples of the
checks' closed-loop runs: the largest distance between matched poles and the spectral radii.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from sensorless.reports.codegen.c_graph import Node, live_nodes
from sensorless.reports.codegen.fixed_program import FixedStep, step_graph
from sensorless.reports.codegen.fixed_ranges import evaluate

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup

_SX = {
    "ADD": lambda a, b: a + b,
    "SUB": lambda a, b: a - b,
    "MUL": lambda a, b: a * b,
    "DIV": lambda a, b: a / b,
    "NEG": lambda a: -a,
    "TWICE": lambda a: 2 * a,
    "SQ": lambda a: a * a,
    "INV": lambda a: 1 / a,
    "SQRT": ca.sqrt,
    "SIN": ca.sin,
    "COS": ca.cos,
    "TAN": ca.tan,
    "ATAN2": ca.atan2,
    "ASIN": ca.asin,
    "SIGN": ca.sign,
    "FABS": ca.fabs,
    "FMIN": ca.fmin,
    "FMAX": ca.fmax,
    "CEIL": ca.ceil,
    "FLOOR": ca.floor,
    "ASSIGN": lambda a: a,
    "LT": lambda a, b: a < b,
    "LE": lambda a, b: a <= b,
    "EQ": lambda a, b: a == b,
    "NE": lambda a, b: a != b,
    "AND": ca.logic_and,
    "OR": ca.logic_or,
    "NOT": ca.logic_not,
    "IF_ELSE_ZERO": lambda c, a: ca.if_else(c, a, 0),
    "SELECT": ca.if_else,
}


def _graph(setup: RuntimeSetup) -> tuple[list[Node], list, dict[int, float]]:
    """The double step's graph (fixed_program.step_graph) and its parameter-derived constants as
    computed in double (node -> value)."""
    nodes, outs = step_graph(setup)
    live = live_nodes(nodes, [n for _, n in outs])
    params = {i for i in live if nodes[i].param}
    exact = {
        i: float(v) for i, v in evaluate(nodes, {2: setup.p, 3: setup.gain}, params).items() if i in params
    }
    return nodes, outs, exact


def _rebuild(
    nodes: list[Node], outs: list, consts: dict[int, float], x: ca.SX, m: ca.SX
) -> tuple[ca.SX, ca.SX]:
    """(x_next, y) of the graph as SX of the state ``x`` and measurements ``m``, the nodes in
    ``consts`` replaced by their values."""
    val: dict[int, ca.SX] = {}

    def get(i: int) -> ca.SX:
        if i not in val:
            nd = nodes[i]
            if i in consts:
                val[i] = ca.SX(consts[i])
            elif nd.op == "CONST":
                val[i] = ca.SX(nd.const)
            elif nd.op == "INPUT":
                val[i] = (x if nd.source[0] == 0 else m)[nd.source[1]]
            else:
                val[i] = _SX[nd.op](*[get(a) for a in nd.args])
        return val[i]

    x_next = ca.vertcat(*[get(n) for (o, _), n in sorted(outs) if o == 0])
    y = ca.vertcat(*[get(n) for (o, _), n in sorted(outs) if o == 1])
    return x_next, y


def _jacobian(nodes: list[Node], outs: list, consts: dict[int, float], n_x: int, n_m: int) -> ca.Function:
    """d x_next / d x of the graph with ``consts`` as a Function of (x, meas)."""
    x, m = ca.SX.sym("x", n_x), ca.SX.sym("m", n_m)
    x_next, _ = _rebuild(nodes, outs, consts, x, m)
    return ca.Function("step", [x, m], [ca.jacobian(x_next, x)])


def pole_shift(
    setup: RuntimeSetup, fx: FixedStep, x: np.ndarray, meas: np.ndarray, samples: int = 40
) -> dict[str, float]:
    """Largest pole displacement and spectral radii (double, stored constants) over ``samples``
    evenly spaced samples of the runs (columns of ``x``, ``meas``); the counter of the guard excluded.
    A sample where the step has no finite derivative (a magnitude's at zero: a run's initial state with
    no current) is passed over."""
    obs = setup.observer
    nodes, outs, exact = _graph(setup)
    stored = {**exact, **fx.stored}
    n_x, n_m = len(obs.state), len(obs.meas)
    jd = _jacobian(nodes, outs, exact, n_x, n_m)
    jq = _jacobian(nodes, outs, stored, n_x, n_m)
    k = n_x - 1  # the guard's counter is not a dynamic state of the observer
    shift, rho_d, rho_q = 0.0, 0.0, 0.0
    for j in np.linspace(0, x.shape[1] - 1, samples).astype(int):
        a = np.asarray(jd(x[:, j], meas[:, j]))[:k, :k]
        b = np.asarray(jq(x[:, j], meas[:, j]))[:k, :k]
        if not (np.isfinite(a).all() and np.isfinite(b).all()):
            continue
        ea, eb = np.linalg.eigvals(a), np.linalg.eigvals(b)
        d = np.abs(ea[:, None] - eb[None, :])
        shift = max(shift, float(d.min(axis=1).max()))
        rho_d, rho_q = max(rho_d, float(np.abs(ea).max())), max(rho_q, float(np.abs(eb).max()))
    return {"max_pole_shift": shift, "spectral_radius_double": rho_d, "spectral_radius_stored": rho_q}


def stored_step(setup: RuntimeSetup, fx: FixedStep) -> ca.Function:
    """The double step with its constants as the fixed-point program stores them (gains, filter and
    discretization coefficients in their Q formats), in double arithmetic: what the discrete analyses
    re-run on to show the quantization's effect on the poles (design/runtime.step_variant). Same
    signature as the step; its p and gain inputs are not read (the constants are the set-up's)."""
    obs = setup.observer
    nodes, outs, exact = _graph(setup)
    x, m = ca.SX.sym("x", len(obs.state)), ca.SX.sym("meas", len(obs.meas))
    x_next, y = _rebuild(nodes, outs, {**exact, **fx.stored}, x, m)
    pp, gg = ca.SX.sym("p", np.size(setup.p)), ca.SX.sym("gain", np.size(setup.gain))  # unread
    return ca.Function(
        f"{obs.name}_stored", [x, m, pp, gg], [x_next, y], ["x", "meas", "p", "gain"], ["x_next", "y"]
    )
