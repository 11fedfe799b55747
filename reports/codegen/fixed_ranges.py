"""The range of every signal of the step, for its fixed-point format (docs/codegen.md, "Fixed point").

Two sources, both from the drive:

- **interval arithmetic** over the step's operation graph (reports/codegen/c_graph.py), seeded with the
  state's bounds that the runtime contract declares (``Field.bound``: the guard keeps every accepted
  state within them) and with the measurements' simulated ranges; sound for the seeds;
- **simulation**: every scenario of the family and the generic checks run in closed loop with the double
  step (design/simulate.py); the observer's inputs of every sample are recorded and the whole graph is
  evaluated on them (vectorized), giving each signal's largest magnitude in the checks' runs.

A signal's range is the simulated one times :data:`MARGIN`, capped by the interval bound where that is
smaller; fields without a bound and the measurements take the simulated range times the margin. The
fixed-point step saturates wherever a worst-case input could exceed the format (fixed_program.py).
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from sensorless.design.family import Drive, GainSet, ObserverFamily, require
from sensorless.reports.codegen.c_graph import Node

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.design.simulate import LoopSetup

MARGIN = 2.0  # simulated ranges are doubled (and inputs clamped at twice their range)

_F = {
    "ADD": np.add,
    "SUB": np.subtract,
    "MUL": np.multiply,
    "DIV": np.divide,
    "NEG": np.negative,
    "TWICE": lambda a: a + a,
    "SQ": np.square,
    "INV": lambda a: 1.0 / a,
    "SQRT": np.sqrt,
    "SIN": np.sin,
    "COS": np.cos,
    "TAN": np.tan,
    "ATAN": np.arctan,
    "ATAN2": np.arctan2,
    "ASIN": np.arcsin,
    "EXP": np.exp,
    "LOG": np.log,
    "FABS": np.abs,
    "FMIN": np.fmin,
    "FMAX": np.fmax,
    "CEIL": np.ceil,
    "FLOOR": np.floor,
    "POW": np.power,
    "CONSTPOW": np.power,
    "ASSIGN": lambda a: a,
    "SIGN": np.sign,
    "LT": lambda a, b: (a < b) * 1.0,
    "LE": lambda a, b: (a <= b) * 1.0,
    "EQ": lambda a, b: (a == b) * 1.0,
    "NE": lambda a, b: (a != b) * 1.0,
    "AND": lambda a, b: ((a != 0) & (b != 0)) * 1.0,
    "OR": lambda a, b: ((a != 0) | (b != 0)) * 1.0,
    "NOT": lambda a: (a == 0) * 1.0,
    "IF_ELSE_ZERO": lambda c, a: np.where(c != 0, a, 0.0),
    "SELECT": lambda c, a, b: np.where(c != 0, a, b),
}


def evaluate(
    nodes: list[Node], inputs: dict[int, np.ndarray], want: set[int] | None = None
) -> dict[int, np.ndarray | float]:
    """Every node's value (float64, vectorized over samples) with input ``i`` = ``inputs[i]`` (rows:
    nonzeros). Only the nodes ``want`` depends on, if given."""
    from sensorless.reports.codegen.c_graph import live_nodes

    idx = sorted(live_nodes(nodes, list(want))) if want is not None else range(len(nodes))
    val: dict[int, np.ndarray | float] = {}

    def get(i: int) -> np.ndarray | float:
        if i not in val:
            nd = nodes[i]
            if nd.op == "CONST":
                val[i] = nd.const
            elif nd.op == "INPUT":
                val[i] = inputs[nd.source[0]][nd.source[1]]
            elif nd.op in _F:
                with np.errstate(all="ignore"):
                    val[i] = _F[nd.op](*[get(a) for a in nd.args])
            else:  # the lowering's own refusal (fixed_program.py), before the ranges need it
                raise NotImplementedError(
                    f"fixed point: operation {nd.op} on runtime values (node {i}) is not supported"
                )
        return val[i]

    for i in idx:
        get(i)
    return val


def interval(
    nodes: list[Node], seeds: dict[int, tuple[float, float]], const: dict[int, float]
) -> dict[int, tuple]:
    """Interval [lo, hi] of every runtime node from the inputs' ``seeds`` (node -> interval) and the
    parameter-only nodes' values ``const``; (-inf, inf) where no bound follows."""
    iv: dict[int, tuple[float, float]] = {}
    inf = math.inf

    def hull(*ps: float) -> tuple[float, float]:
        ps2 = [p for p in ps if not math.isnan(p)]
        return (min(ps2), max(ps2)) if len(ps2) == len(ps) else (-inf, inf)

    def mul(a: tuple, b: tuple) -> tuple:
        with np.errstate(all="ignore"):
            return hull(*(x * y for x in a for y in b))  # inf * 0: NaN, no bound

    for i, nd in enumerate(nodes):
        if i in const:
            iv[i] = (const[i], const[i])
            continue
        if nd.op == "INPUT":
            iv[i] = seeds.get(i, (-inf, inf))
            continue
        if nd.op == "CONST":
            iv[i] = (nd.const, nd.const)
            continue
        if nd.param:
            continue  # parameter-only, not read by the step
        a = [
            iv[j] if j in iv else (const[j], const[j]) if j in const else (nodes[j].const,) * 2
            for j in nd.args
        ]
        op = nd.op
        if op == "ADD":
            r = (a[0][0] + a[1][0], a[0][1] + a[1][1])
        elif op == "SUB":
            r = (a[0][0] - a[1][1], a[0][1] - a[1][0])
        elif op == "TWICE":
            r = (2 * a[0][0], 2 * a[0][1])
        elif op == "NEG":
            r = (-a[0][1], -a[0][0])
        elif op == "MUL":
            r = mul(a[0], a[1])
        elif op == "SQ":
            lo, hi = a[0]
            m = max(lo * lo, hi * hi)
            r = (0.0 if lo <= 0 <= hi else min(lo * lo, hi * hi), m)
        elif op in ("DIV", "INV"):
            num, den = (a[0], a[1]) if op == "DIV" else ((1.0, 1.0), a[0])
            r = (-inf, inf) if den[0] <= 0 <= den[1] else mul(num, (1 / den[1], 1 / den[0]))
        elif op == "FABS":
            lo, hi = a[0]
            r = (0.0 if lo <= 0 <= hi else min(abs(lo), abs(hi)), max(abs(lo), abs(hi)))
        elif op == "SQRT":
            r = (math.sqrt(max(a[0][0], 0.0)), math.sqrt(max(a[0][1], 0.0)))
        elif op in ("SIN", "COS"):
            r = (-1.0, 1.0)
        elif op == "ATAN2":
            r = (-math.pi, math.pi)
        elif op == "ASIN":
            r = (-math.pi / 2, math.pi / 2)
        elif op == "SIGN":
            r = (-1.0, 1.0)
        elif op in ("FMIN", "FMAX"):
            f = min if op == "FMIN" else max
            r = (f(a[0][0], a[1][0]), f(a[0][1], a[1][1]))
        elif op in ("CEIL", "FLOOR"):
            r = (
                math.floor(a[0][0]) if a[0][0] > -inf else -inf,
                math.ceil(a[0][1]) if a[0][1] < inf else inf,
            )
        elif op in ("LT", "LE", "EQ", "NE", "AND", "OR", "NOT"):
            r = (0.0, 1.0)
        elif op == "IF_ELSE_ZERO":
            r = hull(a[1][0], a[1][1], 0.0)
        elif op == "SELECT":
            r = hull(a[1][0], a[1][1], a[2][0], a[2][1])
        elif op == "ASSIGN":
            r = a[0]
        else:
            r = (-inf, inf)
        iv[i] = r
    return iv


