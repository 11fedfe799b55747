"""Tables and figures of the reduced-order observer analysis: poles (continuous, discrete), steady errors."""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.pmac_reduced_order.linearize import ObserverPoles
from sensorless.reports.csv_cells import REASON
from sensorless.reports.csv_cells import row as csv_row
from sensorless.reports.document import pyplot
from sensorless.reports.figure_layout import lay_out
from sensorless.reports.pole_map import pole_table

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure
    from sensorless.design.pmac_reduced_order.schema import PmacDrive


# why a row has empty cells (its values there are not finite)
OVERFLOW = "not finite here: the linearized observer overflows (check the drive's units and the gains)"


def format_poles(poles: np.ndarray, digits: int = 4) -> str:
    """'-400, -389.2, -10.66' with complex pairs as '-200±34.1j' (upper member only)."""
    out = []
    for p in poles:
        if p.imag < -1e-9 * max(1.0, abs(p)):
            continue
        if abs(p.imag) > 1e-9 * max(1.0, abs(p)):
            out.append(f"{p.real:.{digits}g}±{abs(p.imag):.{digits - 1}g}j")
        else:
            out.append(f"{p.real:.{digits}g}")
    return ", ".join(out)


def poles_csv(r: ObserverPoles, drive: PmacDrive) -> str:
    """One row per operating point (reports/pole_map.py ``pole_table``, with the mechanical speed in
    r/min beside it); continuous (``pole_c``) and discrete (``pole_d``) poles as re/im pairs [1/s], the
    other one-step eigenvalues' |z|, the worst dampings, the steady errors; units and settings in the
    header."""
    head = (
        f"{drive.name}: load-torque estimation {'on' if r.load_estimation else 'off (Gamma = 0)'}",
        f"discretization {r.method}, T_s = {r.T_s:.10g} s",
        f"speeds: electrical rad/s and mechanical r/min (p = {drive.motor.p})",
        "errors: true minus estimate, steady state of the discrete observer",
    )
    return pole_table(
        r,
        drive.w_base,
        {"pole_c": r.poles, "pole_d": r.poles_discrete},
        notes=head,
        before={"speed_rpm": np.array([float(drive.w_to_rpm(w)) for w in r.w])},
        after={
            **{f"memory_abs_z{k}": r.memory_z[:, k] for k in range(r.memory_z.shape[1])},
            "monodromy_steps": r.steps,
            "worst_damping_c": np.nanmin(r.damping, axis=1),
            "worst_damping_d": np.nanmin(r.damping_discrete, axis=1),
            "err_w_rad_s": r.err_w,
            "err_theta_rad": r.err_theta,
            "err_T_L_Nm": r.err_T,
            "ripple_w_rad_s": r.ripple_w,
            "ripple_T_L_Nm": r.ripple_T,
        },
        why=OVERFLOW,
    )


def study_csv(rows: Sequence[Any], drive: PmacDrive) -> str:
    """The discretization study (design/pmac_reduced_order/discretization.py) as CSV."""
    buf = io.StringIO()
    buf.write(
        f"# {drive.name}: steady state of the discrete observer with load-torque estimation; "
        "effect_w = |speed error without load estimation| (continuous time)\n"
    )
    buf.write(
        "method,T_s_s,speed_rpm,T_L_Nm,err_w_rad_s,err_theta_rad,err_T_L_Nm,ripple_w_rad_s,"
        f"effect_w_rad_s,slow_pole_c_1_s,slow_pole_d_1_s,{REASON}\n"
    )
    for s in rows:
        vals = [
            s.T_s,
            s.rpm,
            s.T_L,
            s.err_w,
            s.err_theta,
            s.err_T,
            s.ripple_w,
            s.effect_w,
            s.slow_c,
            s.slow_d,
        ]
        buf.write(s.method + "," + csv_row(vals, OVERFLOW) + "\n")
    return buf.getvalue()


def plot_poles(results: dict[str, ObserverPoles], drive: PmacDrive, title: str) -> Figure:
    """Per variant (column): real parts of the poles vs speed, continuous (o) and discrete ln(z)/T_s (x),
    and the discrete observer's steady speed and load-torque errors vs speed; colored by load."""
    plt = pyplot()
    cols = len(results)
    fig, axes = plt.subplots(3, cols, figsize=(5.6 * cols, 9.0), squeeze=False, sharex=True)
    loads = np.unique(np.concatenate([r.T_L for r in results.values()]))
    colors = {T: plt.get_cmap("tab10")(k % 10) for k, T in enumerate(loads)}
    for c, (label, r) in enumerate(results.items()):
        rpm = drive.w_to_rpm(r.w)
        ax_p, ax_w, ax_t = axes[0, c], axes[1, c], axes[2, c]
        for T in loads:
            sel = r.T_L == T
            order = np.argsort(rpm[sel])
            x = rpm[sel][order]
            col = colors[T]
            for k in range(r.poles.shape[1]):
                lab = f"T_L = {T:g} N m" if k == 0 else None
                ax_p.plot(x, r.poles[sel][order, k].real, "o", mfc="none", color=col, ms=6, label=lab)
                ax_p.plot(x, r.poles_discrete[sel][order, k].real, "x", color=col, ms=6)
            ax_w.plot(x, r.err_w[sel][order], "x-", color=col, lw=0.8, label=f"T_L = {T:g} N m")
            ax_t.plot(x, r.err_T[sel][order], "x-", color=col, lw=0.8)
        ax_p.set_title(f"{label}\npoles: o continuous, x {r.method} at {r.T_s * 1e6:g} us", fontsize=9)
        ax_p.set_ylabel("Re(pole) (1/s)")
        ax_w.set_ylabel("steady speed error w - w_hat (rad/s)")
        ax_t.set_ylabel("steady load error (N m)")
        ax_t.set_xlabel("speed (r/min)")
        for ax in (ax_w, ax_t):
            ax.set_yscale("symlog", linthresh=1e-4)
        for ax in (ax_p, ax_w, ax_t):
            ax.grid(True, lw=0.3)
            ax.set_xscale("symlog", linthresh=100)
        ax_p.legend(loc="lower left", fontsize=8)
    lay_out(fig, axes, title=title)
    return fig
