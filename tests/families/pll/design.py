"""The PLL observer family in the design layer: drive files, gains, runtime, linearization, simulation.

Everything a command may ask of a family (sensorless.design.family.ObserverFamily), for the back-EMF
PLL observer of symbolic.py, and the family record :data:`FAMILY` (registered by
``sensorless.design.registry.registered(FAMILY)``; its drive kind is written here only).

Linearization. The observer's equilibrium on a motor in steady state (speed w, torque T_e, the true
motor's MTPA current i_d = 0) is a rotating one in the stationary frame; in the rotor frame (the EMF
state rotated by -theta, the angle error delta = theta - theta_hat, and w_i) it is a fixed point. Both
the continuous observer (1)-(3) (``rhs_function`` of symbolic.py) and the sampled one that runs (its
runtime step, the Function that codegen prints) are written in that frame by composing their own SX
Functions with the rotations; the equilibrium is found by Newton's method on the SX expressions and the
poles are the eigenvalues of their CasADi Jacobians there: continuous poles, and the discrete ones
mapped by ln(z)/T_s. Nothing is re-typed. The sampled observer sees the motor's steady samples as the
drive loop gives them: the current at t_k and the voltage held over the period (taken as the steady
voltage at mid-period); its equilibrium's angle error is the steady error it runs with.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.discrete import (
    SampledLoop,
    discrete_poles,
    fixed_points,
    pmsm_zoh_plant,
    pmsm_zoh_sample,
)
from sensorless.design.drive_file import check_keys, drive_header, load_section, q, quantities, table
from sensorless.design.family import CapabilityError, GainSet, ObserverFamily
from sensorless.design.gain_table import GainTable, GainTableError
from sensorless.design.linearization import Linearization
from sensorless.design.pmsm_drive import CURRENT_PANEL, loop_setup
from sensorless.design.pmsm_schema import PmsmControl, PmsmEstimate, PmsmMotor, load_estimate, load_motor
from sensorless.design.poles import eigvals_batched
from sensorless.design.runtime import RuntimeSetup
from sensorless.design.scenario import Scenario
from sensorless.design.simulate import LoopSetup
from sensorless.design.units import DriveFileError
from sensorless.symbolic.frames import J, rot, wrap_angle
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current, mtpa_current, stator_voltage

from families.pll.symbolic import DISCRETIZATIONS, N_OBS, OBSERVER, PARAMS, rhs_function

KIND = "pmsm-pll"
TABLE_LAWS: dict[str, tuple[str, ...]] = {"pll": ("w_pll",)}  # PLL bandwidth [rad/s]


# --------------------------------------------------------------------------------------------------
# Drive files
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Rating:
    """Nameplate: the per-unit speed base and the nominal torque."""

    n_N: float = q("mech_speed", doc="nominal mechanical speed [r/min]")
    T_N: float = q("torque", doc="nominal torque [N m]")


@dataclass(frozen=True)
class Observer:
    """The observer's settings; w_pll is its gain (the tunable)."""

    g: float = q("angular", doc="EMF observer bandwidth [rad/s]")
    w_pll: float = q("angular", doc="PLL bandwidth [rad/s]")
    w_0: float = q("angular", doc="speed below which the PLL error fades [rad/s]")


@dataclass(frozen=True)
class Envelope:
    """Operating points of analysis and tuning: |speed| from speed_min to speed_max, both directions."""

    speed_min: float = q("angular", doc="smallest |speed| [rad/s]")
    speed_max: float = q("angular", doc="largest |speed| [rad/s]")
    speeds: int = q("integer", doc="speeds per direction")
    torques: tuple[float, ...] = field(default=(), metadata={"dim": "torque", "doc": "torques [N m]"})


