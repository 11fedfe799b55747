"""Extended reduced-order EMF and load-torque observer for PM AC motors (De Angelo et al. 2006): the family.

This module registers the family (design/registry.py finds ``FAMILY``); the drive kind string of its
drive files is written here and nowhere else in the code. Its pieces: schema.py (drive files),
motor.py (its [motor] in datasheet terms), derive.py (complete drive files from minimal ones,
``sensorless init``, and loading), runtime.py (gains, runtime set-up), linearize.py (continuous and
discrete error dynamics), discretization.py (the sampling study), simulation.py (Fig. 1 for a
scenario), presets/ and scenarios/.
Equations: symbolic/pmac_reduced_order/. Theory and choices: docs/families/pmac_reduced_order.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from sensorless.design.family import CapabilityError, DriveScales, GainSet, GainTableData, ObserverFamily
from sensorless.design.law_gains import table_gains
from sensorless.design.pmac_reduced_order import runtime as _runtime
from sensorless.design.pmac_reduced_order import schema, simulation

if TYPE_CHECKING:  # typed by name only
    from numpy.typing import ArrayLike
    from sensorless.design.capabilities import MonteCarloModule
    from sensorless.design.drive_file import DriveDocument
    from sensorless.design.pmac_reduced_order.linearize import ObserverPoles
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.design.simulate import LoopSetup


class ReducedOrderObserver(ObserverFamily[schema.PmacDrive]):
    """The extended reduced-order observer of the EMF (with harmonics) and the load torque."""

    kind = "pmac-reduced-order"
    name = "pmac_reduced_order"
    title = "extended reduced-order EMF and load-torque observer, for PM AC motors with EMF harmonics"
    citation = "De Angelo, Bossio, Solsona, Garcia, Valla (2006)"
    presets = "sensorless.design.pmac_reduced_order.presets"
    scenarios = "sensorless.design.pmac_reduced_order.scenarios"
    tuning = "sensorless.tuning.pmac_reduced_order"
    report = "sensorless.reports.pmac_reduced_order"
    laws = _runtime.TABLE_LAWS
    law_aliases = _runtime.LAW_ALIASES
    scenario_options = simulation.SCENARIO_OPTIONS
    estimate_keys = simulation.SCENARIO_ESTIMATE_KEYS
    panels = simulation.PANELS

    # the modules below are imported by the methods that use them: every command registers every family,
    # and one that does not load, linearize or spread this family's drives need not import them

    @property
    def montecarlo(self) -> MonteCarloModule[schema.PmacDrive]:
        """Monte-Carlo: its motor's and estimates' parameters, linearized on the exact-estimate orbit."""
        from sensorless.design.pmac_reduced_order import montecarlo

        return montecarlo

    def load(self, data: Mapping[str, Any], file: str, digest: str) -> schema.PmacDrive:
        from sensorless.design.pmac_reduced_order import derive

        return derive.load(data, file, digest, self.kind)

    def document(self, data: Mapping[str, Any], file: str) -> DriveDocument:
        """The complete drive document of a (minimal) drive file (derive.py; ``sensorless init``)."""
        from sensorless.design.pmac_reduced_order import derive

        return derive.document(data, file)

    def gains(
        self,
        drive: schema.PmacDrive,
        *,
        name: str | None = None,
        table: GainTableData | None = None,
        table_file: str = "",
    ) -> GainSet:
        if name is not None:
            raise CapabilityError(
                f"{drive.file}: this observer has one set of gains ([observer] g, Gamma); there is no "
                f"[observer.gains.{name}] to choose"
            )
        if table is None:
            return _runtime.drive_gains(drive)
        return table_gains(self, drive, table, table_file, values=_runtime.table_values)

    def runtime(
        self, drive: schema.PmacDrive, gains: GainSet, *, discretization: str | None = None
    ) -> RuntimeSetup:
        return _runtime.runtime_setup(drive, gains, discretization)

    def linearize(
        self, drive: schema.PmacDrive, gains: GainSet, w: ArrayLike, torque: ArrayLike, **options: Any
    ) -> ObserverPoles:
        """Observer poles, continuous and discrete (linearize.analyze); ``torque`` is the load T_L.

        Options: load_estimation, method, T_s, settle_time, n_angles."""
        from sensorless.design.pmac_reduced_order.linearize import analyze

        g = gains.values
        return analyze(drive, w, torque, g=g["g"], Gamma=g["Gamma"], **options)

    def low_speed_options(self, drive: schema.PmacDrive) -> dict[str, Any]:
        """Its noise model, and the discrete observer's steady errors (the angle bias) where the
        estimates differ from the motor (exact, the bias is the discretization's, below 1e-9 rad on
        the examples, and simulating the error window at low speed costs seconds per point)."""
        e, m = drive.estimate, drive.motor
        exact = (e.R, e.L, tuple(e.Phi)) == (m.R, m.L, tuple(m.Phi))
        # exact, the analysis starts on the observer's steady orbit: a short settling will do
        return {"noise": True, "errors": not exact, **({"settle_time": 0.05} if exact else {})}

    def low_speed_reason(self, drive: schema.PmacDrive) -> str:
        """An EMF observer: the position is unobservable where the EMF vanishes."""
        return "an EMF observer: the rotor position is unobservable at zero frequency, where the EMF vanishes"

    def with_estimate_errors(self, drive: schema.PmacDrive, factors: Mapping[str, float]) -> schema.PmacDrive:
        """[estimate] R, L (key L_d, as on a PMSM), J and the EMF harmonics Phi scaled."""
        e = drive.estimate
        k = {key: float(factors.get(key, 1.0)) for key in ("R_s", "L_d", "J", "Phi")}
        est = dataclasses.replace(
            e, R=e.R * k["R_s"], L=e.L * k["L_d"], J=e.J * k["J"], Phi=tuple(x * k["Phi"] for x in e.Phi)
        )
        return dataclasses.replace(drive, estimate=est)

    def scales(self, drive: schema.PmacDrive) -> DriveScales:
        c = drive.control
        m = drive.motor
        return DriveScales(drive.T_N, c.T_max, m.J, drive.pole_pairs, drive.w_base, c.alpha_s, ZERO_SPEED)

    def simulation(self, drive: schema.PmacDrive, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        return simulation.build(drive, scenario, gains)

    def drive_loop(self, drive: schema.PmacDrive, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        return simulation.analysed_loop(drive, scenario, gains)

    def trace_notes(self, meta: Mapping[str, Any]) -> tuple[str, ...]:
        """No HF injection: said as the traces' header has always said it (the same trace files)."""
        return ("HF injection off",)


# De Angelo et al. (2006), Sec. V (Fig. 10): like other EMF-based observers it "cannot be used at very
# low or zero speed"; the paper reverses through zero with an open-loop procedure, not modelled here
ZERO_SPEED = (
    "The reduced-order EMF observer does not run through zero speed in closed loop: De Angelo et al. "
    "(2006), Sec. V, reverse with an open-loop procedure that this family does not model."
)

FAMILY = ReducedOrderObserver()
