"""The minimum sensorless speed in every report and tune summary: section, table, figure, verdict line.

Shared by every family: the computation is design/low_speed.py (the family's linearization at the gains
under review); here it becomes report.json's ``low_speed``, a section with w_min(T) as a figure and a
table, and the headline line of the verdict (:func:`add_to_report`), and one line of ``sensorless
tune``'s summary (:func:`tune_line`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np
from sensorless.design.family import CapabilityError, Drive, GainSet
from sensorless.design.low_speed import MAX_BIAS_DEG, QUICK, LowSpeed, headline, minimum_speed
from sensorless.design.pmsm_drive import startup_values
from sensorless.design.registry import family_of
from sensorless.design.startup import ACCELERATION_LIMIT, ON_FACTOR
from sensorless.reports.document import Figure, Paragraph, Report, Section, Table, num
from sensorless.reports.svg_render import svg_later


def _figure(ls: LowSpeed, title: str) -> Any:
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
    fig.tight_layout()
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
        f"{', '.join(crit['applied'])}); from the linearization (design/low_speed.py). {headline(ls)}."
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
        grid = QUICK if quick else {}
        ls = minimum_speed(drive, gains, min_damping=min_damping, max_bias=max_bias, **grid)
    except CapabilityError:
        return rep
    line = headline(ls)
    fam = family_of(drive)
    start = ""
    if ls.w_min_rated > 0 and not fam.holds_zero_speed(drive):
        why = fam.low_speed_reason(drive) or "the observer does not hold zero speed under rated load"
        # the start's own speeds (its handover w_min asks for more than the analysis': design/startup.py)
        w_on, w_off, limit = ON_FACTOR * ls.w_min_rated, ls.w_min_rated, ""
        try:
            values, sline, _ = startup_values(drive, gains)  # type: ignore[arg-type]
        except CapabilityError:
            values, sline = None, ""
        if values is not None:
            w_on, w_off = values["if_w_on"], values["if_w_off"]
            limit = f"; {sline[sline.index(ACCELERATION_LIMIT) :]}" if ACCELERATION_LIMIT in sline else ""
        start = (
            f"{why[0].upper() + why[1:]}; a start or a reversal under load passes through the open-loop I-f "
            f"start, 0 to {w_on / ls.w_base:.3g} p.u. (handover; back below "
            f"{w_off / ls.w_base:.3g} p.u.: design/startup.py){limit}"
        )
    data = {**rep.data, "low_speed": {**ls.data(), "headline": line, "startup": start}}
    if isinstance(data.get("verdict"), dict):
        data["verdict"] = {**data["verdict"], "low_speed": line}
    lines = rep.verdict.lines
    extra = (Paragraph(line[0].upper() + line[1:] + "."), *((Paragraph(start + "."),) if start else ()))
    verdict = dataclasses.replace(rep.verdict, lines=(*lines[:1], *extra, *lines[1:]))
    sec = section(len(rep.sections) + 1, ls, drive, rep.review)
    return dataclasses.replace(rep, data=data, verdict=verdict, sections=(*rep.sections, sec))


def tune_line(drive: Drive, gains: GainSet, min_damping: float) -> str:
    """The tune summary's line (the tuned gains, the grid of ``report --quick``), or "" where the family
    has no linearization."""
    try:
        ls = minimum_speed(drive, gains, min_damping=min_damping, max_bias=np.radians(MAX_BIAS_DEG), **QUICK)
        return headline(ls)
    except CapabilityError:
        return ""
