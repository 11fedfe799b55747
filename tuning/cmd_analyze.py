"""``sensorless analyze``: pole maps over speed, unstable speed bands and worst damping (paper 000 IV).

Dispatches on the drive kind; each kind registers its analysis in ``ANALYZERS`` (paper 002's
"pmac-reduced-order" lives in tuning/analyze_pmac.py).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.linearize import linearize, unstable_bands
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.reports.files import OutputSet

ANALYZERS: dict[str, Callable[[Any, argparse.Namespace], int]] = {}


def register(sub: Any) -> None:
    """Add the ``analyze`` subcommand."""
    p = sub.add_parser(
        "analyze",
        help="linearized closed-loop poles over speed (pole maps, unstable bands, damping)",
        description="Linearize the motor+observer closed loop over speed at given torques by automatic "
        "Jacobians; print unstable speed bands and worst damping; write pole-map CSV and figures.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument(
        "--gain",
        default=None,
        help="observer gain from [observer.gains.*]: zero, constant, speed, or 'all' "
        "(default: the drive's [observer] gain)",
    )
    p.add_argument(
        "--torque",
        action="append",
        default=None,
        help="torque(s) in N m or relative to nominal, comma-separated or repeated "
        "(e.g. --torque=1T_N,-1T_N or --torque 14); default: nominal torque T_N",
    )
    p.add_argument("--injection", action="store_true", help="include the averaged HF injection (19)-(22)")
    p.add_argument("--speed-max", type=float, default=1.0, help="sweep |w_m| up to this (p.u.); default 1")
    p.add_argument("--points", type=int, default=2001, help="speed grid points; default 2001")
    p.add_argument(
        "--speed",
        action="append",
        default=None,
        help="pmac-reduced-order drives: mechanical speeds, e.g. --speed=250rpm,-400rpm "
        "(default: the drive's [envelope] speeds)",
    )
    p.add_argument(
        "--load",
        action="append",
        default=None,
        help="pmac-reduced-order drives: load torques in N m, e.g. --load=0,5Nm (default: [envelope] loads)",
    )
    p.add_argument(
        "--discretization",
        default=None,
        help="pmac-reduced-order drives: observer scheme (default: the drive's [control] discretization)",
    )
    p.add_argument(
        "--study",
        action="store_true",
        help="pmac-reduced-order drives: also run the discretization study (all schemes x 45..360 us)",
    )
    p.add_argument("--out", default=None, help="output directory (default: analysis-<drive name>)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load the drive and run the analysis of its kind."""
    drive = load_drive(args.drive)
    return ANALYZERS[drive.kind](drive, args)


def parse_torques(values: list[str] | None, T_N: float, source: str = "--torque") -> list[float]:
    """Torques from the command line in N m; 'T_N' is the drive's nominal torque."""
    if not values:
        return [T_N]
    out = []
    for v in (part for item in values for part in item.split(",") if part.strip()):
        txt = v.replace("T_N", " T_N").replace("TN", " T_N") if "N m" not in v else v
        txt = " ".join(txt.split())
        if txt.endswith("T_N"):
            x = float(txt[:-3].strip() or 1.0) * T_N
        else:
            try:
                x, _ = parse_quantity(txt, "torque", file="command line", key=source)
            except DriveFileError as e:
                raise DriveFileError("command line", source, e.problem) from None
        out.append(x)
    return out


def refine_band_edges(
    f_unstable: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray, iters: int = 40
) -> np.ndarray:
    """Bisect each bracket [lo, hi] (stability differs at the ends) to the switching speed."""
    s_lo = f_unstable(lo)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        s_mid = f_unstable(mid)
        same = s_mid == s_lo
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    return 0.5 * (lo + hi)


