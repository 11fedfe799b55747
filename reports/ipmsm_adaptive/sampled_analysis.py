"""The discrete-time observer that runs, in ``sensorless analyze`` and in the report.

Piippo, Hinkkanen, Luomi (2008) analyse the continuous observer; design/ipmsm_adaptive/one_step.py
linearizes the runtime step (what simulation runs and C is printed from) on the motor sampled under
zero-order hold. Here: the printed table and CSV beside the continuous
analysis, the study of every discretization over the sampling period, and the report's section.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.ipmsm_adaptive import FAMILY, with_alpha_fo
from sensorless.design.ipmsm_adaptive.one_step import (
    STUDY_SAMPLING,
    STUDY_SPEEDS,
    DiscretePoleSweep,
    StudyRow,
    discretization_study,
)
from sensorless.design.ipmsm_adaptive.runtime import law_of
from sensorless.reports.csv_cells import REASON
from sensorless.reports.csv_cells import row as csv_row
from sensorless.reports.document import Figure, Paragraph, Section, Table, f, num
from sensorless.reports.figure_layout import lay_out
from sensorless.reports.pole_map import pole_table
from sensorless.reports.svg_render import svg_later
from sensorless.symbolic.ipmsm_adaptive.step import DISCRETIZATIONS

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive


def header(a: DiscretePoleSweep) -> str:
    """The line that introduces the discrete results."""
    return (
        f"discrete-time observer that runs: {a.discretization} at T_s = {a.T_s * 1e6:g} us, injection off; "
        "poles ln(z)/T_s of its one-step map on the motor sampled under zero-order hold"
    )


TABLE_HEAD = (
    f"{'gain':<14} {'T_e [N m]':>9}  {'worst damping c/d':>17}  {'pole error':>10}  "
    f"{'steady angle error [deg]':<26} {'w_hat per volt':>14}"
)


def line(label: str, T: float, a: DiscretePoleSweep, w_base: float) -> str:
    """One row: worst damping continuous/discrete and the largest steady position error (and where) at
    |w| >= 0.05 p.u. (below, at the edge of the low-speed unstable band, a real pole passes through
    zero and any bias grows without bound), the largest pole error [1/s], the voltage feedthrough
    [rad/s per V]."""
    ok = np.abs(a.w) >= 0.05 * w_base
    zc = np.nanmin(a.worst_damping[ok], initial=np.inf)
    zd = np.nanmin(a.worst_damping_discrete[ok], initial=np.inf)
    k = int(np.nanargmax(np.where(ok, np.abs(a.err_theta), -1)))
    err = f"{np.degrees(a.err_theta[k]):+.4f} at {a.w[k] / w_base:+.3f} p.u."
    return (
        f"{label:<14} {T:>9.3g}  {f'{zc:.3f}/{zd:.3f}':>17}  {np.nanmax(a.pole_error):>10.3g}  "
        f"{err:<26} {np.nanmax(np.abs(a.feedthrough)):>14.3g}"
    )


# why a row has empty cells (its values there are not finite)
NO_POLES = "not finite here: no steady state found or the sampled observer overflows"


def discrete_csv(a: DiscretePoleSweep, w_base: float) -> str:
    """CSV text: per operating point the continuous and discrete poles, steady errors, feedthrough."""
    return pole_table(
        a,
        w_base,
        {"pole": a.poles, "dpole": a.poles_discrete},
        notes=(f"gain law: {a.law.name}", f"discretization: {a.discretization}", f"T_s {a.T_s:.10g} s"),
        legend="pole = continuous, dpole = ln(z)/T_s",
        after={
            "err_theta_deg": np.degrees(a.err_theta),
            "err_w_rad_s": a.err_w,
            "dw_hat_du_d_rad_s_V": a.feedthrough[:, 0],
            "dw_hat_du_q_rad_s_V": a.feedthrough[:, 1],
            "memory_abs_z": a.memory_z,
        },
        why=NO_POLES,
    )


def analyze_output(drive: IpmsmDrive, sweeps: list[tuple[str, float, Any, Any]], out: Any) -> None:
    """Print the discrete results of ``sweeps`` ((label, torque, sweep, low-speed sweep), each a
    DiscretePoleSweep); stage their CSV and pole maps of ln(z)/T_s."""
    import matplotlib.pyplot as plt
    from sensorless.design.linearization import Linearization
    from sensorless.reports.pole_map import plot_pole_maps

    wb = drive.w_base
    print(header(sweeps[0][2]))
    print(TABLE_HEAD)
    by_T: dict[float, tuple[dict[str, Any], dict[str, Any]]] = {}
    for label, T, a, low in sweeps:
        print(line(label, T, a, wb))
        out.add_text(f"poles_discrete_{label.replace(' ', '_')}_T{T:+g}Nm.csv", discrete_csv(a, wb))
        full, lows = by_T.setdefault(T, ({}, {}))
        full[label] = Linearization(a.w, a.torque, a.poles_discrete)
        lows[label] = Linearization(low.w, low.torque, low.poles_discrete)
    print(
        "  (damping and steady angle error theta_m - theta_hat at the samples over |w_m| >= 0.05 p.u.;\n"
        "   pole error: largest |ln(z)/T_s - s| [1/s]; w_hat per volt: d w_hat / d u [rad/s per V])"
    )
    a = sweeps[0][2]
    for T, (full, lows) in by_T.items():
        fig = plot_pole_maps(
            full,
            wb,
            f"{drive.name}: discrete-time observer ({a.discretization}, T_s = {a.T_s * 1e6:g} us), "
            f"ln(z)/T_s at T_e = {T:g} N m",
            lows,
        )
        out.add_figures(f"pole_map_discrete_T{T:+g}Nm", fig)
        plt.close(fig)


def study_output(
    drive: IpmsmDrive, choices: dict[str, Any], out: Any, progress: Callable[[str], None]
) -> None:
    """Print the discretization study for the gain choices and stage its CSV."""
    print(
        "discretization study (injection off): every scheme at "
        f"{', '.join(f'{t * 1e6:g}' for t in STUDY_SAMPLING)} us, |w_m| "
        f"{STUDY_SPEEDS[0]:g}..{STUDY_SPEEDS[-1]:g} p.u., +-T_N"
    )
    rows = study(drive, choices, progress)
    print(STUDY_HEAD)
    for ln in study_lines(rows):
        print(ln)
    out.add_text("discretization_study.csv", study_csv(rows, drive.w_base))


def study(
    drive: IpmsmDrive, choices: dict[str, Any], progress: Callable[[str], None]
) -> dict[str, list[StudyRow]]:
    """The study for each gain choice: every scheme at STUDY_SAMPLING, |w| in STUDY_SPEEDS, +-T_N."""
    sp = np.array(STUDY_SPEEDS)
    w = np.concatenate([-sp[::-1], sp]) * drive.w_base
    T = np.array([drive.T_N, -drive.T_N])
    out = {}
    for label, g in choices.items():
        d = with_alpha_fo(drive, g)
        out[label] = discretization_study(
            d, law_of(g), DISCRETIZATIONS, STUDY_SAMPLING, w[:, None], T[None, :], progress
        )
    return out


STUDY_HEAD = (
    f"  {'gain':<14} {'scheme':<11} {'T_s':>6} {'steady angle [deg]':>18} {'w_hat/volt':>10} "
    f"{'slow decay':>10} {'damping c/d':>12} {'pole error':>10}"
)


def study_lines(rows: dict[str, list[StudyRow]]) -> list[str]:
    """The study as printed lines (see STUDY_HEAD): the largest steady angle error, the voltage
    feedthrough [rad/s per V], the slowest pole's decay-rate error, worst damping, pole error [1/s]."""
    out = []
    for label, rs in rows.items():
        for r in rs:
            out.append(
                f"  {label:<14} {r.discretization:<11} {r.T_s * 1e6:>4.0f}us "
                f"{np.degrees(r.err_theta):>18.4f} {r.feedthrough:>10.4f} {100 * r.decay_error:>9.1f}% "
                f"{f'{r.damping_c:.3f}/{r.damping_d:.3f}':>12} {r.pole_error:>10.1f}"
            )
    return out


