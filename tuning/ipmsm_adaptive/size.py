"""How large a gain law of the adaptive observer is over the speed range: the size the tuner's tie-break
minimizes among equally damped gains (tuning/tiebreak.py).

The gain lambda = lambda1 I + lambda2 J of a law (eq. (16) of Piippo, Hinkkanen, Luomi (2008), or a
schedule) is a function of the speed estimate. Its size is the RMS, over speed estimates spread evenly
on [-w_max, w_max] (w_max: the envelope's largest speed, so the low speeds a reversal crosses count,
below the envelope's smallest speed too), of

    sqrt(lambda1^2 + lambda2^2 + (w_base dlambda1/dw_hat)^2 + (w_base dlambda2/dw_hat)^2) / R̂s,

the gain and its slope per p.u. speed, both in units of R̂s. The slope is there because the damping
objective cannot see it: at every equilibrium of the linearized loop the slope multiplies the current
error, which is zero there, so nothing in the objective limits it, while in a transient the speed
estimate moves and the gain with it (a steep eq. (16) ramp, omega_lambda small, is what lost the
rotor position in the speed steps of a 5.5 kW industrial motor; docs/tuning.md "Tie-break").
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw

N_SPEEDS = 201  # speed estimates on [-w_max, w_max] (odd: zero is one of them)


@functools.cache
def _values_and_slopes(law: GainLaw) -> ca.Function:
    """(w_hat, params) -> [lambda1, lambda2, dlambda1/dw_hat, dlambda2/dw_hat] at one speed estimate
    (built once per law)."""
    w, p = ca.SX.sym("w_hat"), ca.SX.sym("params", law.width)
    l1, l2 = law.expr(w, p)
    lam = ca.vertcat(l1, l2)
    return ca.Function(f"size_{law.name}", [w, p], [ca.vertcat(lam, ca.jacobian(lam, w))])


def gain_size_function(
    law: GainLaw, R_s_hat: float, w_base: float, w_max: float
) -> Callable[[np.ndarray], np.ndarray]:
    """thetas (K, n_theta) -> (K,) the size above; entries of theta beyond the law's parameters (a
    tuned alpha_fo) do not count."""
    f = _values_and_slopes(law)
    w = np.linspace(-w_max, w_max, N_SPEEDS)
    weight = np.array([1.0, 1.0, w_base, w_base])[:, None] / R_s_hat

    def size(thetas: np.ndarray) -> np.ndarray:
        th = np.atleast_2d(np.asarray(thetas, float))
        K = th.shape[0]
        out = np.empty(K)
        params = np.zeros((law.width, K))
        params[: law.n_params] = th[:, : law.n_params].T
        # every theta's speeds in one batch, on CasADi's virtual machine (jit False: the bits of a call
        # of the Function, as the sizes were computed before; one call per theta through DM cost 0.4 ms,
        # 0.2 s CPU of a tie-break's pattern search): (K * N_SPEEDS, 4, 1)
        vals = evaluate_batch(
            f, K * N_SPEEDS, [np.tile(w, K), np.repeat(params, N_SPEEDS, axis=1)], jit=False
        )[0]
        vals = vals[:, :, 0].reshape(K, N_SPEEDS, 4)
        for k in range(K):
            v = np.ascontiguousarray(vals[k].T) * weight
            out[k] = float(np.sqrt(np.mean(np.sum(v**2, axis=0))))
        return out

    return size
