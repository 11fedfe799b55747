"""Compiled CasADi Functions, cached on disk: generate C once, compile with the system compiler, reuse.

A simulation is a ``mapaccum`` over a loop step of a few thousand operations; CasADi's virtual machine
runs it, but compiled C runs it an order of magnitude faster. ``compiled(fn)`` generates C for ``fn``
(CasADi's code generator), compiles it into a shared library with the system C compiler and loads it
with ``casadi.external``. The library is cached under ``$SENSORLESS_CACHE`` (default
``~/.cache/sensorless``) by the SHA-256 of the generated source and the compiler flags, so a second
process pays nothing. Processes that need the same library at once (pytest-xdist's workers on an
empty cache) compile it once: the first takes a lock on the library's name, the others wait for it
and load its library. Without a working compiler (or with ``SENSORLESS_NO_JIT=1``) the Function is
returned unchanged and runs on the virtual machine: same numbers, slower.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

import casadi as ca

# -O1: two thirds of -O2's compile time on the drive loops' generated C (the cost of an empty cache),
# within a few per cent of its run time, and the same bits (IEEE arithmetic either way: no fast-math)
CFLAGS = ("-O1", "-fPIC", "-shared", "-fno-fast-math")
# $SENSORLESS_CC_OPT: another optimization level (-O0 ... -O3, -Os) for a process that compiles more than
# it runs, such as the test suite on an empty cache (-O0: ~0.35 s instead of ~0.9 s for a drive loop's
# library; the libraries are cached under their flags, so they never mix)
OPT_ENV = "SENSORLESS_CC_OPT"


def cflags() -> tuple[str, ...]:
    """The compiler flags: CFLAGS, with $SENSORLESS_CC_OPT's level if it names one."""
    opt = os.environ.get(OPT_ENV, "")
    return (opt, *CFLAGS[1:]) if opt in ("-O0", "-O1", "-O2", "-O3", "-Os") else CFLAGS


