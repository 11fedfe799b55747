"""The max-min NLP (tuning/nlp.py) from a feasible start that is already the optimum: IPOPT must solve it
in its first run and end no worse than the start.

The case is the example servo's (docs/examples/motors/servo400.toml) law (16), eq. (16) of Piippo,
Hinkkanen, Luomi (2008), on its default envelope, from two starts of its global phase with lambda' on its
cap: omega_lambda = 0.02 p.u., below every envelope speed, where eq. (16) saturates at every point and no
constraint sees omega_lambda; and omega_lambda = 0.43 p.u., on the ridge of the optimum. Each NLP keeps
its start's slowest decay as its floor, as tune does. Before the fix (a round holds the parameters its
points do not see, and its trust region stays between eq. (16)'s kinks at the active points' speeds)
IPOPT ended Infeasible_Problem_Detected or Maximum_Iterations_Exceeded there from a start meeting every
constraint, and succeeded only after 1-5 halvings of the trust region. The optimum is
cross-checked by a brute force over a small grid of (lambda', omega_lambda) through the same
eigenvalues."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers.tuning import paper_law
from sensorless.design.drive import load_drive
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning import nlp
from sensorless.tuning.candidates import lowest_decay
from sensorless.tuning.conditions import candidates
from sensorless.tuning.family import tunable_for
from sensorless.tuning.model import evaluate
from sensorless.tuning.result import figures

SERVO = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "servo400.toml"


@pytest.fixture(scope="module")
def servo():
    drive = load_drive(str(SERVO))
    # the NLP of law (16) as the paper tunes it: a start meeting the damping and decay rows; the angle-lag
    # rows a drive file's tune holds by default bound the start's own lag only where it meets them
    drive = dataclasses.replace(drive, tuning=dataclasses.replace(drive.tuning, law=paper_law(drive.tuning)))
    tunable = tunable_for(drive, "speed-dependent")
    settings = tunable.settings(drive)
    model = tunable.build(drive, settings, None)
    W, T = settings.envelope.grid()
    scale = float(np.abs(figures(model, np.asarray(model.theta0, float), W, T).poles).max())
    return drive, settings, model, W, T, scale


def _brute_force(model, W, T, floor, scale):
    """The best worst damping over a 6 x 6 grid of (lambda', omega_lambda) in the law's box among the
    gains that meet the decay floor, by eigenvalues at every envelope point."""
    lps = np.linspace(model.upper[0] / 6, model.upper[0], 6)
    wls = np.geomspace(model.lower[1], model.upper[1] / 5, 6)
    th = np.stack([a.ravel() for a in np.meshgrid(lps, wls, indexing="ij")])
    P = model.make_points(W, T, model.nominal_estimate)
    K, N = th.shape[1], P.shape[1]
    poles = evaluate(model, np.repeat(th, N, axis=1), np.tile(P, K)).poles
    damping = worst_damping(poles).reshape(K, N).min(axis=1)
    decay = (-max_real(poles)).reshape(K, N).min(axis=1)
    ok = decay >= lowest_decay(floor, scale)
    assert ok.any()
    return float(damping[ok].max())


@pytest.mark.parametrize("w_lambda_pu", [0.02, 0.43])
def test_ipopt_solves_from_a_feasible_optimal_start(servo, w_lambda_pu):
    drive, settings, model, W, T, scale = servo
    theta = np.array([model.upper[0], w_lambda_pu * drive.w_base])  # lambda' on its cap
    f0 = figures(model, theta, W, T)
    floor = float(np.min(f0.decay))  # the NLP keeps its start's slowest decay (tuning/tune.py)
    cand = candidates(model, dataclasses.replace(settings, min_decay=floor), W, T, drive.w_base, scale)
    sol = nlp.solve(model, cand, theta, scale)
    assert sol.failed_attempts == ()  # no IPOPT run failed, none retried with half the trust region
    f1 = figures(model, sol.theta, W, T)
    assert f1.worst_damping() >= f0.worst_damping() - 1e-9  # no worse than the start
    assert np.min(f1.decay) >= lowest_decay(floor, scale)  # the floor held
    assert f1.worst_damping() >= _brute_force(model, W, T, floor, scale) - 1e-6
