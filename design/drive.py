"""Drive descriptions: strict TOML loading into frozen dataclasses (motor, estimates, control, observer).

A drive description names its kind in ``[drive] kind``; each kind has its own schema, written here as
frozen dataclasses whose field metadata carries the physical dimension and the validity check. Loading
is strict: an unknown key, a missing key, a wrong type or unit, or a non-physical value raises
:class:`~sensorless.design.units.DriveFileError` naming the file and the dotted key.

Conventions (see docs/conventions.md): SI units; speeds are electrical angular speeds in rad/s; per-unit
values are accepted on input only ("0.13 pu") and are scaled by ``[base] w``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from sensorless.design.envelope import TuningSettings, load_tuning
from sensorless.design.units import DriveFileError, parse_quantity


def q(dim: str, check: str | None = "positive", doc: str = "") -> Any:
    """A dataclass field holding a quantity of dimension ``dim`` (SI), validated by ``check``."""
    return field(metadata={"dim": dim, "check": check, "doc": doc})


_CHECKS: dict[str, tuple[Callable[[float], bool], str]] = {
    "positive": (lambda x: x > 0, "must be > 0"),
    "nonnegative": (lambda x: x >= 0, "must be >= 0"),
    "any": (lambda x: True, ""),
}


# --------------------------------------------------------------------------------------------------
# Schema of kind "ipmsm-adaptive" (Piippo, Hinkkanen, Luomi 2008)
# --------------------------------------------------------------------------------------------------
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
class Motor:
    """True motor parameters, eqs. (1)-(3) and Table I."""

    p: int = q("integer", doc="pole pairs")
    R_s: float = q("resistance", doc="stator resistance [ohm]")
    L_d: float = q("inductance", doc="d-axis inductance [H]")
    L_q: float = q("inductance", doc="q-axis inductance [H]")
    psi_pm: float = q("flux", doc="permanent-magnet flux linkage [V s]")
    J: float = q("inertia", doc="total moment of inertia [kg m^2]")

    def vector(self) -> list[float]:
        """[R_s, L_d, L_q, psi_pm]: the electrical parameter vector the CasADi functions take."""
        return [self.R_s, self.L_d, self.L_q, self.psi_pm]


@dataclass(frozen=True)
class Estimate:
    """The observer's parameter estimates (R̂s, L̂d, L̂q, ψ̂pm); kept apart from the true motor."""

    R_s: float = q("resistance", doc="estimated stator resistance [ohm]")
    L_d: float = q("inductance", doc="estimated d-axis inductance [H]")
    L_q: float = q("inductance", doc="estimated q-axis inductance [H]")
    psi_pm: float = q("flux", doc="estimated PM flux linkage [V s]")

    def vector(self) -> list[float]:
        """[R̂s, L̂d, L̂q, ψ̂pm]."""
        return [self.R_s, self.L_d, self.L_q, self.psi_pm]


@dataclass(frozen=True)
class Control:
    """Control-system settings (Table II and Section VI)."""

    T_s: float = q("time", doc="sampling period [s]")
    alpha_c: float = q("angular", doc="current-control bandwidth [rad/s]")
    alpha_s: float = q("angular", doc="speed-control bandwidth [rad/s]")
    T_max: float = q("torque", doc="electromagnetic torque limit [N m]")
    u_dc: float = q("voltage", doc="nominal DC-link voltage [V]")


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
    u_c: float = q("voltage", doc="carrier amplitude at zero speed [V]")
    alpha_i: float = q("angular", doc="PI (21) bandwidth at zero speed [rad/s], eq. (22)")
    w_Delta: float = q("angular", doc="transition speed where injection reaches zero [rad/s]")


@dataclass(frozen=True)
class Runtime:
    """Discrete-time runtime settings (not in the paper; choices in docs/runtime.md). Optional section.

    Every key may be omitted; RUNTIME_DEFAULTS are the documented choices for the paper-000 drive.
    """

    discretization: str = field(metadata={"dim": "choice", "doc": "euler or heun"})
    w_bp: float = q("angular", doc="band-pass -3 dB bandwidth around w_c [rad/s]")
    w_lp: float = q("angular", doc="low-pass cut-off after demodulation [rad/s]")
    x_eps_max: float = q("angular", check="nonnegative", doc="bound on the integral of (21) [rad/s]")
    carrier_delay: float = q(
        "dimensionless", check="nonnegative", doc="samples from carrier command to applied voltage"
    )


