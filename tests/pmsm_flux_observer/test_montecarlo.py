"""Monte-Carlo of the flux family through the contract: a draw at the drive's own values is the
family's linearization, a drawn estimate is its linearization under that estimate, and `sensorless
montecarlo` without --spread spreads the family's typical values (tiny draw counts)."""

from __future__ import annotations

import json

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.reports.cli.main import main


def test_draws_reproduce_the_familys_linearization():
    d = load_drive("outrunner270")
    fam = family_of(d)
    params = fam.montecarlo_parameters(d)
    g = fam.gains(d)
    w = np.array([0.3, 0.7, 1.0]) * d.w_base
    T = np.array([0.0, d.T_N, d.T_N])
    nominal = np.array([p.plant for p in params])
    est = np.array([p.estimate if p.estimate is not None else p.plant for p in params])
    off = est.copy()
    off[0] *= 1.2  # the R_s estimate 20 % high
    lin = fam.linearize_draws(d, g, np.vstack([nominal, nominal]), np.vstack([est, off]), w, T)
    ref = fam.linearize(d, g, w, T)
    ref_off = fam.linearize(d, g, w, T, estimate={"R_s": off[0]})
    for k, r in ((0, ref), (1, ref_off)):
        got = lin.poles[3 * k : 3 * k + 3]
        for a, b in zip(got, r.poles, strict=True):
            assert np.allclose(np.sort_complex(a), np.sort_complex(b), rtol=1e-8, atol=1e-6)
        assert np.allclose(lin.theta_err[3 * k : 3 * k + 3], r.theta_err, atol=1e-9)
    assert not np.allclose(lin.theta_err[3:], lin.theta_err[:3])  # the estimate error shows


def test_montecarlo_command_defaults_to_the_typical_spread(tmp_path, capsys):
    out = tmp_path / "mc"
    rc = main(
        [
            "montecarlo",
            "outrunner270",
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
    params = family_of(load_drive("outrunner270")).montecarlo_parameters(load_drive("outrunner270"))
    assert s["spread"] == {p.name: f"{100 * p.typical:g}%" for p in params if p.typical > 0}
    assert s["min_damping"] == 0.0  # the family's: stable (its damping falls with speed by design)
    # the points the gains run sensorless: from the I-f start's hand-back speed up
    assert s["samples"] == 3 and 0 < s["envelope_points"] < load_drive("outrunner270").grid()[0].size