def analyze_ipmsm(drive: Any, args: argparse.Namespace) -> int:
    """Paper-000 analysis: pole maps of G_c(s) over speed for each gain and torque."""
    for opt in ("speed", "load", "discretization"):
        if getattr(args, opt, None) is not None:
            raise DriveFileError("command line", f"--{opt}", "applies to pmac-reduced-order drives only")
    if getattr(args, "study", False):
        raise DriveFileError("command line", "--study", "applies to pmac-reduced-order drives only")
    gains = list(drive.observer.gains) if args.gain == "all" else [args.gain or drive.observer.gain]
    for g in gains:
        drive.gain(g)  # raises a clear KeyError for an unknown gain name
    torques = parse_torques(args.torque, drive.T_N)
    if args.points < 3 or args.speed_max <= 0:
        raise DriveFileError("command line", "--points/--speed-max", "need >= 3 points and a positive range")
    wb = drive.base.w
    w = np.linspace(-args.speed_max, args.speed_max, args.points) * wb
    inj = args.injection
    out = OutputSet(args.out or f"analysis-{drive.name}", force=args.force)

    print(f"{drive.name}: {drive.source}")
    print(
        f"linearized closed loop (paper 000 eqs. (11)-(15){', HF injection (19)-(22)' if inj else ''}); "
        f"{args.points} speeds in [-{args.speed_max:g}, {args.speed_max:g}] p.u., "
        f"1 p.u. = {wb:.2f} rad/s electrical"
    )
    print(f"{'gain':<9} {'T_e [N m]':>9}  {'unstable speed bands [p.u.]':<38} worst damping (stable pts)")

    from sensorless.reports.pole_map import plot_pole_maps, pole_csv

    suffix = "_inj" if inj else ""
    w_low = np.linspace(-0.05, 0.05, 1001) * wb  # dense low-speed sweep for the magnified panel
    for T in torques:
        sweeps, low = {}, {}
        for g in gains:
            s = linearize(drive, w, T, gain=g, injection=inj)
            sweeps[g] = s
            low[g] = linearize(drive, w_low, T, gain=g, injection=inj)
            tol = 1e-9 * np.nanmax(np.abs(s.poles))

            def unstable(ws: np.ndarray, g=g, T=T, tol=tol) -> np.ndarray:
                return linearize(drive, ws, T, gain=g, injection=inj).max_real > tol

            bands = unstable_bands(w, s.max_real, tol)
            text = []
            for lo_w, hi_w in bands:
                i_lo, i_hi = np.searchsorted(w, lo_w), np.searchsorted(w, hi_w)
                edges = [lo_w, hi_w]
                if i_lo > 0:
                    edges[0] = float(refine_band_edges(unstable, w[[i_lo - 1]], w[[i_lo]])[0])
                if i_hi < w.size - 1:
                    edges[1] = float(refine_band_edges(unstable, w[[i_hi + 1]], w[[i_hi]])[0])
                mode = "motoring" if np.sign(np.mean(edges)) == np.sign(T) else "regenerating"
                text.append(f"{edges[0] / wb:+.4f}..{edges[1] / wb:+.4f} ({mode})")
            stable = s.max_real <= tol
            wd = np.where(stable, s.worst_damping, np.inf)
            k = int(np.argmin(wd))
            worst = f"{wd[k]:.3f} at {w[k] / wb:+.3f} p.u." if np.isfinite(wd[k]) else "n/a"
            print(f"{g:<9} {T:>9.3g}  {'; '.join(text) or 'none':<38} {worst}")
            out.add_text(f"poles_{g}{suffix}_T{T:+g}Nm.csv", pole_csv(s, wb))
        fig = plot_pole_maps(
            sweeps,
            wb,
            f"{drive.name}: closed-loop poles, T_e = {T:g} N m"
            f"{' with HF injection (averaged)' if inj else ''}",
            low,
        )
        out.add_figure(f"pole_map{suffix}_T{T:+g}Nm.png", fig, dpi=110)
        out.add_figure(f"pole_map{suffix}_T{T:+g}Nm.svg", fig)
        import matplotlib.pyplot as plt

        plt.close(fig)
    for p in out.commit():
        print(f"wrote {p}")
    return 0


def analyze_pmac(drive: Any, args: argparse.Namespace) -> int:
    """Paper-002 analysis (tuning/analyze_pmac.py, imported on use)."""
    from sensorless.tuning.analyze_pmac import analyze_pmac as run_pmac

    return run_pmac(drive, args)


ANALYZERS["ipmsm-adaptive"] = analyze_ipmsm
ANALYZERS["pmac-reduced-order"] = analyze_pmac
