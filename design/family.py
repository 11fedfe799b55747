"""The observer-family contract: its core, one base class (its further capabilities: capabilities.py).

An observer family (the speed-adaptive flux observer of Piippo et al., the reduced-order EMF observer
of De Angelo et al., a firmware's flux observer + PLL, ...) is one :class:`ObserverFamily` instance,
registered in :mod:`sensorless.design.registry`, which is the only place that maps a drive file's
``[drive] kind`` to code. Its core, here:

- its drive-file schema (:meth:`ObserverFamily.load`, returning its own drive dataclass, the type
  parameter of :class:`ObserverFamily`), presets and built-in scenarios (packages);
- its gains: which gain laws (gain-table ``law``) it accepts and their keys, and the gains of a drive
  (:meth:`gains`, from the drive file or a tuned table);
- its runtime observer: the discrete-time step of the one runtime contract (symbolic/runtime.py),
  with its parameters from a drive (:meth:`runtime`), which simulation runs and codegen prints as C;
- the scenario keys it adds, the parameter-error factors a scenario may give (``estimate_keys``) and
  the trace panels of its own (``panels``: :class:`Panel`, drawn by the shared figure code);
- the names of the modules that hold its higher-layer hooks: tuning (tunable gain laws, tuners;
  imported by ``sensorless.tuning``) and reports (analysis output, report sections, firmware formats;
  imported by ``sensorless.reports``). The design layer never imports them, so no layer reaches up
  (docs/architecture.md).

Beyond the core, each capability is a typed Protocol of design/capabilities.py that a family has by
defining its methods: a minimal drive file's completion (``Documented``), its linearization
(``Linearizable``), estimate errors (``EstimateScaling``), simulation (``Simulatable``, ``Scaled``,
``AnalysedLoop``), Monte-Carlo (``MonteCarlo``: its ``montecarlo`` module) and the open-loop start
(``OpenLoopStart``). Shared code asks for one by its Protocol; a command that needs one the family
lacks says so in one line (:class:`CapabilityError`, ``capabilities.require``).
"""

from __future__ import annotations

import importlib
import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, TypeVar, runtime_checkable

import numpy as np
from sensorless.design.gain_set import GainSet  # its own module (runtime.py imports it); read here too

if TYPE_CHECKING:  # the result types below import this module: typed by name only where no cycle
    from numpy.typing import ArrayLike
    from sensorless.design.linearization import Linearization
    from sensorless.design.runtime import RuntimeSetup


class CapabilityError(ValueError):
    """A family lacks what was asked of it; the message names the family and the capability."""


class Drive(Protocol):
    """What shared code reads of any family's drive description (each family adds its own sections)."""

    # read-only (a family's drive is a frozen dataclass)
    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def source(self) -> str: ...
    @property
    def file(self) -> str:
        """The file it was loaded from (or "preset:<name>"), for messages."""
        ...

    @property
    def digest(self) -> str:
        """sha256 of the TOML text."""
        ...

    @property
    def warnings(self) -> tuple[str, ...]:
        """Plausibility findings of its drive file (design/plausibility.py), one line each: every command
        prints them (reports/cli/common.py); () where there are none."""
        ...

    @property
    def T_N(self) -> float:
        """Nominal torque [N m]."""
        ...

    @property
    def w_base(self) -> float:
        """Per-unit speed base [rad/s, electrical]."""
        ...

    @property
    def pole_pairs(self) -> int:
        """Pole pairs (mechanical r/min <-> electrical rad/s)."""
        ...

    @property
    def T_s(self) -> float:
        """Sampling period of the runtime observer [s]."""
        ...


class GainTableData(Protocol):
    """What a family reads of a gain table (design/gain_table.GainTable, which imports the registry)."""

    @property
    def law(self) -> str: ...
    @property
    def drive(self) -> dict[str, str]: ...
    @property
    def gains(self) -> dict[str, Any]: ...
    @property
    def envelope(self) -> dict[str, Any]: ...
    @property
    def points(self) -> list[dict[str, Any]]: ...
    @property
    def summary(self) -> dict[str, Any]: ...
    @property
    def file(self) -> str: ...

    def where(self, table_file: str = "") -> str:
        """How messages name the table."""
        ...


@dataclass(frozen=True)
class TraceLine:
    """One line of a trace panel: the first of ``traces`` (recorded trace names) that the run has,
    drawn with the matplotlib format ``style`` and the legend entry ``label``."""

    traces: tuple[str, ...]
    style: str  # e.g. "k-", "k--", "k:"
    label: str  # legend entry (TeX)


