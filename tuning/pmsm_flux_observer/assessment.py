"""The flux-observer tuners' figures: every candidate judged by the sampled observer's linearization on
the envelope x the estimate-error corners (holds, damping, bias, noise, the observer's decay, the PLL's
slow root), its low-speed limit, the damping-versus-bias front and the firmware defaults' hold speed;
criterion.py ranks and judges them."""

from __future__ import annotations

import math
import pickle
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.memo import BytesMemo
from sensorless.design.pmsm_flux_observer import corner_estimate
from sensorless.design.pmsm_flux_observer.gains import constant_law, pll_gains, runtime_params
from sensorless.design.pmsm_flux_observer.linearize import (
    current_noise,
    discrete_analysis,
    gain_voltage,
    motor_vector,
    rotor_frame_loop,
    sampled_loop,
    with_gain,
)
from sensorless.design.poles import worst_damping
from sensorless.design.rotor_frame import equilibrium_points
from sensorless.symbolic.pmsm_flux_observer.observer import PARAMS
from sensorless.tuning.pmsm_flux_observer.settings import CHUNK, NOISE_INDEX, FluxTuneSettings, corners

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


@dataclass
class Assessment:
    """Per candidate: per-point discrete damping and bias (nominal estimates), per-speed holds."""

    damping: np.ndarray  # (C, P) worst damping over the corners
    bias: np.ndarray  # (C, P) worst |bias| [rad] over the corners
    holds: np.ndarray  # (C, S) per envelope |speed|
    poles: np.ndarray  # (C, P, n) nominal discrete poles [1/s]
    noise: np.ndarray | None = None  # (C, P, 2) worst PLL angle [rad] and speed [rad/s] noise, RMS
    decay: np.ndarray | None = None  # (C, P) decay rate of the observer's own modes [1/s], nominal
    pll: np.ndarray | None = None  # (C,) the PLL's slower root [1/s] (its speed estimate's lag)


def assess(drive: FluxObserverDrive, cands: list[GainSet], settings: FluxTuneSettings) -> Assessment:
    """The sampled observer with each candidate's gains on the envelope x the error corners."""
    W, T = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    cs = corners(settings.errors)
    names = [f.name for f in PARAMS]
    rows, gains = [], []
    for g in cands:
        base = runtime_params(drive, g)
        k_0 = (
            4 * float(g.values["foc_observer_gain"]) * drive.estimate.psi_pm**2
            if g.law == "voltage-scaled"
            else float(g.values["observer_gain"])
        )
        for c in cs:
            p = dict(base)
            p.update(R_s=p["R_s"] * c["R_s"], psi_pm=p["psi_pm"] * c["psi_pm"])
            p.update(L_d=p["L_d"] * c["L"], L_q=p["L_q"] * c["L"])
            rows.append([p[n] for n in names])
            gains.append(k_0)
    nc, npt = len(cs), W.size
    s, zmax, err, noise, own = _points(drive, np.asarray(rows), np.asarray(gains), W, T, len(cands))
    ok = np.isfinite(zmax)
    zeta = worst_damping(s).reshape(len(cands), nc, npt)
    bias = np.abs(np.where(ok, err, np.nan)).reshape(len(cands), nc, npt)
    stable = (ok & (zmax < 1)).reshape(len(cands), nc, npt)
    noise = np.where(ok[:, None], noise, np.inf).reshape(len(cands), nc, npt, 2)
    good = stable & (bias <= math.radians(settings.bias_max_deg))
    for name, lim in noise_limits(settings):
        good &= noise[..., NOISE_INDEX[name]] <= lim
    good_pt = good.all(axis=1)  # (C, P)
    holds = np.stack([good_pt[:, np.abs(W) == sp].all(axis=1) for sp in speeds], axis=1)
    worst = np.where(stable.all(axis=1), np.nanmin(np.where(np.isnan(zeta), -1, zeta), axis=1), -1.0)
    return Assessment(
        worst,
        np.nanmax(np.where(np.isnan(bias), np.inf, bias), axis=1),
        holds,
        s.reshape(len(cands), nc, npt, -1)[:, 0],
        np.nanmax(noise, axis=1),
        np.where(ok, own, np.nan).reshape(len(cands), nc, npt)[:, 0],
        np.array([pll_slow_root(g) for g in cands]),
    )


