"""The one operating envelope (design/envelope.py ``Envelope``): each family's drive-file keys become
the SI grid with the arithmetic typed here from the keys (no value moved by the translation), and
analyze, tune and Monte-Carlo read the same points."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensorless.design.drive import load_drive, preset_text
from sensorless.design.registry import family_of
from sensorless.reports import envelope_review
from sensorless.tuning.family import tunable_for


def test_adaptive_speeds_are_the_tuning_keys_in_pu_times_the_base():
    d = load_drive("piippo2008")
    env = d.envelope
    # [tuning] defaults: 0.05..1 p.u., 20 per direction, both directions; torques -1, 0, 1 T_N
    mag = np.linspace(0.05, 1.0, 20) * d.w_base
    assert np.array_equal(env.speed_grid(), np.concatenate([-mag[::-1], mag]))
    assert np.array_equal(env.torque_grid(), np.array([-1.0, 0.0, 1.0]) * d.T_N)
    assert env.speeds == tuple(env.speed_grid().tolist())


def test_flux_speeds_are_evenly_spaced_in_rad_s():
    d = load_drive("outrunner270")
    k = d.envelope.rule
    s = np.linspace(k.lo, k.hi, (k.count - 1) * 2 + 1)
    assert np.array_equal(d.envelope.speed_grid(2), np.concatenate([-s[::-1], s]))
    assert d.envelope.speed_max == k.hi


def test_reduced_order_speeds_are_the_listed_rpm_sorted_and_electrical():
    d = load_drive("deangelo2006")
    rpm = np.unique(np.asarray(d.envelope.rule.listed, float))  # the file's list: -250 .. 4000 r/min
    assert np.array_equal(d.envelope.speed_grid(), rpm * (math.pi / 30) * d.motor.p)
    assert np.array_equal(d.envelope.speed_grid(), d.rpm_to_w(rpm))


def test_reduced_order_montecarlo_judges_the_tuners_grid():
    """The file lists its loads unsorted (0, 5, -7 N m): the Monte-Carlo points are the tuner's grid,
    sorted and distinct, not the file's order."""
    from sensorless.tuning.pmac_reduced_order.settings import default_settings, grid

    d = load_drive("deangelo2006")
    n, T = grid(default_settings(d))
    W_mc, T_mc = family_of(d).montecarlo.envelope_points(d)
    assert np.array_equal(W_mc, d.rpm_to_w(n)) and np.array_equal(T_mc, T)


def test_adaptive_readers_agree_on_the_range_of_a_users_drive(tmp_path):
    """On a drive of the user's own whose [tuning] stops at +-T_N, tune, analyze/report and Monte-Carlo
    all judge the same points, widened to the torque limit +-T_max; the preset keeps +-T_N."""
    f = tmp_path / "mine.toml"
    f.write_text(preset_text("piippo2008"), encoding="utf-8")
    for spec, top in ((str(f), "T_max"), ("piippo2008", "T_N")):
        d = load_drive(spec)
        assert max(abs(t) for t in d.tuning.envelope.torques) == pytest.approx(d.T_N)  # the file's
        W, T = family_of(d).montecarlo.envelope_points(d)
        W_r, T_r = envelope_review.points(d, 1)
        W_t, T_t = tunable_for(d, "speed-dependent").settings(d).envelope.grid()
        assert np.array_equal(W, W_r) and np.array_equal(T, T_r)
        assert np.array_equal(W, W_t) and np.array_equal(T, T_t)
        expect = d.control.T_max if top == "T_max" else d.T_N
        assert T.max() == pytest.approx(expect) and T.min() == pytest.approx(-expect)
