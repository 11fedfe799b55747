"""Fast batched evaluation of CasADi Functions over many operating points, into numpy arrays.

``Function.map(n)`` evaluates a Function at n points in one call, but converting its inputs and
outputs through casadi.DM costs as much as the evaluation itself for small Functions. This module
evaluates mapped Functions through CasADi's buffer interface straight into numpy memory, and, for
large batches, compiles the Function with the system C compiler (design/compiled.py, cached on disk);
without a working compiler it falls back to CasADi's virtual machine with identical results.
Set SENSORLESS_NO_JIT=1 to disable compilation.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable, Sequence

import casadi as ca
import numpy as np
from sensorless.design.compiled import compiled

JIT_MIN_POINTS = 4096  # below this the ~0.3 s compile does not pay off
_POINTS: dict[ca.Function, int] = {}  # points evaluated so far, per Function (evaluate_batch)
# the cores design/poles.py splits a large batch of eigenvalues over, read once (os.cpu_count reads /sys
# at every call: 50 us, 865 calls in the README servo's tune). A batch of a Function runs on one thread:
# CasADi's thread map (the same code per point, the same bits) took 1.2-1.8x the CPU of the serial map
# on the 2-core machine from 1100 to 40 000 points of the tuner's closed loop when the other core was
# free (its wall time 0.7-1.4x), 2-4x and more wall time when it was busy (benchmarks/bench_batch_threads.py);
# the README flow's target is CPU
CORES = min(4, os.cpu_count() or 1)


@functools.cache
def _shape(
    fn: ca.Function,
) -> tuple[bool, tuple[tuple[int, int, str], ...], tuple[tuple[int, int, bool, str], ...]]:
    """(whether ``fn`` is an SX Function, (rows, cols, name) of each input, (rows, cols, dense, name) of
    each output): read once per Function (a few microseconds per query through SWIG, ~20 per batch)."""
    ins = tuple((fn.size1_in(i), fn.size2_in(i), fn.name_in(i)) for i in range(fn.n_in()))
    outs = tuple(
        (fn.size1_out(j), fn.size2_out(j), fn.sparsity_out(j).is_dense(), fn.name_out(j))
        for j in range(fn.n_out())
    )
    return fn.is_a("SXFunction"), ins, outs


@functools.cache
def _compiled(fn: ca.Function) -> ca.Function:
    """Compiled copy of an SX Function (common subexpressions eliminated), or ``fn`` itself.

    Compiled through design/compiled.py, whose libraries are cached on disk by the hash of their C
    source: a process pays the compiler (~0.3 s per Function) only the first time a Function is
    ever seen, not once per process as CasADi's own ``jit`` option would."""
    if os.environ.get("SENSORLESS_NO_JIT"):
        return fn
    try:
        sx_in = fn.sx_in()
        sx_out = ca.cse([ca.densify(o) for o in fn.call(sx_in)])
        flat = ca.Function(f"{fn.name()}_jit", sx_in, sx_out, fn.name_in(), fn.name_out())
    except Exception as e:  # not an SX Function: stay on the virtual machine
        warnings.warn(f"JIT compilation unavailable ({e}); using CasADi's VM", stacklevel=3)
        return fn
    return compiled(flat)  # the VM (and a warning) where no compiler works


# A map of n points costs O(n) to build (CasADi lays out its n-fold inputs and outputs: 3.5 ms for 4096
# points of the tuner's closed loop, about what evaluating them costs), and a tune asks for ~30 sizes
# per Function, the largest once (217 maps, 0.6 s CPU of the README servo's tune). So a batch runs as
# maps of a few sizes only: chunks of CHUNK points, then the rest padded up to a bucket size (1, 2, 3
# or 4 times a power of two, at most CHUNK; the last point repeated, its results cut off). Each point
# is evaluated by the same code whatever the map it is in: the same bits.
CHUNK = 2048


@functools.lru_cache(maxsize=512)
def _mapped(fn: ca.Function, n: int) -> ca.Function:
    return fn.map(n)


def _bucket(n: int) -> int:
    """The map size of a rest of n points: 1, 2, 3 or 4 times a power of two (at most 50 % padding)."""
    p = 1
    while 3 * p < n:
        p *= 2
    return min(c for c in (p, 2 * p, 3 * p, 4 * p) if c >= n)


def _calls(n: int) -> list[tuple[int, int, int]]:
    """The map calls of a batch of n points: (first point, points, map size)."""
    out = [(k, CHUNK, CHUNK) for k in range(0, n - CHUNK + 1, CHUNK)]
    done = len(out) * CHUNK
    if n > done or n == 0:
        out.append((done, n - done, _bucket(n - done) if n > done else 0))
    return out