# each candidate's figures at its points (the envelope x the error corners), kept in this process by the
# bytes of everything they are computed from: a tune judges the firmware defaults and the drive file's
# gains again beside its refinement, and a report in the same process the tuned gains and the defaults
# (each point's Newton iteration is its own: the same numbers in any batch). ~40 kB a candidate
_KEPT: BytesMemo[tuple[np.ndarray, ...]] = BytesMemo(256)


def _points(
    drive: FluxObserverDrive, rows: np.ndarray, gains: np.ndarray, W: np.ndarray, T: np.ndarray, n_cand: int
) -> tuple[np.ndarray, ...]:
    """(poles, largest |z|, angle error, (PLL angle, speed) noise, observer decay) at each point of
    :func:`assess`'s layout: candidate, corner, envelope point; ``rows`` (candidates x corners, PARAMS)
    and ``gains`` (the same) the runtime parameters and k_0 of each candidate's corners."""
    o = drive.observer
    law = constant_law()
    frame = rotor_frame_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    loop = sampled_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    m = motor_vector(drive)
    sigma = current_noise(drive)
    npt, nc = W.size, rows.shape[0] // n_cand
    per = nc * npt
    common = pickle.dumps(
        (W, T, m, drive.motor.vector(), o.T_obs, o.inductance_rule, o.lambda_adaptation, sigma, loop.n_y)
    )
    keys = [common + rows[c * nc : (c + 1) * nc].tobytes() + gains[c * nc : (c + 1) * nc].tobytes()
            for c in range(n_cand)]  # fmt: skip
    kept = {k: v for k in dict.fromkeys(keys) if (v := _KEPT.get(k)) is not None}
    new = list(dict.fromkeys(k for k in keys if k not in kept))  # each missing candidate once
    if new:
        first = [keys.index(k) for k in new]
        idx = np.concatenate([np.arange(c * per, (c + 1) * per) for c in first])
        P = np.repeat(rows.T, npt, axis=1)[:, idx]
        G = np.repeat(gains[None, :], npt, axis=1)[:, idx]
        Wn, Tn = np.tile(W, n_cand * nc)[idx], np.tile(T, n_cand * nc)[idx]
        # each distinct observer at each point once, in the layout's order; the others take its numbers:
        # the voltage-scaled grid's candidates that differ in the slow gain alone (62 % of its points on
        # the README skate), the corners that coincide where an estimate error is 0 (criterion.py
        # lost_cause, the report's findings: each error alone)
        key = _slow_gain_unread(drive, P, W, T, idx % npt) if len(new) > 1 else P
        u, back = _distinct_columns(np.vstack([key, G, Wn, Tn]))
        k = u.size
        out = (
            np.full((k, loop.n_y), np.nan + 0j),
            np.full(k, np.nan),
            np.full(k, np.nan),
            np.full((k, 2), np.nan),
            np.full(k, np.nan),
        )
        for j in range(0, k, CHUNK):
            sl = u[j : j + CHUNK]
            y0 = equilibrium_points(frame, Wn[sl], Tn[sl], m, with_gain(P[:, sl], G[:, sl])).x
            figs = discrete_analysis(
                drive, loop, y0, Wn[sl], Tn[sl], P[:, sl], G[:, sl], sigma, observer_decay=True
            )
            for a, f in zip(out, figs, strict=True):
                a[j : j + CHUNK] = f
        out = tuple(a[back] for a in out)
        for i, key in enumerate(new):
            kept[key] = _KEPT.put(key, tuple(a[i * per : (i + 1) * per].copy() for a in out))
    return tuple(np.concatenate([kept[key][j] for key in keys]) for j in range(5))


def _distinct_columns(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the first column of each distinct one of ``a``, in order; for each column the position of its
    distinct one in the first): equal bit for bit (0.0 and -0.0 apart)."""
    one = np.ascontiguousarray(a.T).view(np.dtype((np.void, a.itemsize * a.shape[0])))[:, 0]
    _, first, back = np.unique(one, return_index=True, return_inverse=True)
    order = np.argsort(first)
    return first[order], np.argsort(order)[back.ravel()]


def _slow_gain_unread(
    drive: FluxObserverDrive, P: np.ndarray, W: np.ndarray, T: np.ndarray, at: np.ndarray
) -> np.ndarray:
    """``P`` (PARAMS, points) with the slow gain k_slow set to -1 at the points where the observer does
    not read it: its gain unscheduled, or VESC's factor max(k_slow, |u|/u_ref) that of the voltage
    (design/pmsm_flux_observer/linearize.py ``gain_voltage``; k_slow below |u|/u_ref by more than
    rounding). There the candidates that differ in the slow gain alone are one observer: every
    figure the same number. ``at``: each column's envelope point (of W, T)."""
    ix = {f.name: k for k, f in enumerate(PARAMS)}
    f = gain_voltage(drive, W, T)[at] / P[ix["u_ref"]] * (1 - 1e-9)
    out = P.copy()
    out[ix["k_slow"], ~(P[ix["scheduled"]] > 0.5) | (P[ix["k_slow"]] < f)] = -1.0
    return out


