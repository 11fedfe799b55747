"""The report's verdict over the drive's range (reports/drive_range.py) is the tune proof's: one envelope,
one analysis, one answer; and where it says unstable, the simulated drive does not settle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.design.scenario import drive_units, load_scenario_text
from sensorless.design.simulate import simulate
from sensorless.reports import drive_range, tune_proof

GIMBAL = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "gimbal.toml"


@pytest.fixture(scope="module")
def gimbal():
    return load_drive(GIMBAL)


def test_the_verdict_over_the_range_is_the_tune_proofs(gimbal):
    """The gimbal's default gain (law (16)) on the proof's envelope and analysis and on the report's
    range judgement: the same points, the same stable set; unstable points make it fail, named rhp_band;
    its constant gain is stable over the range and passes."""
    fam = family_of(gimbal)
    g = fam.gains(gimbal, name="speed")
    proof = tune_proof.prove(gimbal, g, "speed", [], tune_proof.ANALYSIS)
    j = drive_range.judge(gimbal, g, 0.2)
    assert j.data["points"] == proof.w.size == 200
    assert np.abs(proof.torque).max() == pytest.approx(gimbal.control.T_max)  # +-T_max is in it
    assert 0 < j.data["stable_points"] == int(proof.stable().sum()) < 200
    assert j.data["worst_damping"] == proof.worst_damping  # the number tune's proof line prints
    assert j.status == "fail" and "rhp_band" in j.findings[0]["causes"]
    j = drive_range.judge(gimbal, fam.gains(gimbal, name="constant"), 0.2)
    assert j.status == "pass" and j.data["stable_points"] == 200 and not j.findings


def test_where_the_range_is_unstable_the_simulated_drive_does_not_settle(gimbal):
    """Independent of the linearization: at 1 p.u. (where the range judgement finds the law-(16) gain
    unstable, max Re ~ +0.8 1/s) a short load pulse leaves the simulated drive oscillating, growing from
    0.5-1 s to 1.5-2 s; with the constant gain (stable there) it settles."""
    ptp = {}
    for name in ("speed", "constant"):
        text = (
            '[scenario]\nname = "pulse"\ntitle = "load pulse at 1 p.u."\nkind = "ipmsm-adaptive"\n'
            f'duration = "2 s"\n[observer]\ngain = "{name}"\n[initial]\nw_m = "1 pu"\n'
            '[speed_reference]\nt = [0]\nvalue = ["1 pu"]\n'
            '[load_torque]\nt = [0, 0.05, 0.1]\nvalue = ["0 Nm", "0.5 T_N", "0 Nm"]\n'
        )
        tr = simulate(gimbal, load_scenario_text(text, "pulse", drive_units(gimbal)))
        e = np.degrees(np.asarray(tr["theta_err"]))
        n = round(0.5 / gimbal.T_s)
        ptp[name] = (float(np.ptp(e[n : 2 * n])), float(np.ptp(e[-n:])))  # 0.5-1 s, 1.5-2 s
    first, last = ptp["speed"]
    assert last > first > 5.0  # grows (to a limit cycle of ~15 deg peak to peak)
    assert ptp["constant"][1] < 0.1  # settled
