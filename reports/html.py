"""One self-contained HTML page of any family's stability report, rendered from a Jinja2 template.

The page (templates/report.html.j2) is well-formed XHTML-compatible HTML5 with its figures embedded as
SVG data URIs: no network, no external resource, and no date, so the same inputs give the same bytes.

The template's compiled Python code is kept with the compiled libraries (design/compiled.py
``cache_dir``, its ``templates`` folder): compiling it costs a report ~17 ms CPU, reading it back well
under 1 ms. Jinja2 keys its bytecode on the template's name, file and source; :class:`KeptTemplates`
adds Jinja2's version and this environment's options, which the code also depends on.
"""

from __future__ import annotations

import functools
import os

import jinja2
from sensorless.reports.document import Figure, Paragraph, Report, Row, Table

# the environment's options (they shape the compiled code: part of its cache key)
OPTIONS = {
    "autoescape": True,
    "trim_blocks": True,
    "lstrip_blocks": True,
    "keep_trailing_newline": True,
    "undefined": jinja2.StrictUndefined,
}


class KeptTemplates(jinja2.FileSystemBytecodeCache):
    """Jinja2's bytecode cache in ``directory`` (created when first written), keyed also on Jinja2's
    version and :data:`OPTIONS`; where it cannot be read or written, templates are compiled as without
    it."""

    def __init__(self, directory: str) -> None:
        super().__init__(directory)
        self.tag = f"jinja2 {jinja2.__version__} {sorted((k, repr(v)) for k, v in OPTIONS.items())}"

    def get_cache_key(self, name: str, filename: str | None = None) -> str:
        return super().get_cache_key(f"{self.tag}|{name}", filename)

    def load_bytecode(self, bucket: jinja2.bccache.Bucket) -> None:
        try:
            super().load_bytecode(bucket)
        except OSError:  # unreadable (Jinja2 passes over a few errors only): compiled as without a cache
            bucket.reset()

    def dump_bytecode(self, bucket: jinja2.bccache.Bucket) -> None:
        try:
            os.makedirs(self.directory, exist_ok=True)
            super().dump_bytecode(bucket)
        except OSError:  # a read-only or full cache: the next report compiles the template again
            pass


@functools.cache
def _env() -> jinja2.Environment:
    from sensorless.design.compiled import cache_dir

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("sensorless.reports", "templates"),
        bytecode_cache=KeptTemplates(str(cache_dir() / "templates")),
        **OPTIONS,
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
