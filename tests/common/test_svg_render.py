"""Figures rendered in forked children (reports/svg_render.py): the same bytes as rendered here, a failed
child falls back to rendering here, an abandoned child is killed and reaped, and the switch works."""

from __future__ import annotations

import functools
import gc
import os
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from sensorless.reports import svg_render
from sensorless.reports.document import svg_uri

pytestmark = pytest.mark.skipif(not svg_render.forking(), reason="figures are rendered in-process here")


@pytest.fixture(autouse=True)
def _deterministic_ids():
    with matplotlib.rc_context({"svg.hashsalt": "sensorless"}):  # as the report modules set it
        yield


def figure(k: int = 0):
    fig, axes = plt.subplots(1, 2, figsize=(6, 3), layout="constrained")
    x = np.linspace(0, 1, 50)
    for ax in axes:
        sc = ax.scatter(x, np.sin(6 * x + k), c=x, s=4, rasterized=True)
        ax.set_title(f"panel {k}")
    fig.colorbar(sc, ax=axes)
    return fig


def test_a_child_renders_the_bytes_rendered_here():
    here = svg_uri(figure(1))
    pending = [svg_render.svg_later(figure(1)) for _ in range(3)]  # more than one child per CPU too
    assert all(isinstance(p, svg_render.PendingSvg) for p in pending)
    assert [str(p) for p in pending] == [here] * 3
    assert here.startswith("data:image/svg+xml;base64,")


def test_a_figure_made_by_the_child_is_the_figure_made_here():
    assert str(svg_render.svg_later(functools.partial(figure, 5))) == svg_uri(figure(5))


def test_a_failed_child_is_rendered_here_instead():
    fig = figure(2)
    expected = svg_uri(figure(2))
    pid = os.fork()
    if pid == 0:
        os._exit(3)  # a child that writes nothing and fails
    read_end, write_end = os.pipe()
    os.close(write_end)
    p = svg_render.PendingSvg(fig)
    svg_render.Batch(pid, read_end, [p])
    assert str(p) == expected


def test_an_abandoned_child_is_killed_and_reaped():
    p = svg_render.svg_later(figure(3))
    pid = p._batch.pid
    del p
    gc.collect()
    with pytest.raises(ChildProcessError):  # already reaped: no zombie left behind
        os.waitpid(pid, os.WNOHANG)


def test_no_fork_renders_here(monkeypatch):
    monkeypatch.setenv("SENSORLESS_NO_FORK", "1")
    out = svg_render.svg_later(figure(4))
    assert isinstance(out, str) and out == svg_uri(figure(4))


def _silent_child() -> tuple[int, int]:
    """A forked child that holds its pipe's write end open and never writes: (its pid, the read end)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:
        try:
            os.close(read_end)
            time.sleep(3600)
        finally:
            os._exit(0)
    os.close(write_end)
    return pid, read_end


def test_a_hung_child_is_killed_and_rendered_here(monkeypatch):
    monkeypatch.setattr(svg_render, "TIMEOUT_S", 0.1)  # the wait this test sits through (idle)
    fig = figure(6)
    expected = svg_uri(figure(6))
    pid, read_end = _silent_child()  # holds its pipe open and never writes (a deadlock after fork)
    p = svg_render.PendingSvg(fig)
    svg_render.Batch(pid, read_end, [p]).flags[0] = 1  # it has started the figure: waited for
    assert str(p) == expected
    with pytest.raises(ChildProcessError):  # killed and reaped
        os.waitpid(pid, os.WNOHANG)


def small(k: int):
    """A figure cheaper to draw than :func:`figure` (one line, no layout engine)."""
    fig, ax = plt.subplots(figsize=(2, 1.5))
    ax.plot([0, 1], [0, k])
    return fig


def _made_in(parent: int, k: int):
    """small(k), or an error in any process but ``parent`` (a figure that fails in its child)."""
    if os.getpid() != parent:
        raise RuntimeError("fails in the child")
    return small(k)


def test_one_child_renders_several_figures_each_as_rendered_here(monkeypatch):
    monkeypatch.setattr(svg_render, "children", lambda: 8)  # a free child whatever else runs
    jobs = [
        svg_render.PendingSvg(functools.partial(small, 7)),
        svg_render.PendingSvg(functools.partial(_made_in, os.getpid(), 8)),  # fails there: drawn here
        svg_render.PendingSvg(functools.partial(small, 9)),
    ]
    svg_render._start(jobs)
    assert len({id(p._batch) for p in jobs}) == 1 and jobs[0]._batch is not None  # one child, all three
    assert [str(p) for p in jobs] == [svg_uri(small(k)) for k in (7, 8, 9)]


def test_figures_no_child_takes_are_drawn_here_when_asked(monkeypatch):
    monkeypatch.setattr(svg_render, "children", lambda: 0)  # every child busy: the figures wait
    pending = [svg_render.svg_later(functools.partial(small, k)) for k in (10, 11)]
    assert all(isinstance(p, svg_render.PendingSvg) and p._batch is None for p in pending)
    assert [str(p) for p in pending] == [svg_uri(small(k)) for k in (10, 11)]


def test_figures_a_child_has_not_started_are_drawn_here_last_first():
    pid, read_end = _silent_child()  # has started nothing yet
    jobs = [svg_render.PendingSvg(functools.partial(small, k)) for k in (12, 13)]
    batch = svg_render.Batch(pid, read_end, jobs)
    assert str(jobs[0]) == svg_uri(small(12))  # both drawn here: the last claimed first
    assert jobs[1]._value == svg_uri(small(13)) and batch.flags[:] == bytes([0, 0, 1, 1])  # the child skips
    del batch, jobs
    gc.collect()
    with pytest.raises(ChildProcessError):  # the child, no longer wanted, is killed and reaped
        os.waitpid(pid, os.WNOHANG)


def test_after_a_fork_the_parent_reads_its_fonts_at_offsets_of_its_own():
    """A forked child and its parent share each inherited file's offset, and FreeType reads a font by a
    seek and a read: a parent drawing text while a child drew got "failed to load glyph". After
    ``own_font_files`` in the parent, the child's seek in an inherited font file leaves the parent's
    offset where it was before the fork (without it, it moves: the test can fail), and the parent's font
    still draws."""
    from matplotlib import font_manager
    from matplotlib.ft2font import FT2Font

    path = font_manager.findfont("DejaVu Sans")
    fd = os.open(path, os.O_RDONLY)
    try:
        for fix in (False, True):
            font = FT2Font(path)  # a font of this test's own, opened before the fork, fresh each time
            os.lseek(fd, 0, os.SEEK_SET)
            files = svg_render.font_files()
            assert files[fd] == (path, 0)
            pid = os.fork()
            if pid == 0:
                try:
                    os.lseek(fd, 12345, os.SEEK_SET)
                finally:
                    os._exit(0)
            if fix:
                svg_render.own_font_files(files)
            _, status = os.waitpid(pid, 0)
            assert os.waitstatus_to_exitcode(status) == 0
            assert (os.lseek(fd, 0, os.SEEK_CUR) == 0) == fix, fix
            font.set_text("0.475")  # reads through its own file
    finally:
        os.close(fd)
