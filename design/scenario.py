"""Simulation scenarios as data: strict TOML loading of references, load, noise and parameter errors.

A scenario says what happens to a drive over time: speed (or torque) reference and load torque as
piecewise profiles, the controllers' feedback (estimates or sensor), initial conditions, measurement
noise and parameter errors, plus the keys its observer family adds (``ObserverFamily.scenario_options``,
e.g. the adaptive observer's gain choice and HF injection), kept in :attr:`Scenario.options`. Each
family ships its papers' experiments as built-in scenarios named after their figures, in its own
``scenarios`` package (``sensorless simulate --list``). Loading is strict like drive files: unknown or
missing keys, wrong units and non-physical values raise :class:`DriveFileError` naming the file and
the dotted key. The schema is documented in docs/simulation.md.
"""

from __future__ import annotations

import itertools
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from sensorless.design import registry
from sensorless.design.drive_file import check_name, read_text
from sensorless.design.family import Drive, DriveScales, Scaled, require
from sensorless.design.units import DriveFileError, check_magnitude, parse_quantity

INTERPOLATIONS = ("step", "linear")
FEEDBACK = ("observer", "sensor")
MODES = ("speed", "torque")
# the trace panels of every drive's simulation (reports/sim_figure.py draws them from the traces every
# loop records: speeds, torques, position error); a family adds its own (ObserverFamily.panels)
GENERIC_PANELS = ("speed", "speed_error", "tracking_error", "torque", "theta_error")


@dataclass(frozen=True)
class Profile:
    """A piecewise signal: breakpoints t [s] (increasing) and values (SI); step or linear between."""

    t: tuple[float, ...] = (0.0,)
    value: tuple[float, ...] = (0.0,)
    interpolation: str = "step"

    def sample(self, t: np.ndarray) -> np.ndarray:
        """Values at times ``t``; before the first breakpoint the first value, after the last the last."""
        tb, vb = np.asarray(self.t), np.asarray(self.value)
        if self.interpolation == "linear":
            return np.interp(t, tb, vb)
        k = np.searchsorted(tb, t, side="right") - 1
        return vb[np.clip(k, 0, len(vb) - 1)]


@dataclass(frozen=True)
class Scenario:
    """A simulation scenario (see the module docstring and docs/simulation.md)."""

    name: str
    title: str
    source: str
    kind: str  # drive kind it is written for
    file: str
    duration: float  # [s]
    figure: tuple[str, ...]  # panels of the figure, top to bottom
    discretization: str | None  # None: the drive's choice
    feedback: str  # "observer" (sensorless) or "sensor"
    mode: str  # "speed" or "torque"
    stiff_load: bool  # the load machine prescribes the speed (w_ref profile)
    speed_filter: float | None  # low-pass bandwidth on the speed feedback [rad/s]; None: speed_filter_of
    current_bandwidth: float | None  # current-control bandwidth [rad/s]; None: the drive's
    w_m0: float  # initial electrical speed [rad/s]
    theta_m0: float  # initial rotor angle [rad]
    theta_err0: float  # initial position estimation error theta_m - theta_hat [rad]
    speed_reference: Profile
    load_torque: Profile
    torque_reference: Profile
    viscous: float  # extra viscous load B [N m s/rad] (added to the drive's own)
    i_noise: float  # standard deviation of the current-measurement noise, per axis [A]
    seed: int
    estimate_scale: Mapping[str, float] = field(default_factory=dict)  # parameter errors
    # the open-loop I-f start below the design's minimum sensorless speed, where it has one
    # (symbolic/startup.py, design/startup.py)
    startup: bool = False
    options: Mapping[str, Any] = field(default_factory=dict)  # the family's keys (scenario_options)


REQUIRED = object()

# section -> key -> (dimension or type, default in SI; REQUIRED = must be given)
_SCHEMA: dict[str, dict[str, tuple[str, Any]]] = {
    "scenario": {
        "name": ("str", REQUIRED),
        "title": ("str", REQUIRED),
        "source": ("str", ""),
        "kind": ("str", REQUIRED),
        "duration": ("time", REQUIRED),
        "figure": ("panels", ("speed", "torque", "theta_error")),  # of panel_names(kind)
    },
    "observer": {
        "discretization": ("str", None),
    },
    "control": {
        "feedback": ("str", "observer"),
        "mode": ("str", "speed"),
        "stiff_load": ("bool", False),
        "speed_filter": ("angular", None),  # None: speed_filter_of (10 x the speed loop, >= 50 Hz)
        "current_bandwidth": ("angular", None),  # None: the drive's (reduced-order drive: 2 pi 400 rad/s)
        "startup": ("bool", False),  # the I-f start below the minimum sensorless speed (design/startup.py)
    },
    "initial": {
        "w_m": ("angular_any", 0.0),
        "theta_m": ("angle", 0.0),
        "theta_error": ("angle", 0.0),
    },
    "noise": {"i_std": ("current", 0.0), "seed": ("int", 0)},
    "mechanics": {"B": ("viscous", 0.0)},
    "estimate_scale": {},  # the family's keys (ObserverFamily.estimate_keys), factors of default 1
}
_PROFILES = {"speed_reference": "angular_any", "load_torque": "torque", "torque_reference": "torque"}


