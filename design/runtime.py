"""Runtime set-up: a family's runtime observer with the numbers of one drive, ready to run or print as C.

What the discrete-time step of a runtime observer (symbolic/runtime.py) needs besides its equations:
the parameter vector (estimates, sampling period, gains and filter settings from the drive file or a
gain table) and, for observers whose gains are scheduled outside the step, the schedule: a symbolic
law with its parameters (a closed-form law such as Piippo et al. (2008) eq. (16)) or a table with
linear interpolation. Each family builds its :class:`RuntimeSetup` (ObserverFamily.runtime);
simulation, C generation and :func:`run_trajectory` take it from there, whatever the family.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from sensorless.design.gain_set import GainSet
from sensorless.symbolic.runtime import Field, RuntimeObserver


@dataclass(frozen=True)
class GainSchedule:
    """Gains evaluated outside the step from the state field ``observer.schedule_state``.

    ``law`` (value, params) -> lam is the schedule's own SX expression (so C prints it); ``params``
    its parameter values with their ``fields`` (names, units, meaning: a closed-form law's parameters
    go into the generated parameter struct). A tabulated schedule has ``grid`` (strictly increasing
    breakpoints) and params [lam_0 at each breakpoint..., lam_1 at each breakpoint, ...]: linear in
    between, held beyond the ends; C gets it as a const table.
    """

    label: str  # the gain law: "speed-dependent", "schedule", "constant", "zero", ...
    law: ca.Function  # (value, params) -> lam
    params: tuple[float, ...]
    fields: tuple[Field, ...]
    grid: tuple[float, ...] = ()  # breakpoints of a tabulated schedule [unit of the state field]
    text: str = ""  # one line for headers: what the law is

    def interpolation(self) -> bool | None:
        """How ``law`` reads a tabulated schedule, checked numerically on both signs, between the
        breakpoints and beyond the ends: False, the linear interpolation of ``params`` over the state's
        value, held beyond the ends; True, the same over its magnitude |value|; None, neither (or not
        tabulated): a table lookup would not be this law."""
        if not self.grid:
            return None
        grid = np.asarray(self.grid, float)
        n = grid.size
        vals = np.asarray(self.params, float).reshape(-1, n)
        mid = (grid[1:] + grid[:-1]) / 2
        pts = np.r_[grid, mid, grid[0] / 2, grid[0] - 1.0, grid[-1] + 1.0, 2 * grid[-1], 0.0]
        w = np.r_[pts, -pts]
        got = np.asarray(self.law.map(w.size)(w[None, :], self.params)).reshape(vals.shape[0], w.size)
        for over_abs in (False, True):
            want = np.stack([np.interp(np.abs(w) if over_abs else w, grid, v) for v in vals])
            if np.allclose(got, want, rtol=1e-12, atol=1e-12 * max(1.0, float(np.abs(vals).max()))):
                return over_abs
        return None


@dataclass(frozen=True)
class RuntimeSetup:
    """Everything a runtime step needs: observer, discretization, parameters, gains and their schedule."""

    observer: RuntimeObserver
    discretization: str
    params: dict[str, float]  # by observer.params field name, SI
    gains: GainSet  # the gains (and where they come from)
    schedule: GainSchedule | None = None  # None: the observer schedules nothing (n_lam = 0)
    notes: tuple[str, ...] = field(default_factory=tuple)  # what a user should know (printed by commands)

    @property
    def p(self) -> np.ndarray:
        """Parameter vector in the observer's field order."""
        return self.observer.pack_params(self.params)

    @property
    def gain(self) -> np.ndarray:
        """The schedule's parameter vector (empty without a schedule): the step's ``gain`` input."""
        return np.asarray(self.schedule.params if self.schedule is not None else (), float)

    @property
    def gain_source(self) -> str:
        """Where the gains come from, for headers and messages."""
        return self.gains.source

    def step_function(self) -> ca.Function:
        """The step (x, meas, p, gain) -> (x_next, y) with this set-up's schedule."""
        law = self.schedule.law if self.schedule is not None else None
        step = scheduled_step(self.observer, self.discretization, law)
        variant = _STEP_VARIANT.get()
        return step if variant is None else variant(self, step)

    def initial_state(self) -> np.ndarray:
        """x0 for these parameters."""
        return np.asarray(self.observer.initial_state()(self.p)).ravel()


