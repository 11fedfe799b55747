"""Firmware configuration files in and out: what VESC, ODrive and SimpleFOC store, as drive values.

Each firmware has a module here (vesc.py, odrive.py, simplefoc.py) with its field names, units and
conventions (docs/families/pmsm_flux_observer_firmware.md: the facts and their public sources).
This module holds what they share:

- :class:`Imported`: the minimal drive file an import writes (TOML text, each converted value with its
  rule as a comment) and the lines said on stderr: which values were missing, what was assumed and
  which option supplies each, which of two redundant values was used and why;
- :class:`FirmwareDrive`: the typed record an export reads (the values the firmware is given, its
  loop period and the law's gains), built from a drive and a gain set by the family's report hooks;
- :class:`Fields`: a firmware file's fields read strictly (a bad value is one line naming the file
  and the field);
- :func:`choose_flux`: the cross-check of redundant flux values (flux linkage, KV, torque constant);
- :class:`Missing`: every value a file lacks and no option supplies, named in one error (one run, not
  one run per missing value);
- :func:`stored`: a number as the firmware stores it (float32), written without float noise.

Units are SI; the firmware's own units are converted where read or written, nowhere else
(:func:`erpm`: electrical rad/s to the firmwares' electrical rpm).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from sensorless.design.drive_file import DriveDocument, Entry
from sensorless.design.motor_data import FLUX_TOLERANCE, kv_to_psi
from sensorless.design.units import MAX_POLE_PAIRS, DriveFileError

# The ranges of the values an import converts: the same as the import options that supply them
# (reports/pmsm_flux_observer/firmware_io.py --pole-pairs, --u-dc, --f-s), so a file's value gets
# the range an option's would
POLE_PAIRS_RANGE = (1, MAX_POLE_PAIRS)
U_DC_RANGE = (1.0, 1e4)  # V
F_S_RANGE = (100.0, 1e6)  # Hz: the observer's rate


@dataclass(frozen=True)
class Imported:
    """An imported firmware configuration: the minimal drive file and what to tell the user."""

    text: str  # TOML of kind pmsm-flux-observer (the family's agreed minimal format)
    notes: tuple[str, ...]  # one line each: missing values, assumptions, cross-checks


@dataclass(frozen=True)
class FirmwareDrive:
    """What an export writes: the motor values the firmware is to be given (the drive's estimates,
    SI, per phase of the equivalent wye), its loop, the observer variant and the law's gains."""

    name: str
    p: int  # pole pairs
    R_s: float  # ohm
    L_d: float  # H
    L_q: float  # H
    psi_pm: float  # Wb (V s), peak phase flux
    u_dc: float  # V
    T_obs: float  # s: the observer and PLL period
    correction: str  # "gradient" | "clamped-gradient" | "box-clamp"
    lambda_adaptation: bool
    law: str  # the gain law: "constant" | "voltage-scaled" | "schedule"
    gains: Mapping[str, float] = field(default_factory=dict)  # the law's gains, SI or firmware-raw
    source: str = ""  # where the gains come from (the drive file's [gains] or a gain table), for messages
    # the open-loop I-f start (design/startup.py): if_i [A], if_acc [rad/s^2], if_w_on, if_w_off [rad/s],
    # electrical; None where the drive has none
    startup: Mapping[str, float] | None = None
    # what the export says of the drive's own settings it changes (one line each, with why)
    notes: tuple[str, ...] = ()
    # [A, amplitude] the torque limit's current (MTPA at [control] T_max): the firmware's motor current
    # limit, which an import reads back as the torque limit (rated_from_limit); None: not written
    i_max: float | None = None