def study_csv(rows: dict[str, list[StudyRow]], w_base: float) -> str:
    """CSV of the study (one row per gain x scheme x T_s)."""
    head = (
        "gain,discretization,T_s_s,err_theta_max_deg,err_theta_at_w_pu,feedthrough_rad_s_V,"
        f"slow_decay_rel_error,worst_damping_c,worst_damping_d,pole_error_max_1_s,{REASON}"
    )
    lines = [f"# speeds +-{', '.join(map(str, STUDY_SPEEDS))} p.u. at +-T_N; injection off", head]
    for label, rs in rows.items():
        for r in rs:
            v = (
                r.T_s,
                np.degrees(r.err_theta),
                r.err_theta_w / w_base,
                r.feedthrough,
                r.decay_error,
                r.damping_c,
                r.damping_d,
                r.pole_error,
            )
            lines.append(f"{label},{r.discretization}," + csv_row(v, NO_POLES))
    return "\n".join(lines) + "\n"


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _decade(x: float, _pos: object = None) -> str:
    """A log axis' decade as plain text, 10 with a Unicode superscript (10⁻³): what matplotlib's
    default label shows, without its mathtext (each label parsed twice per figure, a third of the
    figure's CPU time); no label off the decades."""
    e = round(math.log10(x)) if x > 0 else None
    return "" if e is None or abs(math.log10(x) - e) > 1e-9 else "10" + str(e).translate(_SUPERSCRIPT)


