"""Report figures rendered to SVG in forked child processes while the report computes on (Linux).

matplotlib takes longer to lay out and draw a report's figures than the report takes for its numbers,
and all of it runs in Python on one core. :func:`svg_later` forks: the child, a copy of this process
with the figure (or the function and data that make it) in it, builds and renders the data URI of
:func:`~sensorless.reports.document.svg_uri` into a pipe and exits; the parent goes on computing, and
``str()`` of the returned object (what the HTML template does with a figure's ``uri``) waits for the
bytes. They are the bytes the parent would have rendered: the same figure in the same matplotlib
state (SVG ids are hashes of the content).

At most one child per CPU (of those this process may run on) runs at a time. The child only renders
(numpy and matplotlib, no CasADi, no threads of its own), leaves by ``os._exit`` (no atexit handlers,
no second flush of inherited buffers), writes nothing but its pipe and dies at once on Ctrl-C or
SIGTERM (the parent reports it). A child whose figure is no longer wanted (the report was abandoned
or interrupted) is killed and reaped. Without fork (not Linux), with SENSORLESS_NO_FORK=1, or if a
child fails, the figure is rendered here.
"""

from __future__ import annotations

import functools
import gc
import os
import select
import signal
import sys
import time
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from sensorless.reports.document import pyplot, svg_uri

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure

PREFIX = b"data:image/svg+xml;base64,"
_running: list[weakref.ref[PendingSvg]] = []  # children not yet collected, oldest first
TIMEOUT_S = 120.0  # far above any figure's ~1 s; past it the child is killed and the figure drawn here


def forking() -> bool:
    """Whether figures are rendered in child processes here."""
    return sys.platform == "linux" and hasattr(os, "fork") and not os.environ.get("SENSORLESS_NO_FORK")


class PendingSvg:
    """The SVG data URI of a figure that a child process renders; ``str()`` waits for it."""

    def __init__(self, fig: Figure | Callable[[], Figure]) -> None:
        self._fig: Figure | Callable[[], Figure] | None = fig  # kept to render it here if the child fails
        self._value: str | None = None
        self._child: tuple[int, int] | None = None  # (pid, read end of its pipe)
        self._finalizer: weakref.finalize | None = None

    def result(self) -> str:
        """The data URI (waits for the child)."""
        if self._value is None:
            data = b""
            if self._child is not None:
                pid, fd = self._child
                self._child = None
                if self._finalizer is not None:
                    self._finalizer.detach()
                data = _collect(pid, fd)
            self._value = data.decode("ascii") if data.startswith(PREFIX) else svg_uri(_made(self._fig))
            self._fig = None
        return self._value

    def __str__(self) -> str:
        return self.result()


def _collect(pid: int, fd: int) -> bytes:
    """Everything the child wrote, once it has exited; b"" if it failed or outlived TIMEOUT_S (a
    child forked from a process with threads could, in principle, wait on a lock that no thread of
    its own will release: then the figure is rendered here instead of the report hanging)."""
    chunks, whole = [], False
    deadline = time.monotonic() + TIMEOUT_S
    try:
        while (left := deadline - time.monotonic()) > 0 and select.select([fd], [], [], left)[0]:
            if not (chunk := os.read(fd, 1 << 20)):
                whole = True
                break
            chunks.append(chunk)
    finally:
        if not whole:  # interrupted or too slow: the child's work is not wanted
            _kill(pid)
        os.close(fd)
        _, status = os.waitpid(pid, 0)
    return b"".join(chunks) if whole and os.waitstatus_to_exitcode(status) == 0 else b""


def _kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:  # already gone
        pass


def _reap(owner: int, pid: int, fd: int) -> None:
    """Kill and reap a child whose result is no longer wanted (only in the process that forked it)."""
    if os.getpid() != owner:
        return
    _kill(pid)
    for step in (lambda: os.close(fd), lambda: os.waitpid(pid, 0)):
        try:
            step()
        except OSError:
            pass


def _child(fig: Figure | Callable[[], Figure], read_end: int, write_end: int, siblings: list[int]) -> None:
    """Render into the pipe and leave; never returns. ``siblings``: the read ends of the other
    children's pipes, closed here so that only the parent holds them (a child whose parent is gone
    then gets a broken pipe instead of waiting for a reader)."""
    code = 1
    try:
        # a short life: no garbage collection, whose passes over the whole inherited heap would copy
        # every page of it (copy-on-write) for nothing
        gc.disable()
        for fd in (read_end, *siblings):
            os.close(fd)
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_DFL)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        view = memoryview(svg_uri(_made(fig)).encode("ascii"))
        while view:
            view = view[os.write(write_end, view) :]
        code = 0
    finally:
        os._exit(code)


def _made(fig: Figure | Callable[[], Figure]) -> Figure:
    return fig() if callable(fig) else fig


@functools.cache
def _shared_before_fork() -> None:
    """Import and build here, once, what every child would otherwise import or build for itself, and
    the children inherit: pyplot with the report's settings (document.py ``pyplot``), the SVG backend
    (svg_backend.py) and the flat ticks (figure_ticks.py) every figure is saved with, the image
    plugins PIL imports to write the first rasterized image (a pole map's), and matplotlib's mathtext
    grammar (a class attribute, ~0.1 s CPU; the trace figures' labels are mathtext)."""
    pyplot()
    from matplotlib import mathtext
    from PIL import Image
    from sensorless.reports import figure_ticks, svg_backend  # noqa: F401  (every figure is saved with them)

    Image.preinit()
    mathtext.MathTextParser("path").parse("$x$")


def svg_later(fig: Figure | Callable[[], Figure], texts: Sequence[str] = ()) -> PendingSvg | str:
    """The figure's SVG data URI as :func:`svg_uri` gives it, rendered by a child process (module
    docstring); ``str()`` of the result is the URI. ``fig`` is a matplotlib figure (closed here) or a
    function without arguments that makes one: the child calls it, so building the figure leaves
    this process too (bind its arguments now, e.g. with functools.partial: it may also be called
    later, here, if the child fails). ``texts``: strings the figure draws that several figures share
    (its mathtext labels), parsed here before the fork (svg_backend.py ``warm``): once a report, not
    once a child."""
    if not forking():
        pyplot()  # the report's settings before the figure is made
        return svg_uri(_made(fig))
    _shared_before_fork()
    if texts:
        from sensorless.reports.svg_backend import warm

        warm(texts)
    limit = len(os.sched_getaffinity(0)) or 1  # the CPUs this process may use
    while True:  # at most ``limit`` children at a time: wait for the oldest
        live = [p for p in (r() for r in _running) if p is not None and p._child is not None]
        _running[:] = [weakref.ref(p) for p in live]
        if len(live) < limit:
            break
        live[0].result()
    pending = PendingSvg(fig)
    try:
        read_end, write_end = os.pipe()
    except OSError:
        return svg_uri(_made(fig))
    try:
        pid = os.fork()
    except OSError:
        os.close(read_end)
        os.close(write_end)
        return svg_uri(_made(fig))
    if pid == 0:
        _child(fig, read_end, write_end, [q._child[1] for q in live if q._child is not None])
    os.close(write_end)
    pending._child = (pid, read_end)
    pending._finalizer = weakref.finalize(pending, _reap, os.getpid(), pid, read_end)
    _running.append(weakref.ref(pending))
    if not callable(fig):
        pyplot().close(fig)  # pyplot forgets it; it can still be rendered here if the child fails
    return pending
