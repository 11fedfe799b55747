"""Drive files of the reduced-order EMF/load observer family (De Angelo et al. 2006): schema and loading.

PM AC motor + extended reduced-order EMF and load-torque observer. Same strictness as every drive file
(design/drive_file.py): unknown or missing keys, wrong units or types and non-physical values raise
:class:`~sensorless.design.units.DriveFileError` naming the file and the key.

The EMF is data: ``harmonics`` lists odd orders (negative = negative sequence), ``Phi`` their amplitudes
(eq. (4)); ``"0.04 Phi_1"`` is a multiple of the fundamental. ``reading`` says how eq. (2) is read
(docs/families/pmac_reduced_order.md): "mechanical" (omega, J, B, T_L and Phi_n per mechanical
radian, eq. (4) in the electrical angle p theta_m) or "electrical" (the printed equations literally,
omega electrical).
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
from sensorless.design.drive_file import (
    check_keys,
    drive_header,
    load_section,
    nonempty_list,
    q,
    quantities,
    table,
)
from sensorless.design.envelope import Envelope, SpeedRule
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.symbolic.pmac import EmfSeries, PmacParams, flux_derivative, operating_point_signals
from sensorless.symbolic.pmac_reduced_order.step import DISCRETIZATIONS, param_names

READINGS = {
    "mechanical": "omega, J, B, T_L of eq. (2) and Phi_n are mechanical; (4) in the electrical angle",
    "electrical": "eqs. (2)-(5) as printed, omega electrical (J, B, T_L, Phi_n per electrical radian)",
}


@dataclass(frozen=True)
class PmacRating:
    """Nameplate data (Section IV); informational, and the per-unit speed base (1 p.u. = n_N). T_N, I_N
    and f_N are optional (0: not given): a minimal drive file's rating (derive.py), checked against
    P_N and n_N (T_N within 1 %) and by the plausibility checks (design/plausibility.py)."""

    P_N: float = q("power", doc="nominal power [W]")
    n_N: float = q("mech_speed", doc="nominal mechanical speed [r/min]")
    T_N: float = q("torque", doc="rated torque [N m]", default=0.0)
    I_N: float = q("current", doc="rated current [A rms]", default=0.0)
    f_N: float = q("frequency", doc="rated frequency [Hz]", default=0.0)


RATING_OPTIONAL = ("T_N", "I_N", "f_N")
T_N_TOLERANCE = 0.01  # a given T_N against P_N / (2 pi n_N / 60)


@dataclass(frozen=True)
class PmacMotor:
    """The true motor, eqs. (2)-(5)."""

    p: int = q("integer", check="pole_pairs", doc="pole pairs")
    # q() is a field specifier mypy does not see: the fields before are required too
    reading: str = field(metadata={"dim": "choice", "doc": "reading of eq. (2): mechanical|electrical"})  # type: ignore[misc]
    R: float = q("resistance", doc="stator resistance [ohm]")
    L: float = q("inductance", doc="stator inductance [H]")
    J: float = q("inertia", doc="inertia [kg m^2]")
    B: float = q("viscous", check="nonnegative", doc="viscous friction [N m s]")
    harmonics: tuple[int, ...] = field(default=(1,), metadata={"dim": "orders"})
    Phi: tuple[float, ...] = field(default=(), metadata={"dim": "flux_derivative"})

    @property
    def p_r(self) -> float:
        """Speed in eq. (2) per electrical speed: omega_paper = w / p_r (symbolic/pmac.py)."""
        return float(self.p) if self.reading == "mechanical" else 1.0

    def vector(self) -> np.ndarray:
        """[R, L, J, B, p_r, Phi_n...]: the motor vector of the analysis Functions."""
        return np.array([self.R, self.L, self.J, self.B, self.p_r, *self.Phi])


@dataclass(frozen=True)
class PmacEstimate:
    """The observer's model of the motor (kept apart from the true one for parameter-error studies)."""

    R: float = q("resistance", doc="estimated stator resistance [ohm]")
    L: float = q("inductance", doc="estimated inductance [H]")
    J: float = q("inertia", doc="estimated inertia [kg m^2]")
    harmonics: tuple[int, ...] = field(default=(1,), metadata={"dim": "orders"})
    Phi: tuple[float, ...] = field(default=(), metadata={"dim": "flux_derivative"})


