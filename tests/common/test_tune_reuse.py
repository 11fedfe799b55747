"""What a tune computes once and reuses (tuning/result.py ``figures``, tuning/selection.py
``infeasible``), checked without tuning: stand-ins for the model and the tuner's records, and a count
of the computations the reuse saves."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from sensorless.tuning import result, selection
from sensorless.tuning.bound import Bound
from sensorless.tuning.model import Evaluation


def _model() -> SimpleNamespace:
    """A stand-in model whose evaluation records its calls (poles -1 - |theta| at every point)."""

    def make_points(w, T, est):
        return np.vstack([np.asarray(w, float), np.asarray(T, float)])

    return SimpleNamespace(
        nominal_estimate=np.zeros(1),
        noise=None,
        make_points=make_points,
        point_gains=lambda theta, w: {"g": np.full(np.size(w), float(np.sum(theta)))},
    )


@pytest.fixture
def evaluations(monkeypatch):
    calls: list = []

    def fake(model, theta, P, noise=False):
        calls.append((np.asarray(theta).copy(), P.copy()))
        p = np.full((P.shape[1], 2), -1.0 - float(np.abs(theta).sum()), complex)
        return Evaluation(p, np.zeros((1, P.shape[1])), None)

    monkeypatch.setattr(result, "evaluate", fake)
    result._FIGURES.clear()
    yield calls
    result._FIGURES.clear()


def test_the_same_gains_on_the_same_grid_are_evaluated_once(evaluations):
    m = _model()
    w, T = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.5, 1.0])
    a = result.figures(m, np.array([1.0, 2.0]), w, T)
    b = result.figures(m, np.array([1.0, 2.0]), w.copy(), T.copy())  # equal content, other arrays
    assert b is a and len(evaluations) == 1
    with pytest.raises(ValueError):
        a.damping[0] = 0.0  # shared: read-only
    c = result.figures(m, np.array([1.0, 2.5]), w, T)  # other gains
    d = result.figures(m, np.array([1.0, 2.0]), w[:2], T[:2])  # another grid
    e = result.figures(_model(), np.array([1.0, 2.0]), w, T)  # another model
    assert len(evaluations) == 4 and len({id(a), id(c), id(d), id(e)}) == 4
    np.testing.assert_array_equal(c.decay, 4.5)


def _bound(speeds, torques, feasible, floor=30.0) -> Bound:
    S = speeds.size
    return Bound(
        speeds=speeds,
        torques=torques,
        damping=np.full(S, 0.5),
        decay=np.full(S, floor + 1.0),
        feasible=np.asarray(feasible, bool),
        theta=np.ones((S, 2)),
        names=("lambda1", "lambda2"),
        units=("ohm", "ohm"),
        floor=floor,
        noise=None,
        evaluations=0,
    )


def _records(coarse_speeds, coarse_torques, floor=30.0):
    """(drive, model, settings, cand, ranked) as ``infeasible`` reads them; the model's pointwise model
    raises: a search run again is seen."""

    def search():
        raise LookupError("searched again")

    env = SimpleNamespace(speed_grid=lambda: coarse_speeds, torque_grid=lambda: coarse_torques)
    return (
        SimpleNamespace(w_base=100.0),
        SimpleNamespace(law="schedule", pointwise=search),
        SimpleNamespace(envelope=env, min_decay=floor),
        SimpleNamespace(labels=("w_m = -0.050 p.u., T_e = -1.27 N m",)),
        SimpleNamespace(worst_point=np.array([0]), evaluated=3, margin=np.array([-0.00195])),
    )


def test_an_infeasible_floor_is_shown_by_the_bound_already_computed_at_it():
    speeds, torques = np.array([-2.0, -1.0, 1.0, 2.0]), np.array([-1.0, 0.0, 1.0])
    dense_s, dense_t = np.linspace(-2.0, 2.0, 13), np.linspace(-1.0, 1.0, 9)  # holds the envelope's
    args = _records(speeds, torques)
    said: list[str] = []
    msg = selection.infeasible(*args, 1.0, None, said.append, _bound(dense_s, dense_t, np.ones(13)))
    assert "at every envelope speed some gain (lambda1, lambda2) is" in msg
    assert "fails at w_m = -0.050 p.u., T_e = -1.27 N m, margin -0.00195" in msg
    assert any(s.strip().startswith("yes:") for s in said)
    # the evidence is not there: infeasible somewhere, another floor, a grid without the envelope's speeds
    for known in (
        _bound(dense_s, dense_t, np.arange(13) != 5),
        _bound(dense_s, dense_t, np.ones(13), floor=29.0),
        _bound(np.linspace(-2.0, 2.0, 12), dense_t, np.ones(12)),
        _bound(dense_s, np.linspace(-1.0, 1.0, 4), np.ones(13)),
        None,
    ):
        with pytest.raises(LookupError, match="searched again"):
            selection.infeasible(*args, 1.0, None, said.append, known)
