"""The types of command-line values, shared by the commands and by the families' options: checked
numbers, quantities, and the errors a user can cause.

Numeric options are parsed by :class:`Number` (an argparse ``type``): a finite number in a stated
range, or a one-line error naming the option before anything is loaded or computed. Families declare
their options with it too (reports/family.py ``Option``); a family option declared with a bare
``float`` or ``int`` still gets the finiteness and magnitude check (``add_family_options``).
Quantities with units or relative to the drive (``--torque 1T_N``, ``--speed 250rpm``) are parsed
against the drive by :func:`parse_torques` and :func:`quantities`, with the same checks.

Errors a user can cause are exceptions that the ``sensorless`` entry point (reports/cli/main.py)
prints as one line naming the file or option; nothing here prints. The command line
(reports/cli/) builds on this module; this module and the families' report hooks never import the
command line.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass

from sensorless.design.envelope import NOISE_DIMS, NOISE_OUTPUTS
from sensorless.design.units import MAGNITUDE, DriveFileError, check_magnitude, parse_number, parse_quantity

# Drive-relative bounds of command-line operating points: |torque| <= RELATIVE_LIMIT T_N and
# |speed| <= RELATIVE_LIMIT times the drive's base speed (far beyond any drive, short of overflow).
RELATIVE_LIMIT = 100.0


class UsageError(ValueError):
    """A command-line value is invalid (the message says which and why)."""


class ResultError(ValueError):
    """The computation ran but its result is not valid (not finite, lost): nothing is written."""


@dataclass(frozen=True)
class Number:
    """An argparse ``type``: a finite number (an integer with ``integer``) in [lo, hi] (open ends with
    ``lo_open``/``hi_open``), ``unit`` for the message; argparse names the option in its error."""

    lo: float = -MAGNITUDE[1]
    hi: float = MAGNITUDE[1]
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    unit: str = ""

    @property
    def __name__(self) -> str:  # argparse names the type in some messages
        return "integer" if self.integer else "number"

    def describe(self) -> str:
        """'a number in (0, 100] p.u.'"""
        lo = "(" if self.lo_open else "["
        hi = ")" if self.hi_open else "]"
        what = "an integer" if self.integer else "a number"
        return f"{what} in {lo}{self.lo:g}, {self.hi:g}{hi}{' ' + self.unit if self.unit else ''}"

    def __call__(self, text: str) -> float | int:
        try:
            x: float | int = int(text) if self.integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {self.describe()}") from None
        if isinstance(x, float) and not math.isfinite(x):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite: expected {self.describe()}")
        ok_lo = x > self.lo if self.lo_open else x >= self.lo
        ok_hi = x < self.hi if self.hi_open else x <= self.hi
        tiny = isinstance(x, float) and x != 0 and abs(x) < MAGNITUDE[0]
        if not (ok_lo and ok_hi) or tiny:
            raise argparse.ArgumentTypeError(f"{text} is out of range: expected {self.describe()}")
        return x


def drive_name(text: str) -> str:
    """An argparse ``type`` for a drive name given on the command line (``--name``): it becomes part of
    file names, so it is checked as a path component (design/drive_file.py ``name_problem``)."""
    from sensorless.design.drive_file import name_problem

    why = name_problem(text)
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return text


FINITE = Number()  # any finite number of a magnitude that drive files accept (a bare ``float``)
COUNT = Number(0, 1e9, integer=True)  # a non-negative integer (a bare ``int``)


def option_error(option: str, problem: str) -> UsageError:
    """The one-line error of a command-line value: 'argument --x: problem'."""
    return UsageError(f"argument {option}: {problem}")


def parse_torques(values: list[str] | None, T_N: float, source: str = "--torque") -> list[float]:
    """Torques from the command line in N m; 'T_N' is the drive's nominal torque. Empty: [T_N].

    Each must be finite and within +-RELATIVE_LIMIT T_N (UsageError naming ``source``)."""
    if not values:
        return [T_N]
    out = []
    for v in (part for item in values for part in item.split(",") if part.strip()):
        txt = v.replace("T_N", " T_N").replace("TN", " T_N") if "N m" not in v else v
        txt = " ".join(txt.split())
        try:
            if txt.endswith("T_N"):
                num = txt[:-3].strip() or "1"
                x = check_magnitude(parse_number(num, file="", key=source) * T_N, v, file="", key=source)
            else:
                x, _ = parse_quantity(txt, "torque", file="", key=source)
        except DriveFileError as e:
            raise option_error(source, e.problem) from None
        if abs(x) > RELATIVE_LIMIT * T_N:
            raise option_error(
                source,
                f"{v} is out of range: |torque| <= {RELATIVE_LIMIT:g} T_N = {RELATIVE_LIMIT * T_N:g} N m",
            )
        out.append(x)
    return out


def quantities(
    items: list[str] | None, dim: str, option: str, limit: tuple[float, str] | None = None
) -> list[float] | None:
    """Comma-separated or repeated quantities of dimension ``dim`` from the command line, SI; each
    finite, and with ``limit`` = (bound, text) of magnitude <= bound (UsageError naming ``option``)."""
    if not items:
        return None
    out = []
    for v in (part.strip() for item in items for part in item.split(",")):
        if not v:
            continue
        try:
            x, rel = parse_quantity(v, dim, file="", key=option)
        except DriveFileError as e:
            raise option_error(option, e.problem) from None
        if rel is not None:
            raise option_error(option, f"unit '{rel}' not allowed here")
        if limit is not None and abs(x) > limit[0]:
            raise option_error(option, f"{v} is out of range: {limit[1]}")
        out.append(x)
    return out


def parse_max_noise(text: str, w_base: float) -> tuple[tuple[str, float], ...]:
    """``position=0.05deg,speed=0.002pu`` (or a bare quantity: an angle limits the position, a speed
    the speed) -> ((output, SI limit), ...)."""
    out: dict[str, float] = {}
    for item in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, val = item.partition("=")
        if not sep:
            val = name
            for cand in NOISE_OUTPUTS:
                try:
                    parse_quantity(_spaced(val), NOISE_DIMS[cand], file="command line", key="--max-noise")
                except DriveFileError:
                    continue
                name = cand
                break
            else:
                raise UsageError(
                    f"--max-noise: cannot read {item!r}: give an angle (e.g. 0.05deg: position) or a speed "
                    "(e.g. 0.002pu, 1rad/s: speed), or NAME=VALUE with NAME in " + ", ".join(NOISE_OUTPUTS)
                )
        name = name.strip()
        if name not in NOISE_OUTPUTS:
            raise UsageError(
                f"--max-noise: unknown noise output {name!r} (allowed: {', '.join(NOISE_OUTPUTS)})"
            )
        x, rel = parse_quantity(_spaced(val), NOISE_DIMS[name], file="command line", key="--max-noise")
        if not x > 0:  # no estimate is free of noise: a zero limit is infeasible for any family
            raise UsageError(f"--max-noise: the {name} limit must be > 0, got {val.strip()!r}")
        out[name] = x * w_base if rel == "pu" else x
    return tuple(out.items())


def _spaced(v: str) -> str:
    """'0.05deg' -> '0.05 deg' (a unit may follow the number without a space)."""
    v = v.strip()
    i = 0
    while (
        i < len(v)
        and (v[i].isdigit() or v[i] in "+-.eE")
        and not (v[i] in "eE" and i + 1 < len(v) and v[i + 1].isalpha())
    ):
        i += 1
    return f"{v[:i]} {v[i:]}".strip()


# Former spellings of options, accepted for one release with a note: former -> current
RENAMED = {"--gain": "--gain-set"}  # a drive file's named gain set, not to be read as --gains TABLE


class Renamed(argparse.Action):
    """``action=Renamed`` for an option whose flags are (current, former...): stores the value; the former
    spelling (:data:`RENAMED`) still works for one release and prints one note on stderr naming the new
    one (the only thing this module prints: at parse time, before anything is computed)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[str] | None,
        option: str | None = None,
    ) -> None:
        if option in RENAMED:
            import sys

            print(
                f"{parser.prog}: note: {option} is now {RENAMED[option]} (the old spelling is accepted "
                "until the next release)",
                file=sys.stderr,
            )
        setattr(namespace, self.dest, values)
