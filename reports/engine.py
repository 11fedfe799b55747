"""The engine that runs many independent tasks (Monte-Carlo chunks, time-domain draws): Dask.

Why Dask (dask.distributed) rather than a pool of our own: it is a maintained engine that runs the
same code on this machine (a ``LocalCluster`` of worker processes) or on an existing cluster
(``--scheduler tcp://HOST:PORT``), cancels tasks, reports worker deaths and serialises the arguments,
none of which a home-made pool would do as well.

- ``Engine(None)``: a local cluster, one single-threaded worker process per core (the tasks are
  CPU-bound numpy/CasADi work; threads would fight for the GIL between calls). Two Dask defaults
  are turned off for its workers (:data:`LOCAL_CONFIG`): the statistical profiler (a stack sample
  every 10 ms) and ``MALLOC_TRIM_THRESHOLD_=65536``, which hands every freed numpy temporary back
  to the kernel and faults it in again at the next allocation; with both a Monte-Carlo chunk took
  ~45 % more CPU in a worker than in the calling process, without them a few per cent.
- ``Engine("tcp://HOST:PORT")``: connect to that scheduler (its workers need sensorless installed).
- ``Engine("synchronous")``: no cluster; tasks run one after another in this process (tests,
  profiling, one-core machines).

:meth:`Engine.map` returns the results in the order of the items whatever order they finish in, so a
result never depends on the number of workers as long as each task is deterministic. While it waits
it prints progress on stderr; on Ctrl-C (reports/interrupts.py raises ``Interrupted`` in the main
thread) it cancels every task and re-raises, so the command writes nothing.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import TYPE_CHECKING, Any, TextIO, TypeVar

if TYPE_CHECKING:  # imported when a cluster starts, not before
    from dask.distributed import Client, LocalCluster

T = TypeVar("T")  # a task's result

SYNCHRONOUS = "synchronous"
LOCAL_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.gil.enabled": False,
}


# The address schemes a scheduler of another process can listen on (Dask's ``inproc://`` is this
# process only; ``ucx://`` needs a library that is not a dependency).
SCHEMES = ("tcp", "tls", "ws", "wss")


class EngineError(ValueError):
    """The engine cannot be started or reached; one line naming the option."""


def scheduler_address(text: str) -> str:
    """An argparse ``type`` for ``--scheduler``: 'synchronous' or SCHEME://HOST:PORT (SCHEMES, a port in
    1..65535), checked before anything runs: Dask's own address parser raises bare ValueErrors (no
    port, an unknown scheme, a port that is not a number) that would end the command in a traceback."""
    import argparse

    if text == SYNCHRONOUS:
        return text
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text  # Dask reads a bare HOST:PORT as tcp
    want = f"expected 'synchronous' or SCHEME://HOST:PORT with SCHEME in {', '.join(SCHEMES)}"
    if scheme not in SCHEMES:
        raise argparse.ArgumentTypeError(f"{text!r}: unknown scheme {scheme!r}; {want}")
    host, colon, port = rest.rpartition(":")
    if not colon or not host.strip("[]") or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: no host and port (1-65535); {want}")
    if any(c.isspace() or c in "/?#@" for c in host):
        raise argparse.ArgumentTypeError(f"{text!r}: {host!r} is not a host name; {want}")
    return text


class Engine:
    """Runs tasks locally, on a cluster, or synchronously (module docstring); a context manager."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None, quiet: bool = False) -> None:
        self.scheduler = scheduler
        self.workers = workers
        self.quiet = quiet
        self.client: Client | None = None
        self.cluster: LocalCluster | None = None

    def __enter__(self) -> Engine:
        if self.scheduler == SYNCHRONOUS:
            return self
        import logging

        import dask
        from dask.distributed import Client, LocalCluster

        logging.getLogger("distributed").setLevel(logging.ERROR)  # its info lines are not ours to print
        try:
            if self.scheduler is None:
                self._start_local(dask, LocalCluster, Client, logging)
            else:
                self.client = Client(self.scheduler, timeout="10s")
        except (OSError, ValueError, TypeError) as e:  # unreachable, or an address Dask cannot parse
            self.__exit__(None, None, None)
            raise EngineError(f"--scheduler {self.scheduler}: cannot connect ({e})") from None
        except BaseException as e:  # Ctrl-C while the cluster starts: close what started, then stop
            self.__exit__(type(e), e, None)
            _close_half_started()
            raise
        return self

    def _start_local(
        self, dask: ModuleType, LocalCluster: type[LocalCluster], Client: type[Client], logging: ModuleType
    ) -> None:
        """The local cluster, its processes started with their standard error on /dev/null: Ctrl-C at
        the terminal reaches the whole process group, and processes still starting printed 30-140
        lines of KeyboardInterrupt tracebacks (a started worker ignores it) while this one cancelled
        their tasks and closed them anyway. What a worker has to say comes back through Dask (a
        task's exception, a worker's death), not through its stderr. (Neither an ignored SIGINT nor a
        blocked one works here: the first would lose a Ctrl-C during the start, numpy's threads
        receive the second and drop it.)"""
        sys.stderr.flush()
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        try:
            n = self.workers or os.cpu_count() or 1
            env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
            env.pop("MALLOC_TRIM_THRESHOLD_", None)
            # the workers are configured when they start: the settings apply to this cluster only
            with dask.config.set({**LOCAL_CONFIG, "distributed.nanny.pre-spawn-environ": env}):
                self.cluster = LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":0",  # no dashboard wanted; its HTTP server on any free port
                    silence_logs=logging.CRITICAL,  # the workers' cancellation warnings on Ctrl-C
                )
            self.client = Client(self.cluster)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            os.close(devnull)

    def __exit__(self, *exc: object) -> None:
        if exc and exc[0] is not None:  # interrupted: Dask's own errors while it closes are not ours
            import logging

            for name in ("distributed", "asyncio", "tornado"):
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        for thing in (self.client, self.cluster):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # closing after an interrupt: nothing more to save
                    pass
        self.client = self.cluster = None

    @property
    def size(self) -> int:
        """Number of workers (1 when synchronous)."""
        if self.client is None:
            return 1
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def map(self, fn: Callable[..., T], items: Sequence[Sequence[object]], label: str = "") -> list[T]:
        """``[fn(*item) for item in items]`` on the engine, in the items' order (module docstring)."""
        return self.map_groups([(fn, items)], label)[0]

    def map_groups(
        self, groups: Sequence[tuple[Callable[..., Any], Sequence[Sequence[object]]]], label: str = ""
    ) -> list[list[Any]]:  # groups of tasks of different results
        """:meth:`map` of several (fn, items) at once: every task submitted together, so a worker
        that ends its share of one group starts on the next instead of waiting for the slowest task
        (the serial part that kept the time-domain draws from scaling); results per group, in order."""
        progress = Progress(label, sum(len(items) for _, items in groups), quiet=self.quiet)
        if self.client is None:
            out: list[list[Any]] = []
            for fn, items in groups:
                out.append([])
                for item in items:
                    out[-1].append(fn(*item))
                    progress.step()
            return out
        from dask.distributed import as_completed

        futures, where = [], {}
        results: list[list[Any]] = [[None] * len(items) for _, items in groups]
        for g, (fn, items) in enumerate(groups):
            for i, item in enumerate(items):
                f = self.client.submit(fn, *item, pure=False)
                futures.append(f)
                where[f.key] = (g, i)
        try:
            for fut in as_completed(futures):
                g, i = where[fut.key]
                results[g][i] = fut.result()
                progress.step()
        except BaseException:
            self.client.cancel(futures, force=True)
            raise
        return results


