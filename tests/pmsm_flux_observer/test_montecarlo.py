"""Monte-Carlo of the flux family through the contract: a draw at the drive's own values is the
family's linearization, a drawn estimate is its linearization under that estimate, and `sensorless
montecarlo` without --spread spreads the family's typical values (tiny draw counts)."""

from __future__ import annotations

import json
from importlib.resources import files

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.reports.cli.main import main


def test_draws_reproduce_the_familys_linearization():
    d = load_drive("outrunner270")
    fam = family_of(d)
    params = fam.montecarlo.parameters(d)
    g = fam.gains(d)
    w = np.array([0.3, 0.7, 1.0]) * d.w_base
    T = np.array([0.0, d.T_N, d.T_N])
    nominal = np.array([p.plant for p in params])
    est = np.array([p.estimate if p.estimate is not None else p.plant for p in params])
    off = est.copy()
    off[0] *= 1.2  # the R_s estimate 20 % high
    lin = fam.montecarlo.linearize_draws(d, g, np.vstack([nominal, nominal]), np.vstack([est, off]), w, T)
    ref = fam.linearize(d, g, w, T)
    ref_off = fam.linearize(d, g, w, T, estimate={"R_s": off[0]})
    for k, r in ((0, ref), (1, ref_off)):
        got = lin.poles[3 * k : 3 * k + 3]
        for a, b in zip(got, r.poles, strict=True):
            assert np.allclose(np.sort_complex(a), np.sort_complex(b), rtol=1e-8, atol=1e-6)
        assert np.allclose(lin.theta_err[3 * k : 3 * k + 3], r.theta_err, atol=1e-9)
    assert not np.allclose(lin.theta_err[3:], lin.theta_err[:3])  # the estimate error shows


def test_draws_judge_the_sampled_observer_of_each_drawn_motor():
    """A draw's discrete poles are the family's sampled-observer poles of the drive with that motor:
    the drawn plant (R_s and psi_pm off) through the per-draw zero-order hold equals the single-drive
    analysis of a drive file whose motor has those values."""
    import dataclasses

    d = load_drive("outrunner270")
    fam = family_of(d)
    params = fam.montecarlo.parameters(d)
    g = fam.gains(d)
    w = np.array([0.3, 1.0]) * d.w_base
    T = np.array([d.T_N, -d.T_N])
    nominal = np.array([p.plant for p in params])
    est = np.array([p.estimate if p.estimate is not None else p.plant for p in params])
    drawn = nominal.copy()
    drawn[0] *= 1.3  # the true R_s 30 % high
    drawn[3] *= 0.95  # the magnets' flux 5 % low
    lin = fam.montecarlo.linearize_draws(d, g, np.vstack([nominal, drawn]), np.vstack([est, est]), w, T)
    ref = fam.linearize(d, g, w, T)
    moved = dataclasses.replace(d, motor=dataclasses.replace(d.motor, R_s=drawn[0], psi_pm=drawn[3]))
    ref_drawn = fam.linearize(moved, g, w, T)
    for k, r in ((0, ref), (1, ref_drawn)):
        for a, b in zip(lin.poles_discrete[2 * k : 2 * k + 2], r.poles_discrete, strict=True):
            assert np.allclose(np.sort_complex(a), np.sort_complex(b), rtol=1e-7, atol=1e-5)
    assert not np.allclose(lin.poles_discrete[2:], lin.poles_discrete[:2])  # the drawn motor shows


def test_montecarlo_command_defaults_to_the_typical_spread(tmp_path, capsys):
    # the preset with a start its user gives: the drive runs open loop below the hand-back speed w_off
    # = 0.2 p.u., so the draws are judged only from there up (the preset's own start hands back below
    # its envelope's lowest speed, 0.05 p.u., and would keep every point)
    preset = (files("sensorless.design.pmsm_flux_observer.presets") / "outrunner270.toml").read_text()
    assert "[startup]" not in preset
    drive_file = tmp_path / "outrunner270_start.toml"
    drive_file.write_text(preset + '\n[startup]\nw_on = "0.3 pu"\nw_off = "0.2 pu"\n')
    out = tmp_path / "mc"
    rc = main(
        [
            "montecarlo",
            str(drive_file),
            "--samples",
            "3",
            "--scheduler",
            "synchronous",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc in (0, 3)
    s = json.loads((out / "summary.json").read_text())
    d = load_drive("outrunner270")
    params = family_of(d).montecarlo.parameters(d)
    assert s["spread"] == {p.name: f"{100 * p.typical:g}%" for p in params if p.typical > 0}
    assert s["min_damping"] == 0.0  # the family's: stable (its damping falls with speed by design)
    # the points the gains run sensorless: from the I-f start's hand-back speed up
    W, _ = d.envelope.grid()
    above = int(np.count_nonzero(np.abs(W) >= 0.2 * d.w_base * (1 - 1e-12)))
    assert 0 < above < W.size
    assert s["samples"] == 3 and s["envelope_points"] == above
