"""ODrive: an odrivetool configuration backup read into a drive file, and tuned values written back.

``odrivetool backup-config`` writes nested JSON (``axis0.motor.config.pole_pairs``,
``axis0.sensorless_estimator.config.observer_gain``, ...) with ``Infinity`` and ``NaN`` literals; the
export writes the same attributes as a flat JSON of paths and as odrivetool lines, and both read back.
The conventions converted here (ODrive v3: github.com/odriverobotics/ODrive,
``Firmware/MotorControl/sensorless_estimator.cpp``, and its documentation):

- ``motor.config.pole_pairs`` is pole pairs; ``phase_resistance``, ``phase_inductance`` are per phase
  of the equivalent wye, one inductance (no saliency);
- ``sensorless_estimator.config.pm_flux_linkage`` [V s] is documented as 5.51328895422 / (pole_pairs
  KV), KV in rpm/V (line-line peak: design/motor_data.py kv_to_psi); ``motor.config.torque_constant``
  [N m/A] is 1.5 pole_pairs psi_pm per ampere of current amplitude (8.27 / KV); factory defaults
  1.58e-3 V s and 0.04 N m/A: a default beside a value the user set is not used;
- ``observer_gain`` = gamma lambda^2 [1/s] and ``pll_bandwidth`` [rad/s] (kp = 2 bw,
  ki = kp^2/4), default 1000 each; the firmware refuses T kp >= 1 (ERROR_UNSTABLE_GAIN), and its
  forward Euler step is unstable for T observer_gain >= 2;
- the loop runs at 8 kHz on v3 boards (the backup does not hold it: --f-s);
- the ramped velocity input (``controller.config.input_mode`` = 2, INPUT_MODE_VEL_RAMP, with
  ``controller.config.vel_ramp_rate`` [turn/s^2, mechanical]: "Ramped velocity control", ODrive v0.5
  documentation, docs.odriverobotics.com/v/0.5.6/control-modes.html) is the speed reference's rate
  limiter (``[control] speed_ramp``, design/speed_ramp.py): 2 pi pole_pairs vel_ramp_rate rad/s^2
  electrical; another input mode passes the command, and the drive file gets none;
- the open-loop start ``config.sensorless_ramp`` (``[startup]``, design/startup.py): ``current`` [A],
  ``accel`` [rad/s^2] and ``vel`` [rad/s], electrical: the I-f start's current, acceleration and
  handover speed w_on. ODrive does not return to open loop (sensorless "does not support stopping or
  changing direction"): w_off has no field.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sensorless.design.drive_file import Entry
from sensorless.design.motor_data import kt_to_psi
from sensorless.design.pmsm_flux_observer.firmware import (
    POLE_PAIRS_RANGE,
    Fields,
    FirmwareDrive,
    Imported,
    Missing,
    check_limit,
    choose_flux,
    drive_document,
    inertia,
    kv_candidates,
    quantity,
    rated_from_limit,
    startup_entries,
    stored,
)
from sensorless.design.units import DriveFileError

MOTOR = "axis0.motor.config."
ESTIMATOR = "axis0.sensorless_estimator.config."
RAMP = "axis0.config.sensorless_ramp."
CONTROLLER = "axis0.controller.config."
INPUT_MODE_VEL_RAMP = 2  # ODrive v0.5's InputMode enum
FACTORY = {  # firmware defaults: a value still at its default was never set
    ESTIMATOR + "pm_flux_linkage": 1.58e-3,
    MOTOR + "torque_constant": 0.04,
    ESTIMATOR + "observer_gain": 1000.0,
    ESTIMATOR + "pll_bandwidth": 1000.0,
}
F_S_V3 = 8e3  # Hz: the v3 boards' current loop


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """Nested JSON objects as dotted attribute paths (a flat export is already flat)."""
    if not isinstance(data, dict):
        return {prefix.rstrip("."): data}
    out: dict[str, Any] = {}
    for k, v in data.items():
        out.update(flatten(v, f"{prefix}{k}."))
    return out


def fields(text: str, file: str) -> dict[str, Any]:
    """The attribute paths of an odrivetool backup (``Infinity``, ``NaN`` read as floats)."""
    try:
        data = json.loads(text)
        if not isinstance(data, dict):
            raise DriveFileError(file, "(top level)", "not a JSON object of odrivetool settings")
        return flatten(data)
    except json.JSONDecodeError as e:
        raise DriveFileError(file, "(syntax)", f"not valid JSON: {e}") from None
    except RecursionError:  # the parser's (or flatten's) recursion: a backup nests a few levels
        raise DriveFileError(
            file, "(structure)", "JSON nested deeper than Python can read: not an odrivetool backup"
        ) from None


def read(text: str, file: str, given: Mapping[str, Any], kind: str) -> Imported:
    """The minimal drive file of an odrivetool configuration backup (module docstring); ``given``: the
    values of the import options (pole_pairs, u_dc, J, KV, f_s, name) that were given."""
    f = Fields(fields(text, file), file)
    notes: list[str] = []
    motor: dict[str, Entry] = {}

    if MOTOR + "motor_type" in f:
        mt = f.number(MOTOR + "motor_type", positive=False)
        if mt == 3:
            raise f.error(MOTOR + "motor_type", "3 (ACIM): an induction motor, not a PM motor")
    missing = Missing(file)  # every value the file lacks and no option supplies, named in one error
    pp = f.integer(MOTOR + "pole_pairs")
    if not given.get("pole_pairs") and pp is None:
        missing.add(MOTOR + "pole_pairs", "give --pole-pairs")
    R = f.number(MOTOR + "phase_resistance")
    L = f.number(MOTOR + "phase_inductance")
    for name, x in (("phase_resistance", R), ("phase_inductance", L)):
        if x is None:
            missing.add(MOTOR + name, "run the motor calibration (odrivetool) or type the value")
    if not given.get("u_dc"):
        missing.add("(bus voltage)", "an odrivetool backup holds no bus voltage: give --u-dc")
    missing.check()
    assert R is not None and L is not None
    if given.get("pole_pairs"):
        p = int(given["pole_pairs"])
        if pp is not None and pp != p:
            notes.append(f"--pole-pairs {p} used; the file's pole_pairs = {pp} differs")
        motor["p"] = Entry(p, "--pole-pairs")
    else:
        assert pp is not None
        f.within(MOTOR + "pole_pairs", pp, POLE_PAIRS_RANGE, "pole pairs")
        p = pp
        motor["p"] = Entry(p, "motor.config.pole_pairs")

    motor["R_s"] = Entry(quantity(R, "ohm"), "motor.config.phase_resistance")
    motor["L_d"] = Entry(quantity(L, "H"), "motor.config.phase_inductance (one inductance: L_d = L_q)")
    motor["L_q"] = Entry(quantity(L, "H"), "motor.config.phase_inductance (one inductance: L_d = L_q)")

    def default(key: str, x: float | None) -> bool:
        return x is not None and math.isclose(x, FACTORY[key], rel_tol=1e-6)  # the firmware stores float32

    psi_fw = f.number(ESTIMATOR + "pm_flux_linkage")
    kT = f.number(MOTOR + "torque_constant")
    candidates: list[tuple[str, float | None, bool, str]] = [
        (
            "pm_flux_linkage",
            psi_fw,
            default(ESTIMATOR + "pm_flux_linkage", psi_fw),
            "sensorless_estimator.config.pm_flux_linkage",
        ),
        (
            "torque_constant",
            None if kT is None else kt_to_psi(kT, "peak", p),
            default(MOTOR + "torque_constant", kT),
            f"torque_constant/(1.5 pole_pairs), torque_constant = {kT!r} N m/A",
        ),
    ]
    candidates += kv_candidates(given, p, "5.51328895422/(pole_pairs KV)")
    psi, rule, flux_notes = choose_flux(candidates, file, "--KV (rpm/V)")
    motor["psi_pm"] = Entry(quantity(psi, "Wb"), rule)
    notes += flux_notes
    inertia(given, motor, notes, "an odrivetool backup")

    f_s = float(given.get("f_s") or F_S_V3)
    if not given.get("f_s"):
        notes.append(f"loop frequency not in the backup: assumed {F_S_V3:g} Hz (ODrive v3); give --f-s")
    inverter = {
        "u_dc": Entry(quantity(float(given["u_dc"]), "V"), "--u-dc"),
        "f_s": Entry(quantity(f_s, "Hz"), "--f-s" if given.get("f_s") else "ODrive v3 current loop"),
    }
    observer = {
        "firmware": Entry("odrive"),
        "correction": Entry("gradient", "ODrive: gradient correction, no clamp"),
        "inductance": Entry("fixed", "one phase_inductance"),
        "lambda_adaptation": Entry(False),
        "T_obs": Entry(quantity(1 / f_s, "s"), "1/f_s: once per current-loop period"),
    }
    gains: dict[str, Entry] = {"law": Entry("constant")}
    for key, unit in (("observer_gain", "1/s"), ("pll_bandwidth", "rad/s")):
        x = f.number(ESTIMATOR + key)
        if x is None:
            x = FACTORY[ESTIMATOR + key]
            notes.append(f"{key} missing: assumed the firmware default {x:g} {unit}")
        gains[key] = Entry(quantity(x, unit), "sensorless_estimator.config." + key)

    rating: dict[str, Entry] = {}
    lim = f.values.get(MOTOR + "current_lim")
    if isinstance(lim, int | float) and not isinstance(lim, bool) and math.isfinite(lim) and lim > 0:
        rating["I_N"] = rated_from_limit(lim, "current_lim")
    elif lim is not None:
        notes.append(f"current_lim = {lim!r}: no rated current taken from it")
    header = [
        f"imported from {Path(file).name} (odrivetool configuration backup) by sensorless init --from odrive",
        "each converted value has its rule as a comment (docs/families/pmsm_flux_observer_firmware.md)",
    ]
    startup = startup_entries(
        f.number(RAMP + "current"),
        f.number(RAMP + "accel"),
        f.number(RAMP + "vel"),
        None,
        {
            k: f"config.sensorless_ramp.{v}"
            for k, v in (("current", "current"), ("acceleration", "accel"), ("w_on", "vel"))
        },
        (float(given["u_dc"]), psi),
        notes,
    )
    control: dict[str, Entry] = {}
    mode = f.number(CONTROLLER + "input_mode", positive=False)
    rate = f.number(CONTROLLER + "vel_ramp_rate")
    if mode == INPUT_MODE_VEL_RAMP and rate is not None:
        control["speed_ramp"] = Entry(
            quantity(2 * math.pi * p * rate, "rad/s^2"),
            "2 pi pole_pairs controller.config.vel_ramp_rate (turn/s^2; input_mode VEL_RAMP)",
        )
    sections = {
        "drive": {
            "name": Entry(str(given.get("name") or Path(file).stem)),
            "kind": Entry(kind),
            "source": Entry(f"odrivetool configuration backup {Path(file).name}"),
        },
        "motor": motor,
        "rating": rating,
        "inverter": inverter,
        "observer": observer,
        "gains": gains,
        "control": control,
        "startup": startup,
    }
    return Imported(drive_document(header, sections), tuple(notes))


def export(d: FirmwareDrive) -> tuple[dict[str, str], list[str]]:
    """``odrive.json`` (attribute path -> value) and ``odrivetool.txt`` (the same as odrivetool lines)
    of the drive's motor values and law ``constant`` gains (ODrive's terms); a DriveFileError (one line)
    where the gains break the firmware's own limits (T kp < 1 with kp = 2 pll_bandwidth; T observer_gain
    < 2)."""
    check_limit(
        d.law == "constant",
        d.source,
        "law",
        lambda: f"law {d.law!r}: the odrive target writes law 'constant' gains (tune --law constant)",
    )
    gain, bw = d.gains["observer_gain"], d.gains["pll_bandwidth"]
    T = d.T_obs
    check_limit(
        T * 2 * bw < 1,
        d.source,
        "pll_bandwidth",
        lambda: (
            f"T kp = {T * 2 * bw:.3g} >= 1 (kp = 2 x {bw:g} rad/s, T = {T * 1e6:.4g} us): ODrive flags "
            "ERROR_UNSTABLE_GAIN"
        ),
    )
    check_limit(
        T * gain < 2,
        d.source,
        "observer_gain",
        lambda: (
            f"T observer_gain = {T * gain:.3g} >= 2 (T = {T * 1e6:.4g} us): "
            "the forward Euler step is unstable"
        ),
    )
    notes = []
    L = d.L_q
    if d.L_d != d.L_q:
        notes.append(f"ODrive has one inductance: phase_inductance = L_q = {L:.6g} H (L_d = {d.L_d:.6g} H)")
    values = {
        MOTOR + "pole_pairs": d.p,
        MOTOR + "phase_resistance": d.R_s,
        MOTOR + "phase_inductance": L,
        MOTOR + "torque_constant": 1.5 * d.p * d.psi_pm,
        ESTIMATOR + "pm_flux_linkage": d.psi_pm,
        ESTIMATOR + "observer_gain": gain,
        ESTIMATOR + "pll_bandwidth": bw,
    }
    if d.i_max is not None:  # the torque limit's current: the limit the start and the tuning assumed
        values[MOTOR + "current_lim"] = d.i_max
    if d.startup is not None:  # the I-f start (module docstring); ODrive has no w_off
        values[RAMP + "current"] = d.startup["if_i"]
        values[RAMP + "accel"] = d.startup["if_acc"]
        values[RAMP + "vel"] = d.startup["if_w_on"]
        notes.append(
            f"sensorless_ramp: the I-f start to w_on = {d.startup['if_w_on']:.6g} rad/s; ODrive does not "
            f"fall back to open loop below w_off = {d.startup['if_w_off']:.6g} rad/s (w_min): do not stop "
            "or reverse in sensorless mode"
        )
    # as the firmware stores them (float32), without float noise
    values = {k: v if isinstance(v, int) else float(stored(v)) for k, v in values.items()}
    js = json.dumps(values, indent=2, sort_keys=True) + "\n"
    lines = [f"# sensorless export for odrivetool: drive {d.name}; paste into odrivetool, then save"]
    lines += [f"odrv0.{k} = {v!r}" for k, v in sorted(values.items())]
    lines.append("odrv0.save_configuration()")
    return {"odrive.json": js, "odrivetool.txt": "\n".join(lines) + "\n"}, notes
