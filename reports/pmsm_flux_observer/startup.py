"""What the flux-observer family's report and tune say of the drive's I-f start at the gains under review,
and where its firmware cannot run a check (ODrive through zero speed)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from sensorless.design.family import GainSet
from sensorless.reports.document import f
from sensorless.reports.time_domain import Check

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def startup_findings(drive: FluxObserverDrive, gains: GainSet) -> tuple[list[str], dict[str, Any] | None]:
    """The drive's I-f start judged at the gains under review (design/startup_check.py): one finding per
    value that does not hold, naming the firmware's field and the value that fixes it, and the data of
    report.json; nothing where the drive needs no start or has no minimum-speed analysis."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.pmsm_flux_observer.firmware import stored
    from sensorless.design.pmsm_flux_observer.firmware.startup import change_lines, fields
    from sensorless.design.startup_check import judge_startup
    from sensorless.reports.pmsm_flux_observer.findings import pll_fixed

    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:
        return [], None
    if judged is None:
        return [], None
    fw = drive.observer.firmware
    lead: list[str] = []
    fixed = None if judged.fixable else pll_fixed(gains, drive.control.alpha_s)
    again = None if fixed is None else judge_startup(drive, fixed)
    if fixed is not None and again is not None and again.fixable:  # the PLL holds w_min at rated speed
        lead = [x for x in change_lines(fw, judged, drive.w_base) if "no start-up value fixes it" in x]
        named = ", ".join(
            f"{k} = {stored(float(v))}" for k, v in fixed.values.items() if v != gains.values[k]
        )
        judged = again
        if judged.shortfalls:
            lead.append(f"start-up with the PLL's fix ({named}; the PLL's finding):")
    data = {
        "at_gains": "the PLL's fix" if lead else "under review",
        "w_min_rad_s": f(judged.w_min),
        "values": {k: f(v) for k, v in sorted(judged.values.items())},
        "firmware_fields": {k: f(v) for k, (v, _) in fields(fw, judged.values).items()}
        if judged.fixable
        else {},
        "shortfalls": [
            {"key": s.key, "value": f(s.value), "needed": f(s.needed), "cause": s.cause, "why": s.why}
            for s in judged.shortfalls
        ],
    }
    return lead + change_lines(fw, judged, drive.w_base), data


def reversal_finding(drive: FluxObserverDrive, runs: Sequence[Any], td: Sequence[Check]) -> list[str]:
    """Where the firmware cannot run a failed check: ODrive's sensorless mode "does not support stopping
    or changing direction" (ODrive's documentation, sensorless mode), so a check through zero speed
    judges the I-f start's fall-back below w_off, which ODrive does not have."""
    from sensorless.design.scenario import crosses_zero

    if drive.observer.firmware != "odrive":
        return []
    through = {sc.name for sc in runs if crosses_zero(sc)}
    names = [c["name"] for c in td if not c["passed"] and c["name"] in through]
    if not names:
        return []
    return [
        f"{', '.join(names)}: through zero speed, which ODrive's sensorless mode does not support (its "
        'documentation: it "does not support stopping or changing direction"; no fall-back to open loop, no '
        "field for w_off); the check judges the I-f start's fall-back of the generated code, not ODrive: "
        "with ODrive, stop and reverse in closed loop with a sensor, or not at all"
    ]


def tune_startup(drive: FluxObserverDrive, gains: GainSet) -> list[str]:
    """What ``tune`` says of the start at the tuned gains: the firmware's start-up fields it proposes
    (``export`` writes them), and one line per value of the drive file's that it changes, with why."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.pmsm_flux_observer.firmware import stored
    from sensorless.design.pmsm_flux_observer.firmware.startup import change_lines, fields
    from sensorless.design.startup_check import judge_startup

    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:
        return []
    if judged is None:
        return []
    fw = drive.observer.firmware
    lines = change_lines(fw, judged, drive.w_base)
    if judged.fixable:
        kept = "the drive file's kept where they hold" if judged.given else "by the rules"
        shown = ", ".join(f"{k} = {stored(v)} {u}" for k, (v, u) in fields(fw, judged.values).items())
        lines.insert(0, f"start-up at these gains ({kept}; sensorless export writes it): {shown}")
    return lines
