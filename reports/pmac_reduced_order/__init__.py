"""Report hooks of the reduced-order observer: its ``analyze`` output, ``tune`` options and stability report.

De Angelo et al. (2006). analyze.py (poles continuous and discrete, steady errors, the discretization
study), tune.py (bounds of the constant-gain tuner), report.py and figures.py (the stability report,
imported where it is computed: every command reads these hooks for their options).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sensorless.design.family import later
from sensorless.reports.family import ReportHooks
from sensorless.reports.pmac_reduced_order import analyze, tune

if TYPE_CHECKING:
    from sensorless.reports.pmac_reduced_order.report import compute
else:
    compute = later(f"{__name__}.report", "compute")

HOOKS = ReportHooks(
    analyze_options=analyze.OPTIONS,
    analyze=analyze.analyze,
    analyze_check=analyze.check,
    tune_options=tune.OPTIONS,
    tune_settings=tune.settings,
    describe_envelope=tune.describe,
    report=compute,
)
