"""The minimum sensorless speed (design/low_speed.py) against a brute-force sweep of simulations.

Two example motors (docs/examples/motors, minimal files completed by their family as `sensorless init`
does), each with a stated resistance-estimate error that makes the angle bias the limit at rated
regenerating load: the simulated loop (the runtime step on the PMSM, held at constant speed by a stiff
load, torque control at -T_N) at 0.5, 0.8, 1.25 and 2 w_min gives the steady angle error; the speed
where it crosses the 30-deg limit (interpolated) is within -25 %/+33 % of the linearization's w_min
(the sampled loop against the continuous-time linearization: the simulations are independent of it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.low_speed import headline, minimum_speed
from sensorless.design.registry import family_of
from sensorless.design.scenario import drive_units, load_scenario_text
from sensorless.design.simulate import simulate

MOTORS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors"
LIMIT = 30.0  # deg, the default max_bias


def steady_angle_error(drive, w_pu: float, T_pu: float, r_scale: float) -> float:
    """Mean angle error [deg] over the last fifth of 0.3 s at constant speed and torque."""
    text = f"""[scenario]
name = "hold"
title = "constant speed and torque"
kind = "{drive.kind}"
duration = "0.3 s"
[control]
mode = "torque"
stiff_load = true
[initial]
w_m = "{w_pu} pu"
[speed_reference]
t = [0]
value = ["{w_pu} pu"]
[torque_reference]
t = [0]
value = ["{T_pu} T_N"]
[estimate_scale]
R_s = {r_scale}
"""
    tr = simulate(drive, load_scenario_text(text, "test", drive_units(drive)), None)
    th = np.angle(np.exp(1j * np.asarray(tr["theta_err"])))
    return float(np.degrees(np.mean(th[-th.size // 5 :])))


@pytest.mark.parametrize(("motor", "r_scale"), [("drone.toml", 1.3), ("servo400.toml", 1.5)])
def test_bias_limited_w_min_matches_simulations(motor, r_scale):
    drive = load_drive(MOTORS / motor)
    ls = minimum_speed(drive, family_of(drive).gains(drive), min_damping=0.2, errors={"R_s": r_scale})
    assert ls.limited_by[0] == "bias"  # at -T_N
    w_min = ls.w_min[0] / drive.w_base
    assert 0.002 < w_min < 0.5
    ks = np.array([0.5, 0.8, 1.25, 2.0])
    err = np.array([abs(steady_angle_error(drive, k * w_min, -1.0, r_scale)) for k in ks])
    assert err[0] > LIMIT > err[-1], (w_min, err)  # the sweep brackets the limit
    # the simulations' crossing of the limit, interpolated in log speed over the first bracket
    j = int(np.flatnonzero((err[:-1] > LIMIT) & (err[1:] <= LIMIT))[0])
    x = np.interp(LIMIT, err[j : j + 2][::-1], np.log(ks[j : j + 2])[::-1])
    assert 0.75 < np.exp(x) < 1.33, (w_min, err)  # tolerance: the continuous-time linearization
    assert "p.u." in headline(ls) and "rpm" in headline(ls)


def test_curve_is_one_batched_grid_and_its_data_is_json_ready():
    drive = load_drive(MOTORS / "servo400.toml")
    ls = minimum_speed(drive, family_of(drive).gains(drive), min_damping=0.2)
    d = ls.data()
    assert len(d["curve"]) == 9 and d["curve"][0]["T_pu"] == -1.0 and d["curve"][-1]["T_pu"] == 1.0
    assert d["w_min_rated_pu"] == max(d["curve"][0]["w_min_pu"], d["curve"][-1]["w_min_pu"])
    assert set(d["criteria"]["applied"]) == {"damping", "decay", "bias", "noise"}
    # a stricter damping requirement cannot lower the minimum speed
    strict = minimum_speed(drive, family_of(drive).gains(drive), min_damping=0.5)
    assert np.all(strict.w_min >= ls.w_min - 1e-9)
