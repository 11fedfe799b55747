"""Tuning hooks of the PLL test family: the gain family ``pll`` (the PLL bandwidth), by a search of its own.

One parameter needs no NLP: the tuner evaluates the poles of the sampled observer (design.linearize:
discrete poles ln(z)/T_s at the drive's sampling period) over the envelope (speeds x torques of the
drive's ``[envelope]``) for bandwidths on a logarithmic grid between the bounds, refines around the
best, and keeps the bandwidth with the fastest slowest decay among those whose worst damping is at
least ``min_damping`` (ties: the smaller bandwidth, less noise). The best candidates are re-verified
on a grid ``dense_factor`` times denser in speed, in rank order; the first that passes is kept.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.tuning.family import Tunable, TuningHooks
from sensorless.tuning.nlp import TuningError

from families.pll.design import linearize

DENSE_TRIES = 6


@dataclass(frozen=True)
class PllSettings:
    """Envelope, bounds and constraint of the ``pll`` tunable."""

    w_min: float  # bandwidth bounds [rad/s]
    w_max: float
    min_damping: float = 0.5  # the PLL's own double pole (damping 1) is split by the EMF observer
    candidates: int = 41
    dense_factor: int = 4

    def check(self, where: str) -> None:
        """TuningError naming the option."""
        if not 0 < self.w_min < self.w_max:
            raise TuningError(f"{where}: --bandwidth-max: need 0 < {self.w_min:g} < {self.w_max:g} rad/s")
        if not 0 <= self.min_damping < 1:
            raise TuningError(f"{where}: --min-damping: must be in [0, 1), got {self.min_damping:g}")
        if self.dense_factor < 4:
            raise TuningError(f"{where}: --dense-factor: must be >= 4, got {self.dense_factor}")


def default_settings(drive: Any) -> PllSettings:
    """Bounds 0.1x .. 20x the drive's bandwidth."""
    w = drive.observer.w_pll
    return PllSettings(w_min=0.1 * w, w_max=20 * w)


@dataclass(frozen=True)
class Figures:
    """Discrete poles of one bandwidth on a grid, and their worst figures."""

    w: np.ndarray
    T: np.ndarray
    poles: np.ndarray
    damping: np.ndarray  # worst per point; -inf where undefined
    decay: np.ndarray  # -max Re per point [1/s]; -inf where undefined

    def rank(self, min_damping: float) -> tuple[bool, float, float]:
        z, d = float(np.min(self.damping)), float(np.min(self.decay))
        return (z >= min_damping - 1e-9 and d > 0, d, z)


