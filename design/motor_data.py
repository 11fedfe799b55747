"""Motor data as datasheets give it: the conversions to the per-phase model of a PMSM.

Any PMSM family reads its drive file's ``[motor]`` table with :func:`read_motor`, which accepts each
quantity in the forms datasheets use and converts it to the per-phase quantities of the equivalent
wye-connected motor the models use (docs/motor_data.md gives every conversion and a worked example):

- pole pairs: ``p``, or ``poles`` (magnets, = 2 p); both given must agree;
- PM flux linkage ``psi_pm`` (peak phase flux, V s), or one of
  ``KV`` (``"270 rpm/V"``: no-load r/min per volt of back-EMF, line-to-line peak unless
  ``emf_convention`` says otherwise),
  ``kE`` (``"39 V/krpm"``, ``"mV/rpm"``, ``"V s/rad"``: back-EMF per mechanical speed) with
  ``emf_convention`` = "line-line peak" | "line-line rms" | "phase peak" | "phase rms" (the measure
  of the back-EMF that kE, and KV beside it, are stated in),
  ``kT`` (``"0.64 Nm/A"``, at i_d = 0) with ``torque_convention`` = "rms" | "peak" (per ampere of
  phase current, rms or amplitude). Several may be given: each must imply a flux within
  :data:`FLUX_TOLERANCE` of the first in the order psi_pm, kE, KV, kT, which is the one used;
- resistance: ``R_s`` (per phase) or ``R_ll`` (between two terminals) with ``connection``;
- inductance: ``L_s`` (per phase, non-salient), ``L_d`` and ``L_q``, or ``L_ll`` with ``connection``;
- ``J`` in kg m2, kg cm2 or g cm2 (any usual spelling: kgm2, kg m^2, kg·cm², gcm2, ...).

Line-to-line R and L measured between two terminals are twice the equivalent wye's per-phase values
for either connection (``connection`` states which the motor has; a delta winding's own phase values
are 3 times the equivalent wye's, docs/motor_data.md). A missing convention key is an error naming it.

design/plausibility.py checks a drive's data against each other with the rated-point helpers here.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sensorless.design.pmsm_schema import PmsmMotor
from sensorless.design.units import MAX_POLE_PAIRS, DriveFileError, parse_quantity

if TYPE_CHECKING:  # imported where a Function is built
    import casadi as ca

EMF_CONVENTIONS = ("line-line peak", "line-line rms", "phase peak", "phase rms")
TORQUE_CONVENTIONS = ("rms", "peak")
CONNECTIONS = ("wye", "delta")
# Largest relative difference between the PM fluxes that two flux keys imply (kE against kT: datasheets
# agree within a few per cent; a mistaken convention is off by sqrt(3/2), sqrt(2), sqrt(3) or sqrt(6)).
FLUX_TOLERANCE = 0.10
FLUX_KEYS = ("psi_pm", "kE", "KV", "kT")  # in the order of preference: the first given is used

MOTOR_KEYS = (
    "p",
    "poles",
    "R_s",
    "R_ll",
    "L_s",
    "L_d",
    "L_q",
    "L_ll",
    "connection",
    "psi_pm",
    "KV",
    "kE",
    "emf_convention",
    "kT",
    "torque_convention",
    "J",
)

# phase peak back-EMF per line-to-line/phase, rms/peak back-EMF
_EMF_TO_PHASE_PEAK = {
    "line-line peak": 1 / math.sqrt(3),
    "line-line rms": math.sqrt(2) / math.sqrt(3),
    "phase peak": 1.0,
    "phase rms": math.sqrt(2),
}


_EMF_RULE = {
    "line-line peak": "kE/(sqrt(3) p)",
    "line-line rms": "kE sqrt(2/3)/p",
    "phase peak": "kE/p",
    "phase rms": "kE sqrt(2)/p",
}


_KV_RULE = {
    "line-line peak": "1/(KV sqrt(3) p)",
    "line-line rms": "sqrt(2/3)/(KV p)",
    "phase peak": "1/(KV p)",
    "phase rms": "sqrt(2)/(KV p)",
}


def emf_to_psi(kE: float, convention: str, p: int) -> float:
    """PM flux [V s] from the back-EMF constant ``kE`` [V per mechanical rad/s] in ``convention``:
    psi_pm = kE_phase_peak / p (the phase peak back-EMF is p psi_pm per mechanical rad/s)."""
    return kE * _EMF_TO_PHASE_PEAK[convention] / p


def kv_to_psi(KV: float, p: int, convention: str = "line-line peak") -> float:
    """PM flux [V s] from the speed constant ``KV`` [mechanical rad/s per volt of back-EMF in
    ``convention``, line-to-line peak by default]: kE (in the same convention) = 1/KV."""
    return emf_to_psi(1 / KV, convention, p)


def kt_to_psi(kT: float, convention: str, p: int) -> float:
    """PM flux [V s] from the torque constant ``kT`` [N m/A] per ampere rms or peak of phase current at
    i_d = 0: T = 1.5 p psi_pm i_peak, i_peak = sqrt(2) i_rms."""
    per_peak = kT / math.sqrt(2) if convention == "rms" else kT
    return per_peak / (1.5 * p)


@dataclass(frozen=True)
class MotorData(PmsmMotor):
    """The motor record (design/pmsm_schema.py) of a ``[motor]`` table in datasheet terms, with where
    each value came from: ``source`` maps each to the key the user wrote, ``rules`` to the conversion in
    words (the comments of the complete drive file ``sensorless init`` writes)."""

    source: Mapping[str, str] = field(default_factory=dict)
    rules: Mapping[str, str] = field(default_factory=dict)


def read_motor(t: Mapping[str, Any], file: str, section: str = "motor") -> MotorData:
    """The per-phase motor of a ``[motor]`` table in datasheet terms (module docstring); strict:
    unknown keys, keys that exclude each other, missing conventions and disagreeing flux constants are
    DriveFileErrors naming the keys."""

    def key(k: str) -> str:
        return f"{section}.{k}"

    def err(k: str, why: str) -> DriveFileError:
        return DriveFileError(file, key(k), why)

    for k in t:
        if k not in MOTOR_KEYS:
            raise err(k, f"unknown key (allowed: {', '.join(MOTOR_KEYS)}; docs/motor_data.md)")

    def qty(k: str, dim: str) -> float:
        x, rel = parse_quantity(t[k], dim, file=file, key=key(k))
        if rel is not None:
            raise err(k, f"unit '{rel}' cannot be resolved here")
        if not x > 0:
            raise err(k, f"non-physical value {t[k]!r}: must be > 0")
        return x

    def choice(k: str, allowed: tuple[str, ...]) -> str:
        v = t[k]
        if not isinstance(v, str) or v.strip().lower() not in allowed:
            raise err(k, f"{v!r} is not one of: {', '.join(repr(a) for a in allowed)}")
        return v.strip().lower()

    rules: dict[str, str] = {}
    source: dict[str, str] = {}

    # pole pairs
    if "p" not in t and "poles" not in t:
        raise err("p", "missing key (pole pairs p, or poles = the number of magnet poles, 2 p)")
    p = None
    if "p" in t:
        p = _integer(t["p"], file, key("p"))
        source["p"] = key("p")
    if "poles" in t:
        poles = _integer(t["poles"], file, key("poles"))
        if poles % 2:
            raise err("poles", f"{poles} poles: the number of magnet poles is even (pole pairs p = poles/2)")
        if p is not None and p != poles // 2:
            raise err("poles", f"{poles} poles are {poles // 2} pole pairs, but {key('p')} = {p}")
        if p is None:
            p = poles // 2
            source["p"] = key("poles")
            rules["p"] = f"poles/2 from poles = {poles}"
    assert p is not None
    if p > MAX_POLE_PAIRS:
        raise err(
            source["p"].split(".")[-1], f"{p} pole pairs: more than {MAX_POLE_PAIRS} (no motor has as many)"
        )

    # windings
    connection = choice("connection", CONNECTIONS) if "connection" in t else None

    def line_line(k: str) -> float:
        if connection is None:
            raise err(
                "connection",
                f"missing key: {key(k)} (between two terminals) needs connection = 'wye' or 'delta'",
            )
        return qty(k, "resistance" if k == "R_ll" else "inductance")

    if "R_s" in t and "R_ll" in t:
        raise err("R_ll", f"give one of {key('R_s')} (per phase) and {key('R_ll')} (line to line), not both")
    if "R_s" in t:
        R_s = qty("R_s", "resistance")
        source["R_s"] = key("R_s")
    elif "R_ll" in t:
        R_s = line_line("R_ll") / 2
        source["R_s"] = key("R_ll")
        rules["R_s"] = f"R_ll/2 = {t['R_ll']}/2 (equivalent wye, {connection} connection)"
    else:
        raise err("R_s", "missing key (stator resistance: R_s per phase, or R_ll line to line)")

    given_L = [k for k in ("L_s", "L_d", "L_ll") if k in t]
    if len(given_L) > 1 or ("L_q" in t and ("L_s" in t or "L_ll" in t)):
        raise err(
            given_L[-1] if len(given_L) > 1 else "L_q",
            f"give one of {key('L_s')}, {key('L_d')} with {key('L_q')}, or {key('L_ll')}",
        )
    if "L_d" in t or "L_q" in t:
        for k in ("L_d", "L_q"):
            if k not in t:
                raise err(k, f"missing key ({key('L_d')} and {key('L_q')} go together; L_s if equal)")
        L_d, L_q = qty("L_d", "inductance"), qty("L_q", "inductance")
        source.update(L_d=key("L_d"), L_q=key("L_q"))
    elif "L_s" in t:
        L_d = L_q = qty("L_s", "inductance")
        source.update(L_d=key("L_s"), L_q=key("L_s"))
        rules["L_d"] = rules["L_q"] = f"L_d = L_q = L_s = {t['L_s']} (non-salient)"
    elif "L_ll" in t:
        L_d = L_q = line_line("L_ll") / 2
        source.update(L_d=key("L_ll"), L_q=key("L_ll"))
        rules["L_d"] = rules["L_q"] = f"L_ll/2 = {t['L_ll']}/2 (equivalent wye, {connection}; non-salient)"
    else:
        raise err("L_d", "missing key (inductance: L_s per phase, L_d and L_q, or L_ll line to line)")

    # PM flux: every form given, checked against the first
    if "emf_convention" in t and "kE" not in t and "KV" not in t:
        raise err(
            "emf_convention",
            f"{key('emf_convention')} without {key('kE')} or {key('KV')}: it states their convention",
        )
    if "torque_convention" in t and "kT" not in t:
        raise err(
            "torque_convention",
            f"{key('torque_convention')} without {key('kT')}: it states the convention of kT",
        )
    fluxes: list[tuple[str, float, str]] = []  # (key, psi_pm, rule)
    if "psi_pm" in t:
        fluxes.append(("psi_pm", qty("psi_pm", "flux"), ""))
    if "kE" in t:
        if "emf_convention" not in t:
            raise err(
                "emf_convention",
                f"missing key: {key('kE')} needs its convention, one of "
                f"{', '.join(repr(c) for c in EMF_CONVENTIONS)} (docs/motor_data.md)",
            )
        conv = choice("emf_convention", EMF_CONVENTIONS)
        psi = emf_to_psi(qty("kE", "emf_constant"), conv, p)
        fluxes.append(("kE", psi, f"{_EMF_RULE[conv]}, kE = {t['kE']} ({conv}, per mechanical speed)"))
    if "KV" in t:
        # KV is r/min per volt of the back-EMF measure emf_convention states (line-line peak if none)
        conv = choice("emf_convention", EMF_CONVENTIONS) if "emf_convention" in t else "line-line peak"
        psi = kv_to_psi(qty("KV", "speed_constant"), p, conv)
        fluxes.append(("KV", psi, f"{_KV_RULE[conv]}, KV = {t['KV']} ({conv} back-EMF)"))
    if "kT" in t:
        if "torque_convention" not in t:
            raise err(
                "torque_convention",
                f"missing key: {key('kT')} needs its convention: 'rms' (N m per A rms) or 'peak' "
                "(N m per A amplitude)",
            )
        conv = choice("torque_convention", TORQUE_CONVENTIONS)
        psi = kt_to_psi(qty("kT", "torque_constant"), conv, p)
        div = "1.5 sqrt(2) p" if conv == "rms" else "1.5 p"
        fluxes.append(("kT", psi, f"kT/({div}), kT = {t['kT']} per A {conv}"))
    if not fluxes:
        raise err(
            "psi_pm",
            "missing key (PM flux: psi_pm, or kE with emf_convention, KV, or kT with torque_convention)",
        )
    k0, psi_pm, rule0 = fluxes[0]
    for k, psi, _ in fluxes[1:]:
        if abs(psi / psi_pm - 1) > FLUX_TOLERANCE:
            raise err(
                k,
                f"implies psi_pm = {psi:.5g} Vs, but {key(k0)} implies {psi_pm:.5g} Vs: they differ by "
                f"{100 * abs(psi / psi_pm - 1):.0f} % (tolerance {100 * FLUX_TOLERANCE:.0f} %); check the "
                "conventions (line-line or phase, rms or peak, poles or pole pairs; docs/motor_data.md)",
            )
    source["psi_pm"] = key(k0)
    if rule0:
        rules["psi_pm"] = rule0
    if len(fluxes) > 1:
        others = ", ".join(f"{k} {psi:.5g} Vs" for k, psi, _ in fluxes[1:])
        rules["psi_pm"] = (rule0 + "; " if rule0 else "") + f"agrees with {others}"

    if "J" not in t:
        raise err("J", "missing key (moment of inertia: kg m2, kg cm2 or g cm2)")
    J = qty("J", "inertia")
    source["J"] = key("J")
    return MotorData(p, R_s, L_d, L_q, psi_pm, J, source, rules)


def _integer(v: object, file: str, key: str) -> int:
    x, _ = parse_quantity(v, "integer", file=file, key=key)
    if x < 1:
        raise DriveFileError(file, key, f"non-physical value {v}: must be >= 1")
    return int(x)


# --------------------------------------------------------------------------------------------------
# The rated point (MTPA current and steady voltage), for the plausibility checks and derived drives
# --------------------------------------------------------------------------------------------------
def mtpa_torque_current(T: float, motor: PmsmMotor) -> tuple[float, float]:
    """(i_d, i_q) [A, peak] of the MTPA current for torque ``T`` [N m]: the shared steady current
    (design/rotor_frame.py ``steady_current_function``, symbolic/pmsm.py), evaluated."""
    from sensorless.design.rotor_frame import pmsm_plant, steady_current_function

    i = steady_current_function()(T, pmsm_plant(motor))
    return float(i[0]), float(i[1])


_MTPA_TORQUE: dict[tuple[float, ...], float] = {}


def mtpa_torque(i_peak: float, motor: PmsmMotor) -> float:
    """MTPA torque [N m] at the current amplitude ``i_peak`` [A] (bisection on the torque). Memoized on
    the numbers it reads: its 80 evaluations are most of the time a drive file takes to load, and each
    command loads its drive again."""
    key = (float(i_peak), float(motor.p), motor.psi_pm, motor.L_d, motor.L_q, *map(float, motor.vector()))
    if key not in _MTPA_TORQUE:
        if len(_MTPA_TORQUE) >= 256:
            _MTPA_TORQUE.clear()
        _MTPA_TORQUE[key] = _mtpa_torque(i_peak, motor)
    return _MTPA_TORQUE[key]


def _mtpa_torque(i_peak: float, motor: PmsmMotor) -> float:
    hi = 1.5 * motor.p * motor.psi_pm * i_peak * 4 + 1e-12
    if abs(motor.L_q - motor.L_d) > 0:
        hi += 1.5 * motor.p * abs(motor.L_q - motor.L_d) * i_peak**2
    lo = 0.0
    for _ in range(80):
        mid = (lo + hi) / 2
        i_d, i_q = mtpa_torque_current(mid, motor)
        if math.hypot(i_d, i_q) > i_peak:
            hi = mid
        else:
            lo = mid
    return lo


@functools.cache
def _voltage_function() -> ca.Function:
    """casadi.Function (w, [i_d, i_q], [R_s, L_d, L_q, psi_pm]) -> |u_s|: the steady stator voltage,
    eq. (1) with dpsi/dt = 0 in rotor coordinates and the flux of (2) (symbolic/pmsm.py)."""
    import casadi as ca
    from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, stator_voltage

    w, i, m = ca.SX.sym("w"), ca.SX.sym("i", 2), ca.SX.sym("motor", 4)
    par = PmsmParams.of(m)
    u = stator_voltage(i, 0, flux_from_current(i, par), w, par.R_s)
    return ca.Function("steady_voltage", [w, i, m], [ca.norm_2(u)])


def steady_voltage(motor: PmsmMotor, w: float, i_d: float, i_q: float) -> float:
    """Peak phase voltage [V] of the motor in steady state at electrical speed ``w`` and current
    (i_d, i_q) [A peak] (symbolic/pmsm.py ``stator_voltage``, evaluated)."""
    return float(_voltage_function()(w, [i_d, i_q], motor.vector()))
