"""Tuning of the flux observer + PLL in each firmware's terms: the laws odrive, vesc and flux_schedule.

Each law is tuned by a search of its own (tuning/family.py ``tuner``): its gains have one or two free
numbers, so every candidate of a grid is judged on the whole envelope at once (one batched evaluation
of the sampled observer's linearization, design/pmsm_flux_observer/linearize.py) under the estimate
errors a user states (default R_s +-30 %, psi_pm +-10 %, L +-20 %: every corner and the nominal).

Criterion (docs/families/pmsm_flux_observer.md "Tuning"), per candidate:
1. a speed *holds* when at every torque, both directions and every error corner the sampled observer
   has an equilibrium, its discrete poles lie inside the unit circle, and its angle bias is at most
   ``bias_max``; the candidate's *low-speed limit* is the lowest envelope speed from which every
   higher one holds (the speed below which it loses the motor);
2. the hold speed: the lowest low-speed limit of the firmwares' defaults on this motor (ODrive's,
   VESC Tool's detection; the envelope's top speed where neither holds anywhere), or ``hold_speed``;
3. of the candidates that hold down to the hold speed, the best has the best worst damping over the
   speeds from it up; where none does, the lowest limit, then the best damping.
So the tuned gains lose the motor at no higher speed than the better firmware default and are the
best damped of those. (Damping grows with the gain, k/(2|w|), and the resistance bias with it too,
k dR i_q/(lambda w^2): the hold speed is where the trade between them is set.)
Limits: T gamma lambda^2 < 2 is in the poles (the Euler bound), T k_p <= KP_T (ODrive refuses T k_p >=
1). The PLL: k_p = 2 bw, k_i = bw^2 with bw = min(max(k, PLL_SPEED_LOOP alpha_s), KP_T / (2 T)) (the
drive's speed loop closes on the PLL's speed: its root at least that multiple of the loop's bandwidth,
the drive file's rule for alpha_s): a double pole at -bw, twice the
observer's decay rate k/2, within the limit (the PLL does not feed back into the observer).
``flux_schedule`` picks the gain per speed by the same criterion at that speed alone.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.design.pmsm_flux_observer.gains import TABLE_LAWS, VESC_U_REF, constant_law, runtime_params
from sensorless.design.pmsm_flux_observer.linearize import (
    current_noise,
    discrete_analysis,
    equilibrium_function,
    motor_vector,
    sampled_loop,
)
from sensorless.design.pmsm_flux_observer.schema import PLL_SPEED_LOOP
from sensorless.design.poles import MIN_DAMPING, worst_damping
from sensorless.symbolic.pmsm_flux_observer.observer import PARAMS
from sensorless.tuning.family import Tunable, TuningHooks

KP_T = 0.5  # T k_p at most (ODrive flags T k_p >= 1 as unstable; half of it leaves a margin)
K_GRID = 24  # candidate observer gains (log grid: 1.33 apart on the outrunner)
# points per batched evaluation: below design/batch.py's JIT threshold, so a tune never waits for the
# compiler on a cold cache (~17 s for an unrolled Newton Function)
CHUNK = 4000
REFINE = 9  # candidates between the best grid point's neighbours
K_MIN = 20.0  # [1/s] smallest candidate
K_T_MAX = 1.9  # T k at most (the Euler bound is 2)
SLOW_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)  # foc_observer_gain_slow candidates
ERRORS = {"R_s": 0.3, "psi_pm": 0.1, "L": 0.2}  # default estimate errors (+-)
BIAS_MAX_DEG = 15.0
NOISE_INDEX = {"position": 0, "speed": 1}  # --max-noise outputs: the PLL's angle and speed
VESC_DEFAULT = {"foc_observer_gain_slow": 0.05, "foc_pll_kp": 2000.0, "foc_pll_ki": 30000.0}
ODRIVE_DEFAULT = {"observer_gain": 1000.0, "pll_bandwidth": 1000.0}


@dataclass(frozen=True)
class FluxTuneSettings:
    """Envelope (the drive's), estimate errors and the bias limit."""

    errors: dict[str, float] = field(default_factory=lambda: dict(ERRORS))
    bias_max_deg: float = BIAS_MAX_DEG
    hold_speed: float | None = None  # [rad/s]; None: the firmware defaults' best limit
    bound: bool = False
    pareto: int = 0  # points of the damping-versus-bias front (``pareto_<law>.csv``); 0: none
    # RMS noise of the PLL's estimates at most, ((output, limit), ...): position [rad], speed [rad/s]
    max_noise: tuple[tuple[str, float], ...] = ()


def default_settings(drive: Any) -> FluxTuneSettings:
    return FluxTuneSettings()


def corners(errors: dict[str, float]) -> list[dict[str, float]]:
    """Nominal and every corner of the error box: factors on R_s, psi_pm, L_d = L_q."""
    out = [{"R_s": 1.0, "psi_pm": 1.0, "L": 1.0}]
    for r, f, L in itertools.product((-1, 1), repeat=3):
        out.append(
            {"R_s": 1 + r * errors["R_s"], "psi_pm": 1 + f * errors["psi_pm"], "L": 1 + L * errors["L"]}
        )
    return out


def vesc_gains(drive: Any) -> GainSet:
    """VESC Tool's detection on this motor: gain 1e-3/lambda^2 stored x1e6, its PLL and slow gain."""
    raw = 1e3 / drive.estimate.psi_pm**2
    return GainSet("vesc", {"foc_observer_gain": raw, **VESC_DEFAULT}, "VESC Tool detection defaults")


def odrive_gains() -> GainSet:
    return GainSet("odrive", dict(ODRIVE_DEFAULT), "ODrive defaults")


@dataclass
class Assessment:
    """Per candidate: per-point discrete damping and bias (nominal estimates), per-speed holds."""

    damping: np.ndarray  # (C, P) worst damping over the corners
    bias: np.ndarray  # (C, P) worst |bias| [rad] over the corners
    holds: np.ndarray  # (C, S) per envelope |speed|
    poles: np.ndarray  # (C, P, n) nominal discrete poles [1/s]
    noise: np.ndarray | None = None  # (C, P, 2) worst PLL angle [rad] and speed [rad/s] noise, RMS


def assess(drive: Any, cands: list[GainSet], settings: FluxTuneSettings) -> Assessment:
    """The sampled observer with each candidate's gains on the envelope x the error corners."""
    W, T = drive.grid()
    speeds = np.unique(np.abs(W))
    cs = corners(settings.errors)
    names = [f.name for f in PARAMS]
    rows, gains = [], []
    for g in cands:
        base = runtime_params(drive, g)
        k_0 = (
            4 * float(g.values["foc_observer_gain"]) * drive.estimate.psi_pm**2
            if g.law == "vesc"
            else float(g.values["observer_gain"])
        )
        for c in cs:
            p = dict(base)
            p.update(R_s=p["R_s"] * c["R_s"], psi_pm=p["psi_pm"] * c["psi_pm"])
            p.update(L_d=p["L_d"] * c["L"], L_q=p["L_q"] * c["L"])
            rows.append([p[n] for n in names])
            gains.append(k_0)
    nc, npt = len(cs), W.size
    n = len(cands) * nc * npt
    P = np.repeat(np.asarray(rows).T, npt, axis=1)
    G = np.repeat(np.asarray(gains)[None, :], npt, axis=1)
    Wn, Tn = np.tile(W, len(cands) * nc), np.tile(T, len(cands) * nc)
    o = drive.observer
    law = constant_law()
    fn = equilibrium_function("gradient", o.inductance_rule, o.lambda_adaptation, law)
    loop = sampled_loop("gradient", o.inductance_rule, o.lambda_adaptation, law)
    m = motor_vector(drive)
    s = np.full((n, loop.n_y), np.nan + 0j)
    zmax, err, noise = np.full(n, np.nan), np.full(n, np.nan), np.full((n, 2), np.nan)
    sigma = current_noise(drive)
    for j in range(0, n, CHUNK):
        sl = slice(j, min(j + CHUNK, n))
        k = sl.stop - sl.start
        x, A, res, _ = evaluate_batch(fn, k, [Wn[sl], Tn[sl], m, P[:, sl], G[:, sl]])
        scale = np.maximum(np.abs(x[:, :, 0]).max(axis=1), 1.0)
        ok = np.isfinite(A).all(axis=(1, 2)) & (res[:, 0, 0] <= 1e-9 * scale)
        y0 = np.where(ok[:, None], x[:, :, 0], np.nan)
        s[sl], zmax[sl], err[sl], nz = discrete_analysis(
            drive, loop, y0, Wn[sl], Tn[sl], P[:, sl], G[:, sl], sigma
        )
        noise[sl] = nz
    ok = np.isfinite(zmax)
    zeta = worst_damping(s).reshape(len(cands), nc, npt)
    bias = np.abs(np.where(ok, err, np.nan)).reshape(len(cands), nc, npt)
    stable = (ok & (zmax < 1)).reshape(len(cands), nc, npt)
    noise = np.where(ok[:, None], noise, np.inf).reshape(len(cands), nc, npt, 2)
    good = stable & (bias <= math.radians(settings.bias_max_deg))
    for name, lim in settings.max_noise:
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
    )


