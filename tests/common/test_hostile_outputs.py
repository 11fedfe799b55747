"""Hostile inputs against what the commands write and how they end (continues test_hostile_inputs.py):
every number written is finite, or its cell is empty and the row says why (reports/csv_cells.py); the
many-drive engine's summary gives each drive's error; work on a plausible-but-wrong input is bounded;
Ctrl-C on many drives is one line."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
from sensorless.design.drive import load_drive


# ------------------------------------------------------------------ no nan or inf in what is written
def test_montecarlo_draws_without_equilibrium_have_an_empty_cell_and_a_reason():
    from types import SimpleNamespace

    from sensorless.design.montecarlo import Draws, Uncertain
    from sensorless.reports.montecarlo import NO_EQUILIBRIUM, draws_csv

    params = [Uncertain("R_s", 1.0, 1.0, "ohm", True)]
    draws = Draws(("R_s",), np.array([[1.0], [2.0]]), np.array([[1.0], [1.0]]), {})
    res = SimpleNamespace(
        draws=draws,
        worst=np.array([0.5, -np.inf]),  # the second draw: no equilibrium somewhere (-inf: '-inf' before)
        at=np.array([1, 0]),
        w=np.array([10.0, 20.0]),
        torque=np.array([0.0, 1.0]),
        td=[],
    )
    text = draws_csv(res, params, 0.2)
    assert "inf" not in text and "nan" not in text, text
    rows = list(csv.DictReader(io.StringIO(text)))
    assert rows[0]["worst_damping"] == "0.5" and rows[0]["worst_speed_rad_s"] == "20"
    assert rows[0]["no_value_reason"] == ""
    assert rows[1]["worst_damping"] == "" and rows[1]["passes_damping"] == "0"
    assert rows[1]["no_value_reason"] == NO_EQUILIBRIUM


def test_a_flux_preset_point_without_a_sampled_fixed_point_is_said_not_written_as_nan():
    # analyze hubmotor48 wrote nan in the discrete columns of this row, silently (exit 0)
    from sensorless.design.pmsm_flux_observer import FAMILY
    from sensorless.reports.pmsm_flux_observer import NO_FIXED_POINT, not_finite, poles_csv

    drive = load_drive("hubmotor48")
    W, T = drive.grid(2)
    k = np.flatnonzero(np.isclose(W / drive.w_base, 0.95682, atol=1e-5) & (T == drive.T_N))
    lin = FAMILY.linearize(drive, FAMILY.gains(drive), W[k], T[k])
    assert not np.isfinite(lin.worst_damping_discrete).all()  # the case: no value there
    text = poles_csv(lin, drive)
    assert "nan" not in text and "inf" not in text, text
    row = next(csv.DictReader(io.StringIO(text.split("\n", 1)[1])))
    assert row["damping_d"] == "" and row["damping_c"] != "" and row["no_value_reason"] == NO_FIXED_POINT
    assert "poles.csv" in not_finite(lin)  # the warning line (exit status 3)


@pytest.mark.parametrize("v", [float("nan"), float("inf"), -float("inf"), None])
def test_a_csv_cell_is_a_finite_number_or_empty_with_the_rows_reason(v):
    from sensorless.reports.csv_cells import row

    assert row([1.5, v], "why") == "1.5,,why"
    assert row([1.5, 2], "why") == "1.5,2,"
