"""The shared discrete-time analysis (design/discrete.py) on both families' presets: against the numbers
the three separate analyses gave before it, and against the runtime step itself.

Independent checks: the runtime step (``RuntimeSetup.step_function``, what codegen prints) is run on the
sampled motor until it has converged, which is the analysis' fixed point (or steady orbit); a central
finite-difference Jacobian of one step, in rotor coordinates typed here, has the analysis' discrete
poles as its ln(z)/T_s. The sampled motor: the adaptive family's ZOH voltage is the analysis' (checked
against scipy in tests/ipmsm_adaptive/test_discrete.py), the reduced-order family's signals come from
the test plant of tests/helpers/plant_pmac.py. The PLL test family's check is in test_third_family.py.
"""

import dataclasses
import math

import numpy as np
import pytest
from helpers.plant_pmac import Plant
from sensorless.design.ipmsm_adaptive import FAMILY as ADAPTIVE
from sensorless.design.pmac_reduced_order import FAMILY as REDUCED
from sensorless.design.pmac_reduced_order.linearize import analyze
from sensorless.design.runtime import run_trajectory

# Reference data: the results of main at fa40de5, before the shared module (the adaptive family's
# design/ipmsm_adaptive/one_step.py and the reduced-order family's one_step.py), printed to 12
# significant digits by FAMILY.linearize(drive, FAMILY.gains(drive, name=gain), w_pu * w_base, T * T_N,
# discretization=disc) and by analyze(deangelo2006, rpm_to_w(rpm), T_L, method=method).
ADAPTIVE_MAIN = {
    # (gain, scheme, w [p.u.], T [T_N]): (poles_discrete [1/s], err_theta [rad], feedthrough [rad/s/V])
    ("speed", "zoh", 0.5, 1.0): (
        [-102.035180788 - 182.958305984j, -411.320168244 - 105.23058504j],
        -5.92378982435e-05,
        [0.0, 0.0],
    ),
    ("constant", "heun", -0.67, 1.0): (
        [-22.5239286125 - 309.750936658j, -441.164861929 + 0j, -243.228189871 + 0j],
        0.000352459068573,
        [0.0, 0.115287803801],
    ),
    ("zero", "euler", 0.3, -1.0): (
        [-41.6823727349 - 137.718844472j, -548.530606267 + 0j, -215.471109191 + 0j],
        -0.0128010824012,
        [0.0, 0.0],
    ),
    ("speed", "heun-model", 0.8, 0.0): (
        [-218.529016041 - 300.736981731j, -338.506482993 - 203.85062094j],
        -1.82256834977e-05,
        [0.0, 0.0],
    ),
}
REDUCED_MAIN = {
    # (scheme, speed [r/min], T_L [N m]): (poles_discrete [1/s], [err_w, err_theta, err_T], memory |z|)
    ("rk2-model", 250.0, 5.0): (
        [-406.231238435, -381.59069267, -10.6753264434],
        [9.19978838187e-05, 1.1457243965e-06, 0.00209172953979],
        0.200105775245,
    ),
    ("rk2", 1000.0, 0.0): (
        [-401.112844059 - 24.2080899687j, -10.7578041274, -401.112844059 + 24.2080899687j],
        [4.84816018119, -0.00671686239602, -95.1309405194],
        0.201405567555,
    ),
    ("rk2-model", -400.0, 5.0): (
        [-415.371649806, -373.435053139, -10.6846404563],
        [0.000198657285062, 2.80824293532e-06, 0.000486499240788],
        0.199243504674,
    ),
}


def rot(a):
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def with_conjugates(poles):
    """The listed poles and the conjugates of the complex ones, sorted."""
    p = np.asarray(poles, complex)
    return np.sort_complex(np.concatenate([p, np.conj(p[p.imag != 0])]))


def same_poles(new, old, rtol):
    """Each pole of ``old`` has one of ``new`` within rtol, one to one (nearest first)."""
    new, old = list(np.asarray(new, complex)), np.asarray(old, complex)
    assert len(new) == old.size, (new, old)
    for p in old:
        k = int(np.argmin([abs(q - p) for q in new]))
        assert abs(new[k] - p) <= rtol * abs(p), (new, old)
        new.pop(k)


