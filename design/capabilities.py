"""The capabilities an observer family may have beyond the core contract, as small typed Protocols.

The core every family has is :class:`~sensorless.design.family.ObserverFamily` (its drive files, its
gains, its runtime observer). Everything else a command may ask is one capability here, a
``runtime_checkable`` Protocol a family has by defining its methods (or, for Monte-Carlo, by naming the
module that does it: ``montecarlo``, a :class:`MonteCarloModule`): shared code asks for it by the
Protocol (``isinstance(fam, Linearizable)``, or :func:`require` where the command needs it and says so
in one line), never by calling and catching. A family that has the capability may still refuse one
drive (e.g. a firmware variant that is not linearizable): that refusal stays a
:class:`~sensorless.design.family.CapabilityError` naming the drive's setting.

Each Protocol is generic in the family's drive type, so a family states its own drive dataclass in
its methods and the type checker holds it to the contract (tests/common/test_types.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

from sensorless.design.family import (
    LACKS,
    Drive,
    EstimateScaling,
    GainSet,
    Linearizable,
    Scaled,
    require,
)
from sensorless.design.simulate import AnalysedLoop, Simulatable

if TYPE_CHECKING:  # typed by name only: these modules import the family contract
    import numpy as np
    from sensorless.design.drive_file import DriveDocument
    from sensorless.design.linearization import Linearization
    from sensorless.design.montecarlo import Uncertain
    from sensorless.design.startup import StartupSettings

D = TypeVar("D", bound=Drive, contravariant=True)  # a drive the capability takes
E = TypeVar("E", bound=Drive)  # a drive it takes and returns

# the capabilities typed beside their result types (a module that checks for one must not import this
# one: design/scenario.py, design/simulate.py), gathered here
__all__ = [
    "AnalysedLoop",
    "Documented",
    "EstimateScaling",
    "Linearizable",
    "MonteCarlo",
    "OpenLoopStart",
    "Scaled",
    "Simulatable",
    "require",
]


@runtime_checkable
class Documented(Protocol):
    """Derives a complete drive file from a minimal one (``sensorless init``)."""

    def document(self, data: Mapping[str, Any], file: str) -> DriveDocument:
        """The complete drive document of a parsed drive TOML that may give only the minimal data
        (motor, rating, inverter): every other value derived by the family's rules, each with its rule."""
        ...


@runtime_checkable
class MonteCarloModule(Protocol[E]):
    """What spreads a family's drive parameters over draws: the functions of its Monte-Carlo module
    (design/<family>/montecarlo.py satisfies this Protocol as a module: one place per family, no
    forwarding methods on the family)."""

    def parameters(self, drive: E) -> tuple[Uncertain, ...]:
        """The parameters a run may spread, in the column order of the draws."""
        ...

    def linearize_draws(
        self,
        drive: E,
        gains: GainSet,
        plant: np.ndarray,
        estimate: np.ndarray,
        w: np.ndarray,
        torque: np.ndarray,
        complete: bool = True,
    ) -> Linearization:
        """Every draw (rows of ``plant``, ``estimate``) at every point (``w`` x ``torque``), draw-major,
        in one batched evaluation; ``complete`` False: a draw may be NaN from its first point without
        equilibrium on."""
        ...

    def envelope_points(self, drive: E, gains: GainSet | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(w [rad/s, electrical], torque [N m]): the points every draw is judged at."""
        ...

    def perturbed(self, drive: E, plant: Mapping[str, float], estimate: Mapping[str, float]) -> E:
        """``drive`` with the true motor's and the observer's parameters replaced (SI values)."""
        ...


@runtime_checkable
class MonteCarlo(Protocol[E]):
    """Spreads its drive's parameters over draws (design/montecarlo.py, ``sensorless montecarlo``)."""

    @property
    def montecarlo(self) -> MonteCarloModule[E]:
        """Its Monte-Carlo module (design/<family>/montecarlo.py; a property may import it when read)."""
        ...


@runtime_checkable
class OpenLoopStart(Protocol[E]):
    """Starts its drives open loop (the I-f start, design/startup.py) below their minimum sensorless
    speed: its drive files take a ``[startup]`` section, which ``sensorless init`` writes."""

    def startup(self, drive: E) -> StartupSettings | None:
        """The drive file's ``[startup]`` section (None: the rules give every value)."""
        ...

    def with_startup(self, drive: E, startup: StartupSettings | None) -> E:
        """The drive with ``startup`` as its ``[startup]`` section."""
        ...


LACKS.update(
    {
        Documented: "reads no minimal drive files (`sensorless init`): write its drive file in full, "
        "starting from a copy of its preset",
        MonteCarlo: "declares no parameters to spread (montecarlo)",
        OpenLoopStart: "has no open-loop start",
    }
)