@dataclass(frozen=True)
class Panel:
    """A trace panel of a family's own (a scenario's ``figure`` names it): what it shows, in which unit,
    and its lines over time, drawn by the shared figure code (reports/sim_figure.py). The panels every
    drive has (speed, torque, position error) are the shared ones of design/scenario.py."""

    name: str  # the name in a scenario's figure list
    unit: str  # SI unit of the values drawn
    meaning: str  # one line: what it shows (cited where it is a paper's figure)
    ylabel: str  # axis label
    lines: tuple[TraceLine, ...]


@dataclass(frozen=True)
class PerUnitBases:
    """A drive's per-unit bases by dimension (the drive-file field metadata ``dim``: angular, voltage,
    current, resistance, inductance, flux) and one line saying what they are, for reports."""

    values: Mapping[str, float]
    note: str


@dataclass(frozen=True)
class DriveScales:
    """What scales a drive's generic time-domain scenarios (design/scenario.py ``generic_scenarios``):
    its rated torque, torque limit, inertia, pole pairs, base speed and speed-loop bandwidth, and
    whether its observer may be taken through zero speed."""

    T_N: float  # rated torque [N m]
    T_max: float  # torque limit [N m]
    J: float  # moment of inertia [kg m^2]
    pole_pairs: int
    w_base: float  # 1 p.u. speed [rad/s, electrical]
    alpha_s: float  # speed-loop bandwidth [rad/s]
    # "" where the observer runs through zero speed in closed loop; else why it does not (cited): the
    # generic speed steps then stay above zero and the report does not hold it to a reversal
    zero_speed: str = ""
    # where zero_speed is given: whether the drive still starts once from standstill by its open-loop
    # start (a firmware that spins up and never returns to open loop): the generic start stays a check
    spins_up: bool = False
    # a speed [rad/s] the observer holds by a low-speed mechanism of its own (an HF injection), and for how
    # long [s]: the generic ``low_hold`` holds it unloaded, speed loop closed on the estimate, from an angle
    # error of HOLD_ERROR (design/scenario.py); 0: none
    hold_speed: float = 0.0
    hold_time: float = 0.0
    # the speed reference's rate limit [rad/s^2 electrical] (the drive file's [control] speed_ramp,
    # symbolic/speed_ramp.py); 0: none, a step of the reference asks for the torque limit
    speed_ramp: float = 0.0

    @property
    def t_acc(self) -> float:
        """Time [s] to change the speed by 1 p.u. against the rated load at the torque limit, or along
        the speed reference's ramp where that is slower (the generic segments then hold the ramp)."""
        t = self.J * self.w_base / self.pole_pairs / max(self.T_max - self.T_N, 0.1 * self.T_N)
        return max(t, self.w_base / self.speed_ramp) if self.speed_ramp > 0 else t

    def braking(self, torque: float | np.ndarray) -> float | np.ndarray:
        """The largest speed change [rad/s^2 electrical] at load ``torque``: the speed loop at the torque
        limit with the load helping, p (T_max + |T|) / J, or the speed reference's ramp where that is
        lower (the drive then is never asked for more than the ramp, but in a transient)."""
        a = self.pole_pairs * (self.T_max + np.abs(np.asarray(torque, float))) / self.J
        return np.minimum(a, self.speed_ramp) if self.speed_ramp > 0 else a

    @property
    def tau_m(self) -> float:
        """Mechanical time constant [s]: 1 p.u. of speed at rated torque."""
        return self.J * self.w_base / self.pole_pairs / self.T_N


@dataclass(frozen=True)
class EstimateErrors:
    """The estimate errors a design is tuned and reviewed for: a box of relative errors (+-) on the
    observer's estimates, judged at its centre (the drive file's estimates) and every corner. ``box``
    labels -> relative error (e.g. {"R_s": 0.3, "L": 0.2}); ``keys`` the ``estimate_keys`` a label
    scales together (default: the label itself); ``source`` where they are stated (one clause)."""

    box: Mapping[str, float] = field(default_factory=dict)
    keys: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    source: str = ""

    def __bool__(self) -> bool:
        return any(v > 0 for v in self.box.values())

    def cases(self) -> list[dict[str, float]]:
        """The centre ({}: no factor) and every corner of the box, as factors on ``estimate_keys``."""
        labels = [k for k, v in self.box.items() if v > 0]
        out: list[dict[str, float]] = [{}]
        for signs in itertools.product((1, -1), repeat=len(labels)):
            case: dict[str, float] = {}
            for lab, s in zip(labels, signs, strict=True):
                case.update(dict.fromkeys(self.keys.get(lab, (lab,)), 1 + s * self.box[lab]))
            out.append(case)
        return out if labels else [{}]

    def text(self) -> str:
        """E.g. "R_s +-30 %, L +-20 %" ("" where none)."""
        return ", ".join(f"{k} +-{100 * v:g} %" for k, v in self.box.items() if v > 0)


