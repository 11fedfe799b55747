"""Drive-file sections that are the same for every PMSM drive, whatever its observer: one definition.

A family whose observer runs on a PMSM in the shared drive loop (design/pmsm_drive.py) reads these
from here instead of writing them again: the ``[control]`` section of that loop (:class:`PmsmControl`,
which a family may extend with keys of its own) and the ``[motor]`` section's pole pairs
(:func:`load_motor`). What depends on the family's motor model stays in the family: its ``[motor]``
and ``[estimate]`` keys (L_d and L_q of a salient motor, or one L), its ``[rating]`` and its own
sections. Loading is the strict loading of every drive file (design/drive_file.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensorless.design.drive_file import load_section, q, table
from sensorless.design.units import DriveFileError


@dataclass(frozen=True)
class PmsmControl:
    """Sampling and the controllers of the shared PMSM drive loop (design/pmsm_drive.py)."""

    T_s: float = q("time", doc="sampling period [s]")
    alpha_c: float = q("angular", doc="current-control bandwidth [rad/s]")
    alpha_s: float = q("angular", doc="speed-control bandwidth [rad/s]")
    T_max: float = q("torque", doc="electromagnetic torque limit [N m]")
    u_dc: float = q("voltage", doc="nominal DC-link voltage [V]")


def load_motor(cls: type, data: Mapping[str, Any], file: str) -> Any:
    """The ``[motor]`` section of ``data`` as the family's dataclass ``cls``, whose field ``p`` (the
    pole pairs) must be at least 1; DriveFileError naming the file and the key otherwise."""
    motor = load_section(cls, table(data, "motor", file), file, "motor")
    if motor.p < 1:
        raise DriveFileError(file, "motor.p", f"non-physical value {motor.p}: must be >= 1")
    return motor
