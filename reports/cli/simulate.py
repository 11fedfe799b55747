"""``sensorless simulate``: time-domain simulation of the whole sensorless drive for a scenario.

Writes the traces (CSV or NPZ, units in the header) and a figure in the style of the paper's figures
(PNG and SVG) into one directory, atomically; prints a short summary of the estimation errors. A run
longer than design/simulate.MAX_SAMPLES control periods is refused before it starts; a run whose
traces are not finite writes nothing (exit status 3); one that loses the rotor position writes its
outputs, with a warning, and exits with status 3.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from typing import TextIO

import numpy as np
from sensorless.design.family import CapabilityError
from sensorless.design.registry import family_of
from sensorless.design.scenario import builtin_names, generic_scenarios, load_scenario
from sensorless.design.simulate import MAX_SAMPLES, Traces, check_length
from sensorless.reports.cli.common import Number, ResultError, UsageError, load
from sensorless.reports.family import add_family_options, hooks, refuse_foreign
from sensorless.reports.files import OutputSet


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``simulate`` subcommand."""
    p = sub.add_parser(
        "simulate",
        help="time-domain simulation of the sensorless drive (compiled loop) for a scenario",
        description="Simulate the closed-loop sensorless drive (motor, inverter, controllers, the runtime "
        "observer) for a scenario: a built-in one named after a paper figure, or a scenario TOML. "
        "Writes traces and a figure.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--scenario", help="built-in scenario name (see --list) or scenario TOML file")
    p.add_argument("--list", action="store_true", help="list the built-in scenarios for this drive and exit")
    p.add_argument("--gains", metavar="TABLE", help="tuned gain table (JSON, docs/gain_tables.md)")
    p.add_argument(
        "--duration",
        type=Number(0, 1e6, lo_open=True, unit="s"),
        help=f"override the scenario's duration [s] (at most {MAX_SAMPLES} control periods)",
    )
    p.add_argument("--format", choices=("csv", "npz"), default="csv", help="traces file format (default csv)")
    p.add_argument(
        "--every",
        type=Number(1, 1e9, integer=True),
        default=1,
        help="write every N-th sample (default 1: all)",
    )
    p.add_argument("--out", help="output directory (default: simulation-<drive>-<scenario>)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument(
        "--precision",
        choices=("double", "fixed"),
        default="double",
        help="the observer step that runs: double, or the fixed-point step of `codegen --precision fixed`",
    )
    add_family_options(p, "simulate")
    p.set_defaults(func=run)


