"""Figures of simulated traces in the style of the papers' figures: stacked panels over time, black lines.

Panels (names used by a scenario's ``figure`` list): the shared ones of every drive
(design/scenario.py ``GENERIC_PANELS``), drawn here from the traces every loop records,

- ``speed``: rotor speed (solid), its estimate (dashed), its reference (dotted) (Piippo et al. 2008
  Fig. 9)
- ``speed_error``: speed estimation error w_m - w_hat (Piippo et al. 2008 Fig. 6; De Angelo et al.
  2006 Figs. 2(b), 3(b))
- ``tracking_error``: speed tracking error w_ref - w_m (De Angelo et al. 2006 Fig. 5)
- ``torque``: estimated electromagnetic torque (solid) and load torque (dotted), p.u. of T_N (Piippo
  et al. 2008 Fig. 9)
- ``theta_error``: position estimation error, electrical degrees (Piippo et al. 2008 Figs. 6, 9, 10,
  last subplot)

and the panels the drive's family declares (``ObserverFamily.panels``: design/family.py ``Panel``, its
lines over time), drawn from their declaration.

Where the open-loop I-f start had the loop (its output ``startup_mode`` is 1: design/startup.py), every
panel is shaded grey: there theta_hat and w_hat are the current vector's, not the observer's estimates,
and the time-domain checks judge the observer only outside (reports/time_domain.py).

Speeds are shown in the drive's display unit (the simulation set-up's ``speed_unit``: p.u. for PMSM
drives, design/pmsm_drive.py; mechanical r/min for the reduced-order-observer drive).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design import registry
from sensorless.design.family import Panel
from sensorless.reports.figure_layout import lay_out

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure as MplFigure
    from sensorless.design.simulate import Traces


def _speed(ax: Axes, tr: Traces) -> None:
    k, unit = tr.meta["speed_scale"], tr.meta["speed_unit"]
    ax.plot(tr.t, tr["w_m"] * k, "k-", lw=1.0, label=r"$\omega_\mathrm{m}$")
    ax.plot(tr.t, tr["w_hat"] * k, "k--", lw=1.0, label=r"$\hat\omega_\mathrm{m}$")
    ax.plot(tr.t, tr["w_ref"] * k, "k:", lw=1.0, label=r"$\omega_\mathrm{m,ref}$")
    if "w_ref_r" in tr.data:  # the drive's rate-limited reference, which its speed controller tracks
        ax.plot(tr.t, tr["w_ref_r"] * k, "k-.", lw=0.8, label=r"$\omega_\mathrm{m,ref}$ ramped")
    ax.set_ylabel(rf"$\omega_\mathrm{{m}}$ ({unit})")


def _speed_error(ax: Axes, tr: Traces) -> None:
    k, unit = tr.meta["speed_scale"], tr.meta["speed_unit"]
    ax.plot(tr.t, (tr["w_m"] - tr["w_hat"]) * k, "k-", lw=1.0, label=r"$\omega - \hat\omega$")
    ax.set_ylabel(rf"speed est. error ({unit})")


def _tracking_error(ax: Axes, tr: Traces) -> None:
    k, unit = tr.meta["speed_scale"], tr.meta["speed_unit"]
    ref = tr["w_ref_r"] if "w_ref_r" in tr.data else tr["w_ref"]  # what the speed controller tracks
    ax.plot(tr.t, (ref - tr["w_m"]) * k, "k-", lw=1.0, label=r"$\omega_\mathrm{ref} - \omega$")
    ax.set_ylabel(rf"tracking error ({unit})")


def _torque(ax: Axes, tr: Traces) -> None:
    T_N = tr.meta["T_N"]
    if "T_e_hat" in tr.data:  # the torque the controller sees (estimated frame)
        ax.plot(tr.t, tr["T_e_hat"] / T_N, "k-", lw=1.0, label=r"$\hat T_\mathrm{e}$")
    else:
        ax.plot(tr.t, tr["T_e"] / T_N, "k-", lw=1.0, label=r"$T_\mathrm{e}$")
    ax.plot(tr.t, tr["T_L"] / T_N, "k:", lw=1.0, label=r"$T_\mathrm{L}$")
    ax.set_ylabel(r"$T$ (p.u.)")


def _theta_error(ax: Axes, tr: Traces) -> None:
    ax.plot(tr.t, np.degrees(tr["theta_err"]), "k-", lw=1.0, label=r"$\tilde\theta_\mathrm{m}$")
    ax.set_ylabel(r"$\tilde\theta_\mathrm{m}$ (deg)")


PANELS: dict[str, Callable[[Axes, Traces], None]] = {  # design/scenario.py GENERIC_PANELS
    "speed": _speed,
    "speed_error": _speed_error,
    "tracking_error": _tracking_error,
    "torque": _torque,
    "theta_error": _theta_error,
}


def _declared(panel: Panel) -> Callable[[Axes, Traces], None]:
    """The drawing of a family's declared panel: each line from the first of its traces the run has."""

    def draw(ax: Axes, tr: Traces) -> None:
        for line in panel.lines:
            name = next((n for n in line.traces if n in tr.data), line.traces[-1])
            ax.plot(tr.t, tr[name], line.style, lw=1.0, label=line.label)
        ax.set_ylabel(panel.ylabel)

    return draw


