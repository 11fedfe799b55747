"""What every subcommand shares: the usage error, the package version, and parsing of quantities.

Errors a user can cause are exceptions that the ``sensorless`` entry point (main.py) prints as one
line naming the file or option; nothing here prints.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

from sensorless.design.envelope import NOISE_DIMS, NOISE_OUTPUTS
from sensorless.design.units import DriveFileError, parse_quantity


class UsageError(ValueError):
    """A command-line value is invalid (the message says which and why)."""


def version() -> str:
    """Installed package version."""
    try:
        return _version("sensorless")
    except PackageNotFoundError:  # running from a source tree without install
        return "0+unknown"


def parse_torques(values: list[str] | None, T_N: float, source: str = "--torque") -> list[float]:
    """Torques from the command line in N m; 'T_N' is the drive's nominal torque. Empty: [T_N]."""
    if not values:
        return [T_N]
    out = []
    for v in (part for item in values for part in item.split(",") if part.strip()):
        txt = v.replace("T_N", " T_N").replace("TN", " T_N") if "N m" not in v else v
        txt = " ".join(txt.split())
        if txt.endswith("T_N"):
            num = txt[:-3].strip() or "1"
            try:
                x = float(num) * T_N
            except ValueError:
                raise DriveFileError("command line", source, f"cannot read {v!r} as '<number> T_N'") from None
        else:
            try:
                x, _ = parse_quantity(txt, "torque", file="command line", key=source)
            except DriveFileError as e:
                raise DriveFileError("command line", source, e.problem) from None
        out.append(x)
    return out


def quantities(items: list[str] | None, dim: str, option: str) -> list[float] | None:
    """Comma-separated or repeated quantities of dimension ``dim`` from the command line, SI."""
    if not items:
        return None
    out = []
    for v in (part.strip() for item in items for part in item.split(",")):
        if not v:
            continue
        try:
            x, rel = parse_quantity(v, dim, file="command line", key=option)
        except DriveFileError as e:
            raise DriveFileError("command line", option, e.problem) from None
        if rel is not None:
            raise DriveFileError("command line", option, f"unit '{rel}' not allowed here")
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
