"""Firmware configuration files to drive files: every unit conversion against a hand calculation typed
here, the missing values and assumptions said, redundant flux values cross-checked, bad files refused
with one line naming the file and the field (design/pmsm_flux_observer/firmware/vesc.py, odrive.py)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pytest
from sensorless.design.pmsm_flux_observer.firmware import odrive, vesc
from sensorless.design.units import DriveFileError, parse_quantity

KIND = "pmsm-flux-observer"
EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples" / "firmware"


def si(value, dim):
    """A drive-file quantity in SI, read by the drive files' own parser."""
    return parse_quantity(value, dim, file="t", key="k")[0]


def imported(mod, text, given=None, file="cfg"):
    r = mod.read(text, file, given or {}, KIND)
    return tomllib.loads(r.text), list(r.notes)


def vesc_xml(**fields):
    body = "".join(f"<{k}>{v}</{k}>" for k, v in fields.items() if v is not None)
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<MCConfiguration>{body}</MCConfiguration>\n'


HUB = dict(
    si_motor_poles=40,
    foc_motor_r=0.085,
    foc_motor_l=0.000225,
    foc_motor_ld_lq_diff=1.8e-05,
    foc_motor_flux_linkage=0.0306,
    foc_f_zv=30000,
    si_battery_cells=14,
    foc_observer_type=3,
    foc_observer_gain=1067965,
    foc_observer_gain_slow=0.05,
    foc_pll_kp=2000,
    foc_pll_ki=30000,
)


# ------------------------------------------------------------------------------------------------ VESC
def test_vesc_hub_motor_example_converts_each_value():
    d, notes = imported(vesc, (EXAMPLES / "hub_motor_mcconf.xml").read_text(), file="hub.xml")
    assert d["drive"]["kind"] == KIND
    m, est = d["motor"], d["estimate"]
    assert m["p"] == 20  # 40 magnet poles
    assert si(m["R_s"], "resistance") == pytest.approx(0.085, rel=1e-11)
    # stored (0.9 x measured): L_d = 225 - 18/2 = 216 uH, L_q = 234 uH; measured = stored / 0.9
    assert si(est["L_d"], "inductance") == pytest.approx(216e-6, rel=1e-11)
    assert si(est["L_q"], "inductance") == pytest.approx(234e-6, rel=1e-11)
    assert si(m["L_d"], "inductance") == pytest.approx(240e-6, rel=1e-11)
    assert si(m["L_q"], "inductance") == pytest.approx(260e-6, rel=1e-11)
    assert si(m["psi_pm"], "flux") == pytest.approx(0.0306, rel=1e-11)
    # 14 cells x 3.7 V; T = 2 / 30 kHz = 66.67 us
    assert si(d["inverter"]["u_dc"], "voltage") == pytest.approx(51.8, rel=1e-11)
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(66.6667e-6, rel=1e-5)
    assert si(d["inverter"]["f_s"], "frequency") == pytest.approx(15e3, rel=1e-11)
    obs = d["observer"]
    assert (obs["firmware"], obs["correction"], obs["lambda_adaptation"]) == ("vesc", "box-clamp", True)
    g = d["gains"]
    assert g["law"] == "voltage-scaled" and g["foc_observer_gain"] == 1067965 and g["foc_pll_ki"] == 30000
    assert si(g["foc_pll_kp"], "rate") == 2000
    # l_current_max 60 A (amplitude) is the torque limit T_max = 2 T_N: rated 30 A amplitude, 21.21 A rms
    assert si(d["rating"]["I_N"], "current") == pytest.approx(30 / math.sqrt(2), rel=1e-11)
    said = "\n".join(notes)
    assert "--u-dc" in said and "--J" in said and "0.9" in said and "--l-scale 1" in said
    # 1000 / 0.0306^2 = 1067965.3: the stored gain is still the detection value, and the note says so
    assert "detection value 1000/lambda^2" in said
    _, notes = imported(vesc, vesc_xml(**{**HUB, "foc_observer_gain": 500000}))
    assert not any("detection value" in n for n in notes)


