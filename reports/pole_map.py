"""Pole maps over speed in the style of Piippo et al. (2008) Figs. 4-5, and their CSV data, for any family.

Fig. 4 shows the closed-loop poles of G_c(s) at nominal torque while the speed sweeps -1..1 p.u.
(upper half-plane only, the map is symmetric); Fig. 5 magnifies the origin, where the low-speed
right-half-plane pole of the motoring mode lives. Both panels are drawn here side by side.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
from sensorless.design.linearization import Linearization
from sensorless.reports.csv_cells import REASON
from sensorless.reports.csv_cells import row as csv_row
from sensorless.reports.document import pyplot
from sensorless.reports.figure_layout import Bar, lay_out

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure

# why a pole table's row has empty cells (the linearization's values there are not finite)
NO_POLES = "no finite poles here: no equilibrium found or the linearized observer overflows"


class OperatingPoints(Protocol):
    """What a pole table reads of its sweep besides the columns it is given: the operating points (a
    :class:`Linearization`, or the whole drive's, design/drive_analysis.py)."""

    @property
    def w(self) -> np.ndarray: ...  # (N,) electrical speed [rad/s]

    @property
    def torque(self) -> np.ndarray: ...  # (N,) torque [N m]

    @property
    def torque_name(self) -> str: ...  # which torque: "T_e" or "T_L"


def pole_csv(sweep: Linearization, w_base: float) -> str:
    """CSV text: one row per operating point; poles as re/im pairs [1/s]; units in the header.

    The family's own columns and notes (``Linearization.point_columns``, ``notes``: e.g. the operating
    point's current, the gain law) follow the operating point and open the header."""
    return pole_table(
        sweep,
        w_base,
        {"pole": sweep.poles},
        notes=sweep.notes(),
        before=sweep.point_columns(),
        after={"worst_damping": sweep.worst_damping, "max_real_1_s": sweep.max_real},
    )


def pole_table(
    sweep: OperatingPoints,
    w_base: float,
    poles: Mapping[str, np.ndarray],
    *,
    notes: Sequence[str] = (),
    legend: str = "",
    before: Mapping[str, np.ndarray] | None = None,
    after: Mapping[str, np.ndarray] | None = None,
    why: str = NO_POLES,
) -> str:
    """CSV text of a pole table (:func:`pole_csv`'s and other ones): per operating point of ``sweep``
    the speed [p.u., rad/s] and torque, the columns ``before``, each set of ``poles`` (its prefix ->
    (N, n) [1/s]) as re/im pairs, the columns ``after`` and the reason column (``why`` where a value is
    not finite). The header's comment: ``notes``, the speed base, ``legend`` (what the prefixes mean)."""
    before, after = before or {}, after or {}
    head = ["w_m_pu", "w_m_rad_s", f"{sweep.torque_name}_Nm", *before]
    for prefix, set_ in poles.items():
        for k in range(set_.shape[1]):
            head += [f"{prefix}{k}_re_1_s", f"{prefix}{k}_im_1_s"]
    head += [*after, REASON]
    comment = [*notes, f"speed base {w_base:.10g} rad/s (electrical)", *([legend] if legend else [])]
    buf = io.StringIO()
    buf.write("# " + "; ".join(comment) + "\n")
    buf.write(",".join(head) + "\n")
    for j in range(sweep.w.size):
        row = [sweep.w[j] / w_base, sweep.w[j], sweep.torque[j], *(col[j] for col in before.values())]
        for set_ in poles.values():
            for p in set_[j]:
                row += [p.real, p.imag]
        row += [col[j] for col in after.values()]
        buf.write(csv_row(row, why) + "\n")
    return buf.getvalue()


def _zoom_window(sweep: Linearization, w_base: float) -> float:
    """Half-width [1/s] of the magnified view: room for the slowest poles at |w_m| <= 0.05 p.u."""
    low = np.abs(sweep.w / w_base) <= 0.05
    mags = np.abs(sweep.poles[low])
    slowest = np.where(np.isfinite(mags), mags, np.inf).min(axis=1, initial=np.inf)
    slowest = slowest[np.isfinite(slowest)]
    return float(max(1.0, 1.5 * slowest.max())) if slowest.size else 50.0


def plot_pole_maps(
    sweeps: Mapping[str, Linearization],
    w_base: float,
    title: str,
    low_speed: Mapping[str, Linearization] | None = None,
) -> Figure:
    """One row per sweep: full map (Fig. 4) and magnified origin (Fig. 5), colored by speed.

    ``low_speed`` (same keys) are denser sweeps of the low-speed range drawn in the magnified panel.
    """
    import matplotlib

    plt = pyplot()
    rows = len(sweeps)
    fig, axes = plt.subplots(rows, 2, figsize=(11, 4.2 * rows), squeeze=False)
    cmap = plt.get_cmap("turbo")  # no white at zero speed: low-speed poles stay visible

    def shown(label: str, c: int) -> Linearization:
        return low_speed[label] if (c == 1 and low_speed) else sweeps[label]

    def speed_max(s: Linearization) -> float:
        return float(np.abs(s.w).max() / w_base) or 1.0

    # One colorbar per column where every row's speed range is the same (the usual case): the same
    # information as one per panel, and each colorbar is an axes that layout and drawing pay for.
    shared = [len({speed_max(shown(label, c)) for label in sweeps}) == 1 for c in range(2)]
    bars = []
    for r, (label, full) in enumerate(sweeps.items()):
        zoom = _zoom_window(full, w_base)
        for c, ax in enumerate(axes[r]):
            s = shown(label, c)
            w_pu = np.repeat(s.w / w_base, s.poles.shape[1])
            w_max = speed_max(s)
            norm = matplotlib.colors.Normalize(-w_max, w_max)
            p = s.poles.reshape(-1)
            keep = np.isfinite(p) & (p.imag >= -1e-9)
            size = 4 if c == 0 else 9  # the magnified view shows fewer points: draw them larger
            sc = ax.scatter(
                p.real[keep], p.imag[keep], c=w_pu[keep], cmap=cmap, norm=norm, s=size, lw=0, rasterized=True
            )
            bad = keep & (p.real > 1e-9)
            if bad.any():
                ax.scatter(p.real[bad], p.imag[bad], marker="x", c="k", s=14, lw=0.8, label="RHP pole")
                ax.legend(loc="upper right", fontsize=8)
            ax.axvline(0, color="0.4", lw=0.8)
            ax.axhline(0, color="0.4", lw=0.8)
            ax.set_xlabel("Real axis (1/s)")
            ax.set_ylabel("Imaginary axis (1/s)")
            ax.grid(True, lw=0.3)
            if not keep.any():  # no finite pole to show (e.g. no equilibrium anywhere): say so
                ax.text(0.5, 0.5, "no finite poles", transform=ax.transAxes, ha="center", va="center")
                ax.set_title(f"{label}: no finite poles", fontsize=9)
            elif c == 0:
                re = p.real[keep]
                im = p.imag[keep]
                ax.set_xlim(min(re.min() * 1.05, -1.0), max(0.05 * abs(re.min()), re.max() * 1.1))
                ax.set_ylim(-0.02 * max(im.max(), 1.0), max(im.max() * 1.1, 1.0))
                ax.set_title(f"{label}: poles of G_c(s), -1..1 p.u. (Fig. 4 style)", fontsize=9)
            else:
                ax.set_xlim(-zoom, 0.4 * zoom)
                seen = keep & (np.abs(p.real) <= zoom) & (p.imag <= zoom)
                top = p.imag[seen].max() if seen.any() else 0.0
                ax.set_ylim(-0.05 * zoom, max(0.25 * zoom, 1.1 * top))
                ax.set_title(f"{label}: magnified near the origin (Fig. 5 style)", fontsize=9)
            xl = ax.get_xlim()
            ax.axvspan(0, xl[1], color="tab:red", alpha=0.06, lw=0)
            ax.set_xlim(xl)
            if not shared[c]:
                bars.append(Bar(sc, c, slice(r, r + 1), "rotor speed ω_m0 (p.u.)"))
            elif r == 0:
                bars.append(Bar(sc, c, slice(0, rows), "rotor speed ω_m0 (p.u.)", aspect=20 * rows))
    lay_out(fig, axes, bars, title)
    return fig
