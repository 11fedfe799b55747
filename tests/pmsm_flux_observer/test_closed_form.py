"""The flux observer's linearization against closed forms typed here from their derivations
(docs/families/pmsm_flux_observer.md): error poles s^2 + gamma lambda^2 s + w^2, the Euler bound
T gamma lambda^2 < 2, the resistance-error angle bias -gamma lambda dR i_q / w^2, the PLL's double pole
at -bw (k_p = 2 bw, k_i = bw^2), and motulator's equal poles with sigma = gamma lambda^2 / 2."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.family import CapabilityError, GainSet
from sensorless.design.registry import family_of


@pytest.fixture(scope="module")
def drive():
    return load_drive("outrunner270")


def gains(k: float, bw: float) -> GainSet:
    return GainSet("constant", {"observer_gain": k, "pll_bandwidth": bw}, "test")


def match(poles: np.ndarray, expected: np.ndarray, rtol: float) -> None:
    """Each expected pole has a computed one within rtol of its magnitude (and vice versa by count)."""
    left = list(poles)
    for e in expected:
        j = int(np.argmin([abs(p - e) for p in left]))
        assert abs(left[j] - e) <= rtol * max(abs(e), 1.0), (poles, expected)
        left.pop(j)


@pytest.mark.parametrize("k", [300.0, 1000.0, 4000.0])
def test_continuous_poles_are_the_error_poles_and_the_pll_double_pole(drive, k):
    bw = 700.0
    w = np.array([100.0, 900.0, 3000.0])  # no double root (k = 2 w)
    lin = family_of(drive).linearize(drive, gains(k, bw), w, np.zeros(3))
    for row, wk in zip(lin.poles, w, strict=True):
        observer = np.roots([1.0, k, wk**2])  # s^2 + gamma lambda^2 s + w^2
        pll = np.roots([1.0, 2 * bw, bw**2])  # k_p = 2 bw, k_i = bw^2: (s + bw)^2
        match(row, np.concatenate([observer, pll]), 1e-4)


def test_motulator_equal_poles(drive):
    """motulator's flux observer for a surface PMSM: s^2 + 2 sigma s + w^2 with sigma = gamma lambda^2/2."""
    k, w = 1200.0, 2500.0
    sigma = k / 2
    expected = np.array([-sigma + 1j * math.sqrt(w**2 - sigma**2), -sigma - 1j * math.sqrt(w**2 - sigma**2)])
    lin = family_of(drive).linearize(drive, gains(k, 400.0), np.array([w]), np.zeros(1))
    osc = lin.poles[0][np.abs(lin.poles[0].imag) > 1]
    match(osc, expected, 1e-5)


def test_euler_bound(drive):
    """Forward Euler at T: the discrete poles leave the unit circle once T gamma lambda^2 > 2."""
    T = drive.observer.T_obs
    w = np.array([0.05 * drive.w_base])
    fam = family_of(drive)
    below = fam.linearize(drive, gains(1.9 / T, 400.0), w, np.zeros(1))
    above = fam.linearize(drive, gains(2.1 / T, 400.0), w, np.zeros(1))
    assert below.decay_rate_discrete[0] > 0
    assert above.decay_rate_discrete[0] < 0
    assert below.decay_rate[0] > 0 and above.decay_rate[0] > 0  # the continuous observer is stable


@pytest.mark.parametrize("w", [800.0, 1500.0])
def test_resistance_error_bias(drive, w):
    """dR at i_d = 0 biases the angle by about -gamma lambda dR i_q / w^2 (small errors)."""
    fam = family_of(drive)
    k = 1000.0
    lam = drive.estimate.psi_pm
    T_e = 0.5 * drive.T_N
    i_q = T_e / (1.5 * drive.motor.p * drive.motor.psi_pm)
    dR = 0.02 * drive.estimate.R_s
    lin = fam.linearize(
        drive, gains(k, 500.0), np.array([w]), np.array([T_e]), estimate={"R_s": drive.estimate.R_s + dR}
    )
    bias_hat_minus_theta = -(k / lam**2) * lam * dR * i_q / w**2
    # the linearization reports theta - theta_obs
    assert -lin.theta_err[0] == pytest.approx(bias_hat_minus_theta, rel=0.05)


def test_box_clamp_is_not_linearizable(drive):
    d = dataclasses.replace(drive, observer=dataclasses.replace(drive.observer, correction="box-clamp"))
    with pytest.raises(CapabilityError, match="not linearizable"):
        family_of(d).linearize(d, gains(1000.0, 1000.0), np.array([1000.0]), np.zeros(1))
