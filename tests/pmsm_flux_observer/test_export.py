"""Drive values and gains to firmware configurations: field names and units, the firmwares' own limits
refused with one line, deterministic bytes, and the round trip export -> import giving the same
drive values (design/pmsm_flux_observer/firmware/vesc.py, odrive.py, simplefoc.py)."""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
import xml.etree.ElementTree as ET

import pytest
from sensorless.design.pmsm_flux_observer.firmware import FirmwareDrive, odrive, simplefoc, vesc
from sensorless.design.units import DriveFileError, parse_quantity

KIND = "pmsm-flux-observer"
REL = 1.2e-7  # the firmwares store float32: 2^-23 relative, written in the fewest digits that keep it


def si(value, dim):
    return parse_quantity(value, dim, file="t", key="k")[0]


SKATE = FirmwareDrive(
    name="skate",
    p=7,
    R_s=0.0276,
    L_d=8.1e-6,
    L_q=9.7e-6,
    psi_pm=4.014e-3,
    u_dc=36.0,
    T_obs=50e-6,
    correction="clamped-gradient",
    lambda_adaptation=False,
    law="voltage-scaled",
    gains={
        "foc_observer_gain": 62064786.2,
        "foc_observer_gain_slow": 0.05,
        "foc_pll_kp": 2000.0,
        "foc_pll_ki": 30000.0,
    },
    source="skate.toml",
)
OUTRUNNER = FirmwareDrive(
    name="outrunner",
    p=7,
    R_s=0.0392,
    L_d=2.37e-5,
    L_q=2.37e-5,
    psi_pm=2.91708e-3,
    u_dc=24.0,
    T_obs=125e-6,
    correction="gradient",
    lambda_adaptation=False,
    law="constant",
    gains={"observer_gain": 1500.0, "pll_bandwidth": 800.0},
    source="gains.json",
)


# ------------------------------------------------------------------------------------------------ VESC
def test_vesc_fields_values_and_display_comment():
    files, notes = vesc.export(SKATE)
    text = files["vesc.xml"]
    root = ET.fromstring(text)
    assert root.tag == "MCConfiguration"
    v = {c.tag: float(c.text) for c in root}
    assert v["si_motor_poles"] == 14
    assert v["foc_motor_r"] == 0.0276
    assert v["foc_motor_l"] == pytest.approx((8.1e-6 + 9.7e-6) / 2)  # 8.9 uH
    assert v["foc_motor_ld_lq_diff"] == pytest.approx(1.6e-6)  # L_q - L_d
    assert v["foc_motor_flux_linkage"] == 4.014e-3
    assert v["foc_f_zv"] == pytest.approx(40e3)  # T = 2 / f_zv = 50 us
    assert v["foc_sample_v0_v7"] == 0  # one step per PWM period, which T = 2 / f_zv assumes
    assert v["foc_observer_type"] == 0  # ORTEGA_ORIGINAL: the clamped gradient
    assert v["foc_observer_gain"] == pytest.approx(62064786.2, rel=REL)  # as float32 holds it: 62064788
    assert (v["foc_observer_gain_slow"], v["foc_pll_kp"], v["foc_pll_ki"]) == (0.05, 2000, 30000)
    assert re.search(
        r"<foc_observer_gain>62064788</foc_observer_gain>\s*<!-- VESC Tool shows 62\.06 \(x1M\)", text
    )
    assert any("62.06" in n for n in notes)


def test_vesc_observer_types():
    """box clamp with flux adaptation: 3 MXLEMMING_LAMBDA_COMP, with the note that the gain does not act."""
    files, notes = vesc.export(dataclasses.replace(SKATE, correction="box-clamp", lambda_adaptation=True))
    assert "<foc_observer_type>3</foc_observer_type>" in files["vesc.xml"]
    assert any("has no gain" in n for n in notes)
    files, _ = vesc.export(dataclasses.replace(SKATE, lambda_adaptation=True))
    assert "<foc_observer_type>2</foc_observer_type>" in files["vesc.xml"]
    with pytest.raises(DriveFileError, match=r"observer\.correction"):
        vesc.export(dataclasses.replace(SKATE, correction="gradient"))


def test_vesc_euler_limit_at_full_duty():
    """T gamma lambda^2 < 2 with gamma = 4 raw max(gain_slow, u_dc / 40 V) at full duty: 36 V gives
    max(0.05, 0.9) = 0.9; T = 50 us, lambda = 4.014 mWb: raw < 2 / (4 x 0.9 x 4.014e-3^2 x 50e-6) =
    6.8963e8."""
    vesc.export(dataclasses.replace(SKATE, gains={**SKATE.gains, "foc_observer_gain": 6.89e8}))
    with pytest.raises(DriveFileError) as e:
        vesc.export(dataclasses.replace(SKATE, gains={**SKATE.gains, "foc_observer_gain": 6.90e8}))
    msg = str(e.value)
    assert msg.startswith("skate.toml: ") and "foc_observer_gain" in msg and "\n" not in msg


