"""Report hooks of the PLL test family: all shared but the option of its law's bandwidth box.

``analyze`` and the stability report are the shared ones of any linearization over the drive's envelope
(reports/envelope_review.py); ``tune`` takes the shared envelope options (reports/envelope_options.py)
and its law's ``--w-pll-max`` (the upper end of its box, constant_law.py ``GainBox``).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from sensorless.reports import envelope_options, envelope_review
from sensorless.reports.family import Option, ReportHooks


def law_options(drive: Any, args: argparse.Namespace, law: Any) -> Any:
    """The ``pll`` law's box with ``--w-pll-max`` applied."""
    return law if args.w_pll_max is None else dataclasses.replace(law, upper=(args.w_pll_max,))


HOOKS = ReportHooks(
    analyze=envelope_review.analyze,
    tune_options=(
        *envelope_options.ENVELOPE_OPTIONS,
        Option(("--w-pll-max",), {"type": float, "help": "upper bound on the PLL bandwidth [rad/s]"}),
    ),
    tune_settings=envelope_options.tune_settings(law_options),
    describe_envelope=envelope_options.describe,
    report=envelope_review.report,
)
