"""The tuning laws of the flux observer: ODrive's and VESC's limits hold, the gain table loads back, the
schedule and the noise limit (the criterion against a brute-force grid: test_criterion.py)."""

from __future__ import annotations

import dataclasses
import itertools
import math
import re

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.reports.cli.main import main
from sensorless.tuning.pmsm_flux_observer import (
    FluxTuneSettings,
    assess,
    constant_candidate,
    figures,
    k_grid,
    tune_constant,
)


@pytest.fixture(scope="module")
def drive(outrunner_coarse):
    """The ODrive-class preset on a coarser envelope (conftest.py): the same laws and limits, tuned and
    judged on fewer points."""
    return outrunner_coarse


@pytest.fixture(scope="module")
def tuned(outrunner_constant):
    return outrunner_constant


def test_constant_law_limits_and_table(drive, tuned):
    g = tuned.table.gains
    T = drive.observer.T_obs
    assert T * g["observer_gain"] < 2  # the Euler bound
    assert T * 2 * g["pll_bandwidth"] < 1  # ODrive's T k_p < 1
    # the table is the family's: it loads through the contract
    gs = family_of(drive).gains(drive, table=tuned.table, table_file="t.json")
    assert gs.values["observer_gain"] == pytest.approx(g["observer_gain"])


def test_baselines_are_the_firmware_defaults(tuned, drive):
    b = tuned.table.summary["baselines"]
    assert b["ODrive defaults"]["gains"] == {"observer_gain": 1000.0, "pll_bandwidth": 1000.0}
    v = b["VESC detection"]["gains"]
    assert v["foc_observer_gain"] == pytest.approx(1e3 / drive.estimate.psi_pm**2)  # 1e-3/lambda^2 x1e6
    assert (v["foc_pll_kp"], v["foc_pll_ki"]) == (2000.0, 30000.0)


def test_schedule_table_runs_as_a_schedule_over_the_pll_speed(drive, outrunner_schedule):
    out = outrunner_schedule
    fam = family_of(drive)
    gains = fam.gains(drive, table=out.table, table_file="s.json")
    setup = fam.runtime(drive, gains)
    speeds, ks = gains.values["speeds"], gains.values["observer_gain"]
    law = setup.schedule.law
    for w, k in zip(speeds, ks, strict=True):  # the law reproduces the table at its breakpoints, both signs
        assert float(law(w, setup.gain)) == pytest.approx(k)
        assert float(law(-w, setup.gain)) == pytest.approx(k)
    lin = fam.linearize(drive, gains, np.array([speeds[-1]]), np.zeros(1))
    assert lin.decay_rate_discrete[0] > 0


def test_default_law_on_a_drive_of_ones_own_is_its_files(tmp_path):
    from importlib.resources import files

    from sensorless.tuning.family import tunable_for

    text = (files("sensorless.design.pmsm_flux_observer.presets") / "hubmotor48.toml").read_text()
    assert 'law = "voltage-scaled"' in text
    own = tmp_path / "hub.toml"
    own.write_text(text)
    assert tunable_for(load_drive(str(own))).name == "voltage-scaled"
    assert tunable_for(load_drive("hubmotor48"), None).name == "constant"  # a preset: the first law
    assert tunable_for(load_drive(str(own)), "schedule").name == "schedule"


def test_the_schedule_laws_former_name_reads_from_drive_files(capsys):
    """``flux_schedule``, the flux law's name before law names were each family's own, reads for one
    release as ``schedule``, with one note per file."""
    from sensorless.design.pmsm_flux_observer.laws import parse_law

    t = {"speeds": [100.0, 1000.0], "observer_gain": [500.0, 2000.0], "pll_bandwidth": 600.0}
    old = parse_law("flux_schedule", {"law": "flux_schedule", **t}, "old.toml", "gains")
    assert old == parse_law("schedule", {"law": "schedule", **t}, "new.toml", "gains")
    parse_law("flux_schedule", t, "old.toml", "gains")
    err = capsys.readouterr().err.splitlines()
    assert err == ["old.toml: note: key 'gains.law': law 'flux_schedule' is now called 'schedule'"]


@pytest.mark.parametrize(
    "old, new, preset",
    [("odrive", "constant", "outrunner270"), ("vesc", "voltage-scaled", "hubmotor48")],
)
def test_the_laws_firmware_names_read_for_one_release(tmp_path, capsys, old, new, preset):
    """``odrive`` and ``vesc``, the laws' names before they were named by role (the firmware names stay
    the export targets), read for one release as ``constant`` and ``voltage-scaled`` with one note line
    on stderr: from a drive file's [gains] (the same gains as the preset's, and ``init`` writes the name
    now), from a gain table (the same gains as under the new name) and from ``tune --law``."""
    from importlib.resources import files

    from sensorless.design.gain_table import GainTable, read_gain_table

    text = (files("sensorless.design.pmsm_flux_observer.presets") / f"{preset}.toml").read_text()
    assert f'law = "{new}"' in text
    own = tmp_path / "own.toml"
    own.write_text(text.replace(f'law = "{new}"', f'law = "{old}"'))
    mine, theirs = load_drive(str(own)), load_drive(preset)
    note = f"key 'gains.law': law '{old}' is now called '{new}'"
    assert capsys.readouterr().err.splitlines() == [f"{own}: note: {note}"]
    assert mine.gains_table == theirs.gains_table
    assert family_of(mine).gains(mine).values == family_of(theirs).gains(theirs).values
    assert main(["init", str(own), "--out", str(tmp_path / "full.toml")]) == 0
    full = (tmp_path / "full.toml").read_text()
    assert f'law = "{new}"' in full and f'law = "{old}"' not in full

    gains = dict(family_of(theirs).gains(theirs).values)
    t = tmp_path / "t.json"
    t.write_text(GainTable(old, {"name": preset, "kind": theirs.kind}, gains).to_json())
    capsys.readouterr()
    table = read_gain_table(t)
    assert capsys.readouterr().err.splitlines() == [f"{t}: note: law '{old}' is now called '{new}'"]
    assert table.law == new and family_of(theirs).gains(theirs, table=table).values == gains

    # tune: the note, then the law by its name now (refused up front, before any work: the box clamp
    # has no observer gain, whatever the law)
    box = tmp_path / "box.toml"
    box.write_text(re.sub(r'correction = "[a-z-]+"', 'correction = "box-clamp"', text))
    assert main(["tune", str(box), "--law", old, "--out", str(tmp_path / "tune"), "--quiet"]) == 2
    err = [x for x in capsys.readouterr().err.splitlines() if ": warning: " not in x]  # the drive's data
    assert err[0] == f"sensorless tune: note: law '{old}' is now called '{new}'"
    assert len(err) == 2 and f"law '{new}'" in err[1] and "no observer gain" in err[1]


