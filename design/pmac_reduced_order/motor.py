"""The ``[motor]`` table of the reduced-order observer's drive files, in datasheet terms or the family's own.

A minimal drive file gives the motor as datasheets do (design/motor_data.py: poles, kE/KV/kT with their
conventions, line-to-line R and L, J in kg cm2, ...); a complete one in the family's own keys (R, L,
reading, B, harmonics, Phi; schema.py). :func:`read_pmac_motor` reads either, or both where they agree,
into the physical motor (for the rating and the plausibility checks) and the EMF amplitude of eq. (4).

Convention (docs/families/pmac_reduced_order.md): the alpha-beta frame of (1)-(5) is power-invariant
(T_e = phi . i has no 3/2), so |e| = sqrt(3/2) times the phase peak back-EMF p w_m psi_pm; in the
mechanical reading e = phi(theta) w_m, hence Phi_1 = sqrt(3/2) p psi_pm, V s per mechanical radian,
and T_e = Phi_1 |i| = 1.5 p psi_pm i_peak as in design/motor_data.py. R and L of (1) are the per-phase
values of the equivalent wye (the transformation keeps them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from sensorless.design.drive_file import check_keys, g6, positive
from sensorless.design.motor_data import FLUX_KEYS, FLUX_TOLERANCE, MOTOR_KEYS, MotorData, read_motor
from sensorless.design.pmac_reduced_order.schema import READINGS, harmonic_series
from sensorless.design.pmsm_schema import saliency
from sensorless.design.units import DriveFileError

NATIVE = ("reading", "R", "L", "B", "harmonics", "Phi")  # the family's own [motor] keys
SALIENCY_MAX = 0.1  # 2 |L_q - L_d| / (L_q + L_d) beyond which model (2) (one L) does not fit
EMF_SCALE = math.sqrt(1.5)  # |e| power-invariant alpha-beta / phase peak


@dataclass(frozen=True)
class PmacMotorData:
    """The ``[motor]`` table read: the physical motor (design/motor_data.MotorData, for the rating and
    the plausibility checks), the reading, and the EMF series in the family's terms (SI)."""

    m: MotorData
    reading: str
    p_r: float  # speed in eq. (2) per electrical speed: p (mechanical reading) or 1
    L: float
    Phi_1: float  # V s per radian of the reading
    L_rule: str
    Phi_rule: str


