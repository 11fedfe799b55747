"""Report hooks of the PLL test family: ``analyze`` output, ``tune`` options, and the stability report.

- analyze: poles of the continuous observer and of the sampled one (ln(z)/T_s) over the drive's envelope,
  the worst damping and slowest decay per speed, and the sampled observer's steady angle error;
  poles.csv and a figure;
- tune: the options of the ``pll`` search (tuning.py) and a one-line envelope;
- report: drive data, the poles over the envelope for the drive's gains (and a tuned table's), the
  built-in scenario re-run (reports/time_domain.py), and a verdict.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sensorless.design.envelope import TuningSettings
from sensorless.design.gain_table import read_gain_table
from sensorless.design.poles import MIN_DAMPING
from sensorless.design.units import DriveFileError
from sensorless.reports import time_domain
from sensorless.reports.cli.common import option_error
from sensorless.reports.document import (
    Figure,
    Paragraph,
    Report,
    Section,
    Table,
    Verdict,
    drive_section,
    drive_tables,
    f,
    num,
    report_inputs,
    svg_uri,
)
from sensorless.reports.family import Option, ReportHooks
from sensorless.reports.files import OutputSet

from families.pll.design import FAMILY, PllLinearization
from families.pll.tuning import default_settings

TIME_DOMAIN = ("speed_steps",)
MAX_RMS_THETA_DEG = 10.0  # a time-domain check passes below this RMS position error


# --------------------------------------------------------------------------------------------------
# Shared by analyze and report
# --------------------------------------------------------------------------------------------------
def _gains(drive: Any, table: Any, table_file: str) -> Any:
    return FAMILY.gains(drive, table=table, table_file=table_file)


def poles_figure(lin: PllLinearization, drive: Any, title: str) -> Any:
    """Real parts of the poles (continuous o, discrete x) and the steady angle error over speed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(6.4, 5.0))
    for j, T in enumerate(np.unique(lin.torque)):
        m = lin.torque == T
        w = lin.w[m] / drive.w_base
        c = f"C{j}"
        a1.plot(np.repeat(w, lin.poles.shape[1]), lin.poles[m].real.ravel(), "o", ms=3, mfc="none", color=c)
        a1.plot(np.repeat(w, lin.poles.shape[1]), lin.poles_discrete[m].real.ravel(), "x", ms=3, color=c)
        a2.plot(w, np.degrees(lin.theta_err[m]), "-", color=c, label=f"T_e = {T:g} N m")
    a1.set_ylabel("Re(p) (1/s)")
    a2.set_ylabel("steady angle error (deg)")
    a2.set_xlabel("speed (p.u.)")
    a2.legend(fontsize=8, frameon=False)
    for a in (a1, a2):
        a.grid(True, lw=0.3, color="0.8")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def poles_csv(lin: PllLinearization, drive: Any) -> str:
    """One row per point: speed, torque, worst damping and decay (continuous, discrete), angle error."""
    lines = [
        f"# {drive.name}: PLL observer poles; discrete at T_s = {lin.T_s:g} s; speeds electrical",
        "w_rad_s,w_pu,T_e_Nm,damping_c,decay_c_1_s,damping_d,decay_d_1_s,theta_err_rad",
    ]
    cols = (lin.w, lin.w / drive.w_base, lin.torque, lin.worst_damping, lin.decay_rate)
    cols += (lin.worst_damping_discrete, lin.decay_rate_discrete, lin.theta_err)
    for row in zip(*cols, strict=True):
        lines.append(",".join(f"{v:.10g}" for v in row))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# sensorless analyze