def grid(drive: Any, factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Flat (speed [rad/s], torque [N m]) of the envelope."""
    W, T = np.meshgrid(drive.speed_grid(factor), np.asarray(drive.envelope.torques, float))
    return W.ravel(), T.ravel()


def figures(drive: Any, w_pll: float, W: np.ndarray, T: np.ndarray) -> Figures:
    lin = linearize(drive, GainSet("pll", {"w_pll": float(w_pll)}), W, T)
    ok = np.isfinite(lin.poles_discrete).all(axis=1)
    z = np.where(ok, lin.worst_damping_discrete, -np.inf)
    d = np.where(ok, lin.decay_rate_discrete, -np.inf)
    return Figures(W, T, lin.poles_discrete, z, d)


@dataclass(frozen=True)
class PllTuneResult:
    """What ``sensorless tune`` reports for the ``pll`` tunable."""

    family: str
    w_pll: float
    w_pll0: float
    dense: Figures
    dense_baseline: Figures
    evaluations: int
    note: str
    settings: PllSettings
    table: GainTable
    seconds: float

    def summary_lines(self, drive: Any = None) -> list[str]:
        z0, d0 = float(np.min(self.dense_baseline.damping)), float(np.min(self.dense_baseline.decay))
        z1, d1 = float(np.min(self.dense.damping)), float(np.min(self.dense.decay))
        return [
            f"searched {self.evaluations} bandwidths in "
            f"[{self.settings.w_min:.4g}, {self.settings.w_max:.4g}] rad/s; "
            f"re-verified on {self.dense.w.size} points in {self.seconds:.1f} s",
            f"{'':<24}{'drive file':>14}{'tuned':>14}",
            f"{'w_pll [rad/s]':<24}{self.w_pll0:>14.5g}{self.w_pll:>14.5g}",
            f"{'slowest decay [1/s]':<24}{d0:>14.4g}{d1:>14.4g}",
            f"{'worst damping':<24}{z0:>14.4f}{z1:>14.4f}",
            f"kept: {self.note}",
        ]


def tune_pll(drive: Any, settings: Any, progress: Callable[[str], None] | None = None) -> PllTuneResult:
    """The bandwidth search of the module docstring."""
    t0 = time.perf_counter()
    st: PllSettings = settings or default_settings(drive)
    st.check(drive.file)
    say = progress or (lambda s: None)
    W, T = grid(drive)
    seen: dict[float, tuple] = {}

    def rank(w: float) -> tuple:
        if w not in seen:
            seen[w] = figures(drive, w, W, T).rank(st.min_damping)
        return seen[w]

    cands = np.geomspace(st.w_min, st.w_max, st.candidates)
    say(f"pll: {cands.size} bandwidths over {W.size} envelope points")

    def key(w: float) -> tuple:
        return (*rank(w), -w)  # feasible, slowest decay, worst damping; ties: the smaller bandwidth

    best = max(cands, key=key)
    k = int(np.flatnonzero(cands == best)[0])
    lo, hi = cands[max(k - 1, 0)], cands[min(k + 1, cands.size - 1)]
    say(f"refining between {lo:.4g} and {hi:.4g} rad/s")
    for w in np.geomspace(lo, hi, 21):
        rank(float(w))
    ranked = sorted(seen, key=key, reverse=True)
    if not seen[ranked[0]][0]:
        raise TuningError(
            f"{drive.file}: no PLL bandwidth in [{st.w_min:g}, {st.w_max:g}] rad/s gives stable discrete "
            f"poles with damping >= {st.min_damping:.3f} over the envelope"
        )
    Wd, Td = grid(drive, st.dense_factor)
    w0 = float(drive.observer.w_pll)
    base = figures(drive, w0, Wd, Td)
    chosen = None
    for i, w in enumerate(ranked[:DENSE_TRIES]):
        f = figures(drive, w, Wd, Td)
        if f.rank(st.min_damping)[0]:
            chosen, note = (w, f), f"candidate {i + 1} by grid rank, verified on the dense grid"
            break
        say(f"  w_pll = {w:.5g} rad/s fails between the grid points; next candidate")
    if chosen is None:
        if not base.rank(st.min_damping)[0]:
            raise TuningError(
                f"{drive.file}: neither the best bandwidths nor the drive's pass the dense grid"
            )
        chosen, note = (w0, base), "the drive's bandwidth (no tuned candidate passes the dense grid)"
    w_pll, dense = chosen
    say(note)
    result = PllTuneResult(
        family="pll",
        w_pll=float(w_pll),
        w_pll0=w0,
        dense=dense,
        dense_baseline=base,
        evaluations=len(seen),
        note=note,
        settings=st,
        table=None,  # type: ignore[arg-type]
        seconds=time.perf_counter() - t0,
    )
    return dataclasses.replace(result, table=_table(drive, result))


def _pairs(p: np.ndarray) -> list[list[float]]:
    return [[float(z.real), float(z.imag)] for z in p]


def _table(drive: Any, r: PllTuneResult) -> GainTable:
    d, d0 = r.dense, r.dense_baseline
    wb = drive.w_base
    points = [
        {
            "w_rad_s": float(d.w[j]),
            "w_pu": float(d.w[j] / wb),
            "T_e_Nm": float(d.T[j]),
            "w_pll": r.w_pll,
            "poles": _pairs(d.poles[j]),
            "damping": float(d.damping[j]),
            "decay_rate": float(d.decay[j]),
            "baseline": {
                "w_pll": r.w_pll0,
                "poles": _pairs(d0.poles[j]),
                "damping": float(d0.damping[j]),
                "decay_rate": float(d0.decay[j]),
            },
        }
        for j in range(d.w.size)
    ]
    st = r.settings
    return GainTable(
        family="pll",
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains={"w_pll": r.w_pll},
        envelope={
            "speed_base_rad_s": wb,
            "speeds_rad_s": drive.speed_grid().tolist(),
            "torques_Nm": list(drive.envelope.torques),
            "dense_factor": st.dense_factor,
            "dense_points": int(d.w.size),
            "T_s_s": drive.control.T_s,
            "bounds": {"w_pll": [st.w_min, st.w_max]},
            "constraints": {"min_damping": st.min_damping},
        },
        points=points,
        summary={
            "objective": "maximize the slowest decay rate of the discrete poles, damping >= min_damping",
            "min_decay_rate": float(np.min(d.decay)),
            "worst_damping": float(np.min(d.damping)),
            "baseline_min_decay_rate": float(np.min(d0.decay)),
            "baseline_worst_damping": float(np.min(d0.damping)),
            "evaluations": r.evaluations,
            "selection": r.note,
            "parameters": {"w_pll": r.w_pll},
            "baseline_parameters": {"w_pll": r.w_pll0},
        },
    )


_LEAD = (("w_m_pu", "w_pu"), ("w_m_rad_s", "w_rad_s"), ("T_e_Nm", "T_e_Nm"), ("w_pll_rad_s", "w_pll"))

HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "pll",
            "back-EMF PLL observer: the PLL bandwidth w_pll",
            default_settings,
            tuner=tune_pll,
            columns=(_LEAD, (("w_pll_rad_s", "w_pll"),)),
        ),
    )
)
