"""The runtime step against a numpy forward Euler of the same equations typed here (ODrive's order:
prediction with the previous period's voltage, then the gradient correction, then the PLL), its
guard on non-finite samples, and a simulation on a preset that converges from a 20-degree error."""

from __future__ import annotations

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.design.runtime import run_trajectory
from sensorless.design.scenario import load_scenario
from sensorless.design.simulate import simulate


def numpy_step(x, i, u, P, k_obs):
    """One period of Lee et al. (2010) eq. (8) as ODrive's sensorless_estimator.cpp runs it (prediction
    with the stored voltage, gradient correction, PLL predicted then corrected)."""
    T, R, L, lam = P["T_s"], P["R_s"], (P["L_d"] + P["L_q"]) / 2, P["psi_pm"]
    flux, u_prev, th, w = x[0:2], x[3:5], x[5], x[6]
    flux = flux + T * (u_prev - R * i)
    eta = flux - L * i
    gamma = k_obs / lam**2
    flux = flux + T * (gamma / 2) * eta * (lam**2 - eta @ eta)
    eta = flux - L * i
    th_obs = np.arctan2(eta[1], eta[0])
    th = th + T * w  # ODrive: predict the PLL angle, then correct it
    e = (th_obs - th + np.pi) % (2 * np.pi) - np.pi
    th_new = (th + T * P["k_p"] * e + np.pi) % (2 * np.pi) - np.pi
    w_new = w + T * P["k_i"] * e
    return np.array([*flux, lam, *u, th_new, w_new, 0.0]), (w_new, th_obs)


def test_step_matches_a_numpy_euler_of_the_same_equations():
    d = load_drive("outrunner270")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    P = setup.params
    rng = np.random.default_rng(5)
    n = 400
    th = np.cumsum(np.full(n, 1500.0 * P["T_s"]))
    i = np.stack([10 * np.cos(th + 1.5), 10 * np.sin(th + 1.5)], 1) + rng.normal(0, 0.3, (n, 2))
    u = np.stack([4.4 * np.cos(th + 1.6), 4.4 * np.sin(th + 1.6)], 1)
    xs, ys = run_trajectory(setup, np.hstack([i, u]))
    x = setup.initial_state()
    for k in range(n):
        x, (w, th_obs) = numpy_step(x, i[k], u[k], P, 1000.0)
        assert np.allclose(xs[k], x, rtol=1e-9, atol=1e-12), k
        assert ys[k, 0] == pytest.approx(w, rel=1e-9, abs=1e-9)
        assert ys[k, 1] == pytest.approx(th_obs, abs=1e-9)
    assert ys[:, -2].all() and not ys[:, -1].any()  # every sample valid, no reset


def test_a_non_finite_sample_is_rejected_and_the_observer_coasts():
    d = load_drive("hubmotor48")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    meas = np.array([[1.0, 0.0, 2.0, 0.0], [np.nan, 0.0, 2.0, 0.0], [1.0, 0.0, np.inf, 0.0]])
    xs, ys = run_trajectory(setup, meas)
    assert ys[:, -2].tolist() == [1.0, 0.0, 0.0]
    assert np.isfinite(xs).all()


@pytest.mark.parametrize("preset", ["outrunner270", "hubmotor48"])
def test_simulation_converges_on_the_presets(preset):
    d = load_drive(preset)
    tr = simulate(d, load_scenario("torque_steps", d))
    err = np.degrees(np.asarray(tr.data["theta_err"]))
    t = np.asarray(tr.t)
    assert abs(err[0]) > 10  # it starts 20 degrees off
    late = t > 0.05
    assert np.abs(err[late]).max() < 6.0
    assert np.asarray(tr.data["valid"]).all()