def panels_of(traces: Traces) -> dict[str, Callable[[Axes, Traces], None]]:
    """Panel name -> drawing, for the traces of a run: the shared panels and its family's."""
    kind = traces.meta.get("kind")
    own = registry.family(kind).panels if kind in registry.kinds() else ()
    return {**PANELS, **{p.name: _declared(p) for p in own}}


class _Labels:
    """Stands in for an Axes to collect the labels a panel draws (its lines' and its y label)."""

    def __init__(self) -> None:
        self.texts: list[str] = []

    def plot(self, *_args: object, label: str | None = None, **_kw: object) -> None:
        if label:
            self.texts.append(label)

    def set_ylabel(self, text: str, *_args: object, **_kw: object) -> None:
        self.texts.append(text)


def labels(traces: Traces, panels: tuple[str, ...]) -> list[str]:
    """The labels :func:`plot_traces` draws for ``panels`` (each panel drawn on a recorder): what the
    report's trace figures share (reports/svg_render.py ``svg_later`` ``texts``)."""
    draw = panels_of(traces)
    rec = _Labels()
    for name in panels:
        draw[name](rec, traces)  # type: ignore[arg-type]  # a recorder in place of an Axes
    return [*dict.fromkeys(rec.texts), "time (s)"]


def open_loop_intervals(traces: Traces) -> list[tuple[float, float]]:
    """(start, end) [s] of each interval in which the open-loop I-f start had the loop (its output
    ``startup_mode`` is 1); none for a run without it."""
    if "startup_mode" not in traces.data:
        return []
    mode = np.asarray(traces["startup_mode"]) > 0.5
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mode.astype(int), [0]))))
    t = traces.t
    return [(float(t[a]), float(t[min(b, t.size - 1)])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


MAX_POINTS = 20000  # per line: more is invisible at figure resolution and bloats the SVG


def plot_traces(traces: Traces, panels: tuple[str, ...], title: str) -> MplFigure:
    """A matplotlib Figure with the given panels stacked over a shared time axis.

    Long runs are thinned to at most MAX_POINTS samples per line (every k-th sample).
    """
    import dataclasses

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"  # deterministic SVG element ids

    k = max(1, -(-len(traces.t) // MAX_POINTS))
    if k > 1:
        traces = dataclasses.replace(
            traces, t=traces.t[::k], data={n: v[::k] for n, v in traces.data.items()}
        )
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(6.4, 1.9 * len(panels) + 0.8))
    axes = np.atleast_1d(axes)
    draw = panels_of(traces)
    shaded = open_loop_intervals(traces)
    for ax, name in zip(axes, panels, strict=True):
        draw[name](ax, traces)
        for a, b in shaded:  # the open-loop I-f start had the loop: not the observer's (time_domain.py)
            ax.axvspan(a, b, color="0.88", lw=0, zorder=0)
        ax.grid(True, lw=0.3, color="0.8")
        if len(ax.get_lines()) > 1:
            ax.legend(loc="best", fontsize=8, frameon=False, ncol=len(ax.get_lines()))
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_xlim(traces.t[0], traces.t[-1])
    lay_out(fig, axes[:, None], title=title, title_size=9, gap=0.15)
    return fig
