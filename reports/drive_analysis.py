"""The whole sampled drive's poles (design/drive_analysis.py) for ``analyze --drive`` and the report.

Shared by every family: the computation is the design layer's; this module sweeps the speed at -T_N, 0
and T_N in one batched linearization and presents it beside the family's observer-only analysis (the
paper's, which stays): a pole map of the drive's slow poles, a CSV of every point, report.json's
``drive_analysis`` and a report section.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.drive_analysis import DriveLinearization, linearize_drive
from sensorless.design.family import Drive, GainSet
from sensorless.design.low_speed import full_acceleration
from sensorless.reports.document import Figure, Paragraph, Report, Section, Table, num
from sensorless.reports.pole_map import pole_table
from sensorless.reports.svg_render import PendingSvg, svg_later

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure

N_SPEEDS = 40  # -1 .. 1 p.u. (no point at exactly zero speed); QUICK_SPEEDS for `report --quick`
QUICK_SPEEDS = 20
TORQUES = (-1.0, 0.0, 1.0)  # in T_N


def sweep(drive: Drive, gains: GainSet, n_speeds: int = N_SPEEDS) -> DriveLinearization:
    """The whole drive over speeds -1..1 p.u. x TORQUES (speed-major), one batched evaluation."""
    w = drive.w_base * np.linspace(-1.0, 1.0, n_speeds)
    T = drive.T_N * np.array(TORQUES)
    return linearize_drive(drive, gains, w[:, None], T[None, :])


def data(lin: DriveLinearization, drive: Drive) -> dict[str, Any]:
    """report.json's ``drive_analysis``: per point the slow poles, worst damping, slowest decay, steady
    angle error and the lag under the full acceleration."""
    a = full_acceleration(drive)
    slow = lin.slow()
    # properties of the whole sweep, each computed over every point: once, not once per point
    max_real, damping, lag = lin.max_real, lin.worst_damping, lin.lag(a)
    f = lambda v: None if not np.isfinite(v) else float(v)  # noqa: E731
    points = []
    for k in range(lin.w.size):
        s = slow[k][np.isfinite(slow[k])]
        points.append(
            {
                "w_pu": float(lin.w[k] / drive.w_base),
                "T_pu": float(lin.torque[k] / drive.T_N),
                "fixed_point": bool(np.isfinite(lin.y[k]).all()),
                "max_real_per_s": f(max_real[k]),
                "worst_damping": f(damping[k]),
                "theta_err_deg": f(np.degrees(lin.theta_err[k])),
                "lag_at_a_max_deg": f(np.degrees(lag[k])),
                "slow_poles": [[float(p.real), float(p.imag)] for p in s if p.imag >= 0],
            }
        )
    return {
        "what": "the whole sampled drive linearized (design/drive_analysis.py): plant under the inverter's "
        "hold, current PI in the estimated frame with its delay, speed PI on the observer's speed, the "
        "observer's runtime step, mechanics with the load",
        "note": lin.note,
        "a_max_rad_per_s2": a,
        "points": points,
    }


# why a row of the CSV has empty cells (its values there are not finite)
NO_FIXED_POINT = "no fixed point of the drive's one-step map found here: no steady operating point"


def csv(lin: DriveLinearization, drive: Drive) -> str:
    """CSV text (reports/pole_map.py ``pole_table``): one row per operating point, its torque also in
    p.u. of T_N, the largest real part, worst damping, steady angle error and lag under the full
    acceleration, then every pole as re/im pairs [1/s]; empty cells and a reason where no fixed point is
    found."""
    a = full_acceleration(drive)
    note = (lin.note,) if lin.note else ()
    return pole_table(
        lin,
        drive.w_base,
        {"pole": lin.poles},
        notes=("whole sampled drive (design/drive_analysis.py)", f"a_max = {a:.6g} rad/s^2", *note),
        before={
            "T_pu": lin.torque / drive.T_N,
            "max_real_1_s": lin.max_real,
            "worst_damping": lin.worst_damping,
            "theta_err_deg": np.degrees(lin.theta_err),
            "lag_at_a_max_deg": np.degrees(lin.lag(a)),
        },
        why=NO_FIXED_POINT,
    )


def figure(lin: DriveLinearization, drive: Drive, title: str) -> MplFigure:
    """Pole map of the slow poles (upper half-plane), one panel per torque, coloured by speed."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TORQUES), figsize=(9.0, 3.4), sharey=True)
    slow = lin.slow()
    T_pu = lin.torque / drive.T_N
    for ax, t in zip(axes, TORQUES, strict=True):
        sel = np.isclose(T_pu, t)
        s = slow[sel]
        w = np.repeat((lin.w[sel] / drive.w_base)[:, None], s.shape[1], axis=1)
        keep = np.isfinite(s) & (s.imag >= 0)
        sc = ax.scatter(s.real[keep], s.imag[keep], c=w[keep], cmap="viridis", s=8, vmin=-1, vmax=1)
        ax.axvline(0, color="k", lw=0.6)
        ax.set_title(f"T = {t:g} T_N", fontsize=9)
        ax.set_xlabel("Re s (1/s)")
        ax.grid(True, color="0.9")
    axes[0].set_ylabel("Im s (1/s)")
    fig.colorbar(sc, ax=axes, label="speed (p.u.)")
    fig.suptitle(title, fontsize=9)
    return fig