DriveT = TypeVar("DriveT", bound=Drive)  # a family's own drive dataclass


class ObserverFamily(Generic[DriveT]):
    """Base class of an observer family, generic in its drive type: the core every family has (module
    docstring); what it may have beyond, each a Protocol of design/capabilities.py, it has by defining
    the Protocol's methods."""

    kind: ClassVar[str]  # the drive files' [drive] kind: written nowhere else
    name: ClassVar[str]  # identifier = folder name in symbolic/, design/, tuning/, reports/
    title: ClassVar[str]  # one line: what the observer is
    citation: ClassVar[str]  # the paper(s) it implements, authors and year
    presets: ClassVar[str | None] = None  # package holding preset drive TOMLs
    scenarios: ClassVar[str | None] = None  # package holding built-in scenario TOMLs
    tuning: ClassVar[str | None] = None  # module of its tuning hooks (sensorless.tuning.family)
    report: ClassVar[str | None] = None  # module of its report hooks (sensorless.reports.family)
    # gain law (a gain table's "law") -> required keys of the table's "gains" (docs/gain_tables.md)
    laws: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    # former law name -> its name now: still read from gain tables and the command line, with a note
    law_aliases: ClassVar[Mapping[str, str]] = {}
    # extra scenario keys: section -> key -> (dimension, default); see design/scenario.py
    scenario_options: ClassVar[Mapping[str, Mapping[str, tuple[str, Any]]]] = {}
    # the keys of a scenario's [estimate_scale]: factors (default 1) on the drive's parameter
    # estimates that its simulation applies (docs/simulation.md)
    estimate_keys: ClassVar[tuple[str, ...]] = ()
    # the trace panels of its own, beyond the shared ones (design/scenario.py GENERIC_PANELS)
    panels: ClassVar[tuple[Panel, ...]] = ()
    # the worst damping its designs must keep where a command is given no --min-damping (`report`, the
    # minimum-speed analysis, `montecarlo`'s yield); None: the shared design/poles.py MIN_DAMPING. A
    # family whose observer's damping falls with speed by design states its own (and judges its gains
    # by a criterion of its own: tuning/family.py TuneOutcome.shortfalls)
    required_damping: ClassVar[float | None] = None

    def min_damping(self) -> float:
        """The damping its designs must keep by default (``required_damping``, else MIN_DAMPING)."""
        from sensorless.design.poles import MIN_DAMPING

        return MIN_DAMPING if self.required_damping is None else float(self.required_damping)

    # ---------------------------------------------------------------------------------- drive file
    def load(self, data: Mapping[str, Any], file: str, digest: str) -> DriveT:
        """The drive of a parsed TOML document (strict; DriveFileError naming file and key)."""
        raise CapabilityError(f"observer family {self.name!r} cannot load drive files")

    # --------------------------------------------------------------------------------------- gains
    def gains(
        self,
        drive: DriveT,
        *,
        name: str | None = None,
        table: GainTableData | None = None,
        table_file: str = "",
    ) -> GainSet:
        """The gains of ``drive``: from the gain table ``table`` if given, else the drive file's
        (``name`` chooses among several gain sections where the family has them)."""
        raise CapabilityError(f"observer family {self.name!r} has no gains to choose")

    # ------------------------------------------------------------------------------------- runtime
    def runtime(self, drive: DriveT, gains: GainSet, *, discretization: str | None = None) -> RuntimeSetup:
        """The runtime set-up (design/runtime.py): observer step, parameters, schedule."""
        raise CapabilityError(f"observer family {self.name!r} has no runtime observer")

    # ------------------------------------------------------------------ low speed (design/low_speed.py)
    def low_speed_options(self, drive: DriveT) -> dict[str, Any]:
        """The :meth:`linearize` options of the minimum-speed analysis (design/low_speed.py): what the
        drive runs at low speed (e.g. its HF injection) and the family's noise model; none here."""
        return {}

    def holds_zero_speed(self, drive: DriveT) -> bool:
        """Whether the drive's observer holds zero speed under load by itself (e.g. on HF injection into
        a salient motor): then it needs no open-loop start (design/startup.py); False here."""
        return False

    def low_speed_reason(self, drive: DriveT) -> str:
        """Why the drive's observer cannot hold zero speed, the physics in one clause (e.g. "non-salient
        motor: rotor position unobservable at zero frequency"); "" where it can or the family does not
        say."""
        return ""

    def estimate_errors(self, drive: DriveT) -> EstimateErrors:
        """The estimate errors the drive's design is tuned and reviewed for (its drive file's, or its
        tuner's defaults): the minimum-speed analysis judges the angle bias under them
        (design/low_speed.py); none here."""
        return EstimateErrors()

    # -------------------------------------------------------------------------- reports and traces
    def bases(self, drive: DriveT) -> PerUnitBases | None:
        """The drive's per-unit bases (the report's drive-data tables show values in them); None where
        its drive files define none."""
        return None

    def trace_notes(self, meta: Mapping[str, Any]) -> tuple[str, ...]:
        """What the header of a run's traces says of the family's own settings of the run (its loop
        set-up's ``meta``), one clause each (reports/traces.py); none here."""
        return ()

    def __repr__(self) -> str:
        return f"<observer family {self.name} (kind {self.kind!r})>"


