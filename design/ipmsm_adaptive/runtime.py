"""The adaptive observer's gains and runtime set-up from a drive file or a tuned gain table.

Gains (:class:`~sensorless.design.family.GainSet`) come from the drive's ``[observer.gains.*]`` (gain
laws ``zero``, ``constant``, ``speed-dependent`` = the ``speed`` table, eq. (16)) or from a gain table
of law ``speed-dependent`` or ``schedule`` (docs/gain_tables.md); either way with the adaptation bandwidth
alpha_fo (10). The runtime parameters (estimates, sampling period, injection and filter settings)
come from the drive file; the gain law (7)/(16) is scheduled at the stored speed estimate.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTableError
from sensorless.design.runtime import GainSchedule, RuntimeSetup
from sensorless.design.units import DriveFileError
from sensorless.symbolic.ipmsm_adaptive.gains import LAWS, GainLaw, schedule_law
from sensorless.symbolic.ipmsm_adaptive.step import OBSERVER
from sensorless.symbolic.runtime import Field

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

# gain-table law -> keys of its "gains" (all SI)
TABLE_LAWS: dict[str, tuple[str, ...]] = {
    # the speed-dependent gain, eq. (16) of Piippo, Hinkkanen, Luomi (2008) [ohm, rad/s], eq. (10) [rad/s]
    "speed-dependent": ("lambda_p", "w_lambda", "alpha_fo"),
    "schedule": ("w_hat", "lambda1", "lambda2", "alpha_fo"),  # breakpoints [rad/s], gains [ohm]
}
# former law names, still read (gain tables, `sensorless tune --law`) for one release
LAW_ALIASES = {"law16": "speed-dependent"}
# the drive file's [observer.gains.<name>] -> gain law
DRIVE_GAINS = {"zero": "zero", "constant": "constant", "speed": "speed-dependent"}
LAW_OF = {"zero": "zero", "constant": "constant", "speed-dependent": "speed"}

_DOCS = {
    "lambda_p": "lambda' of the speed-dependent gain, eq. (16)",
    "w_lambda": "omega_lambda of the speed-dependent gain, eq. (16)",
    "lambda1": "constant gain lambda1, eq. (7)",
    "lambda2": "constant gain lambda2, eq. (7)",
}
_TEXT = {
    "speed-dependent": "speed-dependent gain, eq. (16), closed form",
    "schedule": "tuned gain schedule, const table with linear interpolation",
    "constant": "constant gain, eq. (7)",
    "zero": "zero gain",
}


def drive_gains(drive: IpmsmDrive, name: str | None = None) -> GainSet:
    """The drive file's ``[observer.gains.<name>]`` (default: ``[observer] gain``) with its alpha_fo."""
    name = name or drive.observer.gain
    g = drive.gain(name)  # KeyError naming the file if absent
    law = DRIVE_GAINS[name]
    values: dict[str, Any] = {n: float(getattr(g, n)) for n in LAWS[LAW_OF[law]].param_names}
    values["alpha_fo"] = float(drive.observer.alpha_fo)
    return GainSet(law, values, f"{drive.file} [observer.gains.{name}]")