# --------------------------------------------------------------------------------------------------
def analyze(drive: Any, args: argparse.Namespace, out: OutputSet) -> None:
    """Poles over the envelope (4x refined in speed); stage poles.csv and the figure."""
    table = read_gain_table(args.gains) if args.gains else None
    gains = _gains(drive, table, args.gains or "")
    W, T = drive.grid(4)
    lin = FAMILY.linearize(drive, gains, W, T)
    print(f"{drive.name}: {drive.source}")
    print(f"{FAMILY.title} ({FAMILY.citation}); gains: {gains.source}")
    print(f"w_pll = {gains.values['w_pll']:.6g} rad/s; sampled observer at T_s = {drive.T_s * 1e6:g} us")
    head = (
        f"{'speed [pu]':>10} {'worst damping c/d':>18} {'slowest decay c/d [1/s]':>24} "
        f"{'theta_err [deg]':>16}"
    )
    for T_e in drive.envelope.torques:
        print(f"T_e = {T_e:g} N m:\n  {head}")
        for k in np.flatnonzero(lin.torque == T_e)[::4]:  # the envelope's own speeds
            z, d = (
                (lin.worst_damping[k], lin.worst_damping_discrete[k]),
                (lin.decay_rate[k], lin.decay_rate_discrete[k]),
            )
            print(
                f"  {lin.w[k] / drive.w_base:>10.3f} {z[0]:>8.3f}/{z[1]:<9.3f} {d[0]:>11.4g}/{d[1]:<12.4g} "
                f"{np.degrees(lin.theta_err[k]):>16.4f}"
            )
    print(
        f"worst over {lin.w.size} points: damping {np.nanmin(lin.worst_damping_discrete):.4f}, slowest decay "
        f"{np.nanmin(lin.decay_rate_discrete):.4g} 1/s (sampled observer)"
    )
    out.add_text("poles.csv", poles_csv(lin, drive))
    fig = poles_figure(lin, drive, f"{drive.name}: PLL observer poles (o continuous, x sampled)")
    out.add_figures("poles", fig)
    import matplotlib.pyplot as plt

    plt.close(fig)


# --------------------------------------------------------------------------------------------------
# sensorless tune
# --------------------------------------------------------------------------------------------------
TUNE_OPTIONS = (
    Option(("--bandwidth-max",), {"type": float, "help": "upper bound on the PLL bandwidth [rad/s]"}),
    Option(("--min-decay",), {"type": float, "help": "minimum decay rate -max Re(p) [1/s]"}),
    Option(("--dense-factor",), {"type": int, "help": "re-verification refinement (>= 4)"}),
)


def tune_settings(drive: Any, args: argparse.Namespace, tunable: Any) -> TuningSettings:
    """The shared settings of the drive's envelope with the command-line overrides, checked."""
    s = default_settings(drive)
    if args.bandwidth_max is not None:
        s = dataclasses.replace(s, law=dataclasses.replace(s.law, w_max=args.bandwidth_max))
    if args.min_decay is not None:
        s = dataclasses.replace(s, min_decay=args.min_decay)
    if args.dense_factor is not None:
        s = dataclasses.replace(s, envelope=dataclasses.replace(s.envelope, dense_factor=args.dense_factor))
    try:
        s.check("", prefix="")
    except DriveFileError as e:  # name the option
        raise option_error(f"--{e.key.replace('_', '-')}", e.problem) from None
    return s


def describe(drive: Any, settings: TuningSettings) -> str:
    e, law = drive.envelope, settings.law
    return (
        f"envelope: |speed| {e.speed_min / drive.w_base:g}..{e.speed_max / drive.w_base:g} p.u. "
        f"({e.speeds} per direction) x torques {', '.join(f'{t:g}' for t in e.torques)} N m; "
        f"w_pll in [{law.w_min:.4g}, {law.w_max:.4g}] rad/s"
    )