def cache_root() -> Path:
    """$SENSORLESS_CACHE (default ``~/.cache/sensorless``): what later processes reuse (compiled
    libraries here, the analyses design/memo.py keeps on disk)."""
    return Path(
        os.environ.get("SENSORLESS_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "sensorless")
    )


def cache_dir() -> Path:
    """Where compiled libraries are kept."""
    return cache_root() / "jit"


def compiler() -> str | None:
    """The C compiler to use ($CC, else cc/gcc/clang on PATH), or None."""
    for c in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if c and shutil.which(c):
            return c
    return None


@contextlib.contextmanager
def _claimed(lock: Path) -> Iterator[None]:
    """Hold an exclusive lock on the file ``lock`` (created if need be) for the block; where file locks
    do not exist (no fcntl), no lock: two processes may then compile one library, harmlessly."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    with open(lock, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)  # released when the file is closed
        yield


def _build(cc: str, src: str, lib: Path) -> None:
    """Compile ``src`` into ``lib``, through a temporary file and a rename."""
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        c_file = Path(tmp, "f.c")
        c_file.write_text(src)
        tmp_lib = Path(tmp, "f.so")
        subprocess.run(
            [cc, *cflags(), str(c_file), "-o", str(tmp_lib), "-lm"],
            check=True,
            capture_output=True,
            text=True,
        )
        os.replace(tmp_lib, lib)  # atomic: concurrent processes never load half a library


def _source(fn: ca.Function) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        name = "sensorless_jit.c"
        cg = ca.CodeGenerator(name, {"with_header": False, "with_mem": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        return Path(tmp, name).read_text()


@functools.cache
def _keyed(fn: ca.Function, cc: str) -> tuple[str, str]:
    """(the C source of ``fn``, its library's file name: the hash of the source, flags and compiler)."""
    src = _source(fn)
    key = hashlib.sha256((src + "\0" + " ".join(cflags()) + "\0" + cc).encode()).hexdigest()[:24]
    return src, f"{fn.name()}_{key}.so"


def _library(fn: ca.Function, cc: str) -> tuple[str, Path]:
    """(the C source of ``fn``, the path of its library in the cache)."""
    src, name = _keyed(fn, cc)
    return src, cache_dir() / name


def is_cached(fn: ca.Function) -> bool:
    """Whether :func:`compiled` would load ``fn``'s library from the cache (no compiler run)."""
    cc = compiler()
    if os.environ.get("SENSORLESS_NO_JIT") or cc is None:
        return False
    try:
        return _library(fn, cc)[1].exists()
    except (OSError, RuntimeError):
        return False


def wanted_elsewhere(fn: ca.Function) -> bool:
    """Whether another process has asked for ``fn``'s library before (a file beside it names the first
    process that did); records this process's asking if none has. A caller that compiles only where
    that pays (design/simulate.py) compiles such a Function: its library serves the next processes."""
    cc = compiler()
    if os.environ.get("SENSORLESS_NO_JIT") or cc is None:
        return False
    try:
        mark = _library(fn, cc)[1].with_suffix(".wanted")
        if mark.exists():
            return mark.read_text().strip() != str(os.getpid())
        mark.parent.mkdir(parents=True, exist_ok=True)
        mark.write_text(str(os.getpid()))
    except (OSError, RuntimeError):
        pass
    return False


def _index_file(key: bytes, cc: str) -> Path:
    digest = hashlib.sha256(key + b"\0" + " ".join(cflags()).encode() + b"\0" + cc.encode()).hexdigest()
    return cache_dir() / "index" / digest[:32]


def indexed(key: bytes) -> ca.Function | None:
    """The compiled Function that :func:`index` recorded under ``key`` (a caller's digest of what it
    would build: its arguments and code), loaded from the cache without building it or generating its C
    (a simulation's map of 1024 loop steps: 0.06-0.09 s to build and 0.02 s to generate); None where
    nothing is recorded, its library is gone or no compiler is in use."""
    cc = compiler()
    if os.environ.get("SENSORLESS_NO_JIT") or cc is None:
        return None
    try:
        name, lib = _index_file(key, cc).read_text().split("\n")[:2]
        path = cache_dir() / lib
        return ca.external(name, str(path)) if path.is_file() and Path(lib).name == lib else None
    except (OSError, ValueError, RuntimeError):
        return None


def index(key: bytes, fn: ca.Function) -> None:
    """Record that ``key`` gives ``compiled(fn)``, for :func:`indexed`, where its library is in the cache
    (nothing for a Function left on the VM; temp file + rename: a reader never sees half a record; a
    cache that cannot be written is no error)."""
    cc = compiler()
    if os.environ.get("SENSORLESS_NO_JIT") or cc is None:
        return
    try:
        _, lib = _library(fn, cc)
        if not lib.exists():
            return
        path = _index_file(key, cc)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
        try:
            with os.fdopen(fd, "w") as fh:
                fh.write(f"{fn.name()}\n{lib.name}\n")
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except (OSError, RuntimeError):
        pass


@functools.cache
def compiled(fn: ca.Function) -> ca.Function:
    """``fn`` compiled to native code (cached on disk), or ``fn`` itself if that is not possible."""
    cc = compiler()
    if os.environ.get("SENSORLESS_NO_JIT") or cc is None:
        return fn
    try:
        src, lib = _library(fn, cc)
        d = lib.parent
        if not lib.exists():
            d.mkdir(parents=True, exist_ok=True)
            with _claimed(lib.with_suffix(".lock")):
                if not lib.exists():  # (else another process compiled it while this one waited)
                    _build(cc, src, lib)
        return ca.external(fn.name(), str(lib))
    except (OSError, subprocess.CalledProcessError, RuntimeError) as e:
        detail = getattr(e, "stderr", "") or str(e)
        warnings.warn(
            f"compiling {fn.name()} failed ({detail.strip()[:200]}); using CasADi's VM", stacklevel=2
        )
        return fn
