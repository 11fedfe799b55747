"""Tuning pipeline of the gain law ``constant`` of the reduced-order observer: the gains g and Gamma.

De Angelo, Bossio, Solsona, Garcia, Valla (2006), eqs. (9)-(10).

Objective. The paper's gains already give damping 1 at every envelope point (all poles real), so
maximizing the worst damping is degenerate here: the tuner maximizes the worst **decay rate**
(slowest pole) of the observer's error dynamics over the envelope (speeds x load torques, the
drive's ``[envelope]``), subject to a worst damping >= ``min_damping`` (default 1/sqrt(2)) and a
limit on the noise of the estimates: the RMS of the position (and, if given, speed) estimate caused
by the drive's current-sensor noise (``[control] i_noise``), from the same discrete linearization
(design/pmac_reduced_order/linearize.py ``analyze(noise=True)``, design/noise.py); default: the
position noise at most NOISE_FACTOR (2) times that of the drive file's gains, worst over the
envelope grid (``--max-noise`` sets absolute limits instead). The noise grows with g (e_hat carries the
current noise times g L): the limit sets g, and the damping floor then sets Gamma. The box
(0.01x .. 100x the drive's g; Gamma from critical damping at the least g to c = g^2 at the largest,
:func:`gamma_box`) only bounds the search.

Formulation (a sound simpler one than the sector NLP of tuning/nlp.py, for two parameters):

1. Closed form. For a sinusoidal EMF the continuous error dynamics are speed- and
   load-independent (docs/families/pmac_reduced_order.md, hand derivation):
   det(sI - A) = (s + g)(s^2 + g s + c), c = Gamma (Phi_1/J)^2. The two roots of the quadratic sum
   to -g, so no gains make every pole decay faster than g/2, and g/2 is reached exactly when the
   quadratic is critically damped or complex, c >= g^2/4 (damping g/(2 sqrt(c)) there). The least
   noisy such gains (least Gamma) are c = g^2/4: a double pole at -g/2, damping 1. With Gamma <=
   Gamma_max and c_max < g^2/4 the roots are real and the slowest, g/2 - sqrt(g^2/4 - c_max), grows
   as g falls to 2 sqrt(c_max). Hence g* = min(g_max, 2 sqrt(c_max)), Gamma* = (g* J / (2 Phi_1))^2.
2. Refinement on what runs. EMF harmonics (Floquet exponents) and sampling move the poles, and a
   double pole splits under any perturbation. A deterministic compass search in (ln g, ln Gamma)
   (directions along g, along Gamma and along the critical curve Gamma ~ g^2) maximizes the worst
   decay rate of the **discrete-time** poles at the drive's sampling period and discretization
   (design/pmac_reduced_order/linearize.py ``analyze``: the one-step map's Jacobian on the observer's
   own orbit) on the envelope grid, feasible points (damping >= min_damping) first. It starts from the better
   of the closed form and the drive's gains, so it never returns worse gains than the drive's on
   that grid (when they are inside the bounds).
3. Re-verification on a grid ``dense_factor`` (>= 4) times denser in speed (within each direction)
   and in load, discrete poles at the real sampling period; the table reports that grid only.

Modules: settings.py (settings, grids, search box, closed form), objective.py (poles, noise, rank,
compass search), result.py (summary and gain table), this one (the pipeline).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.tuning.family import TuningError
from sensorless.tuning.pmac_reduced_order.objective import (
    compass_search,
    drive_check,
    drive_shortfall,
    figures,
    rank,
)
from sensorless.tuning.pmac_reduced_order.result import ConstantGainResult, gain_table
from sensorless.tuning.pmac_reduced_order.settings import (
    NOISE_FACTOR,
    ConstantGainSettings,
    closed_form,
    default_settings,
    grid,
    limits_text,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

DENSE_TRIES = 6  # candidates re-verified densely at most
DENSE_SPREAD = 0.1  # least distance in ln g or ln Gamma between two of them


def tune_constant_gains(
    drive: PmacDrive, settings: Any, progress: Callable[[str], None] | None = None
) -> ConstantGainResult:
    """Tune g and Gamma of a drive of this family (this module's docstring)."""
    t0 = time.perf_counter()
    st: ConstantGainSettings = settings or default_settings(drive)
    st.check(drive.file)
    say = progress or (lambda s: None)
    g0, G0 = float(drive.observer.g), float(drive.observer.Gamma)
    n, T = grid(st)
    base_grid = figures(drive, g0, G0, n, T)
    if st.max_noise is None:
        p0 = float(base_grid.worst_noise()[0])
        st = dataclasses.replace(st, max_noise=(("position", NOISE_FACTOR * p0),) if np.isfinite(p0) else ())
        say(
            f"noise limit: position <= {math.degrees(NOISE_FACTOR * p0):.4g} deg el. rms ({NOISE_FACTOR:g} x "
            "the drive file's gains)"
        )
    lim = st.noise_limits()
    # the noise grows about in proportion to g: the closed form starts at the g the limit allows
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.nanmin(np.where(np.isfinite(lim), lim / base_grid.worst_noise(), np.inf))
    g_cap = st.g_max if not np.isfinite(ratio) or ratio <= 0 else min(st.g_max, g0 * ratio)
    gc, Gc = closed_form(drive, g_cap, st.Gamma_max)
    lower = np.log([st.g_min, st.Gamma_min])
    upper = np.log([st.g_max, st.Gamma_max])
    say(
        f"constant: g, Gamma over {n.size} envelope points; closed form (sinusoidal, continuous): "
        f"g = {gc:.5g} 1/s, Gamma = {Gc:.5g} A^2 s^2"
    )

    # the whole sampled drive (feedforward off and on) must stay stable where the drive file's gains give it
    # a fixed point (objective.py, FEEDFORWARD)
    if st.whole_drive:
        say("the whole sampled drive's constraint: its poles at the drive file's gains over +-T_N")
    check = drive_check(drive, g0, G0) if st.whole_drive else None

    def evaluate(x: np.ndarray) -> tuple:
        score = rank(figures(drive, math.exp(x[0]), math.exp(x[1]), n, T), st.min_damping, lim)
        say(
            f"  g = {math.exp(x[0]):9.5g} 1/s, Gamma = {math.exp(x[1]):11.5g}: slowest decay "
            f"{score[1]:9.4g} 1/s, worst damping {score[2]:.4f}{'' if score[0] else ' (infeasible)'}"
        )
        return score

    whole: dict[tuple[float, float], str] = {}  # (ln g, ln Gamma) -> the whole drive's shortfall ('': none)

    def drive_ok(x: tuple[float, float] | np.ndarray) -> bool:
        key = (round(float(x[0]), 12), round(float(x[1]), 12))
        if check is None:
            return True
        if key not in whole:
            whole[key] = drive_shortfall(drive, math.exp(key[0]), math.exp(key[1]), check)
            if whole[key]:
                say(f"  g = {math.exp(key[0]):9.5g} 1/s, Gamma = {math.exp(key[1]):11.5g}: {whole[key]}")
        return not whole[key]

    def refine(x: np.ndarray, score: tuple) -> tuple:
        # the whole drive's constraint (1-2 s) only where the observer's poles would improve the search
        return score if not score[0] or drive_ok(x) else (False, *score[1:])

    starts = [np.log([gc, Gc])]
    if G0 > 0:
        starts.append(np.log([g0, G0]))
    say("compass search on the discrete-time poles at the sampling period")
    _, best, seen = compass_search(evaluate, starts, lower, upper, refine)
    if not best[0]:
        raise TuningError(
            f"{drive.file}: the envelope is infeasible: no g, Gamma within the bounds give damping >= "
            f"{st.min_damping:.3f}, stable discrete poles and noise within {limits_text(st)} at every point"
        )
    say(f"re-verifying on the {st.dense_factor}x denser grid")
    nd, Td = grid(st, st.dense_factor)
    dense0 = figures(drive, g0, G0, nd, Td)

    # The grid optimum sits on the damping floor, which the poles may cross between grid speeds:
    # verify the best candidates densely, in grid-rank order, and keep the first feasible one.
    ranked = sorted(seen.items(), key=lambda kv: kv[1], reverse=True)
    chosen, tried = None, []
    # distinct candidates (DENSE_SPREAD apart in ln g or ln Gamma): the search's last steps cluster on one
    # ridge of the grid, which the dense grid may reject as a whole (EMF harmonics at speeds between the
    # grid's, the whole drive's margin)
    picks: list[tuple[float, float]] = []
    looked = 0  # candidates checked on the whole drive here (1-2 s each): at most 3 DENSE_TRIES
    for key, r in list(ranked):
        if not r[0] or len(picks) == DENSE_TRIES or looked == 3 * DENSE_TRIES:
            break
        if any(max(abs(key[0] - k[0]), abs(key[1] - k[1])) < DENSE_SPREAD for k in picks):
            continue
        looked += 1
        if not drive_ok(key):  # (held already where the search refined it)
            continue
        picks.append(key)
        f = figures(drive, math.exp(key[0]), math.exp(key[1]), nd, Td)
        tried.append((key, f))
        if rank(f, st.min_damping, lim)[0]:
            chosen = (key, f)
            break
        if rank(f, st.min_damping)[0]:
            # too noisy between the grid points only: the noise grows in proportion to g, so scale g
            # to the limit and Gamma with g^2 (the same damping of the quadratic factor)
            over = float(np.nanmax(np.where(np.isfinite(lim), f.worst_noise() / lim, 0.0)))
            # (1 % margin: the discrete noise figure moves by ~0.2 % with the simulated settling)
            k2 = (key[0] - math.log(over * 1.01), key[1] - 2 * math.log(over * 1.01))
            f2 = figures(drive, math.exp(k2[0]), math.exp(k2[1]), nd, Td)
            tried.append((k2, f2))
            if rank(f2, st.min_damping, lim)[0] and drive_ok(k2):
                say(
                    f"  g = {math.exp(key[0]):.5g}: {100 * (over - 1):.2g} % too noisy between the grid "
                    f"points; scaled to g = {math.exp(k2[0]):.5g}, Gamma = {math.exp(k2[1]):.5g}"
                )
                seen[k2] = rank(f2, st.min_damping, lim)
                ranked.insert(0, (k2, seen[k2]))
                chosen = (k2, f2)
                break
        say(
            f"  g = {math.exp(key[0]):.5g}, Gamma = {math.exp(key[1]):.5g}: damping {f.worst()[0]:.4f}, "
            f"slowest decay {f.worst()[1]:.4g} 1/s on the dense grid: below the floor, unstable, too noisy "
            "between the grid points or the whole drive unstable; next candidate"
        )
    if chosen is None:
        if not rank(dense0, st.min_damping, lim)[0]:
            raise TuningError(
                f"{drive.file}: neither the {len(tried)} best tuned gains nor the drive's meet damping >= "
                f"{st.min_damping:.3f} on the dense grid"
            )
        note = (
            f"kept the drive's gains: the {len(tried)} best distinct tuned candidates violate the damping "
            "floor, the noise limit or the whole drive's stability between the optimization grid points"
        )
        chosen = ((math.log(g0), math.log(G0)), dense0)
    else:
        k = [key for key, _ in ranked].index(chosen[0])
        note = f"candidate {k + 1} of {len(ranked)} by grid rank ({len(tried)} verified densely)"
    say(note)
    (lg, lG), dense = chosen
    if dense is dense0:
        g, Gamma = g0, G0
    else:
        # exp(ln(bound)) may exceed the bound by round-off: clip, and re-verify what is reported
        g = float(np.clip(math.exp(lg), st.g_min, st.g_max))
        Gamma = float(np.clip(math.exp(lG), st.Gamma_min, st.Gamma_max))
        if (g, Gamma) != (math.exp(lg), math.exp(lG)):
            dense = figures(drive, g, Gamma, nd, Td)
    on_grid = figures(drive, g, Gamma, n, T)
    evals = len(seen)
    seconds = time.perf_counter() - t0
    result = ConstantGainResult(
        law="constant",
        g=g,
        Gamma=Gamma,
        g0=g0,
        Gamma0=G0,
        closed_form=(gc, Gc),
        dense=dense,
        dense_baseline=dense0,
        grid=on_grid,
        evaluations=evals,
        note=note,
        settings=st,
        table=None,  # type: ignore[arg-type]
        seconds=seconds,
    )
    return dataclasses.replace(result, table=gain_table(drive, result))