def settled(fn: ca.Function, jit: bool | None = None) -> bool:
    """Whether every later :func:`evaluate_batch` of ``fn`` with this ``jit`` runs the same code (the
    virtual machine or the compiled library, not one and then the other): ``jit`` given, or ``fn``
    compiled already. A caller that reuses a point's earlier results (design/discrete.py ``newton``'s
    cycles) relies on it: the two may differ in the last bits."""
    return jit is not None or _POINTS.get(fn, 0) >= JIT_MIN_POINTS


def evaluate_batch(
    fn: ca.Function, n: int, args: Sequence[np.ndarray], jit: bool | None = None
) -> list[np.ndarray]:
    """Evaluate ``fn`` at ``n`` points; returns each output as an array (n, rows, cols).

    Each argument is either one instance (broadcast to all points: shape (rows,) or (rows, 1) or a
    scalar) or all points (shape (rows, n), or (n,) for a scalar input). ``jit``: compile ``fn``
    whatever ``n`` (a caller that evaluates one Function again and again, on batches below
    JIT_MIN_POINTS: the library is compiled once per machine); None: once this process has evaluated
    ``fn`` at JIT_MIN_POINTS points in all.
    """
    if jit is None:
        # compiled once the Function has been asked for JIT_MIN_POINTS points in all, in one batch or
        # many (a search, a Newton solve, a tuner calls one Function hundreds of times on a few dozen
        # points each: on CasADi's VM 7x the CPU of the compiled library)
        _POINTS[fn] = _POINTS.get(fn, 0) + n
        jit = _POINTS[fn] >= JIT_MIN_POINTS
    is_sx, ins, outs_shape = _shape(fn)
    f = _compiled(fn) if jit and is_sx else fn  # (an External is compiled already)
    calls = _calls(n)
    total = calls[-1][0] + calls[-1][2]  # the points evaluated, padding included
    cols = []  # per input: (total, rows) contiguous (a point's values together, as CasADi maps them)
    for i, a in enumerate(args):
        rows, width, name = ins[i]
        if width != 1:
            raise ValueError(f"input {name} must be a column vector")
        a = np.asarray(a, dtype=float)
        if a.size == rows:
            cols.append(np.ascontiguousarray(np.broadcast_to(a.reshape(1, rows), (total, rows))))
            continue
        a = a.reshape(rows, n).T
        if total > n:  # the rest padded with its last point
            a = np.concatenate([a, np.repeat(a[-1:], total - n, axis=0)])
        cols.append(np.ascontiguousarray(a))
    outs = []
    for r, c, dense, name in outs_shape:
        if not dense:
            raise ValueError(f"output {name} must be dense (wrap it in casadi.densify)")
        outs.append(np.empty((total, r * c)))
    for k, _, m in calls:
        buf, run = _mapped(f, m).buffer()
        for i, a in enumerate(cols):
            buf.set_arg(i, memoryview(a[k : k + m].reshape(-1)))
        for j, o in enumerate(outs):
            buf.set_res(j, memoryview(o[k : k + m].reshape(-1)))
        run()
    res = []
    for (r, c, _, _), o in zip(outs_shape, outs, strict=True):
        # per point its (r, c) output column-major -> (n, r, c)
        res.append(o[:n].reshape(n, c, r).transpose(0, 2, 1))
    return res


def mapped(fn: ca.Function, n: int) -> ca.Function:
    """``fn.map(n)`` (serial), cached: building a map costs as much as evaluating many points."""
    return _mapped(fn, n)


def bound_call(
    fn: ca.Function, args: Sequence[np.ndarray]
) -> tuple[Callable[[], None], list[np.ndarray]] | None:
    """``fn`` bound to the memory of ``args`` through CasADi's buffer interface: (a function that
    evaluates ``fn`` on the arguments' current values, its results). Each argument is a float array the
    caller keeps and writes between calls, its input's entries in column-major order (a (rows, cols)
    input as a C-ordered (cols, rows) array); each result likewise, a new (cols, rows) array. The same
    Function on the same numbers as calling it, without converting every argument and result through
    casadi.DM (which costs more than evaluating a large compiled Function). None where an input or
    output is not dense or an argument's size is not its input's."""
    if len(args) != fn.n_in() or not all(
        fn.sparsity_in(i).is_dense() and a.dtype == float and a.flags.c_contiguous and a.size == fn.nnz_in(i)
        for i, a in enumerate(args)
    ):
        return None
    if not all(fn.sparsity_out(j).is_dense() for j in range(fn.n_out())):
        return None
    res = [np.empty((fn.size2_out(j), fn.size1_out(j))) for j in range(fn.n_out())]
    buf, run = fn.buffer()
    for i, a in enumerate(args):
        buf.set_arg(i, memoryview(a.reshape(-1)))
    for j, r in enumerate(res):
        buf.set_res(j, memoryview(r.reshape(-1)))
    held = (buf, tuple(args), tuple(res))  # the buffer reads and writes their memory: kept while it lives

    def call(held: tuple = held) -> None:
        run()

    return call, res
