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

# named by what the gain does over the operating range: ``constant`` (one gamma lambda^2, the PLL by its
# bandwidth: ODrive's terms), ``voltage-scaled`` (gamma lambda^2 times a factor growing with
# the applied voltage, the PLL by k_p and k_i: VESC's terms), ``schedule`` (gamma lambda^2 a table over speed)
LAW_KEYS: dict[str, dict[str, str]] = {
    "constant": {"observer_gain": "rate", "pll_bandwidth": "angular"},
    "voltage-scaled": {
        "foc_observer_gain": "dimensionless",
        "foc_observer_gain_slow": "dimensionless",
        "foc_pll_kp": "rate",
        "foc_pll_ki": "rate_squared",
    },
    "schedule": {"pll_bandwidth": "angular"},  # plus the lists speeds [rad/s], observer_gain [1/s]
}
# former name -> name now (read for one release, with a note): odrive and vesc are firmware names (export
# targets, [observer] firmware), not what the law does
LAW_ALIASES = {"flux_schedule": "schedule", "odrive": "constant", "vesc": "voltage-scaled"}
TABLE_LAWS: dict[str, tuple[str, ...]] = {
    "constant": ("observer_gain", "pll_bandwidth"),
    "voltage-scaled": ("foc_observer_gain", "foc_observer_gain_slow", "foc_pll_kp", "foc_pll_ki"),
    "schedule": ("speeds", "observer_gain", "pll_bandwidth"),
}


# k T_obs below this (k = gamma lambda^2 [1/s], T_obs the observer period): linearized, the flux
# estimate's amplitude error decays at the rate k (d|eta|/dt = -k (|eta| - lambda)), and the firmwares'
# forward-Euler step multiplies it by 1 - k T_obs per period, which leaves the unit circle at k T_obs = 2
EULER_LIMIT = 2.0


@functools.cache
def _renamed(file: str, key: str, law: str) -> None:
    print(f"{file}: note: key '{key}': law {law!r} is now called {LAW_ALIASES[law]!r}", file=sys.stderr)


def law_now(law: Any, file: str, key: str = "gains.law") -> Any:
    """``law`` by its name now: a former name (:data:`LAW_ALIASES`) said once per file on stderr and
    replaced; any other value as it is (the reader judges it)."""
    if isinstance(law, str) and law in LAW_ALIASES:
        _renamed(file, key, law)
        return LAW_ALIASES[law]
    return law


def _number(
    t: Mapping[str, Any], k: str, dim: str, file: str, section: str, allow_zero: bool = False
) -> float:
    if k not in t:
        raise DriveFileError(file, f"{section}.{k}", "missing key")
    x, rel = parse_quantity(t[k], dim, file=file, key=f"{section}.{k}")
    if rel is not None or not math.isfinite(x) or not (x > 0 or (allow_zero and x == 0)):
        raise DriveFileError(file, f"{section}.{k}", f"non-physical value {t[k]!r}: must be > 0")
    return x


def parse_law(
    law: str,
    t: Mapping[str, Any],
    file: str,
    section: str,
    T_obs: float | None = None,
    period: str = "observer.T_obs",
) -> dict[str, Any]:
    """The SI gains of ``law`` from a table of quantities; DriveFileError naming the key. Given the
    observer period ``T_obs`` [s] (named ``period`` in messages), each observer gain within the Euler
    limit too (:func:`check_euler`)."""
    law = law_now(law, file, f"{section}.law")  # a former name: read, and said once per file
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
    if T_obs is not None:
        check_euler(out, T_obs, file, section, period)
    return out


def check_euler(values: Mapping[str, Any], T_obs: float, file: str, section: str, period: str) -> None:
    """DriveFileError naming ``section``.observer_gain where a gain k [1/s] of the laws that give it
    (constant; each of a schedule's) has k T_obs at or above :data:`EULER_LIMIT`: the observer diverges
    at every speed, whatever the rest of the drive."""
    ks = values.get("observer_gain")
    if ks is None:  # voltage-scaled: its run-time gain follows the voltage
        return
    for i, k in enumerate(ks if isinstance(ks, list) else [ks]):
        if k * T_obs >= EULER_LIMIT:
            at = f" (its value at {values['speeds'][i]:.4g} rad/s)" if isinstance(ks, list) else ""
            raise DriveFileError(
                file,
                f"{section}.observer_gain",
                f"{k:.6g} 1/s{at} with the observer period {T_obs:.4g} s ({period}) gives k T_obs = "
                f"{k * T_obs:.3g}, at or above {EULER_LIMIT:g}, where the observer's forward-Euler step "
                f"diverges: give at most {0.95 * EULER_LIMIT / T_obs:.4g} 1/s (k T_obs = "
                f"{0.95 * EULER_LIMIT:g}, as the tuner does), or run `sensorless tune`",
            )


def section_gains(
    t: Mapping[str, Any], file: str, T_obs: float | None = None, period: str = "observer.T_obs"
) -> GainSet:
    """The gains of a drive file's [gains] section ``t`` (``T_obs``, ``period``: :func:`parse_law`)."""
    law = t.get("law")
    if not isinstance(law, str):
        raise DriveFileError(file, "gains.law", f"missing key or not a string ({' | '.join(LAW_KEYS)})")
    values = parse_law(law, t, file, "gains", T_obs, period)
    return GainSet(LAW_ALIASES.get(law, law), values, f"{file} [gains]")
