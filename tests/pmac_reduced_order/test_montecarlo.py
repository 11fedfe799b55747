"""Monte-Carlo of the reduced-order family through the contract: a draw at the drive's own values is
the family's continuous linearization, a drawn motor is the linearization of that motor's drive built
by ``perturbed``, and `sensorless montecarlo` without --spread spreads the family's typical values."""

from __future__ import annotations

import json

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.pmac_reduced_order.linearize import continuous_poles
from sensorless.design.registry import family_of
from sensorless.reports.cli.main import main


def test_draws_reproduce_the_linearization_of_the_perturbed_drive():
    d = load_drive("deangelo2006")
    fam = family_of(d)
    params = fam.montecarlo.parameters(d)
    g = fam.gains(d)
    w = d.rpm_to_w(np.array([100.0, 400.0, -250.0]))
    T = np.array([0.0, 5.0, -7.0])
    nominal = np.array([p.plant for p in params])
    est = np.array([p.estimate for p in params])
    drawn = nominal * np.array([1.2, 0.9, 1.3, 1.05])  # R, L, J, Phi of another motor
    lin = fam.montecarlo.linearize_draws(d, g, np.vstack([nominal, drawn]), np.vstack([est, est]), w, T)
    over = {"g": g.values["g"], "Gamma": g.values["Gamma"]}
    np.testing.assert_allclose(lin.poles[:3], fam.linearize(d, g, w, T).poles, rtol=1e-9, atol=1e-9)
    other = fam.montecarlo.perturbed(d, dict(zip([p.name for p in params], drawn, strict=True)), {})
    np.testing.assert_allclose(lin.poles[3:], continuous_poles(other, w, T, **over), rtol=1e-9, atol=1e-9)
    assert not np.allclose(lin.poles[3:], lin.poles[:3])


def test_montecarlo_command_defaults_to_the_typical_spread(tmp_path):
    out = tmp_path / "mc"
    argv = ["montecarlo", "deangelo2006", "--samples", "3", "--scheduler", "synchronous"]
    assert main([*argv, "--out", str(out), "--quiet"]) in (0, 3)
    s = json.loads((out / "summary.json").read_text())
    d = load_drive("deangelo2006")
    params = family_of(d).montecarlo.parameters(d)
    assert s["spread"] == {p.name: f"{100 * p.typical:g}%" for p in params}
    assert s["samples"] == 3 and s["envelope_points"] == len(d.envelope.speeds) * len(d.envelope.torques)
