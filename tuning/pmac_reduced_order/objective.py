"""Objective of the constant-gain tuner: discrete poles and noise of one gain pair on a grid, their rank,
the whole sampled drive's stability constraint, and the compass search that maximizes it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.pmac_reduced_order.linearize import analyze

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

# The drive runs with the load-torque feedforward off (De Angelo et al. 2006, Fig. 5(a)) or on (Fig. 5(b)).
# With it on, T_L_hat = tau + (Gamma L / J) phi_hat . i, eq. (17), feeds the measured current back into
# the torque reference within a sample or two: a loop of gain ~ Gamma L / J (its pole near z = -Gamma L
# k / J on the negative real axis) that the observer-only poles, under ideal current control, cannot
# see. The gains that maximize the observer's decay (Gamma ~ 7e5 on the paper's motor) make it
# unstable at the sampling rate (the rotor lost within 1 ms of fig5b), so the tuner holds the whole
# sampled drive (design/drive_analysis.py) stable with the feedforward off and on, and with a margin.
FEEDFORWARD = (False, True)
GAIN_MARGIN = 2.0  # the whole drive stays stable with both gains times this (a 6 dB gain margin)


@dataclass(frozen=True)
class Figures:
    """Discrete-time (and continuous) poles of one gain pair on a grid."""

    n_rpm: np.ndarray
    w: np.ndarray  # electrical [rad/s]
    T_L: np.ndarray  # [N m]
    poles: np.ndarray  # discrete poles ln(z)/T_s [1/s] (N, n)
    poles_c: np.ndarray  # continuous poles (Floquet exponents) [1/s]
    damping: np.ndarray  # worst per point (discrete), -inf where not finite
    decay: np.ndarray  # -max Re per point (discrete) [1/s], -inf where not finite
    noise: np.ndarray  # (N, 2) RMS of the position [rad] and speed [rad/s] estimates; inf: unstable

    def worst(self) -> tuple[float, float]:
        """(worst damping, slowest decay rate)."""
        return float(np.min(self.damping)), float(np.min(self.decay))

    def worst_noise(self) -> np.ndarray:
        """[position rad, speed rad/s]: the worst RMS over the grid."""
        return np.where(np.isnan(self.noise), np.inf, self.noise).max(axis=0)


def figures(drive: PmacDrive, g: float, Gamma: float, n_rpm: np.ndarray, T_L: np.ndarray) -> Figures:
    """Poles of the observer with gains (g, Gamma) at the points, by linearize.analyze."""
    w = drive.rpm_to_w(n_rpm)
    r = analyze(drive, w, T_L, g=float(g), Gamma=float(Gamma), noise=True, errors=False)
    assert r.noise is not None  # noise=True
    ok = np.isfinite(r.poles_discrete).all(axis=1)
    with np.errstate(invalid="ignore"):
        zeta = np.where(ok, np.nanmin(np.where(ok[:, None], r.damping_discrete, 0.0), axis=1), -np.inf)
        decay = np.where(ok, -np.max(np.where(ok[:, None], r.poles_discrete.real, 0.0), axis=1), -np.inf)
    return Figures(
        np.asarray(n_rpm, float), w, np.asarray(T_L, float), r.poles_discrete, r.poles, zeta, decay, r.noise
    )


DRIVE_SPEEDS = 10  # per direction, 0.05 .. 1 p.u. (the range ``sensorless tune`` proves the table on)


@dataclass(frozen=True)
class DriveCheck:
    """The whole-drive constraint: its set-ups (feedforward off, on), its points (speeds +-[0.05, 1] p.u.
    x torques {-T_N, 0, T_N}: the drive's range, motoring and regenerating, not only the [envelope] the
    observer's poles are tuned on; at +-T_max the speed loop saturates and has no fixed point, as in
    reports/tune_proof.py) and, per gain scale (1, GAIN_MARGIN) and set-up,
    where the drive file's gains are stable: a candidate must be stable there too (no worse than the
    drive file's gains, also with the margin)."""

    scenarios: tuple[Any, ...]
    w: np.ndarray  # [rad/s electrical]
    torque: np.ndarray  # [N m]
    where: np.ndarray  # (2 scales, len(scenarios), N) bool


def drive_check(drive: PmacDrive, g0: float, Gamma0: float) -> DriveCheck:
    """The constraint of a drive, from its drive file's gains (g0, Gamma0)."""
    from sensorless.design.capabilities import Scaled, require
    from sensorless.design.drive_analysis import analysis_scenario
    from sensorless.design.registry import family_of

    scs = tuple(
        analysis_scenario(drive, f"[control]\nfeedforward = {str(ff).lower()}\n") for ff in FEEDFORWARD
    )
    sc = require(family_of(drive), Scaled).scales(drive)
    mag = np.linspace(0.05, 1.0, DRIVE_SPEEDS) * sc.w_base
    W, T = np.meshgrid(np.concatenate([-mag[::-1], mag]), np.array([-sc.T_N, 0.0, sc.T_N]))
    w, t = W.ravel(), T.ravel()
    with np.errstate(invalid="ignore"):
        where = np.array(
            [drive_max_real(drive, k * g0, k * Gamma0, w, t, scs) < 0 for k in (1.0, GAIN_MARGIN)]
        )
    return DriveCheck(scs, w, t, where)


