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

A computation that swallows the signal and goes on (an interrupted IPOPT returns; the tuner starts its
next round) is not waited for: :func:`handled` starts a watchdog with the first signal, and if the
command has not ended :data:`GRACE` seconds later, it prints the command's line, ends the processes
this one started (a local Dask cluster's workers) and exits with the signal's status. So SIGTERM ends
the whole process tree within seconds (a SIGTERMed ``tune`` computed on for 8 minutes).

The watchdog is the script's (``main()`` run as ``sensorless``): a caller that runs ``main([...])`` in its
own process (a test, a notebook) is never ended by it; it gets the exit status when the command ends.

:func:`budget` is a command's time budget: SIGALRM after that many seconds of wall time, handled as a
signal (nothing written), whose line says the budget ran out, and why a run may take that long. The
alarm repeats every :data:`REPEAT` seconds until the block ends: CasADi may swallow the first one (a
tune then computed on for minutes), a later one lands in Python code and ends the block.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any, TextIO

SIGNALS = (signal.SIGINT, signal.SIGTERM)
BUDGET = signal.SIGALRM  # a command's time budget ran out (:func:`budget`)
GRACE = 10.0  # s: how long a command may take to end after a signal before the watchdog ends it
REPEAT = 0.25  # s: the budget's alarm again, while the block runs on after a swallowed one
_received: int | None = None
_defer = 0
_prefix = "sensorless"  # the command's line prefix (the watchdog's line)
_budget_note = ""  # what the budget's line says
_handling = False  # inside handled(watchdog=True) in the main thread: a signal starts the watchdog
_cancel: threading.Event | None = None  # the running watchdog's: set when the command ends or resets


class Interrupted(KeyboardInterrupt):
    """The process received SIGINT or SIGTERM (``signum``)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _handler(signum: int, frame: FrameType | None) -> None:
    global _received, _cancel
    if _received is None:
        _received = signum
        if _handling:
            _cancel = threading.Event()
            _watch(signum, _cancel)
    elif signum == BUDGET and frame is not None and frame.f_code.co_filename in _UNWINDING:
        return  # a repeated alarm while this module or a with statement unwinds the first one's exception
    if _defer == 0:
        raise Interrupted(signum)


_UNWINDING = frozenset({__file__, contextlib.__file__})


def line(signum: int) -> tuple[str, int]:
    """(the one line, the exit status) of a command ended by ``signum``."""
    if signum == BUDGET:
        return f"{_prefix}: error: {_budget_note}", 3
    return f"{_prefix}: {'interrupted' if signum == SIGNALS[0] else 'terminated'}", 128 + signum


def _watch(signum: int, done: threading.Event) -> None:
    """End the process and its children if the command has not ended GRACE s after ``signum``."""

    def run() -> None:
        if done.wait(GRACE):
            return
        text, code = line(signum)
        err = sys.__stderr__  # None: no stderr to write to
        try:
            if err is not None:
                err.write(text + "\n")
                err.flush()
        except (OSError, ValueError, AttributeError):
            pass
        kill_children()
        os._exit(code)

    threading.Thread(target=run, name="sensorless-watchdog", daemon=True).start()


def kill_children() -> None:
    """SIGKILL every process this one started, their children first (psutil: a dependency of Dask)."""
    try:
        import psutil

        kids = psutil.Process().children(recursive=True)
    except Exception:  # no psutil, or the process table unreadable: nothing more to do
        return
    for k in reversed(kids):
        try:
            k.kill()
        except Exception:
            pass


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class _CasadiInterruptFilter:
    """sys.stderr without CasADi's own report of an interrupt it caught (IPOPT's callback prints
    ``CasADi - <date> WARNING("KeyboardInterruptException") [...]``): the command prints its one line."""

    def __init__(self, stream: TextIO) -> None:
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
def handled(prefix: str = "sensorless", watchdog: bool = True) -> Iterator[None]:
    """Record SIGINT and SIGTERM for the length of the block (the command line's whole run; ``prefix``
    its line's start), with the watchdog of a swallowed signal (module docstring) if ``watchdog``: only
    in a process that is the command (the watchdog exits the process)."""
    global _prefix, _handling
    reset()
    _prefix, _handling = prefix, watchdog and _main_thread()
    old = {s: signal.signal(s, _handler) for s in SIGNALS} if _main_thread() else {}
    stderr = sys.stderr
    filtered = _CasadiInterruptFilter(stderr)
    sys.stderr = filtered  # type: ignore[assignment]
    try:
        yield
    finally:
        _handling = False
        reset()  # the command ended: no watchdog (main() has read the signal)
        sys.stderr = stderr
        if filtered._held and "KeyboardInterruptException" not in filtered._held:
            stderr.write(filtered._held)  # a CasADi line without its end: as it was
        for s, h in old.items():
            signal.signal(s, h)


@contextmanager
def budget(seconds: float | None, note: str) -> Iterator[None]:
    """SIGALRM after ``seconds`` of wall time (None or 0: no budget), then every :data:`REPEAT` s, for the
    length of the block, handled as SIGINT is; ``note``: the error line's text. Only in the main thread
    (elsewhere: no budget)."""
    global _budget_note
    if not seconds or not _main_thread():
        yield
        return
    _budget_note = note
    old = signal.signal(BUDGET, _handler)
    signal.setitimer(signal.ITIMER_REAL, float(seconds), REPEAT)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(BUDGET, old)


def ignore() -> None:
    """Ignore SIGINT and SIGTERM from now on (a process about to exit, its work done)."""
    if _main_thread():
        for s in SIGNALS:
            signal.signal(s, signal.SIG_IGN)


def received() -> int | None:
    """The first signal received inside :func:`handled` (None: none)."""
    return _received


def reset() -> None:
    """Forget a received signal (the next command of the same process starts afresh), and stop its
    watchdog (the command has handled it)."""
    global _received, _cancel
    _received = None
    if _cancel is not None:
        _cancel.set()
        _cancel = None


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
