"""The minimum sensorless speed in every report and tune summary: section, table, figure, verdict line.

Shared by every family: the computation is design/low_speed.py (the family's linearization at the gains
under review); here it becomes report.json's ``low_speed``, a section with w_min(T) as a figure and a
table, and the headline line of the verdict (:func:`add_to_report`), and one line of ``sensorless
tune``'s summary (:func:`tune_line`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import TYPE_CHECKING, Unpack

from sensorless.design.capabilities import OpenLoopStart
from sensorless.design.family import CapabilityError, Drive, EstimateErrors, GainSet
from sensorless.design.low_speed import (
    MAX_BIAS_DEG,
    QUICK,
    LowSpeed,
    SpeedOptions,
    headline,
    minimum_speed,
    minimum_speed_under,
)
from sensorless.design.registry import family_of
from sensorless.design.startup import ACCELERATION_LIMIT, HANDOVER_CAPPED, ON_FACTOR
from sensorless.reports.document import Figure, Paragraph, Report, Section, Table, num
from sensorless.reports.figure_layout import lay_out
from sensorless.reports.svg_render import svg_later

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure


def _figure(ls: LowSpeed, title: str) -> MplFigure:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    ax.plot(ls.torque / ls.T_N, ls.w_min / ls.w_base, "k.-")
    ax.fill_between(ls.torque / ls.T_N, 0, ls.w_min / ls.w_base, color="0.85", label="below w_min")
    ax.set_xlabel(r"torque $T/T_N$")
    ax.set_ylabel(r"$\omega_{min}$ (p.u.)")
    ax.set_title(title, fontsize=9)
    ax.set_ylim(bottom=0)
    ax.grid(True, color="0.9")
    ax.legend(loc="best", fontsize=8)
    lay_out(fig, [[ax]])
    return fig


def section(number: int, ls: LowSpeed, drive: Drive, label: str) -> Section:
    """The report section of w_min(T)."""
    crit = ls.data()["criteria"]
    text = (
        f"The lowest speed from which the observer (gains: {label}) meets, at every speed above, the "
        f"required damping {crit['min_damping']:g}, a decay rate of {crit['min_decay_per_s']:.4g} 1/s "
        f"(a tenth of the speed-loop bandwidth unless stated), an angle bias under the estimate errors "
        f"of at most {crit['max_bias_deg']:.3g} deg and an RMS angle noise from the current sensor of at "
        f"most {crit['max_noise_deg_rms']:.3g} deg (criteria the family's linearization gives: "
        f"{', '.join(crit['applied'])}); from the linearization of {ls.basis or 'the observer'} "
        f"(design/low_speed.py). {headline(ls)}."
    )
    rows = tuple(
        (num(t / ls.T_N, 3), num(w / ls.w_base, 4), num(ls.rpm(w), 4), lim or "–")
        for t, w, lim in zip(ls.torque, ls.w_min, ls.limited_by, strict=True)
    )
    table = Table(
        ("torque (p.u.)", "w_min (p.u.)", "w_min (rpm)", "limited by"), rows, numeric=frozenset({0, 1, 2})
    )
    fig = Figure(
        svg_later(functools.partial(_figure, ls, f"{drive.name}: minimum sensorless speed")),
        "Minimum sensorless speed w_min over the torque (T < 0: regenerating at positive speed).",
    )
    return Section(f"{number}. Minimum sensorless speed versus load", (Paragraph(text), table, fig))


def add_to_report(
    rep: Report, drive: Drive, gains: GainSet, min_damping: float, max_bias: float, quick: bool = False
) -> Report:
    """``rep`` with report.json's ``low_speed``, its section (last) and the headline in the verdict;
    ``quick``: the coarser grid of ``sensorless report --quick``."""
    try:
        grid: SpeedOptions = QUICK if quick else {}
        errors = family_of(drive).estimate_errors(drive)
        opts: SpeedOptions = {**grid, "max_bias": max_bias}
        ls = under_errors(drive, gains, errors, min_damping=min_damping, **opts)
    except CapabilityError:
        return rep
    line = headline(ls)
    fam = family_of(drive)
    start = ""
    if ls.w_min_rated > 0 and not fam.holds_zero_speed(drive):
        why = fam.low_speed_reason(drive) or "the observer does not hold zero speed under rated load"
        on, off, limit = _handover(drive, gains, ls)
        start = (
            f"{why[0].upper() + why[1:]}; a start or a reversal under load passes through the open-loop I-f "
            f"start, 0 to {on / ls.w_base:.3g} p.u. (handover; back below {off / ls.w_base:.3g} p.u.: "
            f"design/startup.py){limit}"
        )
        if off < ls.w_min_rated * (1 - 1e-3):  # the start's rules take w_min at the drive's estimates
            start += handover_advice(ls.w_min_rated / ls.w_base)
    data = {**rep.data, "low_speed": {**ls.data(), "headline": line, "startup": start}}
    if isinstance(data.get("verdict"), dict):
        data["verdict"] = {**data["verdict"], "low_speed": line}
    lines = rep.verdict.lines
    extra = (Paragraph(line[0].upper() + line[1:] + "."), *((Paragraph(start + "."),) if start else ()))
    verdict = dataclasses.replace(rep.verdict, lines=(*lines[:1], *extra, *lines[1:]))
    sec = section(len(rep.sections) + 1, ls, drive, rep.review)
    return dataclasses.replace(rep, data=data, verdict=verdict, sections=(*rep.sections, sec))


def handover_advice(w: float) -> str:
    """What the start's line adds where its handover is below ``w`` [p.u.], the w_min under the estimate
    errors: the [startup] speeds that hand over only where they allow it, never a w_on above 1 pu (the
    drive file's loader refuses one: the open loop hands over below the rated speed); advised only where
    w_off = w_min stays below it by the printed digits."""
    head = f"; that is below w_min = {w:.3g} p.u. under the estimate errors"
    if w < 0.995:
        return (
            f"{head}: give [startup] w_on = {min(ON_FACTOR * w, 1.0):.3g} pu and w_off = {w:.3g} pu to hand "
            "over only where they allow it"
        )
    return (
        f"{head}, at the rated speed or above: no handover (at most 1 p.u.) is where they allow it: gains "
        "with a lower w_min (sensorless tune)"
    )


def _handover(drive: Drive, gains: GainSet, ls: LowSpeed) -> tuple[float, float, str]:
    """(w_on, w_off) [rad/s] of the drive's I-f start where its family runs one (its [startup], else
    the rules from w_min at its estimates: design/pmsm_drive.py), else the rules at ``ls``'s w_min; and
    the physical limit the start names ("; ..." or "": an observer too slow for the full acceleration)."""
    if isinstance(family_of(drive), OpenLoopStart):
        from sensorless.design.pmsm_drive import startup_values

        try:
            values, sline, _ = startup_values(drive, gains)  # type: ignore[arg-type]
        except CapabilityError:
            values, sline = None, ""
        if values is not None:
            # why the handover is high, where the start's line says it (design/startup.py handover_reason)
            at = [sline.index(k) for k in (ACCELERATION_LIMIT, HANDOVER_CAPPED) if k in sline]
            limit = f"; {sline[min(at) :]}" if at else ""
            return values["if_w_on"], values["if_w_off"], limit
    return ON_FACTOR * ls.w_min_rated, ls.w_min_rated, ""


def under_errors(
    drive: Drive, gains: GainSet, errors: EstimateErrors, *, min_damping: float, **kw: Unpack[SpeedOptions]
) -> LowSpeed:
    """w_min under ``errors`` (design/low_speed.py ``minimum_speed_under``); where the family's analysis
    takes no estimate errors, at the drive file's estimates, saying so."""
    try:
        return minimum_speed_under(drive, gains, errors, min_damping=min_damping, **kw)
    except CapabilityError:
        if not errors:
            raise
    ls = minimum_speed(drive, gains, min_damping=min_damping, **kw)
    why = f"its family's analysis takes no estimate errors, not the stated {errors.text()}"
    return dataclasses.replace(ls, errors_source=why)


def tune_line(drive: Drive, gains: GainSet, min_damping: float, errors: EstimateErrors) -> str:
    """The tune summary's line (the tuned gains under the ``errors`` tuned under, the grid of ``report
    --quick``), or "" where the family has no linearization."""
    try:
        # a float, as `report` passes it: the same analysis, the same memo key (design/memo.py)
        kw: SpeedOptions = {"max_bias": math.radians(MAX_BIAS_DEG), **QUICK}
        return headline(under_errors(drive, gains, errors, min_damping=min_damping, **kw))
    except CapabilityError:
        return ""
