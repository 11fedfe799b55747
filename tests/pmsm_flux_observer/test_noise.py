"""The PLL's angle-noise figure (design/pmsm_flux_observer/linearize.py ``discrete_analysis`` with
``sigma``) against a Monte-Carlo run of the runtime step itself: the generated step iterated with
current-sensor noise added to its current samples, on the motor sampled under zero-order hold, at one
operating point; the RMS of theta - theta_pll is compared with the figure (a statistical tolerance)."""

from __future__ import annotations

import casadi as ca
import numpy as np
from sensorless.design.discrete import fixed_points, pmsm_zoh_plant
from sensorless.design.drive import load_drive
from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer.gains import runtime_setup
from sensorless.design.pmsm_flux_observer.linearize import (
    discrete_analysis,
    motor_vector,
    rotor_frame_loop,
    sampled_loop,
    with_gain,
)
from sensorless.design.rotor_frame import equilibrium_points, pmsm_steady_current


def test_angle_noise_matches_a_monte_carlo_run_of_the_step():
    drive = load_drive("outrunner270")
    g = GainSet("constant", {"observer_gain": 400.0, "pll_bandwidth": 400.0}, "test")
    o = drive.observer
    setup = runtime_setup(drive, g)
    p = setup.observer.pack_params(dict(setup.params))
    law = setup.schedule.law
    w, T = np.array([0.5 * drive.w_base]), np.array([0.5 * drive.T_N])
    frame = rotor_frame_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    x = equilibrium_points(frame, w, T, motor_vector(drive), with_gain(p, setup.gain)).x[:, :, None]
    loop = sampled_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    sigma = 0.05  # [A]: small beside the current (linear regime), large beside round-off
    _, _, _, noise = discrete_analysis(drive, loop, x[:, :, 0], w, T, p, setup.gain, sigma)
    # one period of the step with noise n added to the current samples, in rotor coordinates
    s = loop.symbols()
    n = ca.SX.sym("n", 2)
    th, ww, pl, pp, gain, y = s["theta"], s["w"], s["plant"], s["p"], s["gain"], s["y"]
    n_x = len(loop.observer.state) - 1
    x0 = loop.state(y, th, ww, pl, pp)
    meas = loop.sample(th, ww, pl, pp) + ca.vertcat(n, ca.SX.zeros(len(loop.observer.meas) - 2))
    x_next, _ = loop.step()(ca.vertcat(x0, 0), meas, pp, gain)
    y_next = loop.rotor(x_next[:n_x], th + ww * pp[loop.observer.index("params", "T_s")])
    f = ca.Function("f", [y, th, ww, pl, pp, gain, n], [y_next])
    i_r = pmsm_steady_current(T, motor_vector(drive))
    plant = pmsm_zoh_plant(drive.motor.vector(), w, i_r, o.T_obs)  # (1, n_plant)
    yf, _ = fixed_points(loop, x[:, :, 0], w, plant, p, setup.gain)
    rng = np.random.default_rng(1)
    N, burn = 40000, 2000
    ix = loop.n_y - 2
    noise_in = sigma * rng.standard_normal((N, 2))
    # the N periods in one call: the same step f iterated (mapaccum feeds each y_next back as y)
    run = f.mapaccum("run", N)
    ys = np.asarray(run(yf[0], 0.0, w[0], plant[0], p, setup.gain, noise_in.T))
    d = ys[ix]
    mc = np.sqrt(np.mean((d[burn:] - yf[0][ix]) ** 2))
    assert np.isfinite(noise[0, 0]) and noise[0, 0] > 0
    print(f"Monte-Carlo {mc:.4g} rad, figure {noise[0, 0]:.4g} rad")
    assert abs(mc / noise[0, 0] - 1) < 0.1
