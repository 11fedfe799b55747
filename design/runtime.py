"""Runtime observer set-up from a drive description (+ optional tuned gain table): parameters and gains.

What the discrete-time step of a runtime observer (symbolic/runtime.py) needs besides its equations:
the parameter vector (estimates, sampling period, injection and filter settings from the drive TOML)
and the gain law with its parameters, taken from the drive's ``[observer.gains.*]`` or from a tuned
gain table (docs/gain_tables.md). Simulation and C generation both start here.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.units import DriveFileError
from sensorless.symbolic.gains import LAWS, GainLaw, schedule_law
from sensorless.symbolic.runtime import RuntimeObserver
from sensorless.symbolic.runtime_000 import OBSERVER as ADAPTIVE000
from sensorless.symbolic.runtime_000 import observer_step_function
from sensorless.tuning.gain_table import GainTable, GainTableError


@dataclass(frozen=True)
class RuntimeSetup:
    """Everything a runtime step needs: observer, discretization, parameters, gain law and gains."""

    observer: RuntimeObserver
    discretization: str
    params: dict[str, float]  # by observer.params field name, SI
    law: GainLaw
    gain: tuple[float, ...]  # law parameters (law.param_names), SI
    gain_source: str  # where the gains come from, for headers and messages
    family: str  # "law16", "schedule", "constant", "zero"

    @property
    def p(self) -> np.ndarray:
        """Parameter vector in the observer's field order."""
        return self.observer.pack_params(self.params)

    def step_function(self) -> ca.Function:
        """The step (x, meas, p, gain) -> (x_next, y) with this set-up's law."""
        return observer_step_function(self.discretization, self.law)

    def initial_state(self) -> np.ndarray:
        """x0 for these parameters."""
        return np.asarray(self.observer.initial_state()(self.p)).ravel()


def ipmsm_params(drive: Any, alpha_fo: float | None = None) -> dict[str, float]:
    """Parameters of the paper-000 runtime step from an ``ipmsm-adaptive`` drive."""
    e, inj, rt = drive.estimate, drive.injection, drive.runtime
    return {
        "R_s": e.R_s,
        "L_d": e.L_d,
        "L_q": e.L_q,
        "psi_pm": e.psi_pm,
        "alpha_fo": drive.observer.alpha_fo if alpha_fo is None else float(alpha_fo),
        "T_s": drive.control.T_s,
        "injection": 1.0,
        "w_c": inj.w_c,
        "u_c": inj.u_c,
        "alpha_i": inj.alpha_i,
        "w_Delta": inj.w_Delta,
        "x_eps_max": rt.x_eps_max,
        "w_bp": rt.w_bp,
        "w_lp": rt.w_lp,
        "carrier_delay": rt.carrier_delay,
    }


def _check_sampling(drive: Any, params: dict[str, float]) -> None:
    """Frequencies the sampled chain must resolve lie below the Nyquist frequency pi / T_s."""
    nyquist = math.pi / params["T_s"]
    for key, name in (("injection.w_c", "w_c"), ("runtime.w_lp", "w_lp")):
        if params[name] >= nyquist:
            raise DriveFileError(
                drive.file,
                key,
                f"{params[name]:.6g} rad/s is not below the Nyquist frequency pi/T_s = {nyquist:.6g} rad/s",
            )


def _drive_gain(drive: Any, name: str) -> tuple[GainLaw, tuple[float, ...], str]:
    g = drive.gain(name)  # KeyError naming the file if absent
    law = LAWS[name]
    values = tuple(float(getattr(g, n)) for n in law.param_names)
    family = "law16" if name == "speed" else name
    return law, values, family


def table_gain(table: GainTable, where: str) -> tuple[GainLaw, tuple[float, ...], float, str]:
    """(law, params, alpha_fo [rad/s], family) of a paper-000 gain table; ``where`` names it in errors."""
    g = table.gains
    try:
        if table.family == "law16":
            return LAWS["speed"], (float(g["lambda_p"]), float(g["w_lambda"])), float(g["alpha_fo"]), "law16"
        if table.family == "schedule":
            law = schedule_law(tuple(float(w) for w in g["w_hat"]))
            values = tuple(float(v) for v in [*g["lambda1"], *g["lambda2"]])
            return law, values, float(g["alpha_fo"]), "schedule"
    except (TypeError, ValueError) as e:
        raise GainTableError(f"{where}: key 'gains': {e}") from None
    raise GainTableError(
        f"{where}: key 'family': {table.family!r} gains are not for the paper-000 observer "
        "(use a law16 or schedule table)"
    )


def runtime_setup(
    drive: Any,
    *,
    gain: str | None = None,
    table: GainTable | None = None,
    table_file: str = "gain table",
    discretization: str | None = None,
) -> RuntimeSetup:
    """Runtime set-up of ``drive``; gains from ``table`` if given, else from ``[observer.gains.<gain>]``."""
    if drive.kind != "ipmsm-adaptive":
        raise ValueError(f"{drive.file}: no runtime observer for drive kind {drive.kind!r}")
    disc = discretization or drive.runtime.discretization
    if table is not None:
        kind = table.drive.get("kind")
        if kind is not None and kind != drive.kind:
            raise GainTableError(
                f"{table_file}: key 'drive.kind': {kind!r} does not match the drive ({drive.kind})"
            )
        law, values, alpha_fo, family = table_gain(table, table_file)
        params = ipmsm_params(drive, alpha_fo)
        source = f"{family} table {table_file} (tuned for {table.drive.get('name')})"
    else:
        name = gain or drive.observer.gain
        law, values, family = _drive_gain(drive, name)
        params = ipmsm_params(drive)
        source = f"{drive.file} [observer.gains.{name}]"
    _check_sampling(drive, params)
    ADAPTIVE000.check_params(params)
    if not np.all(np.isfinite(values)):
        raise GainTableError(f"{table_file if table else drive.file}: non-finite gain values")
    return RuntimeSetup(ADAPTIVE000, disc, params, law, values, source, family)


@functools.cache
def _mapaccum(fn: ca.Function, n: int) -> ca.Function:
    return fn.mapaccum(n)


def run_trajectory(setup: RuntimeSetup, meas: np.ndarray, x0: np.ndarray | None = None) -> tuple[Any, Any]:
    """Run the step over ``meas`` (N x n_meas, one row per sample): (states N x n_x, outputs N x n_y).

    ``states[k]`` is the state *after* step k. One ``mapaccum`` call, no Python loop.
    """
    meas = np.atleast_2d(np.asarray(meas, dtype=float))
    n = meas.shape[0]
    x0 = setup.initial_state() if x0 is None else np.asarray(x0, dtype=float)
    xs, ys = _mapaccum(setup.step_function(), n)(x0, meas.T, setup.p, np.asarray(setup.gain))
    return np.asarray(xs).T, np.asarray(ys).T
