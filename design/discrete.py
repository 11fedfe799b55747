"""The discrete-time analysis of every family: its runtime step on the sampled plant, fixed point, poles.

What runs on a drive is a family's runtime step (symbolic/runtime.py) at the sampling period T_s, not
the continuous observer of its paper. This module linearizes that step, the same CasADi graph that
simulation runs and ``sensorless codegen`` prints (``RuntimeSetup.step_function``: the core with its
gain schedule), on the plant it is sampled from. A family declares a :class:`SampledLoop`:

- **the plant's samples** (``sample``): what the step takes in the period that starts with the motor
  at the electrical angle theta, at speed w, from a per-point vector ``plant`` of the family's choice.
  For a PMSM under ideal current control fed by an inverter (the voltage held constant in the
  stationary frame over each period) the hold is sampled exactly by :func:`zoh_voltage` and
  :func:`pmsm_zoh_sample`;
- **rotor coordinates** (``rotor``: a runtime state at motor angle theta -> y, and ``state``: y ->
  the runtime state, with what y leaves out filled in, e.g. stored samples of the plant). The
  contract's counter ``rejects`` (the state's last field) is not a coordinate: it is 0 in steady
  state and the guard accepts every sample there.

The one-step map is y_k -> y_k+1 = rotor(step(state(y_k, theta), sample(theta)), theta + w T_s). Where
the plant and the step are invariant under a common rotation it does not depend on theta (evaluated
at theta = 0); a family whose plant is not (EMF harmonics) evaluates it along its own orbit. Its
**fixed point** is found by Newton's method on the SX map (:func:`fixed_points`), its Jacobian there is
``casadi.jacobian`` of the same graph, and its eigenvalues z give the **poles** ln(z)/T_s
(:func:`discrete_poles`). :func:`sensitivity_function` gives the step's outputs and the map's
derivatives with respect to the runtime state and the samples (feedthrough, measurement noise).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeAlias

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.batch import evaluate_batch, settled
from sensorless.design.compiled import compiled
from sensorless.design.expm import expm_batched
from sensorless.design.poles import sort_poles
from sensorless.design.runtime import scheduled_step
from sensorless.symbolic.frames import rot, wrap_angle
from sensorless.symbolic.runtime import RuntimeObserver

Sym: TypeAlias = ca.SX
INPUTS = ("y", "theta", "w", "plant", "p", "gain")


@dataclass(frozen=True, eq=False)
class SampledLoop:
    """What a family declares to get its discrete-time analysis (the module docstring).

    Compared and hashed by identity: a family builds one per (discretization, schedule, ...) and caches
    it, so that the Functions built from it are cached too.
    """

    observer: RuntimeObserver
    discretization: str
    law: ca.Function | None  # the gain schedule's law (RuntimeSetup.schedule.law); None: no schedule
    names: tuple[str, ...]  # of the rotor coordinates y
    n_plant: int  # size of the per-point plant vector
    sample: Callable[[Sym, Sym, Sym, Sym], Sym]  # (theta, w, plant, p) -> meas of the period
    state: Callable[[Sym, Sym, Sym, Sym, Sym], Sym]  # (y, theta, w, plant, p) -> x (without the counter)
    rotor: Callable[[Sym, Sym], Sym]  # (x without the counter, theta) -> y
    angles: tuple[int, ...] = ()  # entries of y that are angles (residuals taken modulo 2 pi)

    @property
    def n_y(self) -> int:
        return len(self.names)

    def step(self) -> ca.Function:
        """The runtime step as generated: (x, meas, p, gain) -> (x_next, out)."""
        return scheduled_step(self.observer, self.discretization, self.law)

    def symbols(self) -> dict[str, Sym]:
        """The inputs of the analysis Functions (:data:`INPUTS`)."""
        law = self.law
        return {
            "y": ca.SX.sym("y", self.n_y),
            "theta": ca.SX.sym("theta"),
            "w": ca.SX.sym("w"),
            "plant": ca.SX.sym("plant", self.n_plant),
            "p": ca.SX.sym("p", len(self.observer.params)),
            "gain": ca.SX.sym("gain", law.size1_in(1) if law is not None else 0),
        }


SENSITIVITIES = ("out", "Jx", "Jm", "Dm")  # :func:`sensitivity_function`'s outputs
OUTPUTS = ("out", "Dm")  # :func:`output_function`'s


def _period(loop: SampledLoop, s: dict[str, Sym], derivatives: Sequence[str] = ()) -> dict[str, Sym]:
    """One period from motor angle theta: the map y -> y_next (SX of the symbols ``s``) and the
    ``derivatives`` named (of :data:`SENSITIVITIES`: the step's outputs and the derivatives of
    :func:`sensitivity_function`), each built the one way whichever others are asked for."""
    obs = loop.observer
    n_x = len(obs.state) - 1
    x = ca.SX.sym("x", n_x)
    m = ca.SX.sym("meas", len(obs.meas))
    theta, w, plant, p, gain = (s[k] for k in INPUTS[1:])
    T_s = p[obs.index("params", "T_s")]
    x_next, out = loop.step()(ca.vertcat(x, 0), m, p, gain)
    y_next = loop.rotor(x_next[:n_x], theta + w * T_s)
    made = {
        "out": lambda: out,
        "Jx": lambda: ca.jacobian(y_next, x),
        "Jm": lambda: ca.jacobian(y_next, m),
        "Dm": lambda: ca.jacobian(out, m),
    }
    per = {"y_next": y_next} | {k: made[k]() for k in SENSITIVITIES if k in derivatives}
    f = ca.Function("period", [x, m, *s.values()], list(per.values()))
    x0 = loop.state(s["y"], theta, w, plant, p)
    m0 = loop.sample(theta, w, plant, p)
    return dict(zip(per, f.call([x0, m0, *s.values()]), strict=True))


@functools.cache
def map_function(loop: SampledLoop) -> ca.Function:
    """(y, theta, w, plant, p, gain) -> (y_next, Jy): the one-step map and its Jacobian d y_next / d y."""
    s = loop.symbols()
    y_next = _period(loop, s)["y_next"]
    outs = ca.cse([ca.densify(v) for v in (y_next, ca.jacobian(y_next, s["y"]))])
    name = f"{loop.observer.name}_one_step_{loop.discretization.replace('-', '_')}"
    return ca.Function(name, list(s.values()), outs, list(INPUTS), ["y_next", "Jy"])


@functools.cache
def sensitivity_function(loop: SampledLoop) -> ca.Function:
    """(y, theta, w, plant, p, gain) -> (out, Jx, Jm, Dm): the step's outputs, and the derivatives of
    y_next with respect to the runtime state (without the counter) and the samples ``meas``, and of
    the outputs with respect to ``meas``: where a perturbation of either enters the map."""
    s = loop.symbols()
    per = _period(loop, s, SENSITIVITIES)
    outs = ca.cse([ca.densify(per[k]) for k in SENSITIVITIES])
    name = f"{loop.observer.name}_one_step_sens_{loop.discretization.replace('-', '_')}"
    return ca.Function(name, list(s.values()), outs, list(INPUTS), list(SENSITIVITIES))


@functools.cache
def output_function(loop: SampledLoop) -> ca.Function:
    """(y, theta, w, plant, p, gain) -> (out, Dm): of :func:`sensitivity_function`'s outputs those an
    analysis of the map's fixed points reads (the step's outputs, their derivative with respect to
    ``meas``: the feedthrough), their bits, from a graph without the map's derivatives (the adaptive
    observer's report builds it for seven loops: a third less graph to build and clean)."""
    s = loop.symbols()
    per = _period(loop, s, OUTPUTS)
    outs = ca.cse([ca.densify(per[k]) for k in OUTPUTS])
    name = f"{loop.observer.name}_one_step_out_{loop.discretization.replace('-', '_')}"
    return ca.Function(name, list(s.values()), outs, list(INPUTS), list(OUTPUTS))


