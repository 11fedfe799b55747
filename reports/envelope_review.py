"""The ``analyze`` output and the stability report of any family from its linearization over its envelope.

A family that has a linearization (``ObserverFamily.linearize``) gets both by naming them in its report
hooks (``ReportHooks(analyze=analyze, report=report)``) and declares nothing more. The operating
points are the drive's envelope (design/envelope.py ``Envelope``, the one record tune and Monte-Carlo
read too): its speeds, refined in speed, times its torques. The poles are the linearization's
continuous ones and, where it has them, the sampled
observer's ln(z)/T_s, which the figures of merit then take (what runs is the sampled observer).

- :func:`analyze`: a summary per torque on the terminal, ``poles.csv`` (and ``poles_discrete.csv``)
  by reports/pole_map.py with the family's own per-point columns, and a figure of the poles' real
  parts and the worst damping over speed;
- :func:`report`: the frame of reports/review.py (gains under review, opening data, time-domain
  checks of the family's built-in or the generic scenarios, verdict) around one section of poles over
  the envelope per gain set: stable, worst damping against the required, slowest decay and where.

A family that judges its gains by a criterion of its own keeps this frame and gives a :class:`Judge`
(``report_with(judge)``, ``analyze_with(judge)``): its envelope's points, the gain sets it reviews, its
sections and figures of the analysis (before the time-domain checks and after them), its verdict's
status and findings, and the form its verdict takes in report.json and the verdict box (the shared
form, :func:`conclude`, or the family's own); the frame does the rest (gains under review, opening data,
the time-domain checks of its scenarios, the verdict's status with those checks, the sections' order,
report.json). :data:`POLES` is the judge of the poles alone, the default.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import numpy as np
from sensorless.design.envelope import Envelope, Enveloped, EnvelopedT
from sensorless.design.family import Drive, DriveT, GainSet, Linearizable, require
from sensorless.design.gain_table import GainTable, read_gain_table
from sensorless.design.linearization import Linearization
from sensorless.design.poles import MIN_DAMPING
from sensorless.design.registry import family_of
from sensorless.design.scenario import Scenario, builtin_names
from sensorless.reports import drive_range, time_domain
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
)
from sensorless.reports.drive_range import Remedy
from sensorless.reports.figure_layout import lay_out
from sensorless.reports.files import OutputSet
from sensorless.reports.pole_map import pole_csv
from sensorless.reports.review import Review, gains_under_review, opening, settle, status_class, verdict_box
from sensorless.reports.svg_render import polling, svg_later
from sensorless.reports.time_domain import Check, Finding

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure

J = TypeVar("J", bound=Drive, contravariant=True)  # the drive a judge takes: its family's
ANALYZE_REFINE = 4  # analyze and the normal report refine the envelope's speeds this many times


def envelope(drive: Enveloped) -> Envelope:
    """The envelope of the drive (design/envelope.py: the one analyze, tune, report and Monte-Carlo
    read)."""
    return drive.envelope


def points(drive: Enveloped, refine: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Flat (speed [rad/s], torque [N m]) of the envelope's speeds (refined) x its torques."""
    return envelope(drive).grid(refine)


@dataclass(frozen=True)
class Analysis:
    """What a judge found over the envelope, before the time-domain checks."""

    analysis: dict[str, Any] | None  # report.json "analysis": per gain set label (None: no such key)
    sections: tuple[Section, ...]  # the report's sections between the drive data and the time-domain checks
    data: dict[str, Any] = field(default_factory=dict)  # more report.json keys
    context: Any = None  # what the judge's verdict needs of it
    later: tuple[Section, ...] = ()  # the report's sections after the time-domain checks
    steps: int = 1  # the progress steps the analysis took (the time-domain checks and verdict follow)


@dataclass(frozen=True)
class Checks:
    """The time-domain checks a verdict reads: the scenarios run and each one's judged result
    (reports/time_domain.py ``checks``)."""

    runs: Sequence[Scenario | str]  # the scenarios (built-in names or the user's files)
    td: Sequence[Check]  # report.json "time_domain": one entry per scenario


