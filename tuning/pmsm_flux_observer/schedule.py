"""The ``schedule`` law's tuner: gamma lambda^2 per envelope speed, by the criterion at that speed."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.tuning.pmsm_flux_observer.assessment import assess, assess_linearized, figures
from sensorless.tuning.pmsm_flux_observer.criterion import judged, requirements, shortfalls
from sensorless.tuning.pmsm_flux_observer.outcome import FluxOutcome, baselines, gain_table, summary_line
from sensorless.tuning.pmsm_flux_observer.settings import (
    KP_T,
    FluxTuneSettings,
    check_variant,
    constant_candidate,
    k_grid,
    pll_floor,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def tune_schedule(drive: FluxObserverDrive, settings: FluxTuneSettings, progress: Any = None) -> FluxOutcome:
    """The ``schedule`` law: gamma lambda^2 per envelope speed, by the criterion at that speed."""
    check_variant(drive, "schedule")
    ks = k_grid(drive)
    cands = [constant_candidate(drive, float(k)) for k in ks]
    a = assess(drive, cands, settings)
    W, _ = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    need = requirements(drive, settings)["decay"]
    chosen = []
    assert a.decay is not None  # assess gives every candidate its decay
    for j, sp in enumerate(speeds):
        sel = np.abs(W) == sp
        hold = a.holds[:, j]
        zeta = [float(np.min(a.damping[c, sel])) for c in range(len(ks))]
        decay = [float(np.nan_to_num(np.min(a.decay[c, sel]), nan=-np.inf)) for c in range(len(ks))]
        # the family's criterion at this speed (criterion.py): holding and decaying as fast as the speed
        # loop needs: the fastest decay; else holding: the fastest decay; else the best damped
        score = [
            (0 if decay[c] >= need else 1, -decay[c], c) if hold[c] else (2, -zeta[c], c)
            for c in range(len(ks))
        ]
        chosen.append(float(ks[min(score)[2]]))
    # below the lowest speed where a gain holds, every candidate ties at "no equilibrium under some
    # error" and the first (K_MIN) would win: an observer slowest where it needs speed most; the
    # schedule is held at the lowest holding speed's gain instead (as the law holds it beyond its ends)
    held = np.flatnonzero(a.holds.any(axis=0))
    if held.size:
        chosen = [chosen[held[0]] if j < held[0] else k for j, k in enumerate(chosen)]
    T = drive.observer.T_obs
    # one PLL at every speed: its double pole at the geometric mean of the scheduled gains
    bw = min(max(float(np.exp(np.mean(np.log(chosen)))), pll_floor(drive)), KP_T / (2 * T))
    g = {"speeds": [float(s) for s in speeds], "observer_gain": chosen, "pll_bandwidth": bw}
    gs = GainSet("schedule", g, "tuned")
    a_s = assess_linearized(drive, gs, settings)  # the schedule itself, its law's derivative included
    f = figures(drive, a_s, 0)
    base_lines, base = baselines(drive, settings)
    lines = [
        "tuned schedule: observer_gain over |speed| "
        + ", ".join(f"{s / drive.w_base:.3g} pu: {k:.4g}" for s, k in zip(speeds, chosen, strict=True))
        + f"; pll_bandwidth = {bw:.6g} rad/s",
        summary_line("tuned", f, settings),
        "baselines (the firmwares' defaults on this motor, same criterion):",
        *base_lines,
    ]
    jd = judged(drive, a_s, 0, settings)
    f.update(worst_decay_1_s=jd["worst_decay_1_s"], pll_root_1_s=jd["pll_root_1_s"])
    summary = {**f, "baselines": base, "errors": settings.errors, "bias_max_deg": settings.bias_max_deg}
    missed = shortfalls(drive, gs, jd, settings)
    return FluxOutcome("schedule", gain_table(drive, "schedule", g, a_s, 0, summary), lines, missed)
