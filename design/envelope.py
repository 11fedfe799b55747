"""The operating envelope of every drive (:class:`Envelope`, SI) and the ``[tuning]`` section of a drive.

:class:`Envelope` is the one record of a drive's operating points that analyze, tune, report and
Monte-Carlo read: electrical speeds [rad/s] x torques [N m], with the per-unit bases for display. Each
family's schema translates its own drive-file keys into it (:class:`SpeedRule` keeps the arithmetic
the family has always used, so no grid value moves).

The ``[tuning]`` section is shared by the families whose tunables go through the max-min damping NLP
(tuning/tune.py): a grid of speeds (p.u. of the drive's base, per direction) x torques (multiples of
T_N), constraints, and errors of the PMSM estimates (R̂s, L̂d, L̂q, ψ̂pm) to stay stable under.

Defaults: |w_m| in [0.05, 1] p.u. in both directions x T_e in
{-T_N, 0, T_N}, no decay-rate constraint, no parameter-error scenarios, no noise limit. Loading is
strict like the rest of the drive file: unknown keys, wrong units or types and inconsistent values
raise DriveFileError naming the file and the key. Its speeds are given in p.u. of the drive's base
speed (the edge unit of the command line and the tables); :func:`tuning_envelope` makes them SI.

What a family's gain laws add (bounds of their own gains, options of their parameterization) is not
here: the family declares those ``[tuning]`` keys and their reader (:class:`LawKeys`), and the loaded
values ride along as ``TuningSettings.law`` (:class:`LawSettings`), read only by the family's own code.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np
from sensorless.design.family import Drive, EstimateErrors
from sensorless.design.units import DriveFileError, check_magnitude, parse_number, parse_quantity

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

ESTIMATE_KEYS = ("R_s", "L_d", "L_q", "psi_pm")  # order of the estimate vector
# noise outputs of the PMSM observers: the position estimate [rad, electrical] and the speed estimate
# [rad/s, electrical] (design/noise.py)
NOISE_OUTPUTS = ("position", "speed")
NOISE_DIMS = {"position": "angle", "speed": "angular"}
DIRECTIONS = ("both", "positive", "negative")
# the ranges of the [tuning] keys, the same for the drive file and the command-line option of the same
# name (reports/ipmsm_adaptive/tune.py): (lowest, highest); speeds in p.u., min_decay in 1/s (a law's own
# keys have theirs beside it, e.g. design/ipmsm_adaptive/law_settings.py BREAKPOINTS)
RANGES = {
    "speed": (0.0, 100.0),  # speed_min, speed_max: (0, 100] p.u.
    "speeds": (2, 1000),
    "dense_factor": (4, 64),
    "min_decay": (0.0, 1e6),
    "pareto": (2, 100),
}


@dataclass(frozen=True)
class SpeedRule:
    """How a drive file gives its speeds, kept so that the SI grid and its refinements come out of the
    family's own arithmetic, bit for bit: either ``count`` evenly spaced magnitudes from ``lo`` to ``hi``
    per direction, or (``count`` 0) the ``listed`` signed speeds, sorted and distinct, refined only
    between speeds of one sign (never across standstill); in the file's unit, times the factors
    ``to_si`` in that order (none: already electrical rad/s)."""

    lo: float = 0.0
    hi: float = 0.0
    count: int = 0
    listed: tuple[float, ...] = ()
    to_si: tuple[float, ...] = ()
    directions: str = "both"

    def native(self, factor: int = 1) -> np.ndarray:
        """The grid in the file's unit, sorted; ``factor`` > 1 refines each interval that many times."""
        if self.count:
            mag = np.linspace(self.lo, self.hi, (self.count - 1) * factor + 1)
            return self._directions(mag)
        s = np.unique(np.asarray(self.listed, float))
        out = [s[:1]]
        for a, b in itertools.pairwise(s):
            if factor > 1 and a * b > 0:
                out.append(np.linspace(a, b, factor + 1)[1:])
            else:
                out.append(np.array([b]))
        return np.concatenate(out)

    def at(self, factor: int = 1) -> np.ndarray:
        """The grid in electrical rad/s, sorted (the unit conversion applied before the mirroring, as the
        families have always computed it)."""
        if self.count:
            mag = np.linspace(self.lo, self.hi, (self.count - 1) * factor + 1)
            for k in self.to_si:
                mag = mag * k
            return self._directions(mag)
        s = self.native(factor)
        for k in self.to_si:
            s = s * k
        return s

    def _directions(self, mag: np.ndarray) -> np.ndarray:
        parts = []
        if self.directions in ("both", "negative"):
            parts.append(-mag[::-1])
        if self.directions in ("both", "positive"):
            parts.append(mag)
        return np.concatenate(parts)


