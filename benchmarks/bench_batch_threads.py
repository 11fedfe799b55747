"""Benchmark: a batch of the tuner's closed loop on CasADi's serial map against its thread map.

Run:  python benchmarks/bench_batch_threads.py [--sizes 1100 4096 40000] [--repeat 20]

design/batch.py ``evaluate_batch`` runs every batch on the serial map (``fn.map(n)``); it ran batches of
1024 points and more on the thread map (``fn.map(n, "thread", cores)``), which evaluates each point by
the same compiled code (the same bits) on the machine's cores. Here both maps of the compiled
linearization of the ``piippo2008`` preset's speed-dependent law (tuning/ipmsm_adaptive/model.py, the
Function the tuner's searches and the pointwise bound evaluate) run on the same points as evaluate_batch
runs them (a buffer per call, the arguments and results bound to numpy memory), alternately: per size
the median CPU (user + sys of this process, the threads included) and wall time per call, and the CPU
ratio thread / serial.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import casadi as ca
import numpy as np
from sensorless.design.batch import CORES, _compiled, _mapped
from sensorless.design.drive import load_drive
from sensorless.tuning.family import tunable_for


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _call(m: ca.Function, cols: list[np.ndarray], outs: list[np.ndarray]) -> None:
    """One batch as evaluate_batch runs it: a buffer on the map, the arguments and results bound."""
    buf, run = m.buffer()
    for i, c in enumerate(cols):
        buf.set_arg(i, memoryview(c.reshape(-1)))
    for j, o in enumerate(outs):
        buf.set_res(j, memoryview(o.reshape(-1)))
    run()


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1100, 2048, 4096, 16384, 40000])
    ap.add_argument("--repeat", type=int, default=20)
    a = ap.parse_args()
    drive = load_drive("piippo2008")
    tunable = tunable_for(drive, "speed-dependent")
    pw = tunable.build(drive, tunable.settings(drive), None).pointwise()
    fn = _compiled(pw.linearization)  # the compiled library, as evaluate_batch runs it
    print(f"{fn.name()}: serial map against thread map ({CORES} threads), medians of {a.repeat} calls")
    head = ("points", "serial CPU", "thread CPU", "ratio", "serial wall", "thread wall")
    print(" ".join(f"{h:>{k}}" for h, k in zip(head, (7, 11, 11, 6, 12, 12), strict=True)))
    for n in a.sizes:
        w = np.linspace(0.05, 1.0, n) * drive.w_base
        P = pw.make_points(w, np.zeros(n), pw.nominal_estimate)
        phi = np.zeros((6, n))
        phi[0], phi[4], phi[5] = drive.estimate.R_s, w, drive.observer.alpha_fo
        x = np.vstack([np.full(n, drive.estimate.psi_pm), np.zeros(n), np.ones(n), w])
        cols = [np.ascontiguousarray(v.T) for v in (phi, x, P)]
        outs = [np.empty((n, fn.size1_out(j) * fn.size2_out(j))) for j in range(fn.n_out())]
        maps = {1: _mapped(fn, n), CORES: fn.map(n, "thread", CORES)}
        for m in maps.values():
            _call(m, cols, outs)  # (first call: its set-up)
        cpu: dict[int, list[float]] = {k: [] for k in maps}
        wall: dict[int, list[float]] = {k: [] for k in maps}
        for _ in range(a.repeat):
            for k, m in maps.items():  # alternately: a busy machine slows both alike
                c0, w0 = _cpu(), time.perf_counter()
                _call(m, cols, outs)
                cpu[k].append(_cpu() - c0)
                wall[k].append(time.perf_counter() - w0)
        cs, ct = statistics.median(cpu[1]), statistics.median(cpu[CORES])
        ws, wt = statistics.median(wall[1]), statistics.median(wall[CORES])
        ratio = ct / cs if cs else float("nan")
        print(
            f"{n:7d} {1e3 * cs:9.2f}ms {1e3 * ct:9.2f}ms {ratio:6.2f} {1e3 * ws:10.2f}ms {1e3 * wt:10.2f}ms"
        )


if __name__ == "__main__":
    main()
