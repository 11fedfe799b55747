"""SimpleFOC: the motor fields its MXLEMMING flux observer reads, written as a C++ snippet.

``MXLEMMINGObserverSensor`` (Arduino-FOC-drivers) reads ``pole_pairs``, ``phase_resistance``,
``phase_inductance`` (taken as L_q) and ``KV_rating``, from which it derives the flux linkage
psi_pm = 60 / (2 pi sqrt(3) pole_pairs KV) (KV in rpm/V, line-line peak; design/motor_data.py
kv_to_psi, whose inverse is written here). It has no gain and no PLL: the correction is the box clamp
of each flux component to +-psi_pm, which the linearized analysis does not cover; the family judges it
by simulation.
"""

from __future__ import annotations

import math

from sensorless.design.motor_data import kv_to_psi
from sensorless.design.pmsm_flux_observer.firmware import FirmwareDrive, stored


def kv_rating(psi_pm: float, p: int) -> float:
    """KV [rpm/V] whose flux (kv_to_psi) is ``psi_pm`` [Wb] with ``p`` pole pairs."""
    kv_si = kv_to_psi(1.0, p) / psi_pm  # kv_to_psi is proportional to 1/KV
    return kv_si * 60 / (2 * math.pi)


def _c(x: float) -> str:
    """A C float literal of ``x`` as the firmware stores it (float32, no float noise)."""
    text = stored(x)
    return f"{text}f" if any(c in text for c in ".e") else f"{text}.0f"


def export(d: FirmwareDrive) -> tuple[dict[str, str], list[str]]:
    """``simplefoc.cpp``: the motor fields of a ``BLDCMotor motor`` for its MXLEMMING observer."""
    kv = kv_rating(d.psi_pm, d.p)
    lines = [
        f"// sensorless export for SimpleFOC (MXLEMMINGObserverSensor): drive {d.name}",
        "// The MXLEMMING observer has no gain to tune and no PLL: its correction clamps each flux",
        "// component to +-psi_pm (box clamp), which has no linearization; the analysis judges it by",
        "// simulation (sensorless simulate). Set these motor fields before motor.init():",
        f"motor.pole_pairs = {d.p};",
        f"motor.phase_resistance = {_c(d.R_s)};  // ohm, per phase",
        f"motor.phase_inductance = {_c(d.L_q)};  // H, L_q (the observer's inductance)",
        f"motor.KV_rating = {_c(kv)};  // rpm/V: flux 60/(2 pi sqrt(3) p KV) = {d.psi_pm:.6g} Wb",
        "// SimpleFOC's docs advise a KV 50-70 % higher than the motor's: that shrinks the clamp (the",
        "// flux it allows) by the same factor; the value above is the motor's own.",
    ]
    notes = ["SimpleFOC's MXLEMMING observer has no gain to tune: only the motor fields are written"]
    if d.correction != "box-clamp":
        notes.append(
            f"the drive was analysed with the {d.correction} correction; SimpleFOC runs the box clamp"
        )
    return {"simplefoc.cpp": "\n".join(lines) + "\n"}, notes
