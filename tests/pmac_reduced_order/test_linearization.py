"""De Angelo et al. (2006): automatic linearization vs a hand derivation; discrete vs continuous poles."""

import dataclasses

import numpy as np
import pytest
from sensorless.design.pmac_reduced_order.linearize import analyze, continuous_poles


def sinusoidal(drive, reading="mechanical", **motor):
    """The preset with the fundamental only (motor and observer), optionally other parameters."""
    motor.setdefault("Phi", drive.motor.Phi[:1])
    m = dataclasses.replace(drive.motor, harmonics=(1,), reading=reading, **motor)
    keys = {k: v for k, v in motor.items() if k in ("R", "L", "J")}
    e = dataclasses.replace(drive.estimate, harmonics=(1,), Phi=m.Phi, **keys)
    return dataclasses.replace(drive, motor=m, estimate=e)


def hand_matrix(g, Gamma, Phi1, J, p_r, with_load):
    """Error dynamics derived by hand (docs/families/pmac_reduced_order.md, "Hand derivation").

    Sinusoidal EMF: e = (w/p_r) Phi1 [-sin th, cos th], so (w_hat, theta_hat) are polar coordinates of
    e_hat and (9) splits into a radial and a tangential part. With delta = theta - theta_hat,
    e_w = w - w_hat (electrical), e_T = T_L + B omega - T_L_hat, linearized on the exact orbit:
        d delta/dt = e_w - g delta                      (tangential part of the correction g (e - e_hat))
        d e_w/dt   = -g e_w - (p_r/J) e_T               (radial part; (1/J) phi_hat (phi_hat.i - T_L_hat))
        d e_T/dt   = (Gamma/J) (Phi1^2/p_r) e_w         (adaptation (10): -(Gamma/J) phi_hat . e_e)
    Without load estimation e_T is not a state (T_L_hat = 0 is a constant input).
    """
    A = np.array(
        [
            [-g, 1.0, 0.0],
            [0.0, -g, -p_r / J],
            [0.0, Gamma / J * Phi1**2 / p_r, 0.0],
        ]
    )
    return A if with_load else A[:2, :2]


@pytest.mark.parametrize("reading", ["mechanical", "electrical"])
@pytest.mark.parametrize("with_load", [True, False])
def test_continuous_poles_match_hand_derivation(deangelo2006, reading, with_load):
    """Random parameters, gains, speeds (both signs) and loads: same characteristic polynomial."""
    rng = np.random.default_rng(2006)
    for _ in range(6):
        params = {
            "R": deangelo2006.motor.R * rng.uniform(0.2, 5),
            "L": deangelo2006.motor.L * rng.uniform(0.2, 5),
            "J": deangelo2006.motor.J * rng.uniform(0.2, 5),
            "Phi": (deangelo2006.motor.Phi[0] * rng.uniform(0.2, 5),),
        }
        d = sinusoidal(deangelo2006, reading, **params)
        g, Gamma = rng.uniform(50, 2000), rng.uniform(0, 1e5)
        w = d.rpm_to_w(rng.choice([-1, 1]) * rng.uniform(20, 4000, 3))
        T_L = rng.uniform(-100, 100, 3)
        if not with_load:
            # without estimation the exact orbit is an equilibrium only when nothing loads the motor
            d = dataclasses.replace(d, motor=dataclasses.replace(d.motor, B=0.0))
            T_L = 0 * T_L
        poles = continuous_poles(d, w, T_L, with_load, g=g, Gamma=Gamma)
        A = hand_matrix(g, Gamma, params["Phi"][0], params["J"], d.motor.p_r, with_load)
        for p in poles:
            np.testing.assert_allclose(np.poly(p).real, np.poly(A), rtol=1e-9, atol=1e-9 * g ** len(p))
        if with_load:
            # and the closed form of the poles: -g and the roots of s^2 + g s + Gamma (Phi1/J)^2
            k2 = Gamma * (params["Phi"][0] / params["J"]) ** 2
            want = np.sort_complex(np.r_[-g, np.roots([1, g, k2])])
            np.testing.assert_allclose(np.sort_complex(poles[0]), want, rtol=1e-7, atol=1e-9 * g)