def noise_limits(settings: FluxTuneSettings) -> tuple[tuple[str, float], ...]:
    """The noise limits a speed must meet to hold: the run's (``--max-noise``), and by default the
    angle's RMS within a third of the bias limit (three standard deviations within it)."""
    lims = dict(settings.max_noise)
    lims.setdefault("position", math.radians(settings.bias_max_deg) / 3)
    return tuple(lims.items())


def pll_slow_root(gains: GainSet) -> float:
    """-(the slower root) of the PLL's s^2 + k_p s + k_i [1/s] in closed form (its real part where
    the roots are complex; a double root k_p/2 exactly, no rounding of a polynomial solver)."""
    k_p, k_i = pll_gains(gains)
    disc = k_p**2 / 4 - k_i
    return float(k_p / 2 - math.sqrt(disc)) if disc > 0 else float(k_p / 2)


def low_limit(holds: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """(C,) the lowest speed from which every higher envelope speed holds (inf: none holds at the top)."""
    out = np.full(holds.shape[0], np.inf)
    for c in range(holds.shape[0]):
        for j in range(len(speeds) - 1, -1, -1):
            if not holds[c, j]:
                break
            out[c] = speeds[j]
    return out


def figures(drive: FluxObserverDrive, a: Assessment, c: int, w_from: float | None = None) -> dict[str, float]:
    """Worst damping and bias over the speeds from ``w_from`` (None: its own low-speed limit) up, and
    the low-speed limit."""
    W, _ = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    lim = low_limit(a.holds[c : c + 1], speeds)[0]
    sel = np.abs(W) >= (lim if w_from is None else w_from)
    if not sel.any():  # no speed holds: the figures over the whole envelope
        sel = np.ones(W.size, bool)
    return {
        "worst_damping": float(np.min(a.damping[c, sel])) if sel.any() else float("nan"),
        "worst_bias_deg": float(np.degrees(np.max(a.bias[c, sel]))) if sel.any() else float("nan"),
        "low_speed_limit_rad_s": float(lim),
        "low_speed_limit_pu": float(lim / drive.w_base),
        "worst_noise_deg": float(np.degrees(np.max(a.noise[c, sel, 0]))) if a.noise is not None else math.nan,
        "worst_speed_noise_rad_s": float(np.max(a.noise[c, sel, 1])) if a.noise is not None else math.nan,
    }


def front(
    drive: FluxObserverDrive, a: Assessment, cands: list[GainSet], w_hold: float, n: int, limit_deg: float
) -> dict[str, Any]:
    """The damping-versus-bias front of the candidates (``tune --pareto N``): of those that hold down
    to the hold speed, the ones no other beats in both worst damping and worst angle bias over the
    speeds from it up, at most ``n`` of them evenly over the front, by increasing bias."""
    W, _ = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    lim = low_limit(a.holds, speeds)
    sel = np.abs(W) >= w_hold
    pts = []
    for c in np.flatnonzero(lim <= w_hold * (1 + 1e-12)):
        fg = figures(drive, a, int(c), w_hold)
        decay = float(-np.nanmax(a.poles[c, sel].real))
        pts.append((fg["worst_bias_deg"], -fg["worst_damping"], decay, fg["worst_noise_deg"], int(c)))
    pts.sort()
    kept, best_z = [], -np.inf
    for b, mz, decay, nz, j in pts:  # by increasing bias: kept where better damped than all before
        if -mz > best_z:
            kept.append((b, -mz, decay, nz, j))
            best_z = -mz
    if len(kept) > n:
        kept = [kept[round(i)] for i in np.linspace(0, len(kept) - 1, n)]
    names = [k for k, v in cands[0].values.items() if not isinstance(v, list)]
    return {
        "metric": "bias",
        "description": "bias = worst steady angle bias [deg] under the estimate errors over the speeds "
        f"from the hold speed {w_hold / drive.w_base:.4g} p.u. up",
        "parameters": names,
        "points": [
            {
                "bias": b,
                "limit": limit_deg,
                "worst_damping": z,
                "min_decay_rate": decay,
                "noise": nz,
                "theta": [float(cands[c].values[k]) for k in names],
            }
            for b, z, decay, nz, c in kept
        ],
    }


def hold_speed(drive: FluxObserverDrive, settings: FluxTuneSettings, base: dict[str, Any]) -> float:
    """The hold speed of the criterion (package docstring) [rad/s]."""
    if settings.hold_speed is not None:
        return settings.hold_speed
    lims = [b["low_speed_limit_rad_s"] for k, b in base.items() if k != "drive file"]
    finite = [x for x in lims if math.isfinite(x)]
    return min(finite) if finite else float(drive.envelope.speed_max)


def assess_linearized(drive: FluxObserverDrive, gains: GainSet, settings: FluxTuneSettings) -> Assessment:
    """:func:`assess` of one gain set of any law through the family's linearization (a scheduled
    gain with its derivative in the PLL speed), one call per estimate corner."""
    from sensorless.design.pmsm_flux_observer import FAMILY as fam

    W, T = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    e = drive.estimate
    zs, bs, st, poles, decay = [], [], [], None, None
    for c in corners(settings.errors):
        est = corner_estimate(e, c)
        lin = fam.linearize(drive, gains, W, T, estimate=est)
        pd, err = lin.poles_discrete, lin.theta_err_discrete
        assert pd is not None and err is not None  # the family's linearization is of the sampled observer
        if poles is None:
            poles = pd
            # the scheduled gain couples the observer to the PLL's speed: the slowest of all modes
            decay = np.where(np.isfinite(lin.decay_rate_discrete), lin.decay_rate_discrete, np.nan)
        ok = np.isfinite(pd).all(axis=1)
        zs.append(np.where(ok, lin.worst_damping_discrete, -1.0))
        bs.append(np.where(ok, np.abs(err), np.inf))
        st.append(ok & (lin.decay_rate_discrete > 0))
    zeta, bias, stable = np.array(zs), np.array(bs), np.array(st)
    good = np.asarray((stable & (bias <= math.radians(settings.bias_max_deg))).all(axis=0))
    holds = np.array([[good[np.abs(W) == sp].all() for sp in speeds]])
    worst = np.where(stable.all(axis=0), zeta.min(axis=0), -1.0)
    assert poles is not None and decay is not None  # from the first corner (the nominal estimates)
    return Assessment(
        worst[None],
        bias.max(axis=0)[None],
        holds,
        poles[None],
        None,
        decay[None],
        np.array([pll_slow_root(gains)]),
    )


def assess_any(drive: FluxObserverDrive, cands: list[GainSet], settings: FluxTuneSettings) -> Assessment:
    """:func:`assess` of gain sets of any law: the scheduled ones (schedule) through
    :func:`assess_linearized` (no noise figure), the others in one batch; in the order given."""
    sched = [j for j, g in enumerate(cands) if g.law == "schedule"]
    if not sched:
        return assess(drive, cands, settings)
    rest = [j for j in range(len(cands)) if j not in sched]
    parts = {j: assess_linearized(drive, cands[j], settings) for j in sched}
    if rest:
        a = assess(drive, [cands[j] for j in rest], settings)
        for i, j in enumerate(rest):
            noise = None if a.noise is None else a.noise[i : i + 1]
            parts[j] = Assessment(
                a.damping[i : i + 1],
                a.bias[i : i + 1],
                a.holds[i : i + 1],
                a.poles[i : i + 1],
                noise,
                None if a.decay is None else a.decay[i : i + 1],
                None if a.pll is None else a.pll[i : i + 1],
            )
    rows = [parts[j] for j in range(len(cands))]
    nan = np.full((*rows[0].damping.shape, 2), np.nan)
    return Assessment(
        np.concatenate([r.damping for r in rows]),
        np.concatenate([r.bias for r in rows]),
        np.concatenate([r.holds for r in rows]),
        np.concatenate([r.poles for r in rows]),
        np.concatenate([r.noise if r.noise is not None else nan for r in rows]),
        np.concatenate([r.decay for r in rows]),
        np.concatenate([r.pll for r in rows]),
    )