def table_values(law: str, g: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The SI gains of a ``speed-dependent`` or ``schedule`` table's ``gains`` (design/law_gains.py
    ``table_gains`` checks the table's kind and law first); ``where`` names the table in errors."""
    scalars = TABLE_LAWS["speed-dependent"] if law == "speed-dependent" else ("alpha_fo",)
    for k in TABLE_LAWS[law]:
        if isinstance(g[k], list) == (k in scalars):
            what = "a number" if k in scalars else "a list of numbers, one per breakpoint"
            raise GainTableError(f"{where}: key 'gains.{k}': expected {what}, got {g[k]!r}")
    try:
        if law == "speed-dependent":
            values: dict[str, Any] = {k: float(g[k]) for k in TABLE_LAWS["speed-dependent"]}
        else:
            n = len(g["w_hat"])
            for k in ("lambda1", "lambda2"):
                if len(g[k]) != n:
                    raise GainTableError(f"{where}: key 'gains.{k}': length {len(g[k])} != len(w_hat) {n}")
            values = {
                "w_hat": [float(w) for w in g["w_hat"]],
                "lambda1": [float(v) for v in g["lambda1"]],
                "lambda2": [float(v) for v in g["lambda2"]],
                "alpha_fo": float(g["alpha_fo"]),
            }
            try:
                schedule_law(tuple(values["w_hat"]))  # validates the breakpoints
            except ValueError as e:
                raise GainTableError(f"{where}: key 'gains.w_hat': {e}") from None
    except GainTableError:
        raise
    except (TypeError, ValueError) as e:
        raise GainTableError(f"{where}: key 'gains': {e}") from None
    flat = [v for x in values.values() for v in (x if isinstance(x, list) else [x])]
    if not np.all(np.isfinite(flat)):
        raise GainTableError(f"{where}: key 'gains': non-finite gain values")
    for k in ("lambda_p", "w_lambda", "alpha_fo"):  # as in the drive file: eq. (16) and (10) need them > 0
        if k in values and not values[k] > 0:
            raise GainTableError(f"{where}: key 'gains.{k}': non-physical value {values[k]!r}: must be > 0")
    return values


def law_of(gains: GainSet) -> tuple[GainLaw, tuple[float, ...]]:
    """(gain law of symbolic/ipmsm_adaptive/gains.py, its parameter vector) of a gain set."""
    v = gains.values
    if gains.law == "schedule":
        law = schedule_law(tuple(float(w) for w in v["w_hat"]))
        return law, tuple(float(x) for x in [*v["lambda1"], *v["lambda2"]])
    law = LAWS[LAW_OF[gains.law]]
    return law, tuple(float(v[n]) for n in law.param_names)


@functools.cache
def law_function(law: GainLaw) -> ca.Function:
    """(w_hat, gain) -> [lambda1, lambda2]: the law's own SX expression, eqs. (7), (16)."""
    w = ca.SX.sym("w_hat")
    g = ca.SX.sym("gain", law.n_params)
    return ca.Function(f"gains_{law.name}", [w, g], [ca.vertcat(*law.expr(w, g))], ["w_hat", "gain"], ["lam"])


def schedule_of(gains: GainSet) -> GainSchedule:
    """The runtime schedule of a gain set: law (7)/(16) or a table, evaluated at the stored w_hat."""
    law, values = law_of(gains)
    fields = tuple(
        Field(n, u, _DOCS.get(n, "gain law parameter"))
        for n, u in zip(law.param_names, law.param_units, strict=True)
    )
    return GainSchedule(gains.law, law_function(law), values, fields, law.grid, _TEXT[gains.law])


def runtime_params(drive: IpmsmDrive, alpha_fo: float | None = None) -> dict[str, float]:
    """Parameters of the runtime step (step.PARAMS) from a drive of this family."""
    e, inj, rt = drive.estimate, drive.injection, drive.run
    return {
        "R_s": e.R_s,
        "L_d": e.L_d,
        "L_q": e.L_q,
        "psi_pm": e.psi_pm,
        "alpha_fo": drive.observer.alpha_fo if alpha_fo is None else float(alpha_fo),
        "T_s": drive.control.T_s,
        "injection": 1.0 if inj.enabled else 0.0,
        "w_c": inj.w_c,
        "u_c": inj.u_c,
        "alpha_i": inj.alpha_i,
        "w_Delta": inj.w_Delta,
        "x_eps_max": rt.x_eps_max,
        "w_bp": rt.w_bp,
        "w_lp": rt.w_lp,
        "carrier_delay": rt.carrier_delay,
        "w_max": rt.w_max,
    }


def _check_sampling(drive: IpmsmDrive, params: dict[str, float]) -> None:
    """Frequencies the sampled chain must resolve lie below the Nyquist frequency pi / T_s."""
    nyquist = math.pi / params["T_s"]
    for key, name in (("injection.w_c", "w_c"), ("runtime.w_lp", "w_lp")):
        if params[name] >= nyquist:
            raise DriveFileError(
                drive.file,
                key,
                f"{params[name]:.6g} rad/s is not below the Nyquist frequency pi/T_s = {nyquist:.6g} rad/s",
            )


def runtime_setup(drive: IpmsmDrive, gains: GainSet, discretization: str | None = None) -> RuntimeSetup:
    """The runtime observer of ``drive`` with ``gains`` (discretization: the drive's ``[runtime]``)."""
    disc = discretization or drive.run.discretization
    if disc not in OBSERVER.discretizations:
        raise ValueError(f"unknown discretization {disc!r} (known: {', '.join(OBSERVER.discretizations)})")
    params = runtime_params(drive, gains.values.get("alpha_fo"))
    _check_sampling(drive, params)
    OBSERVER.check_params(params)
    return RuntimeSetup(OBSERVER, disc, params, gains, schedule_of(gains))


def with_alpha_fo(drive: IpmsmDrive, gains: GainSet) -> IpmsmDrive:
    """The drive with the adaptation bandwidth (10) of ``gains`` (a tuned table may carry its own)."""
    a = gains.values.get("alpha_fo", drive.observer.alpha_fo)
    if a == drive.observer.alpha_fo:
        return drive
    return dataclasses.replace(drive, observer=dataclasses.replace(drive.observer, alpha_fo=float(a)))
