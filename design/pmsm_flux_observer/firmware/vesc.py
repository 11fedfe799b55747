"""VESC: VESC Tool's motor configuration XML read into a drive file, and tuned values written back.

The file is ``<MCConfiguration>`` with one element per configuration field, values in SI (VESC Tool's
"save motor configuration XML"). The conventions converted here (VESC Tool's and the VESC firmware's
documented settings: github.com/vedderb/vesc_tool, github.com/vedderb/bldc ``motor/foc_math.c``):

- ``si_motor_poles`` is the number of magnet poles (p = poles / 2); older files lack it (--pole-pairs);
- ``foc_motor_l`` = (L_d + L_q) / 2 and ``foc_motor_ld_lq_diff`` = L_q - L_d, both as detection
  stores them: 0.9 x the measured values ("more stable when the inductance is underestimated"). The
  stored values are what the firmware runs ([estimate]); the motor's are stored / 0.9 (``--l-scale``:
  the factor the file's values carry, 1 for values typed from a datasheet);
- ``foc_motor_flux_linkage`` [Wb] and ``foc_motor_r`` [ohm] are per phase of the equivalent wye;
- ``foc_observer_gain`` is raw: detection stores 1e6 x (1e-3 / lambda^2) = 1000 / lambda^2 and VESC
  Tool shows raw x 1e-6 as "Observer Gain (x1M)"; at run time gamma = 4 x raw x max(gain_slow,
  |duty| V_bus / 40 V), so gamma lambda^2 = 4000 x max(...) with the detection gain;
- the observer and PLL run once per PWM period, T = 2 / ``foc_f_zv`` (f_zv counts both zero vectors),
  or T = 1 / f_zv when ``foc_sample_v0_v7`` samples at both; older files' ``foc_f_sw`` is the same
  setting under its earlier name (the loop runs at half the "switching frequency" set: vedderb/bldc#212);
- ``foc_observer_type``: 0 ORTEGA_ORIGINAL (clamped gradient), 1 MXLEMMING (box clamp),
  2 ORTEGA_LAMBDA_COMP, 3 MXLEMMING_LAMBDA_COMP (with online flux adaptation), 4 MXV and
  5 MXV_LAMBDA_COMP (circular clamp, not modelled: read as the box clamp, with a note);
- the open-loop start (``[startup]``, design/startup.py): ``foc_openloop_rpm`` [ERPM] is the speed the
  open loop drives the motor to and below which it returns to it: the handover speed w_on;
  ``foc_sl_openloop_time`` [s] its duration: w_on / acceleration; VESC's hysteresis is a time,
  ``foc_sl_openloop_hyst`` [s]: the time the I-f ramp takes across the band w_off..w_on, (w_on - w_off) /
  acceleration; ``foc_sl_erpm`` [ERPM] (the observer's lower speed in the hybrid sensor modes) is the
  user's and is not written (firmware/startup.py writes the judged start's fields).
  VESC sets the open loop's current by its own (``foc_sl_openloop_boost_q``, ...): not written;
- ``s_pid_ramp_erpms_s`` [ERPM/s] (firmware 5.2 on): where it is > 0 the speed PID's set point steps
  towards the speed command by at most that times dt (``utils_step_towards`` in ``motor/foc_math.c``
  ``foc_run_pid_control_speed``): the speed reference's rate limiter, ``[control] speed_ramp`` =
  x 2 pi/60 rad/s^2 electrical (design/speed_ramp.py); 0 or below (or absent): none.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from xml.parsers.expat import errors as expat_errors

from sensorless.design.drive_file import Entry
from sensorless.design.pmsm_flux_observer.firmware import (
    F_S_RANGE,
    POLE_PAIRS_RANGE,
    U_DC_RANGE,
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

ROOT = "MCConfiguration"
DETECTION_L_SCALE = 0.9  # detection stores 0.9 x the measured inductances
DETECTION_GAIN = 1e-3  # detection: gain = 1e-3 / lambda^2, stored x 1e6
GAIN_DISPLAY = 1e-6  # VESC Tool shows the raw gain x 1e-6 ("x1M")
SCHEDULE_FACTOR = 4.0  # gamma = 4 raw max(gain_slow, |duty| V_bus / V_SCHEDULE)
OLD_SCHEDULE_FACTOR = 5.0  # the same map's factor in firmware before about 2020
V_SCHEDULE = 40.0  # V
# firmware defaults, used (with a note) where an older file lacks the field
DEFAULTS = {
    "foc_observer_gain_slow": 0.05,
    "foc_pll_kp": 2000.0,
    "foc_pll_ki": 30000.0,
    "foc_f_zv": 25e3,
}
V_PER_CELL = 3.7  # V: nominal li-ion cell, for si_battery_cells when --u-dc is not given
# foc_observer_type -> (name, correction, online flux adaptation)
OBSERVER_TYPES = {
    0: ("ORTEGA_ORIGINAL", "clamped-gradient", False),
    1: ("MXLEMMING", "box-clamp", False),
    2: ("ORTEGA_LAMBDA_COMP", "clamped-gradient", True),
    3: ("MXLEMMING_LAMBDA_COMP", "box-clamp", True),
    4: ("MXV", "box-clamp", False),
    5: ("MXV_LAMBDA_COMP", "box-clamp", True),
}
NOT_MODELLED = (4, 5)


def observer_gain_detection(psi_pm: float) -> float:
    """The raw ``foc_observer_gain`` VESC Tool's detection stores for flux linkage ``psi_pm`` [Wb]."""
    return DETECTION_GAIN / psi_pm**2 / GAIN_DISPLAY


