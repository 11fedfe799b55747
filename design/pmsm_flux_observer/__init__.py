"""The nonlinear flux observer + PLL that VESC, ODrive and SimpleFOC run (Lee et al. 2010): the family.

This module registers the family; the drive kind string is written here and nowhere else. Its pieces:
schema.py (drive files: a minimal file completed by rules), gains.py (the laws constant, voltage-scaled,
schedule and the runtime set-up), linearize.py (continuous and discrete poles), simulation on the shared PMSM
drive loop (below), presets/ and scenarios/. Equations: symbolic/pmsm_flux_observer/. Theory and
choices: docs/families/pmsm_flux_observer.md.
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
)
from sensorless.design.law_gains import table_gains
from sensorless.design.pmsm_drive import CURRENT_PANEL, ESTIMATE_KEYS, loop_setup
from sensorless.design.pmsm_flux_observer import laws as _laws
from sensorless.design.pmsm_flux_observer import schema
from sensorless.design.simulate import StateFrames

if TYPE_CHECKING:  # typed by name only
    from numpy.typing import ArrayLike
    from sensorless.design.capabilities import MonteCarloModule
    from sensorless.design.drive_file import DriveDocument
    from sensorless.design.pmsm_flux_observer.linearize import FluxLinearization
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.design.simulate import LoopSetup
    from sensorless.design.startup import StartupSettings


def simulation(drive: schema.FluxObserverDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """The loop set-up of ``sc``: the scenario's estimate errors scale the observer's model as the
    controllers'."""
    from sensorless.design.pmsm_flux_observer import gains as _gains

    k = sc.estimate_scale
    setup = _gains.runtime_setup(drive, gains or _gains.drive_gains(drive), sc.discretization)
    params = dict(setup.params)
    for key in ("R_s", "L_d", "L_q", "psi_pm"):
        params[key] = params[key] * k.get(key, 1.0)
    setup.observer.check_params(params)
    setup = dataclasses.replace(setup, params=params)
    meta = {
        "gain": f"{setup.gain_source}: law {setup.gains.law}, {drive.observer.correction}, "
        f"{drive.observer.inductance_rule} inductance, T_obs = {drive.observer.T_obs * 1e6:.6g} us"
    }
    frames = FRAMES if drive.observer.lambda_adaptation else FRAMES_FIXED
    return loop_setup(drive, sc, setup, meta=meta, frames=frames)


# how the observer's state turns with the rotor (the whole-drive linearization, design/drive_analysis.py):
# the flux state and the stored voltage are stationary-frame vectors, the PLL angle an angle; the flux
# linkage estimate is a constant where it is not adapted
FRAMES = StateFrames(angles=("theta_pll",), vectors=(("x_alpha", "x_beta"), ("u_prev_alpha", "u_prev_beta")))
FRAMES_FIXED = dataclasses.replace(FRAMES, held=("lambda_hat",))


# ODrive's sensorless mode (odriverobotics/ODrive v0.5, Firmware/MotorControl/axis.cpp, state
# AXIS_STATE_SENSORLESS_CONTROL): one open-loop spin-up (run_lockin_spin on config.sensorless_ramp, "TODO:
# restart if desired"), the speed setpoint set to the ramp's vel, then the sensorless control loop until an
# error or another state: it never returns to open loop, so it has no w_off and runs through no zero speed
ODRIVE_ONE_WAY = (
    "ODrive's sensorless mode spins up once by its open-loop ramp (axis0.config.sensorless_ramp) and then "
    "runs closed loop on the observer until the axis leaves the state: it never returns to open loop "
    '(odriverobotics/ODrive, Firmware/MotorControl/axis.cpp; its documentation: sensorless "does not '
    'support stopping or changing direction"). Keep the speed command above the minimum sensorless speed '
    "in one direction; to stop, set the axis to AXIS_STATE_IDLE and spin up again from standstill."
)


# the estimate errors its tuner and its report judge the gains under by default (+-; "L" scales L_d and
# L_q together): docs/families/pmsm_flux_observer.md "Tuning"; `tune --r-error/--flux-error/--l-error`
ERRORS = {"R_s": 0.3, "psi_pm": 0.1, "L": 0.2}
ERROR_KEYS = {"L": ("L_d", "L_q")}


