"""The top-down search for the minimum sensorless speed on a speed x torque grid (design/low_speed.py).

Per point, :func:`failing` judges the figures of an analysis (the family's observer-only linearization,
or the whole sampled drive's: ``low_speed.WholeDrive``) against the criteria the caller states
(:data:`CRITERIA`: damping, decay, angle bias, angle noise, the angle error under acceleration), each
only where the analysis gives it. Per torque, :func:`search` finds w_min = the lowest speed from which
every speed up to the highest passing one meets them all: the grid (logarithmic in speed) is walked
from the top speed down in SPEED_BLOCKS batched calls of the analysis, a torque left at the first
failure below its first pass (the speeds below it, where the drive's fixed points are the slowest to
find, cannot change its w_min), then the highest failing grid interval is bisected in log speed (one
batched call per step over the torques). tests/common/test_low_speed_search.py checks the shortcuts
against the full grid.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

import numpy as np

CRITERIA = ("damping", "decay", "bias", "noise", "acceleration")
SPEED_BLOCKS = 8  # the grid in this many batched analyses (see search)


class Figures(Protocol):
    """What the criteria judge at N points (design/linearization.py ``Linearization``, or the whole drive's
    ``low_speed.WholeDrive``, which adds ``floors()`` and ``angle_lag()``: read where present)."""

    @property
    def worst_damping(self) -> np.ndarray: ...

    def low_speed_decay(self) -> np.ndarray: ...

    def angle_bias(self) -> np.ndarray | None: ...

    def angle_noise(self) -> np.ndarray | None: ...


def failing(lin: Figures, crit: Mapping[str, float]) -> tuple[np.ndarray, list[str]]:
    """(N,) index of the first failed criterion per point (-1: all met) and the criteria applied."""
    zeta = np.where(np.isnan(lin.worst_damping), -np.inf, lin.worst_damping)
    decay = lin.low_speed_decay()
    decay = np.where(np.isnan(decay), -np.inf, decay)
    # the whole drive: no less than required, or than the controllers give with a sensor where they
    # give less (a loop the observer does not make worse is no low-speed limit of the observer)
    floor = getattr(lin, "floors", lambda: None)()
    need_z, need_d = (
        (crit["damping"], crit["decay"])
        if floor is None
        else (
            np.minimum(crit["damping"], floor[0]),
            np.minimum(crit["decay"], floor[1]),
        )
    )
    tests = [zeta < need_z, decay < need_d]
    applied = ["damping", "decay"]
    bias, noise = lin.angle_bias(), lin.angle_noise()
    lag = getattr(lin, "angle_lag", lambda: None)() if "acceleration" in crit else None
    for name, val in (("bias", bias), ("noise", noise)):
        if val is None or np.isnan(np.asarray(val, float)).all():  # not given here
            tests.append(np.zeros(zeta.shape, bool))
        else:
            applied.append(name)
            v = np.abs(np.asarray(val, float))
            tests.append(np.where(np.isnan(v), False, v > crit[name]))
    if lag is None:
        tests.append(np.zeros(zeta.shape, bool))
    else:  # the bias and the lag under the full acceleration (or braking) together within the limit
        applied.append("acceleration")
        v = np.abs(np.asarray(bias, float)) + np.abs(np.asarray(lag, float))
        tests.append(np.where(np.isnan(v), True, v > crit["bias"]))
    bad = np.stack(tests)  # (5, N)
    first = np.where(bad.any(axis=0), np.argmax(bad, axis=0), -1)
    return first, applied


def search(
    analyse: Callable[[np.ndarray, np.ndarray], Figures],
    w: np.ndarray,
    T: np.ndarray,
    crit: Mapping[str, float],
    bisections: int,
    bound: np.ndarray | None = None,
    known: frozenset[str] = frozenset(),
) -> tuple[np.ndarray, np.ndarray, set[str]]:
    """(w_min, index of the limiting criterion (-1: none), criteria applied) per torque on the grid
    ``w`` x ``T`` (module docstring: the highest passing grid speed, the highest failing one below it,
    bisection between them).

    The grid is walked from the top speed down, one batched call per block of speeds over the torques
    still searched: a torque is done at the first failure below its first pass, so the speeds below it,
    where the drive's fixed points are the slowest to find, are not analysed for it (they cannot change
    its w_min). ``bound`` (per torque): a w_min at or below it is not needed (the caller keeps a higher
    or equal one: design/low_speed.py ``minimum_speed_under``), so a torque whose w_min is shown to be
    at or below it is left (its w_min then is some value at or below ``bound``). The criteria applied
    are those some analysed grid point gives; where one of them, not in ``known`` (applied already by
    the caller's other cases), is missing, the grid is completed, so that the set is the full grid's.
    """
    n_speeds, n_torques = w.size, T.size
    need = {c for c in CRITERIA if c in crit or c in ("damping", "decay")} - set(known)
    bound = np.full(n_torques, -np.inf) if bound is None else bound
    top = np.full(n_torques, -1)  # the grid's top speed's first failing criterion
    k_pass = np.full(n_torques, -1)  # the highest passing grid speed
    k = np.full(n_torques, -1)  # the highest failing grid speed below it
    cause = np.full(n_torques, -1)
    left = np.zeros(n_torques, bool)  # w_min shown to be at or below bound
    seen = np.zeros((n_speeds, n_torques), bool)
    given: set[str] = set()
    # blocks of speeds: a family that simulates its discrete observer over a window growing as 1/w (the
    # reduced-order family's steady errors) runs every point of a call as long as its slowest one
    # (no empty block where the grid has fewer speeds than SPEED_BLOCKS: CasADi refuses a map of none)
    blocks = [b for b in np.array_split(np.arange(n_speeds), SPEED_BLOCKS)[::-1] if b.size]

    def run(blk: np.ndarray, cols: np.ndarray) -> np.ndarray:
        first, applied = failing(analyse(w[blk, None], T[None, cols]), crit)
        given.update(applied)
        seen[np.ix_(blk, cols)] = True
        return first.reshape(blk.size, cols.size)

    for blk in blocks:
        cols = np.flatnonzero((k < 0) & ~left)
        if cols.size == 0:
            break
        first = run(blk, cols)
        for jj, j in enumerate(cols):
            for ii in range(blk.size - 1, -1, -1):
                i, f = blk[ii], first[ii, jj]
                if i == n_speeds - 1:
                    top[j] = f
                if k_pass[j] < 0:
                    if f < 0:
                        k_pass[j] = i
                elif f >= 0:
                    k[j], cause[j] = i, f
                    break
            # passing down to this block's lowest speed: w_min <= w[blk[0]] (bisection's exp(log(.)),
            # within a rounding: the margin)
            if k[j] < 0 <= k_pass[j] and w[blk[0]] * (1 + 1e-12) <= bound[j]:
                left[j] = True
    if not need <= given:  # criteria the analysed points do not give: the rest of the grid
        for blk in blocks:
            cols = np.flatnonzero(~seen[blk].all(axis=0))
            if cols.size and not need <= given:
                run(blk, cols)
    none = k_pass < 0  # no speed meets the criteria at this torque
    k = np.where(none, n_speeds - 1, k)
    cause = np.where(none, top, cause)
    w_min = np.zeros(n_torques)
    w_min[none] = w[-1]
    ref = (k >= 0) & ~none & ~left
    if ref.any():
        idx = np.flatnonzero(ref)
        lo, hi = np.log(w[k[ref]]), np.log(w[k[ref] + 1])
        c = cause[ref]
        act = np.ones(idx.size, bool)  # still bisected (not shown at or below bound)
        for _ in range(bisections):
            act &= ~(np.exp(hi) <= bound[idx])
            if not act.any():
                break
            mid = 0.5 * (lo + hi)
            f_mid, _ = failing(analyse(np.exp(mid[act]), T[idx[act]]), crit)
            fails = np.zeros(idx.size, bool)
            fails[act] = f_mid >= 0
            f_all = np.full(idx.size, -1)
            f_all[act] = f_mid
            c = np.where(fails, f_all, c)
            lo = np.where(act & fails, mid, lo)
            hi = np.where(act & ~fails, mid, hi)
        w_min[ref] = np.exp(hi)
        cause[ref] = c
    w_min[left] = np.minimum(w_min[left], bound[left])
    return w_min, cause, given
