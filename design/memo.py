"""An in-process memo of analyses keyed on the content of their (frozen, unhashable) arguments.

A drive and its gains are frozen dataclasses, but hold dicts and arrays, so ``functools.cache`` cannot
key on them, and an analysis of the same drive at the same gains recurs within one process: the I-f
start's rules ask for the whole drive's minimum speed at every simulation set-up (each time-domain
check of a report, the start-up check, codegen --startup), the tune line and the report ask for it
under the same estimate errors. :func:`by_content` keys on the pickled arguments: equal bytes rebuild
equal objects, so a hit is the same computation (a miss where two equal objects pickle differently
costs only the recomputation). Only results that are immutable (frozen dataclasses whose arrays are
made read-only here) are memoized, so no caller can change what another one gets.

A dataclass field marked :data:`LABEL` in its metadata (a gain set's ``source``: the table's file as
the caller named it) says where an argument comes from, not what it is: it is left out of the key, so
the same gains read as ``tune/gains.json`` and as ``/abs/tune/gains.json`` are one computation. A
memoized function must therefore not quote a label in its result (the first caller's would reach
every later one): the callers put their own label into what they print (e.g. reports/low_speed.py's
section takes the report's ``review``).

A memo made with ``disk=True`` also keeps its results in ``$SENSORLESS_CACHE/memo`` (design/compiled.py
``cache_root``; ``SENSORLESS_NO_DISK_MEMO=1``: in-process only), for the next process that asks: the
README flow's ``report`` asks for the analyses its ``tune`` made (the whole drive's minimum speed of the
tuned gains for the I-f start of every check, and under the drive's estimate errors for the tune line)
and the time-domain runs of its proof (design/simulate.py ``simulated``). A file is named by the SHA-256
of the function, its key and :func:`fingerprint` (the toolbox's source and the versions of what
computes), so a result is reused only by the same code on the same content; a file that cannot be read
is recomputed and written again (temp file + rename).

:func:`kept_function` keeps the CasADi Functions a builder makes the same way: building a graph (SX
operations through Python, common subexpressions, Jacobians) costs each process 0.02-0.3 s per
Function, where reading the serialized Function back costs about a millisecond, and the README flow's
four commands build the same ones (the linearizations, the drive loop and its maps) from the same
structural arguments (a gain law's name, an observer step, a chunk length).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import importlib.metadata
import importlib.util
import io
import os
import pickle
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, ParamSpec, TypeVar, cast

import numpy as np

P = ParamSpec("P")  # the memoized function's arguments
R = TypeVar("R")  # its result

LABEL = {"memo": "label"}  # a dataclass field's metadata: a label for messages, not content (not keyed)


def _content(value: Any) -> Any:
    """``value`` as keyed: a dataclass instance with :data:`LABEL` fields as its type and the values of
    its other fields (an argument's own fields only: labels nested deeper stay in the key)."""
    if not dataclasses.is_dataclass(value) or isinstance(value, type):
        return value
    kept = [f.name for f in dataclasses.fields(value) if f.metadata.get("memo") != LABEL["memo"]]
    if len(kept) == len(dataclasses.fields(value)):
        return value
    return (type(value), tuple((name, getattr(value, name)) for name in kept))


class BytesMemo(Generic[R]):
    """An in-process memo keyed on bytes (what a result is computed from): the ``maxsize`` most recent
    entries; safe from several threads (a threaded scheduler may tune several drives in one process)."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._memo: collections.OrderedDict[bytes, R] = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: bytes) -> R | None:
        """The result kept for ``key``, or None."""
        with self._lock:
            if key not in self._memo:
                return None
            self._memo.move_to_end(key)
            return self._memo[key]

    def put(self, key: bytes, value: R) -> R:
        """Keep ``value`` for ``key``; returns it."""
        with self._lock:
            self._memo[key] = value
            self._memo.move_to_end(key)
            if len(self._memo) > self.maxsize:
                self._memo.popitem(last=False)
        return value

    def clear(self) -> None:
        with self._lock:
            self._memo.clear()


class OwnedMemo(Generic[R]):
    """A :class:`BytesMemo` of results computed from an object not worth pickling (a tuning model with
    its CasADi Functions) and some arrays: keyed on the object's identity and the arrays' bytes; an entry
    holds its object, so that the id cannot be reused by another object while the entry lives."""

    def __init__(self, maxsize: int) -> None:
        self._memo: BytesMemo[tuple[object, R]] = BytesMemo(maxsize)

    def get(self, owner: object, key: bytes) -> R | None:
        """The result kept for ``owner`` and ``key``, or None."""
        hit = self._memo.get(_owned(owner, key))
        return None if hit is None else hit[1]

    def put(self, owner: object, key: bytes, value: R) -> R:
        """Keep ``value`` for ``owner`` and ``key``; returns it."""
        self._memo.put(_owned(owner, key), (owner, value))
        return value

    def clear(self) -> None:
        self._memo.clear()


def _owned(owner: object, key: bytes) -> bytes:
    return id(owner).to_bytes(8, "little") + key


def frozen_result(value: R) -> R:
    """``value`` with the arrays of its dataclass fields made read-only (in place; returned)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            a = getattr(value, f.name)
            if isinstance(a, np.ndarray):
                a.flags.writeable = False
    return value


def uncached(fn: Callable[P, R]) -> Callable[P, R]:
    """The function a :func:`by_content` memo wraps, for a call whose result is asked for once (not
    worth a place in the memo)."""
    return fn.__wrapped__  # type: ignore[attr-defined,no-any-return]


@functools.cache
def fingerprint() -> bytes:
    """What a result kept on disk depends on besides its arguments: the toolbox's source (every
    ``.py`` file of its four packages, found without importing them) and the versions of Python and
    of the libraries that compute (numpy, scipy, CasADi)."""
    h = hashlib.sha256(sys.version.encode())
    for dist in ("numpy", "scipy", "casadi"):
        try:
            h.update(f"|{dist} {importlib.metadata.version(dist)}".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"|{dist} -".encode())
    for layer in ("symbolic", "design", "tuning", "reports"):
        spec = importlib.util.find_spec(f"sensorless.{layer}")
        for root in map(Path, (spec.submodule_search_locations or []) if spec else []):
            for f in sorted(root.rglob("*.py")):
                h.update(f"{layer}/{f.relative_to(root).as_posix()}\0".encode())
                h.update(f.read_bytes())
    return h.digest()


def before_fork() -> None:
    """:func:`fingerprint` computed now where the disk memo is on (it hashes the toolbox's source: 20-30
    ms CPU), for a process about to fork children that use the memo too (design/forked.py): a child is a
    copy of this process, so it is computed once for both."""
    if not os.environ.get("SENSORLESS_NO_DISK_MEMO"):
        fingerprint()


def _disk_path(fn: Callable[..., object], key: bytes) -> Path | None:
    """The file of ``fn``'s result for ``key`` (None: the disk memo is off)."""
    return _named_path(fn.__module__, fn.__qualname__, key)


def _named_path(module: str, name: str, key: bytes) -> Path | None:
    """The file of the result named ``name`` (of ``module``) for ``key`` (None: the disk memo is off)."""
    if os.environ.get("SENSORLESS_NO_DISK_MEMO"):
        return None
    from sensorless.design.compiled import cache_root

    digest = hashlib.sha256(fingerprint() + f"{module}.{name}".encode() + b"\0" + key).hexdigest()
    return cache_root() / "memo" / f"{name}-{digest}.pickle"


def _disk_get(path: Path) -> tuple[bool, object]:
    """(found, value) of a result kept in ``path``; a file that cannot be read counts as absent."""
    try:
        with open(path, "rb") as fh:
            return True, pickle.load(fh)
    except Exception:  # absent, unreadable, truncated, or of a class since renamed: recomputed
        return False, None


def _disk_put(path: Path, value: object) -> None:
    """Keep ``value`` in ``path`` (temp file + rename: a reader never sees half a file); a cache that
    cannot be written is no error (the next process computes it again)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".pickle")
        try:
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except (OSError, pickle.PicklingError, TypeError, AttributeError):
        pass


def _pickled(content: object) -> bytes | None:
    """The key of ``content`` (its pickled bytes); None: it cannot be pickled (not memoized), or holds
    a cycle. Pickled without the pickler's memo (``fast``): with it, an object met a second time is
    written as a reference to the first, so equal content pickled differently wherever the same string
    or tuple was one object in one process and two equal ones in another (a gain table's keys read back
    from its JSON file by ``report`` against the same names ``tune`` held as the drive's own strings:
    every analysis ``tune`` kept was missed). Without it the bytes are the content's alone."""
    buf = io.BytesIO()
    pickler = pickle.Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.fast = True
    try:
        pickler.dump(content)
    except (pickle.PicklingError, TypeError, AttributeError, ValueError, RecursionError):
        return None  # ValueError: a cycle (the fast pickler refuses one rather than recursing forever)
    return buf.getvalue()


def _kept(path: Path | None, compute: Callable[[], R]) -> tuple[bool, R]:
    """(found, value): the result kept in ``path``, else ``compute()``'s, then kept there (None: the
    disk memo is off, computed); its arrays read-only whichever way it came (:func:`frozen_result`)."""
    if path is not None:
        found, kept = _disk_get(path)
        if found:
            return True, frozen_result(cast(R, kept))  # pickled under this key by the same code
    value = frozen_result(compute())
    if path is not None:
        _disk_put(path, value)
    return False, value


def by_content(
    maxsize: int = 32, when: Callable[[], bool] = lambda: True, disk: bool = False
) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Memoize a function on the pickled bytes of its arguments, their labels left out (module
    docstring), the ``maxsize`` most recent results; ``when()`` False: computed and not memoized (a
    state outside the arguments that the result depends on, e.g. a step variant). Arguments that
    cannot be pickled: not memoized. ``disk``: results kept on disk for later processes too (module
    docstring). ``fn.cache_info()`` gives (hits, misses), a result read from disk counted as a hit."""

    def deco(fn: Callable[P, R]) -> Callable[P, R]:
        memo: collections.OrderedDict[bytes, R] = collections.OrderedDict()
        counts = [0, 0]
        lock = threading.Lock()  # a threaded scheduler may call it from several threads

        @functools.wraps(fn)
        def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
            if not when():
                return fn(*args, **kwargs)
            key = _pickled((tuple(map(_content, args)), sorted((k, _content(v)) for k, v in kwargs.items())))
            if key is None:
                return fn(*args, **kwargs)
            with lock:
                if key in memo:
                    counts[0] += 1
                    memo.move_to_end(key)
                    return memo[key]
            # outside the lock: computed in parallel
            found, value = _kept(_disk_path(fn, key) if disk else None, lambda: fn(*args, **kwargs))
            with lock:
                counts[0 if found else 1] += 1
                memo[key] = value
                if len(memo) > maxsize:
                    memo.popitem(last=False)
            return value

        wrapper.cache_info = lambda: tuple(counts)  # type: ignore[attr-defined]

        def cache_clear() -> None:
            memo.clear()
            counts[:] = [0, 0]

        wrapper.cache_clear = cache_clear  # type: ignore[attr-defined]
        return wrapper

    return deco


def kept_function(fn: Callable[P, R]) -> Callable[P, R]:
    """A builder of CasADi Functions (hashable, picklable arguments: names, flags, Functions), cached in
    the process (``functools.cache``) and on disk for later processes (:func:`by_content` with
    ``disk=True``: keyed by its arguments' content and the toolbox's source; a CasADi Function
    pickles as its serialization, which rebuilds the same graph: the same evaluations to the bit and
    the same generated C). Arguments that cannot be pickled: built here, kept in the process only."""
    return functools.cache(by_content(maxsize=8, disk=True)(fn))  # type: ignore[return-value]


def kept_result(module: str, name: str, content: object, compute: Callable[[], R]) -> R:
    """``compute()``, kept on disk as a :func:`by_content` memo with ``disk=True`` keeps its results
    (the same files, fingerprint and temp file + rename), under ``name`` and the pickled ``content``: for
    a computation whose own inputs do not pickle (a tuning model holds closures and CasADi Functions)
    but are built from ``content`` alone (the drive, the settings and the numbers they were built
    from), which the caller passes whole (a tuple: each item's labels left out, as :func:`by_content`
    does for each argument). Not kept in the process (a caller asks once per command);
    content that cannot be pickled, or no disk memo: computed. The result's arrays are read-only
    whichever way it came (a caller that changed them would fail in the tests too, not only where the
    disk memo is on)."""
    key = _pickled(tuple(map(_content, content)) if isinstance(content, tuple) else _content(content))
    return _kept(None if key is None else _named_path(module, name, key), compute)[1]
