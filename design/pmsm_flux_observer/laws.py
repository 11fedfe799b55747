"""The gain laws of the flux-observer family and their reader (docs/families/pmsm_flux_observer.md
"Gains"): each law's keys with their dimensions, the former law names still read, and the SI values of
a [gains] section or a gain table's gains (``parse_law``). No drive here: the drive file's schema reads
its [gains] through this module, and gains.py (the runtime set-up of a drive) builds on it.
"""

from __future__ import annotations

import functools
import itertools
import math
import sys
from collections.abc import Mapping
from typing import Any

from sensorless.design.family import GainSet
from sensorless.design.units import DriveFileError, parse_quantity

LAW_KEYS: dict[str, dict[str, str]] = {
    "odrive": {"observer_gain": "rate", "pll_bandwidth": "angular"},
    "vesc": {
        "foc_observer_gain": "dimensionless",
        "foc_observer_gain_slow": "dimensionless",
        "foc_pll_kp": "rate",
        "foc_pll_ki": "rate_squared",
    },
    "schedule": {"pll_bandwidth": "angular"},  # plus the lists speeds [rad/s], observer_gain [1/s]
}
LAW_ALIASES = {"flux_schedule": "schedule"}  # former name -> name now (read for one release)
TABLE_LAWS: dict[str, tuple[str, ...]] = {
    "odrive": ("observer_gain", "pll_bandwidth"),
    "vesc": ("foc_observer_gain", "foc_observer_gain_slow", "foc_pll_kp", "foc_pll_ki"),
    "schedule": ("speeds", "observer_gain", "pll_bandwidth"),
}


@functools.cache
def _renamed(file: str, key: str, law: str) -> None:
    print(f"{file}: note: key '{key}': law {law!r} is now called {LAW_ALIASES[law]!r}", file=sys.stderr)


def _number(
    t: Mapping[str, Any], k: str, dim: str, file: str, section: str, allow_zero: bool = False
) -> float:
    if k not in t:
        raise DriveFileError(file, f"{section}.{k}", "missing key")
    x, rel = parse_quantity(t[k], dim, file=file, key=f"{section}.{k}")
    if rel is not None or not math.isfinite(x) or not (x > 0 or (allow_zero and x == 0)):
        raise DriveFileError(file, f"{section}.{k}", f"non-physical value {t[k]!r}: must be > 0")
    return x


def parse_law(law: str, t: Mapping[str, Any], file: str, section: str) -> dict[str, Any]:
    """The SI gains of ``law`` from a table of quantities; DriveFileError naming the key."""
    if law in LAW_ALIASES:  # its former name: read, and said once per file
        _renamed(file, f"{section}.law", law)
        law = LAW_ALIASES[law]
    if law not in LAW_KEYS:
        raise DriveFileError(file, f"{section}.law", f"{law!r} is not one of: {', '.join(LAW_KEYS)}")
    for k in t:
        if k != "law" and k not in TABLE_LAWS[law]:
            raise DriveFileError(
                file, f"{section}.{k}", f"unknown key (law {law}: {', '.join(TABLE_LAWS[law])})"
            )
    out: dict[str, Any] = {
        k: _number(t, k, dim, file, section, k == "foc_observer_gain_slow")
        for k, dim in LAW_KEYS[law].items()
    }
    if law == "schedule":
        for k, dim in (("speeds", "angular"), ("observer_gain", "rate")):
            v = t.get(k)
            if not isinstance(v, list) or len(v) < 2:
                raise DriveFileError(file, f"{section}.{k}", "expected a list of at least two values")
            out[k] = [_number({k: x}, k, dim, file, section) for x in v]
        if len(out["speeds"]) != len(out["observer_gain"]):
            raise DriveFileError(file, f"{section}.observer_gain", "one value per speed")
        if any(b <= a for a, b in itertools.pairwise(out["speeds"])):
            raise DriveFileError(file, f"{section}.speeds", "must increase strictly")
    return out


def section_gains(t: Mapping[str, Any], file: str) -> GainSet:
    """The gains of a drive file's [gains] section ``t``."""
    law = t.get("law")
    if not isinstance(law, str):
        raise DriveFileError(file, "gains.law", "missing key or not a string (odrive | vesc | schedule)")
    return GainSet(LAW_ALIASES.get(law, law), parse_law(law, t, file, "gains"), f"{file} [gains]")
