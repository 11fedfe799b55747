"""The flux family's noise figure takes the one-step Jacobian's spectral radius from the eigenvalues its
linearization already has (design/noise.py ``noise_rms_periodic(..., rho=)``): the same figures, bit for
bit, as computing the monodromy's eigenvalues again, on stable, unstable and non-finite matrices."""

from __future__ import annotations

import numpy as np
from sensorless.design.discrete import eigenvalues_by_size
from sensorless.design.noise import noise_rms_periodic


def test_the_given_radius_gives_the_bits_of_the_recomputed_one():
    rng = np.random.default_rng(7)
    n, N = 6, 400
    J = rng.normal(scale=0.45, size=(N, n, n))  # spectral radii on both sides of 1
    J[:5, 0, 0] = np.nan  # a linearization that failed
    G = rng.normal(size=(N, n, 2))
    G[5] = np.inf  # a sensitivity that overflowed
    C = np.zeros((2, n))
    C[0, n - 2] = C[1, n - 1] = 1.0
    rho = np.abs(eigenvalues_by_size(J)[:, 0])
    given = noise_rms_periodic(J[:, None], G[:, None], C, 0.01, rho=rho)
    again = noise_rms_periodic(J[:, None], G[:, None], C, 0.01)
    assert np.array_equal(given, again, equal_nan=True)
    # the sample holds each kind of point: unstable (inf), stable (finite) and not computed (NaN)
    assert np.isinf(given).any() and np.isfinite(given).any() and np.isnan(given[:6]).all()
