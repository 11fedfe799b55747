"""The max-min NLP's exact derivatives assembled from one slot's: the Jacobian of the constraints and
the Hessian of the Lagrangian for IPOPT, built once per slot kind and mapped over the slots.

The NLP of tuning/slots.py is a sum of slots that share only the law's parameters theta and the damping
variable t: each slot's constraints (its tie phi = local(theta, point), its factor equalities, its
sector inequalities) depend on the shared variables and on the slot's own unknowns. Left to CasADi,
the derivatives are generated from the whole expanded graph by graph colouring, at a cost that grows
faster than the number of slots (4.1 s for the 128 slots of a 50-gain schedule, 5.5 s of the README
servo's 19 s ``tune``). Here they are generated once per slot kind (free, fixed, noise) on the slot
alone, mapped over the layout's slots with ``Function.map``, and scattered into the NLP's sparse
matrices by a constant sparse matrix (the entries that several slots share, of theta and t, summed):
the same derivatives up to rounding, a layout's solver built in milliseconds. Small layouts keep the
whole-graph solver (tuning/slots.py ``WHOLE_GRAPH_SLOTS``), whose rounding the presets' tables carry.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from sensorless.tuning.model import TuningModel


@dataclass(frozen=True)
class SlotKind:
    """One slot kind's constraints and derivatives, as Functions of (shared, v, s[, lam])."""

    rows: ca.Function  # (shared, v, s) -> (g_phi, g_eq, g_ineq)
    jac: ca.Function  # (shared, v, s) -> nonzeros of d[g_phi; g_eq; g_ineq]/d[shared; v]
    hess: ca.Function  # (shared, v, s, lam) -> nonzeros of triu(d2 lam'[g_phi; g_eq; g_ineq]/d[shared; v]2)
    jac_sp: ca.Sparsity
    hess_sp: ca.Sparsity
    n_rows: tuple[int, int, int]  # rows of g_phi, g_eq, g_ineq

    @property
    def per(self) -> int:
        return int(self.rows.size1_in(1))

    @property
    def width(self) -> int:
        return int(self.rows.size1_in(2))


def _triplet(sp: ca.Sparsity) -> tuple[np.ndarray, np.ndarray]:
    r, c = sp.get_triplet()
    return np.asarray(r, int), np.asarray(c, int)


@functools.cache
def slot_kind(rows: ca.Function) -> SlotKind:
    """The derivatives of one slot whose constraints are ``rows`` (an SX Function, tuning/slots.py)."""
    sh, v, s = rows.sx_in()
    out = rows.call([sh, v, s])
    G = ca.vertcat(*out)
    w = ca.vertcat(sh, v)
    J = ca.jacobian(G, w)
    lam = ca.SX.sym("lam", G.numel())
    H = ca.triu(ca.hessian(ca.dot(lam, G), w)[0])
    names = ["shared", "v", "s"]
    jac = ca.Function(f"{rows.name()}_jac", [sh, v, s], [ca.vertcat(*J.nonzeros())], names, ["jac"])
    hess = ca.Function(
        f"{rows.name()}_hess", [sh, v, s, lam], [ca.vertcat(*H.nonzeros())], [*names, "lam"], ["hess"]
    )
    return SlotKind(rows, jac, hess, J.sparsity(), H.sparsity(), tuple(int(o.numel()) for o in out))