@pytest.mark.parametrize("correction", ["gradient", "clamped-gradient", "box-clamp"])
def test_flux_adaptation_recovers_a_flux_error(correction):
    """With the online adaptation on and the flux estimate 10 % low, lambda_hat reaches the motor's flux
    (within 1 %) on a steady motor (0.6 p.u., half the rated torque; the independent steady samples of
    tests/helpers/fuzz.py), and the angle error settles within 2 degrees."""
    import dataclasses

    from helpers.fuzz import pmsm_steady_segments

    d = load_drive("outrunner270")
    m = d.motor
    d = dataclasses.replace(
        d,
        observer=dataclasses.replace(d.observer, lambda_adaptation=True, correction=correction),
        estimate=dataclasses.replace(d.estimate, psi_pm=0.9 * m.psi_pm),
    )
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    w, T_e = 0.6 * d.w_base, 0.5 * d.T_N
    seg = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), d.T_s, [(w, T_e, 0.3)], 3000)[0]
    op = [0.3, w, 0.0, T_e / (1.5 * m.p * m.psi_pm)]
    x0 = np.asarray(setup.observer.steady_state()(setup.p, op)).ravel()
    xs, ys = run_trajectory(setup, seg[:, :4], x0)
    lam = xs[:, setup.observer.index("state", "lambda_hat")]
    assert lam[0] == pytest.approx(0.9 * m.psi_pm, rel=0.01)
    assert lam[-1] == pytest.approx(m.psi_pm, rel=0.01)
    err = np.degrees(np.angle(np.exp(1j * (seg[:, 4] - ys[:, 1]))))
    assert np.abs(err[-500:]).max() < 2.0


def test_a_pll_speed_at_its_bound_is_clamped_not_rejected_and_the_observer_recovers():
    """The PLL speed at its bound min(w_max, pi/(2T)) and the PLL angle 2 rad behind the rotor, so
    that the samples push the speed beyond it: every sample is used (valid; a rejecting guard coasts
    here), each period's speed is the PI's update clamped to the bound, typed here from the state and
    the observer angle, and the estimates come back to the motor's within the family's documented 200
    periods (0.1 rad, 2 % of the base speed; docs/families/pmsm_flux_observer.md)."""
    from helpers.fuzz import pmsm_steady_segments

    d = load_drive("outrunner270")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    obs, P, m = setup.observer, setup.params, d.motor
    T, b = P["T_s"], min(P["w_max"], np.pi / (2 * P["T_s"]))
    w, T_e = -0.8 * d.w_base, 0.5 * d.T_N
    seg = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), T, [(w, T_e, 0.3)], 400)[0]
    x0 = np.asarray(obs.steady_state()(setup.p, [0.3 - w * T, w, 0.0, T_e / (1.5 * m.p * m.psi_pm)])).ravel()
    j_th, j_w = obs.index("state", "theta_pll"), obs.index("state", "w_pll")
    x0[j_w] = -b  # the direction of rotation; its predicted angle 2 rad behind the first sample's
    x0[j_th] = (0.3 + 2.0 - T * x0[j_w] + np.pi) % (2 * np.pi) - np.pi
    xs, ys = run_trajectory(setup, seg[:, :4], x0)
    Y = {f.name: k for k, f in enumerate(obs.outputs)}
    assert ys[:, Y["valid"]].all() and not ys[:, Y["reset"]].any()
    prev = np.vstack([x0, xs[:-1]])
    th_pred = prev[:, j_th] + T * prev[:, j_w]
    e = (ys[:, Y["theta_hat"]] - th_pred + np.pi) % (2 * np.pi) - np.pi
    w_pi = prev[:, j_w] + T * P["k_i"] * e
    assert (np.abs(w_pi) > b).sum() >= 3  # the PI alone would leave the bound: the clamp acts
    assert np.allclose(xs[:, j_w], np.clip(w_pi, -b, b), rtol=1e-12, atol=1e-9)
    late = slice(200, None)
    assert np.abs(np.angle(np.exp(1j * (ys[late, Y["theta_hat"]] - seg[late, 4])))).max() < 0.1
    assert np.abs(ys[late, Y["w_hat"]] - w).max() < 0.02 * d.w_base