def test_vesc_detection_gain_and_its_display():
    """VESC Tool's detection: gain 1e-3 / lambda^2 stored x 1e6; lambda = 4.014 mWb: 6.206e7 raw,
    62.06 shown."""
    assert vesc.observer_gain_detection(4.014e-3) == pytest.approx(6.2065e7, rel=1e-4)
    text = vesc_xml(**{**HUB, "foc_motor_flux_linkage": 0.004014, "foc_observer_gain": None})
    r = vesc.read(text, "cfg", {}, KIND)
    d = tomllib.loads(r.text)
    assert d["gains"]["foc_observer_gain"] == pytest.approx(62064786, rel=1e-6)
    assert "VESC Tool shows 62.06 (x1M)" in r.text
    assert any("foc_observer_gain missing" in n and "1000/lambda^2" in n for n in r.notes)


def test_vesc_older_file_names_what_is_missing_and_the_options():
    text = (EXAMPLES / "outrunner_old_mcconf.xml").read_text()
    # one run names every missing value (the pole count and, with neither cells nor l_max_vin, the voltage)
    with pytest.raises(DriveFileError) as e:
        vesc.read(text, "old.xml", {}, KIND)
    said = str(e.value)
    assert "old.xml" in said and "\n" not in said
    for name in ("si_motor_poles", "--pole-pairs", "si_battery_cells", "--u-dc"):
        assert name in said, name
    d, notes = imported(vesc, text, {"pole_pairs": 7, "u_dc": 36.0, "l_scale": 1.0})
    assert d["motor"]["p"] == 7 and "estimate" not in d  # l-scale 1: the file's values are the motor's
    assert si(d["motor"]["L_d"], "inductance") == si(d["motor"]["L_q"], "inductance") == pytest.approx(8.9e-6)
    # the older foc_f_sw is f_zv's earlier name: the loop runs at half of it, 2/20 kHz = 100 us
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(100e-6, rel=1e-11)
    assert d["observer"]["correction"] == "clamped-gradient" and d["observer"]["lambda_adaptation"] is False
    assert d["gains"]["foc_observer_gain_slow"] == 0.05 and d["gains"]["foc_pll_ki"] == 40000
    said = "\n".join(notes)
    for missing in ("si_motor_poles", "foc_motor_ld_lq_diff", "foc_observer_type", "foc_observer_gain_slow"):
        assert missing in said, missing
    assert "foc_f_sw" in said


def test_vesc_ld_lq_diff_and_scale():
    """foc_motor_l = (L_d + L_q)/2, foc_motor_ld_lq_diff = L_q - L_d: 100 uH and 40 uH give 80 and
    120 uH as stored; --l-scale 0.8 gives 100 and 150 uH."""
    text = vesc_xml(**{**HUB, "foc_motor_l": 1e-4, "foc_motor_ld_lq_diff": 4e-5})
    d, _ = imported(vesc, text, {"l_scale": 0.8})
    assert si(d["estimate"]["L_d"], "inductance") == pytest.approx(80e-6, rel=1e-11)
    assert si(d["motor"]["L_q"], "inductance") == pytest.approx(150e-6, rel=1e-11)
    with pytest.raises(DriveFileError, match="foc_motor_ld_lq_diff"):
        vesc.read(vesc_xml(**{**HUB, "foc_motor_l": 1e-5, "foc_motor_ld_lq_diff": 3e-5}), "c", {}, KIND)


def test_vesc_loop_sampled_at_both_zero_vectors():
    d, _ = imported(vesc, vesc_xml(**HUB, foc_sample_v0_v7=1))
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(1 / 30e3, rel=1e-11)


