"""The PMSM motor record and the drive-file sections every PMSM drive shares, whatever its observer.

A PMSM in the models (symbolic/pmsm.py; Piippo, Hinkkanen, Luomi (2008) eqs. (1)-(3)) is the
per-phase equivalent wye in the amplitude-invariant dq frame: :class:`PmsmMotor` (``[motor]`` of a
complete drive file: pole pairs, R_s, L_d, L_q, psi_pm, J) and the observer's and controllers'
model of it, :class:`PmsmEstimate` (``[estimate]``). A drive file may give ``[motor]`` in datasheet
terms instead (design/motor_data.py ``read_motor``, which returns the same record with where each
value came from), and :class:`PmsmControl` is the ``[control]`` of the shared drive loop
(design/pmsm_drive.py; a family may extend it with keys of its own). Loading is the strict loading
of every drive file (design/drive_file.py). :class:`PmsmRating` is the nameplate's minimum (n_N, T_N:
the per-unit speed base and the nominal torque) for a family that needs no more. What is a family's
own stays in its folder: a ``[rating]`` with more nameplate keys, its observer's sections, and a motor model
of its own (the EMF series of design/pmac_reduced_order/, read from datasheet terms with the same
``read_motor``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensorless.design.drive_file import load_section, q, table
from sensorless.design.units import DriveFileError, parse_quantity


@dataclass(frozen=True)
class PmsmMotor:
    """The true motor, per phase of the equivalent wye, SI: eqs. (1)-(3) of the PMSM model."""

    p: int = q("integer", check="pole_pairs", doc="pole pairs")
    R_s: float = q("resistance", doc="stator resistance [ohm]")
    L_d: float = q("inductance", doc="d-axis inductance [H]")
    L_q: float = q("inductance", doc="q-axis inductance [H]")
    psi_pm: float = q("flux", doc="permanent-magnet flux linkage [V s]")
    J: float = q("inertia", doc="total moment of inertia [kg m^2]")

    def vector(self) -> list[float]:
        """[R_s, L_d, L_q, psi_pm]: the electrical parameter vector the CasADi functions take
        (symbolic/pmsm.py ``PmsmParams.of``)."""
        return [self.R_s, self.L_d, self.L_q, self.psi_pm]


@dataclass(frozen=True)
class PmsmEstimate:
    """The observer's and the controllers' model of the motor (R̂s, L̂d, L̂q, ψ̂pm), kept apart from the
    true motor so that parameter errors can be studied."""

    R_s: float = q("resistance", doc="estimated stator resistance [ohm]")
    L_d: float = q("inductance", doc="estimated d-axis inductance [H]")
    L_q: float = q("inductance", doc="estimated q-axis inductance [H]")
    psi_pm: float = q("flux", doc="estimated PM flux linkage [V s]")

    def vector(self) -> list[float]:
        """[R̂s, L̂d, L̂q, ψ̂pm]."""
        return [self.R_s, self.L_d, self.L_q, self.psi_pm]


@dataclass(frozen=True)
class PmsmRating:
    """The nameplate's minimum: the nominal speed (1 p.u.) and the nominal torque."""

    n_N: float = q("mech_speed", doc="nominal mechanical speed [r/min]")
    T_N: float = q("torque", doc="nominal torque [N m]")

    def w_base(self, pole_pairs: int) -> float:
        """1 p.u. speed: the nominal speed, electrical rad/s."""
        return self.n_N * math.pi / 30 * pole_pairs


def saliency(L_d: float, L_q: float) -> float:
    """2 |L_q - L_d| / (L_q + L_d): 0 for a non-salient motor, 0.35 for the IPMSM of Piippo et al. (2008)."""
    return 2 * abs(L_q - L_d) / (L_q + L_d)


@dataclass(frozen=True)
class PmsmControl:
    """Sampling and the controllers of the shared PMSM drive loop (design/pmsm_drive.py)."""

    T_s: float = q("time", doc="sampling period [s]")
    alpha_c: float = q("angular", doc="current-control bandwidth [rad/s]")
    alpha_s: float = q("angular", doc="speed-control bandwidth [rad/s]")
    T_max: float = q("torque", doc="electromagnetic torque limit [N m]")
    u_dc: float = q("voltage", doc="nominal DC-link voltage [V]")
    # optional: the speed reference's rate limit before the speed controller (symbolic/speed_ramp.py),
    # electrical rad/s^2 or "pu/s" (1 p.u. = the base speed); 0: none (the command steps)
    speed_ramp: float = q(
        "acceleration",
        check="nonnegative",
        doc="speed reference's rate limit [rad/s^2]",
        default=0.0,
        optional=True,
    )


def speed_ramp(t: Mapping[str, object], file: str, w_base: float) -> float:
    """``[control] speed_ramp`` of a table ``t`` [rad/s^2 electrical] ("pu/s": per unit of ``w_base``
    per second); 0 where it is not given; DriveFileError naming the key for a negative or unreadable one."""
    if "speed_ramp" not in t:
        return 0.0
    x, rel = parse_quantity(t["speed_ramp"], "acceleration", file=file, key="control.speed_ramp")
    x = x * w_base if rel == "pu/s" else x
    if not x >= 0:
        raise DriveFileError(
            file, "control.speed_ramp", f"non-physical value {t['speed_ramp']!r}: must be >= 0"
        )
    return x


class PmsmDriveProperties:
    """The ``Drive`` properties (design/family.py) of a drive record with fields ``rating``
    (:class:`PmsmRating`), ``motor`` and ``control``: a mixin of a family's frozen drive dataclass."""

    rating: PmsmRating
    motor: PmsmMotor
    control: PmsmControl

    @property
    def T_N(self) -> float:
        return self.rating.T_N

    @property
    def w_base(self) -> float:
        return self.rating.w_base(self.motor.p)

    @property
    def pole_pairs(self) -> int:
        return self.motor.p

    @property
    def T_s(self) -> float:
        return self.control.T_s


def load_motor(data: Mapping[str, Any], file: str) -> PmsmMotor:
    """The ``[motor]`` section of a complete drive file (pole pairs at least 1); DriveFileError naming
    the file and the key otherwise."""
    motor = load_section(PmsmMotor, table(data, "motor", file), file, "motor")
    if motor.p < 1:
        raise DriveFileError(file, "motor.p", f"non-physical value {motor.p}: must be >= 1")
    return motor


def load_estimate(data: Mapping[str, Any], file: str) -> PmsmEstimate:
    """The ``[estimate]`` section of a complete drive file."""
    return load_section(PmsmEstimate, table(data, "estimate", file), file, "estimate")
