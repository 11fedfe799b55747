"""The sampled observer's fixed point is the one that continues the continuous equilibrium: on the
hubmotor48 preset at rated load near 1 p.u., plain Newton from the continuous equilibrium failed (no
fixed point at 0.95 p.u.) or landed on another fixed point of the nonlinear step (+16.5 deg, unstable)
at 1 p.u.; the sampled observer there differs from the continuous one only by its sampling (the angle
errors within half a degree, both stable), at the neighbouring torques as well."""

from __future__ import annotations

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of


def test_the_sampled_fixed_point_continues_the_continuous_equilibrium():
    d = load_drive("hubmotor48")
    fam = family_of(d)
    w = np.array([0.93, 0.95, 0.98, 1.0, 0.95, 1.0]) * d.w_base
    T = np.array([1, 1, 1, 1, 0.98, 1.01]) * d.T_N
    lin = fam.linearize(d, fam.gains(d), w, T)
    assert np.isfinite(lin.theta_err_discrete).all()
    assert np.degrees(np.abs(lin.theta_err_discrete - lin.theta_err)).max() < 0.5
    assert (lin.decay_rate_discrete > 0).all() and (lin.decay_rate > 0).all()


def test_points_without_a_continuous_equilibrium_are_left_out_and_the_others_unchanged(monkeypatch):
    """The damped Newton (design/discrete.py ``newton``, through sampled_fixed_points) iterates only the
    points that have a start (the continuous equilibrium): the others NaN, never evaluated (it once
    iterated them from 0 for every damped step), and the rest the same numbers, bit for bit, as Newton
    on those points alone."""
    from sensorless.design import discrete
    from sensorless.design.pmsm_flux_observer.linearize import (
        motor_vector,
        rotor_frame_loop,
        sampled_fixed_points,
        sampled_loop,
        sampled_plant,
        with_gain,
    )
    from sensorless.design.rotor_frame import equilibrium_points

    d = load_drive("hubmotor48")
    setup = family_of(d).runtime(d, family_of(d).gains(d))
    assert setup.schedule is not None
    law, o = setup.schedule.law, d.observer
    p = setup.observer.pack_params(dict(setup.params))
    w = np.array([0.3, 0.5, 0.7, 0.9, 1.0]) * d.w_base
    T = np.array([0.5, 1.0, 0.0, 1.0, -1.0]) * d.T_N
    frame = rotor_frame_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    y0 = equilibrium_points(frame, w, T, motor_vector(d), with_gain(p, setup.gain)).x
    y0[[1, 3]] = np.nan
    loop = sampled_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    plant = sampled_plant(d, w, T)
    evaluated = []
    real = discrete.evaluate_batch
    monkeypatch.setattr(
        discrete, "evaluate_batch", lambda fn, n, *a, **k: evaluated.append(n) or real(fn, n, *a, **k)
    )
    y, Jd = sampled_fixed_points(loop, y0, w, plant, p, setup.gain)
    with_nan = sum(evaluated)
    evaluated.clear()
    kept = [0, 2, 4]
    y_alone, Jd_alone = sampled_fixed_points(loop, y0[kept], w[kept], plant[kept], p, setup.gain)
    assert with_nan == sum(evaluated)  # the points without a start cost nothing
    assert np.isnan(y[[1, 3]]).all() and np.isnan(Jd[[1, 3]]).all() and np.isfinite(y[kept]).all()
    np.testing.assert_array_equal(y[kept], y_alone)
    np.testing.assert_array_equal(Jd[kept], Jd_alone)


def test_the_angle_errors_under_several_estimates_in_one_batch_are_each_linearizations():
    """sampled_angle_errors (the report's bias curves) runs the estimates in one batch: each row the
    ``theta_err_discrete`` of the family's linearization under that estimate, bit for bit."""
    from sensorless.design.pmsm_flux_observer.linearize import sampled_angle_errors

    d = load_drive("hubmotor48")
    fam, e = family_of(d), d.estimate
    gains = fam.gains(d)
    w = np.array([0.2, 0.5, 0.8, 1.0]) * d.w_base
    estimates = [{"R_s": 1.3 * e.R_s}, {"psi_pm": 0.9 * e.psi_pm, "L_d": 1.2 * e.L_d, "L_q": 1.2 * e.L_q}]
    errs = sampled_angle_errors(d, gains, w, d.T_N, estimates)
    assert errs.shape == (2, w.size) and np.isfinite(errs).any()
    for err, est in zip(errs, estimates, strict=True):
        np.testing.assert_array_equal(err, fam.linearize(d, gains, w, d.T_N, estimate=est).theta_err_discrete)
