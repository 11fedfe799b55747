"""Tuning of the flux observer + PLL in each firmware's terms: the laws constant (ODrive's terms),
voltage-scaled (VESC's) and schedule.

Each law is tuned by a search of its own (tuning/family.py ``tuner``): its gains have one or two free
numbers, so every candidate of a grid is judged on the whole envelope at once (one batched evaluation
of the sampled observer's linearization, design/pmsm_flux_observer/linearize.py) under the estimate
errors a user states (default R_s +-30 %, psi_pm +-10 %, L +-20 %: every corner and the nominal).

Criterion: the family's own, criterion.py (docs/families/pmsm_flux_observer.md "Tuning"): a speed
holds where the sampled observer is stable with its angle bias and noise within limits at every error
corner; the candidates that decay fast enough (the speed loop, the full acceleration) with a PLL fast
enough rank first, then the lower low-speed limit, then the faster decay. The firmware defaults of the
law and the drive file's gains are candidates, so the tuned gains rank no worse than either.
Limits: T gamma lambda^2 < 2 is in the poles (the Euler bound), T k_p <= KP_T (ODrive refuses T k_p >=
1). The PLL: k_p = 2 bw, k_i = bw^2 with bw = min(max(k, PLL_SPEED_LOOP alpha_s), KP_T / (2 T)) (the
drive's speed loop closes on the PLL's speed: its root at least that multiple of the loop's bandwidth,
the drive file's rule for alpha_s): a double pole at -bw, twice the
observer's decay rate k/2, within the limit (the PLL does not feed back into the observer).
``schedule`` picks the gain per speed by the criterion at that speed alone.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sensorless.design.family import EstimateErrors, later
from sensorless.design.pmsm_flux_observer import ERROR_KEYS
from sensorless.design.pmsm_flux_observer.laws import TABLE_LAWS
from sensorless.tuning.family import Tunable, TuningHooks

if TYPE_CHECKING:  # typed by name; at run time each name is imported from its module when first read
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive
    from sensorless.tuning.pmsm_flux_observer.assessment import (
        Assessment,
        assess,
        assess_any,
        assess_linearized,
        figures,
        front,
        hold_speed,
        low_limit,
    )
    from sensorless.tuning.pmsm_flux_observer.constant import tune_constant
    from sensorless.tuning.pmsm_flux_observer.constant import tune_constant as _tune_constant
    from sensorless.tuning.pmsm_flux_observer.criterion import best, judged, requirements, shortfalls
    from sensorless.tuning.pmsm_flux_observer.outcome import FluxOutcome
    from sensorless.tuning.pmsm_flux_observer.schedule import tune_schedule
    from sensorless.tuning.pmsm_flux_observer.schedule import tune_schedule as _tune_schedule
    from sensorless.tuning.pmsm_flux_observer.settings import (
        FluxTuneSettings,
        check_variant,
        constant_candidate,
        corners,
        default_settings,
        k_grid,
        odrive_defaults,
        vesc_detection,
    )
    from sensorless.tuning.pmsm_flux_observer.settings import default_settings as _default_settings
    from sensorless.tuning.pmsm_flux_observer.voltage_scaled import tune_voltage_scaled
    from sensorless.tuning.pmsm_flux_observer.voltage_scaled import (
        tune_voltage_scaled as _tune_voltage_scaled,
    )
else:  # the hooks' functions, each importing its module at its first call
    _default_settings = later(f"{__name__}.settings", "default_settings")
    _tune_constant = later(f"{__name__}.constant", "tune_constant")
    _tune_schedule = later(f"{__name__}.schedule", "tune_schedule")
    _tune_voltage_scaled = later(f"{__name__}.voltage_scaled", "tune_voltage_scaled")

# the package's names by their modules (read through __getattr__, PEP 562): `tune` lists every family's
# laws, and only a flux drive's tune or report computes with them
_MODULES = {
    "Assessment": "assessment",
    "assess": "assessment",
    "assess_any": "assessment",
    "assess_linearized": "assessment",
    "figures": "assessment",
    "front": "assessment",
    "hold_speed": "assessment",
    "low_limit": "assessment",
    "tune_constant": "constant",
    "best": "criterion",
    "judged": "criterion",
    "requirements": "criterion",
    "shortfalls": "criterion",
    "FluxOutcome": "outcome",
    "tune_schedule": "schedule",
    "FluxTuneSettings": "settings",
    "check_variant": "settings",
    "constant_candidate": "settings",
    "corners": "settings",
    "default_settings": "settings",
    "k_grid": "settings",
    "odrive_defaults": "settings",
    "vesc_detection": "settings",
    "tune_voltage_scaled": "voltage_scaled",
}


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return getattr(importlib.import_module(f"{__name__}.{_MODULES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "HOOKS",
    "Assessment",
    "FluxOutcome",
    "FluxTuneSettings",
    "assess",
    "assess_any",
    "assess_linearized",
    "best",
    "check_variant",
    "constant_candidate",
    "corners",
    "default_settings",
    "figures",
    "front",
    "hold_speed",
    "judged",
    "k_grid",
    "low_limit",
    "odrive_defaults",
    "own_law",
    "requirements",
    "shortfalls",
    "tune_constant",
    "tune_schedule",
    "tune_voltage_scaled",
    "vesc_detection",
]


def own_law(drive: FluxObserverDrive) -> str | None:
    """The default law on a drive of the user's own: the law of its file's [gains] (a VESC user's drive
    tunes the voltage-scaled law), where it is a tunable one (the schema writes a former name as now)."""
    law = drive.gains_table.get("law")
    return law if law in TABLE_LAWS else None


_LEAD = (("w_m_pu", "w_m_pu"), ("T_e_Nm", "T_e_Nm"))


HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "constant",
            "flux observer: observer_gain (gamma lambda^2) and pll_bandwidth, constant over speed (ODrive's "
            "terms)",
            _default_settings,
            tuner=_tune_constant,
            columns=(_LEAD, ()),
        ),
        Tunable(
            "voltage-scaled",
            "flux observer: VESC's foc_observer_gain, foc_observer_gain_slow (scaled with the voltage at run "
            "time), PLL",
            _default_settings,
            tuner=_tune_voltage_scaled,
            columns=(_LEAD, ()),
        ),
        Tunable(
            "schedule",
            "flux observer: gamma lambda^2 free over speed, with the PLL",
            _default_settings,
            tuner=_tune_schedule,
            columns=(_LEAD, ()),
        ),
    ),
    own_default=own_law,
    estimate_errors=lambda drive, settings: EstimateErrors(dict(settings.errors), ERROR_KEYS),
)