@dataclass(frozen=True)
class PmacObserver:
    """Observer gains, eqs. (9)-(10)."""

    g: float = q("rate", doc="EMF observer gain g [1/s]")
    Gamma: float = q("adaptation", check="nonnegative", doc="load-torque adaptation gain [A^2 s^2]")


@dataclass(frozen=True)
class PmacControl:
    """Sampling, discretization, and the speed loop of Fig. 1 (its gains are not given in the paper)."""

    T_s: float = q("time", doc="sampling period [s]")
    discretization: str = field(metadata={"dim": "choice", "doc": "observer discretization scheme"})  # type: ignore[misc]
    alpha_s: float = q("angular", doc="speed-loop bandwidth [rad/s]")
    T_max: float = q("torque", doc="torque reference limit [N m]; bounds the runtime observer's load state")
    # optional: the current sensor's noise, per axis, rms, in each sample at T_s (design/noise.py)
    i_noise: float = q("current", doc="current-sensor noise [A rms]", default=0.0)
    # optional: the DC-link voltage (0: not given); the plausibility checks only (the simulated inverter's
    # limit stays twice the EMF at n_N, simulation.py)
    u_dc: float = q("voltage", doc="DC-link voltage [V]", default=0.0)


@dataclass(frozen=True)
class EnvelopeKeys:
    """[envelope] as the file gives it: mechanical speeds (r/min, nonzero) x load torques (N m); made the
    drive's :class:`~sensorless.design.envelope.Envelope` at load."""

    speeds: tuple[float, ...] = field(default=(), metadata={"dim": "mech_speed"})
    loads: tuple[float, ...] = field(default=(), metadata={"dim": "torque"})


I_NOISE_DEFAULT = 0.003  # default current-sensor noise: 0.3 % of the current amplitude at T_N, base speed


