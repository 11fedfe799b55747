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
