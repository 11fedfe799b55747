"""Report section of the adaptive observer: the tuned gains against the pointwise bound, and their noise.

At every speed of the tuning envelope's dense grid: the best worst-case damping that any gain
(lambda1, lambda2) reaches there (the pointwise bound, tuning/bound.py), beside the gains under review,
law (16) when the table carries it (a schedule's seed), and the drive file's gains; and the noise of
the estimates from the drive's current-sensor noise (design/noise.py) against the worst damping, with
the damping-versus-noise front of ``sensorless tune --pareto`` when the table has one.

From a gain table of ``sensorless tune`` the bound and the front are the table's (the same decay
floor as the tuning); without one, the bound is computed here on the drive's envelope
(``drive.envelope``: its ``[tuning]`` keys, widened to +-T_max on a drive of the user's own) with the
drive file's gains' own slowest decay as the floor (what any gain reaches while decaying at least as
fast), and there is no front.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.ipmsm_adaptive import FAMILY
from sensorless.reports.document import Figure, Paragraph, Section, Table, arr, f, num
from sensorless.reports.figure_layout import lay_out
from sensorless.reports.svg_render import svg_later

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive


def compute(
    drive: IpmsmDrive,
    table: Any | None,
    choices: dict[str, GainSet],
    review: str,
    progress: Callable[[str], None],
    default: str,
) -> tuple[dict[str, Any], Section | None]:
    """Data and section (None if there is nothing to show: no envelope to bound); ``default`` is the
    label of the drive file's default gains in ``choices``."""
    from sensorless.tuning.bound import pointwise_bound
    from sensorless.tuning.ipmsm_adaptive.laws import build_pointwise

    settings = drive.tuning
    env = drive.envelope  # the drive's range, the one tune judges (+-T_max on a drive of the user's own)
    wb = drive.w_base
    speeds = env.speed_grid(env.dense_factor)
    torques = env.torque_grid(env.dense_factor)
    W, T = np.meshgrid(speeds, torques)
    sigma, T_s = drive.control.i_noise, drive.control.T_s
    summary = table.summary if table is not None else {}
    # the gain sets to show: the drive file's default, the table's (and its seed, the speed-dependent law)
    sets: dict[str, GainSet] = {f"drive file ({drive.observer.gain})": choices[default]}
    seed = summary.get("seed")
    if seed is not None and seed.get("law") == "speed-dependent":
        p = seed["parameters"]
        vals = {"lambda_p": p["lambda_p"], "w_lambda": p["w_lambda"], "alpha_fo": drive.observer.alpha_fo}
        sets["speed-dependent (seed)"] = GainSet("speed-dependent", vals, "the table's seed")
    if table is not None:
        sets[review] = choices[review]
    figs: dict[str, dict[str, Any]] = {}
    for label, g in sets.items():
        s = FAMILY.linearize(drive, g, W.ravel(), T.ravel(), noise=True)
        z = s.worst_damping.reshape(torques.size, speeds.size)
        z = np.where(np.isfinite(z), z, -np.inf).min(axis=0)
        nz = s.noise_rms(sigma, T_s)
        nz = np.where(np.isnan(nz), np.inf, nz).max(axis=0)
        figs[label] = {
            "per_speed": z,
            "worst_damping": float(np.min(z)),
            "min_decay_rate": float(np.nanmin(s.decay_rate)),
            "noise_position_rad": float(nz[0]),
            "noise_speed_rad_s": float(nz[1]),
        }
    # the bound: the table's, else computed with the drive file's decay as the floor
    if "speeds" in summary:
        rows = summary["speeds"]
        bound = np.array([r["bound"] for r in rows], float)
        w_b = np.array([r["w_m_pu"] for r in rows], float) * wb
        floor = float(summary["bound"]["floor_1_s"])
        where = "the gain table (the tuning's decay floor)"
    else:
        floor = figs[next(iter(figs))]["min_decay_rate"]
        if not floor > 0:
            floor = float(settings.min_decay)
        progress(f"      pointwise bound on {speeds.size} speeds x {torques.size} torques")
        pw = build_pointwise(drive, settings)
        base = FAMILY.linearize(drive, sets[next(iter(sets))], W.ravel(), T.ravel())
        scale = float(np.nanmax(np.abs(base.poles)))
        b = pointwise_bound(pw, speeds, torques, floor, scale, coarse=env.dense_factor)
        bound, w_b = b.damping, b.speeds
        where = "computed here (the drive file's gains' slowest decay as the floor)"
    data: dict[str, Any] = {
        "envelope": env.describe(),
        "speeds_pu": arr(speeds / wb),
        "bound": {"damping": arr(bound), "speeds_pu": arr(w_b / wb), "floor_1_s": f(floor), "source": where},
        "gains": {
            k: {**{kk: f(vv) for kk, vv in v.items() if kk != "per_speed"}, "per_speed": arr(v["per_speed"])}
            for k, v in figs.items()
        },
        "noise": {"sigma_A": f(sigma), "T_s_s": f(T_s)},
        "pareto": summary.get("pareto"),
    }
    fig1 = Figure(
        svg_later(functools.partial(_bound_figure, w_b / wb, bound, speeds / wb, figs, floor)),
        "Worst damping over the envelope's torques at each speed: the pointwise bound (the best any gain "
        f"(λ1, λ2) reaches at that speed with decay ≥ {floor:.4g} 1/s; {where}) beside the gains. No gain "
        "law exceeds the bound's lowest value anywhere on the envelope.",
    )
    rows = [
        (
            label,
            num(v["worst_damping"], 4),
            num(float(np.min(bound)) - v["worst_damping"], 3),
            num(v["min_decay_rate"], 4),
            num(np.degrees(v["noise_position_rad"]), 3),
            num(v["noise_speed_rad_s"], 3),
        )
        for label, v in figs.items()
    ]
    tab = Table(
        (
            "gains",
            "worst damping",
            "below the bound's worst",
            "slowest decay (1/s)",
            "position noise (° el., rms)",
            "speed noise (rad/s el., rms)",
        ),
        tuple(rows),
        caption=f"Over the dense envelope {env.describe()}; noise for {sigma:.4g} A rms current-sensor noise "
        f"per axis and sample at T_s = {T_s * 1e6:g} µs (density σ² T_s; design/noise.py).",
        numeric=frozenset({1, 2, 3, 4, 5}),
    )
    blocks: list[Any] = [fig1, tab]
    pf = summary.get("pareto")
    if pf and table is not None:  # a front only in a table's summary
        blocks.append(
            Figure(
                svg_later(functools.partial(_pareto_figure, pf, figs)),
                f"Damping-versus-noise front of the {table.law} law (sensorless tune --pareto): the "
                f"best worst damping for a limit on the {pf['output']} noise, each point re-verified on the "
                "dense grid; the gain sets of the table above marked.",
            )
        )
    else:
        blocks.append(
            Paragraph(
                "No damping-versus-noise front: run `sensorless tune --pareto` and review its table to "
                "add it."
            )
        )
    ridge = summary.get("ridge")
    if ridge:
        blocks.append(Paragraph(ridge["text"]))
    return data, Section("7. Tuning: the pointwise bound and noise", tuple(blocks))