@dataclass(frozen=True)
class Judgement:
    """A judge's verdict before the time-domain checks' own findings (reports/review.py ``settle``)."""

    status: str  # pass | warn | fail
    findings: list[Any]  # before the time-domain checks' findings (text; records in a family's own form)
    text: str  # the verdict's paragraph
    after: list[str] = field(default_factory=list)  # findings after the time-domain checks'
    data: dict[str, Any] = field(default_factory=dict)  # more report.json "verdict" keys
    more: dict[str, Any] = field(default_factory=dict)  # more report.json keys


class Judge(Protocol[J]):
    """How a family judges its gains over its envelope on the shared frame (module docstring)."""

    def points(self, drive: J, refine: int) -> tuple[np.ndarray, np.ndarray]:
        """Flat (speed [rad/s], torque [N m]) of the envelope, speeds refined ``refine`` times."""
        ...

    def review(self, drive: J, table: GainTable | None, table_file: str) -> Review:
        """The gain sets reviewed and the one under review (reports/review.py ``gains_under_review``:
        with a gain ``table``, the table's)."""
        ...

    def notes(self, drive: J) -> tuple[str, ...]:
        """Lines ``analyze`` prints of the drive's own settings under the gains (e.g. its variant)."""
        ...

    def scenarios(self, drive: J) -> Sequence[str]:
        """The built-in scenarios the report checks in the time domain."""
        ...

    def range_remedy(self, drive: J, gains: GainSet, held: np.ndarray, lost: np.ndarray) -> Remedy | None:
        """The family's named cause of instability over the range with its change (reports/drive_range.py
        ``Remedy``), given |w| [rad/s] of the stable points and of the unstable ones; None: the shared
        cause (``rhp_band``)."""
        ...

    def analyse(
        self, drive: J, rev: Review, min_damping: float, resolution: str, progress: Callable[[str], None]
    ) -> Analysis:
        """The gain sets judged over the envelope: report.json data and sections."""
        ...

    def verdict(
        self, drive: J, rev: Review, found: Analysis, checks: Checks, min_damping: float
    ) -> Judgement:
        """The status and findings of the analysis, with the time-domain ``checks``."""
        ...

    def conclude(
        self, v: Judgement, status: str, td_findings: list[Finding], limits: list[str]
    ) -> tuple[dict[str, Any], Verdict]:
        """report.json "verdict" and the verdict box of the judgement ``v`` settled with the time-domain
        checks (``status``, their findings ``td_findings``) and what the checks leave out (``limits``)."""
        ...


def conclude(
    v: Judgement, status: str, td_findings: list[Finding], limits: list[str]
) -> tuple[dict[str, Any], Verdict]:
    """The shared form of a verdict: its findings as text (the judgement's, the time-domain checks', the
    judgement's after them), its paragraph, the limitations as notes."""
    findings = [*v.findings, *(x["text"] for x in td_findings), *v.after]
    data = {"status": status, **v.data, "findings": findings, "limitations": limits}
    box = verdict_box(status, Paragraph(v.text, status_class(status)), notes=limits, findings=findings)
    return data, box


def figures(lin: Linearization) -> tuple[np.ndarray, np.ndarray]:
    """(worst damping, decay rate) per point: the sampled observer's where the linearization has it."""
    if lin.poles_discrete is not None:
        return lin.worst_damping_discrete, lin.decay_rate_discrete
    return lin.worst_damping, lin.decay_rate