# what the XML parser's errors mean in a configuration file (its own words say "invalid token")
XML_PROBLEMS = {
    expat_errors.XML_ERROR_INVALID_TOKEN: "a character that cannot stand there (an unescaped '<' or '&' in "
    "a value, a stray character before the first tag, or not a text file)",
    expat_errors.XML_ERROR_UNCLOSED_TOKEN: "the file ends inside a tag (cut off?)",
    expat_errors.XML_ERROR_NO_ELEMENTS: "no element, or the file ends before its elements close (empty or "
    "cut off?)",
    expat_errors.XML_ERROR_TAG_MISMATCH: "a closing tag that does not match the element it closes (a tag "
    "misspelt, or one not closed)",
    expat_errors.XML_ERROR_JUNK_AFTER_DOC_ELEMENT: f"text after the closing </{ROOT}> (two configurations in "
    "one file?)",
    expat_errors.XML_ERROR_UNDEFINED_ENTITY: "an undefined entity (&name;): write '&' as '&amp;'",
    expat_errors.XML_ERROR_DUPLICATE_ATTRIBUTE: "an attribute given twice in one tag",
    expat_errors.XML_ERROR_MISPLACED_XML_PI: "the <?xml ...?> declaration is not at the very start",
}


def xml_problem(e: ET.ParseError, text: str) -> str:
    """A malformed XML file's problem in words: what is wrong, where, and the line it is on."""
    line, col = e.position
    message = expat_errors.messages.get(e.code, "")
    what = XML_PROBLEMS.get(message, message or str(e))
    lines = text.splitlines()
    shown = lines[line - 1].strip()[:60] if 0 < line <= len(lines) else ""
    return f"not a readable XML file: {what}, at line {line}, column {col + 1}" + (
        f" ({shown!r})" if shown else ""
    )


