"""Benchmark: Monte-Carlo of the linearized closed loop (batched draws on the engine) against a plain
loop over draws, and the time-domain draws' scaling from 1 to 2 local Dask workers.

Run:  python benchmarks/bench_montecarlo.py [--draws N] [--loop-draws M] [--time-draws K]

The drive is the preset ``piippo2008`` (Piippo, Hinkkanen, Luomi (2008)) with its default envelope
(|w_m| in [0.05, 1] p.u., 20 speeds per direction x {-T_N, 0, T_N}: 120 points), spreads R_s, L_d,
L_q 10 %, psi_pm 5 %, J 30 % on the motor and R_s 10 % on the estimate.

1. Linear: ``reports.montecarlo.run`` of N draws (default 10,000) on a local cluster of 2 worker
   processes (start-up timed apart) and on the synchronous engine, against a plain Python loop over
   M draws (default 200) each calling the family's per-drive ``linearize``, extrapolated to N (the
   loop over all 10,000 takes minutes). Medians of ``--repeats`` runs. The two paths' worst damping
   per draw are compared on the loop's draws.
2. Time domain: K draws (default 24) on the generic scenarios, 1 worker against 2 (every worker
   warmed up with one simulation first, so the simulation loop's compilation is not timed).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from sensorless.design import montecarlo as mc
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.reports import montecarlo as rmc
from sensorless.reports.engine import SYNCHRONOUS, Engine

SPREAD = "R_s=10%,L_d=10%,L_q=10%,psi_pm=5%,J=30%"
ESTIMATE = "R_s=10%"


def worker_cpu(engine) -> float:
    """CPU seconds used so far by this process, or by all the engine's workers."""
    if engine.client is None:
        return time.process_time()
    return sum(engine.client.run(time.process_time).values())


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=10000)
    ap.add_argument("--skip-linear", action="store_true", help="only the time-domain part")
    ap.add_argument("--skip-time", action="store_true", help="only the linear part")
    ap.add_argument("--loop-draws", type=int, default=200)
    ap.add_argument("--time-draws", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    d = load_drive("piippo2008")
    fam = family_of(d)
    g = fam.gains(d)
    params = fam.montecarlo.parameters(d)
    plant = mc.parse_spreads(SPREAD, "--spread", params, False)
    est = mc.parse_spreads(ESTIMATE, "--estimate-error", params, True)
    w, T = rmc.envelope(d)
    n = args.draws

    def run(engine, k=0, samples=n):
        return rmc.run(d, g, params, plant, est, samples, 1, k, 0.2, engine)

    if not args.skip_linear:
        with Engine(SYNCHRONOUS, quiet=True) as sync:
            run(sync, samples=300)  # warm-up: builds and compiles the Functions once
            c0 = worker_cpu(sync)
            t_sync = median_time(lambda: run(sync), args.repeats)
            cpu_sync = (worker_cpu(sync) - c0) / args.repeats
            res = run(sync)
        t0 = time.perf_counter()
        with Engine(None, workers=2, quiet=True) as two:
            t_start = time.perf_counter() - t0
            run(two, samples=600)  # warm-up on both workers
            c0 = worker_cpu(two)
            t_two = median_time(lambda: run(two), args.repeats)
            cpu_two = (worker_cpu(two) - c0) / args.repeats
            res2 = run(two)
        assert np.array_equal(res.worst, res2.worst)

        draws = res.draws
        m = min(args.loop_draws, n)

        def loop():
            out = np.empty(m)
            for i in range(m):
                di = fam.montecarlo.perturbed(d, dict(zip(draws.names, draws.plant[i], strict=True)), {})
                wd = fam.linearize(di, g, w, T, estimate=draws.estimate[i, :4]).worst_damping
                out[i] = -np.inf if np.isnan(wd).any() else wd.min()
            return out

        ref = loop()
        c0 = time.process_time()
        t_loop = median_time(loop, 1) * n / m
        cpu_loop = (time.process_time() - c0) * n / m
        same = np.isclose(ref, res.worst[:m], rtol=1e-6, atol=1e-9) | (
            np.isinf(ref) & np.isinf(res.worst[:m])
        )
        print(f"linear Monte-Carlo: {n} draws x {w.size} operating points ({n * w.size} linearizations)")
        print(
            f"  local cluster, 2 workers: {t_two:7.2f} s wall (median; start-up {t_start:.1f} s apart), "
            f"{cpu_two:.2f} CPU-s in the workers"
        )
        print(f"  synchronous, 1 process:   {t_sync:7.2f} s wall (median), {cpu_sync:.2f} CPU-s")
        print(f"  plain loop over draws:    {t_loop:7.2f} s wall, {cpu_loop:.2f} CPU-s (from {m} draws)")
        print(f"  ratio loop / synchronous in CPU-s: {cpu_loop / cpu_sync:.1f}x")
        print(f"  ratio loop / 2 workers: {t_loop / t_two:.1f}x   (target: < 10 s on 2 cores)")
        print(f"  worst damping equal to the loop's on {same.sum()} of {m} draws")
        print(f"  yield {res.summary['yield']['damping']['value']:.4f}")

    if args.skip_time:
        return
    k = args.time_draws
    times, cpus, per_worker = {}, {}, {}
    for workers in (1, 2):
        with Engine(None, workers=workers, quiet=True) as eng:
            # warm-up on every worker: the simulation loop compiled (or loaded) once per process
            eng.client.run(rmc.time_task, d, g, {}, {}, rmc.time_scenarios(d))
            run(eng, samples=1)
            c0 = worker_cpu(eng)
            w0 = eng.client.run(time.process_time)
            # K draws in the time domain (their linear part, K draws in one chunk, is negligible)
            times[workers] = median_time(lambda eng=eng: run(eng, k=k, samples=k), 1)
            cpus[workers] = worker_cpu(eng) - c0
            per_worker[workers] = [v - w0[a] for a, v in eng.client.run(time.process_time).items()]
    print(f"time domain: {k} draws x {len(rmc.time_scenarios(d))} generic scenarios")
    print(
        f"  1 worker: {times[1]:.2f} s wall ({cpus[1]:.2f} CPU-s), 2 workers: {times[2]:.2f} s wall "
        f"({cpus[2]:.2f} CPU-s), speed-up {times[1] / times[2]:.2f}x"
    )
    busiest = max(per_worker[2])
    print(
        f"  2 workers' CPU-s: {', '.join(f'{c:.2f}' for c in per_worker[2])}; speed-up with a core per "
        f"worker (1-worker CPU-s / busiest worker's, no other load): {cpus[1] / busiest:.2f}x"
    )
    print("  (target >= 1.8x; on a machine shared with other work the wall speed-up measures the load)")


if __name__ == "__main__":
    main()
