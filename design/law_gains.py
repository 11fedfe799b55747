"""A family's gains from its drive file or a gain table, built from its laws' declared keys alone.

For a family whose gains are plain numbers named by its laws (``ObserverFamily.laws``: law ->
keys): :func:`section_gains` reads them from a drive-file section (a dataclass or mapping holding the
keys) and :func:`table_gains` from a gain table (design/gain_table.py), checking that the table is for
the drive's kind, that its law is one the family declares and that every key of that law is a finite
number; each error is one line naming the table and the key. A family whose gains are more than finite
numbers (lists of a schedule, ranges, units) gives its own reader of the values (``values``); the
checks of kind and law stay here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from sensorless.design.family import Drive, GainSet, GainTableData, ObserverFamily
from sensorless.design.gain_table import GainTableError


def section_gains(law: str, keys: tuple[str, ...], section: Any, source: str) -> GainSet:
    """The gains ``keys`` of ``law`` from a drive-file ``section`` (attributes or a mapping), SI."""
    get = section.get if isinstance(section, dict) else lambda k: getattr(section, k)
    return GainSet(law, {k: float(get(k)) for k in keys}, source)


# (law, the table's gains, where: the table named for errors) -> the law's SI values; GainTableError
# naming the key where one is not what the law needs
ValuesReader = Callable[[str, Mapping[str, Any], str], dict[str, Any]]


def table_gains(
    family: ObserverFamily,
    drive: Drive,
    table: GainTableData,
    table_file: str = "",
    values: ValuesReader | None = None,
) -> GainSet:
    """The gains of a gain table of one of ``family``'s laws (module docstring)."""
    where = table.where(table_file)
    kind = table.drive.get("kind")
    if kind is not None and kind != drive.kind:
        raise GainTableError(f"{where}: key 'drive.kind': {kind!r} does not match the drive ({drive.kind})")
    keys = family.laws.get(table.law)
    if keys is None:
        raise GainTableError(
            f"{where}: key 'law': {table.law!r} gains are not for {family.title} drives "
            f"(kind '{family.kind}'); its laws: {', '.join(family.laws)}"
        )
    tuned_for = table.drive.get("name")
    source = f"{table.law} table {where} (tuned for {tuned_for})"
    if values is not None:
        return GainSet(table.law, values(table.law, table.gains, where), source)
    out = {}
    for k in keys:
        try:
            out[k] = float(table.gains[k])
        except (KeyError, TypeError, ValueError) as e:
            raise GainTableError(f"{where}: key 'gains.{k}': {e}") from None
        if not math.isfinite(out[k]):
            raise GainTableError(f"{where}: key 'gains.{k}': need a finite number")
    return GainSet(table.law, out, source)