def _builtin(kind: str) -> dict[str, Any]:
    """Built-in scenario name -> resource of the family of ``kind``."""
    pkg = registry.family(kind).scenarios
    if pkg is None:
        return {}
    return {p.name[:-5]: p for p in resources.files(pkg).iterdir() if p.name.endswith(".toml")}


def builtin_names(kind: str) -> list[str]:
    """Names of the built-in scenarios of the family of drive kind ``kind``."""
    return sorted(_builtin(kind))


def panel_names(kind: str | None) -> tuple[str, ...]:
    """The trace panels a scenario of drive kind ``kind`` may show: the shared ones and its family's."""
    own = registry.family(kind).panels if kind is not None else ()
    return GENERIC_PANELS + tuple(p.name for p in own)


def _schema(kind: str | None) -> dict[str, dict[str, tuple[str, Any]]]:
    """The common schema plus the keys of the family of ``kind`` (if known)."""
    schema = {k: dict(v) for k, v in _SCHEMA.items()}
    if kind is not None:
        fam = registry.family(kind)
        for section, keys in fam.scenario_options.items():
            schema.setdefault(section, {}).update(keys)
        schema["estimate_scale"].update({k: ("factor", 1.0) for k in fam.estimate_keys})
    return schema


def _value(raw: Any, dim: str, file: str, key: str, rel: Mapping[str, float]) -> Any:
    if dim == "str":
        if not isinstance(raw, str):
            raise DriveFileError(file, key, f"expected a string, got {raw!r}")
        return raw
    if dim == "bool":
        if not isinstance(raw, bool):
            raise DriveFileError(file, key, f"expected true or false, got {raw!r}")
        return raw
    if dim == "int":
        if not isinstance(raw, int) or isinstance(raw, bool) or raw < 0:
            raise DriveFileError(file, key, f"expected a non-negative integer, got {raw!r}")
        return raw
    if dim == "factor":
        x, _ = parse_quantity(raw, "dimensionless", file=file, key=key)
        if x <= 0:
            raise DriveFileError(file, key, f"non-physical scale factor {raw!r}: must be > 0")
        return x
    if dim == "angle":
        if isinstance(raw, str) and raw.strip().endswith("deg"):
            x, _ = parse_quantity(raw.strip()[:-3], "dimensionless", file=file, key=key)
            return np.deg2rad(x)
        if isinstance(raw, str) and raw.strip().endswith("rad"):
            raw = raw.strip()[:-3]
        x, _ = parse_quantity(raw, "dimensionless", file=file, key=key)
        return x
    if dim == "torque" and isinstance(raw, str) and raw.strip().endswith("T_N"):
        num = raw.strip()[:-3].strip() or "1"
        x, _ = parse_quantity(num, "dimensionless", file=file, key=key)
        if "T_N" not in rel:
            raise DriveFileError(file, key, "'T_N' needs a drive with a nominal torque")
        return check_magnitude(x * rel["T_N"], raw, file=file, key=key)
    if dim in ("angular_any", "angular") and isinstance(raw, str) and raw.strip().endswith(("rpm", "r/min")):
        num = raw.strip().removesuffix("rpm").removesuffix("r/min")
        x, _ = parse_quantity(num, "dimensionless", file=file, key=key)
        x = check_magnitude(x * rel["rpm"], raw, file=file, key=key)
        if dim == "angular" and x < 0:
            raise DriveFileError(file, key, f"non-physical value {raw!r}: must be >= 0")
        return x
    base_dim = {"angular_any": "angular"}.get(dim, dim)
    x, unit = parse_quantity(raw, base_dim, file=file, key=key)
    if unit is not None:
        if unit not in rel:
            raise DriveFileError(file, key, f"unit '{unit}' cannot be resolved here")
        x = check_magnitude(x * rel[unit], raw, file=file, key=key)
    if dim in ("time", "angular", "current", "viscous") and x < 0:
        raise DriveFileError(file, key, f"non-physical value {raw!r}: must be >= 0")
    if dim == "time" and key.endswith("duration") and x <= 0:
        raise DriveFileError(file, key, f"non-physical value {raw!r}: must be > 0")
    return x


