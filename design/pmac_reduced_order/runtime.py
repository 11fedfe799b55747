"""The reduced-order observer's gains and runtime set-up from a drive file or a tuned gain table.

Gains g (9) and Gamma (10) come from the drive's ``[observer]`` or a gain table of law ``constant``
(docs/gain_tables.md). Every parameter of the runtime step (symbolic/pmac_reduced_order/step.py), the
gains and the EMF series of the observer's model included, is a runtime parameter; nothing is
scheduled outside the step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTableError
from sensorless.design.runtime import RuntimeSetup
from sensorless.symbolic.pmac_reduced_order.step import runtime_observer

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

# gain-table law -> keys of its "gains": the constant gains g, Gamma of De Angelo et al. (2006)
TABLE_LAWS: dict[str, tuple[str, ...]] = {
    "constant": ("g", "Gamma"),  # observer gains [1/s], [A^2 s^2], eqs. (9)-(10)
}
# former law names, still read (gain tables, `sensorless tune --law`) for one release
LAW_ALIASES = {"deangelo": "constant"}


def drive_gains(drive: PmacDrive) -> GainSet:
    """The drive file's ``[observer]`` g and Gamma."""
    o = drive.observer
    return GainSet("constant", {"g": float(o.g), "Gamma": float(o.Gamma)}, f"{drive.file} [observer]")


def table_values(law: str, gains: Mapping[str, Any], where: str) -> dict[str, float]:
    """The SI gains of a ``constant`` table (design/law_gains.py ``table_gains`` checks kind and law);
    ``where`` names the table in errors."""
    values = {}
    for k, need in (("g", "a finite number > 0"), ("Gamma", "a finite number >= 0")):
        v = gains[k]
        x = float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan
        if not (math.isfinite(x) and (x > 0 if k == "g" else x >= 0)):
            raise GainTableError(f"{where}: key 'gains.{k}': expected {need}, got {v!r}")
        values[k] = x
    return values


def runtime_params(drive: PmacDrive, gains: GainSet) -> dict[str, float]:
    """Parameters of the runtime step from the drive's estimates, sampling period and ``gains``."""
    obs = runtime_observer(tuple(drive.estimate.harmonics))
    vals = drive.observer_params(g=gains.values["g"], Gamma=gains.values["Gamma"])
    return {f.name: float(v) for f, v in zip(obs.params, vals, strict=True)}


def runtime_setup(drive: PmacDrive, gains: GainSet, discretization: str | None = None) -> RuntimeSetup:
    """The runtime observer of ``drive`` with ``gains`` (discretization: the drive's ``[control]``)."""
    obs = runtime_observer(tuple(drive.estimate.harmonics))
    disc = discretization or drive.control.discretization
    if disc not in obs.discretizations:
        raise ValueError(f"unknown discretization {disc!r} (known: {', '.join(obs.discretizations)})")
    params = runtime_params(drive, gains)
    obs.check_params(params)
    return RuntimeSetup(obs, disc, params, gains)
