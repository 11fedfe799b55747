"""Objective of the constant-gain tuner: discrete poles and noise of one gain pair on a grid, their rank,
and the compass search that maximizes it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.pmac_reduced_order.linearize import analyze

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive


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
    ok = np.isfinite(r.poles_discrete).all(axis=1)
    with np.errstate(invalid="ignore"):
        zeta = np.where(ok, np.nanmin(np.where(ok[:, None], r.damping_discrete, 0.0), axis=1), -np.inf)
        decay = np.where(ok, -np.max(np.where(ok[:, None], r.poles_discrete.real, 0.0), axis=1), -np.inf)
    return Figures(
        np.asarray(n_rpm, float), w, np.asarray(T_L, float), r.poles_discrete, r.poles, zeta, decay, r.noise
    )


def rank(f: Figures, min_damping: float, limits: np.ndarray | None = None) -> tuple[bool, float, float]:
    """Lexicographic: feasible (stable, damping >= min, noise within the limits) first, then the
    slowest decay, then damping."""
    zeta, decay = f.worst()
    ok = zeta >= min_damping - 1e-9 and decay > 0
    if limits is not None:
        ok = ok and bool(np.all(f.worst_noise() <= limits * (1 + 1e-9)))
    return (bool(ok), decay, zeta)


def compass_search(
    evaluate: Callable[[np.ndarray], tuple], x0: list[np.ndarray], lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, tuple, dict[tuple[float, float], tuple]]:
    """Maximize ``evaluate`` (a comparable rank) over the box from the best of the starts x0:
    poll +-h along ln g, ln Gamma and the critical curve (1, 2), take the first improvement, halve h
    when none improves, stop below h = 0.01. Deterministic. Returns (best x, its rank, every
    evaluated x -> rank)."""
    cache: dict[tuple[float, float], tuple] = {}

    def f(x: np.ndarray) -> tuple:
        key = (round(float(x[0]), 12), round(float(x[1]), 12))
        if key not in cache:
            cache[key] = evaluate(x)
        return cache[key]

    starts = [np.clip(x, lower, upper) for x in x0]
    best = max(starts, key=f)
    dirs = [np.array(d, float) for d in ((1, 2), (-1, -2), (1, 0), (-1, 0), (0, 1), (0, -1))]
    h = 0.25
    while h >= 0.01:
        for d in dirs:
            cand = np.clip(best + h * d / np.linalg.norm(d), lower, upper)
            if f(cand) > f(best):
                best = cand
                break
        else:
            h /= 2
    return best, f(best), cache