# --------------------------------------------------------------------------------------------------
# the adaptive observer (Piippo et al. 2008), the preset
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", list(ADAPTIVE_MAIN))
def test_adaptive_discrete_analysis_is_unchanged_and_is_the_runtime_step(drive, key):
    gain, disc, w_pu, T = key
    gains = ADAPTIVE.gains(drive, name=gain)
    w = w_pu * drive.base.w
    a = ADAPTIVE.linearize(drive, gains, w, T * drive.T_N, discretization=disc)
    poles, err_theta, feedthrough = ADAPTIVE_MAIN[key]
    # the numbers of main, within 1e-6
    same_poles(a.poles_discrete[0], with_conjugates(poles), 1e-6)
    assert a.err_theta[0] == pytest.approx(err_theta, rel=1e-6)
    assert np.allclose(a.feedthrough[0], feedthrough, rtol=1e-6, atol=1e-12)

    # the runtime step as generated (injection off), fed by the sampled motor
    s = ADAPTIVE.runtime(drive, gains, discretization=disc)
    setup = dataclasses.replace(s, params={**s.params, "injection": 0.0})
    step, T_s = setup.step_function(), setup.params["T_s"]
    X = {f.name: k for k, f in enumerate(setup.observer.state)}
    i_s0, u_z = a.i_s0[0], a.u_z[0]

    def state(y, theta_m):  # y = [psi_d, psi_q, w_i, theta_m - theta_hat, w_hat]
        x = setup.initial_state() * 0
        x[[X["psi_d"], X["psi_q"], X["w_i"], X["w_hat"]]] = y[[0, 1, 2, 4]]
        x[X["theta"]] = theta_m - y[3]
        return x

    def coords(x, theta_m):
        d = math.remainder(theta_m - x[X["theta"]], 2 * math.pi)
        return np.array([x[X["psi_d"]], x[X["psi_q"]], x[X["w_i"]], d, x[X["w_hat"]]])

    def F(y):  # one period from theta_m = 0.4
        x1 = np.asarray(step(state(y, 0.4), np.r_[rot(0.4) @ i_s0, rot(0.4) @ u_z], setup.p, setup.gain)[0])
        return coords(x1.ravel(), 0.4 + w * T_s)

    # from the continuous equilibrium, the step converges to the analysis' fixed point
    x0c = a.x0[0]  # [psi_d, psi_q, theta_tilde, w_i]
    n = 6000
    th = 0.4 + w * T_s * np.arange(n)
    R = np.array([rot(t) for t in th])  # each sample's rotation as before, the products in one batch
    meas = np.hstack([R @ i_s0, R @ u_z])
    xs, _ = run_trajectory(setup, meas, state(np.r_[x0c[[0, 1, 3, 2]], w], 0.4))
    y_sim = coords(xs[-1], th[-1] + w * T_s)
    assert np.allclose(y_sim[[0, 1]], a.y_d[0][[0, 1]], rtol=0, atol=1e-10)
    assert np.allclose(y_sim[[2, 4]], a.y_d[0][[2, 4]], rtol=1e-10)
    assert y_sim[3] == pytest.approx(a.err_theta[0], abs=1e-11)
    # the Jacobian of the step there, by central differences
    y0 = a.y_d[0]
    h = 1e-6 * np.maximum(np.abs(y0), 1.0)
    Jfd = np.column_stack(
        [(F(y0 + h[j] * e) - F(y0 - h[j] * e)) / (2 * h[j]) for j, e in enumerate(np.eye(5))]
    )
    assert np.allclose(a.J_d[0], Jfd, rtol=1e-6, atol=1e-6 * np.abs(Jfd).max())
    z = np.linalg.eigvals(Jfd).astype(complex)
    z = z[np.argsort(-np.abs(z))][:4]
    same_poles(a.poles_discrete[0], np.log(z) / T_s, 1e-6)


# --------------------------------------------------------------------------------------------------
# the reduced-order observer (De Angelo et al. 2006), the preset: EMF harmonics, Floquet on the orbit
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", list(REDUCED_MAIN))
def test_reduced_order_discrete_analysis_is_unchanged(deangelo2006, key):
    method, rpm, T_L = key
    r = analyze(deangelo2006, deangelo2006.rpm_to_w(rpm), T_L, method=method)
    poles, errs, memory = REDUCED_MAIN[key]
    same_poles(r.poles_discrete[0], np.asarray(poles, complex), 1e-6)
    assert np.allclose([r.err_w[0], r.err_theta[0], r.err_T[0]], errs, rtol=1e-6, atol=0)
    assert r.memory_z[0].max() == pytest.approx(memory, rel=1e-6)