def test_vesc_kv_cross_check():
    """--KV against the flux linkage: 20 pole pairs, 9 rpm/V give 5.51328895422/(20 x 9) = 30.63 mWb,
    0.1 % from 30.6 mWb (agrees); 5 rpm/V gives 55.13 mWb, 80 % off (said)."""
    _, notes = imported(vesc, vesc_xml(**HUB), {"KV": 9.0})
    assert any("--KV (30.629 mWb) agrees" in n for n in notes), notes
    _, notes = imported(vesc, vesc_xml(**HUB), {"KV": 5.0})
    assert any("--KV implies 55.133 mWb, 80 %" in n for n in notes), notes


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("<MCConfiguration><foc_motor_r>0.1</foc_motor_r>", "(syntax)"),
        ("<McConf><foc_motor_r>0.1</foc_motor_r></McConf>", "McConf"),
        ('<!DOCTYPE x [<!ENTITY a "b">]><MCConfiguration/>', "MCConfiguration"),
        (vesc_xml(**{**HUB, "foc_motor_r": "abc"}), "foc_motor_r"),
        (vesc_xml(**{**HUB, "foc_motor_r": -0.1}), "foc_motor_r"),
        (vesc_xml(**{**HUB, "foc_motor_flux_linkage": "nan"}), "foc_motor_flux_linkage"),
        (vesc_xml(**{**HUB, "foc_motor_l": None}), "foc_motor_l"),
        (vesc_xml(**{**HUB, "si_motor_poles": 41}), "si_motor_poles"),
        (vesc_xml(**{**HUB, "foc_observer_type": 9}), "foc_observer_type"),
        (vesc_xml(**{**HUB, "foc_motor_flux_linkage": None}), "foc_motor_flux_linkage"),
    ],
)
def test_vesc_bad_files_one_line_naming_file_and_field(text, field):
    with pytest.raises(DriveFileError) as e:
        vesc.read(text, "bad.xml", {}, KIND)
    msg = str(e.value)
    assert msg.startswith("bad.xml: ") and f"'{field}'" in msg and "\n" not in msg


# ----------------------------------------------------------------------------------------------- ODrive
def odrive_json(motor=None, estimator=None):
    m = {"pole_pairs": 7, "phase_resistance": 0.0392, "phase_inductance": 2.37e-5, "current_lim": 40.0}
    e = {"observer_gain": 1000.0, "pll_bandwidth": 1000.0, "pm_flux_linkage": 1.58e-3}
    m.update(motor or {})
    e.update(estimator or {})
    m = {k: v for k, v in m.items() if v is not None}
    e = {k: v for k, v in e.items() if v is not None}
    return json.dumps({"axis0": {"motor": {"config": m}, "sensorless_estimator": {"config": e}}})


def test_odrive_outrunner_example_uses_the_torque_constant_over_the_default_flux():
    """pm_flux_linkage is the factory 1.58e-3 (float32), torque_constant 8.27/150 = 0.055133 N m/A:
    psi = 0.055133 / (1.5 x 7) = 5.2508 mWb (= 5.51328895422 / (7 x 150), KV 150)."""
    d, notes = imported(odrive, (EXAMPLES / "outrunner_odrive.json").read_text(), {"u_dc": 24.0})
    m = d["motor"]
    assert m["p"] == 7
    assert si(m["psi_pm"], "flux") == pytest.approx(0.055133333 / 10.5, rel=1e-7)
    assert si(m["psi_pm"], "flux") == pytest.approx(5.51328895422 / (7 * 150), rel=1e-4)  # 8.27 is rounded
    assert si(m["R_s"], "resistance") == pytest.approx(0.0392, rel=1e-7)
    assert si(m["L_d"], "inductance") == si(m["L_q"], "inductance") == pytest.approx(2.37e-5, rel=1e-7)
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(125e-6, rel=1e-11)  # 8 kHz, v3
    assert d["observer"]["correction"] == "gradient" and d["gains"]["law"] == "constant"
    assert si(d["gains"]["observer_gain"], "rate") == 1000
    assert si(d["gains"]["pll_bandwidth"], "angular") == 1000
    assert si(d["rating"]["I_N"], "current") == pytest.approx(40 / (2 * math.sqrt(2)), rel=1e-11)
    said = "\n".join(notes)
    assert "pm_flux_linkage is still the factory default" in said and "torque_constant" in said
    assert "--f-s" in said and "--J" in said


def test_odrive_flux_from_kv():
    """ODrive's documented pm_flux_linkage = 5.51328895422 / (pole_pairs KV): 7 pole pairs, 270 rpm/V
    give 2.9171 mWb; the file's default flux (and default torque constant) are not used."""
    d, notes = imported(odrive, odrive_json(motor={"torque_constant": 0.04}), {"u_dc": 24.0, "KV": 270.0})
    assert si(d["motor"]["psi_pm"], "flux") == pytest.approx(2.91708e-3, rel=1e-5)
    assert sum("factory default" in n for n in notes) == 2, notes