# What runs in place of the double step while :func:`step_variant` is active (e.g. the fixed-point
# step of sensorless codegen, reports/codegen/fixed_model.py): design does not know the variants
StepVariant = Callable[[RuntimeSetup, ca.Function], ca.Function]
_STEP_VARIANT: contextvars.ContextVar[StepVariant | None] = contextvars.ContextVar(
    "step_variant", default=None
)


@contextlib.contextmanager
def step_variant(variant: StepVariant | None) -> Iterator[None]:
    """Within the block, ``RuntimeSetup.step_function()`` returns ``variant(setup, double_step)``: a
    Function of the same signature (simulation then runs, e.g., the fixed-point step in closed loop).
    It applies to the run, not to the analyses that set the run up (design/pmsm_drive.py runs those
    inside ``step_variant(None)``: a linearization of a fixed-point step's floors has no derivative)."""
    token = _STEP_VARIANT.set(variant)
    try:
        yield
    finally:
        _STEP_VARIANT.reset(token)


def double_step_active() -> bool:
    """Whether ``RuntimeSetup.step_function()`` gives the double step here (no :func:`step_variant`)."""
    return _STEP_VARIANT.get() is None


@functools.cache
def scheduled_step(observer: RuntimeObserver, discretization: str, law: ca.Function | None) -> ca.Function:
    """(x, meas, p, gain) -> (x_next, y): the observer's core step with lam = law(x[schedule_state], gain).

    Suited to ``mapaccum`` (the state is the first input and the first output).
    """
    core = observer.core(discretization)
    x = ca.SX.sym("x", len(observer.state))
    meas = ca.SX.sym("meas", len(observer.meas))
    p = ca.SX.sym("p", len(observer.params))
    if law is None:
        gain = ca.SX.sym("gain", 0)
        lam = ca.SX(0, 1)
    else:
        gain = ca.SX.sym("gain", law.size1_in(1))
        assert observer.schedule_state is not None  # a scheduled law reads the observer's schedule state
        lam = law(x[observer.index("state", observer.schedule_state)], gain)
    x_next, y = core(x, meas, p, lam)
    name = f"{core.name()}_{law.name() if law is not None else 'fixed'}"
    return ca.Function(name, [x, meas, p, gain], [x_next, y], ["x", "meas", "p", "gain"], ["x_next", "y"])


# samples per mapaccum call of run_trajectory: CasADi builds a mapaccum of 10^4 steps or more ~15x slower
# than one below (0.4-1 s against 0.03 s for the adaptive observer's step, the evaluation ~0.05 s either
# way), so a long trajectory runs as consecutive chunks of at most this many, the state carried over
CHUNK = 8192


@functools.cache
def _mapaccum(fn: ca.Function, n: int) -> ca.Function:
    return fn.mapaccum(n)


def run_trajectory(
    setup: RuntimeSetup, meas: np.ndarray, x0: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Run the step over ``meas`` (N x n_meas, one row per sample): (states N x n_x, outputs N x n_y).

    ``states[k]`` is the state *after* step k. One ``mapaccum`` call per :data:`CHUNK` samples, no
    Python loop over samples.
    """
    meas = np.atleast_2d(np.asarray(meas, dtype=float))
    n = meas.shape[0]
    x = setup.initial_state() if x0 is None else np.asarray(x0, dtype=float)
    step = setup.step_function()
    xs, ys = [], []
    for k in range(0, n, CHUNK):
        m = meas[k : k + CHUNK]
        xk, yk = _mapaccum(step, m.shape[0])(x, m.T, setup.p, setup.gain)
        xs.append(np.asarray(xk))
        ys.append(np.asarray(yk))
        x = xs[-1][:, -1]
    return np.hstack(xs).T, np.hstack(ys).T
