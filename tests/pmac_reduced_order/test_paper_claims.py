"""De Angelo et al. (2006) claims (Figs. 2-4) in a short simulation of the observer fed by an exact motor."""

import dataclasses

import numpy as np
import pytest
from helpers.observer_pmac import T_END, T_STEP, WINDOW, simulate, window_mean


@pytest.fixture(scope="module", params=["mechanical", "electrical"])
def runs(request, deangelo2006):
    d = dataclasses.replace(
        deangelo2006, motor=dataclasses.replace(deangelo2006.motor, reading=request.param)
    )
    return d, {G: simulate(d, 250.0, 5.0, Gamma=G) for G in (0.0, None)}


def test_without_load_estimation_speed_error_is_constant_and_nonzero(runs):
    """Fig. 2: without T_L estimation the speed error settles at a nonzero constant after the step;
    its size is the hand-derived steady state of the linearized error dynamics, e_w = -p_r T / (J g)."""
    d, res = runs
    t, w, _, T_obs, w_hat, _, _ = res[0.0]
    err = w - w_hat
    T_tot = window_mean(t, T_obs, T_END)  # 5 N m + B omega
    expect = -d.motor.p_r * T_tot / (d.estimate.J * d.observer.g)
    loaded = window_mean(t, err, T_END)
    assert loaded == pytest.approx(expect, rel=0.02)
    # constant: the last two windows agree to 1 %
    assert window_mean(t, err, T_END - WINDOW) == pytest.approx(loaded, rel=0.01)
    # before the step only viscosity loads the motor: a much smaller error of the same law
    T0 = window_mean(t, T_obs, T_STEP)
    assert window_mean(t, err, T_STEP) == pytest.approx(-d.motor.p_r * T0 / (d.estimate.J * 400), rel=0.05)


def test_with_load_estimation_speed_error_returns_to_zero(runs):
    """Fig. 3: with the adaptation (10) the error returns to (near) zero. 'Near' = at most 2 % of the
    error the estimation removes (the Gamma = 0 steady state): the default discretization leaves a
    steady bias far below that (docs/families/pmac_reduced_order.md), so 2 % is a margin, not a fit."""
    _, res = runs
    t, w, th, _, w_hat, th_hat, _ = res[None]
    ref = abs(window_mean(t, res[0.0][1] - res[0.0][4], T_END))
    err = window_mean(t, w - w_hat, T_END)
    assert abs(err) < 0.02 * ref, (err, ref)
    # and right after the step the error is of the same order as without estimation (there is a
    # transient to remove), so the test is not passing because nothing happens
    sel = (t > T_STEP) & (t < T_STEP + 0.1)
    assert np.abs(w - w_hat)[sel].max() > 0.3 * ref
    # the position error is negligible as well (electrical rad)
    pos = np.angle(np.exp(1j * (th - th_hat)))
    assert abs(window_mean(t, pos, T_END)) < 1e-3


def test_load_torque_estimate_converges_to_load_plus_viscosity(runs):
    """Figs. 3(a), 4: T_L_hat -> T_L + B omega, before (viscosity only) and after the step. The
    tolerance is 10 % of the viscous torque B omega, so it tells T_L + B omega from T_L."""
    d, res = runs
    t, w, _, T_obs, _, _, T_hat = res[None]
    B_w = d.motor.B * window_mean(t, w, T_END) / d.motor.p_r
    assert B_w > 0.03  # N m: 0.039 mechanical reading, 0.31 electrical
    for t_end, load in ((T_STEP, 0.0), (T_END, 5.0)):
        est = window_mean(t, T_hat, t_end)
        assert est == pytest.approx(load + B_w, abs=0.1 * B_w)
        assert window_mean(t, T_obs, t_end) == pytest.approx(load + B_w, abs=1e-3 * B_w)
