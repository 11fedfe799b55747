"""``sensorless export``: a drive's motor values and gains in a firmware's own configuration terms.

The observer families declare the firmwares they export to (reports/family.py ``Exporter``: VESC Tool
XML, odrivetool settings, a SimpleFOC snippet, ...); this command loads the drive and its gains (the
drive file's or a tuned gain table), asks the family's exporter for the files, and writes them as one
set (reports/files.py: all or nothing, byte-identical for the same inputs). An exporter refuses, with
one line, gains that break the firmware's own limits.
"""

from __future__ import annotations

import argparse
import sys

from sensorless.design.family import CapabilityError
from sensorless.design.gain_table import read_gain_table
from sensorless.design.registry import family_of
from sensorless.reports.cli.common import UsageError, foreign_table, load
from sensorless.reports.family import exporter_names, hooks
from sensorless.reports.files import OutputSet
from sensorless.reports.options import Renamed


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``export`` subcommand."""
    names = exporter_names()
    p = sub.add_parser(
        "export",
        help="write a drive's motor values and gains as a firmware's configuration",
        description="Write the drive's motor values and its gains (the drive file's, or a tuned gain table) "
        "in a firmware's own field names and units, refusing gains that break the firmware's own limits.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--gains", metavar="TABLE", help="tuned gain table (JSON, sensorless-gain-table/1)")
    p.add_argument(
        "--gain-set",
        "--gain",
        action=Renamed,
        default=None,
        metavar="NAME",
        help="without --gains: which of the drive file's named gain sets, if several (--gain: its former "
        "spelling, accepted until the next release)",
    )
    p.add_argument(
        "--target",
        required=True,
        metavar="FIRMWARE",
        help=f"the firmware ({', '.join(names) or 'none declared'}; each observer family declares its own)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check, export, write."""
    drive = load(args.drive, "export")
    fam = family_of(drive)
    table = read_gain_table(args.gains) if args.gains else None
    if table is not None and args.gain_set:
        raise UsageError("--gain-set and --gains exclude each other (the table holds the gains)")
    gains = fam.gains(drive, name=args.gain_set, table=table, table_file=args.gains or "")
    foreign = foreign_table(table, args.gains, drive) if table is not None else None
    exporter = hooks(fam).exporters.get(args.target)
    out = OutputSet(args.out, force=args.force, names=exporter.files if exporter else ())
    out.check()  # every option is checked before the target's capability and any computation
    if exporter is None:
        have = ", ".join(sorted(hooks(fam).exporters)) or "none"
        raise CapabilityError(
            f"--target {args.target}: {fam.title} drives (kind '{fam.kind}') export to: {have}"
        )
    if foreign:
        print(f"sensorless export: warning: {foreign}", file=sys.stderr)
    files, notes = exporter.export(drive, gains)
    for name in sorted(files):
        out.add_text(name, files[name])
    written = out.commit()
    print(f"{drive.name}: {exporter.title}; gains: {gains.source or gains.law}")
    for note in notes:
        print(f"note: {note}")
    for p in written:
        print(f"wrote {p}")
    return 0
