"""Gain tables: tuned observer gains as data (JSON), shared by tuning, simulation, C generation and reports.

Format ``sensorless-gain-table/1`` (see docs/gain_tables.md)::

    {"format": "sensorless-gain-table/1",
     "drive": {"name": ..., "kind": ..., "sha256": ...},
     "family": "law16" | "schedule" | "deangelo" | ...,  # a gain family of an observer family
     "gains": {...},          # family-specific, SI units: the keys its observer family declares
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

from sensorless.design.registry import families

FORMAT = "sensorless-gain-table/1"


def gain_keys() -> dict[str, tuple[str, ...]]:
    """Gain family -> required keys of "gains", over every registered observer family."""
    return {g: keys for f in families() for g, keys in f.gain_families.items()}


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
        return json.dumps(clean(doc), indent=1, sort_keys=True, allow_nan=False) + "\n"


def clean(x: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to lists, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean(v) for v in x]
    if hasattr(x, "tolist"):
        return clean(x.tolist())
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
    known = gain_keys()
    if fam not in known:
        raise GainTableError(f"{p}: key 'family': unknown family {fam!r} (known: {', '.join(known)})")
    gains = doc.get("gains")
    if not isinstance(gains, dict):
        raise GainTableError(f"{p}: key 'gains': missing or not an object")
    for k in known[fam]:
        if k not in gains:
            raise GainTableError(f"{p}: key 'gains.{k}': missing for family {fam}")
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
