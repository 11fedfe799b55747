"""The speed reference's rate limiter of a drive (symbolic/speed_ramp.py) with its number: runtime set-up.

A drive file's ``[control] speed_ramp`` [rad/s^2 electrical; "pu/s" per unit of the base speed per
second] limits how fast the speed reference the speed controller tracks may change; 0 (the default of
a drive file without the key) is none. ``sensorless init`` derives it where the drive needs it
(reports/cli/init.py: the I-f start's acceleration, where the observer cannot follow the drive's full
braking at low speed), and a firmware import carries the firmware's own setting. The limiter runs in
the runtime observer's step (the drive loop's speed controller takes its output ``w_ref_r``), so the
simulated drive and the generated C are one expression.
"""

from __future__ import annotations

import dataclasses

from sensorless.design.capabilities import Scaled
from sensorless.design.family import Drive
from sensorless.design.registry import family_of
from sensorless.design.runtime import RuntimeSetup
from sensorless.symbolic.speed_ramp import RAMP_ACC, with_speed_ramp


def with_ramp(setup: RuntimeSetup, rate: float) -> RuntimeSetup:
    """``setup`` with its observer wrapped in the speed reference's rate limiter at ``rate`` [rad/s^2]
    (> 0); unchanged for 0 (no limiter: the step, its C and the loop stay those of a drive without one)."""
    if not rate > 0:
        return setup
    obs = with_speed_ramp(setup.observer)
    params = {**setup.params, RAMP_ACC.name: float(rate)}
    obs.check_params(params)
    notes = (*setup.notes, f"speed reference ramped at {rate:.4g} rad/s^2 (electrical; [control] speed_ramp)")
    return dataclasses.replace(setup, observer=obs, params=params, notes=notes)


def speed_ramp_of(drive: Drive) -> float:
    """The drive's speed reference rate limit [rad/s^2] (its family's ``DriveScales.speed_ramp``: the
    drive file's ``[control] speed_ramp``); 0 where it has none or its family gives no scales."""
    fam = family_of(drive)
    return float(fam.scales(drive).speed_ramp) if isinstance(fam, Scaled) else 0.0


def drive_ramp(drive: Drive, setup: RuntimeSetup) -> RuntimeSetup:
    """``setup`` with the drive's own speed reference rate limiter (:func:`with_ramp`; unchanged without)."""
    return with_ramp(setup, speed_ramp_of(drive))
