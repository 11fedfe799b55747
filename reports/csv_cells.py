"""CSV cells of computed numbers: a finite number, or an empty cell whose row says why it has none.

Every number a command writes is finite (docs/conventions.md): where a computation gives no value at a
point (no equilibrium found, a linearized observer that overflows), the cell is empty and the row's
last column, :data:`REASON`, says why; a row with every value has that column empty. Readers get no
``nan`` or ``inf`` to parse (spreadsheets and ``csv`` read an empty cell as missing).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import SupportsFloat

REASON = "no_value_reason"


def finite(v: SupportsFloat | str | None) -> bool:
    """Whether ``v`` is a finite number (None is not)."""
    try:
        return v is not None and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def cell(v: SupportsFloat | None, spec: str = ".10g") -> str:
    """``v`` formatted with ``spec``, or an empty cell where it is not a finite number."""
    return format(float(v), spec) if v is not None and finite(v) else ""


def row(values: Iterable[SupportsFloat | None], why: str, spec: str = ".10g") -> str:
    """A CSV line of ``values`` (each :func:`cell`) ending with the reason column: ``why`` where a value
    is missing, else empty. ``why`` must hold no comma or quote (one cell)."""
    assert "," not in why and '"' not in why, why
    # a float (most cells: a gain table's CSV writes 63 600) formatted without cell()'s conversion
    cells = [format(v, spec) if type(v) is float and math.isfinite(v) else cell(v, spec) for v in values]
    cells.append(why if "" in cells else "")  # (a number's text is never empty)
    return ",".join(cells)