def corner_estimate(estimate: Any, factors: Mapping[str, float]) -> dict[str, float]:
    """The estimates R_s, psi_pm, L_d, L_q of ``estimate`` scaled by one corner of the error box
    (``factors`` on the :data:`ERRORS` keys, "L" on both inductances: :data:`ERROR_KEYS`)."""
    return {
        "R_s": estimate.R_s * factors["R_s"],
        "psi_pm": estimate.psi_pm * factors["psi_pm"],
        "L_d": estimate.L_d * factors["L"],
        "L_q": estimate.L_q * factors["L"],
    }


class FluxObserverFamily(ObserverFamily[schema.FluxObserverDrive]):
    """Lee et al. (2010) gradient flux observer with a PI PLL, in the firmwares' variants."""

    kind = "pmsm-flux-observer"
    name = "pmsm_flux_observer"
    title = "nonlinear flux observer with PLL, as VESC, ODrive and SimpleFOC run it"
    citation = "Lee, Hong, Nam, Ortega, Praly, Astolfi (2010); Ortega et al. (2011)"
    presets = "sensorless.design.pmsm_flux_observer.presets"
    scenarios = "sensorless.design.pmsm_flux_observer.scenarios"
    tuning = "sensorless.tuning.pmsm_flux_observer"
    report = "sensorless.reports.pmsm_flux_observer"
    laws = _laws.TABLE_LAWS
    law_aliases = _laws.LAW_ALIASES
    estimate_keys = ESTIMATE_KEYS
    panels = (CURRENT_PANEL,)
    # its damping k/(2|w|) falls with speed by design (its error does not oscillate in the stationary
    # frame): stable is all it asks of damping; its criterion is decay, angle bias and noise, the PLL's
    # lag (tuning/pmsm_flux_observer/criterion.py)
    required_damping = 0.0

    # the modules below are imported by the methods that use them: every command registers every family,
    # and one that does not load, linearize or spread this family's drives need not import them

    @property
    def montecarlo(self) -> MonteCarloModule[schema.FluxObserverDrive]:
        """Monte-Carlo: the electrical parameters and J, each draw's sampled observer in one batch."""
        from sensorless.design.pmsm_flux_observer import montecarlo

        return montecarlo

    def load(self, data: Mapping[str, Any], file: str, digest: str) -> schema.FluxObserverDrive:
        return schema.load(data, file, digest, self.kind)

    def document(self, data: Mapping[str, Any], file: str) -> DriveDocument:
        return schema.document(data, file)

    def gains(
        self,
        drive: schema.FluxObserverDrive,
        *,
        name: str | None = None,
        table: GainTableData | None = None,
        table_file: str = "",
    ) -> GainSet:
        if name is not None:
            raise CapabilityError(f"{drive.file}: one [gains] section; there is no [gains.{name}] to choose")
        from sensorless.design.pmsm_flux_observer import gains as _gains

        if table is None:
            return _gains.drive_gains(drive)
        T_obs = drive.observer.T_obs

        def values(law: str, gains: Mapping[str, Any], where: str) -> dict[str, Any]:
            return _gains.table_values(law, gains, where, T_obs)

        return table_gains(self, drive, table, table_file, values=values)

    def runtime(
        self, drive: schema.FluxObserverDrive, gains: GainSet, *, discretization: str | None = None
    ) -> RuntimeSetup:
        from sensorless.design.pmsm_flux_observer.gains import runtime_setup

        return runtime_setup(drive, gains, discretization)

    def linearize(
        self, drive: schema.FluxObserverDrive, gains: GainSet, w: ArrayLike, torque: ArrayLike, **options: Any
    ) -> FluxLinearization:
        from sensorless.design.pmsm_flux_observer.linearize import linearize

        unknown = set(options) - {"estimate"}
        if unknown:
            raise CapabilityError(
                f"observer family {self.name!r}: no linearization options {sorted(unknown)}"
            )
        return linearize(drive, gains, w, torque, **options)

    def estimate_errors(self, drive: schema.FluxObserverDrive) -> EstimateErrors:
        """The tuner's default errors (:data:`ERRORS`), which its report judges the gains under too."""
        return EstimateErrors(dict(ERRORS), ERROR_KEYS, "the flux tuner's defaults")

    def with_estimate_errors(
        self, drive: schema.FluxObserverDrive, factors: Mapping[str, float]
    ) -> schema.FluxObserverDrive:
        """[estimate] R_s, L_d, L_q, psi_pm scaled: the runtime parameters the observer runs with."""
        e = drive.estimate
        new = {k: getattr(e, k) * float(v) for k, v in factors.items() if k in e.__dataclass_fields__}
        return dataclasses.replace(drive, estimate=dataclasses.replace(e, **new))

    def scales(self, drive: schema.FluxObserverDrive) -> DriveScales:
        """Its drives are taken through zero speed by the open-loop I-f start below w_min
        (``open_loop_start``), so the generic checks run a start, a reversal and speed steps through
        zero (``zero_speed`` left empty; why the observer needs the start: :meth:`low_speed_reason`).
        Not an ODrive drive: ODrive spins up once and never returns to open loop (:data:`ODRIVE_ONE_WAY`):
        its checks are the start and speed steps above zero (``spins_up``).
        Not the box clamp without ``[startup]`` w_on and w_off: it has no linearization, so no w_min for
        the start's speed rules (design/pmsm_drive.py ``startup_values``)."""
        c = drive.control
        why = ""
        start = drive.startup
        if drive.observer.correction == "box-clamp" and (start is None or start.needs_w_min):
            why = (
                "The box-clamp observer (MXLEMMING) has no linearization, so no minimum sensorless speed "
                "to derive the open-loop I-f start's speeds from: give [startup] w_on and w_off (rad/s, "
                "Hz or p.u.; e.g. the firmware's open-loop ERPM) to check a start and a reversal."
            )
        spin = False
        if not why and drive.observer.firmware == "odrive":
            why, spin = ODRIVE_ONE_WAY, True
        m = drive.motor
        return DriveScales(
            drive.T_N, c.T_max, m.J, m.p, drive.w_base, c.alpha_s, why, spin, speed_ramp=c.speed_ramp
        )

    def drive_loop(
        self, drive: schema.FluxObserverDrive, scenario: Scenario, gains: GainSet | None
    ) -> LoopSetup:
        """The loop as run, except the clamped gradient observer (VESC's ORTEGA_ORIGINAL): analysed on its
        active side, the gradient observer, as its observer-only linearization is (linearize.py). At
        exact estimates its fixed point lies on the clamp's kink (|eta| = lambda), where the one-sided
        correction has no derivative: taken as off, a flux error inside the circle would be a
        neutral pair at +-j w at every speed, which no gain moves (the simulation runs the clamp)."""
        if drive.observer.correction != "clamped-gradient":
            return simulation(drive, scenario, gains)
        gradient = dataclasses.replace(drive.observer, correction="gradient")
        active = dataclasses.replace(drive, observer=gradient)
        setup = simulation(active, scenario, gains)
        note = (
            "the clamped gradient observer linearized on its active side (the gradient observer): at exact "
            "estimates its fixed point lies on the clamp's kink"
        )
        return dataclasses.replace(setup, meta={**setup.meta, "drive_note": note})

    def low_speed_reason(self, drive: schema.FluxObserverDrive) -> str:
        """The observer sees the rotor only through the back-EMF it integrates."""
        return (
            "a back-EMF (flux) observer: the rotor position is unobservable at zero frequency, where the "
            "back-EMF vanishes (Henwood, Malaize, Praly 2012)"
        )

    def simulation(
        self, drive: schema.FluxObserverDrive, scenario: Scenario, gains: GainSet | None
    ) -> LoopSetup:
        return simulation(drive, scenario, gains)

    # the open-loop I-f start (design/startup.py): its drive files' optional [startup] section
    def startup(self, drive: schema.FluxObserverDrive) -> StartupSettings | None:
        return drive.startup

    def with_startup(
        self, drive: schema.FluxObserverDrive, startup: StartupSettings | None
    ) -> schema.FluxObserverDrive:
        return dataclasses.replace(drive, startup=startup)


FAMILY = FluxObserverFamily()