def _panels(raw: object, allowed: tuple[str, ...], file: str, key: str) -> tuple[str, ...]:
    """A figure's list of panels, each one of ``allowed`` (``panel_names`` of the scenario's kind)."""
    if not isinstance(raw, list) or not raw or any(p not in allowed for p in raw):
        raise DriveFileError(file, key, f"expected a list of panels from: {', '.join(allowed)}")
    return tuple(raw)


def _section(
    data: Mapping[str, Any],
    name: str,
    file: str,
    rel: Mapping[str, float],
    schema_all: Mapping[str, Any],
    panels: tuple[str, ...],
) -> dict[str, Any]:
    schema = schema_all[name]
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise DriveFileError(file, name, "expected a table [section]")
    for k in table:
        if k not in schema:
            raise DriveFileError(file, f"{name}.{k}", f"unknown key (allowed: {', '.join(schema)})")
    out = {}
    for k, (dim, default) in schema.items():
        key = f"{name}.{k}"
        if k not in table:
            if default is REQUIRED:
                raise DriveFileError(file, key, "missing key")
            out[k] = default
            continue
        out[k] = (
            _panels(table[k], panels, file, key) if dim == "panels" else _value(table[k], dim, file, key, rel)
        )
    return out


def _profile(data: Mapping[str, Any], name: str, file: str, rel: Mapping[str, float]) -> Profile:
    table = data.get(name)
    if table is None:
        return Profile()
    if not isinstance(table, dict):
        raise DriveFileError(file, name, "expected a table [section]")
    for k in table:
        if k not in ("t", "value", "interpolation"):
            raise DriveFileError(file, f"{name}.{k}", "unknown key (allowed: t, value, interpolation)")
    interp = table.get("interpolation", "step")
    if interp not in INTERPOLATIONS:
        raise DriveFileError(file, f"{name}.interpolation", f"expected one of: {', '.join(INTERPOLATIONS)}")
    ts, vs = table.get("t"), table.get("value")
    for k, v in (("t", ts), ("value", vs)):
        if not isinstance(v, list) or not v:
            raise DriveFileError(file, f"{name}.{k}", "expected a non-empty list")
    if len(ts) != len(vs):
        raise DriveFileError(file, f"{name}.value", f"{len(vs)} values for {len(ts)} times")
    t = [_value(x, "time", file, f"{name}.t[{i}]", rel) for i, x in enumerate(ts)]
    if any(b < a for a, b in itertools.pairwise(t)):
        raise DriveFileError(file, f"{name}.t", "times must not decrease")
    v = [_value(x, _PROFILES[name], file, f"{name}.value[{i}]", rel) for i, x in enumerate(vs)]
    return Profile(tuple(t), tuple(v), interp)


