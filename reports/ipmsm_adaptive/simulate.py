"""``sensorless simulate`` options of the adaptive observer: the scenario's gain choice and HF injection.

Piippo, Hinkkanen, Luomi (2008): a scenario's ``[observer] gain`` (the drive file's
``[observer.gains.*]``: zero, constant, speed-dependent (16)) and ``injection`` (Section V), the keys this
family adds to scenarios (design/ipmsm_adaptive/simulation.py ``SCENARIO_OPTIONS``), overridden from
the command line.
"""

from __future__ import annotations

import argparse
import dataclasses

from sensorless.design.ipmsm_adaptive import FAMILY
from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive
from sensorless.design.scenario import Scenario
from sensorless.reports.family import Option
from sensorless.reports.options import Renamed

OPTIONS = (
    Option(
        ("--gain-set", "--gain"),
        {
            "action": Renamed,
            "metavar": "NAME",
            "help": "override the scenario's [observer] gain: a drive file's [observer.gains.*] name "
            "(--gain: the former spelling, accepted until the next release)",
        },
    ),
    Option(
        ("--injection",),
        {"choices": ("on", "off"), "help": "override the scenario's [observer] injection switch"},
    ),
)


def scenario(drive: IpmsmDrive, args: argparse.Namespace, sc: Scenario) -> Scenario:
    """``sc`` with the options given; a gain the drive file does not define is one line naming it."""
    options = dict(sc.options)
    if args.gain_set is not None:
        options["gain"] = args.gain_set
    if args.injection is not None:
        options["injection"] = args.injection == "on"
    if args.gain_set:
        FAMILY.gains(drive, name=args.gain_set)  # clear error naming the drive file if absent
    return dataclasses.replace(sc, options=options)