def _close_half_started() -> None:
    """Close the local clusters whose start was interrupted (the constructor never returned one to
    close): else Dask's exit hook tries, and prints ``AssertionError: Status.init`` at exit."""
    from distributed.deploy.spec import SpecCluster

    for cluster in list(SpecCluster._instances):
        try:
            cluster.close(timeout=5)
        except BaseException:  # it cannot close from where the start stopped: its processes end with us
            pass
        SpecCluster._instances.discard(cluster)


class Progress:
    """Progress on stderr: a bar on a terminal, a line per 10 % otherwise; silent for one item."""

    def __init__(self, label: str, total: int, quiet: bool = False, stream: TextIO | None = None) -> None:
        self.label, self.total, self.done = label, total, 0
        self.stream = stream or sys.stderr
        self.quiet = quiet or total <= 1 or not label
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last = 0

    def step(self) -> None:
        self.done += 1
        if self.quiet:
            return
        frac = self.done / self.total
        text = f"{self.label}: {self.done}/{self.total} ({time.perf_counter() - self.t0:.1f} s)"
        if self.tty:
            self.stream.write(f"\r[{'#' * int(30 * frac):<30}] {text}" + ("\n" if frac >= 1 else ""))
        elif int(10 * frac) > self.last:
            self.last = int(10 * frac)
            self.stream.write(text + "\n")
        self.stream.flush()
