"""One computation run in a forked child process while this process computes on (Linux): its value later.

``sensorless tune`` runs one thread of Python at a time on a 2-core machine: the proof of the drive
file's gains (reports/tune_proof.py: four time-domain checks and the linear analysis over +-T_max, ~0.7 s
CPU on the README servo) does not depend on the tuning, and the proof of a candidate table need not wait
for the tuning that may replace it. :func:`later` forks: the child, a copy of this process with every
Function and memo built so far, calls the function, pickles its value into a pipe and exits; the parent
goes on, and :meth:`Pending.result` reads the value (waiting for the child if need be). It is the value
the parent would have computed: the same code on the same data (a forked child's arithmetic is this
process's). Not a pool: one child per call, as reports/svg_render.py's figures.

The child writes nothing but its pipe and, if asked, its progress lines on stderr (stdout goes to
/dev/null), leaves by ``os._exit`` (no atexit handlers, no second flush of inherited
buffers) and dies at once on Ctrl-C or SIGTERM. A result no longer wanted is killed and reaped
(:meth:`Pending.cancel`, or when it is garbage collected). Where the child fails (the function raised,
its value does not pickle, the child was killed), or without fork (not Linux, or SENSORLESS_NO_FORK=1),
:meth:`Pending.result` calls the function here: its exception, if any, is raised here as it would have
been.
"""

from __future__ import annotations

import gc
import os
import pickle
import select
import signal
import sys
import weakref
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


def forking() -> bool:
    """Whether :func:`later` runs its function in a child process here."""
    return sys.platform == "linux" and hasattr(os, "fork") and not os.environ.get("SENSORLESS_NO_FORK")


class Pending(Generic[T]):
    """The value of a function a child process computes (:func:`later`)."""

    def __init__(self, fn: Callable[[], T]) -> None:
        self._fn: Callable[[], T] | None = fn  # kept to compute it here if the child fails
        self.forked = False  # a child computes it (else result() does, here)
        self._child: tuple[int, int] | None = None  # (pid, read end of its pipe)
        self._chunks: list[bytes] = []
        self._eof = False
        self._finalizer: weakref.finalize | None = None
        self._has_value = False
        self._value: T | None = None

    def _read(self, timeout: float | None) -> None:
        """Read what the child has written, until its end (``timeout`` None: wait for it) or until
        ``timeout`` seconds pass without data."""
        assert self._child is not None
        fd = self._child[1]
        while not self._eof and select.select([fd], [], [], timeout)[0]:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                self._eof = True
            else:
                self._chunks.append(chunk)

    def done(self) -> bool:
        """Whether the value is there (the child has finished), without waiting."""
        if self._has_value or self._child is None:
            return True
        self._read(0.0)
        return self._eof

    def result(self) -> T:
        """The function's value (waits for the child; computed here where the child failed)."""
        if not self._has_value:
            data = b""
            if self._child is not None:
                pid, fd = self._child
                try:
                    self._read(None)
                finally:
                    self._child = None
                    if self._finalizer is not None:
                        self._finalizer.detach()
                    if not self._eof:  # interrupted while waiting: the child's work is not wanted
                        _kill(pid)
                    os.close(fd)
                    _, status = os.waitpid(pid, 0)
                if os.waitstatus_to_exitcode(status) == 0:
                    data = b"".join(self._chunks)
            self._chunks = []
            fn, self._fn = self._fn, None
            assert fn is not None
            self._value = pickle.loads(data) if data else fn()
            self._has_value = True
        return self._value  # type: ignore[return-value]

    def cancel(self) -> None:
        """Kill the child (its value is not wanted)."""
        if self._child is not None:
            pid, fd = self._child
            self._child = None
            if self._finalizer is not None:
                self._finalizer.detach()
            _reap(os.getpid(), pid, fd)
        self._fn = None


def _kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:  # already gone
        pass


def _reap(owner: int, pid: int, fd: int) -> None:
    """Kill and reap a child whose value is no longer wanted (only in the process that forked it)."""
    if os.getpid() != owner:
        return
    _kill(pid)
    for step in (lambda: os.close(fd), lambda: os.waitpid(pid, 0)):
        try:
            step()
        except OSError:
            pass


def _child(fn: Callable[[], object], read_end: int, write_end: int, stderr: bool) -> None:
    """Compute, pickle into the pipe and leave; never returns (``stderr``: keep it, for progress lines)."""
    code = 1
    try:
        # a short life: no garbage collection, whose passes over the whole inherited heap would copy
        # every page of it (copy-on-write) for nothing
        gc.disable()
        os.close(read_end)
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_DFL)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        if not stderr:
            os.dup2(devnull, 2)
        view = memoryview(pickle.dumps(fn(), protocol=pickle.HIGHEST_PROTOCOL))
        while view:
            view = view[os.write(write_end, view) :]
        code = 0
    finally:
        os._exit(code)


def later(fn: Callable[[], T], stderr: bool = False) -> Pending[T]:
    """``fn()``'s value, computed by a forked child while this process goes on (module docstring);
    bind the arguments now (functools.partial). ``stderr``: the child's progress lines go to this
    process's stderr (where they would have gone; a child that fails and is computed again here says
    them twice), else to /dev/null. Flushes stdout and stderr first (the child must not write what this
    process has buffered)."""
    pending = Pending(fn)
    if not forking():
        return pending  # result() computes it here
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        read_end, write_end = os.pipe()
    except OSError:
        return pending
    try:
        pid = os.fork()
    except OSError:
        os.close(read_end)
        os.close(write_end)
        return pending
    if pid == 0:
        _child(fn, read_end, write_end, stderr)
    os.close(write_end)
    pending.forked = True
    pending._child = (pid, read_end)
    pending._finalizer = weakref.finalize(pending, _reap, os.getpid(), pid, read_end)
    return pending
