"""The runtime contract's guard (symbolic/runtime.py): bounds as expressions of the parameters, the
counter of rejected samples, the self-reset; checked on the Python step of both built-in families (the
C is the same expression graph: tests/*/test_codegen*.py)."""

import math

import casadi as ca
import numpy as np
import pytest
from sensorless.design.registry import family_of
from sensorless.design.runtime import run_trajectory
from sensorless.symbolic.runtime import (
    REJECTS,
    RESET,
    RESET_AFTER,
    VALID,
    X_MAX,
    Field,
    RuntimeObserver,
    bound_expression,
)


def setup_of(drive):
    fam = family_of(drive)
    return fam.runtime(drive, fam.gains(drive))


@pytest.fixture(params=["drive", "deangelo2006"])
def setup(request):
    return setup_of(request.getfixturevalue(request.param))


def test_bounds_are_the_documented_expressions(drive, deangelo2006):
    """The values the headers document for the presets (docs/families/*.md, "Bounds and recovery")."""
    s = setup_of(drive)
    b = dict(
        zip([f.name for f in s.observer.state], np.asarray(s.observer.bounds()(s.p)).ravel(), strict=True)
    )
    assert b["psi_d"] == b["psi_q"] == pytest.approx(4 * 0.545)
    assert b["w_hat"] == b["w_i"] == pytest.approx(4 * drive.base.w)  # 2 w_max, w_max = 2 p.u.
    assert b["theta"] == b["phi_c"] == math.pi and b["x_eps"] == pytest.approx(0.1 * drive.base.w)
    assert b["bp_z1"] == X_MAX and b["rejects"] == RESET_AFTER
    s = setup_of(deangelo2006)
    b = dict(
        zip([f.name for f in s.observer.state], np.asarray(s.observer.bounds()(s.p)).ravel(), strict=True)
    )
    assert b["w_hat"] == (math.pi / 2) / deangelo2006.control.T_s
    assert b["tau"] == pytest.approx(2 * (1 + 1e4 * 1e-4 / 0.78) * 143)
    assert b["zeta_a"] == X_MAX


def test_a_run_of_rejected_samples_resets_the_state(setup):
    """NaN samples: rejected, counted; the 100th resets the state to the initial state (reset = 1) and
    the count starts again."""
    obs = setup.observer
    Y = {f.name: k for k, f in enumerate(obs.outputs)}
    meas = np.full((2 * RESET_AFTER + 10, 4), np.nan)
    x0 = setup.initial_state()
    x_start = x0.copy()
    x_start[obs.index("state", "theta")] = 1.0
    x_start[obs.index("state", "w_hat")] = 100.0
    xs, ys = run_trajectory(setup, meas, x_start)
    n = xs[:, -1]
    assert np.all(ys[:, Y["valid"]] == 0)
    resets = np.flatnonzero(ys[:, Y["reset"]])
    assert list(resets) == [RESET_AFTER - 1, 2 * RESET_AFTER - 1]
    assert np.array_equal(n[: RESET_AFTER - 1], np.arange(1, RESET_AFTER))
    assert n[RESET_AFTER - 1] == 0 and n[RESET_AFTER] == 1
    assert np.array_equal(xs[RESET_AFTER - 1], x0)  # as *_init leaves it
    assert xs[RESET_AFTER - 2, obs.index("state", "w_hat")] == 100.0  # coasting before
    assert np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))


def test_rejected_samples_outweighing_accepted_ones_reset_too(setup):
    """The counter goes down by one per accepted sample, not to 0: three NaN samples in every four
    still reach the reset (after 2 x 100 samples less a few); one in two never does."""
    obs = setup.observer
    Y = {f.name: k for k, f in enumerate(obs.outputs)}
    good = np.zeros(4)
    meas = np.array([good if k % 4 == 3 else np.full(4, np.nan) for k in range(300)])
    xs, ys = run_trajectory(setup, meas)
    first = np.flatnonzero(ys[:, Y["reset"]])[0]
    assert 190 <= first <= 200
    meas = np.array([good if k % 2 else np.full(4, np.nan) for k in range(1000)])
    xs, ys = run_trajectory(setup, meas)
    assert ys[:, Y["reset"]].sum() == 0 and xs[:, -1].max() == 1


def test_a_candidate_beyond_its_bound_is_rejected(drive):
    """The adaptive observer at the bound of its speed: a sample that would push |w_hat| beyond
    min(2 w_max, pi / (2 T_s)) is rejected and the speed estimate stays where it was."""
    s = setup_of(drive)
    obs = s.observer
    Y = {f.name: k for k, f in enumerate(obs.outputs)}
    w_b = float(np.asarray(obs.bounds()(s.p)).ravel()[obs.index("state", "w_hat")])
    x = s.initial_state()
    x[obs.index("state", "w_i")] = x[obs.index("state", "w_hat")] = w_b
    # a q-axis current error that raises the speed (9): i_q below its estimate
    xs, ys = run_trajectory(s, np.array([[0.0, -50.0, 0.0, 0.0]]), x)
    assert ys[0, Y["valid"]] == 0 and xs[0, obs.index("state", "w_hat")] == w_b


def test_the_contract_checks_its_fields_and_bound_expressions():
    params = (Field("a", "1", "", "positive"), Field("T_s", "s", "", "positive"))
    p = ca.SX.sym("p", 2)
    f = ca.Function("b", [p], [bound_expression("min(2 * a, pi / 2 / T_s)", params, p)])
    assert float(f([0.5, 0.01])) == 1.0 and float(f([1000, 0.01])) == pytest.approx(50 * math.pi)
    assert bound_expression("", params, p) is None
    for bad, words in [
        ("4 * b", "'b' is not a parameter"),
        ("__import__('os')", "not understood"),
        ("a +", "not an expression"),
    ]:
        with pytest.raises(ValueError, match=words):
            bound_expression(bad, params, p)

    def make(state, outputs):
        return RuntimeObserver(
            "toy", "toy", state, (), params, outputs, (), None, lambda d: None, lambda: None
        )

    make((Field("x", "1", "", bound="a"), REJECTS), (VALID, RESET))
    with pytest.raises(ValueError, match="last state field must be the contract's 'rejects'"):
        make((Field("x", "1", ""),), (VALID, RESET))
    with pytest.raises(ValueError, match="outputs must end with 'valid', 'reset'"):
        make((Field("x", "1", ""), REJECTS), (VALID,))
    with pytest.raises(ValueError, match="toy: state field x: bound 'c': 'c' is not a parameter"):
        make((Field("x", "1", "", bound="c"), REJECTS), (VALID, RESET))
