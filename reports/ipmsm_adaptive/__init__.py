"""Report hooks of the adaptive observer: its ``analyze`` output, ``tune`` options and stability report.

Piippo, Hinkkanen, Luomi (2008). analyze.py (pole maps, unstable bands), tune.py (envelope options of
the shared NLP), simulate.py (the scenario options of ``simulate``), report.py and figures.py (the
stability report) and causes.py (its causes of failed checks): these two imported where they run, since
every command reads these hooks for their options.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sensorless.design.family import later
from sensorless.reports.family import ReportHooks
from sensorless.reports.ipmsm_adaptive import analyze, simulate, tune

if TYPE_CHECKING:
    from sensorless.reports.ipmsm_adaptive.causes import failure_cause
    from sensorless.reports.ipmsm_adaptive.report import compute
else:
    compute = later(f"{__name__}.report", "compute")
    failure_cause = later(f"{__name__}.causes", "failure_cause")

HOOKS = ReportHooks(
    analyze_options=analyze.OPTIONS,
    analyze=analyze.analyze,
    analyze_check=analyze.check,
    tune_options=tune.OPTIONS,
    tune_settings=tune.settings,
    describe_envelope=tune.describe,
    simulate_options=simulate.OPTIONS,
    simulate_scenario=simulate.scenario,
    report=compute,
    failure_cause=failure_cause,
    settings_sections=("runtime", "tuning"),  # [runtime], [tuning]: settings, in their own sections
)
