"""The HF carrier of a derived drive file (design/ipmsm_adaptive/carrier.py) against a hand calculation.

The q-axis carrier current at an angle error theta, i_qc = (u_c/w_c) (L_q - L_d)/(2 L_d L_q) sin 2 theta,
is typed here from the pulsating-injection model; the derived u_c must make a 5-deg error show 3x above
the sensor noise after the PI's averaging (variance x alpha_i T_s), its frequency be f_s/6, a noisier
sensor need a proportionally larger carrier, a sensor too noisy for the saliency turn the injection off
with a warning naming the key, and the paper's preset keep its 40 V."""

from __future__ import annotations

import math
from pathlib import Path

from sensorless.design.drive import load_drive

MOTORS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors"


def _with(text: str, extra: str) -> str:
    return text.replace("[inverter]", f"[control]\n{extra}\n[inverter]") if extra else text


def _drive(tmp_path: Path, extra: str = ""):
    f = tmp_path / "prius.toml"
    f.write_text(_with((MOTORS / "prius.toml").read_text(encoding="utf-8"), extra), encoding="utf-8")
    return load_drive(f)


def test_amplitude_and_frequency_from_the_saliency_and_the_sensor(tmp_path):
    d = _drive(tmp_path, 'i_noise = "0.5 A"\ni_resolution = "1 A"')
    m, inj, T_s = d.motor, d.injection, d.control.T_s
    assert math.isclose(inj.w_c, 2 * math.pi / T_s / 6, rel_tol=1e-5)
    sigma = math.hypot(0.5, 1 / math.sqrt(12))
    i_qc = inj.u_c / inj.w_c * (m.L_q - m.L_d) / (2 * m.L_d * m.L_q) * math.sin(2 * math.radians(5))
    noise_avg = sigma * math.sqrt(inj.alpha_i * T_s)
    assert math.isclose(i_qc / noise_avg, 3.0, rel_tol=1e-4)
    # the carrier stays within the inverter's voltage and the current share
    assert inj.u_c < 0.5 * d.control.u_dc / math.sqrt(3)
    assert inj.u_c / (inj.w_c * m.L_d) <= 0.1 * d.base.i * (1 + 1e-9)
    # twice the noise, twice the carrier
    d2 = _drive(tmp_path, 'i_noise = "1 A"\ni_resolution = "2 A"')
    assert math.isclose(d2.injection.u_c / inj.u_c, 2.0, rel_tol=1e-4)


def test_a_sensor_too_noisy_for_the_saliency_turns_injection_off_with_a_warning(tmp_path):
    d = _drive(tmp_path, 'i_noise = "40 A"')
    assert d.injection.u_c == 0 and not d.injection.enabled
    assert any("injection.u_c" in w and "too small for the current sensor" in w for w in d.warnings)


def test_the_preset_keeps_the_papers_carrier():
    d = load_drive("piippo2008")
    assert math.isclose(d.injection.u_c, 40.0) and math.isclose(d.injection.w_c, 2 * math.pi * 833)