def load_scenario_text(text: str, file: str, rel: Mapping[str, float]) -> Scenario:
    """Parse and validate scenario TOML ``text``; ``rel`` resolves 'pu' and 'T_N' (from the drive)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DriveFileError(file, "(syntax)", f"not valid TOML: {e}") from None
    if "scenario" not in data:
        raise DriveFileError(file, "scenario", "missing section")
    head0 = data["scenario"]
    kind = head0.get("kind") if isinstance(head0, dict) else None
    if isinstance(kind, str) and kind not in registry.kinds():
        known = ", ".join(registry.kinds())
        raise DriveFileError(file, "scenario.kind", f"unknown drive kind {kind!r} (known: {known})")
    schema = _schema(kind if isinstance(kind, str) else None)
    allowed = (*schema, *_PROFILES)
    for k in data:
        if k not in allowed:
            raise DriveFileError(file, k, f"unknown section (allowed: {', '.join(allowed)})")
    panels = panel_names(kind if isinstance(kind, str) else None)
    s = {name: _section(data, name, file, rel, schema, panels) for name in schema}
    c, o = s["control"], s["observer"]
    for key, val, allowed_vals in (
        ("control.feedback", c["feedback"], FEEDBACK),
        ("control.mode", c["mode"], MODES),
    ):
        if val not in allowed_vals:
            raise DriveFileError(file, key, f"{val!r}: expected one of: {', '.join(allowed_vals)}")
    if c["stiff_load"] and c["mode"] != "torque":
        raise DriveFileError(file, "control.stiff_load", "a prescribed speed needs control.mode = 'torque'")
    if c["mode"] == "torque" and "torque_reference" not in data:
        raise DriveFileError(file, "torque_reference", "missing section (control.mode = 'torque')")
    if c["speed_filter"] is not None and c["speed_filter"] <= 0:
        raise DriveFileError(file, "control.speed_filter", "must be > 0")
    head = s["scenario"]
    return Scenario(
        name=check_name(head["name"], file, "scenario.name"),
        title=head["title"],
        source=head["source"],
        kind=head["kind"],
        file=file,
        duration=head["duration"],
        figure=head["figure"],
        discretization=o["discretization"],
        feedback=c["feedback"],
        mode=c["mode"],
        stiff_load=c["stiff_load"],
        speed_filter=c["speed_filter"],
        current_bandwidth=c["current_bandwidth"],
        w_m0=s["initial"]["w_m"],
        theta_m0=s["initial"]["theta_m"],
        theta_err0=s["initial"]["theta_error"],
        speed_reference=_profile(data, "speed_reference", file, rel),
        load_torque=_profile(data, "load_torque", file, rel),
        torque_reference=_profile(data, "torque_reference", file, rel),
        viscous=s["mechanics"]["B"],
        i_noise=s["noise"]["i_std"],
        seed=s["noise"]["seed"],
        estimate_scale=s["estimate_scale"],
        startup=c["startup"],
        options={
            k: s[sec][k]
            for sec, keys in schema.items()
            if sec != "estimate_scale"
            for k in keys
            if k not in _SCHEMA.get(sec, {})
        },
    )


def drive_units(drive: Drive) -> dict[str, float]:
    """Drive-relative units a scenario may use: 'pu' (base speed), 'rpm' (mechanical r/min, converted
    to electrical rad/s with the pole pairs) and 'T_N' (nominal torque)."""
    return {"pu": drive.w_base, "T_N": drive.T_N, "rpm": np.pi / 30 * drive.pole_pairs}


def load_scenario(spec: str | Path, drive: Drive) -> Scenario:
    """A built-in scenario by name (e.g. ``"fig9b"``) or a scenario TOML file, checked against ``drive``."""
    spec_s = str(spec)
    path = Path(spec_s)
    rel = drive_units(drive)
    if path.suffix != ".toml" and "/" not in spec_s:
        res = _builtin(drive.kind).get(spec_s)
        generic = {}
        if res is None and spec_s in GENERIC:
            generic = {sc.name: sc for sc in generic_scenarios(drive)}
        if spec_s in generic:
            return generic[spec_s]
        if res is None:
            have = ", ".join(builtin_names(drive.kind) + list(GENERIC)) or "none"
            raise FileNotFoundError(
                f"{spec_s}: no such scenario file, and not a built-in one for "
                f"{drive.kind} drives (built-in: {have})"
            )
        sc = load_scenario_text(res.read_text(encoding="utf-8"), f"scenario:{spec_s}", rel)
    else:
        if not path.is_file():
            raise FileNotFoundError(f"{spec_s}: no such scenario file")
        sc = load_scenario_text(read_text(path), str(path), rel)
    if sc.kind != drive.kind:
        raise DriveFileError(
            sc.file,
            "scenario.kind",
            f"written for {sc.kind!r} drives, but {drive.file} is a {drive.kind!r} drive",
        )
    return sc


SPEED_FILTER_MIN = 2 * np.pi * 50  # the papers' drives: 10 x Piippo et al.'s 5-Hz speed loop


def speed_filter_of(sc: Scenario, alpha_s: float) -> float:
    """The speed-feedback low-pass bandwidth [rad/s] of ``sc`` in a speed loop of bandwidth ``alpha_s``:
    the scenario's, else 10 alpha_s and at least 2 pi 50 rad/s (a filter near the loop's own bandwidth
    makes a fast servo's speed loop limit-cycle)."""
    return sc.speed_filter if sc.speed_filter is not None else default_speed_filter(alpha_s)


def default_speed_filter(alpha_s: float) -> float:
    """The speed-feedback low-pass bandwidth [rad/s] a scenario that gives none runs: 10 alpha_s, at least
    2 pi 50 rad/s."""
    return max(SPEED_FILTER_MIN, 10 * alpha_s)


