"""The complete drive file of the reduced-order observer from a minimal one, each value with its rule.

A minimal drive file gives ``[drive]`` (name, kind), ``[motor]`` in datasheet terms (motor.py,
design/motor_data.py; the EMF is sinusoidal unless the file gives ``harmonics`` and ``Phi``),
``[rating]`` n_N and T_N or I_N, and ``[inverter]`` u_dc and f_s (the sampling frequency).
:func:`document` fills in every other key of the schema (schema.py) by the rules below, scaled by the
motor and the sampling rate, and keeps every key the file does give (a full drive file passes through
unchanged). The loader reads the document's data, so a minimal file and the complete file ``sensorless
init`` writes from it load to the same drive. Rules, reasons and the paper's numbers:
docs/families/pmac_reduced_order.md ("Derived drive files"); speeds there are mechanical r/min, eq. (2)
in the mechanical reading, Phi_1 in V s per mechanical radian (motor.py).

- ``[motor]``: R = R_s, L = L_s (per phase, equivalent wye); reading "mechanical"; Phi_1 = sqrt(3/2) p
  psi_pm; harmonics [1]; B = 0 (viscosity is part of the load the observer estimates, Section II).
- ``[rating]``: P_N = T_N 2 pi n_N / 60; T_N from I_N: 1.5 p psi_pm sqrt(2) I_N (the fundamental).
- ``[estimate]``: the motor's values (exact estimates).
- ``[observer]``: linearized, the error dynamics (9)-(10) have the poles -g and the roots of
  s^2 + g s + Gamma (Phi_1/J)^2 (hand derivation, docs). tau_m = J w_N / T_N (mechanical time
  constant, rated speed at rated torque).
  g = max(0.072/T_s, 50/tau_m), at most 0.2/T_s: the paper's g T_s (400 1/s x 180 us), which sets the
  noise the estimates carry; but at least 50/tau_m, because before the load estimate catches up a load
  step dT moves the speed estimate by dT/(J g), 1/(g tau_m) p.u. for a rated one (eq. (36): g above
  gamma L_phi, with gamma = T_L/J and L_phi ~ 1/omega: that error must stay below the speed).
  The slow (load-torque) root s_T = min(48.55/tau_m, g/4): the paper's s_T tau_m (10.64 1/s x 4.56 s),
  at most g/4 (both roots real and apart, at g/4 and 3g/4); Gamma = s_T (g - s_T) (J/Phi_1)^2 puts it
  there. On the paper's motor: g = 400 1/s, Gamma = 9999.9 A^2 s^2 (the paper: 400 and 10000).
- ``[control]``: T_s = 1/f_s; discretization "rk2-model" (the family's default); speed loop alpha_s =
  min(5/tau_m, g/10): fast enough that a rated load change does not swing the speed through zero (the
  observer loses the rotor there), slower than the speed estimate it closes on; T_max = 2 T_N (as the
  preset); u_dc kept for the plausibility checks.
- ``[envelope]``: speeds -0.25, 0.025, 0.1, 0.25 and 1 p.u. of n_N (both directions, down to the
  paper's lowest test speed 0.025 p.u.), loads 0, T_N and -T_N.
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Mapping
from typing import Any

import numpy as np
from sensorless.design.drive_file import (
    DriveDocument,
    Entry,
    check_keys,
    derived_document,
    g6,
    positive,
    sampling_frequency,
    table,
    toml_value,
)
from sensorless.design.motor_data import mtpa_torque
from sensorless.design.plausibility import plausibility, warning_lines
from sensorless.design.pmac_reduced_order.motor import read_pmac_motor
from sensorless.design.pmac_reduced_order.schema import SECTIONS, PmacDrive, harmonic_series, load_complete
from sensorless.design.units import DriveFileError

# the rules (module docstring)
G_TS = 0.072  # g T_s: De Angelo et al. (2006), 400 1/s at 180 us
G_TAU = 50.0  # g tau_m at least: a rated load step moves the speed estimate by 1/(g tau_m) p.u., eq. (36)
G_TS_MAX = 0.2  # g T_s at most (f_s/5)
S_TAU = 48.55  # slow pole x tau_m: the paper's gains on its motor, 10.64 1/s x 4.561 s
S_G_MAX = 0.25  # slow pole at most g/4: roots g/4 and 3g/4, damping 1.15
ALPHA_S_TAU = 5.0  # speed-loop bandwidth x tau_m
ALPHA_S_G = 0.1  # speed loop at most g/10: slower than the speed estimate it closes on
T_MAX_TN = 2.0
SPEEDS_PU = (-0.25, 0.025, 0.1, 0.25, 1.0)
LOADS_TN = (0.0, 1.0, -1.0)

RATING = {"P_N": "power", "n_N": "mech_speed", "T_N": "torque", "I_N": "current", "f_N": "frequency"}
MOTOR_ORDER = ("p", "reading", "R", "L", "J", "B", "harmonics", "Phi")
INVERTER = ("u_dc", "f_s")


def _with_unit(x: float, units: tuple[tuple[str, float, float], ...]) -> str:
    """``x`` (SI) with 6 significant digits in the first of ``units`` (name, size, from) it reaches."""
    name, size, _ = next((u for u in units if x >= u[2]), units[-1])
    return f"{g6(x / size)} {name}"


def document(data: Mapping[str, Any], file: str) -> DriveDocument:
    """The complete drive document of ``data`` (module docstring); DriveFileError naming the key for
    what is missing or wrong. Each key given is kept as written; each derived one carries its rule."""
    check_keys(data, (*SECTIONS, "inverter"), file, "")
    doc = derived_document(data, file, "docs/families/pmac_reduced_order.md")

    # ------------------------------------------------------------------ motor
    motor_t = table(data, "motor", file)
    pm = read_pmac_motor(motor_t, file)
    m = pm.m
    sec = doc.section("motor", "the true motor, eqs. (2)-(5) (docs/families/pmac_reduced_order.md)")
    if any(k not in MOTOR_ORDER for k in motor_t):
        given = "given as: " + ", ".join(f"{k} = {toml_value(v)}" for k, v in motor_t.items())
        doc.notes["motor"] += textwrap.wrap(given, 100)
    derived_motor = {
        "p": (m.p, m.rules.get("p", "")),
        "reading": ("mechanical", "omega, J, B, T_L and Phi_n of eq. (2) per mechanical radian"),
        "R": (
            _with_unit(m.R_s, (("ohm", 1.0, 0.1), ("mohm", 1e-3, 0.0))),
            m.rules.get("R_s", f"= {m.source['R_s']}, per phase (equivalent wye)"),
        ),
        "L": (_with_unit(pm.L, (("H", 1.0, 1.0), ("mH", 1e-3, 1e-3), ("uH", 1e-6, 0.0))), pm.L_rule),
        "J": (motor_t.get("J"), ""),
        "B": ("0 kg m^2/s", "viscosity: part of the load the observer estimates (Section II)"),
        "harmonics": ([1], "sinusoidal EMF: the fundamental only, eq. (4)"),
        "Phi": ([f"{g6(pm.Phi_1)} Vs"], pm.Phi_rule),
    }
    for k, (v, rule) in derived_motor.items():
        sec[k] = Entry(motor_t[k], given=True) if k in motor_t else Entry(v, rule)

    # ------------------------------------------------------------------ rating
    rating_t = table(data, "rating", file)
    check_keys(rating_t, tuple(RATING), file, "rating.")
    if "n_N" not in rating_t:
        raise DriveFileError(file, "rating.n_N", "missing key (rated mechanical speed, e.g. '3000 rpm')")
    n_N = positive(rating_t, "n_N", "mech_speed", file, "rating")
    w_Nm = 2 * math.pi * n_N / 60
    rule_P = "T_N 2 pi n_N / 60"
    if "T_N" in rating_t:
        T_N = positive(rating_t, "T_N", "torque", file, "rating")
    elif "P_N" in rating_t:
        T_N = positive(rating_t, "P_N", "power", file, "rating") / w_Nm
    elif "I_N" in rating_t:
        T_N = float(g6(mtpa_torque(math.sqrt(2) * positive(rating_t, "I_N", "current", file, "rating"), m)))
        rule_P += f", T_N = {g6(T_N)} Nm = 1.5 p psi_pm sqrt(2) I_N"
    else:
        raise DriveFileError(
            file, "rating.T_N", "missing key (rated torque T_N, or the rated current I_N in A rms)"
        )
    sec = doc.section("rating", "rated values; 1 p.u. speed = the rated speed n_N")
    sec["P_N"] = (
        Entry(rating_t["P_N"], given=True) if "P_N" in rating_t else Entry(f"{g6(T_N * w_Nm)} W", rule_P)
    )
    sec.update({k: Entry(v, given=True) for k, v in rating_t.items() if k != "P_N"})
    tau_m = m.J * w_Nm / T_N  # physical J: rated speed at rated torque, the mechanical time constant

    # ------------------------------------------------------------------ sampling and DC link
    inv_t = table(data, "inverter", file) if "inverter" in data else {}
    check_keys(inv_t, INVERTER, file, "inverter.")
    ctl_t = table(data, "control", file) if "control" in data else {}
    f_s, T_s_key = sampling_frequency(inv_t, ctl_t, file)
    u_dc, u_dc_key = _dc_link(inv_t, ctl_t, file)

    # ------------------------------------------------------------------ estimate
    est_t = table(data, "estimate", file) if "estimate" in data else {}
    sec = doc.section("estimate", "the observer's model of the motor (kept apart from the true one)")
    for k in ("R", "L", "J", "harmonics", "Phi"):
        sec[k] = (
            Entry(est_t[k], given=True) if k in est_t else Entry(doc.sections["motor"][k].value, "= [motor]")
        )
    _extra(sec, est_t)
    J_hat = positive(est_t, "J", "inertia", file, "estimate") if "J" in est_t else m.J * (pm.p_r / m.p) ** 2
    Phi_hat = harmonic_series(est_t, file, "estimate")[1][0] if "Phi" in est_t else pm.Phi_1

    # ------------------------------------------------------------------ observer
    obs_t = table(data, "observer", file) if "observer" in data else {}
    g_rule = min(max(G_TS * f_s, G_TAU / tau_m), G_TS_MAX * f_s)
    g = positive(obs_t, "g", "rate", file, "observer") if "g" in obs_t else g_rule
    s_T = min(S_TAU / tau_m, S_G_MAX * g)
    Gamma = s_T * (g - s_T) * (J_hat / Phi_hat) ** 2
    sec = doc.section(
        "observer", "observer gains, eqs. (9)-(10); poles -g and s^2 + g s + Gamma (Phi_1/J)^2 = 0"
    )
    cap = " = g/4 (cap)" if s_T < S_TAU / tau_m else ""
    derived_obs = {
        "g": (
            f"{g6(g)} 1/s",
            f"max({G_TS:g}/T_s, {G_TAU:g}/tau_m), at most {G_TS_MAX:g}/T_s (De Angelo et al.: 400 1/s at "
            "180 us), eqs. (9), (36)",
        ),
        "Gamma": (
            f"{g6(Gamma)} A^2 s^2",
            f"s_T (g - s_T) (J/Phi_1)^2: slow pole s_T = min({S_TAU:g}/tau_m, g/4) = {g6(s_T)} 1/s{cap}, "
            f"tau_m = J w_N/T_N = {g6(tau_m)} s (De Angelo et al.: 1e4, 10.64 1/s, 4.56 s), eq. (10)",
        ),
    }
    for k, (v, rule) in derived_obs.items():
        sec[k] = Entry(obs_t[k], given=True) if k in obs_t else Entry(v, rule)
    _extra(sec, obs_t)

    # ------------------------------------------------------------------ control
    alpha_s = min(ALPHA_S_TAU / tau_m, ALPHA_S_G * g)
    sec = doc.section("control", "sampling, discretization and the speed loop of Fig. 1")
    derived_ctl: dict[str, tuple[object, str]] = {
        "T_s": (f"{g6(1e6 / f_s)} us", f"1/f_s, f_s = {g6(f_s / 1e3)} kHz"),
        "discretization": ("rk2-model", "the family's default (docs/families/pmac_reduced_order.md)"),
        "alpha_s": (
            f"{g6(alpha_s / (2 * math.pi))} Hz",
            f"speed PI min({ALPHA_S_TAU:g}/tau_m, g/{1 / ALPHA_S_G:g}), tau_m = {g6(tau_m)} s",
        ),
        "T_max": (f"{g6(T_MAX_TN * T_N)} Nm", "2 T_N (as the preset deangelo2006)"),
    }
    if u_dc is not None:
        derived_ctl["u_dc"] = (inv_t.get("u_dc"), "from [inverter] u_dc: the plausibility checks")
    for k, (v, rule) in derived_ctl.items():
        sec[k] = Entry(ctl_t[k], given=True) if k in ctl_t else Entry(v, rule)
    _extra(sec, ctl_t)
    if u_dc is None:
        doc.optional.setdefault("control", []).append(
            'u_dc = "..."  # optional: the DC-link voltage; without it the voltage checks are skipped'
        )
    if "i_noise" not in ctl_t:
        doc.optional.setdefault("control", []).append(
            'i_noise = "..."  # optional: current-sensor noise, A rms per axis and sample (default 0.3 % '
            "of the current at T_N)"
        )

    # ------------------------------------------------------------------ envelope
    env_t = table(data, "envelope", file) if "envelope" in data else {}
    sec = doc.section("envelope", "operating points analysed by default (mechanical speeds, load torques)")
    derived_env = {
        "speeds": (
            [f"{g6(x * n_N)} rpm" for x in SPEEDS_PU],
            f"{', '.join(f'{x:g}' for x in SPEEDS_PU)} p.u. of n_N (the paper's tests reach 0.025 p.u.)",
        ),
        "loads": ([f"{g6(x * T_N)} Nm" for x in LOADS_TN], "0, T_N, -T_N"),
    }
    for k, (v, rule) in derived_env.items():
        sec[k] = Entry(env_t[k], given=True) if k in env_t else Entry(v, rule)
    _extra(sec, env_t)
    w_top = max(abs(x) for x in SPEEDS_PU) * w_Nm * m.p
    if "speeds" not in env_t and w_top / f_s >= math.pi / 2:
        raise DriveFileError(
            file,
            f"{T_s_key}, rating.n_N",
            f"{2 * math.pi * f_s / w_top:.3g} samples per electrical period at n_N: the speed sign (14) "
            "needs more than 4; sample faster",
        )

    doc.context["motor"] = m
    doc.context["keys"] = {
        "n_N": "rating.n_N",
        "T_N": next(f"rating.{k}" for k in ("T_N", "P_N", "I_N") if k in rating_t),
        "I_N": "rating.I_N",
        "f_N": "rating.f_N",
        "u_dc": u_dc_key,
        "T_s": T_s_key,
        "w_max": "envelope.speeds",
    }
    doc.context["given"] = {
        "I_N": "I_N" in rating_t and ("T_N" in rating_t or "P_N" in rating_t),
        "f_N": "f_N" in rating_t,
    }
    return doc


def _extra(sec: dict[str, Entry], given: Mapping[str, Any]) -> None:
    """Keys given beyond the derived ones, kept (the strict loader names them if unknown)."""
    for k, v in given.items():
        if k not in sec:
            sec[k] = Entry(v, given=True)


def _dc_link(inv: Mapping[str, Any], ctl: Mapping[str, Any], file: str) -> tuple[float | None, str]:
    """(DC-link voltage [V] or None, the key it came from): [inverter] u_dc or [control] u_dc."""
    v_inv = positive(inv, "u_dc", "voltage", file, "inverter") if "u_dc" in inv else None
    v_ctl = positive(ctl, "u_dc", "voltage", file, "control") if "u_dc" in ctl else None
    if v_inv is not None and v_ctl is not None and abs(v_inv / v_ctl - 1) > 1e-9:
        raise DriveFileError(file, "inverter.u_dc", "differs from control.u_dc: give one of them")
    return (v_inv, "inverter.u_dc") if v_inv is not None else (v_ctl, "control.u_dc")


def check_plausibility(drive: PmacDrive, context: Mapping[str, Any]) -> list[str]:
    """Warning lines of the plausibility checks (design/plausibility.py) of a loaded drive; DriveFileError
    for the first error (naming its keys). Without a DC-link voltage the voltage checks are skipped."""
    r, c, keys, given = drive.rating, drive.control, context["keys"], context["given"]
    findings = plausibility(
        context["motor"],
        n_N=r.n_N,
        T_N=drive.T_N,
        I_N=r.I_N if given["I_N"] else None,
        f_N=r.f_N if given["f_N"] else None,
        u_dc=c.u_dc or math.inf,
        T_s=c.T_s,
        w_max=float(np.max(np.abs(drive.envelope.speed_grid()))),
        keys=keys,
    )
    return warning_lines(findings, drive.file)


def load(data: Mapping[str, Any], file: str, digest: str, kind: str) -> PmacDrive:
    """Validate a parsed drive TOML of this family: a minimal one is completed first (derive.py), then
    the complete data is loaded strictly and checked for plausibility (design/plausibility.py)."""
    doc = document(data, file)
    with doc.blaming_given_keys(data, file):
        drive = load_complete(doc.data(), file, digest, kind)
    warnings = check_plausibility(drive, doc.context)
    return dataclasses.replace(drive, warnings=tuple(warnings)) if warnings else drive
