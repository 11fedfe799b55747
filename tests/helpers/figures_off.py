"""Reports without their figures, for the tests that read a report's data only (its verdict, its checks'
metrics): drawing the figures, and the linearizations the flux family's bias figure computes for itself
alone, was most of such a test's CPU (a quick report of hubmotor48 on 4 speeds per direction: ~2.5 s
with its figures, ~0.4 s without, its data the same). The figures themselves are drawn and checked by
the tests that write reports (tests/common/test_report.py, test_outputs.py, the README's commands)."""

from __future__ import annotations

import contextlib
import importlib
import sys
from collections.abc import Iterator

import pytest

# the modules that draw a report's figures (imported here, so that their names are replaced before
# the report imports them)
DRAWING = (
    "sensorless.reports.document",
    "sensorless.reports.svg_render",
    "sensorless.reports.envelope_review",
    "sensorless.reports.time_domain",
    "sensorless.reports.low_speed",
    "sensorless.reports.drive_analysis",
    "sensorless.reports.pmsm_flux_observer.review",
)


def _no_uri(fig: object) -> str:
    if fig is not None:
        sys.modules["sensorless.reports.document"].pyplot().close(fig)
    return ""


@contextlib.contextmanager
def figures_off() -> Iterator[None]:
    """Within the block, a report's figures are empty: every ``svg_uri`` and ``svg_later`` of the
    report modules gives "" (nothing drawn, no child forked), and the figures built from data computed
    for them alone (the poles over the envelope, the flux family's bias and front) are not built."""
    mods = [importlib.import_module(m) for m in DRAWING]
    document, svg_render, envelope_review = mods[:3]
    review = mods[-1]
    uri, later = document.svg_uri, svg_render.svg_later
    with pytest.MonkeyPatch.context() as mp:
        for name, m in list(sys.modules.items()):
            if name.startswith("sensorless.reports"):
                if getattr(m, "svg_uri", None) is uri:
                    mp.setattr(m, "svg_uri", _no_uri)
                if getattr(m, "svg_later", None) is later:
                    mp.setattr(m, "svg_later", lambda fig, texts=(): "")
        mp.setattr(envelope_review, "poles_figure", lambda *a: None)
        mp.setattr(review, "bias_curves", lambda *a: None)
        mp.setattr(review, "front_figure", lambda *a: None)
        yield


@contextlib.contextmanager
def figure_files_off() -> Iterator[None]:
    """Within the block, the figure files a command writes (``OutputSet.add_figure``: analyze's pole
    maps, simulate's traces) are built but not rendered: each is staged under its name as an empty
    file once the figure is checked to have drawn something (axes with artists on them). For the
    tests that read a command's data and check its file list only: rendering a figure to PNG and SVG
    was most of such a command's CPU (analyze piippo2008 --discrete: ~60 %); the rendered bytes are
    checked by the tests that write figures (tests/ipmsm_adaptive/test_cli_analyze.py's preset
    analysis, tests/common/test_outputs.py, the README's commands)."""
    from sensorless.reports.document import pyplot
    from sensorless.reports.files import OutputSet

    def staged(self: OutputSet, name: str, fig: object, **kwargs: float) -> None:
        axes = fig.get_axes()  # type: ignore[attr-defined]
        assert axes and any(ax.has_data() for ax in axes), f"{name}: an empty figure"
        pyplot().close(fig)
        self.add_bytes(name, b"")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(OutputSet, "add_figure", staged)
        yield