@dataclass(frozen=True)
class Envelope:
    """The operating points of a drive, SI: electrical speeds [rad/s] x torques [N m] (``speeds``,
    ``torques``: sorted explicit grids), their refinements, and the bases of the per-unit display.

    Each family's schema translates its own drive-file keys into this record at load (``speeds`` from
    its :class:`SpeedRule`, ``torques`` the distinct ``torque_values`` times ``torque_unit``), so the grid
    values are the ones it has always computed; analyze, tune, report and Monte-Carlo read only this."""

    rule: SpeedRule
    torque_values: tuple[float, ...]  # torques in the file's unit (``torque_unit`` N m each)
    w_base: float  # per-unit speed base [rad/s electrical] (display at the edges)
    T_N: float  # nominal torque [N m] (display at the edges)
    torque_unit: float = 1.0  # N m per unit of ``torque_values`` (T_N for torques given in T_N)
    dense_factor: int = 4  # the re-verification grid is this many times denser (>= 4)
    # the section's keys as the file gives them (a dataclass; the drive-data table shows it), or None
    given: DataclassInstance | None = field(default=None, compare=False, repr=False)

    @functools.cached_property
    def speeds(self) -> tuple[float, ...]:
        """Electrical speeds [rad/s], sorted."""
        return tuple(self.rule.at().tolist())

    @functools.cached_property
    def torques(self) -> tuple[float, ...]:
        """Torques [N m], sorted and distinct."""
        return tuple(self.torque_grid().tolist())

    def speed_grid(self, factor: int = 1) -> np.ndarray:
        """Electrical speeds [rad/s], sorted; ``factor`` > 1 refines each interval that many times."""
        return self.rule.at(factor)

    def torque_grid(self, factor: int = 1) -> np.ndarray:
        """Torques [N m], sorted; ``factor`` > 1 inserts points in each interval between them."""
        T = np.unique(np.asarray(self.torque_values, float))
        if self.torque_unit != 1.0:
            T = T * self.torque_unit
        if factor == 1 or T.size == 1:
            return T
        pieces = [np.linspace(a, b, factor + 1)[:-1] for a, b in itertools.pairwise(T)]
        return np.concatenate([*pieces, T[-1:]])

    def grid(self, factor: int = 1, torque_factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Flat (w [rad/s], T_e [N m]) of the speed x torque grid (torque-major), speeds refined
        ``factor`` times and torques ``torque_factor`` times."""
        W, T = np.meshgrid(self.speed_grid(factor), self.torque_grid(torque_factor))
        return W.ravel(), T.ravel()

    @property
    def speed_max(self) -> float:
        """The largest |speed| [rad/s electrical]."""
        return float(np.max(np.abs(self.rule.at())))

    def widened(self, T_max: float) -> Envelope:
        """This envelope with its torques widened to +-``T_max`` where they stop short of it (added in
        the file's unit, as ``torque_values``)."""
        k = T_max / self.torque_unit
        tq = self.torque_values
        if max(abs(t) for t in tq) >= k * (1 - 1e-9):
            return self
        return dataclasses.replace(self, torque_values=tuple(sorted({*tq, -k, k})))

    def describe(self) -> str:
        """One line for the terminal (speeds in p.u. of ``w_base``, torques in T_N)."""
        r = self.rule
        if r.count and r.to_si == (self.w_base,):
            lo, hi, n = r.lo, r.hi, r.count
        else:
            mag = np.abs(self.rule.at())
            lo, hi, n = float(mag.min()) / self.w_base, float(mag.max()) / self.w_base, len(self.speeds)
        dirs = {"both": "both directions", "positive": "positive speeds", "negative": "negative speeds"}
        scale = self.torque_unit / self.T_N
        tq = ", ".join(f"{t * scale:g}" for t in self.torque_values)
        return (
            f"|w_m| in [{lo:g}, {hi:g}] p.u. ({n} speeds, "
            f"{dirs.get(r.directions, r.directions)}) x T_e in {{{tq}}} T_N"
        )


# the [tuning] envelope keys and their defaults (p.u. of the drive's base speed; torques in T_N)
TUNING_ENVELOPE = {
    "speed_min": 0.05,  # smallest |w_m| [p.u.]
    "speed_max": 1.0,  # largest |w_m| [p.u.]
    "speeds": 20,  # grid points per direction
    "directions": "both",
    "torques_TN": (-1.0, 0.0, 1.0),  # torques as multiples of T_N
    "dense_factor": 4,
}


def tuning_envelope(w_base: float, T_N: float, **keys: Any) -> Envelope:
    """The :class:`Envelope` of the ``[tuning]`` keys (``TUNING_ENVELOPE``; absent ones keep their
    defaults): ``speeds`` speeds per direction evenly spaced in p.u. times ``w_base``, torques in T_N."""
    k = {**TUNING_ENVELOPE, **keys}
    rule = SpeedRule(k["speed_min"], k["speed_max"], k["speeds"], to_si=(w_base,), directions=k["directions"])
    torques = tuple(k["torques_TN"])
    return Envelope(rule, torques, w_base, T_N, torque_unit=T_N, dense_factor=k["dense_factor"])


def with_tuning_keys(env: Envelope, **keys: Any) -> Envelope:
    """``env`` (made by :func:`tuning_envelope`) with the given ``[tuning]`` keys replaced."""
    return tuning_envelope(env.w_base, env.T_N, **{**tuning_keys(env), **keys})


def tuning_keys(env: Envelope) -> dict[str, Any]:
    """The ``[tuning]`` keys of an envelope made by :func:`tuning_envelope` (to apply overrides)."""
    r = env.rule
    return {
        "speed_min": r.lo,
        "speed_max": r.hi,
        "speeds": r.count,
        "directions": r.directions,
        "torques_TN": env.torque_values,
        "dense_factor": env.dense_factor,
    }


class LawSettings(Protocol):
    """The settings a family's gain laws add to the shared ones (its own ``[tuning]`` keys)."""

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """Raise DriveFileError for an inconsistent value (the key named with ``prefix``)."""
        ...

    def constraints(self) -> dict[str, Any]:
        """Entries of the gain table's ``envelope.constraints`` (SI values, keys with their unit)."""
        ...


@dataclass(frozen=True)
class NoLawSettings:
    """The law settings of a family whose laws add none."""

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """Nothing to check."""

    def constraints(self) -> dict[str, Any]:
        """No entries."""
        return {}


@dataclass(frozen=True)
class LawKeys:
    """The ``[tuning]`` keys a family's gain laws add, and their reader (``load_tuning``)."""

    keys: tuple[str, ...]
    # (the [tuning] table, file, relative units as in load_tuning) -> the law's settings; reads only ``keys``
    load: Callable[[Mapping[str, Any], str, Mapping[str, float]], LawSettings]


class Enveloped(Drive, Protocol):
    """A drive with its operating envelope (every family's: the one analyze, tune, report and
    Monte-Carlo read)."""

    @property
    def envelope(self) -> Envelope: ...


EnvelopedT = TypeVar("EnvelopedT", bound=Enveloped)  # a family's drive, with its envelope


@dataclass(frozen=True)
class TuningSettings:
    """Envelope, constraints and options of ``sensorless tune`` (drive TOML ``[tuning]``)."""

    envelope: Envelope | None = None  # the [tuning] envelope (tuning_envelope); None: not resolved yet
    min_decay: float = 0.0  # required decay rate -max Re(p) at every envelope point [1/s]; 0: off
    errors: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # relative errors of the estimates
    smoothing: float = 1e-3  # weight of the law's regularizer (if it has one) against damping
    # noise limits: (noise output, limit in SI) pairs, e.g. (("position", 0.001),) [rad]; () none
    max_noise: tuple[tuple[str, float], ...] = ()
    pareto: int = 0  # points of the damping-versus-noise front to compute (0: none)
    pareto_output: str = ""  # noise output of the front ("": the first limited one, else the family's first)
    bound: bool = True  # compute the pointwise bound (the certificate) on the dense grid
    # hold the law's bounded figures (tuning/model.py TuningModel.bounded) to the drive file's gains'; off
    # where those gains fail a time-domain check in the I-f start (reports/cli/tune.py): a reference that
    # fails there is no bound (servo400's speed steps, which the tuned gains pass only unbounded)
    hold_bounded: bool = True
    law: LawSettings = NoLawSettings()  # what the family's gain laws add (LawKeys)

    @property
    def resolved(self) -> Envelope:
        """``envelope``, resolved (a loaded drive's settings have it; ValueError where not yet)."""
        if self.envelope is None:
            raise ValueError("tuning settings without their envelope (not resolved yet: tuning_envelope)")
        return self.envelope

    def estimate_errors(self, source: str = "the drive file's [tuning] errors") -> EstimateErrors:
        """``errors`` as the box the design is tuned and reviewed for (design/family.py)."""
        return EstimateErrors(dict(zip(ESTIMATE_KEYS, self.errors, strict=True)), source=source)

    def noise_limits(self, outputs: tuple[str, ...]) -> np.ndarray | None:
        """Limits per noise output (inf: none), in the order of ``outputs``; None if no limit is set."""
        if not self.max_noise:
            return None
        lim = dict(self.max_noise)
        return np.array([lim.get(o, np.inf) for o in outputs], float)

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """Raise DriveFileError for inconsistent values (the key named with ``prefix``)."""

        def bad(key: str, why: str) -> DriveFileError:
            return DriveFileError(file, f"{prefix}{key}", why)

        if self.envelope is not None:
            check_envelope(tuning_keys(self.envelope), bad)

        if not RANGES["min_decay"][0] <= self.min_decay <= RANGES["min_decay"][1]:
            raise bad(
                "min_decay",
                f"must be in [0, {RANGES['min_decay'][1]:g}] 1/s (as --min-decay), got {self.min_decay:g}",
            )
        if self.pareto and not RANGES["pareto"][0] <= self.pareto <= RANGES["pareto"][1]:
            raise bad(
                "pareto",
                f"need 0 (none) or {RANGES['pareto'][0]}..{RANGES['pareto'][1]} points, got {self.pareto}",
            )
        if self.min_decay < 0:
            raise bad("min_decay", f"must be >= 0, got {self.min_decay:g}")
        for k, v in zip(ESTIMATE_KEYS, self.errors, strict=True):
            if not 0 <= v < 0.9:
                raise bad(f"errors.{k}", f"must be in [0 %, 90 %), got {100 * v:g} %")
        if not 0 <= self.smoothing < 0.1:
            raise bad("smoothing", f"must be in [0, 0.1), got {self.smoothing:g}")
        for name, v in self.max_noise:
            if name not in NOISE_OUTPUTS:
                raise bad(f"max_noise.{name}", f"unknown noise output (allowed: {', '.join(NOISE_OUTPUTS)})")
            if not v > 0:
                raise bad(f"max_noise.{name}", f"must be > 0, got {v:g}")
        if self.pareto < 0 or self.pareto == 1:
            raise bad("pareto", f"need 0 (none) or at least 2 points, got {self.pareto}")
        if self.pareto_output and self.pareto_output not in NOISE_OUTPUTS:
            raise bad("pareto_output", f"unknown noise output (allowed: {', '.join(NOISE_OUTPUTS)})")
        self.law.check(file, prefix)


def check_envelope(e: Mapping[str, Any], bad: Callable[[str, str], DriveFileError]) -> None:
    """Raise ``bad(key, why)`` for inconsistent ``[tuning]`` envelope keys (``TUNING_ENVELOPE``)."""
    speed_min, speed_max, speeds = e["speed_min"], e["speed_max"], e["speeds"]
    directions, torques_TN, dense_factor = e["directions"], e["torques_TN"], e["dense_factor"]
    if not 0 < speed_min < speed_max:
        raise bad("speed_min", f"need 0 < speed_min < speed_max, got {speed_min:g}, {speed_max:g}")
    if speed_max > RANGES["speed"][1]:
        raise bad("speed_max", f"must be <= {RANGES['speed'][1]:g} p.u. (as --speed-max), got {speed_max:g}")
    for key, v in (("speeds", speeds), ("dense_factor", dense_factor)):
        lo, hi = RANGES[key]
        if not lo <= v <= hi:
            opt = "--" + key.replace("_", "-")
            raise bad(key, f"must be an integer in {lo}..{hi} (as {opt}), got {v}")
    if speeds < 2:
        raise bad("speeds", f"need at least 2 speed points per direction, got {speeds}")
    if directions not in DIRECTIONS:
        raise bad("directions", f"{directions!r} is not one of {', '.join(DIRECTIONS)}")
    if not torques_TN:
        raise bad("torques", "need at least one torque")
    if dense_factor < 4:
        raise bad("dense_factor", f"the re-verification grid must be >= 4x denser, got {dense_factor}")


_KEYS = (
    "speed_min",
    "speed_max",
    "speeds",
    "directions",
    "torques",
    "dense_factor",
    "min_decay",
    "errors",
    "smoothing",
    "max_noise",
)


def parse_relative(value: object, dim: str, rel: Mapping[str, float], file: str, key: str) -> float:
    """A quantity that may carry a relative unit (``T_N``, or a unit of ``rel``: ``pu``, ...); returns SI."""
    if dim == "torque" and isinstance(value, str) and value.strip().endswith("T_N"):
        num = value.strip()[:-3].strip() or "1"
        return check_magnitude(parse_number(num, file=file, key=key) * rel["T_N"], value, file=file, key=key)
    x, unit = parse_quantity(value, dim, file=file, key=key)
    if unit is not None:
        if unit not in rel:
            raise DriveFileError(file, key, f"unit '{unit}' cannot be resolved here")
        x = check_magnitude(x * rel[unit], value, file=file, key=key)
    return x


def read_int(value: object, file: str, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise DriveFileError(file, key, f"expected an integer, got {value!r}")
    return value


def load_tuning(
    table: Mapping[str, Any], file: str, rel: Mapping[str, float], law: LawKeys | None = None
) -> TuningSettings:
    """Strictly load a ``[tuning]`` table; absent keys keep their defaults. ``rel`` resolves the
    relative units: ``pu`` (base speed, rad/s), ``T_N`` (N m) and any the family adds. ``law``: the keys
    the family's gain laws add and their reader (None: none)."""
    allowed = _KEYS + (law.keys if law is not None else ())
    for k in table:
        if k not in allowed:
            raise DriveFileError(file, f"tuning.{k}", f"unknown key (allowed: {', '.join(allowed)})")
    env: dict[str, Any] = {}
    out: dict[str, Any] = {}
    w_base, T_N = rel["pu"], rel["T_N"]
    for k in ("speed_min", "speed_max"):
        if k in table:
            env[k] = parse_relative(table[k], "angular", rel, file, f"tuning.{k}") / w_base
    for k in ("speeds", "dense_factor"):
        if k in table:
            env[k] = read_int(table[k], file, f"tuning.{k}")
    if "directions" in table:
        if not isinstance(table["directions"], str):
            raise DriveFileError(file, "tuning.directions", f"expected a string, got {table['directions']!r}")
        env["directions"] = table["directions"]
    if "torques" in table:
        tq = table["torques"]
        if not isinstance(tq, list):
            raise DriveFileError(
                file, "tuning.torques", f"expected a list such as ['-1 T_N', '0 Nm'], got {tq!r}"
            )
        env["torques_TN"] = tuple(
            parse_relative(v, "torque", rel, file, f"tuning.torques[{i}]") / T_N for i, v in enumerate(tq)
        )
    if "min_decay" in table:
        out["min_decay"] = parse_relative(table["min_decay"], "rate", rel, file, "tuning.min_decay")
    if "errors" in table:
        et = table["errors"]
        if not isinstance(et, dict):
            raise DriveFileError(file, "tuning.errors", "expected a table {R_s = '20 %', ...}")
        errs = [0.0] * 4
        for k, v in et.items():
            if k not in ESTIMATE_KEYS:
                raise DriveFileError(
                    file, f"tuning.errors.{k}", f"unknown key (allowed: {', '.join(ESTIMATE_KEYS)})"
                )
            errs[ESTIMATE_KEYS.index(k)] = parse_relative(v, "fraction", rel, file, f"tuning.errors.{k}")
        out["errors"] = tuple(errs)
    if "smoothing" in table:
        out["smoothing"] = parse_relative(table["smoothing"], "dimensionless", rel, file, "tuning.smoothing")
    if "max_noise" in table:
        mt = table["max_noise"]
        if not isinstance(mt, dict):
            raise DriveFileError(file, "tuning.max_noise", "expected a table {position = '0.1 deg', ...}")
        lims = []
        for k, v in mt.items():
            if k not in NOISE_OUTPUTS:
                raise DriveFileError(
                    file,
                    f"tuning.max_noise.{k}",
                    f"unknown noise output (allowed: {', '.join(NOISE_OUTPUTS)})",
                )
            lims.append((k, parse_relative(v, NOISE_DIMS[k], rel, file, f"tuning.max_noise.{k}")))
        out["max_noise"] = tuple(lims)
    if law is not None:
        out["law"] = law.load(table, file, rel)
    settings = TuningSettings(envelope=tuning_envelope(w_base, T_N, **env), **out)
    settings.check(file)
    return settings
