"""The constant-gain tuner (De Angelo et al. 2006) on any motor: the default Gamma search box scales with
(J/Phi_1)^2 and contains the hand-derived critical curve over the g box; the fast paths of the analysis
(no error window, batched matrix exponential) give the same poles as the full one."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.envelope import Envelope, SpeedRule
from sensorless.design.pmac_reduced_order.linearize import analyze
from sensorless.tuning.pmac_reduced_order.settings import closed_form, default_settings


@pytest.fixture(scope="module")
def servo_drive():
    return load_drive(str(Path(__file__).parent / "drives" / "servo5kw_minimal.toml"))


def fake_drive(J, Phi1, g, Gamma):
    return SimpleNamespace(
        estimate=SimpleNamespace(J=J, Phi=(Phi1,)),
        observer=SimpleNamespace(g=g, Gamma=Gamma),
        envelope=Envelope(SpeedRule(listed=(100.0,)), (0.0,), 1.0, 1.0),
    )


def c_of(Gamma, d):
    """c = Gamma (Phi_1/J)^2: the constant term of s^2 + g s + c (the family's hand derivation)."""
    return Gamma * (d.estimate.Phi[0] / d.estimate.J) ** 2


@pytest.mark.parametrize("J_over_Phi", [1e-6, 4e-4, 1.55, 1e3])
@pytest.mark.parametrize("sT_over_g", [1e-6, 0.026, 0.25])  # a flywheel's slow root .. the derivation's cap
def test_gamma_box_scales_with_the_motor(J_over_Phi, sT_over_g):
    """In units of c the box depends on g only; it holds the drive's gains, critical damping (the
    quadratic's roots at -g/2, c = g^2/4, checked on np.roots) at every g of the g box, and the closed
    form reaches the g bound (Gamma never caps it), for tiny and huge J/Phi_1."""
    g0 = 400.0
    s_T = sT_over_g * g0
    d = fake_drive(J_over_Phi, 1.0, g0, s_T * (g0 - s_T) * J_over_Phi**2)
    st = default_settings(d)
    lo, hi = c_of(st.Gamma_min, d), c_of(st.Gamma_max, d)
    assert st.g_min == pytest.approx(4.0) and st.g_max == pytest.approx(4e4)
    assert st.Gamma_min <= d.observer.Gamma <= st.Gamma_max
    for g in np.geomspace(st.g_min, st.g_max, 9):
        c = g**2 / 4
        assert lo * (1 - 1e-12) <= c <= hi * (1 + 1e-12)
        r = np.roots([1, g, c])
        assert np.allclose(r, -g / 2, rtol=1e-6)
    # the quadratic's damping at the upper bound and g_max: g / (2 sqrt(c)) = 1/2
    assert st.g_max / (2 * np.sqrt(hi)) == pytest.approx(0.5)
    g, G = closed_form(d, st.g_max, st.Gamma_max)
    assert g == pytest.approx(st.g_max) and c_of(G, d) == pytest.approx(g**2 / 4)


def test_gamma_box_of_the_servo_is_not_an_absolute_clamp(servo_drive):
    """The 5-kW servo's Gamma (0.758) is below 1 A^2 s^2: the box follows its (J/Phi_1)^2."""
    st = default_settings(servo_drive)
    k = (servo_drive.estimate.J / servo_drive.estimate.Phi[0]) ** 2
    assert st.Gamma_min == pytest.approx(min((st.g_min / 2) ** 2 * k, 0.01 * servo_drive.observer.Gamma))
    assert st.Gamma_max == pytest.approx(st.g_max**2 * k)


def test_poles_do_not_depend_on_the_error_window(servo_drive):
    """analyze(errors=False), the tuner's path, gives the full analysis' discrete poles and noise."""
    w = servo_drive.rpm_to_w(np.array([75.0, -750.0, 3000.0]))
    T = np.array([0.0, 16.0, -16.0])
    full = analyze(servo_drive, w, T, g=3000.0, Gamma=8.0, noise=True)
    fast = analyze(servo_drive, w, T, g=3000.0, Gamma=8.0, noise=True, errors=False)
    np.testing.assert_array_equal(fast.poles_discrete, full.poles_discrete)
    np.testing.assert_array_equal(fast.noise, full.noise)
    assert np.isfinite(full.err_w).all() and np.isnan(fast.err_w).all()