class Fields:
    """A firmware file's fields (flat names -> raw values), read strictly: ``number`` refuses a value
    that is not a finite number (odrivetool writes ``Infinity`` and ``NaN``) with one line naming the
    file and the field; ``missing`` lists what was asked for and absent."""

    def __init__(self, values: Mapping[str, Any], file: str) -> None:
        self.values, self.file = values, file

    def __contains__(self, name: str) -> bool:
        return name in self.values

    def error(self, name: str, problem: str) -> DriveFileError:
        """The one-line error naming the file and the field."""
        return DriveFileError(self.file, name, problem)

    def number(self, name: str, positive: bool = True) -> float | None:
        """The field as a finite number (> 0 with ``positive``), or None if absent."""
        if name not in self.values:
            return None
        raw = self.values[name]
        try:
            x = float(raw) if not isinstance(raw, bool) else math.nan
        except (TypeError, ValueError):
            raise self.error(name, f"{raw!r} is not a number") from None
        if not math.isfinite(x):
            raise self.error(name, f"{raw!r} is not a finite number")
        if positive and not x > 0:
            raise self.error(name, f"{raw!r}: must be > 0")
        return x

    def within(self, name: str, x: float, limits: tuple[float, float], what: str, unit: str = "") -> None:
        """Refuse ``x``, converted from the field ``name`` as ``what``, outside ``limits`` (one line
        naming the file and the field, with the value as written)."""
        lo, hi = limits
        if not lo <= x <= hi:
            u = f" {unit}" if unit else ""
            raise self.error(
                name, f"{self.values[name]!r} gives {what} = {x:.6g}{u}: expected {lo:g} to {hi:g}{u}"
            )

    def integer(self, name: str) -> int | None:
        """The field as an integer >= 1, or None if absent."""
        x = self.number(name)
        if x is None:
            return None
        if x != int(x):
            raise self.error(name, f"{self.values[name]!r} is not a whole number")
        return int(x)


class Missing:
    """The values a firmware file lacks that no option supplies: collected while the file is read, then
    one DriveFileError naming every one with what supplies it (:meth:`check`)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.items: list[tuple[str, str]] = []

    def add(self, name: str, todo: str) -> None:
        """``name`` is missing; ``todo``: what supplies it (an option, a measurement)."""
        self.items.append((name, todo))

    def check(self) -> None:
        """Raise the one error of every missing value, if any."""
        if self.items:
            what = "; ".join(f"{name}: {todo}" for name, todo in self.items)
            raise DriveFileError(self.file, ", ".join(n for n, _ in self.items), f"missing ({what})")


def float32(x: float) -> float:
    """``x`` rounded to the float32 the firmwares store (VESC, ODrive and SimpleFOC keep float)."""
    return float(struct.unpack("f", struct.pack("f", x))[0])


def stored(x: float) -> str:
    """``x`` as the firmware stores it, in the fewest digits that read back to the same float32: what a
    firmware file holds, without float noise (10.0 not 9.999999999999998; 400 not 400.00000000034464)."""
    y = float32(x)
    if y == int(y) and abs(y) < 1e10:
        return str(int(y))
    for digits in range(1, 10):
        text = f"{y:.{digits}g}"
        if float32(float(text)) == y:
            return text
    return repr(y)


def choose_flux(
    candidates: list[tuple[str, float | None, bool, str]], file: str, need: str
) -> tuple[float, str, list[str]]:
    """The PM flux to use from redundant values, with the reason and the notes of the cross-check.

    ``candidates``: (name, psi_pm or None if absent, is the factory default, rule), in the order of
    preference (the value the observer itself runs with first). The first that is not a factory
    default is used; a default is used only when nothing else is given, with a note naming ``need``
    (the option that supplies a real value). Every other given value is compared with it: beyond
    design/motor_data.py FLUX_TOLERANCE a note says so (the file is kept; the firmware holds both)."""
    given = [c for c in candidates if c[1] is not None]
    if not given:
        raise DriveFileError(file, candidates[0][0], f"missing: no PM flux value in the file; give {need}")
    real = [c for c in given if not c[2]]
    name, psi, _, rule = (real or given)[0]
    assert psi is not None
    notes: list[str] = []
    why = f"flux linkage {psi * 1e3:.5g} mWb from {name}"
    if not real:
        notes.append(
            f"{why} is still the factory default: the drive's flux is a guess until you give {need} "
            "(the flux observer needs it within a few per cent)"
        )
    else:
        for other, x, default, _ in given:
            if other == name:
                continue
            assert x is not None
            if default:
                notes.append(
                    f"{other} is still the factory default ({x * 1e3:.5g} mWb); used {why} instead "
                    "(set by the user or measured); an export writes it back"
                )
            elif abs(x / psi - 1) > FLUX_TOLERANCE:
                notes.append(
                    f"{other} implies {x * 1e3:.5g} mWb, {100 * abs(x / psi - 1):.0f} % from the {why} "
                    f"(tolerance {100 * FLUX_TOLERANCE:.0f} %); used {name}: check pole pairs and the "
                    "constants' conventions"
                )
            else:
                notes.append(f"{other} ({x * 1e3:.5g} mWb) agrees with the {why}, which is used")
    return psi, rule, notes


def kv_candidates(given: Mapping[str, Any], p: int, rule: str) -> list[tuple[str, float | None, bool, str]]:
    """The flux candidate of a ``--KV`` option (rpm/V, line-line peak: design/motor_data.py kv_to_psi)
    for :func:`choose_flux`, ``rule`` naming the firmware's own form of the conversion; none without it."""
    if not given.get("KV"):
        return []
    kv = float(given["KV"])
    return [("--KV", kv_to_psi(kv * 2 * math.pi / 60, p), False, f"{rule}, KV {kv:g}")]


