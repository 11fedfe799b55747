"""The ``voltage-scaled`` law's tuner (VESC's terms): foc_observer_gain and foc_observer_gain_slow under
VESC's run-time schedule, with its PLL."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer.gains import SCALED_U_REF
from sensorless.tuning.pmsm_flux_observer.assessment import assess, front
from sensorless.tuning.pmsm_flux_observer.criterion import best, judged
from sensorless.tuning.pmsm_flux_observer.outcome import FluxOutcome, baselines, outcome, same_law
from sensorless.tuning.pmsm_flux_observer.settings import (
    K_MIN,
    K_T_MAX,
    KP_T,
    ODRIVE_DEFAULT,
    REFINE,
    SLOW_GRID,
    FluxTuneSettings,
    check_variant,
    pll_floor,
    vesc_detection,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def tune_voltage_scaled(
    drive: FluxObserverDrive, settings: FluxTuneSettings, progress: Any = None
) -> FluxOutcome:
    """The ``voltage-scaled`` law: foc_observer_gain and foc_observer_gain_slow under VESC's run-time
    schedule."""
    check_variant(drive, "voltage-scaled")
    psi = drive.estimate.psi_pm
    T = drive.observer.T_obs
    # the schedule's factor at the top of the envelope: k there = 4 raw psi^2 max(slow, |u|/u_ref)
    u_top = drive.envelope.speed_max * drive.motor.psi_pm
    top = max(u_top / SCALED_U_REF, 1e-3)
    cands = []
    for slow in SLOW_GRID:
        for k in np.geomspace(K_MIN, K_T_MAX / T, 16):
            raw = k / (4 * psi**2 * max(slow, top))  # k at the top speed
            kp = min(max(k, 2 * pll_floor(drive)), KP_T / T)  # a double root at -k_p/2
            cands.append(
                GainSet(
                    "voltage-scaled",
                    {
                        "foc_observer_gain": raw,
                        "foc_observer_gain_slow": slow,
                        "foc_pll_kp": kp,
                        "foc_pll_ki": kp**2 / 4,
                    },
                    "candidate",
                )
            )
    if progress:
        progress(f"{len(cands)} (gain, slow gain) pairs x the envelope")
    a = assess(drive, cands, settings)
    base_lines, base = baselines(drive, settings)
    c = best(drive, a, settings)
    w_hold = judged(drive, a, c, settings)["hold_from_rad_s"]
    pf = front(drive, a, cands, w_hold, settings.pareto, settings.bias_max_deg) if settings.pareto else None
    # refined in the gain at the best slow gain, with VESC Tool's detection and the drive file's gains
    # of this law as candidates too (the tuned gains are never worse than either)
    raw0, slow0 = cands[c].values["foc_observer_gain"], cands[c].values["foc_observer_gain_slow"]
    step = (K_T_MAX / T / K_MIN) ** (1 / 15)
    fine = []
    for raw in np.geomspace(raw0 / step, raw0 * step, REFINE):
        g0 = dict(cands[c].values)
        g0["foc_observer_gain"] = float(raw)
        fine.append(GainSet("voltage-scaled", g0, "candidate"))
    cands = [cands[c], *fine, vesc_detection(drive), odrive_defaults_voltage_scaled(drive)]
    cands += same_law(drive, "voltage-scaled")
    del slow0
    a = assess(drive, cands, settings)
    return outcome(
        drive,
        "voltage-scaled",
        lambda g: (
            f"tuned voltage-scaled: foc_observer_gain = {g['foc_observer_gain']:.6g} "
            f"({g['foc_observer_gain'] / 1e6:.4g} x1M), "
            f"foc_observer_gain_slow = {g['foc_observer_gain_slow']:.3g}, "
            f"foc_pll_kp = {g['foc_pll_kp']:.6g}, foc_pll_ki = {g['foc_pll_ki']:.6g}"
        ),
        cands,
        a,
        (base, base_lines),
        settings,
        pf,
    )


def odrive_defaults_voltage_scaled(drive: FluxObserverDrive) -> GainSet:
    """ODrive's defaults (k = 1000 1/s, a PLL double root at 1000 1/s) as VESC gains: the slow gain 1
    keeps k = 4 raw lambda^2 constant up to |u| = u_ref (23.1 V), and above it k grows with |u|."""
    k, bw = ODRIVE_DEFAULT["observer_gain"], ODRIVE_DEFAULT["pll_bandwidth"]
    values = {
        "foc_observer_gain": k / (4 * drive.estimate.psi_pm**2),
        "foc_observer_gain_slow": 1.0,
        "foc_pll_kp": 2 * bw,
        "foc_pll_ki": bw**2,
    }
    return GainSet("voltage-scaled", values, "ODrive defaults in VESC's terms")
