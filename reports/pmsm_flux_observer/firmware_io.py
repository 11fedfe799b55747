"""The firmware formats of the flux observer + PLL family, as the shared ``init --from`` and ``export``
commands find them (reports/family.py ``Importer``, ``Exporter``; the family's ``HOOKS`` names them).

The formats themselves are design/pmsm_flux_observer/firmware/; here are their command-line options and
the adapters between the commands and them: :data:`IMPORTERS` and :data:`EXPORTERS` are what the
family's ``HOOKS`` declares.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

from sensorless.design.drive_file import name_problem
from sensorless.design.family import CapabilityError, DriveT, GainSet, later
from sensorless.design.motor_data import mtpa_torque_current
from sensorless.design.pmsm_flux_observer import FAMILY
from sensorless.design.pmsm_flux_observer.firmware import (
    F_S_RANGE,
    POLE_PAIRS_RANGE,
    U_DC_RANGE,
    FirmwareDrive,
)
from sensorless.reports.family import Exporter, Importer, Option
from sensorless.reports.options import Number, UsageError, drive_name

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

# each firmware's reader and writer, imported where a file is read or written: ``sensorless init``
# lists the importers and their options
if TYPE_CHECKING:
    from sensorless.design.pmsm_flux_observer.firmware import odrive, simplefoc, vesc
else:  # each module as the two functions read of it below (SimpleFOC's files are written, never read)
    odrive, simplefoc, vesc = (
        SimpleNamespace(read=later(m, "read"), export=later(m, "export"))
        for m in (f"{FirmwareDrive.__module__}.{name}" for name in ("odrive", "simplefoc", "vesc"))
    )

POLE_PAIRS = Option(
    ("--pole-pairs",),
    {
        "type": Number(*POLE_PAIRS_RANGE, integer=True),
        "help": "pole pairs, where the file lacks them or to override",
    },
)
U_DC = Option(
    ("--u-dc",), {"type": Number(*U_DC_RANGE, unit="V"), "metavar": "V", "help": "DC bus voltage [V]"}
)
INERTIA = Option(
    ("--J",),
    {
        "type": Number(1e-9, 1e4, unit="kg m2"),
        "metavar": "KGM2",
        "help": "moment of inertia [kg m2] (rotor and load)",
    },
)
KV = Option(
    ("--KV",),
    {
        "type": Number(0.01, 1e5, lo_open=True, unit="rpm/V"),
        "metavar": "RPM_PER_V",
        "help": "speed constant [rpm/V, line-line peak], cross-checked against the file's flux values",
    },
)
L_SCALE = Option(
    ("--l-scale",),
    {
        "type": Number(0.1, 10, unit=""),
        "help": "the factor the file's inductances carry (default 0.9, as VESC Tool's detection stores them; "
        "1 for values typed from a datasheet)",
    },
)
F_S = Option(
    ("--f-s",),
    {
        "type": Number(*F_S_RANGE, unit="Hz"),
        "metavar": "HZ",
        "help": "the firmware's current-loop frequency [Hz]",
    },
)
NAME = Option(("--name",), {"type": drive_name, "help": "the drive's name (default: the file's name)"})


def importers(kind: str) -> dict[str, Importer]:
    """The importers, writing drive files of ``kind`` (the family's drive kind)."""

    def reader(
        read: Callable[..., Any],
    ) -> Callable[[str, str, Mapping[str, Any]], tuple[str, tuple[str, ...]]]:
        def run(text: str, file: str, given: Mapping[str, Any]) -> tuple[str, tuple[str, ...]]:
            if not given.get("name"):  # the default, the file's name, becomes the drive's
                why = name_problem(Path(file).stem)
                if why is not None:
                    raise UsageError(
                        f"argument --name: the file's name cannot be the drive's ({why}): give --name"
                    )
            imported = read(text, file, given, kind)
            return imported.text, imported.notes

        return run

    return {
        "vesc": Importer(
            "VESC Tool motor configuration XML",
            reader(vesc.read),
            (POLE_PAIRS, U_DC, INERTIA, KV, L_SCALE, NAME),
        ),
        "odrive": Importer(
            "odrivetool configuration backup", reader(odrive.read), (POLE_PAIRS, U_DC, INERTIA, KV, F_S, NAME)
        ),
    }


def exporters(record: Callable[[DriveT, GainSet], FirmwareDrive]) -> dict[str, Exporter[DriveT]]:
    """The exporters; ``record`` makes the typed record of a drive and its gains (the family's)."""

    def writer(export: Callable[[FirmwareDrive], tuple[dict[str, str], list[str]]]) -> Callable[..., Any]:
        def run(drive: DriveT, gains: GainSet) -> tuple[dict[str, str], list[str]]:
            d = record(drive, gains)
            files, notes = export(d)
            return files, [*d.notes, *notes]

        return run

    return {
        "vesc": Exporter("VESC Tool motor configuration XML fragment", ("vesc.xml",), writer(vesc.export)),
        "odrive": Exporter(
            "odrivetool settings (JSON and odrivetool lines)",
            ("odrive.json", "odrivetool.txt"),
            writer(odrive.export),
        ),
        "simplefoc": Exporter("SimpleFOC motor fields (C++)", ("simplefoc.cpp",), writer(simplefoc.export)),
    }


def firmware_record(drive: FluxObserverDrive, gains: GainSet) -> FirmwareDrive:
    """What an export writes: the drive's estimates (what the firmware is given), loop and gains, and its
    I-f start judged at the gains (design/startup_check.py): the drive file's values kept where they
    hold, each one that does not replaced by the value that fixes it, with one line saying why."""
    from sensorless.design.pmsm_flux_observer.firmware.startup import change_lines
    from sensorless.design.startup_check import judge_startup

    e, obs = drive.estimate, drive.observer
    notes: list[str] = []
    startup = None  # none where the drive needs no start (its observer holds zero speed)
    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:  # no minimum-speed analysis (e.g. the box clamp is not linearizable)
        judged = None
        given = drive.startup.values() if drive.startup is not None else {}
        startup = given if {"if_i", "if_acc", "if_w_on", "if_w_off"} <= set(given) else None
        # not judged against a w_min, but never a speed the motor cannot reach
        top = min(drive.w_base, drive.control.u_dc / (math.sqrt(3) * drive.motor.psi_pm))
        if startup is not None and startup["if_w_on"] > top:
            notes.append(
                f"start-up not written: [startup] w_on = {startup['if_w_on']:.6g} rad/s is above the rated "
                f"or no-load speed ({top:.6g} rad/s), which the open loop never reaches "
                "(cause: speed_unreachable)"
            )
            startup = None
    if judged is not None:
        startup = judged.values if judged.fixable else None
        notes = change_lines(obs.firmware, judged, drive.w_base)
        if not judged.fixable:
            notes.append("start-up not written (the firmware keeps its own): no start-up value fixes it")
    return FirmwareDrive(
        name=drive.name,
        p=drive.motor.p,
        R_s=e.R_s,
        L_d=e.L_d,
        L_q=e.L_q,
        psi_pm=e.psi_pm,
        u_dc=drive.control.u_dc,
        T_obs=obs.T_obs,
        correction=obs.correction,
        lambda_adaptation=obs.lambda_adaptation,
        law=gains.law,
        gains=dict(gains.values),
        source=gains.source,
        startup=startup,
        notes=tuple(notes),
        i_max=float(f"{math.hypot(*mtpa_torque_current(drive.control.T_max, drive.motor)):.4g}"),
    )


IMPORTERS = importers(FAMILY.kind)
EXPORTERS = exporters(firmware_record)
