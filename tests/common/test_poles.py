"""Batched evaluation and batched eigenvalues agree with the plain paths they replace."""

import casadi as ca
import numpy as np
import pytest
from sensorless.design import batch
from sensorless.design.ipmsm_adaptive.linearize import linearize, sort_poles
from sensorless.design.poles import charpoly, eigvals_batched


def test_quartic_path_matches_lapack_on_random_and_structured_matrices():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3000, 4, 4)) * rng.uniform(0.1, 500, size=(3000, 1, 1))
    # structured cases: a zero eigenvalue, repeated eigenvalues, a block-diagonal with real poles,
    # widely spread scales (like the observer: 0.01 .. 500 1/s)
    A[0] = np.diag([0.0, -1.0, -2.0, -3.0])
    A[1] = np.diag([-5.0, -5.0, -5.0, -5.0])
    A[2] = np.array([[-1, 1, 0, 0], [0, -1, 1, 0], [0, 0, -1, 1], [0, 0, 0, -1.0]])
    A[3] = np.diag([-0.01, -500.0, -200.0, -100.0]) + 1e-3 * rng.normal(size=(4, 4))
    got = sort_poles(eigvals_batched(A))
    ref = sort_poles(np.linalg.eigvals(A))
    scale = np.abs(ref).max(axis=1, keepdims=True)
    close = np.abs(got - ref) / scale
    # defective matrices (rows 1, 2) have eigenvalues sensitive at sqrt(eps) or worse for any method
    assert close[3:].max() < 1e-9
    assert close[:3].max() < 1e-3
    c = charpoly(A[:10])
    for k in range(10):
        assert np.allclose(c[k], np.poly(A[k]), rtol=1e-9, atol=1e-9 * np.abs(c[k]).max())


def test_sweep_poles_match_lapack(drive):
    w = np.linspace(-1, 1, 2001) * drive.base.w
    for gain in ("zero", "constant", "speed"):
        s = linearize(drive, w, drive.T_N, gain=gain)
        ref = sort_poles(np.linalg.eigvals(s.A))
        assert np.abs(s.poles - ref).max() / np.abs(ref).max() < 1e-9


def test_batch_evaluation_matches_function_call_and_jit_matches_vm(monkeypatch):
    x = ca.SX.sym("x", 2)
    p = ca.SX.sym("p", 3)
    f = ca.Function(
        "f",
        [x, p],
        [ca.densify(ca.vertcat(ca.sin(x[0]) * p[0], x[1] ** 2 + p[2])), ca.densify(ca.horzcat(x, 2 * x))],
        ["x", "p"],
        ["y", "M"],
    )
    n = 5000
    rng = np.random.default_rng(0)
    X = rng.normal(size=(2, n))
    P = np.array([1.5, -2.0, 0.25])
    y, M = batch.evaluate_batch(f, n, [X, P])  # n >= JIT_MIN_POINTS: compiled when possible
    ref = f.map(n)(X, P)
    assert np.array_equal(y[:, :, 0].T, np.asarray(ref[0]))
    assert np.array_equal(M.transpose(1, 0, 2).reshape(2, -1), np.asarray(ref[1]))
    monkeypatch.setattr(batch, "JIT_MIN_POINTS", 10**9)  # force the virtual machine
    y_vm, _ = batch.evaluate_batch(f, n, [X, P])
    assert np.array_equal(y, y_vm)


@pytest.mark.parametrize("injection", [False, True])
def test_large_sweep_equals_small_sweeps(drive, injection):
    """The compiled large-batch path gives the same numbers as the VM small-batch path."""
    w = np.linspace(-1, 1, 5001) * drive.base.w
    big = linearize(drive, w, drive.T_N, injection=injection)
    idx = np.arange(0, w.size, 250)
    small = linearize(drive, w[idx], drive.T_N, injection=injection)
    assert np.array_equal(big.A[idx], small.A)


def test_batches_of_any_size_run_on_maps_of_a_few_sizes_with_the_bits_of_one_map(monkeypatch):
    x = ca.SX.sym("x", 2)
    p = ca.SX.sym("p", 1)
    f = ca.Function("f_sizes", [x, p], [ca.densify(ca.vertcat(ca.exp(x[0]) / (1 + x[1] ** 2), p * x[1]))])
    built = batch._mapped
    sizes: set[int] = set()

    def recorded(fn, n):
        sizes.add(n)
        return built(fn, n)

    monkeypatch.setattr(batch, "_mapped", recorded)
    rng = np.random.default_rng(1)
    odd = (5, 100, batch.CHUNK - 1, batch.CHUNK + 1, 2 * batch.CHUNK + 777)
    for n in (1, batch.CHUNK, *odd):
        X = rng.normal(size=(2, n))
        (y,) = batch.evaluate_batch(f, n, [X, 0.5], jit=False)
        assert np.array_equal(y[:, :, 0].T, np.asarray(f.map(n)(X, 0.5)))  # one map of n points
    # the chunk and the buckets of the rests (1, 2, 3 or 4 times a power of two), never a batch's own n
    assert batch.CHUNK in sizes and sizes <= {batch._bucket(k) for k in range(1, batch.CHUNK + 1)}
    assert not sizes & set(odd)
