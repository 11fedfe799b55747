"""One computation run in a forked child process while this process computes on (Linux): its value later.

``sensorless tune`` runs one thread of Python at a time on a 2-core machine: the proof of the drive
file's gains (reports/tune_proof.py: four time-domain checks and the linear analysis over +-T_max, ~0.7 s
CPU on the README servo) does not depend on the tuning, and the proof of a candidate table need not wait
for the tuning that may replace it. :func:`later` forks: the child, a copy of this process with every
Function and memo built so far, calls the function, pickles its value into a pipe and exits; the parent
goes on, and :meth:`Pending.result` reads the value (waiting for the child if need be). It is the value
the parent would have computed: the same code on the same data (a forked child's arithmetic is this
process's). Not a pool: one child per computation, as reports/svg_render.py's figures.

A computation in steps (``then``): after its value the child stays, with what it built, for the
follow-up requests of the same computation (:meth:`Pending.ask`, answered in order; the tuned gains'
proof after the drive file's reuses its simulations' set-up: 0.2 s CPU instead of 1.0 s on the README
servo), and ends when the parent closes (:meth:`Pending.close`) or drops it.

The child writes nothing but its pipe and, if asked, its progress lines on stderr (stdout goes to
/dev/null), leaves by ``os._exit`` (no atexit handlers, no second flush of inherited buffers) and dies at
once on Ctrl-C or SIGTERM. A result no longer wanted is killed and reaped (:meth:`Pending.cancel`, or
when it is garbage collected). Where the child fails (the function raised, its value does not pickle,
the child was killed), or without fork (not Linux, or SENSORLESS_NO_FORK=1), the value (or a reply) is
computed here: its exception, if any, is raised here as it would have been.
"""

from __future__ import annotations

import gc
import os
import pickle
import select
import signal
import struct
import sys
import weakref
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar, cast

T = TypeVar("T")
R = TypeVar("R")  # a follow-up request's reply
_HEAD = struct.Struct("<Q")  # a message: its length, then its pickle


def forking() -> bool:
    """Whether :func:`later` (and reports/svg_render.py's figures) run in child processes here."""
    return sys.platform == "linux" and hasattr(os, "fork") and not os.environ.get("SENSORLESS_NO_FORK")


class Pending(Generic[T, R]):
    """The value of a function a child process computes (:func:`later`), and its replies to follow-up
    requests (``then``)."""

    def __init__(self, fn: Callable[[], T], then: Callable[..., R] | None = None) -> None:
        self._fn: Callable[[], T] | None = fn  # kept to compute it here if the child fails
        self._then = then
        self.forked = False  # a child computes it (else result() does, here)
        self._child: tuple[int, int, int] | None = None  # (pid, read end of its pipe, write end of ours)
        self._buf = bytearray()
        self._eof = False
        self._finalizer: weakref.finalize | None = None
        self._has_value = False
        self._value: T | None = None
        self._requests: list[object] = []  # follow-up requests sent (answered in this order)
        self._replies: dict[int, R | None] = {}  # replies read and not yet taken, by request
        self._taken = 0  # replies taken

    def _read(self, timeout: float | None) -> None:
        """Read what the child has written, until its end or a whole next message (``timeout`` None:
        wait for one) or until ``timeout`` seconds pass without data."""
        assert self._child is not None
        fd = self._child[1]
        while not self._eof and not self._whole() and select.select([fd], [], [], timeout)[0]:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                self._eof = True
            else:
                self._buf += chunk

    def _whole(self) -> bool:
        return len(self._buf) >= _HEAD.size and len(self._buf) >= _HEAD.size + _HEAD.unpack_from(self._buf)[0]

    def _message(self) -> tuple[bool, object]:
        """(True, the child's next message) or (False, None) where it ended without one."""
        self._read(None)
        if not self._whole():
            return False, None
        n = _HEAD.unpack_from(self._buf)[0]
        data = bytes(self._buf[_HEAD.size : _HEAD.size + n])
        del self._buf[: _HEAD.size + n]
        return True, pickle.loads(data)

    def done(self) -> bool:
        """Whether the value is there (the child has computed it), without waiting."""
        if self._has_value or self._child is None:
            return True
        self._read(0.0)
        return self._whole() or self._eof

    def result(self) -> T:
        """The function's value (waits for the child; computed here where the child failed)."""
        if not self._has_value:
            ok, value = self._message() if self._child is not None else (False, None)
            if not ok:
                self._end()
            fn, self._fn = self._fn, None
            assert fn is not None
            self._value = cast(T, value) if ok else fn()
            self._has_value = True
            if self._then is None:
                self._end()
        return self._value  # type: ignore[return-value]

    def ask(self, request: object) -> Callable[[], R]:
        """Send the child a follow-up request; returns the function that gives its reply,
        ``then(request)`` (computed here where the child is gone). The child answers in the order asked."""
        assert self._then is not None
        k = len(self._requests)
        self._requests.append(request)
        if self._child is not None:
            try:
                data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
                write_all(self._child[2], _HEAD.pack(len(data)) + data)
            except (OSError, pickle.PicklingError, TypeError, AttributeError):
                self._end()
        return lambda: self._reply(k)

    def _reply(self, k: int) -> R:
        self.result()  # the first value comes first
        while k not in self._replies:
            j = len(self._replies) + self._taken
            ok, value = self._message() if self._child is not None else (False, None)
            if not ok:
                self._end()
                assert self._then is not None
                value = self._then(self._requests[j]) if j == k else None  # (an earlier one: not wanted)
            self._replies[j] = cast("R | None", value)
        self._taken += 1
        return cast(R, self._replies.pop(k))

    def close(self) -> None:
        """No more requests: the child ends (after the replies not yet read, which are dropped)."""
        self._end()

    def cancel(self) -> None:
        """Kill the child (its value is not wanted)."""
        self._end()
        self._fn = None

    def _end(self) -> None:
        if self._child is not None:
            pid, fd, req = self._child
            self._child = None
            if self._finalizer is not None:
                self._finalizer.detach()
            reap(os.getpid(), pid, fd, req)


