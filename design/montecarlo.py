"""Monte-Carlo robustness of a design: draws of the true motor and of its estimates, their linearized
closed loops over the envelope, yield, worst draws and a sensitivity ranking.

The family's Monte-Carlo module (its ``montecarlo``, design/capabilities.py ``MonteCarloModule``)
declares what can be spread (``parameters``: each parameter's nominal plant value, its estimate if the
observer has one, and whether it enters the linearization), evaluates many draws at once
(``linearize_draws``: one batched linearization over draws x operating points), names the points they
are judged at (``envelope_points``) and builds a perturbed drive for the time domain (``perturbed``).
This module knows no family's parameters: it reads the names the family declares.

Spreads (``--spread``, ``--estimate-error``): ``NAME=X%`` draws NAME = nominal x (1 + X/100 z) with z
standard normal (X is one standard deviation); ``NAME=X%u`` with z uniform in [-1, 1] (X is the half
width). Plant and estimates are drawn independently (the estimate of a parameter is drawn around the
drive's estimate, not around the drawn plant). A value drawn at or below zero is non-physical: a
uniform spread of 100 % or more, or a normal one of 50 % or more, is refused; otherwise the few draws
at or below zero are clipped to :data:`CLIP_FRACTION` of the nominal value, and the run says how many.

Reproducibility: draws are made in chunks of :data:`CHUNK` draws, chunk c from the random generator
seeded by ``SeedSequence(seed).spawn`` child c, so a draw's values depend only on the seed and its
index, never on how many workers evaluate the chunks.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.family import Drive, DriveT, GainSet

CHUNK = 250  # draws per chunk: the unit of seeding and of distributed work
CLIP_FRACTION = 0.05  # a non-physical draw (<= 0) is clipped to this fraction of the nominal value
MAX_NORMAL, MAX_UNIFORM = 0.5, 1.0  # relative spreads refused: they draw <= 0 too often (or always)
_SPEC = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)=([0-9.eE+-]+)%(u?)$")


def perturbed(drive: DriveT, plant: Mapping[str, float], estimate: Mapping[str, float]) -> DriveT:
    """``drive`` (a frozen dataclass with ``motor`` and ``estimate`` records) with its true motor's and
    its estimates' parameters replaced by the given values: a draw's time domain."""
    motor = dataclasses.replace(drive.motor, **{k: float(v) for k, v in plant.items()})
    est = dataclasses.replace(drive.estimate, **{k: float(v) for k, v in estimate.items()})
    return dataclasses.replace(drive, motor=motor, estimate=est)


class SpreadError(ValueError):
    """A spread option cannot be used; the message names the option and the entry (one line)."""


@dataclass(frozen=True)
class Uncertain:
    """A parameter a family lets Monte-Carlo spread."""

    name: str
    plant: float  # the drive's true (motor) value, SI
    estimate: float | None  # the observer's estimate of it, SI; None: the observer has none
    unit: str
    linear: bool  # enters the linearized closed loop (else: the time domain only)
    # the plant's spread a report assumes when given none (``report --montecarlo``): relative, 1 sigma
    typical: float = 0.0


@dataclass(frozen=True)
class Spread:
    """One parameter's relative spread: ``rel`` (1 sigma, or the half width if ``uniform``)."""

    rel: float
    uniform: bool = False

    def text(self) -> str:
        return f"{100 * self.rel:g}%{'u' if self.uniform else ''}"


def parse_spreads(
    text: str | None, option: str, params: Sequence[Uncertain], estimates: bool
) -> dict[str, Spread]:
    """``R_s=10%,L_d=5%u`` -> {name: Spread}; names checked against the family's parameters (those with
    an estimate for ``estimates``); SpreadError naming the option and the entry otherwise."""
    if not text:
        return {}
    known = [p.name for p in params if (p.estimate is not None) or not estimates]
    out: dict[str, Spread] = {}
    for item in text.split(","):
        item = item.strip()
        m = _SPEC.match(item)
        if not m:
            raise SpreadError(
                f"{option}: {item!r} is not NAME=X% (normal, X = 1 sigma) or NAME=X%u (uniform)"
            )
        name, num, uni = m.groups()
        if name not in known:
            what = "estimated parameters" if estimates else "parameters"
            raise SpreadError(f"{option}: {name!r} is not one of the drive's {what} ({', '.join(known)})")
        if name in out:
            raise SpreadError(f"{option}: {name} given twice")
        try:
            rel = float(num) / 100
        except ValueError:
            rel = float("nan")
        if not np.isfinite(rel) or rel < 0:
            raise SpreadError(f"{option}: {item!r}: the spread must be a finite percentage >= 0")
        limit = MAX_UNIFORM if uni else MAX_NORMAL
        if rel >= limit:
            kind = "uniform" if uni else "normal"
            raise SpreadError(
                f"{option}: {item!r}: a {kind} spread of {100 * limit:g} % or more draws {name} <= 0 "
                f"(non-physical) {'always' if uni else 'too often'}; refused"
            )
        out[name] = Spread(rel, bool(uni))
    return out


