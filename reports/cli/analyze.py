"""``sensorless analyze``: the linearized observer of a drive over speed (and torque), as its family sees it.

What a family prints and writes (unstable speed bands, worst damping, poles, steady errors, pole
maps) and its options come from its report hooks (reports/family.py); options of another family are
refused, never ignored.
"""

from __future__ import annotations

import argparse
import sys

from sensorless.design.family import CapabilityError, Drive
from sensorless.design.registry import family_of
from sensorless.reports.cli.common import foreign_table, load
from sensorless.reports.family import add_family_options, hooks, refuse_foreign
from sensorless.reports.files import OutputSet


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``analyze`` subcommand."""
    p = sub.add_parser(
        "analyze",
        help="linearized observer poles over speed (pole maps, unstable bands, damping, steady errors)",
        description="Linearize the observer (with the motor) of a drive by automatic Jacobians over its "
        "operating points; print what its family reports (unstable speed bands, worst damping, poles, "
        "steady errors); write the data (CSV) and figures.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--gains", metavar="TABLE", default=None, help="analyse the gains of a tuned gain table")
    p.add_argument("--out", default=None, help="output directory (default: analysis-<drive name>)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument(
        "--drive",
        dest="whole_drive",
        action="store_true",
        help="also linearize the whole sampled drive (current PI in the estimated frame, delay, speed PI on "
        "the estimate; design/drive_analysis.py): print its summary, write drive_poles.csv and .svg",
    )
    add_family_options(p, "analyze")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load the drive and run the analysis of its family."""
    drive = load(args.drive, "analyze")
    fam = family_of(drive)
    h = hooks(fam)
    if h.analyze is None:
        raise CapabilityError(f"observer family {fam.name!r} has no analysis to run")
    refuse_foreign(args, fam, "analyze")
    if h.analyze_check is not None:
        h.analyze_check(drive, args)  # the family's options against the drive, before any computation
    if (
        args.gains
    ):  # a table tuned for another drive may still be analysed, with the warning of codegen/report
        from sensorless.design.gain_table import read_gain_table

        foreign = foreign_table(read_gain_table(args.gains), args.gains, drive)
        if foreign:
            print(f"sensorless analyze: warning: {foreign}", file=sys.stderr)
    # the file names depend on the options and come with the results: an existing directory must be
    # empty (or --force)
    out = OutputSet(args.out or f"analysis-{drive.name}", force=args.force)
    out.check()
    h.analyze(drive, args, out)
    if args.whole_drive:
        _whole_drive(drive, args, out)
    for p in out.commit():
        print(f"wrote {p}")
    for line in out.warnings:  # written (the rest is the result), but said: exit status 3
        print(f"sensorless analyze: warning: {line}", file=sys.stderr)
    return 3 if out.warnings else 0  # 3: a result that does not hold (reports/cli/main.py EXIT_RESULT)


def _whole_drive(drive: Drive, args: argparse.Namespace, out: OutputSet) -> None:
    """The whole sampled drive beside the family's analysis: summary lines, CSV and pole map."""
    from sensorless.design.gain_table import read_gain_table
    from sensorless.reports import drive_analysis as whole

    fam = family_of(drive)
    if args.gains:
        gains = fam.gains(drive, table=read_gain_table(args.gains), table_file=args.gains)
    else:
        gains = fam.gains(drive)
    lin = whole.sweep(drive, gains)
    for line in whole.summary(lin, drive):
        print(line)
    out.add_text("drive_poles.csv", whole.csv(lin, drive))
    out.add_figures("drive_poles", whole.figure(lin, drive, f"{drive.name}: whole sampled drive, slow poles"))