def _bound_figure(
    w_b: np.ndarray, bound: np.ndarray, w_pu: np.ndarray, figs: dict[str, Any], floor: float
) -> Any:
    import matplotlib.pyplot as plt

    def gap(w: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A NaN between the directions: no line across standstill (outside the envelope)."""
        k = np.flatnonzero(np.diff(np.sign(w)) != 0) + 1
        return np.insert(w.astype(float), k, np.nan), np.insert(np.asarray(z, float), k, np.nan)

    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    ax.plot(*gap(w_b, bound), color="k", lw=2.2, label="pointwise bound (any gain)")
    for label, v in figs.items():
        ax.plot(*gap(w_pu, v["per_speed"]), lw=1.3, label=label)
    ax.set_xlabel("speed ω_m (p.u.)")
    ax.set_ylabel("worst damping over the torques")
    ax.set_ylim(min(0.0, float(np.nanmin([np.min(v["per_speed"]) for v in figs.values()]))) - 0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower center")
    lay_out(fig, [[ax]])
    return fig


def _pareto_figure(pf: dict[str, Any], figs: dict[str, Any]) -> Any:
    import matplotlib.pyplot as plt

    key = "noise_position_rad" if pf["output"] == "position" else "noise_speed_rad_s"
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    pts = sorted(pf["points"], key=lambda p: p["noise"])
    ax.plot([p["noise"] for p in pts], [p["worst_damping"] for p in pts], "o-", color="k", label="front")
    for (label, v), mk in zip(figs.items(), ("s", "^", "D", "v"), strict=False):
        ax.plot([v[key]], [v["worst_damping"]], mk, ms=9, label=label)
    ax.set_xlabel(f"worst RMS {pf['output']} noise ({pf['unit']})")
    ax.set_ylabel("worst damping")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    lay_out(fig, [[ax]])
    return fig
