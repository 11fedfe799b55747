"""Monte-Carlo draws of the adaptive-observer drive: the linearized closed loop of many perturbed motors
and estimates at once, and a perturbed drive for the time domain (design/montecarlo.py uses both).

The parameters that can be spread are the true motor's R_s, L_d, L_q, psi_pm and J (the plant) and the
observer's estimates of the first four. The linearization of Piippo, Hinkkanen, Luomi (2008), eqs.
(11)-(15), is the same Jacobian Function as design/ipmsm_adaptive/linearize.py, evaluated over draws x
operating points in one mapped call per Newton step; J does not enter it (the loop is driven by the
true speed) and is spread for the time domain only.

Equilibria: with estimation errors the observer's equilibrium is found by Newton's method continued
along the estimates from the exact-estimate closed form, as operating_point.solve_equilibrium does,
but with every point's Newton iteration done together in numpy on the compiled Jacobian (batched
4x4 solves) instead of a rootfinder per point: at 10^6 points that is the difference between minutes
and seconds. The continuation's
steps, acceptance rules (residual, a position jump under 0.3 rad) and step control (start 0.25,
doubled to at most 0.5 after a success, halved after a failure, lost below 1e-3) are those of
solve_equilibrium, so both follow the same equilibrium branch: a whole step at once can land on
another equilibrium within the position rule (an unstable one, where the branch is stable).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.compiled import compiled
from sensorless.design.ipmsm_adaptive.linearize import PoleSweep, drive_arguments, linearization_function
from sensorless.design.ipmsm_adaptive.operating_point import (
    PARAM_NAMES,
    nominal_equilibrium_function,
    residual_function,
)
from sensorless.design.montecarlo import Uncertain
from sensorless.design.poles import eigvals_batched, sort_poles

ELECTRICAL = ("R_s", "L_d", "L_q", "psi_pm")  # the motor and estimate vectors' order
NEWTON_ITERATIONS = 10  # per continuation step; a converging step takes 3-6
MAX_ROUNDS = 40
# a report's default spread of the true motor (1 sigma): winding resistance with its temperature rise,
# inductance tolerance and saturation, magnet flux, the load's inertia (``report --montecarlo``)
TYPICAL = {"R_s": 0.10, "L_d": 0.10, "L_q": 0.10, "psi_pm": 0.05, "J": 0.30}
BLOCK = 2048  # points per compiled call: below batch.JIT_MIN_POINTS, where evaluate_batch takes fn as given


def parameters(drive: Any) -> tuple[Uncertain, ...]:
    """The spreadable parameters of ``drive``: the four electrical ones (plant and estimate) and J."""
    m, e = drive.motor, drive.estimate
    units = {"R_s": "ohm", "L_d": "H", "L_q": "H", "psi_pm": "V s"}
    out = [Uncertain(k, getattr(m, k), getattr(e, k), units[k], True, TYPICAL[k]) for k in ELECTRICAL]
    out.append(Uncertain("J", m.J, None, "kg m^2", False, TYPICAL["J"]))
    return tuple(out)


def perturbed(drive: Any, plant: Mapping[str, float], estimate: Mapping[str, float]) -> Any:
    """``drive`` with its true motor's and its estimates' parameters replaced by the given values."""
    motor = dataclasses.replace(drive.motor, **{k: float(v) for k, v in plant.items()})
    est = dataclasses.replace(drive.estimate, **{k: float(v) for k, v in estimate.items()})
    return dataclasses.replace(drive, motor=motor, estimate=est)


@functools.cache
def _newton_function(law: Any, injection: bool) -> ca.Function:
    """(x, w_m, T_e, motor, p, estimate, gain, alpha_fo, inj) -> (d x_dot/dx, x_dot)."""
    f = residual_function(law, injection)
    ins = f.sx_in()
    (x_dot,) = f.call(ins)
    outs = ca.cse([ca.densify(ca.jacobian(x_dot, ins[0])), ca.densify(x_dot)])  # dense: evaluate_batch
    return ca.Function("newton_step", ins, outs, f.name_in(), ["jac_x_dot_x", "x_dot"])


def _evaluate(fn: ca.Function, n: int, args: list[np.ndarray]) -> list[np.ndarray]:
    """evaluate_batch of ``fn`` compiled, in blocks of :data:`BLOCK` points, the last one (or a small
    batch) padded to a power of two: each new batch size builds a map, which costs more than
    evaluating a small batch, and a map of 10^6 points costs more than the blocks' calls. Parallelism
    comes from the workers that run the chunks of draws, not from threads here."""
    f = compiled(_flat(fn))
    outs: list[list[np.ndarray]] = []
    for lo in range(0, n, BLOCK):
        m = min(BLOCK, n - lo)
        size = 1 << max(0, (m - 1).bit_length())
        part = []
        for a in args:
            if a.ndim == 2 and a.shape[1] == n:
                a = a[:, lo : lo + m]
                if size > m:
                    a = np.pad(a, ((0, 0), (0, size - m)), mode="edge")
            part.append(a)
        outs.append([o[:m] for o in evaluate_batch(f, size, part)])
    return [np.concatenate(col) for col in zip(*outs, strict=True)]


@functools.cache
def _flat(fn: ca.Function) -> ca.Function:
    ins = fn.sx_in()
    return ca.Function(f"{fn.name()}_mc", ins, ca.cse(fn.call(ins)), fn.name_in(), fn.name_out())


def _equilibria(
    law: Any, injection: bool, cols: dict[str, np.ndarray], n: int, group: np.ndarray | None = None
) -> np.ndarray:
    """(n, n_x) equilibria at the points of ``cols`` (each input (rows, n)); NaN rows where the branch
    that starts at the exact-estimate equilibrium ends (module docstring). ``group``: the draw of each
    point; once a point of a draw has no equilibrium, the draw's other points are not solved further
    (NaN too: the draw has failed, and the lost points are the costly ones)."""
    nominal = nominal_equilibrium_function(injection)
    x = _evaluate(nominal, n, [cols[k] for k in ("w_m", "T_e", "motor", "p")])[0][:, :, 0]
    step = _newton_function(law, injection)
    true, est = cols["motor"], cols["estimate"]
    scale = 1.0 + np.abs(cols["w_m"][0]) + np.abs(x).max(axis=1)
    tau, h = np.zeros(n), np.full(n, 0.25)
    lost = np.zeros(n, bool)
    for _ in range(MAX_ROUNDS):
        act = np.flatnonzero((tau < 1) & ~lost)
        if act.size == 0:
            break
        t_try = np.minimum(1.0, tau[act] + h[act])
        a = {k: v[:, act] if v.shape[1] == n else v for k, v in cols.items()}  # (rows, 1): the same
        a["estimate"] = true[:, act] + t_try * (est[:, act] - true[:, act])
        ins = [a[k] for k in PARAM_NAMES]
        xa = x[act].copy()
        ok = np.zeros(act.size, bool)
        live = np.arange(act.size)
        for _ in range(NEWTON_ITERATIONS):
            sub = ins if live.size == act.size else [v[:, live] if v.shape[1] > 1 else v for v in ins]
            J, r = _evaluate(step, live.size, [np.ascontiguousarray(xa[live].T), *sub])
            r = r[:, :, 0]
            # at rest: x_dot in V (flux rates) and rad/s^2 within 1e-6 of the point's size, as
            # solve_equilibrium accepts; the Newton step that follows takes it to rounding level
            ok[live] = np.isfinite(r).all(axis=1) & (np.abs(r).max(axis=1) <= 1e-6 * scale[act[live]])
            go = np.isfinite(J).all(axis=(1, 2)) & np.isfinite(r).all(axis=1)
            try:
                dx = np.linalg.solve(J[go], r[go][:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:  # a singular Jacobian somewhere: those points stop here
                go[go] = np.abs(np.linalg.det(J[go])) > 0
                dx = np.linalg.solve(J[go], r[go][:, :, None])[:, :, 0]
            ok[live[~go]] = False
            idx = live[go]
            xa[idx] -= dx
            # done: at rest before this step, and the step small enough (1e-8 relative) that, Newton
            # converging quadratically, it leaves the error at rounding level; no evaluation is spent
            # only to see the next step vanish
            small = np.abs(dx).max(axis=1) <= 1e-8 * (1 + np.abs(xa[idx]).max(axis=1))
            small &= ok[idx]
            # a point whose position left the step's reach is rejected below whatever Newton does next
            far = np.abs(xa[idx, 2] - x[act[idx], 2]) >= 0.3
            ok[idx[far]] = False
            live = idx[~small & ~far]
            if live.size == 0:
                break
        # a solve that jumps far in position is another branch, not a continuation step
        ok &= np.abs(xa[:, 2] - x[act, 2]) < 0.3
        x[act[ok]] = xa[ok]
        tau[act[ok]] = t_try[ok]
        h[act] = np.where(ok, np.minimum(2 * h[act], 0.5), h[act] / 2)
        lost[act] |= ~ok & (h[act] < 1e-3)
        if group is not None and lost.any():
            failed = np.zeros(int(group.max()) + 1, bool)
            failed[group[lost]] = True
            lost |= failed[group]
    x[lost | (tau < 1)] = np.nan
    return x


def linearize_draws(
    drive: Any,
    gain: Any,
    plant: np.ndarray,
    estimate: np.ndarray,
    w: np.ndarray,
    torque: np.ndarray,
    complete: bool = True,
) -> PoleSweep:
    """The closed loop of each draw (rows of ``plant``/``estimate``, columns in :func:`parameters`'
    order; J ignored) at each operating point, draw-major: N = draws x points (family.linearize_draws).
    ``gain``: (law, parameters) as linearize.linearize takes it; ``drive`` carries the gains' alpha_fo.
    ``complete`` False: a draw with a point without equilibrium is NaN at all its points."""
    law, args = drive_arguments(drive, gain)
    n_d, n_p = plant.shape[0], w.size
    n = n_d * n_p
    k = len(ELECTRICAL)
    # inputs the same at every point stay one column (evaluate_batch broadcasts them)
    cols = {name: np.asarray(args.get(name, 0.0), float).reshape(-1, 1) for name in PARAM_NAMES}
    cols["w_m"], cols["T_e"] = np.tile(w, n_d)[None, :], np.tile(torque, n_d)[None, :]
    cols["motor"] = np.ascontiguousarray(np.repeat(plant[:, :k], n_p, axis=0).T)
    cols["estimate"] = np.ascontiguousarray(np.repeat(estimate[:, :k], n_p, axis=0).T)
    x0 = _equilibria(law, False, cols, n, None if complete else np.repeat(np.arange(n_d), n_p))
    good = np.isfinite(x0).all(axis=1)
    fn = linearization_function(law, False)
    out = _evaluate(fn, n, [np.where(good[:, None], x0, 0.0).T, *[cols[k] for k in PARAM_NAMES]])
    A, charpoly = out[0], out[7][:, :, 0]
    A[~good] = np.nan
    poles = np.full((n, A.shape[1]), np.nan + 0j)
    ok = np.isfinite(A).all(axis=(1, 2))
    if ok.any():
        poles[ok] = sort_poles(eigvals_batched(A[ok], charpoly[ok]))
    return PoleSweep(
        law=law,
        injection=False,
        w=cols["w_m"][0].copy(),
        torque=cols["T_e"][0].copy(),
        x0=x0,
        i_s0=out[6][:, :, 0],
        A=A,
        B=out[1],
        C=out[2],
        D=out[3],
        poles=poles,
    )