def test_without_estimation_loaded_poles_move_by_the_steady_offset(deangelo2006):
    """Loaded and without load estimation, [11]'s observer settles at the speed offset
    e_w = -p_r (T_L + B omega) / (J g); the linearization (taken on the exact orbit) then differs from
    the hand matrix by O(e_w / w), and by no more."""
    d = sinusoidal(deangelo2006)
    w = d.rpm_to_w(np.array([100.0, 250.0, 1000.0]))
    T_L = 5.0
    poles = continuous_poles(d, w, T_L, False)
    A = hand_matrix(400.0, 0.0, 0.5021, 0.78, 8.0, False)
    offset = 8.0 * T_L / (0.78 * 400.0)  # |e_w| [rad/s]
    for p, wk in zip(poles, w, strict=True):
        err = np.max(np.abs(np.poly(p).real - np.poly(A)) / 400.0 ** np.arange(3))
        assert err < 10 * offset / wk, (err, offset / wk)


def test_preset_poles_are_the_papers_gains(deangelo2006):
    """g = 400, Gamma = 10000, Phi1 = 0.5021, J = 0.78: -400, -389.4 and the slow -10.6 1/s, at every speed
    and load, in both readings (the poles do not depend on the reading: p_r cancels)."""
    for reading in ("mechanical", "electrical"):
        d = sinusoidal(deangelo2006, reading)
        w = d.rpm_to_w([-4000, -250, 100, 250, 4000])
        poles = continuous_poles(d, w[:, None], np.array([0, 5, -7])[None, :])
        k2 = 1e4 * (0.5021 / 0.78) ** 2
        slow = -200 + np.sqrt(200**2 - k2)
        assert slow == pytest.approx(-10.65, abs=0.01)
        np.testing.assert_allclose(poles.real.max(axis=1), slow, rtol=1e-9)
        np.testing.assert_allclose(poles.real.min(axis=1), -400, rtol=1e-9)


def charpoly_error(p, q, scale):
    """Largest difference of the monic characteristic polynomials, coefficient k scaled by scale^k.

    Coefficients, not roots: the preset's two fast poles (-400, -389) are nearly a double root, which a
    perturbation eps splits by sqrt(eps); the polynomial moves by eps."""
    cp, cq = np.poly(p).real, np.poly(q).real
    k = np.arange(cp.size)
    return np.max(np.abs(cp - cq) / scale**k)


@pytest.mark.parametrize("method", ["euler", "rk2", "rk2-model"])
def test_discrete_poles_converge_to_continuous(deangelo2006, method):
    """The one-step map's eigenvalues, mapped by ln(z)/T_s, approach the continuous poles as T_s -> 0
    (first order for Euler, second for the RK2 schemes)."""
    d = sinusoidal(deangelo2006)
    w, T_L = d.rpm_to_w(250.0), 5.0
    pc = continuous_poles(d, w, T_L)[0]
    errs = []
    for T_s in (180e-6, 45e-6):
        r = analyze(d, w, T_L, method=method, T_s=T_s)
        np.testing.assert_allclose(r.poles[0], pc)
        errs.append(charpoly_error(r.poles_discrete[0], pc, 400.0))
    order = np.log2(errs[0] / errs[1]) / 2  # the step shrank 4x
    assert errs[1] < (0.02 if method == "euler" else 0.002), errs
    assert order > (0.8 if method == "euler" else 1.6), (errs, order)


def test_default_discretization_keeps_continuous_poles_at_180us(deangelo2006):
    """At the paper's 180 us the runtime scheme's poles are within 3 % of the continuous ones (harmonic
    motor: Floquet exponents over one period), over the preset's envelope."""
    w = deangelo2006.rpm_to_w(np.array([-250, 100, 250, 400, 1000]))
    r = analyze(deangelo2006, w[:, None], np.array([0.0, 5.0])[None, :])
    assert r.method == "rk2-model"
    for pd, pc in zip(r.poles_discrete, r.poles, strict=True):
        assert charpoly_error(pd, pc, 400.0) < 0.02
    slow_c, slow_d = r.poles.real.max(axis=1), r.poles_discrete.real.max(axis=1)
    np.testing.assert_allclose(slow_d, slow_c, rtol=0.03)
    assert (r.memory_z < 0.5).all()  # the harmonic-removal memory modes are fast


