"""The ``constant`` law's tuner (ODrive's terms): one observer_gain and pll_bandwidth over the envelope."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.tuning.pmsm_flux_observer.assessment import assess, front
from sensorless.tuning.pmsm_flux_observer.criterion import best, judged
from sensorless.tuning.pmsm_flux_observer.outcome import FluxOutcome, baselines, outcome, same_law
from sensorless.tuning.pmsm_flux_observer.settings import (
    REFINE,
    FluxTuneSettings,
    check_variant,
    constant_candidate,
    corners,
    k_grid,
    odrive_defaults,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def tune_constant(drive: FluxObserverDrive, settings: FluxTuneSettings, progress: Any = None) -> FluxOutcome:
    """The ``constant`` law: one observer_gain and pll_bandwidth over the envelope (package docstring)."""
    check_variant(drive, "constant")
    ks = k_grid(drive)
    cands = [constant_candidate(drive, float(k)) for k in ks]
    if progress:
        progress(
            f"{len(cands)} observer gains x the envelope x {len(corners(settings.errors))} estimate cases"
        )
    a = assess(drive, cands, settings)
    base_lines, base = baselines(drive, settings)
    c = best(drive, a, settings)
    w_hold = judged(drive, a, c, settings)["hold_from_rad_s"]
    pf = front(drive, a, cands, w_hold, settings.pareto, settings.bias_max_deg) if settings.pareto else None
    # refined between the grid's neighbours of the best, with the firmware's default and the drive
    # file's gains of this law as candidates too (the tuned gains are never worse than either)
    lo, hi = ks[max(c - 1, 0)], ks[min(c + 1, len(ks) - 1)]
    cands = [cands[c], *(constant_candidate(drive, float(k)) for k in np.geomspace(lo, hi, REFINE))]
    cands += [odrive_defaults(), *same_law(drive, "constant")]
    a = assess(drive, cands, settings)
    return outcome(
        drive,
        "constant",
        lambda g: (
            f"tuned constant: observer_gain = {g['observer_gain']:.6g} 1/s, "
            f"pll_bandwidth = {g['pll_bandwidth']:.6g} rad/s"
        ),
        cands,
        a,
        (base, base_lines),
        settings,
        pf,
    )