def poles_figure(lin: Linearization, w_base: float, title: str) -> MplFigure:
    """Real parts of the poles (continuous o, sampled x) and the worst damping over speed, per torque;
    below, the steady angle error where the linearization gives it (``angle_bias``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    bias = lin.angle_bias()
    rows = 2 if bias is None else 3
    fig, axes = plt.subplots(rows, 1, sharex=True, figsize=(6.4, 2.5 * rows))
    a1, a2 = axes[0], axes[1]
    for j, T in enumerate(np.unique(lin.torque)):
        m, c = lin.torque == T, f"C{j}"
        w = lin.w[m] / w_base
        n = lin.poles.shape[1]
        a1.plot(np.repeat(w, n), lin.poles[m].real.ravel(), "o", ms=3, mfc="none", color=c)
        a2.plot(w, lin.worst_damping[m], "--" if lin.poles_discrete is not None else "-", color=c)
        if lin.poles_discrete is not None:
            a1.plot(np.repeat(w, n), lin.poles_discrete[m].real.ravel(), "x", ms=3, color=c)
            a2.plot(w, lin.worst_damping_discrete[m], "-", color=c)
        a2.plot([], [], "-", color=c, label=f"{lin.torque_name} = {T:g} N m")
        if bias is not None:
            axes[2].plot(w, np.degrees(bias[m]), "-", color=c)
    a1.set_ylabel("Re(p) (1/s)")
    a2.set_ylabel("worst damping")
    a2.legend(fontsize=8, frameon=False)
    if bias is not None:
        axes[2].set_ylabel("angle error (deg)")
    axes[-1].set_xlabel("speed (p.u.)")
    for a in axes:
        a.grid(True, lw=0.3, color="0.8")
    lay_out(fig, axes[:, None], title=title, title_size=9, gap=0.15)
    return fig


CAPTION = (
    "Real parts of the observer's poles over speed, continuous observer (o) and, where analysed, the "
    "sampled observer at the drive's sampling period, ln(z)/T_s (x); below, the worst damping "
    "(sampled: solid, continuous: dashed) and, where the family gives it, the observer's steady angle "
    "error at the drive's estimates. Colours: torque."
)


def analyze_with(judge: Judge[DriveT]) -> Callable[[DriveT, argparse.Namespace, OutputSet], None]:
    """The ``analyze`` hook of a family judged by ``judge`` (its envelope's points)."""

    def analyze(drive: DriveT, args: argparse.Namespace, out: OutputSet) -> None:
        """Poles over the envelope (speeds refined ANALYZE_REFINE times): terminal summary, CSV, figure."""
        fam = family_of(drive)
        table = read_gain_table(args.gains) if args.gains else None
        gains = (
            fam.gains(drive, table=table, table_file=args.gains) if table is not None else fam.gains(drive)
        )
        W, T = judge.points(drive, ANALYZE_REFINE)
        lin = require(fam, Linearizable).linearize(drive, gains, W, T)
        sampled = lin.poles_discrete is not None
        print(f"{drive.name}: {drive.source}")
        print(f"{fam.title} ({fam.citation}); gains: {gains.source}")
        print("; ".join(f"{k} = {v:.6g}" for k, v in gains.values.items() if np.ndim(v) == 0))
        for line in judge.notes(drive):
            print(line)
        z, d = figures(lin)
        kind = f"sampled observer at T_s = {lin.T_s:g} s" if sampled else "continuous observer"
        own = np.isclose(lin.w[:, None], np.unique(judge.points(drive, 1)[0])[None, :], rtol=1e-12).any(
            axis=1
        )
        for T_e in np.unique(T):  # at the envelope's own speeds
            print(f"{lin.torque_name} = {T_e:g} N m:")
            print(f"  {'speed [pu]':>10} {'worst damping':>14} {'slowest decay [1/s]':>20}")
            for k in np.flatnonzero((lin.torque == T_e) & own):
                print(f"  {lin.w[k] / drive.w_base:>10.3f} {z[k]:>14.4f} {d[k]:>20.5g}")
        worst = f"damping {np.nanmin(z):.4f}, slowest decay {np.nanmin(d):.4g} 1/s"
        print(f"worst over {lin.w.size} points: {worst} ({kind})")
        out.add_text("poles.csv", pole_csv(lin, drive.w_base))
        lost = ~np.isfinite(lin.poles).all(axis=1)
        if lin.poles_discrete is not None:
            lost |= ~np.isfinite(lin.poles_discrete).all(axis=1)
        if lost.any():  # not a result: every written number finite or said (exit status 3)
            out.warnings.append(
                f"poles.csv: no finite poles at {int(lost.sum())} of {lost.size} operating points (nan in "
                "their rows): no equilibrium found there, or the linearized observer overflows; check the "
                "drive's units and the gains"
            )
        if lin.poles_discrete is not None:
            out.add_text(
                "poles_discrete.csv",
                pole_csv(dataclasses.replace(lin, poles=lin.poles_discrete), drive.w_base),
            )
        fig = poles_figure(lin, drive.w_base, f"{drive.name}: observer poles over the envelope")
        out.add_figures("poles", fig)
        import matplotlib.pyplot as plt

        plt.close(fig)

    return analyze


def summary(lin: Linearization, gains: GainSet, w_base: float) -> dict[str, Any]:
    """The report.json figures of one gain set over the envelope."""
    z, d = figures(lin)
    k = int(np.nanargmin(d)) if np.isfinite(d).any() else 0
    return {
        **{name: f(v) for name, v in gains.values.items() if np.ndim(v) == 0},
        "worst_damping_continuous": f(np.nanmin(lin.worst_damping)),
        "worst_damping": f(np.nanmin(z)),
        "min_decay_rate": f(np.nanmin(d)),
        "slowest_at": {"w_pu": f(lin.w[k] / w_base), f"{lin.torque_name}_Nm": f(lin.torque[k])},
        "stable": bool(np.isfinite(d).all() and (d > 0).all()),
    }


def poles_section_figure(drive: Drive, lin: Linearization, label: str) -> Figure:
    """The report's figure of the poles over the envelope of the gains ``label``."""
    title = f"{drive.name}: poles, gains {label}"
    return Figure(svg_later(functools.partial(poles_figure, lin, drive.w_base, title)), CAPTION)


class Judging(Generic[EnvelopedT]):
    """What most judges share, to subclass: the envelope's points, the drive file's gains under review
    (or a table's), no notes, the family's built-in scenarios, the shared form of the verdict. Generic
    in the drive type: ``class MyJudge(Judging[MyDrive])``."""

    def points(self, drive: EnvelopedT, refine: int) -> tuple[np.ndarray, np.ndarray]:
        return points(drive, refine)

    def review(self, drive: EnvelopedT, table: GainTable | None, table_file: str) -> Review:
        return gains_under_review(family_of(drive), drive, table, table_file)

    def notes(self, drive: EnvelopedT) -> tuple[str, ...]:
        return ()

    time_domain: tuple[str, ...] | None = None  # the built-in scenarios checked; None: all the family's

    def scenarios(self, drive: EnvelopedT) -> Sequence[str]:
        return builtin_names(drive.kind) if self.time_domain is None else self.time_domain

    def range_remedy(
        self, drive: EnvelopedT, gains: GainSet, held: np.ndarray, lost: np.ndarray
    ) -> Remedy | None:
        return None

    def conclude(
        self, v: Judgement, status: str, td_findings: list[Finding], limits: list[str]
    ) -> tuple[dict[str, Any], Verdict]:
        return conclude(v, status, td_findings, limits)


class PolesJudge(Judging[Enveloped]):
    """The judge of the poles alone: every gain set linearized over the shared envelope, stable and
    damped as required (the module docstring's report)."""

    def analyse(
        self,
        drive: Enveloped,
        rev: Review,
        min_damping: float,
        resolution: str,
        progress: Callable[[str], None],
    ) -> Analysis:
        fam = family_of(drive)
        W, T = self.points(drive, 1 if resolution == "quick" else ANALYZE_REFINE)
        progress(f"[1/3] poles over the envelope ({W.size} points)")
        lins = {
            label: require(fam, Linearizable).linearize(drive, g, W, T) for label, g in rev.choices.items()
        }
        analysis = {label: summary(lin, rev.choices[label], drive.w_base) for label, lin in lins.items()}
        torque_key = f"{lins[rev.label].torque_name}_Nm"
        rows = tuple(
            (
                label,
                "yes" if x["stable"] else "NO",
                num(x["worst_damping"]),
                num(x["min_decay_rate"]),
                f"{num(x['slowest_at']['w_pu'])}, {num(x['slowest_at'][torque_key])}",
            )
            for label, x in analysis.items()
        )
        header = ("gains", "stable", "worst damping", "slowest decay (1/s)", "at (p.u., N m)")
        fig = poles_section_figure(drive, lins[rev.label], rev.label)
        table = Table(header, rows, "", frozenset({2, 3}))
        section = Section("2. Observer poles over the envelope", (fig, table))
        return Analysis(analysis, (section,), {"sampling_period_s": f(drive.T_s)})

    def verdict(
        self, drive: Enveloped, rev: Review, found: Analysis, checks: Checks, min_damping: float
    ) -> Judgement:
        a = (found.analysis or {})[rev.label]
        damped = a["worst_damping"] is not None and a["worst_damping"] >= min_damping
        status = "fail" if not a["stable"] else "pass" if damped else "warn"
        findings = [] if damped else [f"worst damping {num(a['worst_damping'])} < required {min_damping:g}"]
        gains_text = ", ".join(f"{k} = {num(v)}" for k, v in a.items() if k in rev.gains.values)
        text = (
            f"Gains {rev.label} ({gains_text}): the observer is {'stable' if a['stable'] else 'NOT stable'} "
            f"over the envelope, worst damping {num(a['worst_damping'])} (required {min_damping:g}), slowest "
            f"decay {num(a['min_decay_rate'])} 1/s."
        )
        return Judgement(status, findings, text, data={"damped": damped})


POLES = PolesJudge()


def report_with(judge: Judge[DriveT]) -> Callable[..., Report]:
    """The ``report`` hook of a family judged by ``judge``: the stability report on the shared frame."""

    def report(
        drive: DriveT,
        table: GainTable | None = None,
        table_file: str = "",
        min_damping: float = MIN_DAMPING,
        resolution: str = "normal",
        progress: Callable[[str], None] = lambda s: None,
        scenarios: Sequence[str] = (),
    ) -> Report:
        """The stability report (module docstring); ``scenarios``: the user's scenario files, checked
        in the time domain besides the judge's built-in ones (reports/time_domain.py)."""
        fam = family_of(drive)
        progress = polling(progress)  # a queued figure goes to a child free by then (svg_render.py)
        rev = judge.review(drive, table, table_file)
        runs = time_domain.scenarios(drive, judge.scenarios(drive), scenarios)
        # the checks first, though their section comes later: their figures take longer to draw than
        # the runs to simulate (or to read back from ``tune``'s proof, design/simulate.py ``simulated``),
        # and the child processes that draw them (reports/svg_render.py) then run beside the analyses
        # instead of after them
        progress(f"time-domain checks first ({len(runs)} scenarios; their figures drawn beside the analyses)")
        td, td_figs = time_domain.checks(drive, rev.simulated, runs, rev.label, progress)
        found = judge.analyse(drive, rev, min_damping, resolution, progress)
        k = found.steps + 1
        progress(f"[{k}/{k + 1}] time-domain checks ({len(runs)} scenarios): done first, above")
        progress(f"[{k + 1}/{k + 1}] verdict")
        limits = time_domain.limitations(drive)
        v = judge.verdict(drive, rev, found, Checks(runs, td), min_damping)
        status, td_findings = settle(v.status, td)
        ranged: dict[str, object] = {}
        # the range tune proves on, judged by the same rule (reports/drive_range.py): one envelope, one
        # answer, for every family with scales (the range is defined by them)
        if drive_range.range_envelope(drive) is not None:
            rj = drive_range.judge(
                drive, rev.gains, min_damping, lambda *w: judge.range_remedy(drive, rev.gains, *w)
            )
            status = time_domain.worst_status(status, rj.status)
            td_findings = [*rj.findings, *td_findings]
            ranged = {"drive_range": {"status": rj.status, **rj.data}}
        verdict, box = judge.conclude(v, status, td_findings, limits)
        analysis = {} if found.analysis is None else {"analysis": found.analysis}
        data = {
            **opening(fam, drive, table, min_damping, rev.label),
            **found.data,
            **analysis,
            "time_domain": td,
            **ranged,
            **v.more,
            # limitations: what the generic checks leave out (e.g. an ODrive drive's zero speed)
            "verdict": verdict,
        }
        n = len(found.sections) + 2
        sections = (
            drive_section(1, data["drive"], fam.bases(drive)),
            *found.sections,
            time_domain.section(n, td, td_figs, limits),
            *found.later,
        )
        return Report(drive.name, rev.label, data, box, sections)

    return report


analyze = analyze_with(POLES)
report = report_with(POLES)