def test_noise_limit_holds_and_front_trades_damping_for_bias(drive, tuned):
    lim = 0.9 * math.radians(tuned.table.summary["worst_noise_deg"])
    s = FluxTuneSettings(max_noise=(("position", lim),), pareto=4)
    r = tune_constant(drive, s)
    assert math.radians(r.table.summary["worst_noise_deg"]) <= lim
    assert r.table.gains["observer_gain"] != tuned.table.gains["observer_gain"]  # the limit binds
    pts = r.table.summary["pareto"]["points"]
    assert 2 <= len(pts) <= 4
    for a, b in itertools.pairwise(pts):  # more bias buys more damping along the front
        assert b["bias"] > a["bias"] and b["worst_damping"] > a["worst_damping"]
    assert all(p["noise"] <= math.degrees(lim) * (1 + 1e-9) for p in pts)
    # each front point re-judged alone gives its figures back
    k = pts[-1]["theta"][0]
    a = assess(drive, [constant_candidate(drive, k)], s)
    f = figures(drive, a, 0, r.table.summary["hold_speed_rad_s"])
    assert f["worst_damping"] == pytest.approx(pts[-1]["worst_damping"])


def test_angle_noise_scales_with_the_sensor_noise(drive):
    c = [constant_candidate(drive, 500.0)]
    a1 = assess(drive, c, FluxTuneSettings())
    a2 = assess(dataclasses.replace(drive, i_noise=0.0), c, FluxTuneSettings())
    a3 = assess(dataclasses.replace(drive, i_noise=1.0), c, FluxTuneSettings())
    assert np.allclose(a1.noise, a2.noise)  # 0: the default
    a4 = assess(dataclasses.replace(drive, i_noise=2.0), c, FluxTuneSettings())
    fin = np.isfinite(a3.noise)
    assert fin.any() and np.allclose(a4.noise[fin], 2 * a3.noise[fin])


def test_schedule_is_held_below_its_lowest_holding_speed(drive, outrunner_schedule):
    """Where no candidate holds (every one lacks an equilibrium under some error corner) the criterion
    ties; the schedule keeps the lowest holding speed's gain there rather than the grid's smallest."""
    s = FluxTuneSettings()
    a = assess(drive, [constant_candidate(drive, float(k)) for k in k_grid(drive)], s)
    first = int(np.flatnonzero(a.holds.any(axis=0))[0])
    assert first > 0  # the outrunner has speeds where no gain holds
    ks = outrunner_schedule.table.gains["observer_gain"]
    assert ks[:first] == [ks[first]] * first and ks[first] > k_grid(drive)[0]


def test_candidates_that_differ_in_a_slow_gain_the_observer_does_not_read_are_judged_as_alone(monkeypatch):
    """assess evaluates each distinct observer at each point once: where VESC's factor max(k_slow,
    |u|/u_ref) is the voltage's, candidates that differ in the slow gain alone are one observer (fewer
    points evaluated than alone). Judged together, each candidate gets the numbers it gets alone, bit
    for bit; and the slow gain still counts where the factor reads it (the candidates differ there)."""
    from sensorless.design.family import GainSet
    from sensorless.tuning.pmsm_flux_observer import assessment

    d = load_drive("hubmotor48")
    d = dataclasses.replace(
        d, envelope=dataclasses.replace(d.envelope, rule=dataclasses.replace(d.envelope.rule, count=4))
    )
    g = {"foc_observer_gain": 1.2e5, "foc_pll_kp": 1250.0, "foc_pll_ki": 1250.0**2 / 4}  # holds at the top
    cands = [
        GainSet("voltage-scaled", {**g, "foc_observer_gain_slow": s}, "candidate") for s in (0.01, 0.1, 0.5)
    ]
    s = FluxTuneSettings()
    points = []
    analysis = assessment.discrete_analysis
    monkeypatch.setattr(
        assessment, "discrete_analysis", lambda *a, **kw: points.append(len(a[2])) or analysis(*a, **kw)
    )
    assessment._KEPT.clear()  # no candidate's numbers from an earlier test
    together = assess(d, cands, s)
    for c, cand in enumerate(cands):
        assessment._KEPT.clear()
        alone = assess(d, [cand], s)
        for f in dataclasses.fields(alone):
            np.testing.assert_array_equal(getattr(together, f.name)[c], getattr(alone, f.name)[0])
    assert points[0] < sum(points[1:])  # points evaluated together, and each candidate's alone
    assert together.holds.any(axis=1).all()
    assert not np.array_equal(together.bias[0], together.bias[2])
