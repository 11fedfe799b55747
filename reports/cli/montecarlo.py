"""``sensorless montecarlo``: the yield of a design over a spread of motors and of parameter estimates.

Draws the true motor (``--spread``) and the observer's estimates (``--estimate-error``) independently,
evaluates every draw's linearized closed loop over the drive's envelope and ``--time-domain K`` draws
on the generic scenarios, on Dask (reports/engine.py: a local cluster by default, ``--scheduler`` for
an existing one), and writes summary.json (key ``yield``), draws.csv, sensitivity.csv and figures
(reports/montecarlo.py). Exit status 3 (outputs written, a warning line) when the damping yield is
below 1.
"""

from __future__ import annotations

import argparse
import sys
import time

from sensorless.design.family import Drive
from sensorless.reports.cli.common import MIN_DAMPING, Number, UsageError, load, version
from sensorless.reports.engine import scheduler_address

NAMES = (
    "summary.json",
    "draws.csv",
    "sensitivity.csv",
    "damping_histogram.png",
    "damping_histogram.svg",
    "damping_scatter.png",
    "damping_scatter.svg",
)
SPREAD_HELP = (
    "NAME=X%% (normal, X = one standard deviation) or NAME=X%%u (uniform in +-X), comma-separated, "
    "relative to the drive's value"
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``montecarlo`` subcommand."""
    p = sub.add_parser(
        "montecarlo",
        help="Monte-Carlo yield of a design over spread motors and estimates (Dask; local by default)",
        description="Draw the true motor and the observer's estimates independently, evaluate each "
        "draw's linearized closed loop over the drive's envelope (batched) and K draws in the time "
        "domain (generic scenarios), and write the yield (summary.json), the worst draws, a sensitivity "
        "ranking (Spearman rank correlation with the worst damping), CSV data and figures. Runs on "
        "Dask: a local cluster, one worker process per core, unless --scheduler names one. "
        "A normal spread of 50% or more, or a uniform one of 100% or more, is refused (it draws "
        "non-physical values); the few draws <= 0 of a smaller spread are clipped to 5% of the "
        "nominal value, with a warning line.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--gains", metavar="TABLE", help="tuned gain table (default: the drive file's gains)")
    p.add_argument("--samples", type=Number(1, 1e6, integer=True), default=1000, help="draws (default 1000)")
    p.add_argument(
        "--spread",
        metavar="SPREADS",
        help=f"spread of the true motor: {SPREAD_HELP}; e.g. R_s=10%%,L_d=10%%,L_q=10%%,psi_pm=5%%,J=30%% "
        "(default: the observer family's typical spread)",
    )
    p.add_argument(
        "--estimate-error",
        metavar="SPREADS",
        help=f"spread of the observer's estimates around the drive's: {SPREAD_HELP}",
    )
    p.add_argument(
        "--time-domain",
        type=Number(0, 1e5, integer=True),
        default=0,
        metavar="K",
        help="simulate the first K draws on the generic scenarios (default 0)",
    )
    p.add_argument(
        "--seed", type=Number(0, 2**63 - 1, integer=True), default=0, help="random seed (default 0)"
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        type=scheduler_address,
        help="Dask scheduler (tcp://HOST:PORT) to run on, or 'synchronous' (in this process); "
        "default: a local cluster",
    )
    p.add_argument(
        "--workers",
        type=Number(1, 1024, integer=True),
        help="worker processes of the local cluster (default: one per core)",
    )
    p.add_argument(
        "--min-damping",
        type=Number(0, 1),
        default=None,
        help=f"required damping ratio, in [0, 1] (default: the observer family's, {MIN_DAMPING:g} for most)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Check everything, run on the engine, write the set."""
    from sensorless.design import montecarlo as mc
    from sensorless.design.capabilities import MonteCarlo, Simulatable, require
    from sensorless.design.registry import family_of
    from sensorless.reports import montecarlo as rmc
    from sensorless.reports.engine import Engine, EngineError
    from sensorless.reports.files import OutputSet

    drive: Drive = load(args.drive, "montecarlo")
    if args.time_domain > args.samples:
        raise UsageError(f"argument --time-domain: {args.time_domain} is more than --samples {args.samples}")
    if args.workers and args.scheduler:
        raise UsageError("argument --workers: sizes the local cluster; not with --scheduler")
    out = OutputSet(args.out, force=args.force, names=NAMES)
    out.check()
    fam = family_of(drive)
    if args.min_damping is None:  # the family's (ObserverFamily.required_damping)
        args.min_damping = fam.min_damping()
    params = require(fam, MonteCarlo).montecarlo.parameters(drive)  # else one line naming the family
    try:
        plant = mc.parse_spreads(args.spread, "--spread", params, estimates=False)
        estimate = mc.parse_spreads(args.estimate_error, "--estimate-error", params, estimates=True)
    except mc.SpreadError as e:
        raise UsageError(str(e)) from None
    if args.spread is None:  # the family's typical spread of the true motor (its Monte-Carlo parameters)
        plant = rmc.typical_spreads(params)
        if not args.quiet:
            typical = ", ".join(f"{k}={v.text()}" for k, v in plant.items())
            print(
                f"sensorless montecarlo: note: no --spread: the family's typical spread {typical}",
                file=sys.stderr,
            )
    if not plant and not estimate:
        raise UsageError("give --spread and/or --estimate-error: nothing is spread")
    gains = fam.gains(drive)
    if args.gains:
        from sensorless.design.gain_table import read_gain_table

        gains = fam.gains(drive, table=read_gain_table(args.gains), table_file=args.gains)
    rmc.envelope(drive)  # one line now if the drive has none
    if args.time_domain:
        require(fam, Simulatable)  # one line now if the family cannot simulate draws
        rmc.time_scenarios(drive)
    scheduler = args.scheduler
    t0 = time.perf_counter()
    try:
        engine = Engine(scheduler, args.workers, quiet=args.quiet)
        with engine:
            res = rmc.run(
                drive, gains, params, plant, estimate, args.samples, args.seed,
                args.time_domain, args.min_damping, engine,
            )  # fmt: skip
    except EngineError as e:
        raise UsageError(str(e)) from None
    for what, count in res.draws.clipped.items():
        which, name = what.split(" ", 1)
        opt = "--spread" if which == "plant" else "--estimate-error"
        print(
            f"sensorless montecarlo: warning: {opt} {name}: {count} of {args.samples} draws were <= 0 "
            f"(non-physical); clipped to {mc.CLIP_FRACTION:g} x nominal",
            file=sys.stderr,
        )
    s = res.summary
    out.add_text("summary.json", rmc.summary_json(s, version()))
    out.add_text("draws.csv", rmc.draws_csv(res, params, args.min_damping))
    out.add_text("sensitivity.csv", rmc.sensitivity_csv(s))
    import matplotlib.pyplot as plt

    for stem, fig in rmc.figures(res, params, args.min_damping).items():
        out.add_figures(stem, fig)
        plt.close(fig)
    y = s["yield"]
    line = f"yield (damping >= {args.min_damping:g} over {s['envelope_points']} points): "
    line += f"{y['damping']['value']:.4g}"
    line += f" +- {y['damping']['standard_error']:.2g} of {args.samples} draws"
    if y["time_domain"]["draws"]:
        line += f"; time domain: {y['time_domain']['value']:.4g} of {y['time_domain']['draws']}"
    print(line)
    if s["sensitivity"]:
        top = s["sensitivity"][0]
        print(f"most sensitive: {top['parameter']} (Spearman rho {top['spearman_rho']})")
    for p in out.commit():
        print(f"wrote {p}")
    print(f"montecarlo computed in {time.perf_counter() - t0:.1f} s")
    below = y["damping"]["value"] < 1 or (y["time_domain"]["draws"] and y["time_domain"]["value"] < 1)
    if below:
        print("sensorless montecarlo: warning: some draws fail (yield below 1)", file=sys.stderr)
    return 3 if below else 0
