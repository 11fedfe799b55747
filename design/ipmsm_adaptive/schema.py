"""Drive files of the speed-adaptive observer (kind of ipmsm_adaptive/__init__.py): schema and loading.

The sections of Piippo, Hinkkanen, Luomi (2008) Tables I-II and Sections IV-VI: ``[rating]``, ``[base]``
(per-unit bases), ``[motor]`` (the true motor), ``[estimate]`` (the observer's parameter estimates, kept
apart so parameter errors can be studied), ``[control]``, ``[observer]`` with ``[observer.gains.*]``,
``[injection]``, and the optional ``[runtime]`` (discrete-time settings) and ``[tuning]`` (envelope of
``sensorless tune``). ``[motor]``, ``[estimate]`` and the loop's part of ``[control]`` are the records
every PMSM family shares (design/pmsm_schema.py). Strict like every drive file (design/drive_file.py);
:func:`load_complete` reads a complete file (derive.py ``load`` completes a minimal one first).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sensorless.design.drive_file import check_keys, drive_header, load_section, q, table
from sensorless.design.envelope import Envelope, TuningSettings, load_tuning, tuning_envelope
from sensorless.design.ipmsm_adaptive.law_settings import LAW_KEYS, AdaptiveLawSettings
from sensorless.design.plausibility import plausibility, warning_lines
from sensorless.design.pmsm_schema import (
    PmsmControl,
    PmsmEstimate,
    PmsmMotor,
    load_estimate,
    load_motor,
    saliency,
)
from sensorless.design.units import DriveFileError, UnknownName
from sensorless.symbolic.ipmsm_adaptive.step import DISCRETIZATIONS

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.startup import StartupSettings


@dataclass(frozen=True)
class Rating:
    """Nameplate data (Table I). Informational, and the source of the per-unit bases."""

    P_N: float = q("power", doc="nominal power [W]")
    U_N: float = q("voltage", doc="nominal line-to-line rms voltage [V]")
    I_N: float = q("current", doc="nominal rms current [A]")
    f_N: float = q("frequency", doc="nominal electrical frequency [Hz]")
    n_N: float = q("mech_speed", doc="nominal mechanical speed [r/min]")
    T_N: float = q("torque", doc="nominal torque [N m]")


@dataclass(frozen=True)
class Base:
    """Per-unit bases (peak-value scaling). Only inputs/outputs use per unit; internals are SI."""

    w: float = q("angular", doc="base electrical angular speed [rad/s]")
    u: float = q("voltage", doc="base voltage, peak phase [V]")
    i: float = q("current", doc="base current, peak [A]")

    @property
    def psi(self) -> float:
        """Base flux linkage [V s]."""
        return self.u / self.w

    @property
    def Z(self) -> float:
        """Base impedance [ohm]."""
        return self.u / self.i


@dataclass(frozen=True)
class Control(PmsmControl):
    """Control-system settings (Table II and Section VI): the shared drive loop's, and the sensor noise."""

    # optional: the current sensor's noise, per axis, rms, in each sample at T_s (design/noise.py)
    i_noise: float = q("current", doc="current-sensor noise [A rms]", default=0.0)
    # optional: its resolution, one step of the converter [A] (sizes the HF carrier: carrier.py)
    i_resolution: float = q("current", doc="current-sensor resolution [A per step]", default=0.0)


I_NOISE_DEFAULT = 0.003  # default current-sensor noise: 0.3 % of the base (nominal peak) current
SALIENCY_MIN = 0.1  # 2 |L_q - L_d| / (L_q + L_d) below which the HF injection is off (derive.py)


@dataclass(frozen=True)
class ZeroGain:
    """lambda = 0 (Fig. 4(a))."""


@dataclass(frozen=True)
class ConstantGain:
    """lambda = lambda1 I + lambda2 J with constant lambda1, lambda2 (eq. (7), Fig. 4(b))."""

    lambda1: float = q("resistance", check="any", doc="[ohm]; the paper requires lambda1 > -R̂s")
    lambda2: float = q("resistance", check="any", doc="[ohm]")