def low_limit(holds: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """(C,) the lowest speed from which every higher envelope speed holds (inf: none holds at the top)."""
    out = np.full(holds.shape[0], np.inf)
    for c in range(holds.shape[0]):
        for j in range(len(speeds) - 1, -1, -1):
            if not holds[c, j]:
                break
            out[c] = speeds[j]
    return out


def figures(drive: Any, a: Assessment, c: int, w_from: float | None = None) -> dict[str, float]:
    """Worst damping and bias over the speeds from ``w_from`` (None: its own low-speed limit) up, and
    the low-speed limit."""
    W, _ = drive.grid()
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


def best(drive: Any, a: Assessment, w_hold: float) -> int:
    """The criterion of the module docstring: the index of the best candidate."""
    W, _ = drive.grid()
    speeds = np.unique(np.abs(W))
    lim = low_limit(a.holds, speeds)
    keys = []
    for c in range(len(lim)):
        if lim[c] <= w_hold * (1 + 1e-12):
            keys.append((0, -figures(drive, a, c, w_hold)["worst_damping"], c))
        else:
            z = figures(drive, a, c)["worst_damping"]
            keys.append((1, lim[c], -(z if math.isfinite(z) else -9.0), c))
    return min(keys)[-1]


def front(
    drive: Any, a: Assessment, cands: list[GainSet], w_hold: float, n: int, limit_deg: float
) -> dict[str, Any]:
    """The damping-versus-bias front of the candidates (``tune --pareto N``): of those that hold down
    to the hold speed, the ones no other beats in both worst damping and worst angle bias over the
    speeds from it up, at most ``n`` of them evenly over the front, by increasing bias."""
    W, _ = drive.grid()
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
    for b, mz, decay, nz, c in pts:  # by increasing bias: kept where better damped than all before
        if -mz > best_z:
            kept.append((b, -mz, decay, nz, c))
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


def hold_speed(drive: Any, settings: FluxTuneSettings, base: dict[str, Any]) -> float:
    """The hold speed of the criterion (module docstring) [rad/s]."""
    if settings.hold_speed is not None:
        return settings.hold_speed
    lims = [b["low_speed_limit_rad_s"] for k, b in base.items() if k != "drive file"]
    finite = [x for x in lims if math.isfinite(x)]
    return min(finite) if finite else float(drive.envelope.speed_max)


def odrive_candidate(drive: Any, k: float) -> GainSet:
    T = drive.observer.T_obs
    bw = min(max(k, pll_floor(drive)), KP_T / (2 * T))
    return GainSet("odrive", {"observer_gain": k, "pll_bandwidth": bw}, "candidate")


def pll_floor(drive: Any) -> float:
    """The slowest PLL root [1/s] the drive's speed loop allows: PLL_SPEED_LOOP x its bandwidth."""
    return PLL_SPEED_LOOP * float(drive.control.alpha_s)


def k_grid(drive: Any) -> np.ndarray:
    return np.geomspace(K_MIN, K_T_MAX / drive.observer.T_obs, K_GRID)


@dataclass
class FluxOutcome:
    law: str
    table: GainTable
    lines: list[str]

    def summary_lines(self, drive: Any) -> list[str]:
        return self.lines


def _baselines(drive: Any, settings: FluxTuneSettings) -> tuple[list[str], dict[str, Any]]:
    cands = [odrive_gains(), vesc_gains(drive), drive_gains_or_none(drive)]
    cands = [c for c in cands if c is not None]
    a = assess(drive, cands, settings)
    lines, out = [], {}
    for j, (label, g) in enumerate(
        zip(("ODrive defaults", "VESC detection", "drive file"), cands, strict=False)
    ):
        f = figures(drive, a, j)
        out[label] = {**f, "gains": dict(g.values)}
        lines.append(_line(label, f))
    return lines, out


def _same_law(drive: Any, law: str) -> list[GainSet]:
    """The drive file's gains where they are of ``law``."""
    g = drive_gains_or_none(drive)
    return [g] if g is not None and g.law == law else []


def drive_gains_or_none(drive: Any) -> GainSet | None:
    from sensorless.design.pmsm_flux_observer.gains import drive_gains

    return drive_gains(drive)


def _line(label: str, f: dict[str, float]) -> str:
    lim = f["low_speed_limit_pu"]
    if not math.isfinite(lim):
        return f"  {label:<16} loses the motor at every envelope speed (unstable or biased beyond the limit)"
    held = f"holds down to {lim:.3g} p.u."
    return (
        f"  {label:<16} worst damping {f['worst_damping']:.3f}, worst angle bias "
        f"{f['worst_bias_deg']:.2f} deg{_noise(f)}; {held}"
    )


def _noise(f: dict[str, float]) -> str:
    n = f.get("worst_noise_deg", float("nan"))
    return f", angle noise {n:.3g} deg rms" if math.isfinite(n) else ""


def _table(
    drive: Any, law: str, gains: dict[str, Any], a: Assessment, c: int, summary: dict[str, Any]
) -> GainTable:
    W, T = drive.grid()
    base = assess(drive, [drive_gains_or_none(drive)], FluxTuneSettings())
    points = []
    for j in range(W.size):
        points.append(
            {
                "w_m_pu": float(W[j] / drive.w_base),
                "T_e_Nm": float(T[j]),
                "damping": float(worst_damping(a.poles[c, j : j + 1])[0]),
                "decay_rate": float(-np.max(a.poles[c, j].real)),
                "poles": [[float(p.real), float(p.imag)] for p in a.poles[c, j]],
                "baseline": {
                    "damping": float(worst_damping(base.poles[0, j : j + 1])[0]),
                    "decay_rate": float(-np.max(base.poles[0, j].real)),
                },
            }
        )
    env = {"speed_base_rad_s": drive.w_base, "T_s_s": drive.observer.T_obs}
    head = {"name": drive.name, "kind": drive.kind, "sha256": drive.digest}
    return GainTable(law, head, gains, env, points, summary)


def _limits(settings: FluxTuneSettings, pf: dict[str, Any] | None) -> dict[str, Any]:
    """The summary's noise limit and front, where the run has them (preset tables stay as they were)."""
    out: dict[str, Any] = {}
    if settings.max_noise:
        out["max_noise"] = dict(settings.max_noise)
    if pf is not None:
        out["pareto"] = pf
    return out


def tune_odrive(drive: Any, settings: FluxTuneSettings, progress: Any = None) -> FluxOutcome:
    """The ``odrive`` law: one observer_gain and pll_bandwidth over the envelope (module docstring)."""
    ks = k_grid(drive)
    cands = [odrive_candidate(drive, float(k)) for k in ks]
    if progress:
        progress(
            f"{len(cands)} observer gains x the envelope x {len(corners(settings.errors))} estimate cases"
        )
    a = assess(drive, cands, settings)
    base_lines, base = _baselines(drive, settings)
    w_hold = hold_speed(drive, settings, base)
    c = best(drive, a, w_hold)
    pf = front(drive, a, cands, w_hold, settings.pareto, settings.bias_max_deg) if settings.pareto else None
    # refined between the grid's neighbours of the best, with the firmware's default and the drive
    # file's gains of this law as candidates too (the tuned gains are never worse than either)
    lo, hi = ks[max(c - 1, 0)], ks[min(c + 1, len(ks) - 1)]
    cands = [cands[c], *(odrive_candidate(drive, float(k)) for k in np.geomspace(lo, hi, REFINE))]
    cands += [odrive_gains(), *_same_law(drive, "odrive")]
    a = assess(drive, cands, settings)
    return _outcome(
        drive,
        "odrive",
        lambda g: (
            f"tuned odrive: observer_gain = {g['observer_gain']:.6g} 1/s, "
            f"pll_bandwidth = {g['pll_bandwidth']:.6g} rad/s"
        ),
        cands,
        a,
        w_hold,
        (base, base_lines),
        settings,
        pf,
    )


def _outcome(
    drive: Any,
    law: str,
    header: Any,
    cands: list[Any],
    a: Any,
    w_hold: float,
    baselines: tuple[Any, list[str]],
    settings: FluxTuneSettings,
    pf: Any,
) -> FluxOutcome:
    """The best candidate held down to ``w_hold``, its table and summary: ``header`` (gains) -> the
    summary's first line, in the law's own terms; ``baselines`` the firmware defaults and their lines."""
    base, base_lines = baselines
    c = best(drive, a, w_hold)
    g = dict(cands[c].values)
    f = figures(drive, a, c)
    lines = [
        header(g),
        _line("tuned", f),
        f"  (hold speed {w_hold / drive.w_base:.3g} p.u.: the better firmware default's low-speed limit)",
        "baselines (the firmwares' defaults on this motor, same criterion):",
        *base_lines,
    ]
    summary = {
        **f,
        "hold_speed_rad_s": w_hold,
        "baselines": base,
        "errors": settings.errors,
        "bias_max_deg": settings.bias_max_deg,
        **_limits(settings, pf),
    }
    return FluxOutcome(law, _table(drive, law, g, a, c, summary), lines)


def tune_vesc(drive: Any, settings: FluxTuneSettings, progress: Any = None) -> FluxOutcome:
    """The ``vesc`` law: foc_observer_gain and foc_observer_gain_slow under VESC's run-time schedule."""
    psi = drive.estimate.psi_pm
    T = drive.observer.T_obs
    # the schedule's factor at the top of the envelope: k there = 4 raw psi^2 max(slow, |u|/u_ref)
    u_top = drive.envelope.speed_max * drive.motor.psi_pm
    top = max(u_top / VESC_U_REF, 1e-3)
    cands = []
    for slow in SLOW_GRID:
        for k in np.geomspace(K_MIN, K_T_MAX / T, 16):
            raw = k / (4 * psi**2 * max(slow, top))  # k at the top speed
            kp = min(max(k, 2 * pll_floor(drive)), KP_T / T)  # a double root at -k_p/2
            cands.append(
                GainSet(
                    "vesc",
                    {
                        "foc_observer_gain": raw,
                        "foc_observer_gain_slow": slow,
                        "foc_pll_kp": kp,
                        "foc_pll_ki": kp**2 / 4,
                    },
                    "candidate",
                )
            )
    if progress:
        progress(f"{len(cands)} (gain, slow gain) pairs x the envelope")
    a = assess(drive, cands, settings)
    base_lines, base = _baselines(drive, settings)
    w_hold = hold_speed(drive, settings, base)
    c = best(drive, a, w_hold)
    pf = front(drive, a, cands, w_hold, settings.pareto, settings.bias_max_deg) if settings.pareto else None
    # refined in the gain at the best slow gain, with VESC Tool's detection and the drive file's gains
    # of this law as candidates too (the tuned gains are never worse than either)
    raw0, slow0 = cands[c].values["foc_observer_gain"], cands[c].values["foc_observer_gain_slow"]
    step = (K_T_MAX / T / K_MIN) ** (1 / 15)
    fine = []
    for raw in np.geomspace(raw0 / step, raw0 * step, REFINE):
        g0 = dict(cands[c].values)
        g0["foc_observer_gain"] = float(raw)
        fine.append(GainSet("vesc", g0, "candidate"))
    cands = [cands[c], *fine, vesc_gains(drive), *_same_law(drive, "vesc")]
    del slow0
    a = assess(drive, cands, settings)
    return _outcome(
        drive,
        "vesc",
        lambda g: (
            f"tuned vesc: foc_observer_gain = {g['foc_observer_gain']:.6g} "
            f"({g['foc_observer_gain'] / 1e6:.4g} x1M), "
            f"foc_observer_gain_slow = {g['foc_observer_gain_slow']:.3g}, "
            f"foc_pll_kp = {g['foc_pll_kp']:.6g}, foc_pll_ki = {g['foc_pll_ki']:.6g}"
        ),
        cands,
        a,
        w_hold,
        (base, base_lines),
        settings,
        pf,
    )


def tune_schedule(drive: Any, settings: FluxTuneSettings, progress: Any = None) -> FluxOutcome:
    """The ``flux_schedule`` law: gamma lambda^2 per envelope speed, by the criterion at that speed."""
    ks = k_grid(drive)
    cands = [odrive_candidate(drive, float(k)) for k in ks]
    a = assess(drive, cands, settings)
    W, _ = drive.grid()
    speeds = np.unique(np.abs(W))
    chosen = []
    for j, sp in enumerate(speeds):
        sel = np.abs(W) == sp
        hold = a.holds[:, j]
        zeta = [float(np.min(a.damping[c, sel])) for c in range(len(ks))]
        bias = [float(np.max(a.bias[c, sel])) for c in range(len(ks))]
        # holding and damped enough: the least bias; else holding: the best damped; else the best damped
        score = [
            (0, bias[c], c) if hold[c] and zeta[c] >= MIN_DAMPING else (1 if hold[c] else 2, -zeta[c], c)
            for c in range(len(ks))
        ]
        chosen.append(float(ks[min(score)[2]]))
    T = drive.observer.T_obs
    # one PLL at every speed: its double pole at the geometric mean of the scheduled gains
    bw = min(max(float(np.exp(np.mean(np.log(chosen)))), pll_floor(drive)), KP_T / (2 * T))
    g = {"speeds": [float(s) for s in speeds], "observer_gain": chosen, "pll_bandwidth": bw}
    gs = GainSet("flux_schedule", g, "tuned")
    a_s = assess_linearized(drive, gs, settings)  # the schedule itself, its law's derivative included
    f = figures(drive, a_s, 0)
    base_lines, base = _baselines(drive, settings)
    lines = [
        "tuned flux_schedule: observer_gain over |speed| "
        + ", ".join(f"{s / drive.w_base:.3g} pu: {k:.4g}" for s, k in zip(speeds, chosen, strict=True))
        + f"; pll_bandwidth = {bw:.6g} rad/s",
        _line("tuned", f),
        "baselines (the firmwares' defaults on this motor, same criterion):",
        *base_lines,
    ]
    summary = {**f, "baselines": base, "errors": settings.errors, "bias_max_deg": settings.bias_max_deg}
    return FluxOutcome("flux_schedule", _table(drive, "flux_schedule", g, a_s, 0, summary), lines)


def assess_linearized(drive: Any, gains: GainSet, settings: FluxTuneSettings) -> Assessment:
    """:func:`assess` of one gain set of any law through the family's linearization (a scheduled
    gain with its derivative in the PLL speed), one call per estimate corner."""
    from sensorless.design.registry import family_of

    fam = family_of(drive)
    W, T = drive.grid()
    speeds = np.unique(np.abs(W))
    e = drive.estimate
    zs, bs, st, poles = [], [], [], None
    for c in corners(settings.errors):
        est = {
            "R_s": e.R_s * c["R_s"],
            "psi_pm": e.psi_pm * c["psi_pm"],
            "L_d": e.L_d * c["L"],
            "L_q": e.L_q * c["L"],
        }
        lin = fam.linearize(drive, gains, W, T, estimate=est)
        if poles is None:
            poles = lin.poles_discrete
        ok = np.isfinite(lin.poles_discrete).all(axis=1)
        zs.append(np.where(ok, lin.worst_damping_discrete, -1.0))
        bs.append(np.where(ok, np.abs(lin.theta_err_discrete), np.inf))
        st.append(ok & (lin.decay_rate_discrete > 0))
    zeta, bias, stable = np.array(zs), np.array(bs), np.array(st)
    good = (stable & (bias <= math.radians(settings.bias_max_deg))).all(axis=0)
    holds = np.array([[good[np.abs(W) == sp].all() for sp in speeds]])
    worst = np.where(stable.all(axis=0), zeta.min(axis=0), -1.0)
    return Assessment(worst[None], bias.max(axis=0)[None], holds, poles[None])


def assess_any(drive: Any, cands: list[GainSet], settings: FluxTuneSettings) -> Assessment:
    """:func:`assess` of gain sets of any law: the scheduled ones (flux_schedule) through
    :func:`assess_linearized` (no noise figure), the others in one batch; in the order given."""
    sched = [j for j, g in enumerate(cands) if g.law == "flux_schedule"]
    if not sched:
        return assess(drive, cands, settings)
    rest = [j for j in range(len(cands)) if j not in sched]
    parts = {j: assess_linearized(drive, cands[j], settings) for j in sched}
    if rest:
        a = assess(drive, [cands[j] for j in rest], settings)
        for i, j in enumerate(rest):
            noise = None if a.noise is None else a.noise[i : i + 1]
            parts[j] = Assessment(
                a.damping[i : i + 1], a.bias[i : i + 1], a.holds[i : i + 1], a.poles[i : i + 1], noise
            )
    rows = [parts[j] for j in range(len(cands))]
    nan = np.full((*rows[0].damping.shape, 2), np.nan)
    return Assessment(
        np.concatenate([r.damping for r in rows]),
        np.concatenate([r.bias for r in rows]),
        np.concatenate([r.holds for r in rows]),
        np.concatenate([r.poles for r in rows]),
        np.concatenate([r.noise if r.noise is not None else nan for r in rows]),
    )


def own_law(drive: Any) -> str | None:
    """The default law on a drive of the user's own: the law of its file's [gains] (a VESC user's drive
    tunes the vesc law), where it is a tunable one."""
    law = drive.gains_table.get("law")
    return law if law in TABLE_LAWS else None


_LEAD = (("w_m_pu", "w_m_pu"), ("T_e_Nm", "T_e_Nm"))
HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "odrive",
            "flux observer: ODrive's observer_gain (gamma lambda^2) and pll_bandwidth, constant over speed",
            default_settings,
            tuner=tune_odrive,
            columns=(_LEAD, ()),
        ),
        Tunable(
            "vesc",
            "flux observer: VESC's foc_observer_gain, foc_observer_gain_slow (its run-time schedule), PLL",
            default_settings,
            tuner=tune_vesc,
            columns=(_LEAD, ()),
        ),
        Tunable(
            "flux_schedule",
            "flux observer: gamma lambda^2 free over speed, with the PLL",
            default_settings,
            tuner=tune_schedule,
            columns=(_LEAD, ()),
        ),
    ),
    own_default=own_law,
)
