"""Time-domain simulation of a whole sensorless drive: a compiled ``mapaccum`` over the loop step.

``simulate(drive, scenario)`` asks the drive's family for its loop set-up (ObserverFamily.simulation:
the loop step around the runtime observer step that is also generated to C, the parameter vectors,
the initial state and the per-sample inputs) and runs the loop as ``Function.mapaccum`` over chunks of
samples, compiled to native code (design/compiled.py). No Python code runs per sample; Python only
moves from one chunk to the next, which is where progress is reported.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.compiled import compiled
from sensorless.design.family import GainSet
from sensorless.design.registry import family_of
from sensorless.design.scenario import Scenario
from sensorless.symbolic.runtime import Field

CHUNK = 2048  # samples per compiled call: progress granularity; the per-call cost is negligible


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


def provenance(drive: Any, sc: Scenario) -> dict[str, Any]:
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
    """The sampling instants t_k = k T_s of ``scenario`` [s]."""
    return np.arange(round(scenario.duration / T_s) + 1) * T_s


def noise(scenario: Scenario, n: int) -> np.ndarray:
    """(2, n) current-measurement noise of ``scenario`` [A] (zeros without noise; seeded)."""
    if scenario.i_noise > 0:
        return scenario.i_noise * np.random.default_rng(scenario.seed).standard_normal((2, n))
    return np.zeros((2, n))


# --------------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------------
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
def compiled_chunk(loop: ca.Function, n: int) -> ca.Function:
    """:func:`chunk_function`, compiled to native code (cached on disk)."""
    return compiled(chunk_function(loop, n))


def run_loop(
    setup: LoopSetup,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = CHUNK,
    compile: bool = True,
) -> np.ndarray:
    """Run the loop over all input columns; returns rec as (n_rec, N). ``progress(done, total)``."""
    n = setup.inputs.shape[1]
    fn = compiled_chunk(setup.loop, chunk) if compile else chunk_function(setup.loop, chunk)
    n_rec = setup.loop.size1_out(1)
    out = np.empty((n_rec, n))
    z = np.asarray(setup.z0, float)
    const = [setup.q, setup.p_obs, setup.gain]
    for k0 in range(0, n, chunk):
        k1 = min(k0 + chunk, n)
        V = setup.inputs[:, k0:k1]
        if k1 - k0 < chunk:  # pad the last chunk by holding its last inputs; the excess is dropped
            V = np.hstack([V, np.repeat(V[:, -1:], chunk - (k1 - k0), axis=1)])
        z_end, rec = fn(z, V, *const)
        out[:, k0:k1] = np.asarray(rec)[:, : k1 - k0]
        z = np.asarray(z_end).ravel()
        if progress is not None:
            progress(k1, n)
    return out


def simulate(
    drive: Any,
    scenario: Scenario,
    gains: GainSet | None = None,
    progress: Callable[[int, int], None] | None = None,
    compile: bool = True,
) -> Traces:
    """Simulate ``scenario`` on ``drive`` (``gains``: e.g. of a tuned table; None: the scenario's or
    the drive file's); returns the traces."""
    setup = family_of(drive).simulation(drive, scenario, gains)
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