D = TypeVar("D", bound=Drive, contravariant=True)  # a drive the capability takes
E = TypeVar("E", bound=Drive)  # a drive it takes and returns
C = TypeVar("C")


@runtime_checkable
class Scaled(Protocol[D]):
    """The capability to give the scales of the generic scenarios (design/scenario.py
    ``generic_scenarios``); here beside its result type, like every capability (design/capabilities.py)."""

    def scales(self, drive: D) -> DriveScales:
        """The drive's torques, inertia, pole pairs, base speed and speed-loop bandwidth."""
        ...


@runtime_checkable
class Linearizable(Protocol[D]):
    """Linearizes its observer about the drive's operating points (design/linearization.py)."""

    def linearize(
        self, drive: D, gains: GainSet, w: ArrayLike, torque: ArrayLike, **options: Any
    ) -> Linearization:
        """The linearization at speeds ``w`` [rad/s, electrical] x ``torque`` [N m]."""
        ...


@runtime_checkable
class EstimateScaling(Protocol[E]):
    """Takes stated estimate errors into its analysis (the minimum-speed analysis under errors)."""

    def with_estimate_errors(self, drive: E, factors: Mapping[str, float]) -> E:
        """The drive with its observer's estimates scaled by ``factors`` (keys of ``estimate_keys``)."""
        ...


# what a command's one line says (after "observer family NAME") where the family lacks a capability
# it needs; each capability's module adds its own (design/simulate.py, design/capabilities.py)
LACKS: dict[type, str] = {
    Linearizable: "has no linearization",
    EstimateScaling: "takes no estimate errors in its analysis",
    Scaled: "gives no scales for generic scenarios",
}


def require(family: ObserverFamily[Any], capability: type[C]) -> C:
    """``family`` as a holder of ``capability`` (a runtime-checkable Protocol); else a one-line
    CapabilityError naming the family and what it lacks (:data:`LACKS`)."""
    if not isinstance(family, capability):
        raise CapabilityError(f"observer family {family.name!r} {LACKS[capability]}")
    return family


@dataclass(frozen=True)
class Later:
    """The function ``name`` of ``module``, imported at the first call (:func:`later`); a record of two
    names, so that it pickles as the function does."""

    module: str
    name: str

    def __call__(self, *args: object, **kwargs: object) -> object:
        return getattr(importlib.import_module(self.module), self.name)(*args, **kwargs)


def later(module: str, *names: str) -> object:
    """Functions ``names`` of ``module``, which each imports at its first call (one name: the function;
    several: a tuple). A family's hook modules (``tuning``, ``report``) name what they compute with this
    way: every command reads every registered family's hooks for its options and laws, and computes with
    one family's. Write the real import beside it under ``TYPE_CHECKING`` so that the type checker reads
    the functions' signatures and the import checks see the dependency (docs/architecture.md)."""
    found = tuple(Later(module, n) for n in names)
    return found[0] if len(found) == 1 else found
