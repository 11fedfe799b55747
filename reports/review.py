"""What every family's stability report shares: the gains under review, the report's opening data, its
time-domain checks and its verdict box.

A family's report hook (reports/family.py ``ReportHooks.report``) computes its own analysis; the frame
around it is here, once: which gains it compares and which one it reviews (:class:`Review`,
:func:`gains_under_review`: a gain table's when one is given), the data every report.json opens with
(:func:`opening`: inputs and their hashes, the drive-data tables, the label under review), the
time-domain checks of the gains under review (:func:`time_domain_checks`, reports/time_domain.py, each
failure named by its cause: reports/causes.py) and the verdict's status with those checks and its box
(:func:`settle`, :func:`verdict_box`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from sensorless.design.family import Drive, GainSet, ObserverFamily
from sensorless.design.gain_table import GainTable
from sensorless.design.scenario import Scenario
from sensorless.reports import time_domain
from sensorless.reports.document import Figure, Paragraph, Verdict, drive_tables, report_inputs
from sensorless.reports.family import hooks
from sensorless.reports.time_domain import Check, Finding


@dataclass(frozen=True)
class Review:
    """The gains a report compares (label -> gains, in order) and the label of the one under review."""

    choices: dict[str, GainSet]
    label: str
    tuned: bool  # the gains under review are a gain table's
    table: GainTable | None = None  # that gain table, None without

    @property
    def gains(self) -> GainSet:
        """The gains under review."""
        return self.choices[self.label]

    @property
    def simulated(self) -> GainSet | None:
        """The gains the time-domain checks run: a table's, else None (each scenario's own choice)."""
        return self.gains if self.tuned else None


def gains_under_review(
    family: ObserverFamily,
    drive: Drive,
    table: GainTable | None,
    table_file: str,
    label: str = "drive file",
    choices: dict[str, GainSet] | None = None,
) -> Review:
    """The drive file's gains (``choices``, default its one gain set as ``label``) and, with a gain
    ``table``, the table's as "tuned"; the last one is under review."""
    choices = dict(choices) if choices is not None else {label: family.gains(drive)}
    if table is not None:
        choices["tuned"] = family.gains(drive, table=table, table_file=table_file)
    return Review(choices, list(choices)[-1], table is not None, table)


def opening(
    family: ObserverFamily, drive: Drive, table: GainTable | None, min_damping: float, label: str
) -> dict[str, Any]:
    """The data every report opens with: its inputs (drive, hashes, required damping), the drive-data
    tables (without the sections the family's report hooks leave out) and the label under review."""
    return {
        "inputs": report_inputs(drive, table, min_damping),
        "drive": drive_tables(drive, hooks(family).settings_sections, family.bases(drive)),
        "review": label,
    }


def time_domain_checks(
    drive: Drive, rev: Review, runs: Sequence[Scenario | str], progress: Callable[[str], None]
) -> tuple[list[Check], list[Figure]]:
    """The scenarios ``runs`` (reports/time_domain.py ``scenarios``) simulated with the gains under
    review and judged: (checks, figures)."""
    return time_domain.checks(drive, rev.simulated, runs, rev.label, progress)


def settle(status: str, td: Sequence[Check]) -> tuple[str, list[Finding]]:
    """A verdict's status with the time-domain checks ``td`` (one rule: a failed check makes it "fail", a
    check not tested sensorless at best "warn") and the findings of those checks, each failure with its
    cause and fix (reports/causes.py)."""
    return time_domain.status_with(status, td), time_domain.findings(td)


def status_class(status: str) -> str:
    """The paragraph class of a verdict's status: "ok" (pass), "bad" (fail), "" (warn)."""
    return "ok" if status == "pass" else "bad" if status == "fail" else ""


def verdict_box(
    status: str,
    summary: Paragraph,
    reasons: Sequence[str] = (),
    notes: Sequence[str] = (),
    findings: Sequence[str] = (),
    reason_class: str = "",
) -> Verdict:
    """The verdict box: the summary, then the reasons (``reason_class``) and notes (what the checks
    leave out) as paragraphs, and the findings as bullet points."""
    lines = [summary, *(Paragraph(r, reason_class) for r in reasons), *(Paragraph(n) for n in notes)]
    return Verdict(status, tuple(lines), tuple(findings))