RUNTIME_DEFAULTS: dict[str, Any] = {
    "discretization": "heun",
    "w_bp": "200 Hz",
    "w_lp": "100 Hz",
    "x_eps_max": "0.1 pu",
    "carrier_delay": 1.0,
}
DISCRETIZATIONS = ("euler", "heun")


@dataclass(frozen=True)
class IpmsmDrive:
    """A drive of kind 'ipmsm-adaptive': IPMSM + speed-adaptive flux observer (paper 000)."""

    name: str
    source: str
    file: str
    rating: Rating
    base: Base
    motor: Motor
    estimate: Estimate
    control: Control
    observer: Observer
    injection: Injection
    runtime: Runtime | None = None  # [runtime], defaults filled in by the loader
    tuning: TuningSettings = field(default_factory=TuningSettings)  # optional [tuning] of `tune`
    digest: str = ""  # sha256 of the TOML text: identifies the inputs in generated outputs

    kind = "ipmsm-adaptive"

    def gain(self, name: str | None = None) -> Any:
        """The gain settings named ``name`` (default: ``[observer] gain``)."""
        name = name or self.observer.gain
        try:
            return self.observer.gains[name]
        except KeyError:
            have = ", ".join(self.observer.gains) or "none"
            raise KeyError(f"{self.file}: no [observer.gains.{name}] (defined: {have})") from None

    @property
    def T_N(self) -> float:
        """Nominal torque [N m]."""
        return self.rating.T_N

    def pu_speed(self, w: Any) -> Any:
        """Electrical rad/s -> per unit of ``base.w``."""
        return w / self.base.w


# --------------------------------------------------------------------------------------------------
# Generic strict loading
# --------------------------------------------------------------------------------------------------
def _table(data: Mapping[str, Any], key: str, file: str, prefix: str = "") -> Mapping[str, Any]:
    full = f"{prefix}{key}"
    if key not in data:
        raise DriveFileError(file, full, "missing section")
    t = data[key]
    if not isinstance(t, dict):
        raise DriveFileError(file, full, "expected a table [section]")
    return t


def load_section(
    cls: type,
    table: Mapping[str, Any],
    file: str,
    section: str,
    relative: Mapping[str, float] | None = None,
    skip: tuple[str, ...] = (),
) -> Any:
    """Build dataclass ``cls`` from a TOML table, strictly; ``relative`` maps relative units to SI."""
    relative = relative or {}
    names = [f.name for f in dataclasses.fields(cls) if f.name not in skip]
    for k in table:
        if k not in names and k not in skip:
            allowed = ", ".join(names) or "(no keys)"
            raise DriveFileError(file, f"{section}.{k}", f"unknown key (allowed: {allowed})")
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        key = f"{section}.{f.name}"
        dim = f.metadata.get("dim")
        if f.name not in table:
            raise DriveFileError(file, key, f"missing key ({f.metadata.get('doc', dim)})")
        raw = table[f.name]
        if dim == "choice":
            if not isinstance(raw, str):
                raise DriveFileError(file, key, f"expected a string, got {raw!r}")
            values[f.name] = raw
            continue
        x, rel = parse_quantity(raw, dim, file=file, key=key)
        if rel is not None:
            if rel not in relative:
                raise DriveFileError(file, key, f"unit '{rel}' cannot be resolved here")
            x *= relative[rel]
        check = f.metadata.get("check") or "any"
        ok, why = _CHECKS[check]
        if not ok(x):
            raise DriveFileError(file, key, f"non-physical value {raw!r}: {why}")
        values[f.name] = int(x) if dim == "integer" else x
    return cls(**values)


def _check_keys(data: Mapping[str, Any], allowed: tuple[str, ...], file: str, prefix: str) -> None:
    for k in data:
        if k not in allowed:
            raise DriveFileError(file, f"{prefix}{k}", f"unknown key (allowed: {', '.join(allowed)})")


def drive_header(data: Mapping[str, Any], file: str) -> Mapping[str, Any]:
    """The [drive] table common to every kind: name, kind, source (strings)."""
    head = _table(data, "drive", file)
    _check_keys(head, ("name", "kind", "source"), file, "drive.")
    for k in ("name", "source"):
        if not isinstance(head.get(k), str):
            raise DriveFileError(file, f"drive.{k}", "missing key or not a string")
    return head


