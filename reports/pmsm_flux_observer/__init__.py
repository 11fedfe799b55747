"""Report hooks of the flux observer + PLL family: its firmware importers and exporters so far.

firmware_io.py declares the firmware formats (``sensorless init --from vesc|odrive``, ``sensorless
export --target vesc|odrive|simplefoc``); :func:`firmware_record` gives them the drive's values.
"""

from __future__ import annotations

from typing import Any

from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer import FAMILY
from sensorless.design.pmsm_flux_observer.firmware import FirmwareDrive
from sensorless.reports.family import ReportHooks
from sensorless.reports.pmsm_flux_observer.firmware_io import exporters, importers


def firmware_record(drive: Any, gains: GainSet) -> FirmwareDrive:
    """What an export writes: the drive's estimates (what the firmware is given), loop and gains."""
    e, obs = drive.estimate, drive.observer
    return FirmwareDrive(
        name=drive.name,
        p=drive.motor.p,
        R_s=e.R_s,
        L_d=e.L_d,
        L_q=e.L_q,
        psi_pm=e.psi_pm,
        u_dc=drive.control.u_dc,
        T_obs=obs.T_obs,
        correction=obs.correction,
        lambda_adaptation=obs.lambda_adaptation,
        law=gains.family,
        gains=dict(gains.values),
        source=gains.source,
    )


HOOKS = ReportHooks(importers=importers(FAMILY.kind), exporters=exporters(firmware_record))
