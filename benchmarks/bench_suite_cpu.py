"""Benchmark: the test suite's CPU seconds per file and per test phase, and the compiler runs behind them.

On a shared machine the suite's wall time says little (other processes take the cores); the CPU seconds
of each test phase do, and they are what the wall time on 2 cores is made of. This file is a pytest
plugin: loaded with ``-p bench_suite_cpu`` (``benchmarks`` on PYTHONPATH), each pytest-xdist worker
appends one JSON line per test phase (setup, call, teardown) to $SUITE_CPU_OUT: its CPU seconds, this
process's (``self``: every thread) and its waited-for children's (``children``: compilers, forked figure
renderers, subprocesses), its worker and its wall-clock span; and one line per compiled library
(design/compiled.py) to $SUITE_CPU_OUT.cc. Collection and worker start-up are in no phase. Run as

    SENSORLESS_CACHE=$(mktemp -d) SUITE_CPU_OUT=cpu.jsonl PYTHONPATH=benchmarks \\
        python -m pytest -p bench_suite_cpu
    python benchmarks/bench_suite_cpu.py cpu.jsonl [BEFORE.jsonl]

(an empty cache: the compiles a fresh clone pays). The second command prints the totals, each worker's
CPU and span, the CPU per file (beside BEFORE's, if given) and the longest phases.
"""

from __future__ import annotations

import collections
import json
import os
import resource
import sys
import time

import pytest

OUT_ENV = "SUITE_CPU_OUT"


def _cpu() -> tuple[float, float]:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime


def _write(path: str, row: dict) -> None:
    with open(path, "a") as f:  # one short line per write: the workers' lines do not interleave
        f.write(json.dumps(row) + "\n")


def _phase(name: str):
    @pytest.hookimpl(hookwrapper=True)
    def hook(item):
        s0, c0 = _cpu()
        t0 = time.time()
        yield
        s1, c1 = _cpu()
        if out := os.environ.get(OUT_ENV):
            worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
            row = {"id": item.nodeid, "phase": name, "self": s1 - s0, "children": c1 - c0}
            _write(out, {**row, "worker": worker, "t0": t0, "t1": time.time()})

    return hook


pytest_runtest_setup = _phase("setup")
pytest_runtest_call = _phase("call")
pytest_runtest_teardown = _phase("teardown")


def pytest_configure(config):
    """Log each library the compiler builds (its CPU seconds, the size of its C source)."""
    if not (out := os.environ.get(OUT_ENV)):
        return
    from sensorless.design import compiled

    build = compiled._build

    def logged(cc, src, lib):
        c0 = _cpu()[1]
        try:
            return build(cc, src, lib)
        finally:
            worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
            _write(out + ".cc", {"lib": lib.name, "cpu": _cpu()[1] - c0, "bytes": len(src), "worker": worker})

    compiled._build = logged


def _files(rows: list[dict]) -> collections.Counter:
    per = collections.Counter()
    for r in rows:
        per[r["id"].split("::")[0]] += r["self"] + r["children"]
    return per


def summary(path: str, before: str | None = None, top: int = 40) -> None:
    rows = [json.loads(line) for line in open(path)]
    print(f"test CPU {sum(r['self'] + r['children'] for r in rows):.1f} s over {len(rows)} phases")
    print(f"  of it children {sum(r['children'] for r in rows):.1f} s")
    start = min(r["t0"] for r in rows)
    for w in sorted({r["worker"] for r in rows}):
        mine = [r for r in rows if r["worker"] == w]
        cpu = sum(r["self"] + r["children"] for r in mine)
        span = max(r["t1"] for r in mine) - start
        print(f"  worker {w}: CPU {cpu:.1f} s, last phase ends {span:.0f} s after the first starts")
    if os.path.exists(path + ".cc"):
        cc = [json.loads(line) for line in open(path + ".cc")]
        print(f"compiled libraries {len(cc)}, {sum(c['cpu'] for c in cc):.1f} s of compiler CPU")
    per = _files(rows)
    old = _files([json.loads(line) for line in open(before)]) if before else None
    print("--- CPU per file" + (f" (before: {before})" if old is not None else ""))
    for f, c in per.most_common(top):
        print(f"  {old[f]:7.1f} -> {c:7.1f}  {f}" if old is not None else f"  {c:7.1f}  {f}")
    print("--- longest phases")
    for r in sorted(rows, key=lambda r: -(r["self"] + r["children"]))[:20]:
        print(f"  {r['self'] + r['children']:7.1f} (children {r['children']:5.1f}) {r['phase']:8s} {r['id']}")


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    summary(*sys.argv[1:])
