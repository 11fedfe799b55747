"""A gain table's per-point figures as CSV (the dense re-verification grid), units in the header."""

from __future__ import annotations

import json
from collections.abc import Sequence

from sensorless.design.gain_table import GainTable, clean
from sensorless.reports.csv_cells import REASON
from sensorless.reports.csv_cells import row as csv_row

# why a cell is empty (reports/csv_cells.py: every number written is finite)
NO_POINT_VALUE = "no finite figure at this operating point (no equilibrium or a linearization that overflows)"
NO_SPEED_VALUE = "no gain of this column reaches a finite figure at this speed"
NO_LIMIT = "no limit on this front point"


def table_csv(table: GainTable, columns: tuple[Sequence[tuple[str, str]], Sequence[tuple[str, str]]]) -> str:
    """CSV text; ``columns`` = (leading per-point columns, baseline columns), each (heading, point key)."""
    env = table.envelope
    lead, base = columns
    head = [h for h, _ in lead] + ["damping", "decay_rate_1_s"]
    n = len(table.points[0]["poles"]) if table.points else 0
    for k in range(n):
        head += [f"pole{k}_re_1_s", f"pole{k}_im_1_s"]
    head += [f"baseline_{h}" for h, _ in base] + ["baseline_damping", "baseline_decay_rate_1_s"]
    p0 = table.points[0] if table.points else {}
    seed = p0.get("seed", {}).get("law")
    if seed:
        head += [f"{seed}_damping", f"{seed}_decay_rate_1_s"]
    bound_keys = [k for k in p0.get("bound", {}) if k != "damping"]
    if "bound" in p0:
        head += ["bound_damping"] + [f"bound_{k}" for k in bound_keys]
    head.append(REASON)
    where = (
        f"speed base {env.get('speed_base_rad_s', float('nan')):.10g} rad/s (electrical)"
        if "speed_base_rad_s" in env
        else "speeds mechanical r/min, w electrical; discrete poles at "
        f"T_s = {env.get('T_s_s', float('nan')):.6g} s"
    )
    lines = [
        f"# sensorless gain table, law {table.law}, drive {table.drive.get('name')}; "
        f"{where}; baseline = the drive file's gains"
        + ("; bound = the best worst-case damping of any gain at the point's speed" if "bound" in p0 else ""),
        "# gains: " + json.dumps(clean(table.gains), sort_keys=True),
        ",".join(head),
    ]
    for p in table.points:
        row = [p[k] for _, k in lead] + [p["damping"], p["decay_rate"]]
        for re, im in p["poles"]:
            row += [re, im]
        b = p["baseline"]
        row += [b[k] for _, k in base] + [b["damping"], b["decay_rate"]]
        if seed:
            row += [p["seed"]["damping"], p["seed"]["decay_rate"]]
        if "bound" in p0:
            row += [p["bound"]["damping"]] + [p["bound"][k] for k in bound_keys]
        lines.append(csv_row(row, NO_POINT_VALUE))
    return "\n".join(lines) + "\n"


def speeds_csv(table: GainTable) -> str:
    """Per speed of the dense grid: the pointwise bound beside this law, its seed and the drive
    file's gains (worst damping over the torques at that speed); from ``summary.speeds``."""
    rows = table.summary["speeds"]
    keys = [k for k in ("bound", "tuned", "seed", "baseline") if k in rows[0]]
    names = {"tuned": table.law, "seed": table.summary.get("seed", {}).get("law", "seed")}
    b = table.summary.get("bound", {})
    lines = [
        f"# sensorless: worst damping over the torques at each speed, law {table.law}, drive "
        f"{table.drive.get('name')}; bound = the best any gain reaches at that speed (decay >= "
        f"{b.get('floor_1_s', float('nan')):.6g} 1/s); baseline = the drive file's gains (which the bound "
        "does not bound where they decay slower than its floor)",
        ",".join(["w_m_pu", *(f"{names.get(k, k)}_damping" for k in keys), REASON]),
    ]
    for r in rows:
        vals = [r["w_m_pu"], *(r[k] for k in keys)]
        lines.append(csv_row(vals, NO_SPEED_VALUE))
    return "\n".join(lines) + "\n"


def pareto_csv(table: GainTable) -> str:
    """The damping-versus-noise front of ``summary.pareto``: noise, worst damping, slowest decay and the
    parameters of each point (dense re-verification)."""
    pf = table.summary["pareto"]
    # a front may trade damping against another figure than noise: its name, the figure's meaning and
    # the parameters' names are then the front's own
    metric = pf.get("metric", "noise")
    names = pf.get("parameters") or list(table.summary.get("parameters", {}))
    meaning = pf.get("description") or (
        f"noise = worst RMS of the {pf['output']} estimate [{pf['unit']}] over the dense grid"
    )
    lines = [
        f"# sensorless: damping-versus-{metric} front, law {table.law}, drive {table.drive.get('name')}; "
        + meaning,
        ",".join([metric, "limit", "worst_damping", "min_decay_rate_1_s", *names, REASON]),
    ]
    for p in pf["points"]:
        vals = [
            p[metric],
            p.get("limit", float("inf")),
            p["worst_damping"],
            p["min_decay_rate"],
            *p["theta"],
        ]
        lines.append(
            csv_row(
                vals, NO_LIMIT if p.get("limit") is None or p.get("limit") == float("inf") else NO_POINT_VALUE
            )
        )
    return "\n".join(lines) + "\n"