@dataclass(frozen=True)
class PllDrive:
    """A drive of the PLL family (SI; speeds electrical)."""

    name: str
    kind: str
    source: str
    file: str
    rating: Rating
    motor: PmsmMotor
    estimate: PmsmEstimate
    control: PmsmControl
    observer: Observer
    envelope: Envelope
    digest: str = ""
    warnings: tuple[str, ...] = ()  # no plausibility checks of its own

    @property
    def T_N(self) -> float:
        return self.rating.T_N

    @property
    def w_base(self) -> float:
        """1 p.u. speed: the nominal speed, electrical rad/s."""
        return self.rating.n_N * math.pi / 30 * self.motor.p

    @property
    def pole_pairs(self) -> int:
        return self.motor.p

    @property
    def T_s(self) -> float:
        return self.control.T_s

    def grid(self, factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Flat (speed [rad/s], torque [N m]) of the envelope's speeds x torques."""
        W, T = np.meshgrid(self.speed_grid(factor), np.asarray(self.envelope.torques, float))
        return W.ravel(), T.ravel()

    def speed_grid(self, factor: int = 1) -> np.ndarray:
        """Envelope speeds [rad/s], both directions; ``factor`` refines each interval."""
        e = self.envelope
        s = np.linspace(e.speed_min, e.speed_max, (e.speeds - 1) * factor + 1)
        return np.concatenate([-s[::-1], s])


def load(data: Mapping[str, Any], file: str, digest: str, kind: str) -> PllDrive:
    """Validate a parsed drive TOML of this family (strict: DriveFileError naming file and key)."""
    sections = ("drive", "rating", "motor", "estimate", "control", "observer", "envelope")
    check_keys(data, sections, file, "")
    head = drive_header(data, file)
    rating = load_section(Rating, table(data, "rating", file), file, "rating")
    motor, estimate = load_motor(data, file), load_estimate(data, file)
    for section, m in (("motor", motor), ("estimate", estimate)):
        if m.L_q != m.L_d:  # the observer's model (1) has one inductance
            raise DriveFileError(file, f"{section}.L_q", "a non-salient motor: L_q must equal L_d")
    w_base = rating.n_N * math.pi / 30 * motor.p
    rel = {"pu": w_base}
    env_t = table(data, "envelope", file)
    envelope = load_section(Envelope, env_t, file, "envelope", rel, skip=("torques",))
    envelope = dataclasses.replace(envelope, torques=quantities(env_t, "torques", "torque", file, "envelope"))
    if envelope.speeds < 2 or not envelope.speed_min < envelope.speed_max:
        raise DriveFileError(file, "envelope", "need speeds >= 2 and 0 < speed_min < speed_max")
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
        envelope=envelope,
        digest=digest,
    )


# --------------------------------------------------------------------------------------------------
# Gains and runtime
# --------------------------------------------------------------------------------------------------
def drive_gains(drive: PllDrive) -> GainSet:
    """The drive file's [observer] w_pll."""
    return GainSet("pll", {"w_pll": float(drive.observer.w_pll)}, f"{drive.file} [observer]")


def table_gains(table: GainTable, where: str) -> GainSet:
    """The gains of a ``pll`` table."""
    if table.law not in TABLE_LAWS:
        raise GainTableError(f"{where}: key 'law': {table.law!r} gains are not for the PLL observer")
    try:
        w = float(table.gains["w_pll"])
    except (TypeError, ValueError) as e:
        raise GainTableError(f"{where}: key 'gains.w_pll': {e}") from None
    if not (math.isfinite(w) and w > 0):
        raise GainTableError(f"{where}: key 'gains.w_pll': need a finite bandwidth > 0")
    return GainSet("pll", {"w_pll": w}, f"pll table {where} (tuned for {table.drive.get('name')})")


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


def runtime_setup(drive: PllDrive, gains: GainSet, discretization: str | None = None) -> RuntimeSetup:
    """The runtime observer of ``drive`` with ``gains``."""
    disc = discretization or DISCRETIZATIONS[0]
    if disc not in DISCRETIZATIONS:
        raise ValueError(f"unknown discretization {disc!r} (known: {', '.join(DISCRETIZATIONS)})")
    params = runtime_params(drive, gains)
    OBSERVER.check_params(params)
    return RuntimeSetup(OBSERVER, disc, params, gains)


# --------------------------------------------------------------------------------------------------
# Linearization (module docstring)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PllLinearization(Linearization):
    """The common result plus the sampled observer's steady angle error at each point."""

    theta_err: np.ndarray | None = None  # (N,) theta - theta_hat at the discrete equilibrium [rad]


NEWTON_STEPS = 12
_N_X = N_OBS  # the observer's states (the runtime state adds the contract's counter)