@functools.cache
def rotor_function(loop: SampledLoop) -> ca.Function:
    """(x, theta) -> y: the rotor coordinates of a runtime state (with its counter) at motor angle theta."""
    x, theta = ca.SX.sym("x", len(loop.observer.state)), ca.SX.sym("theta")
    y = ca.densify(loop.rotor(x[:-1], theta))
    return ca.Function(f"{loop.observer.name}_rotor", [x, theta], [y], ["x", "theta"], ["y"])


@functools.cache
def _period_function(loop: SampledLoop) -> ca.Function:
    """([x; theta], [w; plant; p; gain]) -> ([x_next; theta_next], out): one period of the runtime step
    on the sampled plant, compiled; one per loop, shared by every orbit length (built per length, the
    sampled plant's graph and the compiled library's lookup: analyze deangelo2006's nine orbit
    Functions took 84 ms to build, 35 ms with the period shared)."""
    s = loop.symbols()
    x, theta = ca.SX.sym("x", len(loop.observer.state)), s["theta"]
    w, plant, p, gain = s["w"], s["plant"], s["p"], s["gain"]
    T_s = p[loop.observer.index("params", "T_s")]
    x_next, out = loop.step()(x, loop.sample(theta, w, plant, p), p, gain)
    par = ca.vertcat(w, plant, p, gain)
    xc_next = ca.vertcat(x_next, wrap_angle(theta + w * T_s))  # the angle wrapped: long runs stay exact
    # the step compiled (design/compiled.py, cached on disk by its C source, which depends neither on
    # n_steps nor on the drive's numbers): the orbit is thousands of steps at each point, 3.5x faster
    # than on CasADi's virtual machine, the same bits (tests/common/test_compiled_paths.py)
    name = f"{loop.observer.name}_period"
    return compiled(ca.Function(name, [ca.vertcat(x, theta), par], [xc_next, out]))


