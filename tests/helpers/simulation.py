"""Test helpers for the simulation tests: cached runs and a model-free pole estimator."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.scenario import drive_units, load_scenario, load_scenario_text
from sensorless.design.simulate import simulate


@functools.cache
def piippo2008():
    return load_drive("piippo2008")


def changed(sc, **changes):
    """The scenario with field overrides; keys of its family's options (gain, injection, ...) too."""
    opts = {k: v for k, v in changes.items() if k in sc.options}
    fields = {k: v for k, v in changes.items() if k not in opts}
    return dataclasses.replace(sc, options={**sc.options, **opts}, **fields)


@functools.cache
def run(name: str, **changes):
    """Simulate the built-in scenario ``name`` with overrides (cached per process)."""
    d = piippo2008()
    return simulate(d, changed(load_scenario(name, d), **changes))


@functools.cache
def run_text(text: str, **changes):
    """Simulate a scenario given as TOML text."""
    d = piippo2008()
    return simulate(d, changed(load_scenario_text(text, "test-scenario", drive_units(d)), **changes))


def matrix_pencil(y: np.ndarray, dt: float, order: int = 2) -> np.ndarray:
    """Continuous-time poles [1/s] of the ``order`` dominant modes of the sampled signal y (Hua-Sarkar).

    Model-free: a Hankel matrix of the data, its rank-``order`` right singular subspace, and the
    eigenvalues of the shift between its rows; no initial guess and nothing taken from the analysis.
    """
    n = len(y)
    L = n // 2
    Y = np.array([y[i : i + L + 1] for i in range(n - L)])
    _, _, Vh = np.linalg.svd(Y, full_matrices=False)
    V = Vh[:order].conj().T
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    return np.log(z.astype(complex)) / dt