def write_all(fd: int, data: bytes) -> None:
    """Write all of ``data`` to ``fd`` (a pipe takes it in pieces)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def kill(pid: int) -> None:
    """SIGKILL to a child, if it is still there."""
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:  # already gone
        pass


def reap(owner: int, pid: int, *fds: int) -> None:
    """Kill and reap a child whose value is no longer wanted, closing ``fds`` (only in the process that
    forked it: a finalizer may also run in a child)."""
    if os.getpid() != owner:
        return
    kill(pid)
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass
    try:
        os.waitpid(pid, 0)
    except OSError:
        pass


def _messages(fd: int) -> Iterator[bytes]:
    """The messages on ``fd`` (blocking), until its end."""
    buf = bytearray()
    while True:
        while len(buf) >= _HEAD.size and len(buf) >= _HEAD.size + (n := _HEAD.unpack_from(buf)[0]):
            yield bytes(buf[_HEAD.size : _HEAD.size + n])
            del buf[: _HEAD.size + n]
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            return
        buf += chunk


def _child(
    fn: Callable[[], object], then: Callable[..., object] | None, fds: tuple[int, int, int, int], stderr: bool
) -> None:
    """Compute, pickle into the pipe, answer the requests (``then``) and leave; never returns
    (``stderr``: keep it, for progress lines)."""
    read_end, write_end, req_read, req_write = fds
    code = 1
    try:
        # a short life: no garbage collection, whose passes over the whole inherited heap would copy
        # every page of it (copy-on-write) for nothing
        gc.disable()
        os.close(read_end)
        os.close(req_write)
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_DFL)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        if not stderr:
            os.dup2(devnull, 2)
        data = pickle.dumps(fn(), protocol=pickle.HIGHEST_PROTOCOL)
        write_all(write_end, _HEAD.pack(len(data)) + data)
        if then is not None:
            for msg in _messages(req_read):
                data = pickle.dumps(then(pickle.loads(msg)), protocol=pickle.HIGHEST_PROTOCOL)
                write_all(write_end, _HEAD.pack(len(data)) + data)
        code = 0
    finally:
        os._exit(code)


def later(fn: Callable[[], T], stderr: bool = False, then: Callable[..., R] | None = None) -> Pending[T, R]:
    """``fn()``'s value, computed by a forked child while this process goes on (module docstring);
    bind the arguments now (functools.partial). ``then``: the child stays for follow-up requests of
    the same computation, ``then(request)`` each (:meth:`Pending.ask`), with what ``fn`` built.
    ``stderr``: the child's progress lines go to this process's stderr (where they would have gone; a
    child that fails and is computed again here says them twice), else to /dev/null. Flushes stdout
    and stderr first (the child must not write what this process has buffered)."""
    pending: Pending[T, R] = Pending(fn, then)
    if not forking():
        return pending  # result() computes it here
    sys.stdout.flush()
    sys.stderr.flush()
    fds: list[int] = []
    try:
        for _ in range(2):
            fds += os.pipe()
        pid = os.fork()
    except OSError:
        for fd in fds:
            os.close(fd)
        return pending
    read_end, write_end, req_read, req_write = fds
    if pid == 0:
        _child(fn, then, (read_end, write_end, req_read, req_write), stderr)
    os.close(write_end)
    os.close(req_read)
    pending.forked = True
    pending._child = (pid, read_end, req_write)
    pending._finalizer = weakref.finalize(pending, reap, os.getpid(), pid, read_end, req_write)
    return pending
