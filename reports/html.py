"""One self-contained HTML page of any family's stability report, rendered from a Jinja2 template.

The page (templates/report.html.j2) is well-formed XHTML-compatible HTML5 with its figures embedded as
SVG data URIs: no network, no external resource, and no date, so the same inputs give the same bytes.
"""

from __future__ import annotations

import functools

import jinja2
from sensorless.reports.document import Figure, Paragraph, Report, Row, Table


@functools.cache
def _env() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("sensorless.reports", "templates"),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        undefined=jinja2.StrictUndefined,
    )
    env.tests["paragraph"] = lambda b: isinstance(b, Paragraph)
    env.tests["table"] = lambda b: isinstance(b, Table)
    env.tests["figure"] = lambda b: isinstance(b, Figure)
    env.tests["row"] = lambda b: isinstance(b, Row)
    return env


def render(report: Report, version: str) -> str:
    """The report page."""
    inp = report.data["inputs"]
    return (
        _env()
        .get_template("report.html.j2")
        .render(
            report=report,
            version=version,
            drive_sha=inp["drive_sha256"][:16],
            gains_sha=(inp["gains_sha256"] or "")[:16],
        )
    )