# --------------------------------------------------------------------------------------------------
# sensorless report
# --------------------------------------------------------------------------------------------------
def compute(
    drive: Any,
    table: Any | None = None,
    table_file: str = "",
    min_damping: float = MIN_DAMPING,
    resolution: str = "normal",
    progress: Callable[[str], None] = lambda s: None,
    scenarios: Sequence[str] = (),
) -> Report:
    """The report's numbers, sections and verdict."""
    choices = {"drive file": FAMILY.gains(drive)}
    if table is not None:
        choices["tuned"] = _gains(drive, table, table_file)
    review = list(choices)[-1]
    W, T = drive.grid(1 if resolution == "quick" else 4)
    progress(f"[1/3] poles over the envelope ({W.size} points)")
    analysis: dict[str, Any] = {}
    lins = {}
    for label, gains in choices.items():
        lin = FAMILY.linearize(drive, gains, W, T)
        lins[label] = lin
        zd, dd = lin.worst_damping_discrete, lin.decay_rate_discrete
        k = int(np.nanargmin(dd))
        analysis[label] = {
            "w_pll": f(gains.values["w_pll"]),
            "worst_damping_continuous": f(np.nanmin(lin.worst_damping)),
            "worst_damping": f(np.nanmin(zd)),
            "min_decay_rate": f(np.nanmin(dd)),
            "slowest_at": {"w_pu": f(W[k] / drive.w_base), "T_e_Nm": f(T[k])},
            "max_abs_theta_err_deg": f(np.degrees(np.nanmax(np.abs(lin.theta_err)))),
            "stable": bool(np.isfinite(dd).all() and (dd > 0).all()),
        }
    progress("[2/3] time-domain check (the built-in scenario re-run)")
    runs = time_domain.scenarios(drive, TIME_DOMAIN, scenarios)
    td, td_figs = time_domain.checks(
        drive, choices[review] if table is not None else None, runs, review, progress
    )
    progress("[3/3] verdict")
    a = analysis[review]
    damped = a["worst_damping"] is not None and a["worst_damping"] >= min_damping
    tracks = all(item["metrics"]["rms_theta_err_deg"] < MAX_RMS_THETA_DEG for item in td)
    status = "fail" if not a["stable"] else "pass" if damped and tracks else "warn"
    status = time_domain.status_with(status, td)
    findings = []
    if not damped:
        findings.append(f"worst damping {num(a['worst_damping'])} < required {min_damping:g}")
    if not tracks:
        findings.append(f"a time-domain check exceeds {MAX_RMS_THETA_DEG:g} deg RMS position error")
    findings += [x["text"] for x in time_domain.findings(td)]
    data = {
        "inputs": report_inputs(drive, table, min_damping),
        "drive": drive_tables(drive),
        "review": review,
        "sampling_period_s": f(drive.T_s),
        "analysis": analysis,
        "time_domain": td,
        "verdict": {"status": status, "damped": damped, "tracks": tracks, "findings": findings},
    }
    rows = tuple(
        (
            label,
            num(x["w_pll"]),
            num(x["worst_damping"]),
            num(x["min_decay_rate"]),
            f"{num(x['slowest_at']['w_pu'])}, {num(x['slowest_at']['T_e_Nm'])}",
            num(x["max_abs_theta_err_deg"]),
        )
        for label, x in analysis.items()
    )
    header = (
        "gains",
        "w_pll (rad/s)",
        "worst damping",
        "slowest decay (1/s)",
        "at (p.u., N m)",
        "max |angle error| (deg)",
    )
    fig = Figure(
        svg_uri(poles_figure(lins[review], drive, f"{drive.name}: poles, gains {review}")),
        "Real parts of the observer's poles over speed: continuous observer (o) and the sampled observer "
        "at the drive's sampling period, ln(z)/T_s (x); below, the sampled observer's steady angle error. "
        "Colours: torque.",
    )
    sections = (
        drive_section(1, data["drive"]),
        Section(
            "2. Observer poles over the envelope",
            (fig, Table(header, rows, "sampled observer (discrete poles)", frozenset({1, 2, 3, 5}))),
        ),
        time_domain.section(3, td, td_figs),
    )
    text = (
        f"Gains {review} (w_pll = {num(a['w_pll'])} rad/s): the sampled observer is "
        f"{'stable' if a['stable'] else 'NOT stable'} over the envelope, worst damping "
        f"{num(a['worst_damping'])} "
        f"(required {min_damping:g}), slowest decay {num(a['min_decay_rate'])} 1/s; time-domain check "
        f"{'within' if tracks else 'beyond'} {MAX_RMS_THETA_DEG:g} deg RMS position error."
    )
    cls = "ok" if status == "pass" else "bad" if status == "fail" else ""
    return Report(
        drive.name, review, data, Verdict(status, (Paragraph(text, cls),), tuple(findings)), sections
    )


HOOKS = ReportHooks(
    analyze=analyze,
    tune_options=TUNE_OPTIONS,
    tune_settings=tune_settings,
    describe_envelope=describe,
    report=compute,
)