def angle_error_figure(
    drive: IpmsmDrive, g: Any, w: np.ndarray, known: Mapping[tuple[str, float], np.ndarray] | None = None
) -> Any:
    """Steady position error of each scheme over speed at +-T_N, the drive's T_s (log scale).

    ``known``: steady angle errors [rad] over ``w`` already linearized, by (scheme, torque)."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    wb = drive.w_base
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for ax, T in zip(axes, (drive.T_N, -drive.T_N), strict=True):
        for m in DISCRETIZATIONS:
            err = (known or {}).get((m, T))
            if err is None:
                a = FAMILY.linearize(drive, g, w, T, discretization=m)
                assert isinstance(a, DiscretePoleSweep)  # with a discretization
                err = a.err_theta
            ax.semilogy(w / wb, np.abs(np.degrees(err)), label=m, lw=1.2)
        ax.axhline(0.1, color="0.4", ls=":", lw=0.8)
        ax.set_xlabel("rotor speed ω_m (p.u.)")
        ax.set_title(f"T_e = {T:+g} N m, T_s = {drive.control.T_s * 1e6:g} µs", fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        ax.yaxis.set_major_formatter(FuncFormatter(_decade))
    axes[0].set_ylabel("|steady position error| (electrical deg)")
    axes[0].legend(fontsize=8)
    lay_out(fig, [axes])
    return fig


def report_section(
    number: int,
    drive: IpmsmDrive,
    choices: dict[str, Any],
    review: str,
    fine: bool,
    progress: Callable[[str], None],
) -> tuple[dict[str, Any], Section]:
    """The report's section: each gain choice at the drive's scheme and T_s over -1..1 p.u. at +-T_N,
    the study of every scheme over T_s for the gains under review, and the steady-angle-error figure."""
    wb = drive.w_base
    disc, T_s = drive.run.discretization, drive.control.T_s
    w = np.linspace(-1, 1, 201 if fine else 41) * wb
    per_gain: dict[str, Any] = {}
    rows = []
    known: dict[tuple[str, float], np.ndarray] = {}  # the figure's, not linearized again
    for label, g in choices.items():
        for T in (drive.T_N, -drive.T_N):
            a = FAMILY.linearize(drive, g, w, T, discretization=disc)
            assert isinstance(a, DiscretePoleSweep)  # with a discretization
            if label == review:
                known[disc, T] = a.err_theta
            env = np.abs(w) >= 0.05 * wb  # below: the low-speed unstable band and its edge
            k = int(np.nanargmax(np.where(env, np.abs(a.err_theta), -1)))
            entry = {
                "T_Nm": f(T),
                "worst_damping_c": f(np.nanmin(np.where(env, a.worst_damping, np.nan))),
                "worst_damping_d": f(np.nanmin(np.where(env, a.worst_damping_discrete, np.nan))),
                "pole_error_max": f(np.nanmax(a.pole_error)),
                "err_theta_max_deg": f(np.degrees(abs(a.err_theta[k]))),
                "err_theta_at_w_pu": f(a.w[k] / wb),
                "feedthrough_max": f(np.nanmax(np.abs(a.feedthrough))),
            }
            per_gain.setdefault(label, {})[f"{T:+g}"] = entry
            rows.append(
                (
                    label,
                    num(entry["T_Nm"]),
                    f"{num(entry['worst_damping_c'], 3)} / {num(entry['worst_damping_d'], 3)}",
                    num(entry["pole_error_max"], 3),
                    f"{num(entry['err_theta_max_deg'], 3)} at {num(entry['err_theta_at_w_pu'], 3)} p.u.",
                    num(entry["feedthrough_max"], 3),
                )
            )
    n = f"{len(DISCRETIZATIONS)} schemes x {len(STUDY_SAMPLING)} sampling periods"
    progress(f"      discretization study ({review}: {n})")
    st = study(drive, {review: choices[review]}, lambda s: None)[review]
    data = {
        "discretization": disc,
        "T_s": f(T_s),
        "gains": per_gain,
        "study": [
            {
                "discretization": r.discretization,
                "T_s": f(r.T_s),
                "err_theta_max_deg": f(np.degrees(r.err_theta)),
                "feedthrough": f(r.feedthrough),
                "slow_decay_rel_error": f(r.decay_error),
                "worst_damping_c": f(r.damping_c),
                "worst_damping_d": f(r.damping_d),
                "pole_error_max": f(r.pole_error),
            }
            for r in st
        ],
    }
    fig = Figure(
        svg_later(functools.partial(angle_error_figure, drive, choices[review], w, known)),
        f"Steady position error at the sampling instants that each discretization of the runtime step "
        f"leaves ({review}, injection off): the fixed point of its one-step map on the motor sampled "
        "under zero-order hold. Dotted: 0.1 electrical degree.",
    )
    table = Table(
        (
            "gains",
            "torque (N m)",
            "worst damping cont. / discr., |ω| ≥ 0.05 p.u.",
            "largest pole error (1/s)",
            "largest steady angle error, |ω| ≥ 0.05 p.u. (deg)",
            "ŵ per volt (rad/s/V)",
        ),
        tuple(rows),
        caption=f"The runtime step as it runs ({disc}, T_s = {T_s * 1e6:g} µs) over −1…1 p.u.",
        numeric=frozenset({1, 3, 5}),
    )
    study_table = Table(
        ("scheme", "T_s (µs)", "steady angle (deg)", "ŵ per volt", "slow decay error", "damping c / d"),
        tuple(
            (
                r.discretization,
                f"{r.T_s * 1e6:g}",
                f"{np.degrees(r.err_theta):.4f}",
                f"{r.feedthrough:.4f}",
                f"{100 * r.decay_error:.1f} %",
                f"{r.damping_c:.3f} / {r.damping_d:.3f}",
            )
            for r in st
        ),
        caption=f"Every discretization over the sampling period ({review}; |ω| from "
        f"{STUDY_SPEEDS[0]:g} to {STUDY_SPEEDS[-1]:g} p.u. at ±T_N).",
        numeric=frozenset({1, 2, 3, 4}),
    )
    text = Paragraph(
        "The observer that runs is the discrete-time runtime step, not the continuous observer of eqs. "
        "(11)-(15): its one-step map, linearized at its own fixed point on the motor sampled under "
        "zero-order hold, gives the poles ln(z)/T_s beside the continuous ones, the steady position "
        "error the discretization leaves, and the voltage feedthrough dŵ/du (how far the speed estimate "
        "of a sample moves with the voltage applied from that sample on, before the current has "
        "answered). docs/families/ipmsm_adaptive.md, “Discretization”."
    )
    return data, Section(f"{number}. Discrete-time observer that runs", (text, table, fig, study_table))