def read_pmac_motor(t: Mapping[str, Any], file: str) -> PmacMotorData:
    """The motor of a ``[motor]`` table in datasheet terms (design/motor_data.py) or the family's own
    (R, L, Phi), or both where they agree; DriveFileError naming the key for what is wrong."""
    check_keys(t, (*MOTOR_KEYS, *NATIVE), file, "motor.")
    for own, others in (("R", ("R_s", "R_ll")), ("L", ("L_s", "L_d", "L_q", "L_ll"))):
        given = [k for k in others if k in t]
        if own in t and given:
            raise DriveFileError(file, f"motor.{own}", f"give one of motor.{own} and motor.{given[0]}")
        if own not in t and not given:
            what = (
                "stator resistance: R (= R_s) per phase, or R_ll line to line"
                if own == "R"
                else "inductance: L (= L_s) per phase, L_d with L_q, or L_ll line to line"
            )
            raise DriveFileError(file, f"motor.{own}", f"missing key ({what})")
    reading = t.get("reading", "mechanical")
    if not isinstance(reading, str):
        raise DriveFileError(file, "motor.reading", f"expected a string, got {reading!r}")
    if reading not in READINGS:
        raise DriveFileError(
            file, "motor.reading", f"unknown reading {reading!r} (known: {', '.join(READINGS)})"
        )
    # read_motor converts the datasheet terms; the family's own R and L enter as R_s and L_s, and a
    # flux given only as Phi as a placeholder that the series replaces below
    md = {k: v for k, v in t.items() if k in MOTOR_KEYS}
    if "R" in t:
        md["R_s"] = positive(t, "R", "resistance", file, "motor")
    if "L" in t:
        md["L_s"] = positive(t, "L", "inductance", file, "motor")
    flux_keys = [k for k in FLUX_KEYS if k in t]
    if reading == "electrical" and flux_keys:
        # datasheet terms describe the physical motor (J in kg m2 as measured); in the electrical
        # reading J and Phi of eq. (2) are per electrical radian (J/p^2): one key, two meanings
        raise DriveFileError(
            file,
            "motor.reading",
            "the electrical reading of eq. (2) takes J and Phi per electrical radian, but "
            f'motor.{flux_keys[0]} gives the physical motor: leave reading at "mechanical" with '
            "datasheet terms, or give the family's own R, L, J and Phi (docs/families/pmac_reduced_order.md)",
        )
    if not flux_keys and "Phi" not in t:
        raise DriveFileError(
            file,
            "motor.psi_pm",
            "missing key (PM flux: psi_pm, or kE with emf_convention, KV, or kT with torque_convention; "
            "or the EMF series harmonics and Phi)",
        )
    if "harmonics" in t and "Phi" not in t:
        raise DriveFileError(file, "motor.Phi", "missing key (the amplitudes of the harmonics, eq. (4))")
    if not flux_keys:
        md["psi_pm"] = 1.0
    m = read_motor(md, file)
    p_r = float(m.p) if reading == "mechanical" else 1.0
    source = dict(m.source)
    for own, k in (("R", "R_s"), ("L", "L_d"), ("L", "L_q")):
        if own in t:
            source[k] = f"motor.{own}"
    xi = saliency(m.L_d, m.L_q)
    if xi > SALIENCY_MAX:
        raise DriveFileError(
            file,
            "motor.L_q",
            f"saliency 2|L_q - L_d|/(L_q + L_d) = {xi:.3g}: the model (2) of this observer has one "
            f"inductance L (at most {SALIENCY_MAX:g}); a salient motor needs a family that models it",
        )
    L = (m.L_d + m.L_q) / 2
    if "L_d" in t:
        L_rule = f"(L_d + L_q)/2 (saliency {xi:.3g} <= {SALIENCY_MAX:g}: model (2) is non-salient)"
    else:
        L_rule = m.rules.get("L_d", f"= {source['L_d']}").split(" (non-salient)")[0]
    # the EMF amplitude: the series' fundamental if given, else sqrt(3/2) p_r psi_pm (module docstring)
    psi_rule = m.rules.get("psi_pm", m.source["psi_pm"])
    if "Phi" in t:
        _, Phi = harmonic_series({"harmonics": [1], **t}, file, "motor")
        psi = Phi[0] / (EMF_SCALE * p_r)
        if flux_keys:
            dev = psi / m.psi_pm - 1
            if abs(dev) > FLUX_TOLERANCE:
                k0 = flux_keys[0]
                raise DriveFileError(
                    file,
                    f"motor.{k0}",
                    f"implies Phi_1 = {EMF_SCALE * p_r * m.psi_pm:.5g} Vs, but motor.Phi[0] is "
                    f"{Phi[0]:.5g} Vs: they differ by {100 * abs(dev):.0f} % (tolerance "
                    f"{100 * FLUX_TOLERANCE:g} %); check the conventions (docs/motor_data.md; Phi_1 = "
                    "sqrt(3/2) p psi_pm per mechanical radian)",
                )
        source["psi_pm"] = "motor.Phi"
        m = replace(m, psi_pm=psi)
        Phi_1, Phi_rule = Phi[0], ""
    else:
        Phi_1 = EMF_SCALE * p_r * m.psi_pm
        per = "mechanical radian" if reading == "mechanical" else "electrical radian"
        factor = "sqrt(3/2) p psi_pm" if reading == "mechanical" else "sqrt(3/2) psi_pm"
        Phi_rule = f"Phi_1 = {factor}, V s per {per}; psi_pm = {g6(m.psi_pm)} Vs = {psi_rule}"
    # J of the reading: physical inertia in the mechanical reading, J/p^2 in the electrical one
    m = replace(m, L_d=L, L_q=L, J=m.J * (m.p / p_r) ** 2, source=source)
    return PmacMotorData(m, reading, p_r, L, Phi_1, L_rule, Phi_rule)
