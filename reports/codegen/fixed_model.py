"""The fixed-point step in Python: the bit-exact integer model, and the same step as a CasADi Function.

``FixedModel`` is built once per drive (the ranges come from the checks' runs, fixed_ranges.py) and
gives, for any runtime set-up of that drive (a scenario's estimate errors change the constants, not the
formats):

- :meth:`FixedModel.program` the fixed-point program (fixed_program.py);
- :func:`step_raw` one step of integer numpy on raw words: what the generated C computes, bit for bit;
- :meth:`FixedModel.function` the step as a CasADi Function with the double step's signature (SI in, SI
  out; the state is carried as the SI value of its raw word, so it round-trips exactly): installed with
  :meth:`FixedModel.variant` (design/runtime.step_variant), ``simulate`` and ``report`` run the
  fixed-point step in closed loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from sensorless.design.family import Drive, GainSet
from sensorless.reports.codegen.fixed_ops import INT_MAX, INT_MIN, NUMPY, SxBackend, run
from sensorless.reports.codegen.fixed_program import FixedStep, fixed_step
from sensorless.reports.codegen.fixed_ranges import probe_runs

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.reports.codegen.fixed_ops import Word
    from sensorless.symbolic.runtime import RuntimeObserver


def step_raw(
    fx: FixedStep, x: np.ndarray, meas: np.ndarray, params: list[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """One step on raw int64 words (rows: fields; columns: independent instances): (x_next, y);
    ``params``: the parameter struct's raw words (default: the drive's)."""
    v = run(fx.prog, NUMPY, [np.asarray(r, np.int64) for r in (*x, *meas)], params)
    return np.stack([v[s] for s in fx.state_out]), np.stack([v[o["slot"]] for o in fx.outputs])


def run_raw(
    fx: FixedStep, meas: np.ndarray, x0: np.ndarray | None = None, params: list[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A trajectory of raw measurements (N x n_meas): (states N x n_x after each step, outputs N x n_y)."""
    x = np.asarray(fx.x0 if x0 is None else x0, np.int64)[:, None]
    xs, ys = [], []
    for row in np.asarray(meas, np.int64):
        x, y = step_raw(fx, x, row[:, None], params)
        xs.append(x[:, 0])
        ys.append(y[:, 0])
    return np.array(xs), np.array(ys)


@dataclass
class FixedModel:
    """The fixed-point step of one drive: the observer inputs of its checks' runs fix the formats."""

    runs: dict[str, tuple[np.ndarray, np.ndarray]]  # observer name -> (x, meas) of its runs
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, drive: Drive, gains: GainSet, scenarios: list[Scenario], compile: bool = True) -> FixedModel:
        """From the closed-loop runs of ``scenarios`` (fixed_ranges.probe_runs)."""
        return cls(probe_runs(drive, gains, scenarios, compile))

    def data(self, setup: RuntimeSetup) -> tuple[np.ndarray, np.ndarray]:
        """(x, meas) of the runs of ``setup``'s observer."""
        if setup.observer.name not in self.runs:
            raise ValueError(f"{setup.observer.name}: no run of the checks runs this observer (no ranges)")
        return self.runs[setup.observer.name]

    @property
    def meas(self) -> np.ndarray:
        """The measurements of the first observer's runs (examples, benchmarks)."""
        return next(iter(self.runs.values()))[1]

    def program(self, setup: RuntimeSetup) -> FixedStep:
        """The lowered step of ``setup`` (one per set-up's constants: the lowering takes seconds)."""
        grid = setup.schedule.grid if setup.schedule is not None else ()
        key = ("program", setup.observer.name, setup.discretization, tuple(setup.p), tuple(setup.gain), grid)
        if key not in self._cache:
            self._cache[key] = fixed_step(setup, *self.data(setup))
        return self._cache[key]

    def function(self, setup: RuntimeSetup) -> ca.Function:
        """The step as a CasADi Function (the module docstring); one per set-up's constants."""
        key = (setup.observer.name, setup.discretization, tuple(setup.p), tuple(setup.gain))
        if key not in self._cache:
            self._cache[key] = _function(self.program(setup), setup.observer, len(setup.p), len(setup.gain))
        return self._cache[key]

    def variant(self, setup: RuntimeSetup, step: ca.Function) -> ca.Function:
        """design/runtime.step_variant: the fixed-point step in place of ``step``."""
        return self.function(setup)


def _function(fx: FixedStep, obs: RuntimeObserver, n_p: int, n_g: int) -> ca.Function:
    n_x, n_m = len(obs.state), len(obs.meas)
    x = ca.SX.sym("x", n_x)
    m = ca.SX.sym("meas", n_m)
    pp, gg = ca.SX.sym("p", n_p), ca.SX.sym("gain", n_g)
    B = SxBackend()
    raw = []
    for k, d in enumerate(fx.inputs):
        v = x[k] if d["vector"] == "x" else m[k - n_x]
        if d["kind"] == "ang":
            raw.append(B.wrap(ca.floor(v * (2.0**31 / np.pi) + 0.5)))
        else:
            raw.append(B.clip(ca.floor(v * 2.0 ** d["f"] + 0.5), INT_MIN, INT_MAX))
    vals = run(fx.prog, B, raw)

    def si(s: int, kind: str, f: int) -> Word:
        return vals[s] * (np.pi / 2.0**31) if kind == "ang" else vals[s] * 2.0**-f

    states = fx.inputs[:n_x]
    x_next = ca.vertcat(*[si(s, d["kind"], d["f"]) for s, d in zip(fx.state_out, states, strict=True)])
    y = ca.vertcat(*[si(o["slot"], o["kind"], o["f"]) for o in fx.outputs])
    return ca.Function(
        f"{obs.name}_fixed", [x, m, pp, gg], [x_next, y], ["x", "meas", "p", "gain"], ["x_next", "y"]
    )
