"""Monte-Carlo robustness run of ``sensorless montecarlo``: draws evaluated on the engine, the yield,
the worst draws, the sensitivity ranking, and their tables and figures.

The linear part: every draw's linearized closed loop over the design's envelope (the drive's
``[tuning]`` envelope), in chunks of design/montecarlo.CHUNK draws, each chunk one batched call of
the family's Monte-Carlo ``linearize_draws`` (no loop over draws); a draw passes when its worst damping
over the envelope is at least the required damping (a point without equilibrium fails it). The time domain:
the first K draws (a random sample of the draws, so their pass fraction estimates the population's)
simulated on the drive's generic scenarios (design/scenario.py, scaled to the nominal drive, so every
draw runs the same test) and judged by reports/time_domain.py; a simulation that raises is a failed
check with its message, not a failed run.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from sensorless.design import montecarlo as mc
from sensorless.design.capabilities import MonteCarlo, require
from sensorless.design.family import Drive, GainSet
from sensorless.design.registry import family_of
from sensorless.design.scenario import Scenario
from sensorless.reports.engine import Engine

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure as MplFigure
    from sensorless.reports.document import Section

WORST = 10  # worst draws listed


class DrawCheck(TypedDict):
    """The time-domain checks of one draw (summary JSON ``time_domain``)."""

    draw: int
    passed: bool
    failed: list[str]  # "<scenario>: <what failed>"


class Fraction(TypedDict):
    """A share of the draws with its standard error (None: no draws)."""

    value: float | None
    draws: int
    standard_error: float | None


@dataclass(frozen=True)
class Result:
    """A Monte-Carlo run: the draws, their per-draw results and the summary (the JSON written)."""

    draws: mc.Draws
    worst: np.ndarray  # (n,) worst damping over the envelope; -inf: a point without equilibrium
    at: np.ndarray  # (n,) index of the worst operating point
    w: np.ndarray  # envelope speeds [rad/s]
    torque: np.ndarray  # envelope torques [N m]
    td: list[DrawCheck]  # per time-domain draw
    summary: dict[str, Any]


def envelope(drive: Drive, gains: GainSet | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The design's envelope: the operating points the tuner held the gains to, where ``gains`` run the
    drive (the family's Monte-Carlo ``envelope_points``)."""
    return require(family_of(drive), MonteCarlo).montecarlo.envelope_points(drive, gains)