@pytest.mark.parametrize("method", ["rk2-model", "rk2"])
def test_reduced_order_sinusoidal_fixed_point_is_the_runtime_step(deangelo2006, method):
    """Sinusoidal EMF: the orbit is a fixed point in rotor coordinates. The runtime step run on the
    test plant's samples settles where the analysis says (its steady errors), and the finite-difference
    Jacobian of one step there has the analysis' discrete poles."""
    m0 = deangelo2006.motor
    m = dataclasses.replace(m0, harmonics=(1,), Phi=m0.Phi[:1])
    d = dataclasses.replace(
        deangelo2006, motor=m, estimate=dataclasses.replace(deangelo2006.estimate, harmonics=(1,), Phi=m.Phi)
    )
    w, T_L = float(d.rpm_to_w(250.0)), 5.0
    r = analyze(d, w, T_L, method=method)
    setup = REDUCED.runtime(d, REDUCED.gains(d), discretization=method)
    step, T_s = setup.step_function(), setup.params["T_s"]
    plant = Plant(m.R, m.L, m.J, m.B, m.p_r, m.harmonics, m.Phi, w)
    T_e = T_L + m.B * w / m.p_r

    def samples(th):
        i, v, _ = plant.current_voltage(np.atleast_1d(th), w, T_e, 0.0, T_L)
        return np.vstack([i, v]).T

    n = 20000  # 3.6 s: the slowest pole (-10.7 1/s) has decayed by e^-38
    th = 0.3 + w * T_s * np.arange(n + 1)
    meas = samples(th)
    x0 = setup.initial_state()
    x0[4], x0[3], x0[5:9] = w, 0.3, meas[0]  # speed and angle known, the EMF state at 0
    xs, ys = run_trajectory(setup, meas[1:], x0)
    # the steady errors of the analysis (mean over a window; constant here)
    assert ys[-1, 0] == pytest.approx(w - r.err_w[0], rel=1e-10)
    assert math.remainder(th[-1] - ys[-1, 1], 2 * math.pi) == pytest.approx(r.err_theta[0], abs=1e-10)
    assert ys[-1, 2] == pytest.approx(T_e - r.err_T[0], abs=1e-8)

    def coords(x, t):  # [R(-theta) zeta, tau, theta_hat - theta, w_hat]
        return np.r_[rot(-t) @ x[0:2], x[2], math.remainder(x[3] - t, 2 * math.pi), x[4]]

    def F(y):  # one period from the motor at angle 0.1: the stored samples are the motor's there
        x = np.r_[rot(0.1) @ y[0:2], y[2], y[3] + 0.1, y[4], samples(0.1)[0], 0.0]
        x1 = np.asarray(step(x, samples(0.1 + w * T_s)[0], setup.p, setup.gain)[0]).ravel()
        return coords(x1, 0.1 + w * T_s)

    y0 = coords(xs[-1], th[-1])
    assert np.allclose(F(y0), y0, rtol=1e-10, atol=1e-10)  # a fixed point of the step
    h = 1e-4 * np.maximum(np.abs(y0), 1.0)  # (rounding dominates below: the step's states are large)
    Jfd = np.column_stack(
        [(F(y0 + h[j] * e) - F(y0 - h[j] * e)) / (2 * h[j]) for j, e in enumerate(np.eye(5))]
    )
    z = np.linalg.eigvals(Jfd).astype(complex)
    z = z[np.argsort(-np.abs(z))][:3]
    same_poles(r.poles_discrete[0], np.log(z) / T_s, 1e-6)


@pytest.mark.parametrize("scheme", ["zoh", "heun", "euler", "heun-model"])
def test_the_output_function_gives_the_sensitivity_functions_bits(scheme):
    """design/discrete.py ``output_function`` (what the adaptive family's discrete sweep evaluates) is
    ``sensitivity_function``'s out and Dm from a smaller graph: the same numbers, bit for bit, at points
    around a fixed point and far from it (law (16): the schedule's derivatives are in Dm)."""
    from sensorless.design import discrete
    from sensorless.design.ipmsm_adaptive.one_step import sampled_loop
    from sensorless.symbolic.ipmsm_adaptive.gains import LAWS

    loop = sampled_loop(scheme, LAWS["speed"])
    full, lean = discrete.sensitivity_function(loop), discrete.output_function(loop)
    rng = np.random.default_rng(7)
    args = [rng.normal(size=(full.size1_in(i), 64)) for i in range(full.n_in())]
    T_s = loop.observer.index("params", "T_s")
    args[4][T_s] = 1e-4  # a sampling period (the others: any numbers)
    out_f, _, _, Dm_f = (np.asarray(v) for v in full(*args))
    out_l, Dm_l = (np.asarray(v) for v in lean(*args))
    assert np.isfinite(out_f).all() and np.abs(Dm_f).max() > 0
    assert out_l.tobytes() == out_f.tobytes() and Dm_l.tobytes() == Dm_f.tobytes()