def _scatter(n_rows: int, n_cols: int, gr: np.ndarray, gc: np.ndarray) -> tuple[ca.Sparsity, ca.DM]:
    """(sparsity of the sum, the constant matrix that sums sources into its nonzeros): source k lands at
    (gr[k], gc[k]); sources at the same entry are summed."""
    key = gc.astype(np.int64) * n_rows + gr  # column-major order, CasADi's
    uniq, where = np.unique(key, return_inverse=True)
    sp = ca.Sparsity.triplet(n_rows, n_cols, (uniq % n_rows).tolist(), (uniq // n_rows).tolist())
    S = ca.DM(ca.Sparsity.triplet(uniq.size, key.size, where.tolist(), list(range(key.size))), 1.0)
    return sp, S


def assemble(
    kinds: list[tuple[SlotKind, int, int, int]],
    n_shared: int,
    nz: int,
    npar: int,
    objective: Callable[[ca.MX, ca.MX], ca.MX],
    reg: tuple[ca.Function, ca.Sparsity] | None,
    proximal: int | None = None,
) -> tuple[dict[str, ca.MX], ca.Function, ca.Function]:
    """(the NLP {x, p, f, g}, jac_g, hess_lag) of the slots ``kinds`` [(kind, M slots, offset of their
    variables in x, offset of their parameters in p)]: g = [g_phi of every kind, g_eq of every kind,
    g_ineq of every kind], each slot's rows together, slots in order. ``objective(x, p)`` is f (of the
    shared variables only); ``reg``: (shared, p[:2]) -> the nonzeros of the upper triangle of its
    Hessian, and their sparsity (None: f is linear); ``proximal``: where f has the proximal term
    |L (theta/typical - c)|^2 (tuning/slots.py ``proximal``) with L = p[k : k + n_theta^2] (column-major),
    k (None: it has none)."""
    x = ca.MX.sym("x", nz)
    p = ca.MX.sym("p", npar)
    lam_f = ca.MX.sym("lam_f")
    sh = x[:n_shared]
    blocks = [[], [], []]
    offs = [0, 0, 0]
    for kind, M, _, _ in kinds:
        for b in range(3):
            offs[b] += kind.n_rows[b] * M
    ng = sum(offs)
    lam_g = ca.MX.sym("lam_g", ng)
    start = [0, offs[0], offs[0] + offs[1]]
    J_src, H_src = [], []
    J_r, J_c, H_r, H_c = [], [], [], []
    for kind, M, zo, po in kinds:
        V = ca.reshape(x[zo : zo + kind.per * M], kind.per, M)
        S = ca.reshape(p[po : po + kind.width * M], kind.width, M)
        outs = kind.rows.map(M)(sh, V, S)
        lam = []
        for b in range(3):
            blocks[b].append(ca.vec(outs[b]))
            n_b = kind.n_rows[b]
            lam.append(ca.reshape(lam_g[start[b] : start[b] + n_b * M], n_b, M))
        J_src.append(ca.vec(kind.jac.map(M)(sh, V, S)))
        H_src.append(ca.vec(kind.hess.map(M)(sh, V, S, ca.vertcat(*lam))))
        # where each slot's local entries land: rows by block, own variables after the shared ones
        slot = np.arange(M)
        lr, lc = _triplet(kind.jac_sp)
        bounds = np.cumsum(kind.n_rows)
        blk = np.searchsorted(bounds, lr, side="right")
        first = np.concatenate([[0], bounds[:-1]])[blk]
        rows_ = (
            np.asarray(start)[blk][None, :]
            + slot[:, None] * np.asarray(kind.n_rows)[blk][None, :]
            + (lr - first)
        )
        J_r.append(rows_.ravel())
        J_c.append(_own(lc, slot, n_shared, zo, kind.per).ravel())
        hr, hc = _triplet(kind.hess_sp)
        H_r.append(_own(hr, slot, n_shared, zo, kind.per).ravel())
        H_c.append(_own(hc, slot, n_shared, zo, kind.per).ravel())
        for b in range(3):
            start[b] += kind.n_rows[b] * M
    f = objective(x, p)
    if reg is not None:
        rr, rc = _triplet(reg[1])
        H_src.append(lam_f * reg[0](sh, p[:2]))
        H_r.append(rr)
        H_c.append(rc)
    if proximal is not None:  # its Hessian 2 L^T L in theta, upper triangle (the entries are summed)
        nth = n_shared - 1
        Lm = ca.reshape(p[proximal : proximal + nth * nth], nth, nth)
        Hq = 2 * lam_f * ca.mtimes(Lm.T, Lm)
        r, c = np.triu_indices(nth)
        H_src.append(ca.vertcat(*[Hq[int(i), int(j)] for i, j in zip(r, c, strict=True)]))
        H_r.append(r)
        H_c.append(c)
    g = ca.vertcat(*blocks[0], *blocks[1], *blocks[2])
    jsp, JS = _scatter(ng, nz, np.concatenate(J_r), np.concatenate(J_c))
    hsp, HS = _scatter(nz, nz, np.concatenate(H_r), np.concatenate(H_c))
    J = ca.sparsity_cast(ca.mtimes(JS, ca.vertcat(*J_src)), jsp)
    H = ca.sparsity_cast(ca.mtimes(HS, ca.vertcat(*H_src)), hsp)
    jac_g = ca.Function("nlp_jac_g", [x, p], [g, J], ["x", "p"], ["g", "jac_g_x"])
    hess_lag = ca.Function(
        "nlp_hess_l", [x, p, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]
    )
    return {"x": x, "p": p, "f": f, "g": g}, jac_g, hess_lag


def _own(local: np.ndarray, slot: np.ndarray, n_shared: int, zo: int, per: int) -> np.ndarray:
    """(M, k) global indices of a slot's local variable indices: shared ones stay, own ones are offset."""
    own = local >= n_shared
    return np.where(own[None, :], zo + slot[:, None] * per + (local - n_shared)[None, :], local[None, :])


@functools.cache
def regularizer_hessian(model: TuningModel) -> tuple[ca.Function, ca.Sparsity] | None:
    """((shared, w) -> nonzeros of the upper triangle of the Hessian of f = -w[0] t + w[1] reg(theta) in
    the shared variables [theta/typical, t], their sparsity); None: the law has no regularizer (f is
    linear)."""
    if model.regularizer is None:
        return None
    sh = ca.SX.sym("shared", model.n_theta + 1)
    w = ca.SX.sym("w", 2)
    r = w[1] * model.regularizer(sh[: model.n_theta] * ca.DM(model.typical))
    H = ca.triu(ca.hessian(r, sh)[0])
    return ca.Function(
        "reg_hess", [sh, w], [ca.vertcat(*H.nonzeros())], ["shared", "w"], ["hess"]
    ), H.sparsity()
