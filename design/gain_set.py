"""The gains an observer runs with (:class:`GainSet`): which gain law, the values, and their source.

Its own module so that design/runtime.py, which runs a family's gains, need not import the family
contract (design/family.py, which re-exports it and types :meth:`ObserverFamily.runtime` as the
``RuntimeSetup`` of design/runtime.py): the import graph has no cycle.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from sensorless.design.memo import LABEL


@dataclass(frozen=True)
class GainSet:
    """The gains an observer runs with: which gain law, the values (SI), and where they come from."""

    law: str  # gain law: e.g. "speed-dependent", "schedule", "constant", "zero"
    values: Mapping[str, Any] = field(default_factory=dict)  # SI; lists for tables
    # for headers and messages: the drive file's section or the table file, as the caller named it (a
    # label, not content: analyses memoized on the gains do not key on it, design/memo.py)
    source: str = field(default="", metadata=LABEL)
