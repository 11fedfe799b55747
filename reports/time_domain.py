"""Time-domain checks of a report: built-in scenarios re-run with the gains under review, and their metrics.

Shared by every family with a simulation (design/simulate.py): each scenario is simulated with the
gains under review; the metrics are the position error (RMS, peak) and the speed error (peak, final),
and the figure is the scenario's own. A run that does not hold (traces not finite, rotor position
lost: design/simulate.Traces.problems) is said so in its entry (``problems``), in the section, and by
``sensorless report`` (a warning, exit status 3).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.scenario import load_scenario
from sensorless.design.simulate import simulate
from sensorless.reports.document import Figure, Paragraph, Section, Table, f, num, svg_uri


def checks(
    drive: Any, gains: GainSet | None, names: Sequence[str], label: str, progress: Callable[[str], None]
) -> tuple[dict[str, Any], list[Figure]]:
    """Run the scenarios ``names`` with ``gains`` (None: each scenario's own choice); (data, figures)."""
    from sensorless.reports.sim_figure import plot_traces

    data: dict[str, Any] = {}
    figs: list[Figure] = []
    for name in names:
        sc = load_scenario(name, drive)
        progress(f"      simulating {name}: {sc.title}")
        tr = simulate(drive, sc, gains)
        m: dict[str, Any] = {"duration_s": f(tr.t[-1]), "samples": int(tr.t.size)}
        if "theta_err" in tr.data:
            th = np.asarray(tr["theta_err"])
            m["rms_theta_err_deg"] = f(np.degrees(np.sqrt(np.mean(th**2))))
            m["max_abs_theta_err_deg"] = f(np.degrees(np.max(np.abs(th))))
        if "w_m" in tr.data and "w_hat" in tr.data:
            e = np.asarray(tr["w_m"]) - np.asarray(tr["w_hat"])
            m["max_abs_speed_err_rad_s"] = f(np.max(np.abs(e)))
            m["final_speed_err_rad_s"] = f(np.mean(e[-max(1, e.size // 20) :]))
        cap = f"{sc.title} ({sc.source}), re-run with the gains under review ({label})."
        problems = tr.problems()
        if problems:
            cap += " " + " ".join(f"{p[0].upper()}{p[1:]}." for p in problems)
        data[name] = {"title": sc.title, "caption": cap, "metrics": m, "problems": problems}
        figs.append(Figure(svg_uri(plot_traces(tr, sc.figure, f"{drive.name}: {sc.title}")), cap))
    return data, figs


def section(number: int, td: dict[str, Any], figs: list[Figure]) -> Section:
    """The report section of the checks."""
    title = f"{number}. Time-domain checks"
    if not td:
        return Section(title, (Paragraph("No time-domain simulation results are included in this report."),))
    rows = []
    for key, item in td.items():
        m = item["metrics"]
        rows.append(
            (
                f"{key}: {item['title']}",
                num(m["duration_s"]),
                num(m.get("rms_theta_err_deg")),
                num(m.get("max_abs_theta_err_deg")),
                num(m.get("max_abs_speed_err_rad_s")),
                num(m.get("final_speed_err_rad_s")),
            )
        )
    header = (
        "scenario",
        "simulated (s)",
        "RMS position error (deg)",
        "max |position error| (deg)",
        "max |speed error| (rad/s)",
        "final speed error (rad/s)",
    )
    return Section(title, (Table(header, tuple(rows), numeric=frozenset({1, 2, 3, 4, 5})), *figs))
