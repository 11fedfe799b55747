"""Time-domain simulation of a whole sensorless drive: a compiled ``mapaccum`` over the loop step.

``simulate(drive, scenario)`` asks the drive's family for its loop set-up (ObserverFamily.simulation:
the loop step around the runtime observer step that is also generated to C, the parameter vectors,
the initial state and the per-sample inputs) and runs the loop as ``Function.mapaccum`` over chunks of
samples, compiled to native code (design/compiled.py) once that pays (:data:`JIT_MIN_STEPS`). No Python
code runs per sample; Python only moves from one chunk to the next, which is where progress is reported.

Limits and checks (docs/simulation.md): a run has at most :data:`MAX_SAMPLES` control periods
(:func:`check_length`, before anything is allocated); :meth:`Traces.problems` says whether a result
holds: every recorded signal finite, and the position estimate not lost (:func:`position_lost`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar, runtime_checkable

import casadi as ca
import numpy as np
from sensorless.design.batch import bound_call
from sensorless.design.compiled import compiled, index, indexed, is_cached, wanted_elsewhere
from sensorless.design.family import LACKS, Drive, GainSet, require
from sensorless.design.memo import by_content, fingerprint
from sensorless.design.registry import family_of
from sensorless.design.runtime import double_step_active
from sensorless.design.scenario import Scenario
from sensorless.symbolic.runtime import Field

CHUNK = 2048  # samples per compiled call: progress granularity; the per-call cost is negligible
# A loop runs on CasADi's virtual machine until this process has run it for JIT_MIN_STEPS control periods
# in all, then compiled: the VM takes ~10 us more per period (10-16 us against 4-5 us, the three
# families' loops), compiling one takes 0.5-1 s, so a short run (a test, a check, a first look) is done
# before a compiler would be. A loop whose library is in the cache (design/compiled.py) runs compiled at
# once, and one that another process has run before is compiled at once (its library then serves every
# later run). The same bits either way (tests/common/test_compiled_paths.py).
JIT_MIN_STEPS = 50_000
_STEPS: dict[ca.Function, int] = {}  # control periods run so far, per loop (simulate)
# Most control periods one run may have: 400 s at 200 us. The traces take about 0.2 kB per period in
# memory (and more as CSV), so the limit keeps a run within a few hundred MB.
MAX_SAMPLES = 2_000_000
# The position estimate is lost when its error, after having been below this, reaches it while the
# rotor turns at LOST_MIN_SPEED of the base speed or faster: beyond 90 degrees the torque produced in
# the estimated frame has the opposite sign of the one commanded. (At standstill an EMF-based
# estimate is undefined, and a flip as the rotor starts is not a loss.)
LOST_ANGLE = math.pi / 2
LOST_MIN_SPEED = 0.01


class SimulationError(ValueError):
    """A simulation that cannot be run as asked (the message names the file or option and why)."""


@dataclass(frozen=True)
class StateFrames:
    """How a runtime observer's state turns with the rotor, by field name: what a family declares of
    its observer for the whole-drive linearization (design/drive_analysis.py) of the loop it runs in.
    The fields not named are invariant (rotor- or estimated-frame quantities, speeds, gains)."""

    angles: tuple[str, ...] = ()  # stationary-frame angles (the angle estimate)
    vectors: tuple[tuple[str, str], ...] = ()  # stationary-frame vectors (alpha, beta)
    held: tuple[str, ...] = ()  # at rest in the drive analysed (e.g. an HF-injection chain switched off)


@dataclass(frozen=True)
class LoopCoordinates:
    """How a drive loop's state turns with the rotor: the declaration its whole-drive linearization
    (design/drive_analysis.py) needs, by index into the loop's state z and per-sample inputs v.

    The loop is invariant under a rotation of the stationary frame (a sinusoidal EMF); in rotor
    coordinates (the angle ``theta`` left out, the other stationary-frame ``angles`` taken relative to
    it, the stationary-frame ``vectors`` turned into the rotor frame) its one-step map has a fixed
    point at a steady operating point. ``held`` entries are no dynamics of the loop analysed (the
    runtime contract's counter, filters whose output nothing reads in it): held at their rest value.
    ``start(v0 (n_v, N), w0 (N,)) -> z0 (n_z, N)``: the loop at rest at those inputs and speeds with the
    rotor at angle 0 (the Newton start of the fixed point)."""

    theta: int
    speed: int
    w_ref: int
    load: int
    angles: tuple[int, ...] = ()
    vectors: tuple[tuple[int, int], ...] = ()
    held: tuple[int, ...] = ()
    start: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = field(default=None, compare=False)

    def key(self) -> tuple:
        """What the map's Function depends on (hashable; ``start`` left out)."""
        return (self.theta, self.speed, self.w_ref, self.load, self.angles, self.vectors, self.held)


@dataclass(frozen=True)
class LoopSetup:
    """Everything the runner needs: the loop Function, its constant inputs, initial state and inputs."""

    loop: ca.Function  # (z, v, q, p_obs, gain) -> (z_next, rec)
    q: np.ndarray
    p_obs: np.ndarray
    gain: np.ndarray
    z0: np.ndarray
    inputs: np.ndarray  # (n_v, N): one column per sample
    record: tuple[Field, ...]  # names and units of the rows of rec
    T_s: float
    meta: dict[str, Any] = field(default_factory=dict)
    # how its state turns with the rotor (the whole-drive linearization); None: not declared
    coordinates: LoopCoordinates | None = None


D = TypeVar("D", bound=Drive, contravariant=True)


# capabilities of a family (design/capabilities.py), typed here beside their result type
@runtime_checkable
class Simulatable(Protocol[D]):
    """Simulates its drive in the time domain."""

    def simulation(self, drive: D, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        """The loop set-up of ``scenario`` on ``drive``."""
        ...


@runtime_checkable
class AnalysedLoop(Protocol[D]):
    """Analyses a loop of its own in the whole-drive linearization (design/drive_analysis.py) instead of
    its simulation's (an HF carrier or EMF harmonics leave the loop as run without a fixed point)."""

    def drive_loop(self, drive: D, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        """The loop the whole-drive analysis linearizes; ``meta['drive_note']`` says how it differs."""
        ...


LACKS.update({Simulatable: "has no time-domain simulation", AnalysedLoop: "has no drive loop"})


@dataclass(frozen=True)
class Traces:
    """Simulated signals at the sampling instants: ``t`` [s] and one array per recorded signal (SI)."""

    t: np.ndarray
    data: dict[str, np.ndarray]
    units: dict[str, str]
    docs: dict[str, str]
    meta: dict[str, Any]
    wall_time: float = 0.0  # [s] spent in the compiled loop (not written: it differs between runs)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def window(self, t0: float, t1: float = math.inf) -> np.ndarray:
        """Boolean mask of the samples with t0 <= t < t1."""
        return (self.t >= t0) & (self.t < t1)

    def nonfinite(self) -> tuple[str, float] | None:
        """(first signal, time [s]) where a recorded signal first stops being finite; None if all are."""
        first: tuple[str, float] | None = None
        for name, x in self.data.items():
            bad = ~np.isfinite(np.asarray(x, float))
            if bad.any():
                t = float(self.t[int(np.argmax(bad))])
                if first is None or t < first[1]:
                    first = (name, t)
        return first

    def problems(self) -> list[str]:
        """What makes the result not hold, one line each (empty: it holds)."""
        out = []
        bad = self.nonfinite()
        if bad is not None:
            out.append(
                f"the simulation diverged: {bad[0]} is not finite from t = {bad[1]:.4g} s on (the motor "
                "and controllers at T_s; check the drive's parameters, e.g. an inertia J too small)"
            )
        if bad is None and "valid" in self.data:
            rejected = int(np.sum(np.asarray(self["valid"]) < 0.5))
            if rejected:
                out.append(
                    f"the observer rejected {rejected} of {self.t.size} samples (output valid = 0: its next "
                    "state would have left its physical bounds or was not finite; it coasted meanwhile)"
                )
        if bad is None and "theta_err" in self.data:
            w_min = LOST_MIN_SPEED * self.meta.get("base_w", 0.0)
            moving = np.abs(self["w_m"]) >= w_min if "w_m" in self.data else None
            if "startup_mode" in self.data:  # the open-loop I-f start: theta_hat is not an estimate
                closed = np.asarray(self["startup_mode"]) < 0.5
                moving = closed if moving is None else moving & closed
            lost = position_lost(self.t, self["theta_err"], moving)
            if lost is not None:
                out.append(
                    f"the position estimate was lost: its error reached {np.degrees(LOST_ANGLE):.0f} deg at "
                    f"t = {lost:.4g} s (peak {np.degrees(np.max(np.abs(_wrap(self['theta_err'])))):.0f} deg)"
                )
        return out


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(angle, float)))


def position_lost(t: np.ndarray, theta_err: np.ndarray, moving: np.ndarray | None = None) -> float | None:
    """The time [s] at which the position estimate is lost: its error (wrapped to +-180 deg) reaches
    :data:`LOST_ANGLE` after having been below it (a run that starts with a large error and converges
    is not lost), at a sample where ``moving`` (default: every sample); None if it never is."""
    e = np.abs(_wrap(theta_err))
    below = np.flatnonzero(e < LOST_ANGLE)
    if below.size == 0:
        return None
    bad = e >= LOST_ANGLE
    if moving is not None:
        bad &= np.asarray(moving, bool)
    after = np.flatnonzero(bad[below[0] :])
    return None if after.size == 0 else float(t[below[0] + after[0]])


def samples(scenario: Scenario, T_s: float) -> int:
    """Number of samples of ``scenario`` at the sampling period ``T_s`` (both ends included)."""
    return round(scenario.duration / T_s) + 1


def check_length(scenario: Scenario, T_s: float, source: str = "") -> int:
    """The number of samples, or SimulationError naming ``source`` (default: the scenario file's key)
    if it is more than :data:`MAX_SAMPLES` or the duration is shorter than one sampling period."""
    n = scenario.duration / T_s + 1
    where = source or f"{scenario.file}: key 'scenario.duration'"
    if scenario.duration < T_s:
        raise SimulationError(
            f"{where}: {scenario.duration:g} s is shorter than one control period (T_s = {T_s * 1e6:g} us): "
            "nothing would be simulated"
        )
    if n > MAX_SAMPLES:
        raise SimulationError(
            f"{where}: {scenario.duration:g} s at T_s = {T_s * 1e6:g} us is {n:.3g} control periods, more "
            f"than the limit of {MAX_SAMPLES} ({MAX_SAMPLES * T_s:g} s; docs/simulation.md)"
        )
    return samples(scenario, T_s)


def provenance(drive: Drive, sc: Scenario) -> dict[str, str]:
    """What a run describes: the drive (and its TOML hash) and the scenario; shared by every kind."""
    return {
        "drive": drive.name,
        "drive_file": drive.file,
        "drive_sha256": drive.digest,
        "kind": drive.kind,
        "scenario": sc.name,
        "scenario_title": sc.title,
        "scenario_source": sc.source,
    }


def sample_times(scenario: Scenario, T_s: float) -> np.ndarray:
    """The sampling instants t_k = k T_s of ``scenario`` [s] (at most MAX_SAMPLES: check_length)."""
    return np.arange(check_length(scenario, T_s)) * T_s


def noise(scenario: Scenario, n: int) -> np.ndarray:
    """(2, n) current-measurement noise of ``scenario`` [A] (zeros without noise; seeded)."""
    if scenario.i_noise > 0:
        return scenario.i_noise * np.random.default_rng(scenario.seed).standard_normal((2, n))
    return np.zeros((2, n))


# --------------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------------
# not kept on disk (design/memo.py kept_function): the serialized map of CHUNK steps is 6-10 MB,
# slower to write and read back than to build (0.1 s against 0.07 s)
@functools.cache
def chunk_function(loop: ca.Function, n: int) -> ca.Function:
    """``n`` loop steps as one Function (z, V, q, p_obs, gain) -> (z after n steps, rec (n_rec, n))."""
    F = loop.mapaccum(n)
    args = [ca.MX.sym(loop.name_in(k), loop.sparsity_in(k)) for k in range(loop.n_in())]
    V = ca.MX.sym("V", loop.size1_in(1), n)
    zs, rec = F(args[0], V, *args[2:])  # constant inputs broadcast over the n steps
    return ca.Function(
        f"{loop.name()}_x{n}",
        [args[0], V, *args[2:]],
        [zs[:, n - 1], rec],
        ["z", "V", "q", "p_obs", "gain"],
        ["z_end", "rec"],
    )


@functools.cache
def _chunk_key(loop: ca.Function, n: int) -> bytes:
    """What :func:`chunk_function` builds from: the loop (its serialization), ``n`` and the toolbox's
    code (design/memo.py ``fingerprint``): the key of its compiled library's record (design/compiled.py
    ``index``)."""
    return hashlib.sha256(fingerprint() + pickle.dumps((loop, n), protocol=pickle.HIGHEST_PROTOCOL)).digest()


@functools.cache
def compiled_chunk(loop: ca.Function, n: int) -> ca.Function:
    """:func:`chunk_function`, compiled to native code (cached on disk); where an earlier process
    compiled the same chunk, its library is loaded without building the chunk again."""
    fn = indexed(_chunk_key(loop, n))
    if fn is None:
        fn = compiled(chunk_function(loop, n))
        index(_chunk_key(loop, n), chunk_function(loop, n))
    return fn


def run_loop(
    setup: LoopSetup,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = CHUNK,
    compile: bool = True,
) -> np.ndarray:
    """Run the loop over all input columns; returns rec as (n_rec, N). ``progress(done, total)``."""
    fn = compiled_chunk(setup.loop, chunk) if compile else chunk_function(setup.loop, chunk)
    return run_chunks(fn, setup.z0, [setup.q, setup.p_obs, setup.gain], setup.inputs, progress)


def run_chunks(
    fn: ca.Function,
    z0: np.ndarray,
    const: list,
    inputs: np.ndarray,
    progress: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """``fn`` (z, V, *const) -> (z_end, rec), a chunk of ``fn.size2_in(1)`` control periods, chained over
    every input column from ``z0``: rec as (n_rec, N). The last chunk is padded by holding its last
    inputs (the excess dropped). Between numpy arrays through CasADi's buffer interface (design/batch.py
    ``bound_call``: the same bits without converting each chunk's inputs and record through casadi.DM, a
    quarter of a simulation's CPU) where ``fn`` takes them so, else as a Function is called."""
    chunk, n_v, n = fn.size2_in(1), fn.size1_in(1), inputs.shape[1]
    out = np.empty((fn.size1_out(1), n))
    z = np.array(z0, float).reshape(-1)  # each chunk's start, the previous chunk's end copied in
    V = np.empty((chunk, n_v))  # column-major (n_v, chunk)
    bound = bound_call(fn, [z, V, *(np.array(c, float).reshape(-1) for c in const)])
    for k0 in range(0, n, chunk):
        k1 = min(k0 + chunk, n)
        if bound is None:
            Vk = inputs[:, k0:k1]
            if k1 - k0 < chunk:
                Vk = np.hstack([Vk, np.repeat(Vk[:, -1:], chunk - (k1 - k0), axis=1)])
            z_end, rec = fn(z, Vk, *const)
            out[:, k0:k1] = np.asarray(rec)[:, : k1 - k0]
            z = np.asarray(z_end).ravel()
        else:
            call, (z_end, rec) = bound
            V[: k1 - k0] = inputs[:, k0:k1].T
            V[k1 - k0 :] = inputs[:, k1 - 1]
            call()
            out[:, k0:k1] = rec[: k1 - k0].T
            z[:] = z_end.reshape(-1)
        if progress is not None:
            progress(k1, n)
    return out


def simulate(
    drive: Drive,
    scenario: Scenario,
    gains: GainSet | None = None,
    progress: Callable[[int, int], None] | None = None,
    compile: bool = True,
) -> Traces:
    """Simulate ``scenario`` on ``drive`` (``gains``: e.g. of a tuned table; None: the scenario's or
    the drive file's); returns the traces (see :meth:`Traces.problems`). SimulationError if the
    scenario is longer than MAX_SAMPLES control periods. ``compile``: the loop compiled where that pays
    (:data:`JIT_MIN_STEPS`); False: on CasADi's virtual machine."""
    check_length(scenario, drive.T_s)
    setup = require(family_of(drive), Simulatable).simulation(drive, scenario, gains)
    if compile:
        _STEPS[setup.loop] = _STEPS.get(setup.loop, 0) + setup.inputs.shape[1]
        compile = _STEPS[setup.loop] >= JIT_MIN_STEPS or indexed(_chunk_key(setup.loop, CHUNK)) is not None
        if not compile:  # (a chunk an earlier process compiled: recorded, its library is in the cache)
            chunk = chunk_function(setup.loop, CHUNK)
            compile = is_cached(chunk) or wanted_elsewhere(chunk)
    if compile:
        compiled_chunk(setup.loop, CHUNK)  # build and compile (or load from the cache) outside the timing
    t0 = time.perf_counter()
    rec = run_loop(setup, progress, compile=compile)
    wall = time.perf_counter() - t0
    t = np.arange(rec.shape[1]) * setup.T_s
    data = {s.name: rec[k] for k, s in enumerate(setup.record)}
    return Traces(
        t=t,
        data=data,
        units={s.name: s.unit for s in setup.record},
        docs={s.name: s.doc for s in setup.record},
        meta={**setup.meta, "samples": rec.shape[1]},
        wall_time=wall,
    )


def simulated(drive: Drive, scenario: Scenario, gains: GainSet | None = None) -> Traces:
    """:func:`simulate`, the traces kept for a later process (design/memo.py, on disk): the checks
    ``sensorless tune`` proves its gains with are the report's (reports/tune_proof.py,
    reports/time_domain.py), so the README flow's ``report`` reads the runs its ``tune`` made instead of
    simulating them again (the same drive, scenario and gains: the same bytes). The traces are shared
    between callers: read them, never change them. ``wall_time`` is 0 (it differs between runs)."""
    tr, label = _kept(drive, scenario, gains)
    if gains is None or label == gains.source:
        return tr
    # the gains' source is a label (left out of the memo's key): the caller's own, not the first caller's
    meta = {
        k: v.replace(label, gains.source) if label and isinstance(v, str) and label in v else v
        for k, v in tr.meta.items()
    }
    return dataclasses.replace(tr, meta=meta)


@by_content(maxsize=16, when=double_step_active, disk=True)
def _kept(drive: Drive, scenario: Scenario, gains: GainSet | None) -> tuple[Traces, str]:
    """(the traces, the label of ``gains`` they quote) of :func:`simulated`."""
    tr = dataclasses.replace(simulate(drive, scenario, gains), wall_time=0.0)
    return tr, gains.source if gains is not None else ""
