"""What every subcommand shares: loading a drive with its warnings, the package version, the gain
table's provenance check; and, re-exported for the commands, the option types and user errors of
reports/options.py (where the families' report hooks import them from: they never import the
command line).
"""

from __future__ import annotations

import functools
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

from sensorless.design.family import Drive
from sensorless.design.gain_table import GainTable
from sensorless.design.poles import MIN_DAMPING  # noqa: F401  (re-exported: the commands read it here)
from sensorless.reports.options import (  # noqa: F401  (re-exported: the commands read them here)
    COUNT,
    FINITE,
    RELATIVE_LIMIT,
    Number,
    ResultError,
    UsageError,
    drive_name,
    option_error,
    parse_max_noise,
    parse_torques,
    quantities,
)


@functools.cache  # the package metadata is read once per process (every parser build asks)
def version() -> str:
    """Installed package version."""
    try:
        return _version("sensorless")
    except PackageNotFoundError:  # running from a source tree without install
        return "0+unknown"


def print_warnings(command: str, drive: Drive) -> None:
    """The drive's plausibility warnings (design/plausibility.py), one line each on stderr."""
    import sys

    for line in drive.warnings:
        print(f"sensorless {command}: warning: {line}", file=sys.stderr)


def load(spec: str, command: str) -> Drive:
    """The drive of a preset name or drive file, its warnings printed (every command loads this way)."""
    from sensorless.design.drive import load_drive

    drive = load_drive(spec)
    print_warnings(command, drive)
    return drive


def foreign_table(table: GainTable, table_file: str, drive: Drive) -> str | None:
    """Why a gain table does not belong to ``drive`` (tuned for another drive, or another version of its
    file), or None: the gains may still be valid for it, so commands warn and go on."""
    tuned_for = table.drive.get("name")
    sha = table.drive.get("sha256")
    if tuned_for != drive.name or (sha and sha != drive.digest):
        again = " (another version of its file)" if tuned_for == drive.name else ""
        return f"{table_file} was tuned for drive {tuned_for!r}{again}, not for {drive.name!r} ({drive.file})"
    return None