def _steady_motor(w: ca.SX, T_e: ca.SX, m: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(i_r, u_r) of the true non-salient motor m = [R_s, L, psi_pm, p] at speed w, torque T_e: the
    MTPA current (i_d = 0) and the steady voltage of the shared PMSM model (symbolic/pmsm.py)."""
    motor = PmsmParams(m[0], m[1], m[1], m[2])
    i_r = mtpa_current(T_e, motor, m[3])
    return i_r, stator_voltage(i_r, 0, flux_from_current(i_r, motor), w, motor.R_s)


def _to_stationary(x_r: ca.SX) -> ca.SX:
    """Observer state at theta = 0 from the rotor-frame state [z_r (2), delta, w_i]."""
    return ca.vertcat(x_r[0:2], -x_r[2], x_r[3])


@functools.cache
def rotor_frame_rates() -> ca.Function:
    """(x_r, w, T_e, motor[4], p) -> f_r: the continuous observer (1)-(3) on the true motor in steady
    state at speed w, torque T_e, written in the rotor frame (x_r = [z_r (2), delta, w_i]); its
    equilibria are its zeros, and its Jacobian in x_r is the linearized observer there."""
    x_r = ca.SX.sym("x_r", _N_X)
    w, T_e = ca.SX.sym("w"), ca.SX.sym("T_e")
    m, p = ca.SX.sym("motor", 4), ca.SX.sym("p", len(PARAMS))
    i_r, u_r = _steady_motor(w, T_e, m)  # at theta = 0: stationary = rotor frame
    dx = rhs_function()(_to_stationary(x_r), i_r, u_r, p)
    G = ca.vertcat(dx[0:2] - w * (J @ x_r[0:2]), w - dx[2], dx[3])
    return ca.Function(
        "pmsm_pll_rotor_rates", [x_r, w, T_e, m, p], [G], ["x_r", "w", "T_e", "motor", "p"], ["f_r"]
    )


def motor_vector(drive: PllDrive) -> np.ndarray:
    """[R_s, L, psi_pm, p] of the true motor (the ``motor`` input of the equilibrium Functions)."""
    mt = drive.motor
    return np.array([mt.R_s, mt.L_d, mt.psi_pm, float(mt.p)])


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


@functools.cache
def equilibrium_function() -> ca.Function:
    """(w, T_e, motor[4], p) -> (x_r*, A, residual): Newton on the SX equations f_r(x_r) = 0 of the
    continuous observer in the rotor frame (:func:`rotor_frame_rates`), then its Jacobian there."""
    x_r = ca.SX.sym("x_r", _N_X)
    w, T_e = ca.SX.sym("w"), ca.SX.sym("T_e")
    m, p = ca.SX.sym("motor", 4), ca.SX.sym("p", len(PARAMS))
    i_r, _ = _steady_motor(w, T_e, m)
    G = rotor_frame_rates()(x_r, w, T_e, m, p)
    g_fn = ca.Function("G", [x_r, w, T_e, m, p], [G, ca.jacobian(G, x_r)])
    # start: the exact EMF of the true motor, no angle error, w_i = w
    e_r = w * ca.vertcat(0, m[2])
    xk = ca.vertcat(e_r + p[3] * p[1] * i_r, 0, w)
    for _ in range(NEWTON_STEPS):
        Gk, Jk = g_fn(xk, w, T_e, m, p)
        xk = xk - ca.solve(Jk, Gk)
    Gk, _ = g_fn(xk, w, T_e, m, p)
    A = ca.substitute(ca.jacobian(G, x_r), x_r, xk)
    return ca.Function(
        "pmsm_pll_equilibrium_c",
        [w, T_e, m, p],
        [xk, ca.densify(A), ca.norm_inf(Gk)],
        ["w", "T_e", "motor", "p"],
        ["x", "A", "res"],
    )


def linearize(drive: PllDrive, gains: GainSet, w: Any, torque: Any) -> PllLinearization:
    """Continuous and discrete poles at speeds ``w`` [rad/s] x torques [N m] (broadcast together)."""
    W, T = (np.ravel(a).astype(float) for a in np.broadcast_arrays(w, torque))
    n = W.size
    setup = runtime_setup(drive, gains)
    motor = motor_vector(drive)
    x, A, res = evaluate_batch(equilibrium_function(), n, [W, T, motor, setup.p])
    scale = np.maximum(np.abs(x[:, :, 0]).max(axis=1), 1.0)
    ok = np.isfinite(A).all(axis=(1, 2)) & (res[:, 0, 0] <= 1e-9 * scale)
    poles = np.full((n, _N_X), np.nan + 0j)
    if ok.any():
        poles[ok] = eigvals_batched(A[ok])
    # the sampled observer that runs (the shared analysis), from the continuous equilibrium
    R, L, psi_pm, p = motor
    i_r = np.column_stack([np.zeros(n), T / (1.5 * p * psi_pm)])  # MTPA of a non-salient motor
    plant = pmsm_zoh_plant([R, L, L, psi_pm], W, i_r, drive.control.T_s)
    y0 = np.where(ok[:, None], x[:, :, 0], np.nan)
    y, Jd = fixed_points(sampled_loop(setup.discretization), y0, W, plant, setup.p)
    return PllLinearization(
        w=W,
        torque=T,
        poles=poles,
        poles_discrete=discrete_poles(Jd, drive.control.T_s, _N_X)[0],
        T_s=drive.control.T_s,
        torque_name="T_e",
        theta_err=y[:, 2],
    )


# --------------------------------------------------------------------------------------------------
# Simulation: the shared PMSM drive loop around the runtime observer
# --------------------------------------------------------------------------------------------------
def simulation(drive: PllDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """Loop set-up of ``sc`` on ``drive``; the scenario's estimate errors scale the observer's model."""
    k = sc.estimate_scale
    setup = runtime_setup(drive, gains or drive_gains(drive), sc.discretization)
    params = dict(setup.params)
    params.update(R_s=params["R_s"] * k["R_s"], L=params["L"] * k["L"], psi_pm=params["psi_pm"] * k["psi_pm"])
    OBSERVER.check_params(params)
    setup = dataclasses.replace(setup, params=params)
    meta = {"gain": f"{setup.gain_source}: w_pll = {params['w_pll']:.6g} rad/s"}
    # the shared loop's controllers see the same errors, their one inductance as L_d = L_q
    loop_k = {"R_s": k["R_s"], "L_d": k["L"], "L_q": k["L"], "psi_pm": k["psi_pm"], "J": k["J"]}
    sc = dataclasses.replace(sc, estimate_scale=loop_k)
    return loop_setup(drive, sc, setup, meta=meta)


# --------------------------------------------------------------------------------------------------
# The family record
# --------------------------------------------------------------------------------------------------
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
    laws = TABLE_LAWS
    estimate_keys = ("R_s", "L", "psi_pm", "J")  # [estimate_scale]: one inductance
    panels = (CURRENT_PANEL,)

    def load(self, data: Any, file: str, digest: str) -> PllDrive:
        return load(data, file, digest, self.kind)

    def gains(
        self, drive: Any, *, name: str | None = None, table: Any = None, table_file: str = ""
    ) -> GainSet:
        if name is not None:
            raise CapabilityError(
                f"{drive.file}: this observer has one gain ([observer] w_pll); there is no "
                f"[observer.gains.{name}] to choose"
            )
        if table is None:
            return drive_gains(drive)
        kind = table.drive.get("kind")
        if kind is not None and kind != drive.kind:
            raise GainTableError(
                f"{table_file or 'gain table'}: key 'drive.kind': {kind!r} does not match the drive "
                f"({drive.kind})"
            )
        return table_gains(table, table.where(table_file))

    def runtime(self, drive: Any, gains: GainSet, *, discretization: str | None = None) -> RuntimeSetup:
        return runtime_setup(drive, gains, discretization)

    def linearize(self, drive: Any, gains: GainSet, w: Any, torque: Any, **options: Any) -> PllLinearization:
        if options:
            raise CapabilityError(
                f"observer family {self.name!r}: no linearization options ({', '.join(options)})"
            )
        return linearize(drive, gains, w, torque)

    def simulation(self, drive: Any, scenario: Any, gains: GainSet | None) -> LoopSetup:
        return simulation(drive, scenario, gains)


FAMILY = PllObserverFamily()
