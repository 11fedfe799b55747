"""``sensorless tune`` options of the adaptive observer: the shared envelope's (reports/envelope_options.py)
and its gain laws' own: the bound on lambda1, lambda2, alpha_fo tuned or not, the schedule's breakpoints.

The drive's ``[tuning]`` section (design/envelope.py) with the command-line overrides applied and
checked (one-line errors naming the option).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import TYPE_CHECKING, Any

from sensorless.design.ipmsm_adaptive.law_settings import BREAKPOINTS
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.reports import envelope_options
from sensorless.reports.envelope_options import ENVELOPE_OPTIONS, NOISE_OPTIONS, tune_settings
from sensorless.reports.family import Option
from sensorless.reports.options import Number, option_error

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

OPTIONS = (
    *ENVELOPE_OPTIONS,
    Option(("--lambda-max",), {"help": "bound on |lambda1|, |lambda2|: ohm or e.g. 5R_s_hat"}),
    NOISE_OPTIONS[0],  # --errors
    Option(
        ("--tune-alpha-fo",),
        {
            "action": "store_true",
            "help": "also tune alpha_fo of eq. (10) (the default on a drive file of your own)",
        },
    ),
    Option(
        ("--breakpoints",),
        {
            "type": Number(*BREAKPOINTS, integer=True),
            "help": "schedule: breakpoints per direction ({}..{})".format(*BREAKPOINTS),
        },
    ),
    *NOISE_OPTIONS[1:],
)


def law_options(drive: IpmsmDrive, args: argparse.Namespace, law: Any) -> Any:
    """The gain laws' own settings (design/ipmsm_adaptive/law_settings.py) with the options given."""
    new: dict[str, Any] = {}
    if args.lambda_max is not None:
        txt = args.lambda_max.replace("R_s_hat", " R_s_hat").strip()
        try:
            x, rel = parse_quantity(txt, "resistance", file="", key="--lambda-max")
        except DriveFileError as e:
            raise option_error("--lambda-max", e.problem) from None
        new["lambda_max"] = x * drive.estimate.R_s if rel else x
    if args.tune_alpha_fo:
        new["tune_alpha_fo"] = True
    if args.breakpoints is not None:
        new["breakpoints"] = args.breakpoints
    return dataclasses.replace(law, **new)


settings = tune_settings(law_options)
describe = envelope_options.describe
