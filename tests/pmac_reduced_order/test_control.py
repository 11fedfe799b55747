"""Speed control of Fig. 1: PI gains, load-torque feedforward, ripple-free current references (25)."""

import numpy as np
import pytest
from sensorless.symbolic.pmac_reduced_order.control import (
    SPEED_PARAM_NAMES,
    speed_controller_function,
    speed_pi_gains,
)


def speed_params(drive, feedforward=True):
    """The speed controller's params (SPEED_PARAM_NAMES) of the drive, as its simulation sets them."""
    k_p, k_i = speed_pi_gains(drive.control.alpha_s, drive.estimate.J, drive.motor.p_r)
    return np.array([k_p, k_i, drive.control.T_max, drive.control.T_s, float(feedforward)])


def test_pi_gains_place_a_double_pole(deangelo2006):
    """Closed loop of s w = (p_r/J)(k_p + k_i/s)(w_ref - w): s^2 + (p_r k_p/J) s + p_r k_i/J = (s+a)^2."""
    for reading_p_r in (8.0, 1.0):
        k_p, k_i = speed_pi_gains(7.0, 0.78, reading_p_r)
        np.testing.assert_allclose(
            np.roots([1, reading_p_r * k_p / 0.78, reading_p_r * k_i / 0.78]), [-7, -7]
        )
    assert len(speed_params(deangelo2006)) == len(SPEED_PARAM_NAMES)


def test_current_references_are_the_least_current_for_the_torque():
    """(25): phi_hat . i* = T_e* + T_L_hat, and i* is the minimum-norm solution (numpy's pseudo-inverse)."""
    F = speed_controller_function()
    rng = np.random.default_rng(25)
    for _ in range(20):
        phi = rng.normal(size=2)
        T_L_hat = rng.uniform(-10, 10)
        w_hat = rng.uniform(-300, 300)
        _, T_ref, i_ref = F(0.0, w_hat + 1.0, w_hat, T_L_hat, phi, [3.0, 10.0, 1e3, 1e-4, 1.0])
        i_ref = np.asarray(i_ref).ravel()
        assert phi @ i_ref == pytest.approx(float(T_ref), rel=1e-12)
        assert float(T_ref) == pytest.approx(3.0 + T_L_hat, rel=1e-12)  # k_p * 1 rad/s + feedforward
        np.testing.assert_allclose(i_ref, np.linalg.pinv(phi[None, :]) @ [float(T_ref)], rtol=1e-12)


def test_feedforward_takes_the_load_off_the_integrator(deangelo2006):
    """Closed speed loop on an ideal plant, dw/dt = p_r (T - T_L)/J, with an exact T_L_hat: with
    feedforward the PI integral settles at 0, without it at T_L; the speed settles at the reference."""
    F = speed_controller_function()
    J, p_r = 0.78, 8.0
    w_ref, T_L, dt = 200.0, 5.0, 1e-3
    for ff, x_i_end in ((1.0, 0.0), (0.0, T_L)):
        par = speed_params(deangelo2006, feedforward=bool(ff))
        par[3] = dt
        w, x_i = w_ref, 0.0
        for _ in range(5000):
            x_i, T, _ = F(x_i, w_ref, w, T_L, [1.0, 0.0], par)
            x_i, T = float(x_i), float(T)
            w += dt * p_r * (T - T_L) / J
        assert w == pytest.approx(w_ref, abs=1e-6)
        assert x_i == pytest.approx(x_i_end, abs=1e-6)


def test_torque_limit_does_not_wind_up():
    F = speed_controller_function()
    par = [10.0, 100.0, 50.0, 1e-3, 1.0]
    x_i = 0.0
    for _ in range(100):  # a large speed error for 0.1 s: the output is limited, the integral frozen
        x_i, T, _ = F(x_i, 1000.0, 0.0, 0.0, [1.0, 0.0], par)
    assert float(T) == 50.0 and float(x_i) == 0.0
    x_i, T, _ = F(x_i, 0.0, 1.0, 0.0, [1.0, 0.0], par)  # error reversed: integrates again at once
    assert float(x_i) < 0
