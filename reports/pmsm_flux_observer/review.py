"""How the flux-observer family judges its gains on the shared report frame (reports/envelope_review.py).

The gains under review beside the firmwares' defaults on this motor (ODrive's, VESC Tool's detection),
each judged by the tuning criterion (tuning/pmsm_flux_observer: damping, angle bias, the speed below
which it loses the motor, the observer's decay and the PLL's slow root) under every estimate error; the
shared poles figure over its envelope and the angle bias under each estimate error; its built-in
scenario re-run; the verdict with the drive's I-f start judged at the gains (design/startup_check.py)
and where its firmware cannot run a failed check. The box clamp has no linearization: judged by
simulation alone.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.design.pmsm_flux_observer import FAMILY
from sensorless.reports import drive_range
from sensorless.reports.document import Figure, Paragraph, Section, Table, f, num
from sensorless.reports.drive_range import Remedy
from sensorless.reports.envelope_review import (
    Analysis,
    Checks,
    Judgement,
    Judging,
    analyze_with,
    poles_section_figure,
    report_with,
)
from sensorless.reports.pmsm_flux_observer.figures import bias_caption, bias_curves, bias_figure, front_figure
from sensorless.reports.pmsm_flux_observer.findings import (
    damping_finding,
    holds_nowhere_finding,
    pll_finding,
    pll_fixed,
)
from sensorless.reports.pmsm_flux_observer.startup import reversal_finding, startup_findings
from sensorless.reports.review import Review, gains_under_review
from sensorless.reports.svg_render import svg_later
from sensorless.tuning.pmsm_flux_observer import (
    FluxTuneSettings,
    assess_any,
    figures,
    hold_speed,
    judged,
    odrive_defaults,
    shortfalls,
    vesc_detection,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

TIME_DOMAIN = ("torque_steps",)
MAX_RMS_THETA_DEG = 10.0
DEFAULTS = ("ODrive defaults", "VESC detection")


@dataclass(frozen=True)
class Found:
    """What the verdict needs of the analysis (``Analysis.context``)."""

    linearizable: bool
    settings: FluxTuneSettings
    assessment: Any  # tuning/pmsm_flux_observer Assessment of the gain sets, None without linearization
    labels: tuple[str, ...]


class FluxJudge(Judging["FluxObserverDrive"]):
    """The family's :class:`~sensorless.reports.envelope_review.Judge` (module docstring)."""

    def review(self, drive: FluxObserverDrive, table: GainTable | None, table_file: str) -> Review:
        mine = FAMILY.gains(drive)
        choices = {DEFAULTS[0]: odrive_defaults(), DEFAULTS[1]: vesc_detection(drive), "drive file": mine}
        return gains_under_review(FAMILY, drive, table, table_file, choices=choices)

    def notes(self, drive: FluxObserverDrive) -> tuple[str, ...]:
        o = drive.observer
        T_us = o.T_obs * 1e6
        return (f"{o.firmware}: {o.correction}, {o.inductance_rule} inductance; T_obs = {T_us:g} us",)

    time_domain = TIME_DOMAIN
    # over the drive's range (reports/drive_range.py), where the PLL's slower root is slower than the
    # speed loop closing on its speed needs, the whole drive oscillates
    # (hubmotor48 with VESC's PLL defaults: a 12-Hz limit cycle at 0.8 p.u., simulated): those points
    # are put down to the PLL root, with its change (tests/pmsm_flux_observer/test_drive_range.py)

    def range_remedy(
        self, drive: FluxObserverDrive, gains: GainSet, held: np.ndarray, lost: np.ndarray
    ) -> Remedy | None:
        why = pll_finding(gains, drive.control.alpha_s, [])
        fixed = pll_fixed(gains, drive.control.alpha_s)
        return None if not why or fixed is None else drive_range.Remedy("pll_root", why, fixed)

    def analyse(
        self,
        drive: FluxObserverDrive,
        rev: Review,
        min_damping: float,
        resolution: str,
        progress: Callable[[str], None],
    ) -> Analysis:
        settings = FluxTuneSettings()
        data = {"observer_period_s": f(drive.observer.T_obs)}
        labels = tuple(rev.choices)
        if drive.observer.correction == "box-clamp":
            text = "The box-clamp observer (MXLEMMING) is not linearizable: it is judged by simulation."
            section = Section("2. No linearization", (Paragraph(text),))
            return Analysis({}, (section,), data, Found(False, settings, None, labels))
        progress("[1/3] the gains judged over the envelope under the estimate errors")
        a = assess_any(drive, [rev.choices[k] for k in labels], settings)
        base = {k: figures(drive, a, j) for j, k in enumerate(labels) if k in DEFAULTS}
        w_hold = hold_speed(drive, settings, base)
        analysis: dict[str, Any] = {}
        for j, k in enumerate(labels):
            fg = figures(drive, a, j)
            jd = judged(drive, a, j, settings)
            analysis[k] = {
                "worst_decay_1_s": f(jd["worst_decay_1_s"]) if math.isfinite(jd["worst_decay_1_s"]) else None,
                "pll_root_1_s": f(jd["pll_root_1_s"]),
                # what the gains under review miss of the family's criterion (the others: their row)
                "criterion_shortfalls": shortfalls(drive, rev.choices[k], jd, settings)
                if k == rev.label
                else [],
                "gains": {n: f(v) for n, v in rev.choices[k].values.items() if not isinstance(v, list)},
                "law": rev.choices[k].law,
                "worst_damping": f(fg["worst_damping"]),
                "worst_bias_deg": f(fg["worst_bias_deg"]),
                "low_speed_limit_pu": f(fg["low_speed_limit_pu"])
                if math.isfinite(fg["low_speed_limit_pu"])
                else None,
                "stable_at_top": bool(a.holds[j, -1]),
            }
        rows = tuple(
            (
                k,
                x["law"],
                num(x["worst_damping"]),
                num(x["worst_bias_deg"]),
                num(x["low_speed_limit_pu"]) if x["low_speed_limit_pu"] is not None else "none holds",
                num(x["worst_decay_1_s"]),
                num(x["pll_root_1_s"]),
            )
            for k, x in analysis.items()
        )
        head: tuple[str, ...] = (
            "gains",
            "law",
            "worst damping",
            "worst angle bias (deg)",
            "holds down to (p.u.)",
        )
        head += ("observer decay (1/s)", "PLL slow root (1/s)")
        caption = "each gain set under every estimate error (sampled observer)"
        cmp_table = Table(head, rows, caption, frozenset({2, 3, 4, 5, 6}))
        W, T = self.points(drive, 1 if resolution == "quick" else 2)
        fig = poles_section_figure(drive, FAMILY.linearize(drive, rev.gains, W, T), rev.label)
        curves = bias_curves(drive, rev.gains, settings)  # here: the child only draws
        bias_fig = Figure(svg_later(functools.partial(bias_figure, curves)), bias_caption(settings))
        text = (
            "Judged as the tuner judges (tuning/pmsm_flux_observer): a speed holds when the sampled "
            "observer "
            f"is stable with an angle bias of at most {settings.bias_max_deg:g} deg under every estimate "
            f"error; the firmwares' defaults on this motor hold down to the speeds shown (the better: "
            f"{w_hold / drive.w_base:.3g} p.u.). The family's criterion (tuning/pmsm_flux_observer/"
            "criterion.py) asks the observer's decay from there up to reach the larger of the speed loop's "
            "bandwidth and what the full acceleration asks, and the PLL's slow root 4 x that bandwidth; "
            "damping is not its figure (k/(2|w|) falls with speed by design)."
        )
        items: tuple[Any, ...] = (Paragraph(text), cmp_table)
        table = rev.table
        pf = table.summary.get("pareto") if table is not None else None
        if table is not None and pf is not None and pf.get("metric") == "bias":
            items += (
                Figure(
                    svg_later(functools.partial(front_figure, pf, analysis.get(rev.label, {}))),
                    f"Damping-versus-bias front of the {table.law} law (sensorless tune --pareto): the "
                    "candidates that hold down to the hold speed and that no other beats in both worst "
                    "damping and worst angle bias over the speeds from it up; x: the gains under review.",
                ),
            )
        sections = (
            Section("2. The gains and the firmwares' defaults", items),
            Section("3. Damping and angle error over speed", (fig, bias_fig)),
        )
        return Analysis(analysis, sections, data, Found(True, settings, a, labels))

    def verdict(
        self, drive: FluxObserverDrive, rev: Review, found: Analysis, checks: Checks, min_damping: float
    ) -> Judgement:
        runs, td = checks.runs, checks.td
        ctx: Found = found.context
        linearizable, settings = ctx.linearizable, ctx.settings
        # the closed-loop error (None: a run the observer never had: not tested sensorless, said by its check)
        untested = [item["name"] for item in td if item.get("untested")]
        tracks = all((item["metrics"]["rms_theta_err_deg"] or 0.0) < MAX_RMS_THETA_DEG for item in td)
        mine = (found.analysis or {}).get(rev.label, {})
        damped = not linearizable or (
            mine.get("worst_damping") is not None and mine["worst_damping"] >= min_damping
        )
        stable = not linearizable or mine.get("low_speed_limit_pu") is not None
        pll = pll_finding(rev.gains, drive.control.alpha_s, td)
        start, start_data = startup_findings(drive, rev.gains)
        # the family's criterion (tuning/pmsm_flux_observer/criterion.py) beyond holding somewhere and the
        # PLL (their own findings): holding only at the top speed, the observer's decay
        crit = (
            [
                x
                for x in mine.get("criterion_shortfalls", [])
                if "PLL" not in x and "at no envelope speed" not in x
            ]
            if linearizable and stable
            else []
        )
        clean = damped and tracks and not pll and not crit and not start
        status = "fail" if not stable else "pass" if clean else "warn"
        findings = []
        if linearizable and not stable:
            findings.append(holds_nowhere_finding(drive, rev.gains, settings))
        if not damped:
            j = ctx.labels.index(rev.label)
            findings.append(damping_finding(drive, ctx.assessment, j, min_damping, rev.gains.law))
        findings += crit
        if not tracks:
            findings.append(f"a time-domain check exceeds {MAX_RMS_THETA_DEG:g} deg RMS position error")
        after = []
        if pll and not any("pll_root" in c.get("causes", ()) for c in td):  # else said as a check's cause
            after.append(pll)
        after += start
        after += reversal_finding(drive, runs, td)
        text = (
            f"Gains {rev.label}: "
            + (
                f"worst damping {num(mine.get('worst_damping'))}, worst angle bias "
                f"{num(mine.get('worst_bias_deg'))} deg, "
                f"holds down to {num(mine.get('low_speed_limit_pu'))} p.u. (the lowest envelope speed from "
                f"which it is stable with an angle bias <= {settings.bias_max_deg:g} deg at every error "
                "corner); "
                if linearizable
                else "box clamp (not linearizable); "
            )
            + f"time-domain check {'within' if tracks else 'beyond'} {MAX_RMS_THETA_DEG:g} deg RMS "
            "position error in closed loop"
            + (f" ({len(untested)} not tested sensorless: {', '.join(untested)})." if untested else ".")
        )
        return Judgement(
            status,
            findings,
            text,
            after=after,
            data={"damped": damped, "tracks": tracks},
            more={"startup": start_data},
        )


JUDGE = FluxJudge()
# the family's analyze and report (its hooks, reports/pmsm_flux_observer/__init__.py, name them)
analyze = analyze_with(JUDGE)
report = report_with(JUDGE)
