"""How the reduced-order observer judges its gains on the shared report frame (reports/envelope_review.py).

De Angelo et al. (2006): the observer's error-dynamics poles, continuous and of the discrete observer at
the real sampling period, with and without load-torque estimation, over the drive's envelope; the
steady errors; the paper's experiments re-run (Figs. 3 and 5(b)); and a verdict. The frame (gains under
review, opening data, time-domain checks, the verdict's status with them) is the shared one; what is
this family's is its analysis over the file's speeds and loads and its verdict's form (the bias of the
load-torque estimate as a reason).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.design.pmac_reduced_order import FAMILY
from sensorless.reports import drive_range
from sensorless.reports.causes import CATALOGUE
from sensorless.reports.document import Figure, Paragraph, Section, Table, Verdict, f, num
from sensorless.reports.drive_range import Remedy
from sensorless.reports.envelope_review import Analysis, Checks, Judgement, Judging, report_with
from sensorless.reports.review import Review, gains_under_review, status_class, verdict_box
from sensorless.reports.svg_render import svg_later
from sensorless.reports.time_domain import Finding

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

TIME_DOMAIN = ("fig3", "fig5b")


def _pole_list(p: np.ndarray) -> list[list[Any]]:
    return [[f(z.real), f(z.imag)] for z in p]


class PmacJudge(Judging["PmacDrive"]):
    """The family's :class:`~sensorless.reports.envelope_review.Judge` (module docstring)."""

    def review(self, drive: PmacDrive, table: GainTable | None, table_file: str) -> Review:
        return gains_under_review(FAMILY, drive, table, table_file, "paper gains")

    time_domain = TIME_DOMAIN
    # over the drive's range (reports/drive_range.py), where the sampled drive loses its operating point
    # at high speed, the points a shorter sampling period holds are put down to the sampling period
    # (tests/pmac_reduced_order/test_drive_range.py)

    def range_remedy(
        self, drive: PmacDrive, gains: GainSet, held: np.ndarray, lost: np.ndarray
    ) -> Remedy | None:
        """The sampling period that holds the highest speed lost, where every lost speed is above a held
        one: the speed at which the whole drive loses its operating point moves with w^2 T_s = const
        (measured on deangelo2006 over +-T_N: lost from 0.6 p.u. at 180 us, 0.85 p.u. at 90 us, 1 p.u. at
        60 us, none at 45 us), so T_s x (the highest speed held below the losses / the highest lost)^2."""
        below = held[held < lost.min()] if lost.size else held
        if not lost.size or not below.size:
            return None
        T_s = float(f"{drive.T_s * (below.max() / lost.max()) ** 2:.3g}")
        shorter = dataclasses.replace(drive, control=dataclasses.replace(drive.control, T_s=T_s))
        wb = drive.w_base
        why = (
            f"{CATALOGUE['sampling_period'].title}: with T_s = {drive.T_s * 1e6:.4g} us the whole sampled "
            f"drive holds |w| <= {below.max() / wb:.3g} p.u. and loses its operating point from "
            f"{lost.min() / wb:.3g} p.u. (w^2 T_s about constant where it is lost); to do: [control] T_s = "
            f"{T_s * 1e6:.3g} us, or keep the drive below {lost.min() / wb:.3g} p.u."
        )
        return drive_range.Remedy("sampling_period", why, gains, shorter)

    def analyse(
        self,
        drive: PmacDrive,
        rev: Review,
        min_damping: float,
        resolution: str,
        progress: Callable[[str], None],
    ) -> Analysis:
        """The poles, continuous and discrete, with and without load-torque estimation, at the drive
        file's speeds x loads in its order, per gain set."""
        from sensorless.reports.pmac_reduced_order.figures import plot_poles

        env = drive.envelope
        rpm = np.array(env.rule.listed, float)  # the file's speeds [r/min] and loads, in its order
        loads = np.array(env.torque_values, float)
        w = drive.rpm_to_w(rpm)
        figs: list[Figure] = []
        progress(f"[1/3] observer poles over the envelope ({rpm.size} speeds x {loads.size} loads)")
        analysis: dict[str, Any] = {}
        for label, gains in rev.choices.items():
            results = {}
            for le in (True, False):
                r = FAMILY.linearize(drive, gains, w[:, None], loads[None, :], load_estimation=le)
                key = f"{label}, {'with' if le else 'without'} T_L estimation"
                results[key] = r
                analysis[key] = _summary(
                    drive, r, gains.values["g"], gains.values["Gamma"] if le else 0.0, le
                )
            figs.append(
                Figure(
                    svg_later(
                        functools.partial(
                            plot_poles,
                            results,
                            drive,
                            f"{drive.name}: observer poles ({label}), continuous o, discrete x",
                        )
                    ),
                    "Real parts of the observer error-dynamics poles over speed, continuous time (o) and the "
                    "discrete observer at the sampling period, ln(z)/T_s (x), with and without load-torque "
                    "estimation; middle and bottom: the discrete observer's steady speed and load-torque "
                    "errors. Colours: load torque.",
                )
            )
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
        section = Section(
            "2. Observer poles over speed × load (g, Gamma)",
            (*figs, Table(header, tuple(rows), numeric=frozenset({1, 2, 3, 4, 5}))),
        )
        data = {"sampling_period_s": f(drive.control.T_s), "discretization": drive.control.discretization}
        return Analysis(analysis, (section,), data)

    def verdict(
        self, drive: PmacDrive, rev: Review, found: Analysis, checks: Checks, min_damping: float
    ) -> Judgement:
        """Stable and damped over the envelope with load-torque estimation (the discrete observer), and
        where the steady load-torque estimate is biased by more than 1 N m, why."""
        key = f"{rev.label}, with T_L estimation"
        a = (found.analysis or {})[key]
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
        wd = a["worst_discrete"]
        text = (
            f"Gains {key}: discrete-time observer at T_s = {found.data['sampling_period_s'] * 1e6:g} us "
            f"({found.data['discretization']}) {'stable' if stable else 'NOT stable'} over the envelope; "
            f"damping {'meets' if damped else 'does not meet'} {min_damping:g} everywhere. "
            "Slowest discrete mode: "
            f"decay {num(wd['decay_rate'], 4)} 1/s at {num(wd['speed_rpm'])} r/min, {num(wd['T_L_Nm'])} N m."
        )
        status = "fail" if not (stable and damped) else "warn" if biased else "pass"
        data = {
            "gains": key,
            "min_damping": min_damping,
            "stable": stable,
            "damped": damped,
            "worst_discrete": wd,
            "reasons": reasons,
            "biased_points": [[p["speed_rpm"], p["T_L_Nm"]] for p in biased],
        }
        return Judgement(status, [], text, data=data)

    def conclude(
        self, v: Judgement, status: str, td_findings: list[Finding], limits: list[str]
    ) -> tuple[dict[str, Any], Verdict]:
        """Its form: the time-domain checks' findings as records, their text among the reasons, shown
        as reasons in the box."""
        reasons = [*v.data["reasons"], *(x["text"] for x in td_findings)]
        data = {
            "status": status,
            **v.data,
            "findings": td_findings,
            "reasons": reasons,
            "limitations": limits,
        }
        summary = Paragraph(v.text, status_class(status))
        return data, verdict_box(status, summary, reasons, limits, reason_class="bad")


def _summary(drive: PmacDrive, r: Any, g: float, Gamma: float, load_estimation: bool) -> dict[str, Any]:
    """report.json "analysis" of one variant: every point's poles, damping, decay and steady errors,
    and its slowest discrete mode."""
    zc, zd = r.damping.min(axis=1), r.damping_discrete.min(axis=1)
    dc, dd = -r.poles.real.max(axis=1), -r.poles_discrete.real.max(axis=1)
    k = int(np.argmin(dd))
    return {
        "g": f(g),
        "Gamma": f(Gamma),
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
        "max_abs_err_T_Nm": f(np.max(np.abs(r.err_T))) if load_estimation else None,
    }


JUDGE = PmacJudge()
compute = report_with(JUDGE)