def drive_max_real(
    drive: PmacDrive, g: float, Gamma: float, w: np.ndarray, torque: np.ndarray, scenarios: tuple[Any, ...]
) -> np.ndarray:
    """(len(scenarios), N) max Re [1/s] of the whole sampled drive's poles at the points (``w`` [rad/s
    electrical], ``torque`` [N m]; NaN: no fixed point), design/drive_analysis.py; its loop compiled
    (the tuner linearizes it at every candidate it would take: 20 % less CPU, the same bits)."""
    from sensorless.design.drive_analysis import drive_loop, linearize_drive

    gains = GainSet("constant", {"g": float(g), "Gamma": float(Gamma)}, "tuning candidate")
    return np.array(
        [
            linearize_drive(drive, gains, w, torque, loop=drive_loop(drive, gains, sc), jit=True).max_real
            for sc in scenarios
        ]
    )


def drive_shortfall(drive: PmacDrive, g: float, Gamma: float, check: DriveCheck) -> str:
    """'' where the whole drive is stable wherever the drive file's gains keep it stable (``check``), with
    the gains and with both times GAIN_MARGIN; else the first point and set-up where it is not, in words."""
    for j, scale in enumerate((1.0, GAIN_MARGIN)):
        mr = drive_max_real(drive, scale * g, scale * Gamma, check.w, check.torque, check.scenarios)
        with np.errstate(invalid="ignore"):
            bad = check.where[j] & ~(mr < 0)
        if bad.any():
            i, k = (int(a[0]) for a in np.nonzero(bad))
            how = "on" if FEEDFORWARD[i] else "off"
            at = "" if scale == 1 else f" with the gains x {GAIN_MARGIN:g}"
            n = drive.w_to_rpm(check.w[k])
            return (
                f"the whole drive (feedforward {how}){at} is unstable at {n:+.5g} r/min, "
                f"{check.torque[k]:+.4g} N m "
                + (f"(max Re {mr[i, k]:+.4g} 1/s)" if np.isfinite(mr[i, k]) else "(no fixed point found)")
                + ", where the drive file's gains keep it stable"
            )
    return ""


def rank(f: Figures, min_damping: float, limits: np.ndarray | None = None) -> tuple[bool, float, float]:
    """Lexicographic: feasible (stable, damping >= min, noise within the limits) first, then the
    slowest decay, then damping."""
    zeta, decay = f.worst()
    ok = zeta >= min_damping - 1e-9 and decay > 0
    if limits is not None:
        ok = ok and bool(np.all(f.worst_noise() <= limits * (1 + 1e-9)))
    return (bool(ok), decay, zeta)


def compass_search(
    evaluate: Callable[[np.ndarray], tuple],
    x0: list[np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    refine: Callable[[np.ndarray, tuple], tuple] | None = None,
) -> tuple[np.ndarray, tuple, dict[tuple[float, float], tuple]]:
    """Maximize ``evaluate`` (a comparable rank) over the box from the best of the starts x0:
    poll +-h along ln g, ln Gamma and the critical curve (1, 2), take the first improvement, halve h
    when none improves, stop below h = 0.01. Deterministic. ``refine(x, rank)``: a costlier constraint
    that can only lower a rank (e.g. to infeasible), applied only where the rank would improve on the
    best (no other x can be taken). Returns (best x, its rank, every evaluated x -> rank; refined
    where it was applied)."""
    cache: dict[tuple[float, float], tuple] = {}
    refined: set[tuple[float, float]] = set()

    def key_of(x: np.ndarray) -> tuple[float, float]:
        return (round(float(x[0]), 12), round(float(x[1]), 12))

    def f(x: np.ndarray) -> tuple:
        key = key_of(x)
        if key not in cache:
            cache[key] = evaluate(x)
        return cache[key]

    def full(x: np.ndarray) -> tuple:
        r, key = f(x), key_of(x)
        if refine is not None and key not in refined:
            refined.add(key)
            cache[key] = r = refine(x, r)
        return r

    starts = [np.clip(x, lower, upper) for x in x0]
    best = max(starts, key=full)
    dirs = [np.array(d, float) for d in ((1, 2), (-1, -2), (1, 0), (-1, 0), (0, 1), (0, -1))]
    h = 0.25
    while h >= 0.01:
        for d in dirs:
            cand = np.clip(best + h * d / np.linalg.norm(d), lower, upper)
            if f(cand) > full(best) and full(cand) > full(best):
                best = cand
                break
        else:
            h /= 2
    return best, full(best), cache
