"""Speed-adaptive stator-flux observer for interior PMSMs (Piippo, Hinkkanen, Luomi 2008): the family.

This module registers the family (design/registry.py finds ``FAMILY``); the drive kind string of its
drive files is written here and nowhere else in the code. Its pieces: schema.py (the drive file's
sections), derive.py (a minimal drive file completed, and loading), runtime.py (gains, runtime
set-up), operating_point.py and linearize.py (the closed loop of Section IV), one_step.py (the step
that runs, by the shared discrete-time analysis of design/discrete.py), simulation.py (Fig. 7 for a
scenario), presets/ and scenarios/ (the paper's drive and experiments).
Equations: symbolic/ipmsm_adaptive/. Theory and choices: docs/families/ipmsm_adaptive.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from sensorless.design.family import (
    CapabilityError,
    DriveScales,
    EstimateErrors,
    GainSet,
    GainTableData,
    ObserverFamily,
    PerUnitBases,
)
from sensorless.design.ipmsm_adaptive import runtime as _runtime
from sensorless.design.ipmsm_adaptive import schema, simulation
from sensorless.design.ipmsm_adaptive.runtime import with_alpha_fo
from sensorless.design.ipmsm_adaptive.simulation import injection_off
from sensorless.design.law_gains import table_gains

if TYPE_CHECKING:  # typed by name only
    from numpy.typing import ArrayLike
    from sensorless.design.capabilities import MonteCarloModule
    from sensorless.design.drive_file import DriveDocument
    from sensorless.design.ipmsm_adaptive.linearize import PoleSweep
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.design.simulate import LoopSetup
    from sensorless.design.startup import StartupSettings


class AdaptiveFluxObserver(ObserverFamily[schema.IpmsmDrive]):
    """The speed-adaptive stator-flux observer with gain (7)/(16), PI adaptation and HF injection."""

    kind = "ipmsm-adaptive"
    name = "ipmsm_adaptive"
    title = "speed-adaptive stator-flux observer with HF injection, for (interior) PMSMs"
    citation = "Piippo, Hinkkanen, Luomi (2008)"
    presets = "sensorless.design.ipmsm_adaptive.presets"
    scenarios = "sensorless.design.ipmsm_adaptive.scenarios"
    tuning = "sensorless.tuning.ipmsm_adaptive"
    report = "sensorless.reports.ipmsm_adaptive"
    laws = _runtime.TABLE_LAWS
    law_aliases = _runtime.LAW_ALIASES
    scenario_options = simulation.SCENARIO_OPTIONS
    estimate_keys = simulation.SCENARIO_ESTIMATE_KEYS
    panels = simulation.PANELS

    # the modules below are imported by the methods that use them: every command registers every family,
    # and one that does not load, linearize or spread this family's drives need not import them

    @property
    def montecarlo(self) -> MonteCarloModule[schema.IpmsmDrive]:
        """Monte-Carlo: the electrical parameters and J, spread in one batched linearization."""
        from sensorless.design.ipmsm_adaptive import montecarlo

        return montecarlo

    def load(self, data: Mapping[str, Any], file: str, digest: str) -> schema.IpmsmDrive:
        from sensorless.design.ipmsm_adaptive import derive

        return derive.load(data, file, digest, self.kind)

    def document(self, data: Mapping[str, Any], file: str) -> DriveDocument:
        """The complete drive document of a (minimal) drive file (derive.py; ``sensorless init``)."""
        from sensorless.design.ipmsm_adaptive import derive

        return derive.document(data, file)

    def gains(
        self,
        drive: schema.IpmsmDrive,
        *,
        name: str | None = None,
        table: GainTableData | None = None,
        table_file: str = "",
    ) -> GainSet:
        if table is None:
            return _runtime.drive_gains(drive, name)
        if name is not None:
            raise CapabilityError("a gain table holds the gains: name no [observer.gains.*] with it")
        return table_gains(self, drive, table, table_file, values=_runtime.table_values)

    def runtime(
        self, drive: schema.IpmsmDrive, gains: GainSet, *, discretization: str | None = None
    ) -> RuntimeSetup:
        return _runtime.runtime_setup(drive, gains, discretization)

    def linearize(
        self, drive: schema.IpmsmDrive, gains: GainSet, w: ArrayLike, torque: ArrayLike, **options: Any
    ) -> PoleSweep:
        """Closed-loop poles (design/ipmsm_adaptive/linearize.py); options: injection, estimate, and
        discretization (with T_s): also the discrete-time observer that runs (one_step.py)."""
        from sensorless.design.ipmsm_adaptive import one_step

        if options.get("injection") and not drive.injection.enabled:
            raise CapabilityError(injection_off(drive))
        return one_step.linearize(
            with_alpha_fo(drive, gains), w, torque, gain=_runtime.law_of(gains), **options
        )

    def low_speed_options(self, drive: schema.IpmsmDrive) -> dict[str, Any]:
        """Its HF injection where the drive injects (it runs at low speed), and its noise model."""
        return {"injection": bool(drive.injection.enabled), "noise": True}

    def holds_zero_speed(self, drive: schema.IpmsmDrive) -> bool:
        """On HF injection (a salient motor the current sensor sees): Piippo et al. (2008) Sec. V."""
        return bool(drive.injection.enabled)

    def low_speed_reason(self, drive: schema.IpmsmDrive) -> str:
        """Without HF injection the flux observer sees the rotor only through its back-EMF."""
        if drive.injection.enabled:
            return ""
        return (
            "no HF injection (a non-salient motor, or a saliency the current sensor cannot see): the rotor "
            "position is unobservable at zero frequency, where the back-EMF vanishes"
        )

    def estimate_errors(self, drive: schema.IpmsmDrive) -> EstimateErrors:
        """Its [tuning] errors: the box the shared tuner keeps gains stable over (tuning/conditions.py)."""
        return drive.tuning.estimate_errors()

    def with_estimate_errors(
        self, drive: schema.IpmsmDrive, factors: Mapping[str, float]
    ) -> schema.IpmsmDrive:
        """[estimate] R_s, L_d, L_q, psi_pm scaled (J only enters the simulated speed controller)."""
        e = drive.estimate
        new = {k: getattr(e, k) * float(v) for k, v in factors.items() if k in e.__dataclass_fields__}
        return dataclasses.replace(drive, estimate=dataclasses.replace(e, **new))

    def bases(self, drive: schema.IpmsmDrive) -> PerUnitBases:
        """The [base] section: speed w, voltage u, current i, impedance Z = u/i, flux psi = u/w."""
        b = drive.base
        values = {
            "angular": b.w,
            "voltage": b.u,
            "current": b.i,
            "resistance": b.Z,
            "inductance": b.Z / b.w,
            "flux": b.psi,
        }
        note = (
            "Per-unit bases: speed = [base] w, voltage = [base] u, current = [base] i, impedance = u/i, "
            "flux = u/w."
        )
        return PerUnitBases(values, note)

    def scales(self, drive: schema.IpmsmDrive) -> DriveScales:
        c, inj = drive.control, drive.injection
        # with injection: hold a third of its fade-out (carrier at 2/3) for 20 / alpha_i (the PI (21)-(22))
        hold_speed, hold_time = (inj.w_Delta / 3, 20 / inj.alpha_i) if inj.enabled else (0.0, 0.0)
        return DriveScales(
            drive.T_N,
            c.T_max,
            drive.motor.J,
            drive.motor.p,
            drive.w_base,
            c.alpha_s,
            hold_speed=hold_speed,
            hold_time=hold_time,
            speed_ramp=c.speed_ramp,
        )

    def simulation(self, drive: schema.IpmsmDrive, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        return simulation.build(drive, scenario, gains)

    def drive_loop(self, drive: schema.IpmsmDrive, scenario: Scenario, gains: GainSet | None) -> LoopSetup:
        return simulation.analysed_loop(drive, scenario, gains)

    def trace_notes(self, meta: Mapping[str, Any]) -> tuple[str, ...]:
        """The run's HF-injection switch (simulation.build puts it in the provenance)."""
        notch = meta.get("speed_notch")
        band = (
            f", speed feedback band-stopped at the carrier (its loop would feed back G = {notch})"
            if notch
            else ""
        )
        return (f"HF injection {'on' if meta['injection'] else 'off'}{band}",)

    # the open-loop I-f start (design/startup.py): its drive files' optional [startup] section
    def startup(self, drive: schema.IpmsmDrive) -> StartupSettings | None:
        return drive.startup

    def with_startup(self, drive: schema.IpmsmDrive, startup: StartupSettings | None) -> schema.IpmsmDrive:
        return dataclasses.replace(drive, startup=startup)


FAMILY = AdaptiveFluxObserver()