def test_odrive_all_defaults_says_so_and_names_the_option():
    d, notes = imported(odrive, odrive_json(), {"u_dc": 24.0})
    assert si(d["motor"]["psi_pm"], "flux") == pytest.approx(1.58e-3)
    assert any("still the factory default" in n and "--KV" in n for n in notes), notes


def test_odrive_set_values_that_disagree_are_said():
    """pm_flux_linkage 3 mWb set, torque_constant 0.05 N m/A -> 0.05/10.5 = 4.762 mWb: 59 % apart."""
    _, notes = imported(
        odrive, odrive_json({"torque_constant": 0.05}, {"pm_flux_linkage": 3e-3}), {"u_dc": 24.0}
    )
    assert any("torque_constant implies 4.7619 mWb, 59 %" in n for n in notes), notes


def test_odrive_given_loop_frequency_and_pole_pairs():
    d, notes = imported(odrive, odrive_json({"pole_pairs": 7}), {"u_dc": 48.0, "f_s": 10e3, "pole_pairs": 5})
    assert d["motor"]["p"] == 5 and any("--pole-pairs 5 used" in n for n in notes)
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(1e-4, rel=1e-11)


@pytest.mark.parametrize(
    ("text", "given", "field"),
    [
        ('{"axis0": ', {"u_dc": 24.0}, "(syntax)"),
        ("[1, 2]", {"u_dc": 24.0}, "(top level)"),
        (
            odrive_json({"phase_resistance": float("inf")}),
            {"u_dc": 24.0},
            "axis0.motor.config.phase_resistance",
        ),
        (odrive_json({"phase_inductance": 0.0}), {"u_dc": 24.0}, "axis0.motor.config.phase_inductance"),
        (odrive_json({"pole_pairs": None}), {"u_dc": 24.0}, "axis0.motor.config.pole_pairs"),
        (odrive_json({"pole_pairs": 7.5}), {"u_dc": 24.0}, "axis0.motor.config.pole_pairs"),
        (odrive_json({"motor_type": 3}), {"u_dc": 24.0}, "axis0.motor.config.motor_type"),
        (odrive_json(estimator={"pm_flux_linkage": float("nan")}), {"u_dc": 24.0}, "pm_flux_linkage"),
        (odrive_json(), {}, "(bus voltage)"),
    ],
)
def test_odrive_bad_files_one_line_naming_file_and_field(text, given, field):
    with pytest.raises(DriveFileError) as e:
        odrive.read(text, "bad.json", given, KIND)
    msg = str(e.value)
    assert msg.startswith("bad.json: ") and field in msg and "\n" not in msg


def test_odrive_infinity_literals_elsewhere_are_read():
    """odrivetool writes Infinity and NaN; only the fields the import needs must be finite."""
    text = odrive_json({"torque_lim": float("inf"), "current_lim": float("inf")})
    assert "Infinity" in text
    d, notes = imported(odrive, text, {"u_dc": 24.0})
    assert "rating" not in d and any("current_lim = inf" in n for n in notes)


# ------------------------------------------------------------------------------------ in one pass
def test_every_missing_value_named_in_one_error():
    """A file that lacks several values gets one error naming each with what supplies it (not one run
    per value): VESC without poles, resistance and any voltage; ODrive without pole pairs, inductance and
    the bus voltage."""
    text = vesc_xml(**{**HUB, "si_motor_poles": None, "foc_motor_r": None, "si_battery_cells": None})
    with pytest.raises(DriveFileError) as e:
        vesc.read(text, "v.xml", {}, KIND)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("v.xml: keys ")
    for name in ("si_motor_poles", "--pole-pairs", "foc_motor_r", "si_battery_cells", "--u-dc"):
        assert name in msg, name
    with pytest.raises(DriveFileError) as e:
        odrive.read(odrive_json({"pole_pairs": None, "phase_inductance": None}), "o.json", {}, KIND)
    msg = str(e.value)
    for name in ("pole_pairs", "--pole-pairs", "phase_inductance", "--u-dc"):
        assert name in msg, name


