"""Gain tuning end to end: envelope -> global phase -> NLP -> dense re-verification -> bound -> gain table.

``tune(drive, name)`` tunes the tunable gain law ``name`` of the drive's observer family (tuning/
family.py): with its own tuner if it has one, else by the shared pipeline below on the TuningModel it
builds:

1. global phase (tuning/search.py): many candidate gains evaluated in batch on the whole envelope;
   the NLP starts from the best distinct ones that meet every constraint. None: the envelope is
   reported infeasible with its evidence (the speeds where no gain at all meets the constraints,
   from the pointwise model), or, if every speed has such gains, as a limit of the law;
2. the max-min NLP (tuning/nlp.py) from each start;
3. re-verification on a grid ``dense_factor`` (>= 4) times denser in speed and in torque of every
   start and every verified NLP round; the best admissible one is kept (never worse than the drive
   file's gains or, for a seeded law, its seed);
4. the pointwise bound (tuning/bound.py) on the dense speeds, with the same decay floor: at each
   speed the best worst-case damping any gain reaches; the certificate is the gap between the tuned
   worst damping and the bound's worst;
   then the tie-break (tuning/tiebreak.py): of the gains within TIE_TOL of that best worst damping,
   the smallest (laws of a few parameters with a gain size);
5. ridges: where the worst point's damping does not move with any of the law's parameters, the
   summary says which point it is and that the law cannot improve it;
6. optionally the damping-versus-noise front (``pareto``).

The numbers a user sees (terminal summary, CSV, JSON) are all from the re-verification; the NLP's
own value of the worst damping is kept in the summary only for comparison.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensorless.design import forked
from sensorless.design.envelope import TuningSettings
from sensorless.design.family import Drive
from sensorless.design.low_speed import handover_decay
from sensorless.design.memo import kept_result
from sensorless.tuning import nlp, search, tiebreak
from sensorless.tuning.bound import Bound, pointwise_bound, with_witness
from sensorless.tuning.candidates import DAMPING, NOISE, Candidates, meets_floor
from sensorless.tuning.conditions import ROBUST_MARGIN, check_error_equilibria, error_scenarios, label, robust
from sensorless.tuning.conditions import candidates as _candidates
from sensorless.tuning.family import TuneOutcome, TuneSettings, tunable_for
from sensorless.tuning.model import TuningModel, evaluate
from sensorless.tuning.result import Figures, TuneResult, figures, gain_table
from sensorless.tuning.selection import DRIVE_FILE, ENVELOPE_INFEASIBLE, infeasible, ridge_of, select

# A law of a few parameters has several local optima: the NLP runs from this many distinct feasible
# starts of the global phase (one NLP each); a rich one from the best start only.
N_STARTS = 3
# A start this close (in damping ratio) to the pointwise bound's worst on the dense grid needs no NLP: no
# gain law exceeds the bound, so the NLP could gain at most this, well inside the selection's TIE (5e-4).
CERTIFIED = 1e-4


def tune(
    drive: Drive,
    law: str | None = None,
    settings: TuneSettings | None = None,
    progress: Callable[[str], None] | None = None,
    retuning: Callable[[TuneOutcome], None] | None = None,
) -> TuneOutcome:
    """Tune the gain law ``law`` (None: the default of the drive's observer family) on ``drive``
    over the envelope of ``settings`` (default: the tunable's, e.g. the drive's ``[tuning]``). Returns a
    TuneResult (or the own tuner's result). Raises nlp.TuningError if the constraints cannot be met
    (with the evidence), CapabilityError if the law cannot be tuned.

    Tuned gains slower anywhere on the dense grid than the decay the I-f handover's w_min asks
    (design/low_speed.py ``handover_decay``; none where the drive needs no I-f start) are tuned again
    with that floor (from the same seed): below it their w_min, and so the handover, rises (a gimbal's to
    0.69 p.u., above its start's and reversal's 0.5 p.u.: those checks never handed over). Where no
    gain meets it, the first gains. ``retuning(first)``: called with the first tuning's result before
    that second tuning, whose result it is unless the second finds gains (the command line starts
    proving it meanwhile)."""
    need = handover_decay(drive)
    st0 = settings if settings is not None else tunable_for(drive, law).settings(drive)
    ahead: list[forked.Pending[tuple[list[str], str | None], None]] = []

    def seeded(seed: TuneResult) -> None:
        # the second tuning (below) depends only on the seed law's result: where its gains decay below the
        # handover's floor (the law starts from them and keeps their decay), it is likely, and a child
        # tunes it while this process tunes the law (on a core the NLP leaves idle)
        if forked.forking() and need > 0 and float(np.min(seed.grid.decay)) < need:
            again = dataclasses.replace(st0, min_decay=need)
            ahead.append(forked.later(functools.partial(_tuned_ahead, drive, law, again, seed)))

    try:
        res = _tune(drive, law, settings, progress, seeded=seeded)
    except BaseException:
        for p in ahead:
            p.cancel()
        raise
    if not isinstance(res, TuneResult) or need <= res.floor or float(np.min(res.dense.decay)) >= need:
        for p in ahead:
            p.cancel()
        return res
    say = progress or (lambda s: None)
    say(
        f"tuned gains decay at {float(np.min(res.dense.decay)):.4g} 1/s, below the {need:.4g} 1/s the "
        "handover's w_min asks: tuning again with that floor"
    )
    if retuning is not None:
        retuning(res)

    def first(e: nlp.TuningError) -> TuneOutcome:
        say(f"no gains meet decay >= {need:.4g} 1/s on the envelope ({e}): the first tuning's gains")
        return res

    if ahead and ahead[0].forked and res.seed is not None:
        lines, failed = ahead[0].result()  # the child's second tuning, from this same seed
        if failed is not None:  # no gains: its lines and its error, as if tuned here
            for line in lines:
                say(line)
            return first(nlp.TuningError(failed))
        # it found gains (a result that does not pickle): tuned again here
    # the seed as the first tuning tuned it (the gimbal's speed-dependent law with alpha_fo tuned and the
    # lag held: no candidate at 11.94 1/s; its schedule: 0.035 p.u., every check passed)
    return _above_seed(drive, law, dataclasses.replace(st0, min_decay=need), progress, res.seed, first)


def _tuned_ahead(
    drive: Drive, law: str | None, settings: TuneSettings, seed: TuneResult
) -> tuple[list[str], str | None]:
    """The second tuning of :func:`tune` (``settings``: the handover's floor) from the seed law's result
    ``seed``, run by a child process ahead of time: (its progress lines, the message of its TuningError);
    None for a message where it found gains (their result holds CasADi Functions, which do not pickle:
    the parent tunes again itself)."""
    lines: list[str] = []
    try:
        _tune(drive, law, settings, lines.append, seed)
    except nlp.TuningError as e:
        return lines, str(e)
    return lines, None


def _above_seed(
    drive: Drive,
    law: str | None,
    settings: TuneSettings,
    progress: Callable[[str], None] | None,
    seed: TuneResult | None,
    missed: Callable[[nlp.TuningError], TuneOutcome],
) -> TuneOutcome:
    """``law`` tuned with the decay floor ``settings.min_decay`` from its seed law's result under a lower
    floor: a seed law of few parameters may meet a floor nowhere where the law it starts does (the
    gimbal's speed-dependent law at 12 1/s, margin -6e-5 at 0.05 p.u.; its schedule meets it). Both
    floors the tuning is held to take this one path: the handover's (:func:`tune`, ``seed`` the first
    tuning's) and an explicit one the seed law cannot meet (:func:`_tune`, ``seed`` None: tuned here
    without a floor). ``missed(e)``: the outcome where the law has no gains meeting the floor either."""
    tunable = tunable_for(drive, law)
    if seed is None and tunable.seed is not None:
        say = progress or (lambda s: None)
        seed_name = tunable.seed
        no_floor = dataclasses.replace(settings, pareto=0, min_decay=0.0)
        seed = _tune(drive, seed_name, no_floor, progress=lambda m: say(f"  [{seed_name}] {m}"), table=False)
    try:
        return _tune(drive, law, settings, progress, seed)
    except nlp.TuningError as e:
        return missed(e)


def _tune(
    drive: Drive,
    law: str | None,
    settings: TuneSettings | None,
    progress: Callable[[str], None] | None,
    seed: TuneResult | None = None,
    table: bool = True,
    seeded: Callable[[TuneResult], None] | None = None,
) -> TuneOutcome:
    """:func:`tune` without the handover's decay floor; ``seed``: the seed law's result where it is
    already tuned. ``table`` False: the result has no gain table (None: a seed law's, whose table
    nobody writes; the law it starts tabulates the seed's gains itself, 0.2 s of the README servo's).
    ``seeded(seed)``: called with the seed law's result where it is tuned here."""
    tunable = tunable_for(drive, law)
    law = tunable.name
    settings = settings if settings is not None else tunable.settings(drive)
    if tunable.tuner is not None:  # a law with a tuner of its own
        return tunable.tuner(drive, settings, progress)
    t_start = time.perf_counter()
    say = progress or (lambda s: None)
    seed_res: TuneResult | None = None
    if tunable.seed is not None and seed is not None:
        seed_res = seed
    elif tunable.seed is not None:
        seed_name = tunable.seed
        say(f"{law}: tuning its start, the {seed_name} law, first")
        seed_set = dataclasses.replace(settings, pareto=0)
        seed_say = lambda m: say(f"  [{seed_name}] {m}")  # noqa: E731
        try:
            seed_res = _tune(drive, seed_name, seed_set, progress=seed_say, table=False)
        except nlp.TuningError as e:
            if settings.min_decay <= 0 or str(e).startswith(ENVELOPE_INFEASIBLE):
                raise  # no floor of the user's, or no gain at all meets it somewhere: no law can
            # an explicit floor as the handover's (tune): the seed as tuned without it, the law with it
            say(f"{seed_name} law: {e}: tuning it without the decay floor, then {law} with it")

            why = (
                f"with decay >= {settings.min_decay:g} 1/s neither the {seed_name} law nor {law} has gains: "
                "lower --min-decay (or the drive file's [tuning] min_decay) or try another law"
            )

            def neither(e2: nlp.TuningError) -> TuneOutcome:
                raise nlp.TuningError(f"{e2}; {why}") from None

            return _above_seed(drive, law, settings, progress, None, neither)
    model = tunable.build(drive, settings, None if seed_res is None else seed_res.theta)
    if seeded is not None and seed_res is not None and seed is None:
        # after the build, before any evaluation: a child forked here (tune's second tuning) builds the
        # same law and finds what this build made for it (its rotor-frame loop, its gain-size Function)
        seeded(seed_res)
    if model.bounded is not None and not getattr(settings, "hold_bounded", True):
        say(f"not held: {', '.join(model.bounded_names)} (the drive file's gains fail a check of their own)")
        model = dataclasses.replace(model, bounded=None, bounded_names=())
    env = settings.envelope
    wb = drive.w_base
    W, T = env.grid()
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    # the baseline as the drive file gives it (reported, and the pole scale); a start in the box (a law
    # may hold some parameters at one value, which the drive file's gains need not have)
    theta0 = np.asarray(model.theta0, float)
    start = None if model.start is None else np.clip(model.start, model.lower, model.upper)
    base = figures(model, theta0, W, T)
    if not np.isfinite(base.poles).all():
        raise nlp.TuningError("the drive file's gains have no closed-loop equilibrium on the envelope")
    scale = float(np.abs(base.poles).max())
    max_noise = settings.noise_limits(model.noise_outputs) if model.noise is not None else None
    if settings.max_noise and model.noise is None:
        raise nlp.TuningError(f"gain law {law} has no noise model: --max-noise does not apply")

    floor = settings.min_decay
    if start is not None:
        # a seeded law keeps at least its seed's decay rate on the grid (here, in the global
        # phase and in the bound: the floor of the whole tuning)
        start_decay = float(np.min(figures(model, start, W, T).decay))
        if start_decay > floor:
            say(f"keeping the start's decay rate: >= {start_decay:.4g} 1/s at every point")
            floor = start_decay
    settings = dataclasses.replace(settings, min_decay=floor)
    check_error_equilibria(model, settings, start if start is not None else theta0, W, T, wb)
    cand = _candidates(model, settings, W, T, wb, scale, max_noise)
    say(
        f"{law}: {model.n_theta} parameters, {W.size} envelope points"
        f"{f', {cand.size - W.size} constraint points' if cand.size > W.size else ''}; "
        f"drive file's gains: worst damping {base.damping.min():.4f}"
    )
    # the pointwise bound first when its optima start the law (a seeded law), else after the NLP
    bound = None
    extra: list[np.ndarray] = []
    if seed_res is not None and model.pointwise is not None and model.from_pointwise is not None:
        bound = _bound(drive, model, settings, floor, scale, max_noise, [seed_res], say, seed_res.bound)
        extra.append(model.from_pointwise(bound.speeds, bound.theta))
    in_box = np.clip(theta0, model.lower, model.upper)
    pb = _Problem(model, settings, W, T, Wd, Td, wb, scale, in_box, start, floor, say)
    opt = _optimize(drive, pb, cand, max_noise, extra, bound)
    theta, dense, note, best_sol, ranked, starts = (
        opt.theta,
        opt.dense,
        opt.note,
        opt.solution,
        opt.ranked,
        opt.starts,
    )
    certified = opt.certified
    dense0 = figures(model, theta0, Wd, Td, noise=model.noise is not None)
    grid = figures(model, theta, W, T)
    if not np.isfinite(dense.damping).all():
        k = int(np.flatnonzero(~np.isfinite(dense.damping))[0])
        raise nlp.TuningError(f"tuned gains: no closed-loop equilibrium at {label(Wd[k], Td[k], wb)}")
    rb = robust(model, settings, theta, Wd, Td, wb)
    if bound is not None and model.pointwise_gains is not None:
        # computed before this law was tuned: its tuned gains are found gains too
        gains = model.pointwise_gains(theta, bound.speeds)
        bound = with_witness(bound, model.pointwise(), gains, scale, max_noise)
    if bound is None and settings.bound and model.pointwise is not None:
        # the same decay floor: the configured one, or else the tuned gains' own slowest decay
        fb = floor if floor > 0 else float(np.min(grid.decay))
        bound = _bound(drive, model, settings, fb, scale, max_noise, [], say, None, theta, theta0)
    ridge = ridge_of(model, theta, dense, bound, wb, say)
    pareto = None
    if settings.pareto and model.noise is not None:
        pareto = damping_noise_front(drive, pb, cand, theta, max_noise)
    seconds = time.perf_counter() - t_start
    result = TuneResult(
        law=law,
        model=model,
        theta=theta,
        theta0=theta0,
        solution=best_sol,
        grid=grid,
        dense=dense,
        dense_baseline=dense0,
        robust=rb,
        table=None,  # type: ignore[arg-type]  # filled below from the result itself
        seconds=seconds,
        selection=note,
        floor=floor,
        bound=bound,
        seed=seed_res,
        ridge=ridge,
        pareto=pareto,
        nlp_retried=opt.nlp_retried,
        global_phase={
            "candidates": int(ranked.evaluated),
            "feasible": int(ranked.feasible.sum()),
            "starts": len(starts),
            "certified": certified,
            # only where a run failed: the tables of runs that did not fail stay as they were
            **({"nlp_failed": list(opt.nlp_failed)} if opt.nlp_failed else {}),
        },
    )
    if not table:
        return result
    return dataclasses.replace(result, table=gain_table(drive, settings, result, scale))


@dataclass(frozen=True)
class _Problem:
    """What the optimization steps share: the model on its envelope, and the decay floor."""

    model: TuningModel
    settings: TuningSettings
    W: np.ndarray
    T: np.ndarray
    Wd: np.ndarray
    Td: np.ndarray
    wb: float
    scale: float
    theta0: np.ndarray
    start: np.ndarray | None
    floor: float
    say: Callable[[str], None]


@dataclass(frozen=True)
class _Optimum:
    theta: np.ndarray
    dense: Figures
    note: dict[str, Any]
    solution: nlp.Solution
    ranked: search.Ranked
    starts: list[np.ndarray]
    certified: bool
    nlp_failed: tuple[str, ...] = ()  # why each NLP run that gave no gains failed
    nlp_retried: tuple[str, ...] = ()  # the IPOPT runs that failed within the others, retried


def _optimize(
    drive: Drive,
    pb: _Problem,
    cand: Candidates,
    max_noise: np.ndarray | None,
    extra: list[np.ndarray],
    bound: Bound | None = None,
) -> _Optimum:
    """Steps 1-4 of the module docstring: global phase, NLP from its best starts, dense selection and
    the tie-break."""
    model, say = pb.model, pb.say
    ranked = search.global_phase(model, cand, pb.scale, max_noise, extra, say)
    if not ranked.feasible[0]:
        raise nlp.TuningError(
            infeasible(drive, model, pb.settings, cand, ranked, pb.scale, max_noise, say, bound)
        )
    # a few parameters: several distinct starts (local optima are common); many: the best one (for
    # a seeded law the better on the grid of its seed's gains and the pointwise optima)
    # (a law holding bounded figures: the best start only; prius's law (16) ran its second and third
    # starts into failed IPOPT runs at every halved trust region, 35 of its 66 s, for no gains)
    k = N_STARTS if model.n_theta <= search.MAX_PATTERN_PARAMETERS and model.bounded is None else 1
    starts = ranked.starts(k, model.typical)
    sols: list[nlp.Solution] = []
    failed: list[str] = []  # the NLP runs that gave no gains (said in the summary, not only in progress)
    retried: list[str] = []  # their IPOPT runs that failed and were retried (the same)
    certified = False
    if bound is not None and max_noise is None:
        # the certificate: no gain law exceeds the bound's worst on the dense grid; a start that is
        # already within CERTIFIED of it leaves the NLP nothing to gain
        f0 = figures(model, starts[0], pb.Wd, pb.Td)
        gap = float(np.min(bound.damping)) - f0.worst_damping()
        certified = gap <= CERTIFIED and bool(np.all(meets_floor(f0.decay, pb.floor, pb.scale)))
        if certified:
            say(f"the best start is {gap:.1e} below the pointwise bound on the dense grid: no NLP needed")
    if not certified:
        say(
            "maximize the worst damping (IPOPT, sector conditions) from "
            + (f"{len(starts)} starts of the global phase" if len(starts) > 1 else "the best start")
        )
    for i, th in enumerate([] if certified else starts):
        # Damping alone would trade decay for damping (a pole creeping to the origin has damping 1):
        # every NLP keeps at least its start's slowest decay on the grid.
        d_start = float(np.min(figures(model, th, pb.W, pb.T).decay))
        c_i = cand
        if d_start > pb.floor * (1 + 1e-6):
            st = dataclasses.replace(pb.settings, min_decay=d_start)
            c_i = _candidates(model, st, pb.W, pb.T, pb.wb, pb.scale, max_noise)
        try:
            sols.append(
                nlp.solve(
                    model,
                    c_i,
                    th,
                    pb.scale,
                    smoothing=pb.settings.smoothing,
                    max_noise=max_noise,
                    progress=lambda m, i=i: say(f"start {i + 1}: {m}"),
                )
            )
            retried += [f"start {i + 1}: {a}" for a in sols[-1].failed_attempts]
        except nlp.TuningError as e:
            say(f"start {i + 1}: the NLP failed ({e}); its start stays a candidate")
            failed.append(f"start {i + 1}: {e}")
    say(f"re-verifying on the {pb.settings.envelope.dense_factor}x denser grid")
    boxed = not np.array_equal(pb.theta0, model.theta0)
    pool = [(DRIVE_FILE + (" in the law's box" if boxed else ""), pb.theta0)]
    if pb.start is not None:
        pool.append((model.start_label or "start", pb.start))
    pool += [(f"global-phase start {i + 1}", th) for i, th in enumerate(starts)]
    theta, dense, note, best_sol = select(model, sols, pool, pb.Wd, pb.Td, pb.floor, max_noise, say, pb.scale)
    if best_sol is None:  # a start was kept: report the best NLP run (if any) for its statistics
        best_sol = max(sols, key=lambda s: s.t) if sols else nlp.Solution(theta, float("nan"), (), 0, 0, ())
    if note["admissible"] and model.gain_size is not None and model.n_theta <= search.MAX_PATTERN_PARAMETERS:
        grids = tiebreak.Grids(
            pb.W,
            pb.T,
            pb.Wd,
            pb.Td,
            [est for _, est in error_scenarios(pb.settings, model)],
            pb.scale,
            max_noise,
            ROBUST_MARGIN,
        )
        others = [th for _, th in pool] + [th for s in sols for th in s.verified]

        def conditions(floor: float, W: np.ndarray, T: np.ndarray) -> Candidates:
            st = dataclasses.replace(pb.settings, min_decay=floor)
            return _candidates(model, st, W, T, pb.wb, pb.scale, max_noise)

        tb = tiebreak.smallest_tie(
            model, theta, dense, note["best_worst_damping"], others, grids, pb.floor, conditions, say, pb.wb
        )
        theta, dense, note = tb.theta, tb.dense, {**note, "tie_break": tb.note}
    return _Optimum(theta, dense, note, best_sol, ranked, starts, certified, tuple(failed), tuple(retried))


def _bound(drive, model, settings, floor, scale, max_noise, others, say, reuse=None, *thetas) -> Bound:
    """The pointwise bound on the dense speeds x torques with decay floor ``floor``; the gains of
    ``thetas`` (this law's) and of the results ``others`` start it at every speed."""
    env = settings.envelope
    if reuse is not None and abs(reuse.floor - floor) <= 1e-9 * max(1.0, floor):
        say("pointwise bound: the seed's (same decay floor)")
        return reuse
    pw = model.pointwise()
    speeds = env.speed_grid(env.dense_factor)
    torques = env.torque_grid(env.dense_factor)
    extra = [model.pointwise_gains(th, speeds) for th in thetas]
    extra += [o.model.pointwise_gains(o.theta, speeds) for o in others]
    say(f"pointwise bound on {speeds.size} speeds x {torques.size} torques, decay >= {floor:.4g} 1/s")
    ex = np.array(extra) if extra else None

    def compute() -> Bound:
        return pointwise_bound(
            pw, speeds, torques, floor, scale, max_noise, ex, coarse=env.dense_factor, progress=say
        )

    # kept on disk for the next command on the same content (the README flow's `tune` run again, a user's
    # second try): the search is half of a tune's CPU (prius: 16-18 of 31 s) and depends only on what the
    # law's model is built from (the drive, the settings, the law and its seed's gains) and the numbers here
    seed = None if model.start is None else np.asarray(model.start, float)
    content = (
        drive,
        settings,
        model.law,
        seed,
        floor,
        scale,
        max_noise,
        ex,
        speeds,
        torques,
        env.dense_factor,
    )
    return kept_result(__name__, "pointwise_bound", content, compute)


def damping_noise_front(drive, pb: _Problem, cand, theta_best, max_noise):
    """The damping-versus-noise front: the tuning (global phase, NLP, dense selection) repeated with the
    noise output limited to a sweep of values from the unconstrained optimum's noise down to the
    least noise of a feasible global candidate (half the optimum's for a law without a candidate
    grid); every point re-verified on the dense grid."""
    model, settings, say = pb.model, pb.settings, pb.say
    outs = model.noise_outputs
    name = settings.pareto_output
    if not name:
        limited = (
            [o for o, v in zip(outs, max_noise, strict=True) if np.isfinite(v)]
            if max_noise is not None
            else []
        )
        name = limited[0] if limited else outs[0]
    i = outs.index(name)
    top = figures(model, theta_best, pb.Wd, pb.Td, noise=True)
    n_hi = float(top.worst_noise()[i])
    lim0 = np.full(len(outs), np.inf) if max_noise is None else np.asarray(max_noise, float).copy()
    lim0[i] = np.inf
    pcand = with_noise_points(cand)
    # the least noise of a global candidate that meets the other constraints
    n_lo = n_hi
    if model.starts is not None:
        ranked = search.rank(model, np.asarray(model.starts(), float), pcand, pb.scale, lim0)
        feas = ranked.thetas[ranked.feasible]
        if feas.size:
            P = model.make_points(pb.W, pb.T, model.nominal_estimate)
            N = pb.W.size
            e = evaluate(model, np.repeat(feas, N, axis=0).T, np.tile(P, (1, feas.shape[0])), noise=True)
            nz = np.where(np.isnan(e.noise[:, i]), np.inf, e.noise[:, i]).reshape(-1, N).max(axis=1)
            n_lo = min(n_lo, float(np.min(nz)))
    if n_lo >= n_hi * 0.999:  # no candidate grid, or none quieter: down to half
        n_lo = 0.5 * n_hi
    say(f"damping-versus-noise front: {name} noise from {n_hi:.4g} down to {n_lo:.4g}")

    def point(th, f, lim=None):
        return {
            "noise": float(f.worst_noise()[i]),
            **({"limit": float(lim)} if lim is not None else {}),
            "worst_damping": f.worst_damping(),
            "min_decay_rate": float(np.min(f.decay)),
            "theta": [float(v) for v in th],
        }

    pts = [point(theta_best, top)]
    prev = theta_best
    quiet = dataclasses.replace(pb, say=lambda s: None)
    for lim in np.geomspace(n_hi, max(n_lo, 1e-12) * 1.0001, settings.pareto)[1:]:
        ln = lim0.copy()
        ln[i] = lim
        try:
            opt = _optimize(drive, quiet, pcand, ln, [prev])
        except nlp.TuningError as e:
            say(f"  {name} noise <= {lim:.4g}: {e}")
            continue
        f = figures(model, opt.theta, pb.Wd, pb.Td, noise=True)
        if f.worst_noise()[i] > lim * (1 + 1e-3):
            say(f"  {name} noise <= {lim:.4g}: no admissible gains on the dense grid")
            continue
        prev = opt.theta
        pts.append(point(opt.theta, f, lim))
        say(f"  {name} noise <= {lim:.4g}: worst damping {f.worst_damping():.4f} (dense)")
    return {"output": name, "unit": model.noise_units[i], "points": pts}


def with_noise_points(cand: Candidates) -> Candidates:
    """The candidates with a noise point at every envelope point (if not there yet)."""
    if (cand.condition == NOISE).any():
        return cand
    dmp = np.flatnonzero(cand.condition == DAMPING)
    return Candidates(
        np.hstack([cand.P, cand.P[:, dmp]]),
        np.concatenate([cand.condition, np.full(dmp.size, NOISE)]),
        np.concatenate([cand.sigma, np.zeros(dmp.size)]),
        (*cand.labels, *(cand.labels[j] + ", noise" for j in dmp)),
    )


def fallbacks(drive: Drive, result: TuneOutcome, settings: TuneSettings) -> list[tuple[str, TuneOutcome]]:
    """The tuner's next candidates where the kept gains fail their proof (reports/tune_proof.py: they
    run worse than the drive file's): (what it is, a result with its own gain table), best first. For the
    shared pipeline: the law's start where it has one and it differs from the kept gains (a seeded law:
    its seed's optimum in this law's parameters, e.g. the tuned speed-dependent law (16) sampled at the
    schedule's breakpoints, which that law reproduces exactly); a tuner of its own offers none."""
    if not isinstance(result, TuneResult) or result.model.start is None:
        return []
    m = result.model
    theta = np.clip(np.asarray(m.start, float), m.lower, m.upper)
    if np.allclose(theta, result.theta, rtol=1e-9, atol=0.0):
        return []
    st = dataclasses.replace(settings, min_decay=result.floor)
    env = st.envelope
    W, T = env.grid()
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    grid = figures(m, theta, W, T)
    dense = figures(m, theta, Wd, Td, noise=m.noise is not None)
    scale = float(np.abs(figures(m, result.theta0, W, T).poles).max())
    what = m.start_label or "the law's start"
    text = f"{what}: the fallback (the optimum ran worse than the drive file's gains in the command's proof)"
    r = dataclasses.replace(
        result,
        theta=theta,
        grid=grid,
        dense=dense,
        selection={"text": text, "fallback": True},
        ridge=None,
        pareto=None,
    )
    return [(what, dataclasses.replace(r, table=gain_table(drive, st, r, scale)))]