def test_vesc_refuses_another_law():
    with pytest.raises(DriveFileError, match="law 'constant'"):
        vesc.export(dataclasses.replace(SKATE, law="constant"))


def test_vesc_round_trip():
    """Export then import (the values as given: --l-scale 1) gives the same drive values."""
    files, _ = vesc.export(SKATE)
    r = vesc.read(files["vesc.xml"], "vesc.xml", {"u_dc": SKATE.u_dc, "l_scale": 1.0}, KIND)
    d = tomllib.loads(r.text)
    m = d["motor"]
    assert m["p"] == SKATE.p and "estimate" not in d
    assert si(m["R_s"], "resistance") == pytest.approx(SKATE.R_s, rel=REL)
    assert si(m["L_d"], "inductance") == pytest.approx(SKATE.L_d, rel=REL)
    assert si(m["L_q"], "inductance") == pytest.approx(SKATE.L_q, rel=REL)
    assert si(m["psi_pm"], "flux") == pytest.approx(SKATE.psi_pm, rel=REL)
    assert si(d["inverter"]["u_dc"], "voltage") == SKATE.u_dc
    obs = d["observer"]
    assert si(obs["T_obs"], "time") == pytest.approx(SKATE.T_obs, rel=REL)
    assert (obs["correction"], obs["lambda_adaptation"]) == (SKATE.correction, SKATE.lambda_adaptation)
    g = d["gains"]
    assert g["law"] == "voltage-scaled"
    assert g["foc_observer_gain"] == pytest.approx(SKATE.gains["foc_observer_gain"], rel=REL)
    assert g["foc_observer_gain_slow"] == SKATE.gains["foc_observer_gain_slow"]
    assert si(g["foc_pll_kp"], "rate") == SKATE.gains["foc_pll_kp"]
    assert g["foc_pll_ki"] == SKATE.gains["foc_pll_ki"]
    # read as detection values (the default), the exported ones become the estimate, the motor's / 0.9
    d = tomllib.loads(vesc.read(files["vesc.xml"], "vesc.xml", {"u_dc": 36.0}, KIND).text)
    assert si(d["estimate"]["L_q"], "inductance") == pytest.approx(SKATE.L_q, rel=REL)
    assert si(d["motor"]["L_q"], "inductance") == pytest.approx(SKATE.L_q / 0.9, rel=REL)


# ----------------------------------------------------------------------------------------------- ODrive
def test_odrive_paths_values_and_odrivetool_lines():
    files, notes = odrive.export(OUTRUNNER)
    values = json.loads(files["odrive.json"])
    assert values == {
        "axis0.motor.config.pole_pairs": 7,
        "axis0.motor.config.phase_resistance": 0.0392,
        "axis0.motor.config.phase_inductance": 2.37e-5,
        "axis0.motor.config.torque_constant": pytest.approx(1.5 * 7 * 2.91708e-3),  # 0.030629 N m/A
        "axis0.sensorless_estimator.config.pm_flux_linkage": 2.91708e-3,
        "axis0.sensorless_estimator.config.observer_gain": 1500.0,
        "axis0.sensorless_estimator.config.pll_bandwidth": 800.0,
    }
    lines = files["odrivetool.txt"].splitlines()
    assert "odrv0.axis0.sensorless_estimator.config.observer_gain = 1500.0" in lines
    assert "odrv0.axis0.sensorless_estimator.config.pll_bandwidth = 800.0" in lines
    assert lines[-1] == "odrv0.save_configuration()"
    assert not notes  # non-salient: nothing to say


def test_odrive_limits():
    """T kp < 1 with kp = 2 bw: at T = 125 us, bw < 4000 rad/s; T observer_gain < 2: gain < 16000 1/s."""
    odrive.export(dataclasses.replace(OUTRUNNER, gains={"observer_gain": 15990.0, "pll_bandwidth": 3990.0}))
    for gains, key in (
        ({"observer_gain": 1000.0, "pll_bandwidth": 4000.0}, "pll_bandwidth"),
        ({"observer_gain": 16000.0, "pll_bandwidth": 1000.0}, "observer_gain"),
    ):
        with pytest.raises(DriveFileError) as e:
            odrive.export(dataclasses.replace(OUTRUNNER, gains=gains))
        msg = str(e.value)
        assert msg.startswith("gains.json: ") and f"'{key}'" in msg and "\n" not in msg
    with pytest.raises(DriveFileError, match="law 'voltage-scaled'"):
        odrive.export(SKATE)


def test_odrive_salient_motor_gets_lq_with_a_note():
    files, notes = odrive.export(dataclasses.replace(OUTRUNNER, L_d=2e-5, L_q=3e-5))
    assert json.loads(files["odrive.json"])["axis0.motor.config.phase_inductance"] == 3e-5
    assert any("L_q" in n for n in notes)