@dataclass(frozen=True)
class Draws:
    """``n`` draws of the plant and of the estimates: arrays (n, k), columns in the family's order."""

    names: tuple[str, ...]
    plant: np.ndarray
    estimate: np.ndarray
    clipped: dict[str, int]  # "plant R_s" -> number of draws clipped

    def chunk(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        s = slice(c * CHUNK, (c + 1) * CHUNK)
        return self.plant[s], self.estimate[s]

    @property
    def chunks(self) -> int:
        return -(-self.plant.shape[0] // CHUNK)


def _column(rng: np.random.Generator, m: int, spread: Spread | None) -> np.ndarray:
    """m relative deviations; drawn from the stream whether or not the parameter is spread, so adding
    a spread to one parameter does not change the others' draws."""
    z_norm = rng.standard_normal(m)
    z_uni = rng.uniform(-1.0, 1.0, m)
    if spread is None:
        return np.zeros(m)
    return spread.rel * (z_uni if spread.uniform else z_norm)


def draw(
    params: Sequence[Uncertain],
    n: int,
    seed: int,
    plant: Mapping[str, Spread],
    estimate: Mapping[str, Spread],
) -> Draws:
    """``n`` draws (module docstring: chunked seeding, clipping)."""
    k = len(params)
    P, E = np.empty((n, k)), np.empty((n, k))
    children = np.random.SeedSequence(seed).spawn(-(-n // CHUNK))
    for c, child in enumerate(children):
        rng = np.random.default_rng(child)
        s = slice(c * CHUNK, min(n, (c + 1) * CHUNK))
        m = s.stop - s.start
        # a whole chunk's values always (the last chunk's unused ones dropped): a draw's values do not
        # depend on how many draws follow it
        for j, p in enumerate(params):
            P[s, j] = p.plant * (1 + _column(rng, CHUNK, plant.get(p.name))[:m])
        for j, p in enumerate(params):
            nominal = p.estimate if p.estimate is not None else p.plant
            E[s, j] = nominal * (1 + _column(rng, CHUNK, estimate.get(p.name))[:m])
    clipped: dict[str, int] = {}
    for which, arr in (("plant", P), ("estimate", E)):
        for j, p in enumerate(params):
            nominal = p.plant if which == "plant" else (p.estimate or p.plant)
            low = arr[:, j] <= 0
            if low.any():
                clipped[f"{which} {p.name}"] = int(low.sum())
                arr[low, j] = CLIP_FRACTION * nominal
    return Draws(tuple(p.name for p in params), P, E, clipped)


def chunk_damping(
    model: Any,  # a family's MonteCarloModule (design/capabilities.py imports this module's Uncertain)
    drive: Drive,
    gains: GainSet,
    plant: np.ndarray,
    estimate: np.ndarray,
    w: ArrayLike,
    torque: ArrayLike,
) -> tuple[np.ndarray, np.ndarray]:
    """Per draw: the worst damping over the operating points (NaN where a point has no equilibrium:
    counted as a failure) and the index of the worst point. One batched linearization; of the sampled
    observer that runs where the family's gives its poles (``poles_discrete``)."""
    w, torque = np.asarray(w, float), np.asarray(torque, float)
    lin = model.linearize_draws(drive, gains, plant, estimate, w, torque, complete=False)
    z = lin.worst_damping_discrete if lin.poles_discrete is not None else lin.worst_damping
    wd = z.reshape(plant.shape[0], w.size)
    worst = np.where(np.isnan(wd), -np.inf, wd)
    at = np.argmin(worst, axis=1)
    return np.take_along_axis(worst, at[:, None], axis=1)[:, 0], at


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of ``a`` and ``b`` (average ranks for ties); NaN if either is constant."""

    def ranks(x: np.ndarray) -> np.ndarray:
        order = np.argsort(x, kind="stable")
        r = np.empty(x.size)
        r[order] = np.arange(x.size, dtype=float)
        # average the ranks of ties (e.g. the -inf of draws without an equilibrium)
        _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
        sums = np.bincount(inv, weights=r)
        return sums[inv] / counts[inv]

    ra, rb = ranks(np.asarray(a, float)), ranks(np.asarray(b, float))
    if ra.std() == 0 or rb.std() == 0:
        return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])


class Sensitivity(TypedDict):
    """How one spread parameter explains the failures (:func:`sensitivity`)."""

    parameter: str  # "plant NAME" or "estimate NAME"
    spearman_rho: float | None  # rank correlation of its relative deviation with the worst damping
    mean_deviation_failed: float | None  # over the failed draws (its sign: which way fails)
    mean_deviation_passed: float | None


def sensitivity(
    draws: Draws, params: Sequence[Uncertain], spread_names: Sequence[str], worst: np.ndarray, ok: np.ndarray
) -> list[Sensitivity]:
    """Which spread parameter explains the failures: Spearman's rank correlation of each drawn relative
    deviation with the draw's worst damping, ranked by its magnitude; with the mean deviation of the
    failed draws (its sign says which way fails)."""
    rows: list[Sensitivity] = []
    for label in spread_names:
        which, name = label.split(" ", 1)
        j = draws.names.index(name)
        p = params[j]
        arr = draws.plant if which == "plant" else draws.estimate
        nominal = p.plant if which == "plant" else (p.estimate if p.estimate is not None else p.plant)
        dev = arr[:, j] / nominal - 1
        rho = spearman(dev, worst)
        fail = ~ok
        rows.append(
            {
                "parameter": label,
                "spearman_rho": None if np.isnan(rho) else round(rho, 6),
                "mean_deviation_failed": None if not fail.any() else round(float(dev[fail].mean()), 6),
                "mean_deviation_passed": None if fail.all() else round(float(dev[ok].mean()), 6),
            }
        )
    rows.sort(key=lambda r: -abs(r["spearman_rho"] or 0.0))
    return rows