def test_the_2017_file_imports_with_the_pole_pairs_alone():
    """The 2017 file has neither si_motor_poles nor si_battery_cells: --pole-pairs is the one value
    asked; the bus voltage is its l_max_vin (42 V), said; its foc_f_sw 20 kHz is f_zv's earlier name
    (2/f_sw = 100 us); the note of the run-time gain factor of that era (5, not 4)."""
    text = (EXAMPLES / "skate_2017_mcconf.xml").read_text()
    with pytest.raises(DriveFileError) as e:
        vesc.read(text, "old.xml", {}, KIND)
    assert "si_motor_poles" in str(e.value) and "si_battery_cells" not in str(e.value)
    d, notes = imported(vesc, text, {"pole_pairs": 7})
    assert si(d["inverter"]["u_dc"], "voltage") == 42.0
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(1e-4, rel=1e-11)
    said = "\n".join(notes)
    assert "l_max_vin = 42 V" in said and "--u-dc" in said
    assert "5 x foc_observer_gain" in said and "1.25 x the gain analysed" in said and "x 0.8" in said
    # the start of that era: 400 ERPM in 0.5 s = 83.78 rad/s^2, back 0.5 s x that below: none left
    s = d["startup"]
    assert si(s["w_on"], "angular") == pytest.approx(400 * 2 * math.pi / 60, rel=1e-11)
    assert si(s["acceleration"], "rate_squared") == pytest.approx(83.7758, rel=1e-5)
    # a current-era file has no such note
    _, notes = imported(vesc, (EXAMPLES / "hub_motor_mcconf.xml").read_text())
    assert not any("older file" in n for n in notes)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("<MCConfiguration><foc_motor_r>0.1 & 2</foc_motor_r></MCConfiguration>", "unescaped '<' or '&'"),
        ("<MCConfiguration><foc_motor_r>0.1</foc_motor_l></MCConfiguration>", "closing tag that does not"),
        ("<MCConfiguration><foc_motor_r>0.1</foc_motor_r>", "file ends before"),
        ("", "no element"),
    ],
)
def test_malformed_xml_says_what_is_wrong_in_words(text, words):
    with pytest.raises(DriveFileError) as e:
        vesc.read(text, "m.xml", {}, KIND)
    msg = str(e.value)
    assert words in msg and "line 1" in msg and "invalid token" not in msg and "\n" not in msg


def test_odrive_ramped_velocity_input_is_the_drive_files_speed_ramp():
    """INPUT_MODE_VEL_RAMP (2) with vel_ramp_rate 3 turn/s^2 on 7 pole pairs: 2 pi 7 x 3 = 131.95 rad/s^2
    electrical, which the written drive file loads as [control] speed_ramp; passthrough (1, the examples'
    mode) writes none."""
    from sensorless.design.drive import load_drive_text

    data = json.loads(odrive_json())
    data["axis0"]["controller"] = {"config": {"input_mode": 2, "vel_ramp_rate": 3.0}}
    r = odrive.read(json.dumps(data), "cfg", {"u_dc": 24.0}, KIND)
    d = tomllib.loads(r.text)
    assert si(d["control"]["speed_ramp"], "acceleration") == pytest.approx(2 * math.pi * 7 * 3.0, rel=1e-11)
    assert load_drive_text(r.text, "cfg.toml").control.speed_ramp == pytest.approx(131.946891, rel=1e-8)
    data["axis0"]["controller"]["config"]["input_mode"] = 1
    assert "control" not in imported(odrive, json.dumps(data), {"u_dc": 24.0})[0]


def test_vesc_speed_pid_ramp_is_the_drive_files_speed_ramp():
    """s_pid_ramp_erpms_s 25000 ERPM/s (the firmware's default): 25000 x 2 pi/60 = 2617.99 rad/s^2;
    -1 (VESC: no ramp) or absent (the examples' files) writes none."""
    d, _ = imported(vesc, vesc_xml(**HUB, s_pid_ramp_erpms_s=25000))
    assert si(d["control"]["speed_ramp"], "acceleration") == pytest.approx(25000 * math.pi / 30, rel=1e-11)
    assert "control" not in imported(vesc, vesc_xml(**HUB, s_pid_ramp_erpms_s=-1))[0]
    assert "control" not in imported(vesc, vesc_xml(**HUB))[0]
