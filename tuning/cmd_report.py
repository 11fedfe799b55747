"""``sensorless report``: a self-contained HTML stability report and its data as JSON."""

from __future__ import annotations

import argparse
import time
from typing import Any

from sensorless.design.drive import load_drive
from sensorless.reports.files import OutputSet


def register(sub: Any) -> None:
    """Add the ``report`` subcommand."""
    p = sub.add_parser(
        "report",
        help="stability report (HTML + JSON) of the paper gains and, optionally, tuned gains",
        description="Write report.html (self-contained, figures embedded as SVG) and report.json (every "
        "number the report shows) for a drive and, with --gains, a tuned gain table.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--gains", default=None, help="gain table JSON from `sensorless tune` to review")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--min-damping", type=float, default=0.2, help="required damping ratio (default 0.2)")
    p.add_argument("--quick", action="store_true", help="coarser grids (for previews and tests)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compute the report, then write both files at once."""
    from sensorless.reports.report import (
        compute_report_data,
        compute_report_data_pmac,
        render_html,
        render_html_pmac,
        report_json,
        today,
    )
    from sensorless.tuning.cli import version
    from sensorless.tuning.gain_table import read_gain_table

    drive = load_drive(args.drive)
    table = read_gain_table(args.gains) if args.gains else None
    out = OutputSet(args.out, force=args.force)
    out.add_text("report.html", "")  # refuse early if the outputs exist, before minutes of work
    out.add_text("report.json", "")
    out.check_free()
    t0 = time.perf_counter()
    compute, render = {
        "ipmsm-adaptive": (compute_report_data, render_html),
        "pmac-reduced-order": (compute_report_data_pmac, render_html_pmac),
    }[drive.kind]
    data, figs = compute(
        drive, table, min_damping=args.min_damping, resolution="quick" if args.quick else "normal"
    )
    v = version()
    out.add_text("report.json", report_json(data, v))
    out.add_text("report.html", render(data, figs, v, today()))
    for p in out.commit():
        print(f"wrote {p}")
    print(f"report computed in {time.perf_counter() - t0:.1f} s")
    return 0
