"""The ``sensorless`` entry point: the parser of every subcommand, and one-line errors.

Errors a user can cause (bad drive file, missing file, existing outputs, unknown gain, a capability
the drive's observer family lacks) are printed as one line naming the file and key, and the process
exits with status 2; nothing is half-written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sensorless.design.family import CapabilityError
from sensorless.design.gain_table import GainTableError
from sensorless.design.units import DriveFileError
from sensorless.reports.cli import analyze, codegen, report, simulate, tune
from sensorless.reports.cli.common import UsageError, version
from sensorless.reports.files import OutputExistsError
from sensorless.tuning.nlp import TuningError

COMMANDS = (analyze, tune, simulate, codegen, report)  # each: register(subparsers) sets ``func``


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="sensorless",
        description="Design, analyse, tune and code-generate observers for sensorless PM drives.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for cmd in COMMANDS:
        cmd.register(sub)
    return parser


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
        GainTableError,
        CapabilityError,
        TuningError,
        KeyError,
    ) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        print(f"sensorless {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
