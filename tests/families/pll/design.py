"""The PLL observer family in the design layer: drive files, gains, runtime, linearization, simulation.

Everything a command may ask of a family (sensorless.design.family.ObserverFamily), for the back-EMF
PLL observer of symbolic.py, and the family record :data:`FAMILY` (registered by
``sensorless.design.registry.registered(FAMILY)``; its drive kind is written here only).

Linearization. The observer's equilibrium on a motor in steady state (speed w, torque T_e, the true
motor's MTPA current i_d = 0) is a rotating one in the stationary frame; in the rotor frame (the EMF
state rotated by -theta, the angle error delta = theta - theta_hat, and w_i) it is a fixed point. The
continuous observer (1)-(3) (``rhs_function`` of symbolic.py) is written in that frame here
(:func:`rotor_frame_rates`) and the shared design/rotor_frame.py finds its equilibrium and poles; the
sampled observer that runs (its runtime step) goes through the shared design/discrete.py, which sees
the motor's samples under the inverter's zero-order hold. Nothing is re-typed.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.discrete import (
    SampledLoop,
    discrete_poles,
    fixed_points,
    pmsm_zoh_plant,
    pmsm_zoh_sample,
)
from sensorless.design.drive_file import check_keys, drive_header, load_section, q, table
from sensorless.design.envelope import Envelope, TuningSettings, load_tuning
from sensorless.design.family import CapabilityError, GainSet, ObserverFamily
from sensorless.design.law_gains import section_gains, table_gains
from sensorless.design.linearization import Linearization
from sensorless.design.pmsm_drive import CURRENT_PANEL, loop_setup
from sensorless.design.pmsm_schema import (
    PmsmControl,
    PmsmDriveProperties,
    PmsmEstimate,
    PmsmMotor,
    PmsmRating,
    load_estimate,
    load_motor,
)
from sensorless.design.rotor_frame import (
    RotorFrameLoop,
    equilibrium_points,
    pmsm_plant,
    pmsm_steady,
    pmsm_steady_current,
)
from sensorless.design.runtime import RuntimeSetup
from sensorless.design.scenario import Scenario
from sensorless.design.simulate import LoopSetup
from sensorless.design.units import DriveFileError
from sensorless.symbolic.frames import J, rot, wrap_angle

from families.pll.symbolic import DISCRETIZATIONS, N_OBS, OBSERVER, PARAMS, rhs_function

KIND = "pmsm-pll"
LAWS: dict[str, tuple[str, ...]] = {"pll": ("w_pll",)}  # PLL bandwidth [rad/s]


@dataclass(frozen=True)
class Observer:
    """The observer's settings; w_pll is its gain (the tunable)."""

    g: float = q("angular", doc="EMF observer bandwidth [rad/s]")
    w_pll: float = q("angular", doc="PLL bandwidth [rad/s]")
    w_0: float = q("angular", doc="speed below which the PLL error fades [rad/s]")


@dataclass(frozen=True)
class PllDrive(PmsmDriveProperties):
    """A drive of the PLL family (SI; speeds electrical); [tuning] is the shared envelope."""

    name: str
    kind: str
    source: str
    file: str
    rating: PmsmRating
    motor: PmsmMotor
    estimate: PmsmEstimate
    control: PmsmControl
    observer: Observer
    tuning: TuningSettings
    digest: str = ""
    warnings: tuple[str, ...] = ()  # no plausibility checks of its own

    @property
    def envelope(self) -> Envelope:
        """The operating range: the [tuning] envelope."""
        return self.tuning.envelope