class Progress:
    """Progress of a long run on stderr: a bar on a terminal, a line per 10 % otherwise."""

    def __init__(self, label: str, T_s: float, stream: TextIO | None = None) -> None:
        self.label, self.T_s = label, T_s
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        frac = done / total
        elapsed = time.perf_counter() - self.t0
        sim, end = done * self.T_s, total * self.T_s
        text = f"{self.label}: {100 * frac:5.1f} % ({sim:.2f} of {end:.2f} s simulated, {elapsed:.1f} s)"
        if self.tty:
            bar = "#" * int(30 * frac)
            self.stream.write(f"\r[{bar:<30}] {text}")
            if done == total:
                self.stream.write("\n")
        else:
            tenth = int(10 * frac)
            if tenth != self.last and (tenth > 0 or done == total):
                self.stream.write(text + "\n")
                self.last = tenth
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Load drive and scenario, simulate, write outputs."""
    drive = load(args.drive, "simulate")
    fam = family_of(drive)
    if args.list:
        for name in builtin_names(drive.kind):
            sc = load_scenario(name, drive)
            print(f"{name:<12} {sc.title}")
        try:
            generic = generic_scenarios(drive)
        except CapabilityError:  # a family without the scales of the generic scenarios
            generic = []
        for sc in generic:
            print(f"{sc.name:<12} {sc.title}; generic, scaled to the drive ({sc.duration:.4g} s)")
        return 0
    if not args.scenario:
        raise UsageError("--scenario NAME_OR_TOML is required (see --list)")
    sc = load_scenario(args.scenario, drive)
    refuse_foreign(args, fam, "simulate")
    h = hooks(fam)
    if h.simulate_scenario is not None:
        sc = h.simulate_scenario(drive, args, sc)  # the family's options, checked against the drive
    if args.duration is not None:
        sc = dataclasses.replace(sc, duration=args.duration)
    check_length(sc, drive.T_s, "argument --duration" if args.duration is not None else "")
    gains = None
    if args.gains:
        from sensorless.design.gain_table import read_gain_table

        gains = fam.gains(drive, table=read_gain_table(args.gains), table_file=args.gains)

    from sensorless.design.simulate import simulate

    name = f"traces.{args.format}"
    out = OutputSet(
        args.out or f"simulation-{drive.name}-{sc.name}",
        force=args.force,
        names=(name, f"{sc.name}.png", f"{sc.name}.svg"),
    )
    out.check()  # the outputs, before spending time on the run

    print(f"{drive.name}: {sc.title}")
    progress = None if args.quiet else Progress(f"simulate {sc.name}", drive.T_s)
    if args.precision == "fixed":
        from sensorless.design.runtime import step_variant
        from sensorless.reports.codegen.fixed_generate import fixed_model

        try:
            model = fixed_model(drive, gains, fam.runtime(drive, gains or fam.gains(drive)))
            with step_variant(model.variant):
                tr = simulate(drive, sc, gains, progress=progress)
        except (NotImplementedError, ValueError) as e:  # a step the fixed-point lowering does not take
            raise UsageError(f"argument --precision fixed: {e}") from None
        tr.meta["precision"] = "fixed"
    else:
        tr = simulate(drive, sc, gains, progress=progress)
    print(f"observer step: {args.precision} precision")
    n = len(tr.t)
    print(
        f"{n} samples ({tr.t[-1]:.3g} s at T_s = {tr.meta['T_s']:g} s) in {tr.wall_time:.2f} s "
        f"({1e6 * tr.wall_time / n:.2f} us per control period); gains: {tr.meta['gain']}"
    )
    problems = tr.problems()
    if tr.nonfinite() is not None:
        raise ResultError(f"{problems[0]}; nothing written")
    print_summary(tr)

    from sensorless.reports.sim_figure import plot_traces
    from sensorless.reports.traces import csv_text, npz_bytes

    if args.format == "csv":
        out.add_text(name, csv_text(tr, args.every))
    else:
        out.add_bytes(name, npz_bytes(tr, args.every))
    fig = plot_traces(tr, sc.figure, f"{drive.name}: {sc.title}")
    out.add_figures(sc.name, fig)
    import matplotlib.pyplot as plt

    plt.close(fig)
    for p in out.commit():
        print(f"wrote {p}")
    for line in problems:
        print(f"sensorless simulate: warning: {line}", file=sys.stderr)
    return 3 if problems else 0


def print_summary(tr: Traces) -> None:
    """RMS and peak estimation errors over the run."""
    k, unit = tr.meta["speed_scale"], tr.meta["speed_unit"]
    e_th = np.degrees(tr["theta_err"])
    e_w = (tr["w_m"] - tr["w_hat"]) * k
    if "speed_ramp" in tr.meta:  # the drive's rate limiter on the speed reference (design/speed_ramp.py)
        print(tr.meta["speed_ramp"])
    if "startup_mode" in tr.data:  # the open-loop I-f start: its theta_hat, w_hat are not estimates
        closed = np.asarray(tr["startup_mode"]) < 0.5
        on = int(np.count_nonzero(closed[1:] & ~closed[:-1]))
        print(
            f"{tr.meta.get('startup', 'I-f start')}: open loop "
            f"{np.count_nonzero(~closed) * tr.meta['T_s']:.3g} s, {on} handover(s); the errors below are "
            "those of the observer's samples"
        )
        if closed.any():
            e_th, e_w = e_th[closed], e_w[closed]
    print(
        f"position error: RMS {np.sqrt(np.mean(e_th**2)):.3g} deg, peak {np.max(np.abs(e_th)):.3g} deg, "
        f"final {e_th[-1]:+.3g} deg; speed error: RMS {np.sqrt(np.mean(e_w**2)):.3g} {unit}, "
        f"peak {np.max(np.abs(e_w)):.3g} {unit}, final {e_w[-1]:+.3g} {unit}"
    )
