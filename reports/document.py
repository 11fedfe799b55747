"""A stability report as data: sections of paragraphs, tables and figures, a verdict, and its JSON numbers.

Each family computes its report (its report hooks, reports/family.py) into a :class:`Report`: the
numbers (``data``, written as report.json: every number the HTML shows, no date, so reruns give
identical bytes) and the sections to show, made of :class:`Paragraph`, :class:`Table` and
:class:`Figure` blocks. The shared renderer (reports/html.py) turns any family's report into one
self-contained HTML page. The helpers below are what every family's report uses: JSON-safe numbers,
figures as data URIs, the drive-data tables.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol, SupportsFloat

import numpy as np
from sensorless.design.envelope import Envelope
from sensorless.design.family import Drive, PerUnitBases
from sensorless.design.gain_table import GainTable
from sensorless.reports.figure_layout import pin_ticks

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure as MplFigure


# --------------------------------------------------------------------------------------------------
# Blocks and sections
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Paragraph:
    """A paragraph; ``cls`` "ok" or "bad" colours it."""

    text: str
    cls: str = ""


@dataclass(frozen=True)
class Table:
    """A table of already formatted cells; ``numeric`` marks right-aligned columns (by index)."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""
    numeric: frozenset[int] = frozenset()
    code: frozenset[int] = frozenset()  # columns shown as code (names of keys)


class PendingUri(Protocol):
    """A figure's data URI still being rendered (reports/svg_render.py ``PendingSvg``): ``str()`` waits
    for it. A protocol here, so that this module needs nothing of the renderer, which needs it."""

    def __str__(self) -> str: ...


@dataclass(frozen=True)
class Figure:
    """A figure as a data URI (SVG) with its caption; ``uri`` may be an object whose ``str()`` is the
    URI, still being rendered (reports/svg_render.py)."""

    uri: str | PendingUri
    caption: str


@dataclass(frozen=True)
class Row:
    """Blocks side by side (e.g. small tables)."""

    blocks: tuple[Block, ...]


Block = Paragraph | Table | Figure | Row  # what a section holds (reports/html.py draws each)


@dataclass(frozen=True)
class Section:
    """A numbered section of the report."""

    title: str
    blocks: tuple[Block, ...]


@dataclass(frozen=True)
class Verdict:
    """The verdict box: ``status`` "pass", "warn" or "fail", and its lines (Paragraphs, lists)."""

    status: str
    lines: tuple[Paragraph, ...]
    findings: tuple[str, ...] = ()  # bullet points: what failed and where


@dataclass(frozen=True)
class Report:
    """A whole report: its numbers (JSON) and what the HTML shows."""

    drive: str
    review: str  # the gains under review
    data: dict[str, Any]
    verdict: Verdict
    sections: tuple[Section, ...] = field(default_factory=tuple)


# --------------------------------------------------------------------------------------------------
# Numbers and figures
# --------------------------------------------------------------------------------------------------
def f(x: SupportsFloat) -> float | None:
    """JSON-safe float (None for NaN/inf), rounded to 12 significant digits for stable text."""
    v = float(x)
    return float(f"{v:.12g}") if np.isfinite(v) else None


def arr(a: np.ndarray) -> list:
    """JSON-safe nested list of a 1-D or 2-D array."""
    return [[f(v) for v in row] for row in np.atleast_2d(a)] if np.ndim(a) == 2 else [f(v) for v in a]


def num(v: float | None, digits: int = 4) -> str:
    """A number for a table cell ('–' for none)."""
    return "–" if v is None else f"{v:.{digits}g}"