def load(data: Mapping[str, Any], file: str, digest: str, kind: str) -> PllDrive:
    """Validate a parsed drive TOML of this family (strict: DriveFileError naming file and key)."""
    check_keys(data, ("drive", "rating", "motor", "estimate", "control", "observer", "tuning"), file, "")
    head = drive_header(data, file)
    rating = load_section(PmsmRating, table(data, "rating", file), file, "rating")
    motor, estimate = load_motor(data, file), load_estimate(data, file)
    for section, m in (("motor", motor), ("estimate", estimate)):
        if m.L_q != m.L_d:  # the observer's model (1) has one inductance
            raise DriveFileError(file, f"{section}.L_q", "a non-salient motor: L_q must equal L_d")
    rel = {"pu": rating.w_base(motor.p), "T_N": rating.T_N}
    return PllDrive(
        name=head["name"],
        kind=kind,
        source=head["source"],
        file=file,
        rating=rating,
        motor=motor,
        estimate=estimate,
        control=load_section(PmsmControl, table(data, "control", file), file, "control"),
        observer=load_section(Observer, table(data, "observer", file), file, "observer", rel),
        tuning=load_tuning(table(data, "tuning", file), file, rel),
        digest=digest,
    )


def drive_gains(drive: PllDrive) -> GainSet:
    """The drive file's [observer] w_pll."""
    return section_gains("pll", LAWS["pll"], drive.observer, f"{drive.file} [observer]")


def runtime_params(drive: PllDrive, gains: GainSet) -> dict[str, float]:
    """The parameters of the runtime step (symbolic.PARAMS)."""
    e, o = drive.estimate, drive.observer
    return {
        "R_s": e.R_s,
        "L": e.L_d,
        "psi_pm": e.psi_pm,
        "g": o.g,
        "w_pll": float(gains.values["w_pll"]),
        "w_0": o.w_0,
        "T_s": drive.control.T_s,
        "w_max": 2 * drive.w_base,  # the runtime bound of the PLL integrator: twice the nominal speed
    }


@dataclass(frozen=True)
class PllLinearization(Linearization):
    """The common result plus the sampled observer's steady angle error at each point."""

    theta_err: np.ndarray | None = None  # (N,) theta - theta_hat at the discrete equilibrium [rad]

    def point_columns(self) -> dict[str, np.ndarray]:
        return {} if self.theta_err is None else {"theta_err_rad": self.theta_err}


@functools.cache
def rotor_frame_rates() -> ca.Function:
    """(x_r, w, T_e, motor[5], p) -> f_r: the continuous observer (1)-(3) on the true motor in steady
    state at speed w, torque T_e (the shared ``pmsm_steady``), written in the rotor frame (x_r = [z_r
    (2), delta, w_i]); its equilibria are its zeros, its Jacobian in x_r the linearized observer."""
    x_r, w, T_e = ca.SX.sym("x_r", N_OBS), ca.SX.sym("w"), ca.SX.sym("T_e")
    m, p = ca.SX.sym("motor", 5), ca.SX.sym("p", len(PARAMS))
    i_r, u_r = pmsm_steady(w, T_e, m)  # at theta = 0: stationary = rotor frame
    dx = rhs_function()(ca.vertcat(x_r[0:2], -x_r[2], x_r[3]), i_r, u_r, p)
    G = ca.vertcat(dx[0:2] - w * (J @ x_r[0:2]), w - dx[2], dx[3])
    return ca.Function("pmsm_pll_rotor_rates", [x_r, w, T_e, m, p], [G])


@functools.cache
def rotor_loop() -> RotorFrameLoop:
    """The continuous observer for the shared design/rotor_frame.py; Newton starts at the exact EMF of
    the true motor (z = e + g L i), no angle error, w_i = w."""
    w, T_e, m, p = ca.SX.sym("w"), ca.SX.sym("T_e"), ca.SX.sym("motor", 5), ca.SX.sym("p", len(PARAMS))
    i_r, _ = pmsm_steady(w, T_e, m)
    x0 = ca.vertcat(w * ca.vertcat(0, m[3]) + p[3] * p[1] * i_r, 0, w)
    return RotorFrameLoop(
        "pmsm_pll", rotor_frame_rates(), ca.Function("pmsm_pll_start", [w, T_e, m, p], [x0])
    )


@functools.cache
def sampled_loop(discretization: str) -> SampledLoop:
    """The runtime step on the motor sampled under zero-order hold (design/discrete.py), in the rotor
    frame y = [z rotated by -theta, delta = theta - theta_hat, w_i]."""

    def state(y: Any, theta: Any, w: Any, plant: Any, p: Any) -> Any:
        return ca.vertcat(rot(theta) @ y[0:2], theta - y[2], y[3])

    def rotor(x: Any, theta: Any) -> Any:
        return ca.vertcat(rot(theta).T @ x[0:2], wrap_angle(theta - x[2]), x[3])

    names = ("z_d", "z_q", "delta", "w_i")
    return SampledLoop(OBSERVER, discretization, None, names, 4, pmsm_zoh_sample, state, rotor, (2,))