@dataclass(frozen=True)
class PmacDrive:
    """A drive of the reduced-order observer family."""

    name: str
    kind: str
    source: str
    file: str
    rating: PmacRating
    motor: PmacMotor
    estimate: PmacEstimate
    observer: PmacObserver
    control: PmacControl
    # [envelope], SI (design/envelope.py): its speeds listed in r/min (``rule.listed``, the file's
    # order) x its loads in N m (``torque_values``)
    envelope: Envelope
    digest: str = ""
    warnings: tuple[str, ...] = ()  # plausibility warnings (design/plausibility.py), printed by every command

    @property
    def T_N(self) -> float:
        """Nominal shaft torque P_N / (2 pi n_N / 60) [N m]."""
        return self.rating.P_N / (self.rating.n_N * math.pi / 30)

    @property
    def w_base(self) -> float:
        """Per-unit speed base: the nominal speed as electrical rad/s."""
        return self.rpm_to_w(self.rating.n_N)

    @property
    def pole_pairs(self) -> int:
        """Pole pairs."""
        return self.motor.p

    @property
    def T_s(self) -> float:
        """Sampling period [s]."""
        return self.control.T_s

    def rpm_to_w(self, n: Any) -> Any:
        """Mechanical r/min -> electrical rad/s (the pole pairs relate them in either reading)."""
        return np.asarray(n, float) * (math.pi / 30) * self.motor.p

    def w_to_rpm(self, w: Any) -> Any:
        """Electrical rad/s -> mechanical r/min."""
        return np.asarray(w, float) / ((math.pi / 30) * self.motor.p)

    def observer_params(
        self, g: float | None = None, Gamma: float | None = None, T_s: float | None = None
    ) -> np.ndarray:
        """The ``p`` vector of the observer step (symbolic/pmac_reduced_order/step.param_names)."""
        e, o = self.estimate, self.observer
        vals = [e.R, e.L, e.J, self.motor.p_r, o.g if g is None else g, o.Gamma if Gamma is None else Gamma]
        vals += [self.control.T_s if T_s is None else T_s, self.control.T_max, *e.Phi]
        assert len(vals) == len(param_names(e.harmonics))
        return np.array(vals, float)


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------
def harmonic_series(
    table: Mapping[str, Any], file: str, section: str
) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Orders and amplitudes of eq. (4), validated: odd, distinct, fundamental first and positive."""
    raw = nonempty_list(table, "harmonics", file, section)
    key = f"{section}.harmonics"
    for n in raw:
        if isinstance(n, bool) or not isinstance(n, int) or n % 2 == 0:
            raise DriveFileError(file, key, f"harmonic orders must be odd integers, got {n!r}")
    if len(set(raw)) != len(raw):
        raise DriveFileError(file, key, f"repeated harmonic order in {raw}")
    if raw[0] != 1:
        raise DriveFileError(file, key, "the first order must be the fundamental 1 (eq. (18) needs it)")
    orders = tuple(raw)
    amps = nonempty_list(table, "Phi", file, section)
    key = f"{section}.Phi"
    if len(amps) != len(orders):
        raise DriveFileError(file, key, f"{len(amps)} amplitudes for {len(orders)} harmonic orders")
    Phi: list[float] = []
    for k, a in enumerate(amps):
        x, rel = parse_quantity(a, "flux_derivative", file=file, key=f"{key}[{k}]")
        if rel is not None:
            if k == 0:
                raise DriveFileError(file, f"{key}[0]", "the fundamental cannot be relative to itself")
            x *= Phi[0]
        if k == 0 and x <= 0:
            raise DriveFileError(file, f"{key}[0]", f"non-physical value {a!r}: Phi_1 must be > 0")
        Phi.append(x)
    # (13) and (25) divide by |phi(theta)|^2: it must not vanish at any angle
    theta = np.linspace(0, 2 * np.pi, 64 * max(abs(n) for n in orders) + 1)
    mag = _phi_magnitude(orders).map(theta.size)(theta[None, :], np.array(Phi))
    mag = np.asarray(mag).ravel()
    if mag.min() <= 1e-6 * Phi[0]:
        k = int(np.argmin(mag))
        raise DriveFileError(
            file, key, f"non-physical series: |phi(theta)| vanishes near theta = {theta[k]:.4f} rad"
        )
    return orders, tuple(Phi)


def nominal_current(drive: PmacDrive) -> float:
    """Amplitude of the current vector at the nominal torque and base speed (the ripple-free current
    (25) of the true motor, symbolic/pmac.py) [A]: the scale of the default current-sensor noise."""
    m = drive.motor
    f = _current_function(tuple(m.harmonics))
    return float(f(0.0, drive.w_base, drive.T_N, m.vector()))


@functools.cache
def _current_function(orders: tuple[int, ...]) -> ca.Function:
    """(theta, w, T_L, motor) -> |i| at that operating point."""
    th, w, T = ca.SX.sym("theta"), ca.SX.sym("w"), ca.SX.sym("T_L")
    mv = ca.SX.sym("motor", 5 + len(orders))
    p = PmacParams(mv[0], mv[1], mv[2], mv[3], mv[4])
    sig, _ = operating_point_signals(th, w, T, p, EmfSeries(orders, mv[5:]))
    return ca.Function("nominal_current", [th, w, T, mv], [ca.norm_2(sig.i)])


@functools.cache
def _phi_magnitude(orders: tuple[int, ...]) -> ca.Function:
    """(theta, Phi) -> |phi(theta)| of eq. (4) (symbolic/pmac.py)."""
    th, Phi = ca.SX.sym("theta"), ca.SX.sym("Phi", len(orders))
    return ca.Function("phi_magnitude", [th, Phi], [ca.norm_2(flux_derivative(th, EmfSeries(orders, Phi)))])


def _with_harmonics(cls: type, table: Mapping[str, Any], file: str, section: str) -> Any:
    obj = load_section(cls, table, file, section, skip=("harmonics", "Phi"))
    orders, Phi = harmonic_series(table, file, section)
    return dataclasses.replace(obj, harmonics=orders, Phi=Phi)


SECTIONS = ("drive", "rating", "motor", "estimate", "observer", "control", "envelope")


def load_complete(data: Mapping[str, Any], file: str, digest: str, kind: str) -> PmacDrive:
    """Validate the complete data of a drive TOML of this family (every section present)."""
    check_keys(data, SECTIONS, file, "")
    head = drive_header(data, file)
    rating_t = table(data, "rating", file)
    rating = load_section(PmacRating, rating_t, file, "rating", optional=RATING_OPTIONAL)
    T_P = rating.P_N / (rating.n_N * math.pi / 30)
    if rating.T_N and abs(rating.T_N / T_P - 1) > T_N_TOLERANCE:
        raise DriveFileError(
            file,
            "rating.T_N",
            f"{rating.T_N:g} N m, but P_N / (2 pi n_N / 60) = {T_P:.5g} N m (tolerance "
            f"{100 * T_N_TOLERANCE:g} %): give P_N or T_N",
        )
    motor = _with_harmonics(PmacMotor, table(data, "motor", file), file, "motor")
    if motor.p < 1:
        raise DriveFileError(file, "motor.p", f"non-physical value {motor.p}: must be >= 1")
    if motor.reading not in READINGS:
        raise DriveFileError(
            file, "motor.reading", f"unknown reading {motor.reading!r} (known: {', '.join(READINGS)})"
        )
    estimate = _with_harmonics(PmacEstimate, table(data, "estimate", file), file, "estimate")
    observer = load_section(PmacObserver, table(data, "observer", file), file, "observer")
    control_t = table(data, "control", file)
    control = load_section(PmacControl, control_t, file, "control", optional=("i_noise", "u_dc"))
    if control.discretization not in DISCRETIZATIONS:
        raise DriveFileError(
            file,
            "control.discretization",
            f"unknown scheme {control.discretization!r} (known: {', '.join(DISCRETIZATIONS)})",
        )
    env_t = table(data, "envelope", file)
    check_keys(env_t, ("speeds", "loads"), file, "envelope.")
    speeds_rpm = quantities(env_t, "speeds", "mech_speed", file, "envelope")
    loads = quantities(env_t, "loads", "torque", file, "envelope")
    for k, n in enumerate(speeds_rpm):
        if n == 0:
            raise DriveFileError(
                file, f"envelope.speeds[{k}]", "zero speed: the EMF observer is undefined at standstill"
            )
    # mechanical r/min -> electrical rad/s as PmacDrive.rpm_to_w computes it (x pi/30, then x p)
    to_w = (math.pi / 30, motor.p)
    w_base = float(np.asarray(rating.n_N, float) * to_w[0] * to_w[1])
    T_N = rating.P_N / (rating.n_N * math.pi / 30)
    given = EnvelopeKeys(tuple(speeds_rpm), tuple(loads))
    envelope = Envelope(SpeedRule(listed=given.speeds, to_si=to_w), given.loads, w_base, T_N, given=given)
    drive = PmacDrive(
        name=head["name"],
        kind=kind,
        source=head["source"],
        file=file,
        rating=rating,
        motor=motor,
        estimate=estimate,
        observer=observer,
        control=control,
        envelope=envelope,
        digest=digest,
    )
    if "i_noise" not in control_t:
        x = I_NOISE_DEFAULT * nominal_current(drive)
        drive = dataclasses.replace(drive, control=dataclasses.replace(control, i_noise=float(x)))
    # The speed sign (14) reads the angle step modulo pi: |w| T_s must stay below pi/2.
    w_max = float(np.max(np.abs(envelope.speed_grid())))
    if w_max * control.T_s >= math.pi / 2:
        raise DriveFileError(
            file,
            "control.T_s",
            f"too long for the envelope: w T_s = {w_max * control.T_s:.3f} rad per step at "
            f"{drive.w_to_rpm(w_max):g} r/min (the speed sign (14) needs < pi/2)",
        )
    return drive
