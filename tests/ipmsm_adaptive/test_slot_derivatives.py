"""The tuning NLP's derivatives assembled from one slot's (tuning/slot_derivatives.py) against CasADi's own
differentiation of the whole NLP graph, at random points, for every slot kind (free, fixed, noise)."""

import casadi as ca
import numpy as np
from helpers.tuning import small
from sensorless.tuning.ipmsm_adaptive.laws import build_schedule
from sensorless.tuning.slot_derivatives import assemble, regularizer_hessian, slot_kind
from sensorless.tuning.slots import proximal, slot_rows


def test_assembled_jacobian_and_hessian_match_the_whole_graph(drive):
    model = build_schedule(drive, small(drive))  # 2 x 10 gains, a smoothing regularizer
    nth = model.n_theta
    zi, pi, kinds = nth + 1, 2, []
    for kind, M in (("free", 1), ("fixed", 2), ("noise", 1)):
        sk = slot_kind(slot_rows(model, kind))
        kinds.append((sk, M, zi, pi))
        zi, pi = zi + sk.per * M, pi + sk.width * M
    reg = ca.Function("reg", [th := ca.SX.sym("th", nth)], [model.regularizer(th)])
    k = pi  # the proximal term's matrix and centre (tuning/slots.py)

    def objective(z, p):
        prox = proximal(z[:nth], p[k : k + nth * nth + nth], nth)
        return -p[0] * z[nth] + p[1] * reg(z[:nth] * ca.DM(model.typical)) + prox

    pi += nth * nth + nth
    nlp, jac_g, hess_lag = assemble(kinds, nth + 1, zi, pi, objective, regularizer_hessian(model), k)
    x, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
    # the reference: CasADi differentiates the whole graph, expanded, as the solver did before
    J_ref = ca.Function("J", [x, p], [ca.jacobian(g, x)]).expand()
    H_ref = ca.Function(
        "H", [x, p, lam_f, lam_g], [ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])]
    ).expand()
    rng = np.random.default_rng(5)
    for _ in range(2):
        xv, pv, lv = rng.normal(size=zi), rng.normal(size=pi), rng.normal(size=g.numel())
        pv[:2] = [1.0, 0.7]
        g_a, J_a = jac_g(xv, pv)
        J_b = J_ref(xv, pv)
        H_a, H_b = hess_lag(xv, pv, 0.3, lv), H_ref(xv, pv, 0.3, lv)
        np.testing.assert_array_equal(np.asarray(g_a), np.asarray(ca.Function("g", [x, p], [g])(xv, pv)))
        for a, b in ((J_a, J_b), (H_a, H_b)):
            a, b = np.asarray(ca.densify(a)), np.asarray(ca.densify(b))
            assert np.abs(b).max() > 0
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
        assert hess_lag.sparsity_out(0).is_triu()
        # the objective's own Hessian (regularizer and proximal term), which the constraints' dwarf above
        a = np.asarray(ca.densify(hess_lag(xv, pv, 0.3, 0 * lv)))
        b = np.asarray(ca.densify(H_ref(xv, pv, 0.3, 0 * lv)))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