CHUNK = 2048  # samples per compiled call of a probe run


@functools.cache
def _probe(step: ca.Function) -> ca.Function:
    """``step`` with its state extended by the measurements it was given: the loop then carries them."""
    nx, nm = step.size1_in(0), step.size1_in(1)
    x = ca.SX.sym("x", nx + nm)
    m = ca.SX.sym("m", nm)
    p, g = ca.SX.sym("p", step.size1_in(2)), ca.SX.sym("g", step.size1_in(3))
    x_next, y = step(x[:nx], m, p, g)
    return ca.Function(f"{step.name()}_probe", [x, m, p, g], [ca.vertcat(x_next, m), y])


@functools.cache
def _states(loop: ca.Function, n: int, native: bool = True) -> ca.Function:
    """(z, V, q, p, gain) -> (the last state, every loop state) of ``n`` steps, compiled (design/compiled.py):
    a chunk in design/simulate.py ``run_chunks``'s terms, its record the states."""
    from sensorless.design.compiled import compiled

    args = [ca.MX.sym(loop.name_in(k), loop.sparsity_in(k)) for k in range(loop.n_in())]
    V = ca.MX.sym("V", loop.size1_in(1), n)
    zs, _ = loop.mapaccum(n)(args[0], V, *args[2:])
    fn = ca.Function(f"{loop.name()}_states{n}", [args[0], V, *args[2:]], [zs[:, n - 1], zs])
    return compiled(fn) if native else fn


