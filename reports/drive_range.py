"""The drive's real range and its linear judgement: the one envelope ``sensorless tune`` proves its table
on and ``sensorless report`` judges the gains under review on, so that both give one answer.

The range (:func:`range_envelope`, a design/envelope.py ``Envelope``) is speeds +-[SPEED_MIN, 1] p.u.
(SPEEDS per direction, both directions) x torques {-T_max, -T_N, 0, T_N, T_max}: motoring and
regenerating at the torque limit the speed loop reaches in every acceleration (design/family.py
``DriveScales``). The analysis (:func:`drive_analysis`) is the whole sampled drive (design/
drive_analysis.py: observer, current PI in the estimated frame, speed PI on the estimate, delay,
mechanics) where the family has a drive loop and the speed loop is within its torque limit, the
family's observer linearization (``ObserverFamily.linearize``) at the saturated loads +-T_max and for a
family without a drive loop. The whole-drive loop leaves out what has no fixed point in it (a low-speed
mechanism of the family's own, e.g. an HF injection: the loop's note, design/drive_analysis.py), so
inside that mechanism's band the range is judged without it. Judged there instead by the observer with
the family's ``low_speed_options`` (measured, not kept): the test traction motor's tuned gains turned
unstable at 6 points where the file's are stable (regenerating, the injection's coupling band), and
poles at 0 ... +0.003 1/s appeared at the band's edge, where the injection's correction fades out:
both to be settled before the range is judged that way.

:func:`judge` reads it as a check with the one verdict rule (reports/time_domain.py ``status_with``): a
point without a stable equilibrium makes it ``fail`` (cause ``rhp_band``, reports/causes.py, naming the
point and the change that fixes it; or the family's own cause, :class:`Remedy`, at the points its change
holds in this analysis), a worst damping below the required one ``warn`` (as the
observer-only judges read the damping), else ``pass``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from sensorless.design.capabilities import Linearizable, Scaled, require
from sensorless.design.envelope import Envelope, tuning_envelope
from sensorless.design.family import CapabilityError, Drive, GainSet
from sensorless.design.linearization import Linearization
from sensorless.design.registry import family_of
from sensorless.reports.causes import CATALOGUE
from sensorless.reports.time_domain import Finding

SPEEDS = 20  # per direction, from SPEED_MIN to 1 p.u.
SPEED_MIN = 0.05  # p.u.
# below the torque limit by this share: at a load of +-T_max the speed loop sits at its limit (saturated:
# no closed-loop fixed point, Newton's result there is noise), so the observer-only analysis judges it
SATURATED_SHARE = 0.999
CHECK = "drive_range"  # the check's name in a verdict's findings


def range_envelope(drive: Drive) -> Envelope | None:
    """The drive's real range (module docstring) as an Envelope; None for a family without scales."""
    fam = family_of(drive)
    if not isinstance(fam, Scaled):
        return None
    sc = fam.scales(drive)
    env = tuning_envelope(sc.w_base, sc.T_N, speed_min=SPEED_MIN, speed_max=1.0, speeds=SPEEDS)
    return env.widened(sc.T_max)


def envelope(drive: Drive) -> tuple[np.ndarray, np.ndarray] | None:
    """Flat (w [rad/s], torque [N m]) of :func:`range_envelope` (torque-major); None without scales."""
    env = range_envelope(drive)
    return None if env is None else env.grid()


def observer_analysis(drive: Drive, gains: GainSet, w: np.ndarray, torque: np.ndarray) -> Linearization:
    """The family's observer linearization (``sensorless analyze``)."""
    return require(family_of(drive), Linearizable).linearize(drive, gains, w, torque)


@dataclass(frozen=True)
class Combined:
    """Per envelope point, the figures of two analyses (module docstring)."""

    max_real: np.ndarray
    worst_damping: np.ndarray


def drive_analysis(
    drive: Drive, gains: GainSet, w: np.ndarray, torque: np.ndarray
) -> Linearization | Combined:
    """The whole sampled drive where the family has a drive loop and the speed loop is within its torque
    limit; the observer-only linearization at the loads at +-T_max (the speed loop saturated there: the
    observer runs with the torque command at the limit, its own set-up) and for a family without a
    drive loop."""
    from sensorless.design.drive_analysis import linearize_drive

    fam = family_of(drive)
    if not isinstance(fam, Scaled):
        return observer_analysis(drive, gains, w, torque)
    try:  # CapabilityError: no drive loop (design/drive_analysis.py)
        T_max = fam.scales(drive).T_max
        inside = np.abs(torque) < SATURATED_SHARE * T_max
        if not inside.any():
            return observer_analysis(drive, gains, w, torque)
        lin = linearize_drive(drive, gains, w[inside], torque[inside])
    except CapabilityError:
        return observer_analysis(drive, gains, w, torque)
    # the observer alone only where the whole drive is not analysed (each point's analysis is its own:
    # the same numbers as at all points; at the range's 200 points the reduced-order family's orbits
    # took 11 s, three fifths of them for points the whole drive then replaced)
    out = ~inside
    mr = np.empty(w.shape, float)
    wd = np.empty(w.shape, float)
    mr[inside], wd[inside] = lin.max_real, lin.worst_damping
    if out.any():
        obs = observer_analysis(drive, gains, w[out], torque[out])
        mr[out], wd[out] = np.asarray(obs.max_real, float), np.asarray(obs.worst_damping, float)
    return Combined(mr, wd)


