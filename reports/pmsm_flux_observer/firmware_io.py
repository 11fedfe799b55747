"""The firmware formats of the flux observer + PLL family, as the shared ``init --from`` and ``export``
commands find them (reports/family.py ``Importer``, ``Exporter``; the family's ``HOOKS`` names them).

The formats themselves are design/pmsm_flux_observer/firmware/; here are their command-line options and
the adapters between the commands and them: :data:`IMPORTERS` and :data:`EXPORTERS` are what the
family's ``HOOKS`` declares.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from sensorless.design.family import CapabilityError, Drive, GainSet
from sensorless.design.pmsm_flux_observer import FAMILY
from sensorless.design.pmsm_flux_observer.firmware import FirmwareDrive, odrive, simplefoc, vesc
from sensorless.reports.family import Exporter, Importer, Option
from sensorless.reports.options import Number

POLE_PAIRS = Option(
    ("--pole-pairs",),
    {"type": Number(1, 1000, integer=True), "help": "pole pairs, where the file lacks them or to override"},
)
U_DC = Option(("--u-dc",), {"type": Number(1, 1e4, unit="V"), "metavar": "V", "help": "DC bus voltage [V]"})
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
        "type": Number(100, 1e6, unit="Hz"),
        "metavar": "HZ",
        "help": "the firmware's current-loop frequency [Hz]",
    },
)
NAME = Option(("--name",), {"help": "the drive's name (default: the file's name)"})


def importers(kind: str) -> dict[str, Importer]:
    """The importers, writing drive files of ``kind`` (the family's drive kind)."""

    def reader(
        read: Callable[..., Any],
    ) -> Callable[[str, str, Mapping[str, Any]], tuple[str, tuple[str, ...]]]:
        def run(text: str, file: str, given: Mapping[str, Any]) -> tuple[str, tuple[str, ...]]:
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


def exporters(record: Callable[[Drive, GainSet], FirmwareDrive]) -> dict[str, Exporter]:
    """The exporters; ``record`` makes the typed record of a drive and its gains (the family's)."""

    def writer(export: Callable[[FirmwareDrive], tuple[dict[str, str], list[str]]]) -> Callable[..., Any]:
        return lambda drive, gains: export(record(drive, gains))

    return {
        "vesc": Exporter("VESC Tool motor configuration XML fragment", ("vesc.xml",), writer(vesc.export)),
        "odrive": Exporter(
            "odrivetool settings (JSON and odrivetool lines)",
            ("odrive.json", "odrivetool.txt"),
            writer(odrive.export),
        ),
        "simplefoc": Exporter("SimpleFOC motor fields (C++)", ("simplefoc.cpp",), writer(simplefoc.export)),
    }


def firmware_record(drive: Any, gains: GainSet) -> FirmwareDrive:
    """What an export writes: the drive's estimates (what the firmware is given), loop and gains."""
    from sensorless.design.pmsm_drive import startup_values

    e, obs = drive.estimate, drive.observer
    try:  # its [startup], else by the rules from w_min
        startup, _, _ = startup_values(drive, gains)
    except CapabilityError:  # no minimum-speed analysis (e.g. the box clamp is not linearizable)
        startup = None if drive.startup is None or len(drive.startup.values()) < 4 else drive.startup.values()
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
    )


IMPORTERS = importers(FAMILY.kind)
EXPORTERS = exporters(firmware_record)