def test_odrive_round_trip():
    files, _ = odrive.export(OUTRUNNER)
    r = odrive.read(files["odrive.json"], "odrive.json", {"u_dc": 24.0, "f_s": 8000.0}, KIND)
    d = tomllib.loads(r.text)
    m = d["motor"]
    assert m["p"] == 7
    assert si(m["R_s"], "resistance") == pytest.approx(OUTRUNNER.R_s, rel=REL)
    assert si(m["L_d"], "inductance") == pytest.approx(OUTRUNNER.L_d, rel=REL)
    assert si(m["psi_pm"], "flux") == pytest.approx(OUTRUNNER.psi_pm, rel=REL)
    assert si(d["observer"]["T_obs"], "time") == pytest.approx(OUTRUNNER.T_obs, rel=REL)
    assert si(d["gains"]["observer_gain"], "rate") == 1500.0
    assert si(d["gains"]["pll_bandwidth"], "angular") == 800.0
    assert any("torque_constant" in n and "agrees" in n for n in r.notes)  # both written, both agree


# -------------------------------------------------------------------------------------------- SimpleFOC
def test_simplefoc_fields():
    """KV_rating from the flux: 7 pole pairs, 2.91708 mWb give 5.51328895422 / (7 x 2.91708e-3) = 270.0
    rpm/V; phase_inductance is L_q."""
    files, notes = simplefoc.export(dataclasses.replace(OUTRUNNER, L_d=2e-5, L_q=3e-5))
    text = files["simplefoc.cpp"]
    assert "motor.pole_pairs = 7;" in text
    assert "motor.phase_resistance = 0.0392f;" in text
    assert "motor.phase_inductance = 3e-05f;" in text
    kv = float(re.search(r"motor\.KV_rating = ([0-9.e+-]+)f;", text).group(1))
    assert kv == pytest.approx(270.0, rel=1e-5)
    assert "no gain to tune" in text and any("no gain to tune" in n for n in notes)
    assert any("gradient" in n for n in notes)  # analysed with another correction than SimpleFOC runs


def test_exports_are_deterministic():
    assert vesc.export(SKATE) == vesc.export(dataclasses.replace(SKATE))
    assert odrive.export(OUTRUNNER) == odrive.export(dataclasses.replace(OUTRUNNER))


# ------------------------------------------------------------------------------ the open-loop I-f start
# typed by hand: 3000 ERPM = 50 electrical rev/s = 100 pi rad/s; back below half of it; 1000 rad/s^2
START = {
    "if_i": 12.0,
    "if_acc": 1000.0,
    "if_w_on": 100 * 3.141592653589793,
    "if_w_off": 50 * 3.141592653589793,
}


def test_vesc_open_loop_fields_by_hand_and_back():
    files, _ = vesc.export(dataclasses.replace(SKATE, startup=START))
    root = ET.fromstring(files["vesc.xml"].split("\n", 1)[1])
    assert root.findtext("foc_openloop_rpm") == "3000"  # whole ERPM, as VESC Tool shows them
    assert root.find("foc_sl_erpm") is None  # the hybrid modes' switch-over: the user's is kept
    # the ramp to 100 pi rad/s at 1000 rad/s^2 lasts 0.1 pi s; the band (50 pi rad/s) half of it: 4 digits
    assert root.findtext("foc_sl_openloop_time") == "0.3142"
    assert root.findtext("foc_sl_openloop_hyst") == "0.1571"
    d = tomllib.loads(vesc.read(files["vesc.xml"], "vesc.xml", {"u_dc": 36.0}, KIND).text)["startup"]
    assert "current" not in d  # VESC sets its open-loop current by its own fields
    assert si(d["acceleration"], "rate_squared") == pytest.approx(1000.0, rel=5e-4)  # the time to 4 digits
    assert si(d["w_on"], "angular") == pytest.approx(START["if_w_on"], rel=REL)
    assert si(d["w_off"], "angular") == pytest.approx(START["if_w_off"], rel=5e-4)
    # no start: no fields, no section
    plain, _ = vesc.export(SKATE)
    assert "openloop" not in plain["vesc.xml"]
    assert "startup" not in tomllib.loads(vesc.read(plain["vesc.xml"], "v.xml", {"u_dc": 36.0}, KIND).text)


def test_odrive_sensorless_ramp_and_back():
    files, notes = odrive.export(dataclasses.replace(OUTRUNNER, startup=START))
    v = json.loads(files["odrive.json"])
    ramp = "axis0.config.sensorless_ramp."
    assert (v[ramp + "current"], v[ramp + "accel"], v[ramp + "vel"]) == (12.0, 1000.0, 314.15927)
    assert f"odrv0.{ramp}vel = 314.15927" in files["odrivetool.txt"]  # float32, without float noise
    assert any("does not fall back to open loop" in n for n in notes)  # w_off has no field
    d = tomllib.loads(odrive.read(files["odrive.json"], "o.json", {"u_dc": 24.0, "f_s": 8000.0}, KIND).text)
    s = d["startup"]
    assert si(s["current"], "current") == pytest.approx(12.0, rel=REL) and "w_off" not in s
    assert si(s["acceleration"], "rate_squared") == pytest.approx(1000.0, rel=REL)
    assert si(s["w_on"], "angular") == pytest.approx(START["if_w_on"], rel=REL)
