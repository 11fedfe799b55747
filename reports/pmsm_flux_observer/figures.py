"""The flux-observer family's own report figures: the damping-versus-bias front of a tuned table, and the
steady angle bias over speed under each estimate error."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer import corner_estimate
from sensorless.design.pmsm_flux_observer.linearize import sampled_angle_errors
from sensorless.reports.figure_layout import lay_out
from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings, corners

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def front_figure(pf: dict[str, Any], mine: dict[str, Any]) -> Any:
    """Worst damping over worst angle bias along the front, the gains under review marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    pts = pf["points"]
    ax.plot([p["bias"] for p in pts], [p["worst_damping"] for p in pts], "o-", ms=4, label="front")
    if mine.get("worst_bias_deg") is not None and mine.get("worst_damping") is not None:
        ax.plot(mine["worst_bias_deg"], mine["worst_damping"], "kx", ms=8, label="gains under review")
    ax.set_xlabel("worst angle bias (deg)")
    ax.set_ylabel("worst damping")
    ax.grid(True, lw=0.3, color="0.8")
    ax.legend(fontsize=8, frameon=False)
    lay_out(fig, [[ax]])
    return fig


def bias_caption(settings: FluxTuneSettings) -> str:
    e = settings.errors
    return (
        "Steady angle bias of the sampled observer at rated torque over speed, for each estimate error "
        f"alone (R_s +-{100 * e['R_s']:g} %, psi_pm +-{100 * e['psi_pm']:g} %, L +-{100 * e['L']:g} %) "
        "and the worst "
        "corner of all three; gains under review."
    )


def bias_curves(
    drive: FluxObserverDrive, gains: GainSet, settings: FluxTuneSettings
) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """What :func:`bias_figure` draws: speeds [p.u.], the steady angle bias [deg] of the sampled
    observer at T_N under each estimate error alone, and the largest |bias| over the worst corners."""
    s = drive.envelope.speed_grid(2)
    s = s[s > 0]
    T = np.full(s.size, drive.T_N)
    e = drive.estimate
    cases = {}
    for key, rel in (("R_s", settings.errors["R_s"]), ("psi_pm", settings.errors["psi_pm"])):
        for sign in (-1, 1):
            cases[f"{key} {sign * 100 * rel:+g} %"] = {key: getattr(e, key) * (1 + sign * rel)}
    for sign in (-1, 1):
        r = 1 + sign * settings.errors["L"]
        cases[f"L {sign * 100 * settings.errors['L']:+g} %"] = {"L_d": e.L_d * r, "L_q": e.L_q * r}
    worst_cases = [corner_estimate(e, c) for c in corners(settings.errors)[1:]]
    errs = sampled_angle_errors(drive, gains, s, T, [*cases.values(), *worst_cases])  # one batch
    curves = {label: np.degrees(err) for label, err in zip(cases, errs, strict=False)}
    worst = np.zeros(s.size)
    for err in errs[len(cases) :]:
        worst = np.fmax(worst, np.abs(np.degrees(err)))
    return s / drive.w_base, curves, worst


def bias_figure(curves: tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]) -> Any:
    """The steady angle bias over speed of :func:`bias_curves` (drawing only: a figure child's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    w, cases, worst = curves
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, bias in cases.items():
        ax.plot(w, bias, label=label)
    ax.plot(w, worst, "k--", label="worst corner |bias|")
    ax.set_ylim(-45, 45)
    ax.set_xlabel("speed (p.u.)")
    ax.set_ylabel("angle bias (deg)")
    ax.grid(True, lw=0.3, color="0.8")
    ax.legend(fontsize=7, frameon=False, ncol=2)
    lay_out(fig, [[ax]])
    return fig
