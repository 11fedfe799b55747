"""A gain table's per-point figures as CSV (the dense re-verification grid), units in the header."""

from __future__ import annotations

import json
import math
from typing import Any

from sensorless.design.gain_table import GainTable, clean


def table_csv(table: GainTable, columns: tuple[Any, Any]) -> str:
    """CSV text; ``columns`` = (leading per-point columns, baseline columns), each (heading, point key)."""
    env = table.envelope
    lead, base = columns
    head = [h for h, _ in lead] + ["damping", "decay_rate_1_s"]
    n = len(table.points[0]["poles"]) if table.points else 0
    for k in range(n):
        head += [f"pole{k}_re_1_s", f"pole{k}_im_1_s"]
    head += [f"baseline_{h}" for h, _ in base] + ["baseline_damping", "baseline_decay_rate_1_s"]
    where = (
        f"speed base {env.get('speed_base_rad_s', float('nan')):.10g} rad/s (electrical)"
        if "speed_base_rad_s" in env
        else "speeds mechanical r/min, w electrical; discrete poles at "
        f"T_s = {env.get('T_s_s', float('nan')):.6g} s"
    )
    lines = [
        f"# sensorless gain table, family {table.family}, drive {table.drive.get('name')}; "
        f"{where}; baseline = the drive file's gains",
        "# gains: " + json.dumps(clean(table.gains), sort_keys=True),
        ",".join(head),
    ]
    for p in table.points:
        row = [p[k] for _, k in lead] + [p["damping"], p["decay_rate"]]
        for re, im in p["poles"]:
            row += [re, im]
        b = p["baseline"]
        row += [b[k] for _, k in base] + [b["damping"], b["decay_rate"]]
        lines.append(",".join("nan" if v is None or not math.isfinite(v) else f"{v:.10g}" for v in row))
    return "\n".join(lines) + "\n"