def inertia(given: Mapping[str, Any], motor: dict[str, Entry], notes: list[str], what: str) -> None:
    """``motor.J`` from ``--J`` [kg m2]; else a note that the family's rule derives it (``what``: the file
    kind, which has no inertia)."""
    if given.get("J"):
        motor["J"] = Entry(quantity(float(given["J"]), "kg m^2"), "--J")
    else:
        notes.append(f"no inertia in {what}: J derived by the family's rule (give --J in kg m2)")


def rated_from_limit(i_max: float, field: str) -> Entry:
    """``rating.I_N`` [A rms] of a firmware's motor current limit ``i_max`` [A, amplitude]: the limit is
    the most current the firmware ever commands, the drive's torque limit T_max (design/pmsm_flux_observer
    schema.py: T_max = T_MAX_TN T_N), so the rated current is the limit / T_MAX_TN, in rms. The drive's
    currents (the I-f start's among them) then stay within the firmware's limit."""
    from sensorless.design.pmsm_flux_observer.schema import T_MAX_TN

    return Entry(
        quantity(i_max / (T_MAX_TN * math.sqrt(2)), "A"),
        f"{field}/({T_MAX_TN:g} sqrt(2)): the limit as the torque limit T_max = {T_MAX_TN:g} T_N, in rms",
    )


def drive_document(header: list[str], sections: Mapping[str, Mapping[str, Entry]]) -> str:
    """The TOML text of a minimal drive file (design/drive_file.py DriveDocument: rules as comments)."""
    doc = DriveDocument(header=list(header))
    for name, entries in sections.items():
        if entries:
            doc.section(name).update(entries)
    return doc.toml()


def quantity(x: float, unit: str) -> str:
    """``x`` [SI] as a drive-file quantity string, to 12 significant digits (an export read back gives
    the exported values to 5e-12 relative; the firmwares store float32, good to 1e-7)."""
    return f"{x:.12g} {unit}"


def erpm(w: float) -> float:
    """Electrical speed ``w`` [rad/s] in ERPM (electrical revolutions per minute, VESC's unit)."""
    return w * 60 / (2 * math.pi)


def startup_entries(
    current: float | None,
    acc: float | None,
    w_on: float | None,
    w_off: float | None,
    rules: Mapping[str, str],
    rated: tuple[float, float] | None = None,
    notes: list[str] | None = None,
) -> dict[str, Entry]:
    """The ``[startup]`` entries (design/startup.py) of the firmware values found (SI), each with its
    rule (``rules``: key -> the firmware fields it comes from). ``rated``: (u_dc [V], psi_pm [Wb]) of
    the drive file written without a rated speed, whose 1 p.u. is then N_SPEED x the no-load speed
    u_dc / (sqrt(3) psi_pm) (design/pmsm_flux_observer/schema.py): a firmware's handover above it is
    left out (the drive file refuses a handover above rated speed, design/startup.py: the open loop
    never gets there, cause speed_unreachable), its hand-back with it, said in ``notes``; the rule's
    handover then applies."""
    if rated is not None and w_on is not None:
        from sensorless.design.pmsm_flux_observer.schema import N_SPEED

        w_rated = N_SPEED * rated[0] / (math.sqrt(3) * rated[1])
        if w_on > w_rated:
            if notes is not None:
                notes.append(
                    f"{rules['w_on']}: the handover w_on = {w_on:.6g} rad/s is above the rated speed "
                    f"{w_rated:.6g} rad/s ({N_SPEED:g} x the no-load speed at u_dc): the open loop never "
                    "gets there (cause: speed_unreachable); left out of [startup] with its hand-back, the "
                    "rule's handover applies (sensorless tune proposes it)"
                )
            w_on = w_off = None
    found = {
        "current": (current, "A"),
        "acceleration": (acc, "rad/s2"),
        "w_on": (w_on, "rad/s"),
        "w_off": (w_off, "rad/s"),
    }
    return {k: Entry(quantity(x, unit), rules[k]) for k, (x, unit) in found.items() if x is not None}


def check_limit(ok: bool, source: str, key: str, why: Callable[[], str]) -> None:
    """Refuse an export that breaks a firmware's own limit: one line naming where the gain came from."""
    if not ok:
        raise DriveFileError(source or "gains", key, why())
