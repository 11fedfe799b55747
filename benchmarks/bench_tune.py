"""Benchmark: law-(16) tuning NLP vs a brute-force grid over (lambda', omega_lambda), same envelope;
and the whole schedule tuning (global phase, pointwise bound, NLP if needed, dense re-verification).

Both law-(16) searches use the same envelope (the preset's [tuning] grid) for the gains that maximize
the worst damping. The grid search is the fastest brute force the toolbox offers: all gain pairs x
envelope points linearized in one Function.map call, eigenvalues in one batched numpy call; the NLP
starts from the drive file's gains. Prints median times of repeated runs in this process, both
optima (worst damping on the envelope grid, by eigenvalues) and the time ratio. Then
``tune(drive, "schedule")`` end to end (its speed-dependent seed included), first call (solver builds, JIT)
and warm, with the schedule's dense worst damping against the pointwise bound's and the speed-dependent law's.

    python benchmarks/bench_tune.py [--pairs 30] [--repeat 5] [--no-schedule]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.ipmsm_adaptive.linearize import drive_arguments
from sensorless.design.ipmsm_adaptive.operating_point import loop_parameters, rotor_frame_loop
from sensorless.design.poles import worst_damping
from sensorless.design.rotor_frame import start_function
from sensorless.tuning import nlp
from sensorless.tuning.family import tunable_for
from sensorless.tuning.model import poles
from sensorless.tuning.tune import _candidates, tune


def grid_search(drive, W, T, lp, wl, fn):
    """Worst damping over the envelope for every (lambda', omega_lambda) pair; the best pair."""
    P1, P2 = np.meshgrid(lp, wl)
    P1, P2 = P1.ravel(), P2.ravel()
    n, N = P1.size, W.size
    _, args = drive_arguments(drive, "speed")
    plant, p = loop_parameters(dict(args, gain=np.vstack([np.repeat(P1, N), np.repeat(P2, N)])), n * N)
    out = fn(w=np.tile(W, n)[None], torque=np.tile(T, n)[None], plant=plant, p=p)
    A = np.asarray(out["A"]).reshape(4, n * N, 4).transpose(1, 0, 2)
    ev = np.linalg.eigvals(A)
    worst = (-ev.real / np.abs(ev)).min(axis=1).reshape(n, N).min(axis=1)
    k = int(np.argmax(worst))
    return worst[k], (P1[k], P2[k])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=30, help="grid points per gain parameter (>= 30: 900 pairs)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-schedule", action="store_true", help="skip the end-to-end schedule timing")
    a = ap.parse_args()
    drive = load_drive("piippo2008")
    # law (16) as the paper tunes it (alpha_fo fixed, no angle-lag bound: the defaults of a user's drive
    # tune alpha_fo and hold the lag), so both searches are over the same (lambda', omega_lambda)
    law = drive.tuning.law
    settings = dataclasses.replace(
        drive.tuning, law=dataclasses.replace(law, tune_alpha_fo=False, hold_lag=False)
    )
    wb, R = drive.base.w, drive.estimate.R_s
    W, T = settings.envelope.grid()
    model = tunable_for(drive, "speed-dependent").build(drive, settings, None)
    lp = np.linspace(model.lower[0], model.upper[0], a.pairs)
    wl = np.linspace(model.lower[1], 3 * wb, a.pairs)
    law, _ = drive_arguments(drive, "speed")
    fn = start_function(rotor_frame_loop(law, False)).map(W.size * a.pairs**2)  # built once, like the NLP

    def run_nlp():
        base_p, _ = poles(model, model.theta0, model.make_points(W, T, model.nominal_estimate))
        scale = float(np.abs(base_p).max())
        cand = _candidates(model, settings, W, T, wb, scale)
        return nlp.solve(model, cand, model.theta0, scale)

    t0 = time.perf_counter()
    run_nlp()  # first call builds the IPOPT solver (derivatives): reported separately
    first = time.perf_counter() - t0
    t_nlp, t_grid = [], []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        sol = run_nlp()
        t_nlp.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        best_grid, pair = grid_search(drive, W, T, lp, wl, fn)
        t_grid.append(time.perf_counter() - t0)
    p, _ = poles(model, sol.theta, model.make_points(W, T, model.nominal_estimate))
    best_nlp = float(worst_damping(p).min())
    mn, mg = statistics.median(t_nlp), statistics.median(t_grid)
    print(f"envelope: {W.size} points; brute force: {a.pairs**2} (lambda', omega_lambda) pairs")
    print(
        f"NLP   (IPOPT, exchange method): median {mn * 1e3:8.1f} ms  "
        f"(first call incl. solver build {first * 1e3:.0f} ms)"
    )
    print(f"grid  (Function.map + eig)    : median {mg * 1e3:8.1f} ms")
    print(
        f"NLP optimum : worst damping {best_nlp:.5f} at lambda' = {sol.theta[0] / R:.3f} R_s_hat, "
        f"omega_lambda = {sol.theta[1] / wb:.4f} p.u."
    )
    print(
        f"grid optimum: worst damping {best_grid:.5f} at lambda' = {pair[0] / R:.3f} R_s_hat, "
        f"omega_lambda = {pair[1] / wb:.4f} p.u."
    )
    print(
        f"ratio grid/NLP time: {mg / mn:.1f}x (first NLP call: {mg / first:.1f}x); "
        f"NLP - grid optimum: {best_nlp - best_grid:+.5f}"
    )
    if a.no_schedule:
        return
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        r = tune(drive, "schedule", settings)
        times.append(time.perf_counter() - t0)
    s = r.table.summary
    b = s["bound"]
    print(
        f"schedule (tune end to end, its seed, global phase, bound): first call {times[0]:.1f} s, "
        f"warm {times[1]:.1f} s"
    )
    print(
        f"dense worst damping: schedule {s['worst_damping']:.5f}, "
        f"speed-dependent {s['seed']['worst_damping']:.5f}, "
        f"drive file {s['baseline_worst_damping']:.5f}; pointwise bound {b['worst_damping']:.5f} at "
        f"{b['worst_at_w_m_pu']:+.3f} p.u. (decay >= {b['floor_1_s']:.4g} 1/s): "
        f"schedule {b['gap']:.5f} below, speed-dependent {b['gap_seed']:.5f} below"
    )


if __name__ == "__main__":
    main()