class PllObserverFamily(ObserverFamily):
    """Back-EMF observer + PLL for non-salient PMSMs (symbolic.py)."""

    kind = KIND
    name = "pmsm_pll"
    title = "back-EMF observer with PLL, for non-salient PMSMs"
    citation = "Sul (2011); Harnefors and Nee (2000)"
    presets = "families.pll.presets"
    scenarios = "families.pll.scenarios"
    tuning = "families.pll.tuning"
    report = "families.pll.report"
    laws = LAWS
    estimate_keys = ("R_s", "L", "psi_pm", "J")  # [estimate_scale]: one inductance
    panels = (CURRENT_PANEL,)

    def load(self, data: Any, file: str, digest: str) -> PllDrive:
        return load(data, file, digest, self.kind)

    def gains(
        self, drive: Any, *, name: str | None = None, table: Any = None, table_file: str = ""
    ) -> GainSet:
        if name is not None:
            raise CapabilityError(f"{drive.file}: one gain ([observer] w_pll), no [observer.gains.{name}]")
        return drive_gains(drive) if table is None else table_gains(self, drive, table, table_file)

    def runtime(self, drive: Any, gains: GainSet, *, discretization: str | None = None) -> RuntimeSetup:
        disc = discretization or DISCRETIZATIONS[0]
        if disc not in DISCRETIZATIONS:
            raise ValueError(f"unknown discretization {disc!r} (known: {', '.join(DISCRETIZATIONS)})")
        params = runtime_params(drive, gains)
        OBSERVER.check_params(params)
        return RuntimeSetup(OBSERVER, disc, params, gains)

    def linearize(self, drive: Any, gains: GainSet, w: Any, torque: Any, **options: Any) -> PllLinearization:
        """Continuous and discrete poles at speeds ``w`` [rad/s] x torques [N m] (module docstring)."""
        if options:  # it has none
            raise CapabilityError(f"{self.name}: no linearization options ({', '.join(options)})")
        W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
        setup, motor, T_s = self.runtime(drive, gains), pmsm_plant(drive.motor), drive.T_s
        e = equilibrium_points(rotor_loop(), W, T, motor, setup.p)
        poles, x = e.poles(), e.x
        # the sampled observer that runs (the shared analysis), from the continuous equilibrium
        plant = pmsm_zoh_plant(motor[:4], W, pmsm_steady_current(T, motor), T_s)
        y, Jd = fixed_points(sampled_loop(setup.discretization), x, W, plant, setup.p)
        poles_d = discrete_poles(Jd, T_s, N_OBS)[0]
        return PllLinearization(W, T, poles, poles_d, T_s, "T_e", theta_err=y[:, 2])

    def simulation(self, drive: Any, sc: Scenario, gains: GainSet | None) -> LoopSetup:
        """Loop set-up of ``sc``; the scenario's estimate errors scale the observer's model."""
        k = sc.estimate_scale
        setup = self.runtime(drive, gains or drive_gains(drive), discretization=sc.discretization)
        params = dict(setup.params)
        params.update(
            R_s=params["R_s"] * k["R_s"], L=params["L"] * k["L"], psi_pm=params["psi_pm"] * k["psi_pm"]
        )
        OBSERVER.check_params(params)
        setup = dataclasses.replace(setup, params=params)
        meta = {"gain": f"{setup.gain_source}: w_pll = {params['w_pll']:.6g} rad/s"}
        # the shared loop's controllers see the same errors, their one inductance as L_d = L_q
        loop_k = {"R_s": k["R_s"], "L_d": k["L"], "L_q": k["L"], "psi_pm": k["psi_pm"], "J": k["J"]}
        sc = dataclasses.replace(sc, estimate_scale=loop_k)
        return loop_setup(drive, sc, setup, meta=meta)


FAMILY = PllObserverFamily()
