"""The report page's template: its compiled code kept on disk, read back by a later process
(reports/html.py)."""

from __future__ import annotations

import jinja2
import pytest
from sensorless.reports import html
from sensorless.reports.document import Paragraph, Report, Section, Verdict


def _page() -> str:
    inputs = {"drive_sha256": "0" * 64, "gains_sha256": None}
    section = Section("1. Drive", (Paragraph("a paragraph <with> markup to escape"),))
    return html.render(
        Report("servo400", "defaults", {"inputs": inputs}, Verdict("pass", ()), (section,)), "0"
    )


@pytest.fixture
def fresh_env(monkeypatch):
    """html.py's environment built anew (it is made once per process), undone afterwards."""
    html._env.cache_clear()
    yield monkeypatch
    html._env.cache_clear()


def test_a_later_process_renders_the_same_page_from_the_kept_template_code(tmp_path, fresh_env):
    fresh_env.setenv("SENSORLESS_CACHE", str(tmp_path))
    first = _page()
    kept = list((tmp_path / "jit" / "templates").iterdir())
    assert len(kept) == 1 and kept[0].stat().st_size > 0
    html._env.cache_clear()  # as a new process: the code read back, the template not compiled again

    def no_compile(*_a, **_k):
        raise AssertionError("the template was compiled again")

    fresh_env.setattr(jinja2.Environment, "compile", no_compile)
    assert _page() == first


def test_an_unwritable_cache_leaves_the_page_as_it_is(tmp_path, fresh_env):
    expected = _page()  # the environment of this process, whatever its cache
    html._env.cache_clear()
    blocked = tmp_path / "not-a-directory"
    blocked.write_text("")
    fresh_env.setenv("SENSORLESS_CACHE", str(blocked))  # its jit/templates cannot be made
    assert _page() == expected
