"""The derived tuning envelope reaches the torque limit, and tuned tables carry no rounding residues.

Gains tuned at +-T_N only sat on the decay floor at the envelope's edge and were unstable just beyond it,
where the speed loop drives the motor in every acceleration (T_max = 1.5 T_N): the derived [tuning]
torques are -T_max, -T_N, 0, T_N, T_max (design/ipmsm_adaptive/derive.py), checked against the motor
data typed here (the measured instability: docs/families/ipmsm_adaptive.md, "Derived drive files")."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.gain_table import GainTable, read_gain_table
from sensorless.tuning.ipmsm_adaptive.laws import build_schedule

MOTORS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors"
IND5K5 = Path(__file__).parent / "drives" / "ind5k5_minimal.toml"


def _prius(tmp_path: Path, control: str = "") -> Path:
    text = (MOTORS / "prius.toml").read_text(encoding="utf-8")
    if control:
        text = text.replace("[inverter]", f"[control]\n{control}\n[inverter]")
    f = tmp_path / "prius.toml"
    f.write_text(text, encoding="utf-8")
    return f


def _torques_Nm(d) -> list[float]:
    return sorted(t * d.T_N for t in d.tuning.envelope.torque_values)


def test_the_envelope_reaches_the_torque_limit(tmp_path):
    d = load_drive(_prius(tmp_path))
    assert d.T_N == pytest.approx(300.0)  # [rating] T_N = "300 Nm"
    assert d.control.T_max == pytest.approx(450.0)  # 1.5 T_N
    assert _torques_Nm(d) == pytest.approx([-450.0, -300.0, 0.0, 300.0, 450.0])


def test_a_given_torque_limit_sets_the_envelope(tmp_path):
    d = load_drive(_prius(tmp_path, 'T_max = "400 Nm"'))
    assert _torques_Nm(d) == pytest.approx([-400.0, -300.0, 0.0, 300.0, 400.0], rel=1e-5)  # 6 digits
    d = load_drive(_prius(tmp_path, 'T_max = "300 Nm"'))  # at T_N: no duplicate
    assert _torques_Nm(d) == pytest.approx([-300.0, 0.0, 300.0])


def test_the_preset_keeps_its_envelope():
    assert load_drive("piippo2008").tuning.envelope.torque_values == (-1.0, 0.0, 1.0)


def test_tuned_schedule_writes_rounding_residues_as_zero(tmp_path):
    """lambda2 at zero speed came out of the optimizer as -4e-14 ohm, which the table reader refuses
    (magnitudes from 1e-12): the table writes it as 0; every other value as it is."""
    d = load_drive(str(IND5K5))
    model = build_schedule(d, d.tuning)
    th = np.asarray(model.theta0, float).copy()
    K = th.size // 2
    th[K + K // 2] = -3.979367978820674e-14
    th[1] = 2.5e-12  # above the threshold: kept
    g = model.table_gains(th)
    assert g["lambda2"][K // 2] == 0.0 and math.copysign(1, g["lambda2"][K // 2]) == 1
    assert g["lambda1"][1] == 2.5e-12
    assert g["lambda1"][0] == th[0]
    table = GainTable(law="schedule", drive={"kind": d.kind, "name": d.name}, gains=g)
    path = tmp_path / "gains.json"
    path.write_text(table.to_json(), encoding="utf-8")
    assert read_gain_table(path).gains["lambda2"][K // 2] == 0.0