@pytest.mark.parametrize("harmonics", [False, True])
def test_slow_pole_is_the_simulated_decay_rate(deangelo2006, harmonics):
    """Linear analysis vs simulation: a T_L_hat error of 0.5 N m on the running observer decays at the
    rate of the slowest discrete pole (the Floquet exponent with harmonics), within 1 %."""
    from sensorless.design.discrete import orbit_function
    from sensorless.design.pmac_reduced_order.one_step import sampled_loop
    from sensorless.design.pmac_reduced_order.operating_point import exact_state_function

    d = deangelo2006 if harmonics else sinusoidal(deangelo2006)
    w, T_L, T_s = float(d.rpm_to_w(250.0)), 5.0, d.control.T_s
    r = analyze(d, w, T_L)
    om, oo = d.motor.harmonics, d.estimate.harmonics
    params = d.observer_params()
    x0 = np.asarray(exact_state_function(om, oo, True)(0.3, w, T_L, d.motor.vector(), params)).ravel()
    n = 2500  # 0.45 s
    plant = np.r_[T_L, d.motor.vector()]
    # the runtime step on the sampled motor (its state with the contract's counter at 0)
    orbit = orbit_function(sampled_loop(d.control.discretization, om, oo, True), n)
    ref = np.asarray(orbit(np.r_[x0, 0], 0.3, w, plant, params, [])[2])[2]  # T_L_hat
    x0[2] += 0.5  # tau, hence T_L_hat, 0.5 N m too high
    # the response to the perturbation: the difference to the unperturbed run (which carries the
    # scheme's small steady bias and, with harmonics, a ripple)
    e_T = np.abs(np.asarray(orbit(np.r_[x0, 0], 0.3, w, plant, params, [])[2])[2] - ref)
    t = T_s * np.arange(1, n + 1)
    # the fast poles (-400, -389) are gone after 0.1 s; fit ln|e_T| on 0.15..0.45 s
    sel = t > 0.15
    slope = np.polyfit(t[sel], np.log(e_T[sel]), 1)[0]
    assert slope == pytest.approx(r.poles_discrete[0].real.max(), rel=0.01)
    assert slope == pytest.approx(r.poles[0].real.max(), rel=0.01)


@pytest.mark.parametrize("errors", [True, False])
def test_point_is_judged_over_its_own_window_only(deangelo2006, errors):
    """A point's result does not depend on the points analysed with it, even where its orbit leaves
    the runtime's bounds after its own window. Constructed: literal rk2 at 180 us, 1481.64 r/min, 5 N m
    is just past a fold (rk2 loses its steady state near 1480 r/min with the preset's harmonics): the
    orbit lingers near it and is rejected only ~5000 steps in, after the point's own window (settling
    4168 + 7 steps) but before that of a 5 r/min point (4169 + 2083: the batch simulates that long)."""
    w = deangelo2006.rpm_to_w(np.array([1481.64, 5.0]))
    alone = analyze(deangelo2006, w[0], 5.0, method="rk2", errors=errors)
    batch = analyze(deangelo2006, w, 5.0, method="rk2", errors=errors)
    # the construction holds: finite over its own window, rejected over a longer one (0.9 s settling)
    assert np.isfinite(alone.poles_discrete).all()
    later = analyze(deangelo2006, w[0], 5.0, method="rk2", errors=errors, settle_time=0.9)
    assert np.isnan(later.poles_discrete).all()
    for f in dataclasses.fields(alone):
        a, b = getattr(alone, f.name), getattr(batch, f.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(b[:1], a, err_msg=f.name)


def test_floquet_poles_and_noise_do_not_depend_on_the_batch(deangelo2006):
    """With harmonics a point's window is M_jac steps (83 at 250 r/min, 521 at 20 r/min); a batch pads
    the shorter windows to its longest. The padding must be exactly neutral: the Floquet product
    pairs a point's own factors as alone, and the noise covariance (the tuner's path: noise, no error
    window) is the mean over the point's own period, not over the padded one."""
    w = deangelo2006.rpm_to_w(np.array([250.0, 20.0]))
    alone = analyze(deangelo2006, w[0], 5.0, noise=True, errors=False)
    batch = analyze(deangelo2006, w, 5.0, noise=True, errors=False)
    assert batch.steps[0] < batch.steps[1]  # the construction: the 250 r/min window is padded
    assert np.isfinite(alone.noise).all() and np.isfinite(alone.poles_discrete).all()
    for f in dataclasses.fields(alone):
        a, b = getattr(alone, f.name), getattr(batch, f.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(b[:1], a, err_msg=f.name)
