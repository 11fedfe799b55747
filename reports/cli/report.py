"""``sensorless report``: a self-contained HTML stability report and its data as JSON, for any family."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from typing import TYPE_CHECKING

from sensorless.design.capabilities import MonteCarlo, require
from sensorless.design.family import CapabilityError, Drive, ObserverFamily
from sensorless.design.low_speed import MAX_BIAS_DEG
from sensorless.design.registry import family_of
from sensorless.reports.cli import many
from sensorless.reports.cli.common import MIN_DAMPING, Number, UsageError, foreign_table, load, version
from sensorless.reports.family import hooks
from sensorless.reports.files import OutputSet

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.gain_table import GainTable
    from sensorless.reports.document import Report


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``report`` subcommand."""
    p = sub.add_parser(
        "report",
        help="stability report (HTML + JSON) of the drive file's gains and, optionally, tuned gains",
        description="Write report.html (self-contained, figures embedded as SVG) and report.json (every "
        "number the report shows) for a drive and, with --gains, a tuned gain table.",
    )
    p.add_argument(
        "drive",
        metavar="PRESET_OR_TOML",
        help="built-in preset name or drive TOML file; or a directory or a quoted glob of drive files: "
        "each drive run on Dask into --out DIR/<drive name>/, with DIR/summary.csv",
    )
    p.add_argument("--gains", default=None, help="gain table JSON from `sensorless tune` to review")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--min-damping",
        type=Number(0, 1),
        default=None,
        help=f"required damping ratio, in [0, 1] (default: the observer family's, {MIN_DAMPING:g} for "
        "most; the flux observer's damping falls with speed by design: stability only)",
    )
    p.add_argument(
        "--scenario",
        action="append",
        default=[],
        metavar="FILE",
        help="a scenario TOML to check in the time domain besides the built-in ones (repeatable)",
    )
    p.add_argument(
        "--max-bias",
        type=Number(0.1, 90),
        default=MAX_BIAS_DEG,
        help="largest angle bias under the estimate errors [deg electrical] of the minimum sensorless "
        f"speed (default {MAX_BIAS_DEG:g})",
    )
    p.add_argument(
        "--montecarlo",
        type=Number(0, 1e6, integer=True),
        default=0,
        metavar="N",
        help="add a Monte-Carlo section: N motors drawn with the family's typical spreads, seed 0, "
        "linearized over the envelope (sensorless montecarlo for more); default 0: none",
    )
    p.add_argument("--quick", action="store_true", help="coarser grids (for previews and tests)")
    p.add_argument(
        "--precision",
        choices=("double", "fixed"),
        default="double",
        help="the observer step the time-domain checks judge: double, or the fixed-point step of "
        "`codegen --precision fixed` (the report then also gives the quantization's effect on the poles)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    many.add_engine_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compute the report, then write both files at once."""
    # here, not at the top: what the report computes and renders (Jinja2) is this command's alone
    from sensorless.design.gain_table import read_gain_table
    from sensorless.reports.document import report_json
    from sensorless.reports.drive_analysis import ahead as drive_analysis_ahead
    from sensorless.reports.html import render
    from sensorless.reports.low_speed import add_to_report

    files = many.drive_files(args.drive)
    if files is not None:
        return many.run("report", args, files)
    many.refuse_engine_options(args)
    drive = load(args.drive, "report")
    fam = family_of(drive)
    if args.min_damping is None:  # the family's (ObserverFamily.required_damping)
        args.min_damping = fam.min_damping()
    compute = hooks(fam).report
    if compute is None:
        raise CapabilityError(f"observer family {fam.name!r} has no stability report")
    if args.gains:  # a directory of tune's tables: this drive's
        args.gains = many.gain_table_of(args.gains, drive.name)
    table = read_gain_table(args.gains) if args.gains else None
    foreign = None
    if table is not None:
        fam.gains(drive, table=table, table_file=args.gains)  # the table suits the drive: one line if not
        foreign = foreign_table(table, args.gains, drive)
        if foreign:
            print(f"sensorless report: warning: {foreign}", file=sys.stderr)
    from sensorless.design.scenario import load_scenario

    for path in args.scenario:  # each loads for this drive: one line naming the file if not
        load_scenario(path, drive)
    if args.montecarlo:
        require(fam, MonteCarlo)  # one line now if the family has no Monte-Carlo
    out = OutputSet(args.out, force=args.force, names=("report.html", "report.json"))
    out.check()  # before minutes of work
    t0 = time.perf_counter()
    gains = fam.gains(drive, table=table, table_file=args.gains) if table is not None else fam.gains(drive)
    # the whole drive's section first (added last): its figure is then drawn beside the report's analyses
    add_drive_analysis = drive_analysis_ahead(drive, gains, args.quick)
    judged = contextlib.nullcontext()
    if args.precision == "fixed":
        from sensorless.reports.codegen.fixed_generate import fixed_model
        from sensorless.reports.fixed_review import judged_with

        setup = fam.runtime(drive, gains)
        try:
            model = fixed_model(drive, gains if table is not None else None, setup)
        except (NotImplementedError, ValueError) as e:  # a step the fixed-point lowering does not take
            raise UsageError(f"argument --precision fixed: {e}") from None
        judged = judged_with(model.variant)
    with judged:
        rep = compute(
            drive,
            table,
            args.gains or "",
            min_damping=args.min_damping,
            resolution="quick" if args.quick else "normal",
            progress=lambda msg: print(msg, file=sys.stderr, flush=True),
            scenarios=tuple(args.scenario),
        )
    rep = add_to_report(rep, drive, gains, args.min_damping, math.radians(args.max_bias), args.quick)
    rep = add_drive_analysis(rep)
    if args.precision == "fixed":
        from sensorless.reports.fixed_review import add_to_report as add_fixed_review

        rep = add_fixed_review(rep, drive, gains, setup, model, args.quick)
    else:
        rep.data.setdefault("inputs", {})["precision"] = "double"
    if foreign:  # said in the report too: its numbers are for this drive, its gains from another
        rep.data["inputs"]["gain_table_warning"] = foreign
    if args.montecarlo:
        rep = _with_montecarlo(rep, drive, fam, table, args)
    v = version()
    out.add_text("report.json", report_json(rep.data, v))
    out.add_text("report.html", render(rep, v))
    for p in out.commit():
        print(f"wrote {p}")
    print(f"observer step judged: {args.precision} precision")
    print(f"verdict: {rep.verdict.status}; report computed in {time.perf_counter() - t0:.1f} s")
    failed = [
        f"time-domain check {item['name']} failed: {line}"
        for item in rep.data.get("time_domain") or ()
        for line in item.get("failed", ())
    ]
    if rep.verdict.status == "fail":
        failed.insert(0, "the verdict is 'fail': see the verdict's findings in report.html")
    untested = [
        f"time-domain check {item['name']} not tested sensorless: {item['untested']}"
        for item in rep.data.get("time_domain") or ()
        if item.get("untested") and item.get("passed")
    ]
    for line in failed + untested:
        print(f"sensorless report: warning: {line}", file=sys.stderr)
    return 3 if failed else 0


def _with_montecarlo(
    rep: Report, drive: Drive, fam: ObserverFamily, table: GainTable | None, args: argparse.Namespace
) -> Report:
    """The report with a Monte-Carlo section at the end (reports/montecarlo.py), in this process."""
    import dataclasses

    from sensorless.reports import montecarlo as rmc
    from sensorless.reports.engine import SYNCHRONOUS, Engine

    print(f"      Monte-Carlo: {args.montecarlo} draws", file=sys.stderr, flush=True)
    gains = fam.gains(drive, table=table, table_file=args.gains) if table is not None else fam.gains(drive)
    params = require(fam, MonteCarlo).montecarlo.parameters(drive)
    with Engine(SYNCHRONOUS, quiet=True) as engine:
        res = rmc.run(
            drive, gains, params, rmc.typical_spreads(params), {}, args.montecarlo, 0, 0,
            args.min_damping, engine,
        )  # fmt: skip
    section = rmc.report_section(len(rep.sections) + 1, res, params, args.min_damping)
    rep.data["montecarlo"] = res.summary
    return dataclasses.replace(rep, sections=(*rep.sections, section))