# --------------------------------------------------------------------------------------------------
# Generic scenarios, scaled to a drive
# --------------------------------------------------------------------------------------------------
GENERIC = ("speed_steps", "load_steps", "reversal", "start", "low_hold")  # low_hold: DriveScales.hold_speed
HOLD_ERROR_DEG = 5.0  # low_hold starts this far off the rotor [deg, electrical]


def generic_times(sc: DriveScales) -> dict[str, float]:
    """The time scales of the generic scenarios [s]: ``t_seg`` = 1.5 t_acc + 6/alpha_s, where t_acc
    changes the speed by 1 p.u. against the rated load at the torque limit and 6/alpha_s lets the speed
    loop settle; ``t_ramp`` = 3 t_seg, the slow reversal's ramp over 1 p.u.; ``t_rise``, the load's
    rise time: a load ramping to T_N in t_rise makes a speed loop of bandwidth alpha_s lag by about
    1/(tau_m alpha_s^2 t_rise) p.u., so t_rise = 10/(tau_m alpha_s^2) keeps the dip near 0.1 p.u. (at
    most t_seg/2): the checks test the observer, not the speed controller's stiffness."""
    t_seg = 1.5 * sc.t_acc + 6 / sc.alpha_s
    t_rise = min(10 / (sc.tau_m * sc.alpha_s**2), t_seg / 2)
    return {"t_acc": sc.t_acc, "tau_m": sc.tau_m, "t_seg": t_seg, "t_ramp": 3 * t_seg, "t_rise": t_rise}


ZERO_SPEED_LOW_PU = 0.25  # speed_steps' low step where the observer does not run through zero speed


def zero_speed_limit(drive: Drive) -> str:
    """Why the drive's observer does not run through zero speed in closed loop (its family's
    ``DriveScales.zero_speed``); "" where it does, or where its family gives no scales."""
    fam = registry.family_of(drive)
    return fam.scales(drive).zero_speed if isinstance(fam, Scaled) else ""


def spins_up(drive: Drive) -> bool:
    """Whether a drive whose observer does not run through zero speed still starts once from
    standstill by its open-loop start (``DriveScales.spins_up``): the generic start stays a check."""
    fam = registry.family_of(drive)
    return fam.scales(drive).spins_up if isinstance(fam, Scaled) else False


def crosses_zero(sc: Scenario) -> bool:
    """Whether the scenario's speed (initial speed and speed reference) changes sign."""
    w = np.array([sc.w_m0, *sc.speed_reference.value])
    return bool(w.min() < 0 < w.max())