@dataclass(frozen=True)
class SpeedGain:
    """Speed-dependent gain of eq. (16) (Fig. 4(c))."""

    lambda_p: float = q("resistance", doc="lambda' [ohm]")
    w_lambda: float = q("angular", doc="omega_lambda [rad/s]")


GAIN_SCHEMAS: dict[str, type] = {"zero": ZeroGain, "constant": ConstantGain, "speed": SpeedGain}


@dataclass(frozen=True)
class Observer:
    """Adaptive observer settings: speed-adaptation bandwidth (10) and the gain choices (7), (16)."""

    alpha_fo: float = q("angular", doc="speed-adaptation bandwidth alpha_fo [rad/s], eq. (10)")
    gain: str = field(default="speed", metadata={"dim": "choice", "doc": "default gain law"})
    gains: Mapping[str, Any] = field(default_factory=dict, metadata={"dim": "gains"})


@dataclass(frozen=True)
class Injection:
    """HF signal injection, Section V: carrier (17), PI (21)-(22), linear fade to w_Delta."""

    w_c: float = q("angular", doc="carrier angular frequency [rad/s]")
    u_c: float = q(
        "voltage", check="nonnegative", doc="carrier amplitude at zero speed [V]; 0: injection off"
    )
    alpha_i: float = q("angular", doc="PI (21) bandwidth at zero speed [rad/s], eq. (22)")
    w_Delta: float = q("angular", doc="transition speed where injection reaches zero [rad/s]")

    @property
    def enabled(self) -> bool:
        """Whether the drive injects (u_c > 0); off for a motor without a usable saliency."""
        return self.u_c > 0


@dataclass(frozen=True)
class Runtime:
    """Discrete-time runtime settings (not in the paper; choices in docs/families/ipmsm_adaptive.md).

    An optional section: every key may be omitted; RUNTIME_DEFAULTS are the documented choices.
    """

    discretization: str = field(
        metadata={"dim": "choice", "doc": f"runtime step's scheme: {', '.join(DISCRETIZATIONS)}"}
    )
    w_bp: float = q("angular", doc="band-pass -3 dB bandwidth around w_c [rad/s]")
    w_lp: float = q("angular", doc="low-pass cut-off after demodulation [rad/s]")
    x_eps_max: float = q("angular", check="nonnegative", doc="bound on the integral of (21) [rad/s]")
    carrier_delay: float = q(
        "dimensionless", check="nonnegative", doc="samples from carrier command to applied voltage"
    )
    w_max: float = q("angular", doc="highest speed of the drive [rad/s]: the runtime state's speed bounds")


# the sections of a drive file of this family (a minimal one gives [inverter] instead of [control]'s
# u_dc and T_s; derive.py)
SECTIONS = (
    "drive",
    "rating",
    "base",
    "motor",
    "estimate",
    "control",
    "observer",
    "injection",
    "runtime",
    "tuning",
    "inverter",
)
RUNTIME_DEFAULTS: dict[str, Any] = {
    "discretization": DISCRETIZATIONS[0],
    "w_bp": "200 Hz",
    "w_lp": "100 Hz",
    "x_eps_max": "0.1 pu",
    "carrier_delay": 1.0,
    "w_max": "2 pu",
}
# why each default (the comments of a derived drive file, derive.py)
RUNTIME_RULES: dict[str, str] = {
    "discretization": "default: the voltage held as the inverter holds it",
    "w_bp": "default: band-pass bandwidth around w_c (envelope 100 Hz >> alpha_i)",
    "w_lp": "default: low-pass after demodulation",
    "x_eps_max": "default: bound on the integral of (21)",
    "carrier_delay": "default: one sample of computation delay",
    "w_max": "default: top speed, 2 p.u.; the runtime state's speed bounds",
}