def linear_task(
    drive: Drive, gains: GainSet, plant: np.ndarray, estimate: np.ndarray, w: np.ndarray, T: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One chunk on a worker: (worst damping, worst point) per draw."""
    model = require(family_of(drive), MonteCarlo).montecarlo
    return mc.chunk_damping(model, drive, gains, plant, estimate, w, T)


def time_task(
    drive: Drive,
    gains: GainSet,
    plant: Mapping[str, float],
    estimate: Mapping[str, float],
    scenarios: Sequence[Scenario],
) -> list[tuple[str, list[str]]]:
    """One draw on a worker: each generic scenario simulated on the perturbed drive, (name, failed)."""
    from sensorless.design.simulate import simulate
    from sensorless.reports.time_domain import judge

    model = require(family_of(drive), MonteCarlo).montecarlo
    out = []
    for sc in scenarios:
        try:
            tr = simulate(model.perturbed(drive, plant, estimate), sc, gains)
            _, failed, _ = judge(tr, sc, drive.w_base)
        except Exception as e:  # a crashing draw is a failed check, recorded with its reason
            failed = [f"simulation raised {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"]
        out.append((sc.name, failed))
    return out


def time_scenarios(drive: Drive) -> list[Scenario]:
    """The generic scenarios of the nominal drive (none through zero speed where the family says its
    observer does not run there)."""
    from sensorless.design.scenario import crosses_zero, generic_scenarios, zero_speed_limit

    out = generic_scenarios(drive)
    if zero_speed_limit(drive):
        out = [sc for sc in out if not crosses_zero(sc)]
    return out


def run(
    drive: Drive,
    gains: GainSet,
    params: Sequence[mc.Uncertain],
    plant: Mapping[str, mc.Spread],
    estimate: Mapping[str, mc.Spread],
    samples: int,
    seed: int,
    time_domain: int,
    min_damping: float,
    engine: Engine,
) -> Result:
    """Draw, evaluate on ``engine``, summarise (module docstring)."""
    draws = mc.draw(params, samples, seed, plant, estimate)
    w, T = envelope(drive, gains)
    chunks = [(drive, gains, *draws.chunk(c), w, T) for c in range(draws.chunks)]
    items = []
    if time_domain:
        scs = time_scenarios(drive)
        items = [
            (
                drive,
                gains,
                dict(zip(draws.names, draws.plant[i], strict=True)),
                _estimated(params, draws.estimate[i]),
                scs,
            )
            for i in range(time_domain)
        ]
    # one submission: the time-domain draws do not wait for the last linear chunk
    label = "draws (linear chunks" + (", time-domain draws)" if items else ")")
    parts, sims = engine.map_groups([(linear_task, chunks), (time_task, items)], label)
    worst = np.concatenate([p[0] for p in parts])
    at = np.concatenate([p[1] for p in parts])
    td: list[DrawCheck] = []
    for i, res in enumerate(sims):
        failed = [f"{name}: {line}" for name, lines in res for line in lines]
        td.append({"draw": i, "passed": not failed, "failed": failed})
    summary = summarise(drive, gains, params, draws, plant, estimate, seed, worst, at, w, T, td, min_damping)
    return Result(draws, worst, at, w, T, td, summary)


def _estimated(params: Sequence[mc.Uncertain], row: np.ndarray) -> dict[str, float]:
    return {p.name: float(v) for p, v in zip(params, row, strict=True) if p.estimate is not None}


def _fraction(ok: np.ndarray) -> Fraction:
    n = int(ok.size)
    if n == 0:
        return {"value": None, "draws": 0, "standard_error": None}
    p = float(ok.mean())
    return {"value": round(p, 6), "draws": n, "standard_error": round(float(np.sqrt(p * (1 - p) / n)), 6)}


def summarise(
    drive: Drive,
    gains: GainSet,
    params: Sequence[mc.Uncertain],
    draws: mc.Draws,
    plant: Mapping[str, mc.Spread],
    estimate: Mapping[str, mc.Spread],
    seed: int,
    worst: np.ndarray,
    at: np.ndarray,
    w: np.ndarray,
    T: np.ndarray,
    td: Sequence[DrawCheck],
    min_damping: float,
) -> dict[str, Any]:
    """The JSON summary: inputs, yield, worst draws, sensitivity."""
    ok = worst >= min_damping
    k = len(td)
    td_ok = np.array([t["passed"] for t in td], bool)
    spread_names = [f"plant {n}" for n in plant] + [f"estimate {n}" for n in estimate]
    order = np.argsort(worst, kind="stable")[:WORST]
    worst_rows = []
    for i in order:
        worst_rows.append(
            {
                "draw": int(i),
                "worst_damping": None if not np.isfinite(worst[i]) else round(float(worst[i]), 6),
                "no_equilibrium": bool(np.isinf(worst[i])),
                # a draw without equilibrium somewhere stops there: its point is not located
                "speed_pu": None if np.isinf(worst[i]) else round(float(w[at[i]] / drive.w_base), 6),
                "torque_TN": None if np.isinf(worst[i]) else round(float(T[at[i]] / drive.T_N), 6),
                "plant": {n: float(v) for n, v in zip(draws.names, draws.plant[i], strict=True)},
                "estimate": _estimated(params, draws.estimate[i]),
            }
        )
    return {
        "drive": drive.name,
        "kind": drive.kind,
        "drive_file": drive.file,
        "drive_sha256": drive.digest,
        "gains": {"law": gains.law, "source": gains.source},
        "samples": int(worst.size),
        "seed": int(seed),
        "spread": {n: s.text() for n, s in plant.items()},
        "estimate_error": {n: s.text() for n, s in estimate.items()},
        "distributions": "X%: normal, X = one standard deviation; X%u: uniform in +-X; relative to the "
        "drive's value (plant) or estimate",
        "clipped": dict(draws.clipped),
        "clip_fraction": mc.CLIP_FRACTION,
        "min_damping": min_damping,
        "envelope_points": int(w.size),
        "yield": {
            "damping": _fraction(ok),
            "time_domain": _fraction(td_ok),
            "both": _fraction(ok[:k] & td_ok) if k else _fraction(td_ok),
        },
        "no_equilibrium_draws": int(np.isinf(worst).sum()),
        "worst_draws": worst_rows,
        "sensitivity_method": "Spearman rank correlation of each drawn relative deviation with the draw's "
        "worst damping (no equilibrium ranked lowest); ranked by magnitude",
        "sensitivity": mc.sensitivity(draws, params, spread_names, worst, ok),
        "time_domain_failures": [t for t in td if not t["passed"]],
    }


NO_EQUILIBRIUM = "no equilibrium at some operating point of the envelope (the observer loses the rotor)"


def _g(x: float) -> str:
    return "nan" if np.isnan(x) else "-inf" if np.isneginf(x) else f"{x:.9g}"


def draws_csv(res: Result, params: Sequence[mc.Uncertain], min_damping: float) -> str:
    """One row per draw: drawn values, worst damping, its operating point, pass/fail."""
    est = [p for p in params if p.estimate is not None]
    head = ["draw", *[f"plant_{p.name}" for p in params], *[f"estimate_{p.name}" for p in est]]
    head += ["worst_damping", "worst_speed_rad_s", "worst_torque_Nm", "passes_damping", "time_domain"]
    head += ["no_value_reason"]
    lines = [",".join(head)]
    td = {t["draw"]: t["passed"] for t in res.td}
    cols = [j for j, p in enumerate(params) if p.estimate is not None]
    for i in range(res.worst.size):
        row = [str(i), *[_g(v) for v in res.draws.plant[i]], *[_g(res.draws.estimate[i, j]) for j in cols]]
        lost = not np.isfinite(res.worst[i])  # no damping to write: the cells empty, the reason said
        row += ["", "", ""] if lost else [_g(res.worst[i]), _g(res.w[res.at[i]]), _g(res.torque[res.at[i]])]
        row += [str(int(res.worst[i] >= min_damping)), "" if i not in td else str(int(td[i]))]
        row += [NO_EQUILIBRIUM if lost else ""]
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def sensitivity_csv(summary: Mapping[str, Any]) -> str:
    lines = ["parameter,spearman_rho,mean_deviation_failed,mean_deviation_passed"]
    for r in summary["sensitivity"]:
        vals = [r["spearman_rho"], r["mean_deviation_failed"], r["mean_deviation_passed"]]
        lines.append(",".join([r["parameter"], *["" if v is None else f"{v:.6g}" for v in vals]]))
    return "\n".join(lines) + "\n"


def summary_json(summary: Mapping[str, Any], version: str) -> str:
    return json.dumps({"sensorless_version": version, **summary}, indent=2, sort_keys=False) + "\n"


def figures(res: Result, params: Sequence[mc.Uncertain], min_damping: float) -> dict[str, MplFigure]:
    """{stem: matplotlib figure}: the histogram of the worst damping, and its scatter against each
    spread parameter's deviation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"  # deterministic SVG element ids
    finite = res.worst[np.isfinite(res.worst)]
    none = int(np.isinf(res.worst).sum())
    fig, ax = plt.subplots(figsize=(7, 4))
    if finite.size:
        ax.hist(finite, bins=50, color="tab:blue")
    ax.axvline(min_damping, color="tab:red", ls="--", label=f"required {min_damping:g}")
    ax.set_xlabel("worst damping ratio over the envelope")
    ax.set_ylabel("draws")
    y = res.summary["yield"]["damping"]["value"]
    ax.set_title(f"{res.summary['drive']}: {res.worst.size} draws, yield {y:.3g}; {none} without equilibrium")
    ax.legend()
    fig.tight_layout()
    out = {"damping_histogram": fig}
    labels = [r["parameter"] for r in res.summary["sensitivity"]]
    if labels:
        n = len(labels)
        cols = min(3, n)
        rows = -(-n // cols)
        fig, axs = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
        shown = np.where(np.isfinite(res.worst), res.worst, np.nan)
        for ax, label in zip(axs.ravel(), labels, strict=False):
            which, name = label.split(" ", 1)
            j = res.draws.names.index(name)
            p = params[j]
            arr = res.draws.plant if which == "plant" else res.draws.estimate
            nominal = p.plant if which == "plant" else (p.estimate or p.plant)
            dev = 100 * (arr[:, j] / nominal - 1)
            ax.scatter(dev, shown, s=3, alpha=0.4, color="tab:blue", rasterized=True)
            ax.axhline(min_damping, color="tab:red", ls="--", lw=1)
            ax.set_xlabel(f"{label} deviation (%)")
            ax.set_ylabel("worst damping")
        for ax in axs.ravel()[n:]:
            ax.set_visible(False)
        fig.tight_layout()
        out["damping_scatter"] = fig
    return out


def typical_spreads(params: Sequence[mc.Uncertain]) -> dict[str, mc.Spread]:
    """The plant spreads a family declares typical (``report --montecarlo``): normal, 1 sigma."""
    return {p.name: mc.Spread(p.typical) for p in params if p.typical > 0}


def report_section(number: int, res: Result, params: Sequence[mc.Uncertain], min_damping: float) -> Section:
    """The report's Monte-Carlo section (``sensorless report --montecarlo N``): yield, sensitivity,
    worst draws and the histogram."""
    import matplotlib.pyplot as plt
    from sensorless.reports.document import Figure, Paragraph, Section, Table, num, svg_uri

    s = res.summary
    y = s["yield"]["damping"]
    spread = ", ".join(f"{k} {v}" for k, v in s["spread"].items())
    intro = Paragraph(
        f"{s['samples']} motors drawn (seed {s['seed']}; normal spreads, one standard deviation: {spread}; "
        "the observer's estimates as in the drive file), each linearized over the tuning envelope "
        f"({s['envelope_points']} operating points). Yield: {y['value']:.4g} (standard error "
        f"{y['standard_error']:.2g}) of the draws keep a damping of at least {min_damping:g} everywhere; "
        f"{s['no_equilibrium_draws']} draws have a point without equilibrium. For other spreads, estimate "
        "errors and time-domain draws: sensorless montecarlo.",
        "ok" if y["value"] == 1 else "bad",
    )
    sens = Table(
        ("parameter", "Spearman rho", "mean deviation, failed", "mean deviation, passed"),
        tuple(
            (
                r["parameter"],
                num(r["spearman_rho"]),
                num(r["mean_deviation_failed"]),
                num(r["mean_deviation_passed"]),
            )
            for r in s["sensitivity"]
        ),
        caption="Which parameter explains the failures: Spearman's rank correlation of the drawn "
        "deviation with the draw's worst damping (largest magnitude first).",
        numeric=frozenset({1, 2, 3}),
    )
    worst = Table(
        ("draw", "worst damping", "speed (p.u.)", "torque (T_N)"),
        tuple(
            (
                str(r["draw"]),
                "no equilibrium" if r["no_equilibrium"] else num(r["worst_damping"]),
                num(r["speed_pu"]),
                num(r["torque_TN"]),
            )
            for r in s["worst_draws"]
        ),
        caption="The worst draws (their values: report.json, montecarlo.worst_draws).",
        numeric=frozenset({1, 2, 3}),
    )
    figs = figures(res, params, min_damping)
    hist = Figure(svg_uri(figs.pop("damping_histogram")), "Worst damping of each draw over the envelope.")
    for fig in figs.values():
        plt.close(fig)
    return Section(f"{number}. Monte-Carlo robustness over a spread of motors", (intro, sens, worst, hist))