def probe_runs(
    drive: Drive, gains: GainSet, scenarios: list[Scenario], compile: bool = True, analysed: bool = False
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{observer name: (x, meas)} of every sample of the closed-loop runs of ``scenarios`` with the
    double step: the observer's state before each step and its measurements (columns are samples), by
    the observer that ran (the I-f start's wrapper is another). A scenario that cannot run on the
    drive (a start its loop does not model) is left out. ``compile``: the runs as native code (False:
    CasADi's virtual machine, cheaper for a short run than compiling). ``analysed``: the loop the
    whole-drive analysis linearizes (the family's ``AnalysedLoop.drive_loop``, whose observer can be
    another: the drive without its EMF harmonics) run on the scenarios, not the simulation's."""
    from sensorless.design.registry import family_of
    from sensorless.design.simulate import run_chunks
    from sensorless.design.units import DriveFileError

    fam = family_of(drive)
    runs: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for sc in scenarios:
        try:
            ls, observer, n_x = _probe_setup(fam, drive, sc, gains, analysed)
        except (DriveFileError, ValueError):
            continue
        n_m = ls.loop.size1_in(0) - len(ls.z0)
        z = np.concatenate([ls.z0, np.zeros(n_m)])
        fn = _states(ls.loop, CHUNK, compile)
        z_all = np.hstack([z[:, None], run_chunks(fn, z, [ls.q, ls.p_obs, ls.gain], ls.inputs)])
        runs.setdefault(observer, []).append((z_all[-(n_x + n_m) : -n_m, :-1], z_all[-n_m:, 1:]))
    return {k: (np.hstack([x for x, _ in v]), np.hstack([m for _, m in v])) for k, v in runs.items()}


def _probe_setup(
    fam: ObserverFamily, drive: Drive, sc: Scenario, gains: GainSet, analysed: bool = False
) -> tuple[LoopSetup, str, int]:
    """(the loop set-up of ``sc`` whose observer step carries its measurements in its state
    (:func:`_probe`), the observer's name, its state's length).

    Only the scenario's own step may be the probe: setting a loop up can analyse other loops of the
    drive first (the I-f start's handover speed is the whole drive's, design/drive_analysis.py), and
    those take the double step as it is (the probe's longer state is not theirs: their initial
    states are the observer's). The scenario's step is the last one its set-up asks for, so a first
    set-up with the double step counts the requests and the second puts the probe in the last."""
    from sensorless.design.runtime import step_variant
    from sensorless.design.simulate import AnalysedLoop, Simulatable

    if analysed:
        build = require(fam, AnalysedLoop).drive_loop
    else:
        build = require(fam, Simulatable).simulation  # one line where the family has no simulation

    asked: list[tuple[RuntimeSetup, ca.Function]] = []

    def count(setup: RuntimeSetup, step: ca.Function) -> ca.Function:
        asked.append((setup, step))
        return step

    with step_variant(count):
        plain = build(drive, sc, gains)
    last = len(asked) - 1
    setup, step = asked[last]
    asked.clear()

    def probe(s: RuntimeSetup, st: ca.Function) -> ca.Function:
        asked.append((s, st))
        return _probe(st) if len(asked) - 1 == last else st

    with step_variant(probe):
        ls = build(drive, sc, gains)
    same = len(asked) == last + 1 and asked[last][1].name() == step.name()
    if not same or not np.array_equal(ls.z0, plain.z0):
        raise RuntimeError(f"{sc.name}: the set-up of the probe run is not that of the scenario's run")
    return ls, setup.observer.name, step.size1_in(0)