def generic_scenarios(drive: Drive, hold: bool = True) -> list[Scenario]:
    """The built-in generic scenarios of any drive whose family gives its scales, in per unit of its
    own rating, with times scaled by :func:`generic_times` (docs/simulation.md, "Generic scenarios"):

    - ``speed_steps``: from 0.5 p.u. unloaded, rated load applied, steps to 1, -0.5 and 0.5 p.u. (two
      reversals through zero under load, motoring and regenerating); to 1, 0.25 and 0.5 p.u. where the
      family says its observer does not run through zero speed (:func:`zero_speed_limit`);
    - ``load_steps``: at 0.2 p.u., the load changes 0 -> T_N -> -T_N -> 0 (motoring, regenerating);
    every load change ramps in ``t_rise`` (:func:`generic_times`);
    - ``reversal``: a slow ramp from 0.5 to -0.5 p.u. at rated load (Piippo et al. 2008 Fig. 10, scaled;
      simulate-able for every drive, but not one of the report's checks where the observer does not
      run through zero speed: reports/time_domain.py);
    - the speed steps, the reversal and the start run through the open-loop I-f start below the
      design's minimum sensorless speed where it does not hold zero speed (``[control] startup``:
      design/pmsm_drive.py ``startup_setup``);
    - ``start``: from standstill, rated load applied in ``t_rise``, then a ramp to 0.5 p.u. in
      ``t_seg``, through the open-loop I-f start where the design does not hold zero speed
      (``[control] startup``: design/pmsm_drive.py ``startup_setup``).
    - ``low_hold`` (``hold``, and only where the family names a low-speed mechanism of its own:
      ``DriveScales.hold_speed``): unloaded at -hold_speed from a HOLD_ERROR_DEG angle error for
      ``hold_time``, the speed loop closed on the estimate.
    """
    fam = require(registry.family_of(drive), Scaled)
    scales = fam.scales(drive)
    t = generic_times(scales)
    seg, ramp, r = t["t_seg"], t["t_ramp"], t["t_rise"]
    # an observer that does not run through zero speed steps down to ZERO_SPEED_LOW_PU, not -0.5 p.u.
    low = f"{ZERO_SPEED_LOW_PU:g}" if scales.zero_speed else "-0.5"
    # the I-f start where the family's observer may be taken through zero speed at all (a family that
    # says it may not stays above it: its loop need not model a start)
    su = "" if scales.zero_speed else "[control]\nstartup = true\n"
    g = lambda x: f"{x:.6g}"  # noqa: E731
    head = (
        f'kind = "{drive.kind}"\nsource = "generic scenario, scaled to the drive: t_seg = {g(seg)} s '
        f'(docs/simulation.md)"\n'
    )
    texts = {
        "speed_steps": (
            f"Speed steps at rated load (0.5, 1, {low}, 0.5 p.u.)",
            5 * seg,
            '["speed", "torque", "theta_error"]',
            f'{su}[initial]\nw_m = "0.5 pu"\n'
            f"[speed_reference]\nt = [0, {g(2 * seg)}, {g(3 * seg)}, {g(4 * seg)}]\n"
            f'value = ["0.5 pu", "1 pu", "{low} pu", "0.5 pu"]\n'
            f'[load_torque]\ninterpolation = "linear"\nt = [0, {g(seg)}, {g(seg + r)}]\n'
            'value = ["0 Nm", "0 Nm", "1 T_N"]\n',
        ),
        "load_steps": (
            "Load steps at 0.2 p.u. (0, T_N, -T_N, 0)",
            4 * seg,
            '["speed", "torque", "theta_error"]',
            '[initial]\nw_m = "0.2 pu"\n[speed_reference]\nt = [0]\nvalue = ["0.2 pu"]\n'
            '[load_torque]\ninterpolation = "linear"\n'
            f"t = [0, {g(seg)}, {g(seg + r)}, {g(2 * seg)}, {g(2 * seg + 2 * r)}, {g(3 * seg)}, "
            f"{g(3 * seg + r)}]\n"
            'value = ["0 Nm", "0 Nm", "1 T_N", "1 T_N", "-1 T_N", "-1 T_N", "0 Nm"]\n',
        ),
        "reversal": (
            "Slow reversal at rated load (0.5 to -0.5 p.u.)",
            ramp + 2 * seg,
            '["speed", "torque", "theta_error"]',
            f'{su}[initial]\nw_m = "0.5 pu"\n'
            f'[speed_reference]\ninterpolation = "linear"\nt = [0, {g(seg)}, {g(seg + ramp)}]\n'
            'value = ["0.5 pu", "0.5 pu", "-0.5 pu"]\n'
            f'[load_torque]\ninterpolation = "linear"\nt = [0, {g(seg / 2)}, {g(seg / 2 + r)}]\n'
            'value = ["0 Nm", "0 Nm", "1 T_N"]\n',
        ),
        "start": (
            "Start from standstill against rated load (0 to 0.5 p.u.)",
            r + 2 * seg,
            '["speed", "torque", "theta_error"]',
            '[control]\nstartup = true\n[initial]\nw_m = "0 pu"\n'
            f'[speed_reference]\ninterpolation = "linear"\nt = [0, {g(r)}, {g(r + seg)}]\n'
            'value = ["0 pu", "0 pu", "0.5 pu"]\n'
            f'[load_torque]\ninterpolation = "linear"\nt = [0, {g(r)}]\nvalue = ["0 Nm", "1 T_N"]\n',
        ),
    }
    if hold and scales.hold_speed > 0:  # the observer's own low-speed mechanism (an HF injection) in the loop
        w_h = g(-scales.hold_speed / scales.w_base)
        texts["low_hold"] = (
            f"Unloaded hold at {w_h} p.u., inside the observer's own low-speed range",
            scales.hold_time,
            '["speed", "torque", "theta_error"]',
            f'[initial]\nw_m = "{w_h} pu"\ntheta_error = "{HOLD_ERROR_DEG:g} deg"\n'
            f'[speed_reference]\nt = [0]\nvalue = ["{w_h} pu"]\n',
        )
    rel = drive_units(drive)
    out = []
    for name, (title, duration, figure, body) in texts.items():
        text = (
            f'[scenario]\nname = "{name}"\ntitle = "{title}"\n{head}duration = "{g(duration)} s"\n'
            f"figure = {figure}\n{body}"
        )
        out.append(load_scenario_text(text, f"generic:{name}", rel))
    return out
