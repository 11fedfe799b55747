"""Benchmark: batched linearized-closed-loop sweep vs a plain numpy loop over the paper's closed form.

Run:  python benchmarks/bench_sweep.py [--points N]

Both paths compute, per operating point (speed x torque, the ``piippo2008`` drive of Piippo, Hinkkanen,
Luomi (2008), speed-dependent gain (16)), the MTPA current, the 4th-order closed loop of eqs. (11)-(14)
and its poles. The batched path is ``sensorless.design.ipmsm_adaptive.linearize.linearize`` (automatic
Jacobians, Function.map, batched poles); the baseline is a Python loop calling numpy on the closed form
typed from the paper. Timings are medians
of repeated runs in the same process; the poles of both paths are compared as a sanity check.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.ipmsm_adaptive.linearize import linearize
from sensorless.design.poles import sort_poles

Jm = np.array([[0.0, -1.0], [1.0, 0.0]])


def loop_closed_form(drive, w_all, T_all):
    """Poles by the paper's closed form, one operating point at a time (the yardstick)."""
    m = drive.motor
    R, Ld, Lq, psi, p = m.R_s, m.L_d, m.L_q, m.psi_pm, m.p
    L = np.diag([Ld, Lq])
    Li = np.linalg.inv(L)
    psi_v = np.array([psi, 0.0])
    a = Lq - Ld
    g = drive.gain("speed")
    alpha = drive.observer.alpha_fo
    kp, ki = 2 * alpha / psi, alpha**2 / psi  # eq. (10)
    out = np.empty((w_all.size, 4), complex)
    for k, (w0, T) in enumerate(zip(w_all, T_all, strict=True)):
        i_q = T / (1.5 * p * psi)  # MTPA by Newton, as in the package, but scalar numpy
        for _ in range(8):
            i_d = -2 * a * i_q**2 / (psi + np.sqrt(psi**2 + 4 * a**2 * i_q**2))
            di_d = 2 * a * i_q / (2 * a * i_d - psi)
            i_q -= (1.5 * p * i_q * (psi - a * i_d) - T) / (1.5 * p * (psi - a * i_d - a * i_q * di_d))
        i_d = -2 * a * i_q**2 / (psi + np.sqrt(psi**2 + 4 * a**2 * i_q**2))
        i0 = np.array([i_d, i_q])
        r = min(abs(w0) / g.w_lambda, 1.0)  # eq. (16)
        lam = g.lambda_p * r * np.eye(2) + g.lambda_p * np.clip(w0 / g.w_lambda, -1, 1) * Jm
        A1 = -R * Li - w0 * Li @ Jm @ L - Li @ lam  # eq. (11)
        B1 = Jm @ i0 - Li @ Jm @ L @ i0 - Li @ Jm @ psi_v
        A2 = w0 * (Li @ Jm @ L @ Jm @ i0 + i0 + Li @ psi_v)
        A = np.zeros((3, 3))
        A[:2, :2], A[:2, 2] = A1, A2
        B = np.append(B1, 1.0)[:, None]
        C = np.array([[0.0, Lq, 0.0]])
        A_cl = np.block([[A + kp * B @ C, ki * B], [C, np.zeros((1, 1))]])  # (12) + (14)
        out[k] = np.linalg.eigvals(A_cl)
    return out


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20000, help="operating points (default 20000)")
    ap.add_argument("--loop-points", type=int, default=2000, help="points for the slow loop")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    drive = load_drive("piippo2008")
    n_T = 20
    n_w = max(args.points // n_T, 1)
    w = np.linspace(-1, 1, n_w) * drive.base.w
    T = np.linspace(-1.5, 1.5, n_T) * drive.T_N
    W, TT = np.meshgrid(w, T, indexing="ij")
    n = W.size

    linearize(drive, W, TT, gain="speed")  # warm-up: builds and compiles the Functions once
    t_batch = median_time(lambda: linearize(drive, W, TT, gain="speed"), args.repeats)

    idx = np.linspace(0, n - 1, min(args.loop_points, n)).astype(int)
    w_s, T_s = W.ravel()[idx], TT.ravel()[idx]
    t_loop = median_time(lambda: loop_closed_form(drive, w_s, T_s), max(3, args.repeats // 2))

    batch_pps = n / t_batch
    loop_pps = idx.size / t_loop
    s = linearize(drive, W, TT, gain="speed")
    ref = sort_poles(loop_closed_form(drive, w_s, T_s))
    diff = np.abs(s.poles[idx] - ref).max() / np.abs(ref).max()
    print(f"operating points: {n} ({n_w} speeds x {n_T} torques), loop on {idx.size} of them")
    print(
        f"batched (Jacobians + Function.map + batched poles): {batch_pps:12.0f} points/s "
        f"(median {t_batch * 1e3:.1f} ms for {n})"
    )
    print(
        f"numpy loop over the closed form (11)-(14):          {loop_pps:12.0f} points/s "
        f"(median {t_loop * 1e3:.1f} ms for {idx.size})"
    )
    print(f"ratio batched / loop: {batch_pps / loop_pps:.1f}x   (targets: >= 2e5 points/s, >= 30x)")
    print(f"max relative pole difference between the paths: {diff:.2e}")


if __name__ == "__main__":
    main()
