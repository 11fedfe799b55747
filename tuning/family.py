"""Tuning hooks of the observer families: the tunable gain laws each offers, and how each is tuned.

An observer family names the module of its tuning hooks (``ObserverFamily.tuning``); that module
defines ``HOOKS``, a :class:`TuningHooks` listing its :class:`Tunable` gain laws (the family's own
names, written in its folder only). A tunable is tuned either by
the shared max-min damping NLP (tuning/nlp.py, through a :class:`~sensorless.tuning.model.TuningModel`
its ``build`` returns) or by a tuner of its own (``tuner``: a few parameters, a search of its own).
Either way the result has a gain table (design/gain_table.py) and a terminal summary.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

from sensorless.design.family import CapabilityError, Drive, DriveT, EstimateErrors, ObserverFamily
from sensorless.design.registry import families, family_of

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.gain_table import GainTable
    from sensorless.tuning.model import TuningModel

Progress = Callable[[str], None]


class TuningError(RuntimeError):
    """The tuning NLP failed or the envelope is infeasible (the message says which and where); here, not
    in tuning/nlp.py, so that the settings of a tuner of its own need not import the NLP."""


O = TypeVar("O", bound=Drive, contravariant=True)  # the drive an outcome speaks of


class TuneOutcome(Protocol[O]):
    """What a tuner returns: the gain table and the lines of its terminal summary (of the family's own
    drive type)."""

    @property
    def law(self) -> str: ...
    @property
    def table(self) -> GainTable: ...

    def summary_lines(self, drive: O) -> list[str]:
        """Parameters before -> after, worst figures and where, what was kept and why."""
        ...

    # Optional: ``shortfalls(drive) -> list[str]``, what the tuned gains miss of a criterion of the
    # family's own (one line each: the cause and the change that fixes it). Where an outcome has it,
    # ``sensorless tune`` exits 3 on any line instead of comparing the worst damping with the report's
    # (a family whose damping falls with speed by design judges its gains by other figures).


class TuneSettings(Protocol):
    """What shared code reads of any tunable's settings (the rest is the tunable's own): which tables
    the run writes beside the gain table."""

    @property
    def bound(self) -> bool:
        """Whether the run computes the pointwise bound per speed (``speeds_<name>.csv``)."""
        ...

    @property
    def pareto(self) -> int:
        """Points of the damping-versus-noise front the run computes (``pareto_<name>.csv``); 0: none."""
        ...


@dataclass(frozen=True)
class Tunable(Generic[DriveT]):
    """A tunable gain law: its name (the gain table's ``law``) and how it is tuned.

    Exactly one of ``build`` (drive, settings, seed) -> TuningModel for the shared NLP, and ``tuner``
    (drive, settings, progress) -> TuneOutcome, is given. ``seed`` names a tunable tuned first whose
    parameters start this one (a rich law started from a tuned simpler one). ``settings`` (drive) ->
    the default settings (envelope, constraints; the law's own part in ``law``) of this tunable.
    ``columns`` are the leading per-point columns of its CSV table, (heading, point key), and those
    of the baseline. Generic in the family's drive type (its callables take its own drive).
    """

    name: str
    description: str
    settings: Callable[[DriveT], TuneSettings]
    # (drive, settings, seed): the family's own drive and settings types
    build: Callable[..., TuningModel] | None = None
    tuner: Callable[..., TuneOutcome[DriveT]] | None = None  # (drive, settings, progress)
    seed: str | None = None
    columns: tuple[tuple[tuple[str, str], ...], tuple[tuple[str, str], ...]] = ((), ())

    def __post_init__(self) -> None:
        if (self.build is None) == (self.tuner is None):
            raise ValueError(f"tunable {self.name!r}: give exactly one of build (shared NLP) and tuner")


@dataclass(frozen=True)
class TuningHooks(Generic[DriveT]):
    """A family's tunables; the first is the default of ``sensorless tune`` on a built-in preset (the
    paper's law, to reproduce the paper), ``own_default`` the default on a drive of the user's own: a
    name (the family's best law), or (drive) -> name (e.g. the law the drive file's own gains are of;
    None from it or no ``own_default``: the first)."""

    tunables: tuple[Tunable[DriveT], ...]
    own_default: str | Callable[[DriveT], str | None] | None = None
    # (drive, settings) -> the estimate errors its tuners of their own judge the gains under, from their
    # settings (the tunable's own settings type); None: the family's estimate_errors(drive)
    # (:func:`estimate_errors`)
    estimate_errors: Callable[[DriveT, Any], EstimateErrors] | None = None

    def tunable(
        self, name: str | None, family: ObserverFamily, preset: bool = True, drive: DriveT = None
    ) -> Tunable[DriveT]:
        """The tunable called ``name`` (None: the default for a preset or a drive of the user's own);
        CapabilityError naming what exists."""
        if name is None and not preset:
            own = self.own_default
            name = own(drive) if callable(own) else own
        if name is None:
            return self.tunables[0]
        for t in self.tunables:
            if t.name == name:
                return t
        have = ", ".join(t.name for t in self.tunables)
        raise CapabilityError(
            f"gain law {name!r} cannot be tuned for {family.title} drives (kind '{family.kind}'); "
            f"it has: {have}"
        )


def hooks(family: ObserverFamily[DriveT]) -> TuningHooks[DriveT]:
    """The tuning hooks of ``family``; CapabilityError if it has none."""
    if family.tuning is None:
        raise CapabilityError(f"observer family {family.name!r} has nothing to tune")
    h = getattr(importlib.import_module(family.tuning), "HOOKS", None)
    if not isinstance(h, TuningHooks):
        raise CapabilityError(f"{family.tuning} defines no TuningHooks HOOKS")
    return h


def tunable_for(drive: Drive, name: str | None = None) -> Tunable:
    """The tunable ``name`` (None: the default, which differs between a built-in preset and a drive of
    the user's own: :class:`TuningHooks`) of the drive's family."""
    fam = family_of(drive)
    preset = drive.file.startswith("preset:")
    return hooks(fam).tunable(name, fam, preset=preset, drive=drive)


def estimate_errors(drive: Drive, tunable: Tunable, settings: TuneSettings) -> EstimateErrors:
    """The estimate errors a run of ``tunable`` with ``settings`` tunes under: a tunable on the shared NLP
    those of its TuningSettings (design/envelope.py), a tuner of its own those of the family's hook; the
    family's ``estimate_errors(drive)`` (with where it states them) where the run's are the same."""
    fam = family_of(drive)
    stated = fam.estimate_errors(drive)
    h = hooks(fam)
    if tunable.build is not None:
        run = settings.estimate_errors()
    elif h.estimate_errors is not None:
        run = h.estimate_errors(drive, settings)
    else:
        return stated
    if run.text() == stated.text():
        return stated
    return dataclasses.replace(run, source="the errors of this tune run's options")


def all_tunables() -> dict[str, str]:
    """Every tunable of every registered family: name -> description (for help texts); a name two
    families have (law names are each family's own) -> each description, after its family's name."""
    named: dict[str, list[tuple[str, str]]] = {}
    for fam in families():
        try:
            for t in hooks(fam).tunables:
                named.setdefault(t.name, []).append((fam.name, t.description))
        except CapabilityError:
            continue
    return {k: v[0][1] if len(v) == 1 else " | ".join(f"({f}) {d}" for f, d in v) for k, v in named.items()}
