"""``sensorless tune`` options of the reduced-order observer: bounds and damping floor of its tuner.

The drive's ``[envelope]`` with default bounds around its ``[observer]`` gains
(tuning/pmac_reduced_order/settings.py), and the command-line overrides, checked.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import TYPE_CHECKING, Any

from sensorless.reports.envelope_options import ENVELOPE_OPTIONS, NOISE_OPTIONS
from sensorless.reports.family import Option
from sensorless.reports.options import Number, UsageError, parse_max_noise
from sensorless.tuning.family import TuningError
from sensorless.tuning.pmac_reduced_order.settings import ConstantGainSettings, default_settings

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

DENSE_FACTOR = next(o for o in ENVELOPE_OPTIONS if o.dest == "dense_factor")
MAX_NOISE = next(o for o in NOISE_OPTIONS if o.dest == "max_noise")
OPTIONS = (
    DENSE_FACTOR,  # the shared options' (reports/envelope_options.py)
    Option(
        ("--g-max",),
        {
            "type": Number(0, 1e9, lo_open=True, unit="1/s"),
            "help": "search box: upper bound on g [1/s] (default 100x the drive's)",
        },
    ),
    Option(
        ("--Gamma-max",),
        {
            "type": Number(0, 1e12, lo_open=True, unit="A^2 s^2"),
            "help": "search box: upper bound on Gamma [A^2 s^2] (default (g_max J / Phi_1)^2, where "
            "Gamma (Phi_1/J)^2 = g_max^2, and at least the drive's Gamma)",
        },
    ),
    MAX_NOISE,
    Option(
        ("--min-damping",),
        {"type": Number(0, 1, hi_open=True), "help": "worst damping required, in [0, 1) (default 0.707)"},
    ),
)


def settings(drive: PmacDrive, args: argparse.Namespace, tunable: Any) -> ConstantGainSettings:
    """Constant-gain settings: the drive's [envelope] and default bounds, with the overrides."""
    s = default_settings(drive)
    out: dict[str, Any] = {}
    for key in ("g_max", "Gamma_max", "min_damping", "dense_factor"):
        v = getattr(args, key)
        if v is not None:
            out[key] = v
    if args.max_noise:
        out["max_noise"] = parse_max_noise(args.max_noise, drive.w_base)
    s = dataclasses.replace(s, **out)
    try:
        s.check("command line")
    except TuningError as e:
        raise UsageError(str(e)) from None
    return s


def describe(drive: PmacDrive, settings: ConstantGainSettings) -> str:
    """One line: the envelope."""
    return (
        f"envelope: speeds {', '.join(f'{v:g}' for v in settings.speeds_rpm)} r/min x loads "
        f"{', '.join(f'{v:g}' for v in settings.loads_Nm)} N m"
    )
