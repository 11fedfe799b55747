"""Stability report of the reduced-order observer: its poles over speed x load for g, Gamma, and time checks.

De Angelo et al. (2006): the observer's error-dynamics poles, continuous and of the discrete observer at
the real sampling period, with and without load-torque estimation, over the drive's envelope; the
steady errors; the paper's experiments re-run (Figs. 3 and 5(b)); and a verdict.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.pmac_reduced_order import FAMILY
from sensorless.design.poles import MIN_DAMPING
from sensorless.reports import time_domain
from sensorless.reports.document import (
    Figure,
    Paragraph,
    Report,
    Section,
    Table,
    Verdict,
    drive_section,
    f,
    num,
    svg_uri,
)
from sensorless.reports.review import (
    gains_under_review,
    opening,
    settle,
    status_class,
    time_domain_checks,
    verdict_box,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

TIME_DOMAIN = ("fig3", "fig5b")


def _pole_list(p: np.ndarray) -> list[list[Any]]:
    return [[f(z.real), f(z.imag)] for z in p]


def compute(
    drive: PmacDrive,
    table: Any | None = None,
    table_file: str = "",
    min_damping: float = MIN_DAMPING,
    resolution: str = "normal",
    progress: Callable[[str], None] = lambda s: None,
    scenarios: Sequence[str] = (),
) -> Report:
    """All numbers, figures and sections of the report; ``scenarios``: the user's scenario files."""
    from sensorless.reports.pmac_reduced_order.figures import plot_poles

    env = drive.envelope
    rpm = np.array(env.rule.listed, float)  # the file's speeds [r/min] and loads, in its order
    loads = np.array(env.torque_values, float)
    w = drive.rpm_to_w(rpm)
    rev = gains_under_review(FAMILY, drive, table, table_file, "paper gains")
    choices, review = rev.choices, rev.label
    data: dict[str, Any] = {
        **opening(FAMILY, drive, table, min_damping, review),
        "sampling_period_s": f(drive.control.T_s),
        "discretization": drive.control.discretization,
    }
    figs: list[Figure] = []
    progress(f"[1/3] observer poles over the envelope ({rpm.size} speeds x {loads.size} loads)")
    analysis: dict[str, Any] = {}
    for label, gains in choices.items():
        results = {}
        for le in (True, False):
            r = FAMILY.linearize(drive, gains, w[:, None], loads[None, :], load_estimation=le)
            key = f"{label}, {'with' if le else 'without'} T_L estimation"
            results[key] = r
            zc, zd = r.damping.min(axis=1), r.damping_discrete.min(axis=1)
            dc, dd = -r.poles.real.max(axis=1), -r.poles_discrete.real.max(axis=1)
            k = int(np.argmin(dd))
            analysis[key] = {
                "g": f(gains.values["g"]),
                "Gamma": f(gains.values["Gamma"] if le else 0.0),
                "points": [
                    {
                        "speed_rpm": f(drive.w_to_rpm(r.w[j])),
                        "T_L_Nm": f(r.T_L[j]),
                        "poles_c": _pole_list(r.poles[j]),
                        "poles_d": _pole_list(r.poles_discrete[j]),
                        "damping_c": f(zc[j]),
                        "damping_d": f(zd[j]),
                        "decay_c": f(dc[j]),
                        "decay_d": f(dd[j]),
                        "err_w_rad_s": f(r.err_w[j]),
                        "err_T_Nm": f(r.err_T[j]),
                    }
                    for j in range(r.w.size)
                ],
                "worst_discrete": {
                    "speed_rpm": f(drive.w_to_rpm(r.w[k])),
                    "T_L_Nm": f(r.T_L[k]),
                    "decay_rate": f(dd[k]),
                    "damping": f(zd.min()),
                },
                "max_abs_err_T_Nm": f(np.max(np.abs(r.err_T))) if le else None,
            }
        figs.append(
            Figure(
                svg_uri(
                    plot_poles(
                        results, drive, f"{drive.name}: observer poles ({label}), continuous o, discrete x"
                    )
                ),
                "Real parts of the observer error-dynamics poles over speed, continuous time (o) and the "
                "discrete observer at the sampling period, ln(z)/T_s (x), with and without load-torque "
                "estimation; middle and bottom: the discrete observer's steady speed and load-torque errors. "
                "Colours: load torque.",
            )
        )
    data["analysis"] = analysis
    runs = time_domain.scenarios(drive, TIME_DOMAIN, scenarios)
    progress(f"[2/3] time-domain checks ({len(runs)} scenarios)")
    td, td_figs = time_domain_checks(drive, rev, runs, progress)
    data["time_domain"] = td
    progress("[3/3] verdict")
    key = f"{review}, with T_L estimation"
    a = analysis[key]
    stable = all(p["decay_d"] is not None and p["decay_d"] > 0 for p in a["points"])
    damped = all(p["damping_d"] is not None and p["damping_d"] >= min_damping for p in a["points"])
    biased = [p for p in a["points"] if p["err_T_Nm"] is not None and abs(p["err_T_Nm"]) > 1.0]
    reasons = []
    if biased:
        worst = max(biased, key=lambda p: abs(p["err_T_Nm"]))
        reasons.append(
            f"steady load-torque estimation bias up to {worst['err_T_Nm']:.3g} N m at "
            f"{worst['speed_rpm']:g} r/min: at this speed the EMF harmonics approach the Nyquist "
            f"frequency of T_s = {drive.control.T_s * 1e6:g} us (docs/families/pmac_reduced_order.md); "
            "sample faster there"
        )
    status, td_findings = settle("fail" if not (stable and damped) else "warn" if biased else "pass", td)
    reasons += [x["text"] for x in td_findings]
    data["verdict"] = {
        "status": status,
        "findings": td_findings,
        "gains": key,
        "min_damping": min_damping,
        "stable": stable,
        "damped": damped,
        "worst_discrete": a["worst_discrete"],
        "reasons": reasons,
        "biased_points": [[p["speed_rpm"], p["T_L_Nm"]] for p in biased],
        "limitations": time_domain.limitations(drive),  # what the generic checks leave out
    }
    rows = []
    for k_, a_ in analysis.items():
        wd = a_["worst_discrete"]
        rows.append(
            (
                k_,
                num(a_["g"]),
                num(a_["Gamma"]),
                num(wd["decay_rate"]),
                f"{num(wd['speed_rpm'])}, {num(wd['T_L_Nm'])}",
                num(a_["max_abs_err_T_Nm"]),
            )
        )
    header = (
        "variant",
        "g (1/s)",
        "Gamma",
        "slowest discrete decay (1/s)",
        "at (r/min, N m)",
        "max |steady T_L error| (N m)",
    )
    sections = (
        drive_section(1, data["drive"]),
        Section(
            "2. Observer poles over speed × load (g, Gamma)",
            (*figs, Table(header, tuple(rows), numeric=frozenset({1, 2, 3, 4, 5}))),
        ),
        time_domain.section(3, td, td_figs, data["verdict"]["limitations"]),
    )
    return Report(drive.name, review, data, _verdict(data), sections)


def _verdict(data: dict[str, Any]) -> Verdict:
    v = data["verdict"]
    wd = v["worst_discrete"]
    text = (
        f"Gains {v['gains']}: discrete-time observer at T_s = {data['sampling_period_s'] * 1e6:g} us "
        f"({data['discretization']}) {'stable' if v['stable'] else 'NOT stable'} over the envelope; damping "
        f"{'meets' if v['damped'] else 'does not meet'} {v['min_damping']:g} everywhere. "
        "Slowest discrete mode: "
        f"decay {num(wd['decay_rate'], 4)} 1/s at {num(wd['speed_rpm'])} r/min, {num(wd['T_L_Nm'])} N m."
    )
    summary = Paragraph(text, status_class(v["status"]))
    return verdict_box(v["status"], summary, v["reasons"], v["limitations"], reason_class="bad")