def summary(lin: DriveLinearization, drive: Drive) -> list[str]:
    """Lines for the terminal: the least stable point, the least damped one, the largest angle error
    and the largest lag under the full acceleration."""
    a = full_acceleration(drive)
    w, T = lin.w / drive.w_base, lin.torque / drive.T_N
    found = np.isfinite(lin.y).all(axis=1)
    out = [f"whole sampled drive: {int(found.sum())} of {found.size} operating points have a fixed point"]
    if lin.note:
        out.append(f"  ({lin.note})")
    if not found.any():
        return out
    at = lambda k: f"at {w[k]:+.3g} p.u., {T[k]:+.3g} T_N"  # noqa: E731
    k = int(np.nanargmax(np.where(found, lin.max_real, -np.inf)))
    out.append(f"  largest real part {lin.max_real[k]:.4g} 1/s {at(k)}")
    k = int(np.nanargmin(np.where(found, lin.worst_damping, np.inf)))
    out.append(f"  worst damping of the slow poles {lin.worst_damping[k]:.3g} {at(k)}")
    err = np.where(found, np.abs(lin.theta_err), -np.inf)
    k = int(np.argmax(err))
    out.append(f"  largest steady angle error {np.degrees(lin.theta_err[k]):.3g} deg {at(k)}")
    lag = np.where(found, np.abs(lin.lag(a)), -np.inf)
    k = int(np.nanargmax(lag))
    out.append(
        f"  largest lag under the full acceleration {a:.4g} rad/s^2: {np.degrees(lag[k]):.3g} deg {at(k)}"
    )
    return out


def section(
    number: int, lin: DriveLinearization, drive: Drive, svg: PendingSvg | str | None = None
) -> Section:
    """The report section of the whole drive's poles; ``svg``: its figure, drawn already (:func:`ahead`)."""
    text = (
        "The whole sampled drive linearized at its fixed point at each speed and load (design/"
        "drive_analysis.py): the loop the simulations run, with the current PI in the estimated frame, "
        "its computation delay, the speed PI on the observer's speed and the observer's runtime step; "
        "its one-step Jacobian by automatic differentiation, poles ln(z)/T_s. Beside the observer-only "
        "analysis above (the paper's), which closes the observer on ideal current control in the true "
        "frame. The minimum sensorless speed and the I-f handover are judged on this one."
        + (f" {lin.note[0].upper() + lin.note[1:]}." if lin.note else "")
    )
    rows = []
    w, T = lin.w / drive.w_base, lin.torque / drive.T_N
    # each a computation over every point (properties of the sweep): once, not once per row
    max_real, damping, lag = lin.max_real, lin.worst_damping, lin.lag(full_acceleration(drive))
    for t in TORQUES:
        sel = np.flatnonzero(np.isclose(T, t) & (w > 0))
        for k in sel[:: max(1, sel.size // 5)]:
            rows.append(
                (
                    num(T[k], 3),
                    num(w[k], 3),
                    num(max_real[k], 4),
                    num(damping[k], 3),
                    num(np.degrees(lin.theta_err[k]), 3),
                    num(np.degrees(lag[k]), 3),
                )
            )
    head = (
        "T (T_N)",
        "speed (p.u.)",
        "max Re s (1/s)",
        "worst damping",
        "angle error (deg)",
        "lag at a_max (deg)",
    )
    table = Table(head, tuple(rows), numeric=frozenset(range(6)))
    fig = Figure(
        svg if svg is not None else drawn(lin, drive),
        "Slow poles of the whole sampled drive (|s| below a quarter of the sampling limit), by speed.",
    )
    return Section(f"{number}. Whole sampled drive: poles", (Paragraph(text), table, fig))


def drawn(lin: DriveLinearization, drive: Drive) -> PendingSvg | str:
    """The section's figure, drawn by a child process (reports/svg_render.py)."""
    return svg_later(functools.partial(figure, lin, drive, f"{drive.name}: whole sampled drive, slow poles"))


def ahead(drive: Drive, gains: GainSet, quick: bool = False) -> Callable[[Report], Report]:
    """:func:`add_to_report` in two steps: the sweep and its figure now, the figure then drawn by a child
    process while the report computes on (the report asks for it first, to have it drawn beside its
    analyses rather than after them); the returned function adds the data and the section (last)."""
    import dataclasses

    try:
        lin = sweep(drive, gains, QUICK_SPEEDS if quick else N_SPEEDS)
    except ValueError as e:  # CapabilityError, or a loop that cannot be set up for this drive (said)
        why = str(e)
        return lambda rep: dataclasses.replace(
            rep, data={**rep.data, "drive_analysis": {"not_analysed": why}}
        )
    svg = drawn(lin, drive)

    def add(rep: Report) -> Report:
        sec = section(len(rep.sections) + 1, lin, drive, svg)
        return dataclasses.replace(
            rep, data={**rep.data, "drive_analysis": data(lin, drive)}, sections=(*rep.sections, sec)
        )

    return add


def add_to_report(rep: Report, drive: Drive, gains: GainSet, quick: bool = False) -> Report:
    """``rep`` with report.json's ``drive_analysis`` and its section (last); unchanged where the family
    declares no drive loop (said in report.json)."""
    return ahead(drive, gains, quick)(rep)
