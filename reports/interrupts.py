"""Ctrl-C and termination: one line, exit status 128 + signal number, and never a partial output set.

CasADi checks for Ctrl-C inside its long computations and turns the resulting KeyboardInterrupt into a
RuntimeError or SystemError of its own, or an interrupted solver simply returns and the computation
goes on. So an interrupt cannot be recognised by the exception it ends with. The command line
(:func:`handled`) therefore records every SIGINT and SIGTERM in a flag, and then:

- the handler raises :class:`Interrupted` (a KeyboardInterrupt) so that Python code stops at once;
- :meth:`OutputSet.commit <sensorless.reports.files.OutputSet.commit>` calls :func:`check` before it
  moves anything into place, so a swallowed interrupt still writes nothing;
- ``main`` prints "interrupted" and returns 128 + the signal number (130 for Ctrl-C, 143 for SIGTERM)
  whenever the flag is set, whatever exception (or none) the computation ended with.

Inside :func:`deferred` (the final move of an output set) signals are only recorded, so the move
completes: the old set or the new one, never a mix.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_received: int | None = None
_defer = 0


class Interrupted(KeyboardInterrupt):
    """The process received SIGINT or SIGTERM (``signum``)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _handler(signum: int, frame: Any) -> None:
    global _received
    if _received is None:
        _received = signum
    if _defer == 0:
        raise Interrupted(signum)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class _CasadiInterruptFilter:
    """sys.stderr without CasADi's own report of an interrupt it caught (IPOPT's callback prints
    ``CasADi - <date> WARNING("KeyboardInterruptException") [...]``): the command prints its one line."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self._held = ""  # a CasADi line being written in pieces, until its end shows what it is

    def write(self, text: str) -> int:
        if self._held or text.startswith("CasADi"):
            self._held += text
            if "\n" not in self._held:
                return len(text)
            line, self._held = self._held, ""
            if "KeyboardInterruptException" not in line:
                self._stream.write(line)
            return len(text)
        return self._stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def handled() -> Iterator[None]:
    """Record SIGINT and SIGTERM for the length of the block (the command line's whole run)."""
    global _received
    _received = None
    old = {s: signal.signal(s, _handler) for s in SIGNALS} if _main_thread() else {}
    stderr = sys.stderr
    filtered = _CasadiInterruptFilter(stderr)
    sys.stderr = filtered  # type: ignore[assignment]
    try:
        yield
    finally:
        sys.stderr = stderr
        if filtered._held and "KeyboardInterruptException" not in filtered._held:
            stderr.write(filtered._held)  # a CasADi line without its end: as it was
        for s, h in old.items():
            signal.signal(s, h)


def ignore() -> None:
    """Ignore SIGINT and SIGTERM from now on (a process about to exit, its work done)."""
    if _main_thread():
        for s in SIGNALS:
            signal.signal(s, signal.SIG_IGN)


def received() -> int | None:
    """The first signal received inside :func:`handled` (None: none)."""
    return _received


def reset() -> None:
    """Forget a received signal (the next command of the same process starts afresh)."""
    global _received
    _received = None


def check() -> None:
    """Raise :class:`Interrupted` if a signal was received (even if the computation swallowed it)."""
    if _received is not None:
        raise Interrupted(_received)


@contextmanager
def deferred() -> Iterator[None]:
    """Signals inside the block are recorded but interrupt nothing; raised at its end."""
    global _defer
    install = _main_thread() and all(signal.getsignal(s) is not _handler for s in SIGNALS)
    old = {s: signal.signal(s, _handler) for s in SIGNALS} if install else {}
    _defer += 1
    try:
        yield
    finally:
        _defer -= 1
        for s, h in old.items():
            signal.signal(s, h)
    if _defer == 0 and _received is not None:
        signum = _received
        if install:  # outside the command line's handling: nothing else will look at the flag
            reset()
        raise Interrupted(signum)