def _load_ipmsm(data: Mapping[str, Any], file: str, digest: str) -> IpmsmDrive:
    _check_keys(
        data,
        (
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
        ),
        file,
        "",
    )
    head = drive_header(data, file)
    rating = load_section(Rating, _table(data, "rating", file), file, "rating")
    base = load_section(Base, _table(data, "base", file), file, "base")
    motor = load_section(Motor, _table(data, "motor", file), file, "motor")
    if motor.p < 1:
        raise DriveFileError(file, "motor.p", f"non-physical value {motor.p}: must be >= 1")
    estimate = load_section(Estimate, _table(data, "estimate", file), file, "estimate")
    rel = {"pu": base.w, "R_s_hat": estimate.R_s, "Rs_hat": estimate.R_s}
    control = load_section(Control, _table(data, "control", file), file, "control", rel)
    obs_t = _table(data, "observer", file)
    observer = load_section(Observer, obs_t, file, "observer", rel, skip=("gains",))
    gains_t = _table(obs_t, "gains", file, "observer.")
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
    injection = load_section(Injection, _table(data, "injection", file), file, "injection", rel)
    runtime = _load_runtime(data, file, rel)
    tuning = TuningSettings()
    if "tuning" in data:
        tuning = load_tuning(_table(data, "tuning", file), file, {**rel, "T_N": rating.T_N})
    return IpmsmDrive(
        name=head["name"],
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


def _load_runtime(data: Mapping[str, Any], file: str, rel: Mapping[str, float]) -> Runtime:
    """The optional [runtime] section; omitted keys take RUNTIME_DEFAULTS (docs/runtime.md)."""
    table = data.get("runtime", {})
    if not isinstance(table, dict):
        raise DriveFileError(file, "runtime", "expected a table [runtime]")
    merged = {**RUNTIME_DEFAULTS, **table}
    rt = load_section(Runtime, merged, file, "runtime", rel)
    if rt.discretization not in DISCRETIZATIONS:
        raise DriveFileError(
            file,
            "runtime.discretization",
            f"unknown discretization {rt.discretization!r} (known: {', '.join(DISCRETIZATIONS)})",
        )
    return rt


def _load_pmac(data: Mapping[str, Any], file: str, digest: str) -> Any:
    """Kind 'pmac-reduced-order' (paper 002), schema in design/drive_pmac.py (imported on use)."""
    from sensorless.design.drive_pmac import load_pmac

    return load_pmac(data, file, digest)


# kind -> loader(data, file, digest). Other drive kinds register here.
KINDS: dict[str, Callable[[Mapping[str, Any], str, str], Any]] = {
    "ipmsm-adaptive": _load_ipmsm,
    "pmac-reduced-order": _load_pmac,
}


def preset_names() -> list[str]:
    """Names of the built-in presets (package data)."""
    files = resources.files("sensorless.design.presets").iterdir()
    return sorted(p.name[:-5] for p in files if p.name.endswith(".toml"))


def load_drive_text(text: str, file: str) -> Any:
    """Parse and validate the TOML ``text``; ``file`` is the name used in error messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DriveFileError(file, "(syntax)", f"not valid TOML: {e}") from None
    head = _table(data, "drive", file)
    kind = head.get("kind")
    if kind not in KINDS:
        raise DriveFileError(file, "drive.kind", f"unknown drive kind {kind!r} (known: {', '.join(KINDS)})")
    digest = hashlib.sha256(text.encode()).hexdigest()
    return KINDS[kind](data, file, digest)


def load_drive(spec: str | Path) -> Any:
    """Load a built-in preset by name (e.g. ``"piippo2008"``) or a drive TOML file by path."""
    spec_s = str(spec)
    path = Path(spec_s)
    if path.suffix != ".toml" and "/" not in spec_s and spec_s in preset_names():
        res = resources.files("sensorless.design.presets") / f"{spec_s}.toml"
        return load_drive_text(res.read_text(encoding="utf-8"), f"preset:{spec_s}")
    if not path.is_file():
        raise FileNotFoundError(
            f"{spec_s}: no such drive file, and not a preset (presets: {', '.join(preset_names())})"
        )
    return load_drive_text(path.read_text(encoding="utf-8"), str(path))


def per_unit_speed_text(drive: Any, w: float) -> str:
    """'0.0200 p.u. (9.42 rad/s)' for messages."""
    return f"{w / drive.base.w:.4f} p.u. ({w:.4g} rad/s)"


__all__ = [
    "GAIN_SCHEMAS",
    "KINDS",
    "Base",
    "ConstantGain",
    "Control",
    "DriveFileError",
    "Estimate",
    "Injection",
    "IpmsmDrive",
    "Motor",
    "Observer",
    "Rating",
    "Runtime",
    "SpeedGain",
    "ZeroGain",
    "load_drive",
    "load_drive_text",
    "load_section",
    "preset_names",
]
