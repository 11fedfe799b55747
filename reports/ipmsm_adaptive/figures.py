"""Report figures of the adaptive observer: damping and decay maps over speed x torque, robustness maps."""

from __future__ import annotations

from typing import Any

import numpy as np
from sensorless.reports.figure_layout import Bar, lay_out


def plane_figure(maps: dict[str, dict[str, Any]], w_pu: np.ndarray, T: np.ndarray, T_N: float) -> Any:
    """Worst damping (top) and decay rate (bottom) over speed x torque, one column per gain choice."""
    import matplotlib.pyplot as plt

    cols = list(maps)
    fig, axes = plt.subplots(2, len(cols), figsize=(5.2 * len(cols), 7.4), squeeze=False)
    bars = []
    for c, label in enumerate(cols):
        m = maps[label]
        for r, (key, name, cmap, vmin, vmax) in enumerate(
            (
                ("damping", "worst damping ratio ζ", "RdYlGn", -0.2, 1.0),
                ("decay_rate", "decay rate −max Re(p) (1/s)", "viridis", 0.0, None),
            )
        ):
            ax = axes[r, c]
            Z = np.array(m[key], float)
            vmax_ = vmax if vmax is not None else np.nanpercentile(Z, 99)
            pc = ax.pcolormesh(
                w_pu, T / T_N, Z.T, cmap=cmap, vmin=vmin, vmax=vmax_, shading="nearest", rasterized=True
            )
            unstable = np.array(m["damping"], float) < 0
            if unstable.any():
                ax.contourf(
                    w_pu,
                    T / T_N,
                    unstable.T.astype(float),
                    levels=[0.5, 1.5],
                    colors="none",
                    hatches=["////"],
                )
                ax.contour(w_pu, T / T_N, unstable.T.astype(float), levels=[0.5], colors="k", linewidths=0.8)
            wk = m["worst"]
            ax.plot(wk["w_pu"], wk["T_Nm"] / T_N, marker="*", ms=14, mfc="w", mec="k")
            ax.set_xlabel("speed ω_m (p.u.)")
            ax.set_ylabel("torque T_e / T_N")
            ax.set_title(f"{label}: {name}", fontsize=9)
            bars.append(Bar(pc, c, slice(r, r + 1)))
    lay_out(fig, axes, bars)
    return fig


def robustness_figure(rob: dict[str, Any], w_pu: np.ndarray, label: str) -> Any:
    """Worst damping over speed x the error of one estimate, one panel per estimate."""
    import matplotlib.pyplot as plt

    names = list(rob["params"])
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.4), squeeze=False)
    cm = plt.get_cmap("RdYlGn").with_extremes(bad="0.6")  # no equilibrium: grey
    pc = None
    for ax, name in zip(axes.ravel(), names, strict=False):
        p = rob["params"][name]
        err = np.array(p["error_pct"], float)
        Z = np.array(p["damping"], float)
        pc = ax.pcolormesh(w_pu, err, Z, cmap=cm, vmin=-0.2, vmax=1.0, shading="nearest", rasterized=True)
        uns = np.nan_to_num(Z, nan=1.0) < 0
        if uns.any():
            ax.contour(w_pu, err, uns.astype(float), levels=[0.5], colors="k", linewidths=0.8)
        ax.axhline(0, color="k", lw=0.5, ls=":")
        ax.set_xlabel("speed ω_m (p.u.)")
        ax.set_ylabel(f"error of estimate {name} (%)")
        ax.set_title(f"{label}: worst damping, {name} misestimated", fontsize=9)
    # one colorbar: every panel has the same colour scale
    bars = [] if pc is None else [Bar(pc, 1, slice(0, 2), "ζ (grey: no equilibrium)", aspect=40)]
    lay_out(fig, axes, bars)
    return fig
