"""``sensorless analyze`` for the adaptive observer: pole maps of G_c(s) over speed, unstable bands, damping.

Piippo, Hinkkanen, Luomi (2008) Section IV: the linearized motor+observer closed loop (11)-(15) over
-speed_max..speed_max p.u. at the given torques, for each gain choice, optionally with the averaged HF
injection (19)-(22). Prints the right-half-plane speed bands (edges refined by bisection) and the worst
damping; stages the pole data (CSV) and Fig. 4-5 style pole maps (PNG, SVG). With ``--discrete`` also the
discrete-time observer that runs, with ``--study`` every discretization over the sampling period
(sampled_analysis.py).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.ipmsm_adaptive import FAMILY, injection_off, with_alpha_fo
from sensorless.design.ipmsm_adaptive.runtime import law_of
from sensorless.reports.family import Option
from sensorless.reports.files import OutputSet
from sensorless.reports.options import Number, Renamed, UsageError, parse_torques
from sensorless.symbolic.ipmsm_adaptive.step import DISCRETIZATIONS

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

# the discrete-time observer's options (sampled_analysis.py): its analysis is imported where it runs
SAMPLED_OPTIONS = (
    Option(
        ("--discrete",),
        {
            "action": "store_true",
            "help": "also the discrete-time observer that runs (its one-step map at the sampling period)",
        },
    ),
    Option(
        ("--discretization",),
        {"help": "the observer's discretization scheme to analyse (default: the drive file's)"},
    ),
    Option(
        ("--study",),
        {
            "action": "store_true",
            "help": "also the discretization study (every scheme over sampling periods)",
        },
    ),
)

OPTIONS = (
    Option(
        ("--gain-set", "--gain"),
        {
            "action": Renamed,
            "metavar": "NAME",
            "help": "gain set from [observer.gains.*]: zero, constant, speed, or 'all' (default: [observer] "
            "gain; --gain: the former spelling, accepted until the next release)",
        },
    ),
    Option(
        ("--torque",),
        {
            "action": "append",
            "help": "torque(s) in N m or relative to nominal, comma-separated or repeated "
            "(e.g. --torque=1T_N,-1T_N or --torque 14); default: nominal torque T_N",
        },
    ),
    Option(("--injection",), {"action": "store_true", "help": "include the averaged HF injection (19)-(22)"}),
    Option(
        ("--speed-max",),
        {
            "type": Number(0, 100, lo_open=True, unit="p.u."),
            "help": "sweep |w_m| up to this (p.u.); default 1",
        },
    ),
    Option(
        ("--points",),
        {"type": Number(3, 100_000, integer=True), "help": "speed grid points (3..100000); default 2001"},
    ),
    *SAMPLED_OPTIONS,
)


def gain_choices(drive: IpmsmDrive, args: argparse.Namespace) -> dict[str, Any]:
    """Label -> GainSet of the gains to analyse (a table's, or the drive file's named ones)."""
    if args.gains:
        from sensorless.design.gain_table import read_gain_table

        if args.gain_set:
            raise UsageError("--gain-set and --gains exclude each other (the table holds the gains)")
        g = FAMILY.gains(drive, table=read_gain_table(args.gains), table_file=args.gains)
        return {f"tuned {g.law}": g}
    names = list(drive.observer.gains) if args.gain_set == "all" else [args.gain_set or drive.observer.gain]
    return {n: FAMILY.gains(drive, name=n) for n in names}


def scheme(drive: IpmsmDrive, args: argparse.Namespace) -> str | None:
    """The scheme to analyse in discrete time (None: continuous only); refuses what cannot be done."""
    if not (args.discrete or args.discretization):
        return None
    name = args.discretization or drive.run.discretization
    if name not in DISCRETIZATIONS:
        raise UsageError(f"--discretization: unknown scheme {name!r} (known: {', '.join(DISCRETIZATIONS)})")
    if args.injection:
        raise UsageError(
            "--discrete/--discretization: the discrete-time analysis is of the observer without the HF "
            "injection (its sampled chain is periodic at the carrier); leave out --injection"
        )
    return name


def check(drive: IpmsmDrive, args: argparse.Namespace) -> None:
    """The options against the drive, before anything is computed: gains, table, torques, injection."""
    gain_choices(drive, args)
    if args.injection and not drive.injection.enabled:
        raise UsageError(f"argument --injection: {injection_off(drive)}")
    parse_torques(args.torque, drive.T_N)
    scheme(drive, args)


def analyze(drive: IpmsmDrive, args: argparse.Namespace, out: OutputSet) -> None:
    """Print the bands and worst damping per gain and torque; stage CSV and figures into ``out``."""
    from sensorless.design.ipmsm_adaptive.linearize import unstable_speed_bands
    from sensorless.reports.ipmsm_adaptive import sampled_analysis

    choices = gain_choices(drive, args)
    torques = parse_torques(args.torque, drive.T_N)
    speed_max = 1.0 if args.speed_max is None else args.speed_max  # ranges: OPTIONS
    points = 2001 if args.points is None else args.points
    wb = drive.w_base
    w = np.linspace(-speed_max, speed_max, points) * wb
    inj = bool(args.injection)
    disc = scheme(drive, args)
    opts = {"injection": inj} if disc is None else {"discretization": disc}

    print(f"{drive.name}: {drive.source}")
    print(
        f"linearized closed loop ({FAMILY.citation} eqs. (11)-(15)"
        f"{', HF injection (19)-(22)' if inj else ''}); {points} speeds in [-{speed_max:g}, {speed_max:g}] "
        f"p.u., 1 p.u. = {wb:.2f} rad/s electrical"
    )
    print(f"{'gain':<14} {'T_e [N m]':>9}  {'unstable speed bands [p.u.]':<38} worst damping where stable")

    import matplotlib.pyplot as plt
    from sensorless.reports.pole_map import plot_pole_maps, pole_csv

    suffix = "_inj" if inj else ""
    w_low = np.linspace(-0.05, 0.05, 1001) * wb  # dense low-speed sweep for the magnified panel
    discrete_sweeps = []
    for T in torques:
        sweeps, low = {}, {}
        for label, g in choices.items():
            s = FAMILY.linearize(drive, g, w, T, **opts)
            sweeps[label] = s
            low[label] = FAMILY.linearize(drive, g, w_low, T, **opts)
            if disc is not None:
                discrete_sweeps.append((label, T, s, low[label]))
            tol = 1e-9 * np.nanmax(np.abs(s.poles))
            text = []
            d = with_alpha_fo(drive, g)
            for edges in unstable_speed_bands(d, w, T, gain=law_of(g), injection=inj, sweep=s):
                mode = "motoring" if np.sign(np.mean(edges)) == np.sign(T) else "regenerating"
                text.append(f"{edges[0] / wb:+.4f}..{edges[1] / wb:+.4f} ({mode})")
            stable = s.max_real < -tol  # strictly: a pole on the axis (damping <= 0) is not stable
            wd = np.where(stable, s.worst_damping, np.inf)
            k = int(np.argmin(wd))
            worst = f"{wd[k]:.3f} at {w[k] / wb:+.3f} p.u." if np.isfinite(wd[k]) else "n/a"
            print(f"{label:<14} {T:>9.3g}  {'; '.join(text) or 'none':<38} {worst}")
            out.add_text(f"poles_{label.replace(' ', '_')}{suffix}_T{T:+g}Nm.csv", pole_csv(s, wb))
        fig = plot_pole_maps(
            sweeps,
            wb,
            f"{drive.name}: closed-loop poles, T_e = {T:g} N m"
            f"{' with HF injection (averaged)' if inj else ''}",
            low,
        )
        out.add_figures(f"pole_map{suffix}_T{T:+g}Nm", fig)
        plt.close(fig)
    if discrete_sweeps:
        sampled_analysis.analyze_output(drive, discrete_sweeps, out)
    if args.study:
        sampled_analysis.study_output(
            drive, choices, out, lambda t: print(f"  ... {t}", file=sys.stderr, flush=True)
        )