# The report figures' matplotlib settings: deterministic SVG element ids; titles at the top of their
# axes plus the title pad, where matplotlib's default search for decorations above the axes puts them
# anyway (no report axes has ticks, labels or an offset text up there), since that search measures the
# whole y axis of every titled axes at each layout pass and at the draw: up to a quarter of a figure's CPU.
STYLE = {"svg.hashsalt": "sensorless", "axes.titley": 1.0}


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend with the report figures' settings (STYLE), imported on
    first use: half a second that only the commands drawing figures pay."""
    import sys

    import matplotlib

    matplotlib.use("Agg")
    if "matplotlib.pyplot" not in sys.modules:
        _import_pyplot()
    import matplotlib.pyplot as plt

    plt.rcParams.update(STYLE)
    return plt


def _import_pyplot() -> None:
    """Import pyplot without the property tables matplotlib writes, as it defines each Artist class,
    into the docstring of its ``set`` (and of the functions whose docstrings quote them): a sixth of the
    import's CPU (~0.13 s a process) for help() text that no command shows. A process that imported
    pyplot before has them (nothing is changed then); the docstrings say where the tables are."""
    from matplotlib import artist

    kwdoc = getattr(artist, "kwdoc", None)
    if kwdoc is None:  # a matplotlib without the hook: import it as it comes
        import matplotlib.pyplot

        return
    artist.kwdoc = lambda _cls: "Properties: see the matplotlib documentation of this Artist class."
    try:
        import matplotlib.pyplot  # noqa: F401
    finally:
        artist.kwdoc = kwdoc


def svg_uri(fig: MplFigure) -> str:
    """A matplotlib figure as an SVG data URI (closed afterwards; no date inside)."""
    plt = pyplot()  # STYLE set here, where the SVG is written: its element ids hash with svg.hashsalt
    from sensorless.reports.figure_ticks import flatten_ticks  # matplotlib's Artist: imported after pyplot
    from sensorless.reports.svg_backend import BACKEND, supported

    buf = io.BytesIO()
    engine = fig.get_layout_engine()
    if engine is not None:
        # savefig with a layout engine draws the figure twice, once only to lay it out; laying it out
        # here and keeping the positions saves that draw
        engine.execute(fig)
        fig.set_layout_engine(None)
    pin_ticks(fig)  # the same ticks from fewer artists
    if supported():  # a matplotlib these were checked on (svg_backend.py TESTED)
        flatten_ticks(fig)  # and those drawn as a few artists per axis
        # matplotlib's SVG, drawn with each string measured and shaped once (svg_backend.py)
        fig.savefig(buf, format="svg", metadata={"Date": None}, backend=BACKEND)
    else:
        fig.savefig(buf, format="svg", metadata={"Date": None})
    plt.close(fig)
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def report_json(data: dict[str, Any], version: str) -> str:
    """Deterministic JSON text of the report data."""
    doc = {"format": "sensorless-report/1", "toolbox": {"name": "sensorless", "version": version}, **data}
    return json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n"


def report_inputs(drive: Drive, table: GainTable | None, min_damping: float) -> dict[str, Any]:
    """What a report describes: the drive, the hashes of its inputs, the required damping."""
    return {
        "drive": drive.name,
        "drive_sha256": drive.digest,
        "gains_sha256": table_digest(table),
        "min_damping": min_damping,
    }


def table_digest(table: GainTable | None) -> str | None:
    """sha256 of a gain table: of the file it was read from (as ``sha256sum`` gives it, like the drive
    file's; for a table tune wrote, its canonical JSON), else of its canonical JSON; None for none."""
    if table is None:
        return None
    return table.file_sha256 or hashlib.sha256(table.to_json().encode()).hexdigest()


# --------------------------------------------------------------------------------------------------
# Drive data
# --------------------------------------------------------------------------------------------------
def _unit_of(doc: str) -> str:
    """The unit in square brackets of a field's doc text ("stator resistance [ohm]" -> "ohm")."""
    m = re.search(r"\[([^\]]+)\]", doc)
    return m.group(1) if m else ""


def _rows(obj: Any, pu: dict[str, float]) -> list[dict[str, Any]]:
    rows = []
    for fd in dataclasses.fields(obj):
        v = getattr(obj, fd.name)
        doc = fd.metadata.get("doc", "")
        dim = fd.metadata.get("dim")
        if isinstance(v, tuple | list):
            if not all(isinstance(x, int | float) for x in v):
                continue
            rows.append(
                {
                    "name": fd.name,
                    "value": None,
                    "unit": _unit_of(doc),
                    "what": doc,
                    "pu": None,
                    "values": [f(x) for x in v],
                }
            )
            continue
        if isinstance(v, bool) or not isinstance(v, int | float):
            if isinstance(v, str):
                rows.append({"name": fd.name, "value": None, "unit": "", "what": f"{doc} = {v}", "pu": None})
            continue
        rows.append(
            {
                "name": fd.name,
                "value": f(v),
                "unit": _unit_of(doc),
                "what": doc,
                "pu": f(v / pu[dim]) if dim in pu else None,
            }
        )
    return rows


def drive_tables(
    drive: Drive, skip: Sequence[str] = (), bases: PerUnitBases | None = None
) -> dict[str, list[dict[str, Any]]]:
    """Drive and observer data as rows (name, value, unit, per-unit in ``bases``, its family's).

    Every dataclass section of the drive but those named in ``skip`` (its family's settings of other
    commands: ``ReportHooks.settings_sections``); gain tables nested in a section (a mapping of
    dataclasses) become rows named ``<gain>.<key>``.
    """
    pu = dict(bases.values) if bases is not None else {}
    tables: dict[str, list[dict[str, Any]]] = {}
    assert dataclasses.is_dataclass(drive), drive  # every family's drive is a frozen dataclass
    for sf in dataclasses.fields(drive):
        obj = getattr(drive, sf.name)
        if isinstance(obj, Envelope) and obj.given is not None:
            obj = obj.given  # the envelope as its file gives it (the file's units)
        if not dataclasses.is_dataclass(obj) or sf.name in skip:
            continue
        rows = _rows(obj, pu)
        for fd in dataclasses.fields(obj):
            v = getattr(obj, fd.name)
            if isinstance(v, dict):  # nested gain sections, e.g. [observer.gains.*]
                for gname, g in v.items():
                    for gf in dataclasses.fields(g):
                        doc = gf.metadata.get("doc", "")
                        rows.append(
                            {
                                "name": f"{gname}.{gf.name}",
                                "value": f(getattr(g, gf.name)),
                                "unit": _unit_of(doc),
                                "what": f"gain law '{gname}': {doc}",
                                "pu": None,
                            }
                        )
        tables[sf.name] = rows
    return tables


def drive_section(number: int, data: dict[str, Any], bases: PerUnitBases | None = None) -> Section:
    """The section "Drive and observer data" from ``drive_tables`` data, with the drive's per-unit
    ``bases`` (its family's ``bases``) said."""
    tables = []
    for name, rows in data.items():
        cells = tuple(
            (
                r["name"],
                ", ".join(num(v, 6) for v in r["values"]) if "values" in r else num(r["value"], 6),
                r["unit"],
                num(r["pu"], 4),
                r["what"],
            )
            for r in rows
        )
        tables.append(
            Table(
                ("name", "value", "unit", "p.u.", "meaning"),
                cells,
                f"[{name}]",
                frozenset({1, 3}),
                frozenset({0}),
            )
        )
    note = "SI units; speeds are electrical rad/s unless marked r/min (mechanical). " + (
        bases.note if bases is not None else "This drive description defines no per-unit bases."
    )
    return Section(f"{number}. Drive and observer data", (Row(tuple(tables)), Paragraph(note, "meta")))