@functools.cache
def orbit_function(loop: SampledLoop, n_steps: int) -> ca.Function:
    """(x0, theta, w, plant, p, gain) -> (x, theta_k, out): ``n_steps`` periods of the runtime step on
    the sampled plant from the runtime state x0 (counter included) with the motor at theta; column k
    is the state after step k, the motor angle then (wrapped) and the step's outputs."""
    s = loop.symbols()
    n_x = len(loop.observer.state)
    F = _period_function(loop).mapaccum(n_steps)
    ins = [ca.MX.sym(k, v) for k, v in [("x0", n_x), *((k, s[k].size1()) for k in INPUTS[1:])]]
    xc, outs = F(ca.vertcat(ins[0], ins[1]), ca.repmat(ca.vertcat(*ins[2:]), 1, n_steps))
    return ca.Function(
        f"{loop.observer.name}_orbit{n_steps}",
        ins,
        [xc[:n_x, :], xc[n_x, :], outs],
        ["x0", *INPUTS[1:]],
        ["x", "theta_k", "out"],
    )


ORBIT_CHUNK = 1024  # steps of the longest orbit Function run_orbit builds


def run_orbit(
    loop: SampledLoop, n_steps: int, n: int, args: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``evaluate_batch(orbit_function(loop, n_steps), n, args)``: (x (n, n_x, n_steps), theta_k (n, 1,
    n_steps), out (n, n_out, n_steps)), run as consecutive orbits of ORBIT_CHUNK steps and then of
    powers of two, each from where the last ended: the same steps, so the same bits, from at most a
    dozen Functions a process builds and maps once (an orbit Function per length, as before, cost a
    build and a map of ~0.1 s at every new settling time: a third of the reduced-order tuner's CPU)."""
    x, theta, *ctx = args
    parts: list[list[np.ndarray]] = [[], [], []]
    left = int(n_steps)
    while left > 0:
        k = ORBIT_CHUNK if left >= ORBIT_CHUNK else 1 << (left.bit_length() - 1)
        xs, ths, outs = evaluate_batch(orbit_function(loop, k), n, [x, theta, *ctx])
        for part, a in zip(parts, (xs, ths, outs), strict=True):
            part.append(a)
        x = np.ascontiguousarray(xs[:, :, -1].T)  # the runtime state (its counter included)
        theta = ths[:, 0, -1]
        left -= k
    xs, ths, outs = (np.concatenate(p, axis=2) for p in parts)
    return xs, ths, outs


def _args(loop: SampledLoop, theta, w, plant, p, gain) -> list[np.ndarray]:
    """The map's inputs after y for evaluate_batch (each one instance or one column per point)."""
    w = np.asarray(w, float).ravel()
    plant = np.asarray(plant, float)
    return [
        np.asarray(theta, float).ravel(),
        w[None, :],
        plant.T if plant.ndim == 2 else plant,
        np.asarray(p, float),
        _gain_columns(gain),
    ]


def _gain_columns(gain: ArrayLike) -> np.ndarray:
    """One gain vector for every point (any shape, flattened), or (n_gain, N): one column per point."""
    g = np.asarray(gain, float)
    return g if g.ndim == 2 else g.ravel()


def fixed_points(
    loop: SampledLoop,
    y0: np.ndarray,
    w: np.ndarray,
    plant: np.ndarray,
    p: np.ndarray,
    gain: Sequence[float] | np.ndarray = (),
    theta: float | np.ndarray = 0.0,
    scale: np.ndarray | None = None,
    iterations: int = 12,
    damped: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Newton's method on y_next(y) = y from ``y0`` (N, n_y): (fixed points y, Jacobians J there).

    ``plant`` is (N, n_plant) or one vector, ``p`` (n_p,) or (n_p, N), ``theta`` the motor angle (one or
    (N,)), ``scale`` (N, n_y) the size of
    each coordinate (default 1 + |y0|). A point whose iteration does not settle (a residual above
    1e-9 of its scale), or that starts from NaN, gets NaN.
    """
    args = _args(loop, theta, w, plant, p, gain)
    y, J = newton(map_function(loop), args, y0, loop.angles, scale, iterations, damped)[:2]
    return y, J


def newton(
    fn: ca.Function,
    args: Sequence[np.ndarray],
    y0: np.ndarray,
    angles: Sequence[int] = (),
    scale: np.ndarray | None = None,
    iterations: int = 12,
    damped: bool = False,
    jit: bool | None = None,
) -> tuple[np.ndarray, ...]:
    """Newton's method on the fixed point of any one-step map ``fn`` (y, *args) -> (y_next, Jy, ...)
    from ``y0`` (N, n_y), batched (evaluate_batch): (y, Jy, the map's other outputs there), each
    (N, ...); ``angles`` the entries of y whose residual is taken modulo 2 pi. A point whose iteration
    does not settle (a residual above 1e-9 of its ``scale``, default 1 + |y0|), or that starts from
    NaN, gets NaN. ``damped``: a step that leaves a larger scaled residual is halved instead (a full
    step from a start outside the fixed point's basin, near a slow mode where the map is nearly
    singular, may land on another fixed point of a nonlinear map). ``jit``: evaluate_batch's (compile
    ``fn`` whatever the batch size)."""
    n, n_y = y0.shape
    bad = ~np.isfinite(y0).all(axis=1)
    y = np.where(bad[:, None], 0.0, y0)
    scale = 1.0 + np.abs(y) if scale is None else scale
    eye = np.eye(n_y)

    def residual(y_next: np.ndarray) -> np.ndarray:
        r = y_next[:, :, 0] - y
        for j in angles:
            r[:, j] = np.angle(np.exp(1j * r[:, j]))
        return r

    # the arguments as evaluate_batch takes them: one instance, or a column per point (a scalar input:
    # one value per point), read once (the iterations take the columns of the points still iterating)
    given = [np.asarray(a, float) for a in args]
    per_point = [
        None if a.size == fn.size1_in(k) else a if a.ndim == 1 else a.reshape(fn.size1_in(k), n)
        for k, a in enumerate(given, start=1)
    ]

    def at(idx: np.ndarray) -> list[np.ndarray]:
        """The arguments at the points idx (evaluate_batch: one instance, or one column per point)."""
        cols = zip(given, per_point, strict=True)
        return [a if c is None else c[idx] if c.ndim == 1 else c[:, idx] for a, c in cols]

    # the points still iterating (only they are evaluated); a NaN start is none: it gets NaN (iterated
    # from 0, such a point took every iteration: two thirds of a flux hub drive's Newton evaluations)
    todo = np.flatnonzero(~bad)
    size = np.full(n, np.inf)  # damped: the scaled residual at each point's last accepted iterate
    last = np.zeros((n, n_y))  # damped: the step that led to the iterate
    # damped: a point's iteration is a function of its state (y, size, last) alone, so a point whose
    # state repeats the one of two iterations before cycles to the end (a residual just above the 1e-13
    # that stops it, the step flipping between two neighbouring floats: the damped flux analysis' 200
    # iterations on a few dozen points per batch); its last state is known from the cycle's parity
    # and it leaves the batch: the same y as iterating on (where each evaluation runs the same code).
    # Not looked for in a plain Newton's few iterations (its cost per iteration, for a few saved)
    # the states at the start of the last two iterations (iteration it in past[it % 2]; only the rows of
    # the points still iterating are written: every earlier iteration iterated them)
    past = [(np.empty_like(y), np.empty_like(size), np.empty_like(last)) for _ in range(2 if damped else 0)]
    for it in range(iterations if todo.size else 0):
        if damped and it >= 2 and settled(fn, jit):
            same = np.ones(todo.size, bool)
            for a, b in zip((y, size, last), past[it % 2], strict=True):
                a_, b_ = a[todo].reshape(todo.size, -1), b[todo].reshape(todo.size, -1)
                same &= (a_.view(np.int64) == b_.view(np.int64)).all(axis=1)
            if same.any():
                if (iterations - it) % 2:  # ends on the other state of the cycle: the one before
                    y[todo[same]] = past[(it - 1) % 2][0][todo[same]]
                todo = todo[~same]
                if todo.size == 0:
                    break
        if damped:
            for a, b in zip((y, size, last), past[it % 2], strict=True):
                b[todo] = a[todo]
        y_next, Jy, *_ = evaluate_batch(fn, todo.size, [y[todo].T, *at(todo)], jit=jit)
        r = y_next[:, :, 0] - y[todo]
        for j in angles:
            r[:, j] = np.angle(np.exp(1j * r[:, j]))
        if damped:  # a step that left a larger residual is halved (back along it), not followed
            now = np.max(np.abs(r) / scale[todo], axis=1)
            back = now > size[todo]
            last[todo[back]] /= 2
            y[todo[back]] += last[todo[back]]
            size[todo[~back]] = now[~back]
        else:
            back = np.zeros(todo.size, bool)
        go = ~back & ~(np.abs(r) <= 1e-13 * scale[todo]).all(axis=1) & np.isfinite(Jy).all(axis=(1, 2))
        if not (go | back).any():
            break
        A = Jy[go] - eye
        with np.errstate(over="ignore", invalid="ignore"):  # a huge determinant is no singular one
            ok = np.abs(np.linalg.det(A)) > 1e-300
        step = np.linalg.solve(A[ok], r[go][ok][:, :, None])[:, :, 0]
        stepped = todo[go][ok]
        y[stepped] -= step
        last[stepped] = step
        todo = np.concatenate([stepped, todo[back]])
        if todo.size == 0:
            break
    live = np.flatnonzero(~bad)
    # the map's outputs at every point: evaluated where there was a start, NaN elsewhere
    outs = [np.full((n, fn.size1_out(j), fn.size2_out(j)), np.nan) for j in range(fn.n_out())]
    if live.size:
        for full, o in zip(outs, evaluate_batch(fn, live.size, [y[live].T, *at(live)], jit=jit), strict=True):
            full[live] = o
    y_next, Jy, *more = outs
    with np.errstate(invalid="ignore"):  # the NaN rows are bad already
        bad |= ~(np.abs(residual(y_next)) <= 1e-9 * scale).all(axis=1)
    y[bad] = np.nan
    nan = lambda a: np.where(bad.reshape(-1, *([1] * (a.ndim - 1))), np.nan, a)  # noqa: E731
    return (y, nan(Jy), *(nan(m) for m in more))


def sensitivities(
    loop: SampledLoop,
    y: np.ndarray,
    w: np.ndarray,
    plant: np.ndarray,
    p: np.ndarray,
    gain: ArrayLike = (),
    theta: float | np.ndarray = 0.0,
    outputs_only: bool = False,
) -> dict[str, np.ndarray]:
    """:func:`sensitivity_function` at the points y (N, n_y) (NaN rows stay NaN): out (N, n_out),
    Jx (N, n_y, n_x), Jm (N, n_y, n_meas), Dm (N, n_out, n_meas); ``outputs_only``: out and Dm alone
    (:func:`output_function`: the same bits)."""
    n = y.shape[0]
    bad = ~np.isfinite(y).all(axis=1)
    ys = np.where(bad[:, None], 0.0, y)
    fn = output_function(loop) if outputs_only else sensitivity_function(loop)
    values = evaluate_batch(fn, n, [ys.T, *_args(loop, theta, w, plant, p, gain)])
    res = dict(zip(OUTPUTS if outputs_only else SENSITIVITIES, values, strict=True))
    res["out"] = res["out"][:, :, 0]
    return {k: np.where(bad.reshape(-1, *([1] * (v.ndim - 1))), np.nan, v) for k, v in res.items()}


def eigenvalues_by_size(J: np.ndarray) -> np.ndarray:
    """(N, n) eigenvalues of each (n, n) matrix, largest |z| first (NaN rows for non-finite matrices)."""
    n = J.shape[0]
    z = np.full((n, J.shape[1]), np.nan + 0j)
    ok = np.isfinite(J).all(axis=(1, 2))
    if ok.any():
        z[ok] = np.linalg.eigvals(J[ok]).astype(complex)
    order = np.argsort(-np.abs(np.where(np.isnan(z), 0, z)), axis=1, kind="stable")
    return np.take_along_axis(z, order, axis=1)


def discrete_poles(J: np.ndarray, T_s: float | np.ndarray, n_poles: int) -> tuple[np.ndarray, np.ndarray]:
    """(ln(z)/T_s of the ``n_poles`` largest |z|, sorted like sort_poles; |z| of the others) of each
    one-step Jacobian (N, n, n). ``T_s`` may be per point (N,), e.g. the length of a window of steps."""
    return poles_by_size(eigenvalues_by_size(J), T_s, n_poles)


def poles_by_size(z: np.ndarray, T_s: float | np.ndarray, n_poles: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`discrete_poles` of the eigenvalues ``z`` of :func:`eigenvalues_by_size` (a caller that
    needs them too computes them once)."""
    T = np.asarray(T_s, float).reshape(-1, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(z[:, :n_poles]) / T
    return sort_poles(s), np.abs(z[:, n_poles:])


def pole_distance(poles_c: np.ndarray, poles_d: np.ndarray) -> np.ndarray:
    """(N,) max |s_d - s_c| [1/s] over the best one-to-one matching of each row's poles (NaN stays)."""
    n = poles_c.shape[1]
    best = np.full(poles_c.shape[0], np.inf)
    for perm in itertools.permutations(range(n)):
        best = np.minimum(best, np.abs(poles_d[:, list(perm)] - poles_c).max(axis=1))
    bad = np.isnan(poles_c).any(axis=1) | np.isnan(poles_d).any(axis=1)
    return np.where(bad, np.nan, best)


# --------------------------------------------------------------------------------------------------
# The PMSM under ideal current control, fed through an inverter's zero-order hold
# --------------------------------------------------------------------------------------------------
def zoh_voltage(
    motor: Sequence[float] | np.ndarray, w_m: np.ndarray, i_s0: np.ndarray, T_s: float
) -> np.ndarray:
    """(N, 2) rotor-frame voltage u_z at the start of a period that keeps the sampled current at i_s0.

    ``motor`` = [R_s, L_d, L_q, psi_pm] (the true motor; or (N, 4), one motor per point), ``w_m`` (N,)
    [rad/s], ``i_s0`` (N, 2) [A]. The
    stationary-frame voltage T(theta_m(t_k)) u_z is held over [t_k, t_k + T_s]; in the rotor frame it
    is T(-w_m tau) u_z. The flux equation of the PMSM (symbolic/pmsm.py; Piippo et al. (2008) eqs.
    (1)-(2)) in the rotor frame, d psi/dt = M psi + c + v with M = -R_s L^-1 - w_m J, c = R_s L^-1
    psi_pm, and dv/dt = -w_m J v: one 5x5 matrix exponential per point gives psi(T_s) = E11 psi(0) +
    E12 u_z + E13, and psi(T_s) = psi(0) = L i_s0 + psi_pm fixes u_z.
    """
    w = np.asarray(w_m, float).ravel()
    n = w.size
    R, Ld, Lq, psi_pm = (np.broadcast_to(v, (n,)) for v in np.asarray(motor, float).reshape(-1, 4).T)
    Jm = np.array([[0.0, -1.0], [1.0, 0.0]])
    Ma = np.zeros((n, 5, 5))
    Ma[:, 0:2, 0:2] = -w[:, None, None] * Jm
    Ma[:, 0, 0] -= R / Ld
    Ma[:, 1, 1] -= R / Lq
    Ma[:, 0:2, 2:4] = np.eye(2)
    Ma[:, 0, 4] = R / Ld * psi_pm
    Ma[:, 2:4, 2:4] = -w[:, None, None] * Jm
    E = expm_batched(Ma * T_s)
    psi0 = np.asarray(i_s0, float) * np.column_stack([Ld, Lq])
    psi0[:, 0] += psi_pm
    rhs = psi0 - np.einsum("nij,nj->ni", E[:, 0:2, 0:2], psi0) - E[:, 0:2, 4]
    return np.linalg.solve(E[:, 0:2, 2:4], rhs[:, :, None])[:, :, 0]


def pmsm_zoh_sample(theta: Sym, w: Sym, plant: Sym, p: Sym) -> Sym:
    """meas = [i_ab, u_ab] of a PMSM (symbolic/pmsm_drive.MEAS_FIELDS) at motor angle theta: the
    current i_s0 = plant[0:2] sampled at the start of the period and the rotor-frame voltage u_z =
    plant[2:4] of :func:`zoh_voltage` held over it, both in the stationary frame."""
    T = rot(theta)
    return ca.vertcat(T @ plant[0:2], T @ plant[2:4])


def pmsm_zoh_plant(
    motor: Sequence[float] | np.ndarray, w: np.ndarray, i_s0: np.ndarray, T_s: float
) -> np.ndarray:
    """(N, 4) plant vectors [i_s0, u_z] of :func:`pmsm_zoh_sample` at speeds ``w`` with currents
    ``i_s0`` (N, 2) in the rotor frame."""
    i_s0 = np.asarray(i_s0, float).reshape(-1, 2)
    return np.hstack([i_s0, zoh_voltage(motor, w, i_s0, T_s)])
