"""Report figures rendered to SVG in forked child processes while the report computes on (Linux).

matplotlib takes longer to lay out and draw a report's figures than the report takes for its numbers,
and all of it runs in Python on one core. :func:`svg_later` queues the figure (or the function and data
that make it) and returns at once; a forked child, a copy of this process with the queued figures in
it, builds and renders the data URI of :func:`~sensorless.reports.document.svg_uri` of each into a pipe
and exits; the parent goes on computing, and ``str()`` of the returned object (what the HTML template
does with a figure's ``uri``) waits for the bytes. They are the bytes the parent would have rendered:
the same figure in the same matplotlib state (SVG ids are hashes of the content).

At most one child per CPU but one (the parent's: :func:`children`) runs at a time, and a child takes
every figure queued when it starts: figures that arrive while the children are busy wait, and the next child
renders them together. A child costs more than the figure it draws alone (each copies, page by page,
the part of the parent's memory it touches, and fills the font and text caches again): one child per
figure spent ~20 % more CPU on the README servo's twelve figures than a few children each drawing
several. The parent never waits for a child while it computes; once it waits for a figure (it has
nothing else to do), it draws the queued figures no child has taken itself, in the order asked, then
the last figures of a child's share that the child has not started (the two balance the end).

The child only renders (numpy and matplotlib, no CasADi, no threads of its own), leaves by ``os._exit``
(no atexit handlers, no second flush of inherited buffers), writes nothing but its pipe and dies at once
on Ctrl-C or SIGTERM (the parent reports it). A child whose figures are no longer wanted (the report
was abandoned or interrupted) is killed and reaped. Without fork (not Linux), with SENSORLESS_NO_FORK=1,
or if a child fails, the figure is rendered here.
"""

from __future__ import annotations

import functools
import gc
import mmap
import os
import select
import signal
import struct
import time
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from sensorless.design.forked import forking, kill, reap, write_all
from sensorless.reports.document import pyplot, svg_uri

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure

PREFIX = b"data:image/svg+xml;base64,"
FRAME = struct.Struct(">Q")  # each figure's length before its bytes in a child's pipe (0: it failed)
_queue: list[weakref.ref[PendingSvg]] = []  # figures no child has taken yet, oldest first
_running: list[weakref.ref[Batch]] = []  # children not yet collected, oldest first
FONT_FILES = (".ttf", ".otf", ".ttc", ".pfb", ".pfa", ".afm")  # what FreeType reads fonts from
TIMEOUT_S = 120.0  # far above any figure's ~1 s; past it the child is killed and the figure drawn here