@dataclass(frozen=True)
class IpmsmDrive:
    """A drive of the speed-adaptive observer family: IPMSM + speed-adaptive flux observer."""

    name: str
    kind: str
    source: str
    file: str
    rating: Rating
    base: Base
    motor: PmsmMotor
    estimate: PmsmEstimate
    control: Control
    observer: Observer
    injection: Injection
    runtime: Runtime | None = None  # [runtime], defaults filled in by the loader
    tuning: TuningSettings = field(  # optional [tuning] of `tune`
        default_factory=lambda: TuningSettings(law=AdaptiveLawSettings())
    )
    digest: str = ""  # sha256 of the TOML text: identifies the inputs in generated outputs
    warnings: tuple[str, ...] = ()  # plausibility warnings (design/plausibility.py), printed by every command
    startup: StartupSettings | None = None  # [startup] of the file (design/startup.py) or None: the rules

    def gain(self, name: str | None = None) -> Any:
        """The gain settings named ``name`` (default: ``[observer] gain``)."""
        name = name or self.observer.gain
        try:
            return self.observer.gains[name]
        except KeyError:
            have = ", ".join(self.observer.gains) or "none"
            raise UnknownName(f"{self.file}: no [observer.gains.{name}] (defined: {have})") from None

    @property
    def T_N(self) -> float:
        """Nominal torque [N m]."""
        return self.rating.T_N

    @property
    def w_base(self) -> float:
        """Per-unit speed base [rad/s, electrical]: ``[base] w``."""
        return self.base.w

    @property
    def pole_pairs(self) -> int:
        """Pole pairs."""
        return self.motor.p

    @property
    def envelope(self) -> Envelope:
        """The drive's operating range, read by analyze, tune, report and Monte-Carlo: the ``[tuning]``
        envelope with its torques widened to the torque limit +-T_max where they stop short of it (the
        speed loop applies +-T_max in every acceleration, motoring and regenerating; gains tuned at +-T_N
        only were unstable just beyond it: piippo2008's schedule, max Re +1.5 .. +11 1/s at
        T_max = 1.57 T_N for |w| >= 0.3 p.u.). A preset keeps its own: piippo2008 reproduces Piippo,
        Hinkkanen, Luomi (2008), tuned at +-T_N."""
        env = self.tuning.resolved
        return env if str(self.file).startswith("preset:") else env.widened(self.control.T_max)

    @property
    def T_s(self) -> float:
        """Sampling period [s]."""
        return self.control.T_s

    @property
    def run(self) -> Runtime:
        """The ``[runtime]`` section (the loader fills its defaults: a loaded drive always has it)."""
        if self.runtime is None:
            raise ValueError(f"{self.file}: the drive has no [runtime] section (load it with load_drive)")
        return self.runtime

    def pu_speed(self, w: Any) -> Any:
        """Electrical rad/s -> per unit of ``base.w``."""
        return w / self.base.w


def check_plausibility(drive: IpmsmDrive, context: Mapping[str, Any]) -> list[str]:
    """Warning lines of the plausibility checks; DriveFileError for the first error (naming its keys)."""
    m, keys, given, file = context["motor"], context["keys"], context["given"], drive.file
    findings = plausibility(
        m,
        n_N=drive.rating.n_N,
        T_N=drive.rating.T_N,
        I_N=drive.rating.I_N if given["I_N"] else None,
        f_N=drive.rating.f_N if given["f_N"] else None,
        u_dc=drive.control.u_dc,
        T_s=drive.control.T_s,
        w_max=drive.run.w_max,
        keys=keys,
    )
    out = warning_lines(findings, file)
    e = drive.estimate
    if drive.injection.enabled:
        xi = saliency(e.L_d, e.L_q)
        if xi == 0:
            raise DriveFileError(
                file,
                "injection.u_c",
                f"HF injection needs a salient motor: [estimate] L_d = L_q gives no error signal (19) "
                f'(K_eps = 0); set u_c = "0 V" (injection off), got {drive.injection.u_c:g} V',
            )
        if xi < SALIENCY_MIN:
            out.append(
                f"{file}: injection.u_c, estimate.L_d, estimate.L_q: HF injection on a motor of saliency "
                f"2|L_q - L_d|/(L_q + L_d) = {xi:.3g} (< {SALIENCY_MIN:g}): its error signal (19) is weak"
            )
    return out


