"""Gain tables: the tuned observer gains as data (JSON), shared by tuning, C generation and reports.

Format ``sensorless-gain-table/1`` (see docs/gain_tables.md)::

    {"format": "sensorless-gain-table/1",
     "drive": {"name": ..., "kind": ..., "sha256": ...},
     "family": "law16" | "schedule" | "deangelo",
     "gains": {...},          # family-specific, SI units, see GAIN_KEYS
     "envelope": {...},       # what was optimized over (free form, documented by the writer)
     "points": [{...}, ...],  # per operating point: gains, poles, damping, decay rate, baseline
     "summary": {...}}

Writing is deterministic (sorted keys, floats as repr) so equal inputs give byte-identical files.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

FORMAT = "sensorless-gain-table/1"

# family -> required keys of "gains" (all SI: ohm, rad/s, ...)
GAIN_KEYS: dict[str, tuple[str, ...]] = {
    "law16": ("lambda_p", "w_lambda", "alpha_fo"),  # eq. (16) [ohm, rad/s], eq. (10) [rad/s]
    "schedule": ("w_hat", "lambda1", "lambda2", "alpha_fo"),  # breakpoints [rad/s], gains [ohm]
    "deangelo": ("g", "Gamma"),  # paper 002 observer gains [1/s], [A^2 s^2], eqs. (9)-(10)
}


class GainTableError(ValueError):
    """A gain table file is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class GainTable:
    """A tuned gain table."""

    family: str
    drive: dict[str, str]
    gains: dict[str, Any]
    envelope: dict[str, Any] = field(default_factory=dict)
    points: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        """Deterministic JSON text."""
        doc = {
            "format": FORMAT,
            "drive": self.drive,
            "family": self.family,
            "gains": self.gains,
            "envelope": self.envelope,
            "points": self.points,
            "summary": self.summary,
        }
        return json.dumps(_clean(doc), indent=1, sort_keys=True, allow_nan=False) + "\n"


def _clean(x: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to lists, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if hasattr(x, "tolist"):
        return _clean(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def read_gain_table(path: str | Path) -> GainTable:
    """Read and validate a gain table JSON file."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such gain table")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise GainTableError(f"{p}: not valid JSON: {e}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise GainTableError(f"{p}: key 'format': expected {FORMAT!r}")
    fam = doc.get("family")
    if fam not in GAIN_KEYS:
        raise GainTableError(f"{p}: key 'family': unknown family {fam!r} (known: {', '.join(GAIN_KEYS)})")
    gains = doc.get("gains")
    if not isinstance(gains, dict):
        raise GainTableError(f"{p}: key 'gains': missing or not an object")
    for k in GAIN_KEYS[fam]:
        if k not in gains:
            raise GainTableError(f"{p}: key 'gains.{k}': missing for family {fam}")
    if fam == "schedule":
        n = len(gains["w_hat"])
        for k in ("lambda1", "lambda2"):
            if len(gains[k]) != n:
                raise GainTableError(f"{p}: key 'gains.{k}': length {len(gains[k])} != len(w_hat) {n}")
        if any(b <= a for a, b in zip(gains["w_hat"], gains["w_hat"][1:], strict=False)):
            raise GainTableError(f"{p}: key 'gains.w_hat': breakpoints must increase strictly")
    drive = doc.get("drive")
    if not isinstance(drive, dict) or "name" not in drive:
        raise GainTableError(f"{p}: key 'drive': missing or without 'name'")
    return GainTable(
        family=fam,
        drive=drive,
        gains=gains,
        envelope=doc.get("envelope", {}),
        points=doc.get("points", []),
        summary=doc.get("summary", {}),
    )


# family -> (CSV heading, point key) of the leading per-point columns, and of the baseline's
_PAPER000 = (
    [
        ("w_m_pu", "w_m_pu"),
        ("w_m_rad_s", "w_m_rad_s"),
        ("T_e_Nm", "T_e_Nm"),
        ("lambda1_ohm", "lambda1"),
        ("lambda2_ohm", "lambda2"),
    ],
    [("lambda1_ohm", "lambda1"), ("lambda2_ohm", "lambda2")],
)
POINT_COLUMNS: dict[str, tuple[list[tuple[str, str]], list[tuple[str, str]]]] = {
    "law16": _PAPER000,
    "schedule": _PAPER000,
    "deangelo": (
        [
            ("n_rpm", "n_rpm"),
            ("w_rad_s", "w_rad_s"),
            ("T_L_Nm", "T_L_Nm"),
            ("g_1_s", "g"),
            ("Gamma_A2s2", "Gamma"),
        ],
        [("g_1_s", "g"), ("Gamma_A2s2", "Gamma")],
    ),
}


def table_csv(table: GainTable) -> str:
    """CSV text of the per-point figures (the dense re-verification grid), units in the header."""
    env = table.envelope
    lead, base = POINT_COLUMNS[table.family]
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
        f"{where}; baseline = the paper's default gains",
        "# gains: " + json.dumps(_clean(table.gains), sort_keys=True),
        ",".join(head),
    ]
    for p in table.points:
        row = [p[k] for _, k in lead] + [p["damping"], p["decay_rate"]]
        for re, im in p["poles"]:
            row += [re, im]
        b = p["baseline"]
        row += [b[k] for _, k in base] + [b["damping"], b["decay_rate"]]
        lines.append(",".join("nan" if not math.isfinite(v) else f"{v:.10g}" for v in row))
    return "\n".join(lines) + "\n"
