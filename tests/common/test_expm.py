"""Batched matrix exponentials (design/expm.py) against scipy.linalg.expm and a closed form."""

from __future__ import annotations

import numpy as np
import pytest
from sensorless.design.expm import expm_batched


def test_agrees_with_scipy_over_every_pade_degree_and_scaling():
    from scipy.linalg import expm  # here, not at every worker's collection (scipy: ~0.3 s)

    rng = np.random.default_rng(7)
    base = rng.standard_normal((60, 5, 5))
    # 1-norms from 1e-4 (degree 3) through 1e3 (degree 13 with squaring), in one stack
    scales = np.logspace(-4, 3, base.shape[0])
    A = base / np.abs(base).sum(axis=1).max(axis=1)[:, None, None] * scales[:, None, None]
    got = expm_batched(A)
    ref = np.array([expm(a) for a in A])
    err = np.abs(got - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    # to rounding where exp(A) is well conditioned; large norms amplify rounding in both
    assert err[scales <= 10].max() < 1e-13
    assert err.max() < 1e-10


def test_rotation_and_decay_closed_form():
    # exp([[-a, -w], [w, -a]] t) = e^{-a t} [[cos wt, -sin wt], [sin wt, cos wt]]: the motor's
    # rotating, decaying flux at speeds up to a few hundred sampling periods per turn and beyond
    a, t = 3.0, 1e-4
    w = np.array([0.0, 10.0, 2e3, 2e4, 2e5])
    A = np.zeros((w.size, 2, 2))
    A[:, 0, 0] = A[:, 1, 1] = -a * t
    A[:, 0, 1], A[:, 1, 0] = -w * t, w * t
    c, s = np.cos(w * t), np.sin(w * t)
    exact = np.exp(-a * t) * np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    np.testing.assert_allclose(expm_batched(A), exact, rtol=0, atol=1e-14)


def test_zero_order_hold_keeps_small_entries_accurate():
    # exp([[A, B], [0, 0]] T) holds int_0^T e^{A s} ds B in its corner: tiny against the identity,
    # it must keep its relative accuracy (scalar case: (e^{aT} - 1)/a)
    a = np.array([-1e-3, -1.0, -50.0, 1e-6])
    T = 1e-4
    M = np.zeros((a.size, 2, 2))
    M[:, 0, 0], M[:, 0, 1] = a * T, T
    corner = expm_batched(M)[:, 0, 1]
    exact = np.expm1(a * T) / a
    np.testing.assert_allclose(corner, exact, rtol=1e-13)


@pytest.mark.parametrize("n", [1, 3])
def test_zero_matrix_is_identity(n):
    np.testing.assert_array_equal(expm_batched(np.zeros((4, n, n))), np.broadcast_to(np.eye(n), (4, n, n)))


def test_stable_matrices_and_a_jordan_block_match_scipy():
    from scipy.linalg import expm

    # the reduced-order observer's Floquet sub-intervals: decaying 3 x 3 matrices over ten decades
    rng = np.random.default_rng(1)
    scale = np.geomspace(1e-8, 30, 200)[:, None, None]
    A = rng.normal(size=(200, 3, 3)) * scale - 2 * scale * np.eye(3)
    A[0] = [[-5, 1, 0], [0, -5, 1], [0, 0, -5]]  # a Jordan block (critical damping)
    ref = np.stack([expm(a) for a in A])
    err = np.abs(expm_batched(A) - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    assert err.max() < 1e-12