def fields(text: str, file: str) -> dict[str, str]:
    """The fields of a VESC Tool motor configuration XML (one-line DriveFileError if it is not one)."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise DriveFileError(file, ROOT, "document type declarations are not read (not a VESC Tool XML)")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise DriveFileError(file, "(syntax)", xml_problem(e, text)) from None
    if root.tag != ROOT:
        raise DriveFileError(file, root.tag, f"the root element is <{root.tag}>, not <{ROOT}>")
    return {child.tag: (child.text or "").strip() for child in root}


def read(text: str, file: str, given: Mapping[str, Any], kind: str) -> Imported:
    """The minimal drive file of a VESC Tool motor configuration XML (module docstring); ``given``:
    the values of the import options (pole_pairs, u_dc, J, KV, l_scale, f_s, name) that were given."""
    f = Fields(fields(text, file), file)
    notes: list[str] = []
    motor: dict[str, Entry] = {}
    estimate: dict[str, Entry] = {}
    missing = Missing(file)  # every value the file lacks and no option supplies, named in one error

    poles = f.integer("si_motor_poles")
    if poles is not None and poles % 2 and not given.get("pole_pairs"):
        raise f.error("si_motor_poles", f"{poles}: the number of magnet poles is even")
    if not given.get("pole_pairs") and poles is None:
        missing.add("si_motor_poles", "an older VESC Tool file has no pole count: give --pole-pairs")
    R = f.number("foc_motor_r")
    L = f.number("foc_motor_l")
    for name, x in (("foc_motor_r", R), ("foc_motor_l", L)):
        if x is None:
            missing.add(name, "run the motor detection in VESC Tool or type the value")
    if f.number("foc_motor_flux_linkage") is None and not given.get("KV"):
        missing.add("foc_motor_flux_linkage", "give --KV (rpm/V, line-line peak)")
    cells = f.integer("si_battery_cells")
    v_max = f.number("l_max_vin")
    if not given.get("u_dc") and cells is None and v_max is None:
        missing.add("si_battery_cells", "no bus voltage in the file (nor l_max_vin): give --u-dc")
    missing.check()
    assert R is not None and L is not None

    if given.get("pole_pairs"):
        p = int(given["pole_pairs"])
        if poles is not None and poles != 2 * p:
            notes.append(f"--pole-pairs {p} used; the file's si_motor_poles = {poles} differs")
        motor["p"] = Entry(p, "--pole-pairs")
        if poles is None:
            notes.append(f"si_motor_poles missing (an older file): {p} pole pairs from --pole-pairs")
    else:
        assert poles is not None
        f.within("si_motor_poles", poles // 2, POLE_PAIRS_RANGE, "pole pairs")
        p = poles // 2
        motor["p"] = Entry(p, f"si_motor_poles/2 = {poles}/2")

    diff = f.number("foc_motor_ld_lq_diff", positive=False)
    if diff is None:
        diff = 0.0
        notes.append("foc_motor_ld_lq_diff missing (an older file): assumed L_d = L_q = foc_motor_l")
    Ld_fw, Lq_fw = L - diff / 2, L + diff / 2
    if not Ld_fw > 0:
        raise f.error("foc_motor_ld_lq_diff", f"{diff!r} H makes L_d = foc_motor_l - diff/2 <= 0")
    scale = float(given.get("l_scale") or DETECTION_L_SCALE)
    motor["R_s"] = Entry(quantity(R, "ohm"), "foc_motor_r")
    rule = "(foc_motor_l {} foc_motor_ld_lq_diff/2)" + (f" / {scale:g}" if scale != 1 else "")
    motor["L_d"] = Entry(quantity(Ld_fw / scale, "H"), rule.format("-"))
    motor["L_q"] = Entry(quantity(Lq_fw / scale, "H"), rule.format("+"))
    if scale != 1:
        estimate["L_d"] = Entry(quantity(Ld_fw, "H"), "foc_motor_l - foc_motor_ld_lq_diff/2: what VESC runs")
        estimate["L_q"] = Entry(quantity(Lq_fw, "H"), "foc_motor_l + foc_motor_ld_lq_diff/2: what VESC runs")
        if "l_scale" not in given:
            notes.append(
                f"foc_motor_l, foc_motor_ld_lq_diff read as VESC Tool's detection stores them ({scale:g} x "
                f"measured): motor L_d, L_q = stored/{scale:g}, the stored values as the estimate the "
                "firmware runs; give --l-scale 1 if they were typed from a datasheet"
            )

    flux_rule = "foc_motor_flux_linkage"
    candidates: list[tuple[str, float | None, bool, str]] = [
        ("foc_motor_flux_linkage", f.number("foc_motor_flux_linkage"), False, flux_rule)
    ]
    candidates += kv_candidates(given, p, "60/(2 pi sqrt(3) p KV)")
    psi, rule, flux_notes = choose_flux(candidates, file, "--KV (rpm/V, line-line peak)")
    motor["psi_pm"] = Entry(quantity(psi, "Wb"), rule)
    notes += flux_notes
    inertia(given, motor, notes, "a VESC file")

    inverter: dict[str, Entry] = {}
    # the bus voltage the drive file states (its rated speed follows from it)
    u_dc = float(given["u_dc"]) if given.get("u_dc") else cells * V_PER_CELL if cells is not None else v_max
    assert u_dc is not None
    if given.get("u_dc"):
        inverter["u_dc"] = Entry(quantity(float(given["u_dc"]), "V"), "--u-dc")
    elif cells is not None:
        f.within("si_battery_cells", cells * V_PER_CELL, U_DC_RANGE, f"u_dc = cells x {V_PER_CELL} V", "V")
        inverter["u_dc"] = Entry(quantity(cells * V_PER_CELL, "V"), f"si_battery_cells x {V_PER_CELL} V")
        notes.append(f"bus voltage assumed {cells} cells x {V_PER_CELL} V (li-ion nominal); give --u-dc")
    else:
        assert v_max is not None
        inverter["u_dc"] = Entry(
            quantity(v_max, "V"), "l_max_vin: the highest input voltage the drive runs at"
        )
        notes.append(
            f"no battery in the file (an older file): bus voltage from l_max_vin = {v_max:g} V, the highest "
            "input voltage the drive runs at (speeds are judged at it); give --u-dc the battery's voltage"
        )
    f_zv = f.number("foc_f_zv")
    if f_zv is None and "foc_f_sw" in f:
        f_sw = f.number("foc_f_sw")
        assert f_sw is not None
        f_zv = f_sw
        notes.append(
            f"foc_f_zv missing (an older file): read foc_f_sw {f_sw:g} Hz as it, the setting's earlier name "
            "(the control loop runs at half of it unless sampled at both zero vectors: vedderb/bldc#212)"
        )
    elif f_zv is None:
        f_zv = DEFAULTS["foc_f_zv"]
        notes.append(f"foc_f_zv missing: assumed the firmware default {f_zv:g} Hz")
    freq = "foc_f_zv" if "foc_f_zv" in f else "foc_f_sw" if "foc_f_sw" in f else "foc_f_zv"
    both = f.values.get("foc_sample_v0_v7", "0").strip().lower() in ("1", "true")
    T = (1 if both else 2) / f_zv
    if freq in f:  # the user's field, not the default
        f.within(freq, 1 / T, F_S_RANGE, "the observer's rate f_s", "Hz")
    loop = f"1/{freq} (foc_sample_v0_v7)" if both else f"2/{freq}"
    inverter["f_s"] = Entry(quantity(1 / T, "Hz"), f"the observer's rate: T_obs = {loop}")

    kind_raw = f.values.get("foc_observer_type")
    if kind_raw is None:
        code = 0
        notes.append(
            "foc_observer_type missing (an older file, before the other observers): assumed 0 ORTEGA_ORIGINAL"
        )
    else:
        by_name = {n: c for c, (n, _, _) in OBSERVER_TYPES.items()}
        word = kind_raw.strip().upper().removeprefix("FOC_OBSERVER_")
        x = by_name.get(word)
        if x is None:
            x = f.number("foc_observer_type", positive=False)
        code = int(x) if x is not None and x == int(x) else -1
        if code not in OBSERVER_TYPES:
            raise f.error("foc_observer_type", f"{kind_raw}: not one of {sorted(OBSERVER_TYPES)}")
    name, correction, adapt = OBSERVER_TYPES[code]
    if code in NOT_MODELLED:
        notes.append(
            f"foc_observer_type {code} ({name}, circular clamp) is not modelled: read as the box clamp"
        )
    observer = {
        "firmware": Entry("vesc"),
        "correction": Entry(correction, f"foc_observer_type {code} ({name})"),
        "inductance": Entry("interpolated", "VESC interpolates L between L_d and L_q"),
        "lambda_adaptation": Entry(adapt, f"foc_observer_type {code} ({name})"),
        "T_obs": Entry(quantity(T, "s"), loop),
    }

    gains: dict[str, Entry] = {"law": Entry("voltage-scaled")}
    raw = f.number("foc_observer_gain")
    if raw is None:
        raw = observer_gain_detection(psi)
        notes.append(
            f"foc_observer_gain missing: assumed VESC Tool's detection rule 1000/lambda^2 = {raw:.6g}"
        )
    elif abs(raw / observer_gain_detection(psi) - 1) < 1e-3:
        notes.append("foc_observer_gain is VESC Tool's detection value 1000/lambda^2 for this flux linkage")
    gains["foc_observer_gain"] = Entry(raw, f"raw; VESC Tool shows {raw * GAIN_DISPLAY:.4g} (x1M)")
    for key, unit in (("foc_observer_gain_slow", ""), ("foc_pll_kp", "1/s"), ("foc_pll_ki", "")):
        x = f.number(key)
        if x is None:
            x = DEFAULTS[key]
            notes.append(f"{key} missing: assumed the firmware default {x:g}")
        gains[key] = Entry(quantity(x, unit) if unit else x, "1/s^2" if key == "foc_pll_ki" else "")

    notes += version_notes(f)
    i_max = f.number("l_current_max")
    rating = {} if i_max is None else {"I_N": rated_from_limit(i_max, "l_current_max")}
    stem = Path(file).stem
    header = [
        f"imported from {Path(file).name} (VESC Tool motor configuration XML) by sensorless init --from vesc",
        "each converted value has its rule as a comment (docs/families/pmsm_flux_observer_firmware.md)",
    ]
    w_on, t_ol, hyst = (
        f.number(k) for k in ("foc_openloop_rpm", "foc_sl_openloop_time", "foc_sl_openloop_hyst")
    )
    w_on = None if w_on is None else w_on * 2 * math.pi / 60
    acc = None if w_on is None or t_ol is None else w_on / t_ol
    w_off = None if acc is None or hyst is None or hyst * acc >= w_on else w_on - hyst * acc  # type: ignore[operator]
    startup = startup_entries(
        None,
        acc,
        w_on,
        w_off,
        {
            "acceleration": "foc_openloop_rpm / foc_sl_openloop_time",
            "w_on": "foc_openloop_rpm x 2 pi/60 (ERPM)",
            "w_off": "foc_openloop_rpm - foc_sl_openloop_hyst x acceleration",
        },
        (u_dc, psi),
        notes,
    )
    ramp = f.number("s_pid_ramp_erpms_s", positive=False)
    control: dict[str, Entry] = {}
    if ramp is not None and ramp > 0:
        control["speed_ramp"] = Entry(
            quantity(ramp * 2 * math.pi / 60, "rad/s^2"), "s_pid_ramp_erpms_s x 2 pi/60 (ERPM/s)"
        )
    sections = {
        "drive": {
            "name": Entry(str(given.get("name") or stem)),
            "kind": Entry(kind),
            "source": Entry(f"VESC Tool motor configuration {Path(file).name}"),
        },
        "motor": motor,
        "rating": rating,
        "inverter": inverter,
        "observer": observer,
        "estimate": estimate,
        "gains": gains,
        "control": control,
        "startup": startup,
    }
    return Imported(drive_document(header, sections), tuple(notes))


def version_notes(f: Fields) -> list[str]:
    """What differs between the firmware the file was saved for and the one the analysis models (the
    present one): the run-time gain factor of files older than the fields VESC added about 2020, and the
    compensations the analysis leaves out where the file turns them on."""
    notes = []
    if "foc_observer_type" not in f and "si_motor_poles" not in f:
        notes.append(
            f"an older file (no foc_observer_type, no si_motor_poles: firmware before about 2020): "
            f"VESC then ran the observer at {OLD_SCHEDULE_FACTOR:g} x foc_observer_gain x max(gain_slow, "
            f"|duty| V_bus/40 V), not {SCHEDULE_FACTOR:g} x; the analysis takes the present factor; on "
            f"the older firmware the observer runs {OLD_SCHEDULE_FACTOR / SCHEDULE_FACTOR:g} x the gain "
            f"analysed (write foc_observer_gain x {SCHEDULE_FACTOR / OLD_SCHEDULE_FACTOR:g} there for the "
            "gain tuned, or update the firmware)"
        )
    for key, what in (
        ("foc_sat_comp", "the saturation compensation"),
        ("foc_temp_comp", "the temperature compensation of R"),
    ):
        raw = f.values.get(key, "0").strip().lower()
        if raw not in ("0", "0.0", "false", ""):
            notes.append(f"{key} = {raw}: {what} is on in the file and not modelled by the analysis")
    return notes


def _element(name: str, value: Any, comment: str = "") -> str:
    text = f"    <{name}>{value}</{name}>"
    return f"{text}  <!-- {comment.replace('--', '-')} -->" if comment else text


def _startup_elements(d: FirmwareDrive) -> list[str]:
    """The open-loop start's fields (module docstring) of the drive's I-f start; none without one.
    ``foc_sl_erpm`` (the hybrid sensor modes' switch-over) is not written: the user's is kept."""
    if d.startup is None:
        return []
    from sensorless.design.pmsm_flux_observer.firmware.startup import fields

    w_on, w_off, acc = d.startup["if_w_on"], d.startup["if_w_off"], d.startup["if_acc"]
    f = {k: stored(v) for k, (v, _) in fields("vesc", d.startup).items()}
    return [
        _element(
            "foc_openloop_rpm", f["foc_openloop_rpm"], f"ERPM: the handover speed w_on = {w_on:.6g} rad/s"
        ),
        _element(
            "foc_sl_openloop_time", f["foc_sl_openloop_time"], f"s: w_on / acceleration ({acc:.6g} rad/s^2)"
        ),
        _element(
            "foc_sl_openloop_hyst",
            f["foc_sl_openloop_hyst"],
            f"s: (w_on - w_off) / acceleration, w_off = {w_off:.6g} rad/s (w_min)",
        ),
    ]


def export(d: FirmwareDrive) -> tuple[dict[str, str], list[str]]:
    """VESC Tool XML fragment (``vesc.xml``) of the drive's motor values and law ``voltage-scaled`` gains; a
    DriveFileError (one line) where the drive or gains break the firmware's own limits."""
    check_limit(
        d.law == "voltage-scaled",
        d.source,
        "law",
        lambda: (
            f"law {d.law!r}: the vesc target writes law 'voltage-scaled' gains (tune --law voltage-scaled)"
        ),
    )
    if d.correction == "gradient":
        raise DriveFileError(
            d.source, "observer.correction", "VESC has no unclamped gradient observer: use 'clamped-gradient'"
        )
    code = next(
        c for c, (_, corr, ad) in OBSERVER_TYPES.items() if corr == d.correction and ad == d.lambda_adaptation
    )
    g = d.gains
    raw, slow, kp, ki = (
        g["foc_observer_gain"],
        g["foc_observer_gain_slow"],
        g["foc_pll_kp"],
        g["foc_pll_ki"],
    )
    # the largest run-time gain: full duty at the drive's bus voltage
    top = SCHEDULE_FACTOR * raw * max(slow, d.u_dc / V_SCHEDULE) * d.psi_pm**2
    check_limit(
        d.T_obs * top < 2,
        d.source,
        "foc_observer_gain",
        lambda: (
            f"T gamma lambda^2 = {d.T_obs * top:.3g} >= 2 at full duty (4 raw max(gain_slow, u_dc/40 V) "
            f"lambda^2 = {top:.4g} 1/s, T = {d.T_obs * 1e6:.4g} us): VESC's forward Euler step is unstable"
        ),
    )
    name = OBSERVER_TYPES[code][0]
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f"<!-- sensorless export for VESC Tool: drive {d.name}; a fragment of the motor configuration: load",
        "     it or copy its fields; SI units. The motor values are those the tuning assumed the firmware",
        "     is given (VESC Tool's detection would store 0.9 x the measured inductances). -->",
        f"<{ROOT}>",
        _element("si_motor_poles", 2 * d.p, f"{d.p} pole pairs"),
        _element("foc_motor_r", stored(d.R_s), "ohm, per phase"),
        _element("foc_motor_l", stored((d.L_d + d.L_q) / 2), "H, (L_d + L_q)/2"),
        _element("foc_motor_ld_lq_diff", stored(d.L_q - d.L_d), "H, L_q - L_d"),
        _element("foc_motor_flux_linkage", stored(d.psi_pm), "Wb"),
        _element("foc_f_zv", stored(2 / d.T_obs), f"Hz: observer period 2/f_zv = {d.T_obs * 1e6:.6g} us"),
        _element("foc_sample_v0_v7", 0, "one observer step per PWM period, as T assumes"),
        _element("foc_observer_type", code, f"{name}: the observer the gains were tuned for"),
        _element("foc_observer_gain", stored(raw), f"VESC Tool shows {raw * GAIN_DISPLAY:.4g} (x1M)"),
        _element("foc_observer_gain_slow", stored(slow)),
        _element("foc_pll_kp", stored(kp), "1/s"),
        _element("foc_pll_ki", stored(ki), "1/s^2"),
        *_startup_elements(d),
        *(
            []
            if d.i_max is None
            else [
                _element("l_current_max", stored(d.i_max), "A: the torque limit's current, the drive's limit")
            ]
        ),
        f"</{ROOT}>",
    ]
    notes = [
        "foc_sl_erpm (the hybrid sensor modes' switch-over to the observer) is not written: yours is kept",
        f"VESC Tool shows foc_observer_gain as {raw * GAIN_DISPLAY:.4g} (x1M); observer type {code} {name}",
    ]
    if d.correction == "box-clamp":
        notes.append(f"{name} has no gain: foc_observer_gain does not act on it")
    return {"vesc.xml": "\n".join(lines) + "\n"}, notes