def load_complete(data: Mapping[str, Any], file: str, digest: str, kind: str) -> IpmsmDrive:
    """Validate the complete data of a drive TOML of this family (every section present)."""
    check_keys(
        data,
        SECTIONS,
        file,
        "",
    )
    head = drive_header(data, file)
    rating = load_section(Rating, table(data, "rating", file), file, "rating")
    base = load_section(Base, table(data, "base", file), file, "base")
    motor = load_motor(data, file)
    estimate = load_estimate(data, file)
    rel = {"pu": base.w, "pu/s": base.w, "R_s_hat": estimate.R_s, "Rs_hat": estimate.R_s}
    control = _load_control(table(data, "control", file), file, rel, base)
    obs_t = table(data, "observer", file)
    observer = load_section(Observer, obs_t, file, "observer", rel, skip=("gains",))
    gains_t = table(obs_t, "gains", file, "observer.")
    gains: dict[str, Any] = {}
    for gname, gtab in gains_t.items():
        if gname not in GAIN_SCHEMAS:
            raise DriveFileError(
                file,
                f"observer.gains.{gname}",
                f"unknown gain law (known: {', '.join(GAIN_SCHEMAS)})",
            )
        if not isinstance(gtab, dict):
            raise DriveFileError(file, f"observer.gains.{gname}", "expected a table")
        g = load_section(GAIN_SCHEMAS[gname], gtab, file, f"observer.gains.{gname}", rel)
        if gname == "constant" and g.lambda1 <= -estimate.R_s:
            raise DriveFileError(
                file,
                "observer.gains.constant.lambda1",
                f"lambda1 = {g.lambda1:g} ohm must be > -R̂s = {-estimate.R_s:g} ohm (Section IV-B)",
            )
        gains[gname] = g
    if observer.gain not in gains:
        raise DriveFileError(
            file,
            "observer.gain",
            f"'{observer.gain}' has no [observer.gains.{observer.gain}] table",
        )
    observer = dataclasses.replace(observer, gains=gains)
    injection = load_section(Injection, table(data, "injection", file), file, "injection", rel)
    runtime = _load_runtime(data, file, rel)
    tuning = TuningSettings(envelope=tuning_envelope(base.w, rating.T_N), law=AdaptiveLawSettings())
    if "tuning" in data:
        tuning = load_tuning(table(data, "tuning", file), file, {**rel, "T_N": rating.T_N}, LAW_KEYS)
    return IpmsmDrive(
        name=head["name"],
        kind=kind,
        source=head["source"],
        file=file,
        rating=rating,
        base=base,
        motor=motor,
        estimate=estimate,
        control=control,
        observer=observer,
        injection=injection,
        runtime=runtime,
        tuning=tuning,
        digest=digest,
    )


def _load_control(t: Mapping[str, Any], file: str, rel: Mapping[str, float], base: Base) -> Control:
    """[control]; ``i_noise`` (the current sensor's noise, A rms per axis and sample) is optional:
    default I_NOISE_DEFAULT times the base current, e.g. 0.018 A for the paper's 6.08 A."""
    c = load_section(Control, t, file, "control", rel, optional=("i_noise", "i_resolution"))
    if "i_noise" in t:
        return c
    return dataclasses.replace(c, i_noise=I_NOISE_DEFAULT * base.i)


# the largest carrier delay [samples]: a computation delay is one sample, two with a slow PWM update;
# beyond a few the demodulation phase (delay + 1/2) w_c T_s is a wrong number, not a delay
CARRIER_DELAY_MAX = 10.0


def _load_runtime(data: Mapping[str, Any], file: str, rel: Mapping[str, float]) -> Runtime:
    """The optional [runtime] section; omitted keys take RUNTIME_DEFAULTS."""
    given = data.get("runtime", {})
    if not isinstance(given, dict):
        raise DriveFileError(file, "runtime", "expected a table [runtime]")
    merged = {**RUNTIME_DEFAULTS, **given}
    rt = load_section(Runtime, merged, file, "runtime", rel)
    if rt.discretization not in DISCRETIZATIONS:
        raise DriveFileError(
            file,
            "runtime.discretization",
            f"unknown discretization {rt.discretization!r} (known: {', '.join(DISCRETIZATIONS)})",
        )
    if rt.carrier_delay > CARRIER_DELAY_MAX:
        raise DriveFileError(
            file,
            "runtime.carrier_delay",
            f"{rt.carrier_delay:g} samples: must be in [0, {CARRIER_DELAY_MAX:g}] (the delay from the "
            "carrier command to the applied voltage, one sample of computation delay by default)",
        )
    return rt
