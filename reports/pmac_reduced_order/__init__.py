"""Report hooks of the reduced-order observer: its ``analyze`` output, ``tune`` options and stability report.

De Angelo et al. (2006). analyze.py (poles continuous and discrete, steady errors, the discretization
study), tune.py (bounds of the constant-gain tuner), report.py and figures.py (the stability report).
"""

from __future__ import annotations

from sensorless.reports.family import ReportHooks
from sensorless.reports.pmac_reduced_order import analyze, report, tune

HOOKS = ReportHooks(
    analyze_options=analyze.OPTIONS,
    analyze=analyze.analyze,
    analyze_check=analyze.check,
    tune_options=tune.OPTIONS,
    tune_settings=tune.settings,
    describe_envelope=tune.describe,
    report=report.compute,
)