@dataclass(frozen=True)
class RangeJudgement:
    """The gains under review over the drive's range: status, findings (the verdict's records) and
    report.json's ``drive_range``."""

    status: str
    findings: list[Finding] = field(default_factory=list)
    data: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Remedy:
    """A family's named cause of instability over the range and its change: ``gains`` (and ``drive``,
    None: the same drive) with that change. A point unstable with the gains under review and stable with
    the change is put down to ``cause`` (reports/causes.py), the others to ``rhp_band``: the cause is
    what the change does, analysed, not a label."""

    cause: str
    why: str  # the cause in the design's numbers and what to do (one line)
    gains: GainSet
    drive: Drive | None = None


# a family's remedy of the unstable points: (|w| [rad/s] of the stable points, of the unstable ones) ->
# its Remedy, or None (the shared cause)
Remedies = Callable[[np.ndarray, np.ndarray], "Remedy | None"]


def judge(
    drive: Drive, gains: GainSet, min_damping: float, remedies: Remedies | None = None
) -> RangeJudgement:
    """The gains over the drive's range (module docstring); ``pass`` with no data where the family has no
    scales (the range is then not defined); ``remedies``: the family's named cause (:class:`Remedy`)
    where points are unstable."""
    pts = envelope(drive)
    if pts is None:
        return RangeJudgement("pass")
    w, t = pts
    lin = drive_analysis(drive, gains, w, t)
    mr = np.asarray(lin.max_real, float)
    wd = np.asarray(lin.worst_damping, float)
    with np.errstate(invalid="ignore"):
        stable = np.isfinite(mr) & (mr < 0)
        damped = stable & (wd >= min_damping)
    wb, T_N = drive.w_base, require(family_of(drive), Scaled).scales(drive).T_N
    at = lambda k: f"w = {w[k] / wb:+.3g} p.u., T = {t[k]:+.4g} N m ({t[k] / T_N:+.3g} T_N)"  # noqa: E731
    # the worst damping as the proof prints it (over every point with an equilibrium, unstable ones too)
    found = np.isfinite(wd)
    k_all = int(np.nanargmin(np.where(found, wd, np.inf))) if found.any() else 0
    k_worst = int(np.nanargmin(np.where(stable, wd, np.inf))) if stable.any() else 0  # of the stable ones
    data: dict[str, object] = {
        "what": "the drive's real range, as `sensorless tune` proves it (reports/drive_range.py): speeds "
        f"+-[{SPEED_MIN:g}, 1] p.u. x torques {{-T_max, -T_N, 0, T_N, T_max}}; the whole sampled drive "
        "within the torque limit, the observer alone at +-T_max (the speed loop saturated)",
        "points": int(w.size),
        "stable_points": int(stable.sum()),
        "worst_damping": float(wd[k_all]) if found.any() else None,
        "worst_at": {"w_pu": float(w[k_all] / wb), "T_Nm": float(t[k_all])} if found.any() else None,
        "min_damping": min_damping,
    }
    findings: list[Finding] = []
    status = "pass"
    if not stable.all():
        status = "fail"
        bad = np.flatnonzero(~stable)
        cured = np.zeros(bad.size, bool)
        remedy = None if remedies is None else remedies(np.abs(w[stable]), np.abs(w[bad]))
        if remedy is not None:  # the family's named cause, where its change makes the point stable
            fixed = drive_analysis(remedy.drive or drive, remedy.gains, w[bad], t[bad])
            with np.errstate(invalid="ignore"):
                cured = np.isfinite(fixed.max_real) & (np.asarray(fixed.max_real) < 0)
            data["remedied_points"] = int(cured.sum())
        for part, cause, why, change in (
            (bad[cured], remedy.cause if remedy else "", remedy.why if remedy else "", ""),
            (bad[~cured], "rhp_band", "", CATALOGUE["rhp_band"].fix),
        ):
            if part.size:
                findings.append(
                    _unstable(part, mr, w, t, wb, at, cause, why or CATALOGUE[cause].title, change)
                )
    low = stable & ~damped
    if low.any():
        status = "warn" if status == "pass" else status
        speeds = np.abs(w[low]) / wb
        findings.append(
            {
                "issue": f"damping below {min_damping:g} over the drive's range",
                "check": CHECK,
                "causes": [],
                "text": f"the drive's range (+-T_max): damping below {min_damping:g} at {int(low.sum())} of "
                f"{w.size} points, {_span(speeds)}, worst "
                f"{wd[k_worst]:.3g} at {at(k_worst)}: gains that damp the drive there (sensorless tune "
                "over this range)",
            }
        )
    return RangeJudgement(status, findings, data)


def _unstable(
    part: np.ndarray,
    mr: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    wb: float,
    at: Callable[[int], str],
    cause: str,
    why: str,
    change: str,
) -> Finding:
    """The finding of the unstable points ``part`` put down to ``cause``."""
    k = int(part[np.argmax(np.nan_to_num(mr[part], nan=np.inf))])
    what = f"max Re {mr[k]:+.3g} 1/s" if np.isfinite(mr[k]) else "no equilibrium"
    fix = f": {change}" if change else ""
    return {
        "issue": "unstable over the drive's range",
        "check": CHECK,
        "causes": [cause],
        "text": f"the drive's range (+-T_max, the envelope `sensorless tune` proves): unstable at "
        f"{part.size} of {w.size} points, {_span(np.abs(w[part]) / wb)}, worst at {at(k)} ({what}) "
        f"(cause: {why}{fix})",
    }


def _span(speeds: np.ndarray) -> str:
    """The range of |w| [p.u.] ``speeds`` covers, in words."""
    lo, hi = float(speeds.min()), float(speeds.max())
    return f"|w| = {lo:.3g} p.u." if lo == hi else f"{lo:.3g} <= |w| <= {hi:.3g} p.u."
