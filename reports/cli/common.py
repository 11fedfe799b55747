"""What every subcommand shares: the usage error, the package version, and parsing of quantities.

Errors a user can cause are exceptions that the ``sensorless`` entry point (main.py) prints as one
line naming the file or option; nothing here prints.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

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
