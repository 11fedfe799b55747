"""The ``sensorless`` command line: one entry point, one module per subcommand.

Errors a user can cause (bad drive file, missing file, existing outputs, unknown gain) are printed
as one line naming the file and key, and the process exits with status 2; nothing is half-written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sensorless.design.operating_point import EquilibriumError
from sensorless.design.units import DriveFileError
from sensorless.reports.files import OutputExistsError
from sensorless.tuning.gain_table import GainTableError

# Subcommand modules; each defines register(subparsers) that sets a ``func`` default.
COMMAND_MODULES = (
    "sensorless.tuning.cmd_analyze",
    "sensorless.tuning.cmd_tune",
    "sensorless.tuning.cmd_simulate",
    "sensorless.tuning.cmd_codegen",
    "sensorless.tuning.cmd_report",
)


class UsageError(ValueError):
    """A command-line value is invalid (the message says which and why)."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    import importlib

    parser = argparse.ArgumentParser(
        prog="sensorless",
        description="Design, analyse, tune and code-generate observers for sensorless PM drives.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def version() -> str:
    """Installed package version."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _v

    try:
        return _v("sensorless")
    except PackageNotFoundError:  # running from a source tree without install
        return "0+unknown"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sensorless`` script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (
        DriveFileError,
        FileNotFoundError,
        OutputExistsError,
        UsageError,
        EquilibriumError,
        GainTableError,
        KeyError,
    ) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        print(f"sensorless {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