class PendingSvg:
    """The SVG data URI of a figure that a child process renders; ``str()`` waits for it."""

    def __init__(self, fig: Figure | Callable[[], Figure]) -> None:
        self._fig: Figure | Callable[[], Figure] | None = fig  # kept to render it here if the child fails
        self._value: str | None = None
        self._batch: Batch | None = None  # the child rendering it (None: queued, or done)

    def result(self) -> str:
        """The data URI (waits for the child, drawing queued figures here meanwhile)."""
        while self._value is None:
            batch = self._batch
            if batch is None:  # no child took it: nothing else to do here but draw it
                _unqueue(self)
                _start(_queued())  # the others queued, to the children free to take them
                self._render_here()
            elif batch.finished():
                batch.collect()
            else:  # while it renders: a free child takes the later half of the queue, this process
                # draws the oldest queued figure, else the last one a child has not started (or waits)
                jobs = _queued()
                _start(jobs[len(jobs) // 2 :] if len(jobs) > 1 else [])
                if not _steal():
                    mine = next((q for b in [batch, *_live()] if (q := b.claim()) is not None), None)
                    if mine is None:
                        batch.collect()
                    else:
                        mine._render_here()
        self._fig = None
        return self._value

    def _render_here(self) -> None:
        # without garbage collection meanwhile, as in a child: a figure makes thousands of objects, and
        # the passes they set off would go over this process's whole heap (its analyses' too)
        enabled = gc.isenabled()
        gc.disable()
        try:
            self._value = svg_uri(_made(self._fig))
        finally:
            if enabled:
                gc.enable()
        self._batch = None

    def _given(self, data: bytes) -> None:
        """Its bytes as a child wrote them (b"": the child failed; rendered here when asked)."""
        self._batch = None
        if data.startswith(PREFIX):
            self._value = data.decode("ascii")

    def __str__(self) -> str:
        return self.result()


class Batch:
    """A child process rendering ``jobs`` in order; it writes them all once done (FRAME, bytes).

    ``flags``: memory the child shares with this process (created before the fork; a private one if
    not given), one byte per figure that the child sets when it starts drawing it, then one per figure
    that this process sets when it draws the figure itself (:meth:`claim`): the child skips it."""

    def __init__(self, pid: int, fd: int, jobs: Sequence[PendingSvg], flags: mmap.mmap | None = None) -> None:
        self.pid, self.fd = pid, fd
        self.jobs = [weakref.ref(p) for p in jobs]  # a figure nobody waits for any more is not kept
        self.flags = flags if flags is not None else mmap.mmap(-1, 2 * len(jobs) or 1)
        for p in jobs:
            p._batch = self
        self._finalizer = weakref.finalize(self, reap, os.getpid(), pid, fd)

    def claim(self) -> PendingSvg | None:
        """The last figure the child has not started, now this process's to draw (None: it has started
        them all). The child draws in order: a figure started means all before it are. Both may draw
        one figure if the child starts it just as it is claimed: the same bytes, the child's unused."""
        n = len(self.jobs)
        for i in reversed(range(n)):
            if self.fd < 0 or self.flags[i]:
                return None
            p = self.jobs[i]()
            if p is not None and p._value is None and p._batch is self and not self.flags[n + i]:
                self.flags[n + i] = 1
                return p
        return None

    def finished(self) -> bool:
        """Whether the child has written (it writes once every figure is drawn), or has exited."""
        return self.fd < 0 or bool(select.select([self.fd], [], [], 0)[0])

    def collect(self) -> None:
        """Wait for the child; each of its figures gets its bytes (or b"": rendered here when asked,
        as after a wait that was interrupted)."""
        fd, self.fd = self.fd, -1
        self._finalizer.detach()
        data = _collect(self.pid, fd) if fd >= 0 else b""
        parts, at = [], 0
        for _ in self.jobs:
            if at + FRAME.size > len(data):
                break
            (n,) = FRAME.unpack_from(data, at)
            parts.append(data[at + FRAME.size : at + FRAME.size + n])
            at += FRAME.size + n
        parts += [b""] * (len(self.jobs) - len(parts))  # a child that failed: all rendered here
        for ref, part in zip(self.jobs, parts, strict=True):
            if (p := ref()) is not None and p._batch is self:
                p._given(part)


def children() -> int:
    """How many children may render at once: one per CPU this process may use but the one it computes
    (or, its computing done, draws queued figures) on; one on a single CPU."""
    return max(1, len(os.sched_getaffinity(0)) - 1)


def poll() -> None:
    """Collect the children that are done and give the queued figures to a child now free: a report
    calls it at each of its progress lines (reports/envelope_review.py), so that a figure queued behind
    a busy child waits for the next progress line, not for the next figure."""
    if _queue:
        _start(_queued())


def polling(progress: Callable[[str], None]) -> Callable[[str], None]:
    """``progress`` that also :func:`poll`s."""

    def told(text: str) -> None:
        progress(text)
        poll()

    return told


def _queued() -> list[PendingSvg]:
    """The queued figures still wanted, oldest first (the queue keeps only those)."""
    live = [p for p in (r() for r in _queue) if p is not None and p._value is None and p._batch is None]
    _queue[:] = [weakref.ref(p) for p in live]
    return live


def _unqueue(p: PendingSvg) -> None:
    _queue[:] = [r for r in _queue if r() is not None and r() is not p]


def _steal() -> bool:
    """Draw the oldest queued figure here (this process would otherwise wait); False if none is."""
    jobs = _queued()
    if not jobs:
        return False
    _unqueue(jobs[0])
    jobs[0]._render_here()
    return True


def _live() -> list[Batch]:
    """The children still rendering; those that have written are collected."""
    live = []
    for b in (r() for r in _running):
        if b is None or b.fd < 0:
            continue
        if b.finished():
            b.collect()
        else:
            live.append(b)
    _running[:] = [weakref.ref(b) for b in live]
    return live


def _start(jobs: list[PendingSvg]) -> None:
    """Give ``jobs`` to a new child if fewer than :func:`children` run; else they stay queued."""
    live = _live()
    if not jobs or len(live) >= children():
        return
    try:
        flags = mmap.mmap(-1, 2 * len(jobs) or 1)  # shared with the child (Batch)
        read_end, write_end = os.pipe()
    except OSError:
        return  # they stay queued: rendered here when asked
    fonts = font_files()
    try:
        pid = os.fork()
    except OSError:
        os.close(read_end)
        os.close(write_end)
        return
    if pid == 0:
        _child(jobs, flags, read_end, write_end, [b.fd for b in live])
    own_font_files(fonts)
    os.close(write_end)
    for p in jobs:
        _unqueue(p)
    _running.append(weakref.ref(Batch(pid, read_end, jobs, flags)))


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
            kill(pid)
        os.close(fd)
        _, status = os.waitpid(pid, 0)
    return b"".join(chunks) if whole and os.waitstatus_to_exitcode(status) == 0 else b""


def _child(
    jobs: Sequence[PendingSvg], flags: mmap.mmap, read_end: int, write_end: int, siblings: list[int]
) -> None:
    """Render ``jobs`` into the pipe (each FRAME and its bytes, all at the end: the parent reads when it
    is done computing, and a full pipe would stall the figures after the first) and leave; never
    returns. ``siblings``: the read ends of the other children's pipes, closed here so that only the
    parent holds them (a child whose parent is gone then gets a broken pipe instead of waiting for a
    reader)."""
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
        out, n = [], len(jobs)
        for i, p in enumerate(jobs):
            uri = b""
            if not flags[n + i]:  # not claimed by the parent (Batch.claim)
                flags[i] = 1
                try:
                    uri = svg_uri(_made(p._fig)).encode("ascii")
                except Exception:  # this figure is drawn by the parent (it says why), the others here
                    uri = b""
            out += [FRAME.pack(len(uri)), uri]
        write_all(write_end, b"".join(out))
        code = 0
    finally:
        os._exit(code)


def font_files() -> dict[int, tuple[str, int]]:
    """The font files this process holds open (Linux): descriptor -> (path, offset), read just before a
    fork for :func:`own_font_files` after it."""
    try:
        names = os.listdir("/proc/self/fd")
    except OSError:
        return {}
    files = {}
    for name in names:
        try:
            path = os.readlink(f"/proc/self/fd/{name}")
            if path.lower().endswith(FONT_FILES):
                files[int(name)] = (path, os.lseek(int(name), 0, os.SEEK_CUR))
        except OSError:  # the listing's own descriptor, closed since
            continue
    return files


def own_font_files(files: dict[int, tuple[str, int]]) -> None:
    """Open again, each in its own descriptor, the font files of ``files`` (this process's
    :func:`font_files` just before it forked): the child keeps the ones it inherited to itself.

    FreeType reads a font through a buffered file (a seek, then a read), and a forked child shares each
    inherited file's offset with its parent: a parent drawing text while a child drew (or closed the
    fonts only matplotlib's cache held, which matplotlib empties in a child) read glyph data from
    wherever the other had left it, "failed to load glyph" (seen in a suite run). Here the parent opens
    each file again, in the same descriptor, at the offset its buffered file knows (the one before the
    fork, not the shared one: the child runs meanwhile), so every cache that holds the font stays valid."""
    for fd, (path, offset) in files.items():
        try:
            if os.readlink(f"/proc/self/fd/{fd}") != path:  # closed since the listing (a font collected)
                continue
            own = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError:  # closed, or the file is gone: nothing to reopen
            continue
        try:
            os.lseek(own, offset, os.SEEK_SET)
            os.dup2(own, fd, inheritable=os.get_inheritable(fd))
        except OSError:  # left shared, as without this function
            pass
        finally:
            os.close(own)


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
    pending = PendingSvg(fig)
    if not callable(fig):
        pyplot().close(fig)  # pyplot forgets it; it is rendered from this object (here or in a child)
    _queue.append(weakref.ref(pending))
    _start(_queued())
    return pending
