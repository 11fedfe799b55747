"""Gain tuning end to end: envelope -> global phase -> NLP -> dense re-verification -> bound -> gain table.

``tune(drive, name)`` tunes the tunable gain family ``name`` of the drive's observer family (tuning/
family.py): with its own tuner if it has one, else by the shared pipeline below on the TuningModel it
builds:

1. global phase (tuning/search.py): many candidate gains evaluated in batch on the whole envelope;
   the NLP starts from the best distinct ones that meet every constraint. None: the envelope is
   reported infeasible with its evidence (the speeds where no gain at all meets the constraints,
   from the pointwise model), or, if every speed has such gains, as a limit of the family;
2. the max-min NLP (tuning/nlp.py) from each start;
3. re-verification on a grid ``dense_factor`` (>= 4) times denser in speed and in torque of every
   start and every verified NLP round; the best admissible one is kept (never worse than the drive
   file's gains or, for a seeded family, its seed);
4. the pointwise bound (tuning/bound.py) on the dense speeds, with the same decay floor: at each
   speed the best worst-case damping any gain reaches; the certificate is the gap between the tuned
   worst damping and the bound's worst;
5. ridges: where the worst point's damping does not move with any of the family's parameters, the
   summary says which point it is and that the family cannot improve it;
6. optionally the damping-versus-noise front (``pareto``).

The numbers a user sees (terminal summary, CSV, JSON) are all from the re-verification; the NLP's
own value of the worst damping is kept in the summary only for comparison.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensorless.design.envelope import ESTIMATE_KEYS, TuningSettings
from sensorless.design.gain_table import GainTable
from sensorless.tuning import nlp, search
from sensorless.tuning.bound import Bound, pointwise_bound
from sensorless.tuning.family import tunable_for
from sensorless.tuning.model import TuningModel, evaluate

ROBUST_MARGIN = 1e-3  # under estimate errors require max Re(p) <= -ROBUST_MARGIN * scale (strictly stable)
RIDGE_TOL = 1e-2  # |d damping / d theta_i| * typical_i below this at the worst point: a ridge (a 10 %
# change of any parameter moves its damping by less than 1e-3)
N_STARTS = 3  # NLP starts from the global phase (families with few parameters)
CERTIFIED = 1e-4  # a start this close to the pointwise bound's worst (dense) needs no NLP
TIE = 5e-4  # candidates within this of the best worst damping tie: the faster slowest decay wins


@dataclass(frozen=True)
class Figures:
    """Closed-loop figures of one gain set on a grid."""

    w_m: np.ndarray  # [rad/s]
    T_e: np.ndarray  # [N m]
    poles: np.ndarray  # (N, n) [1/s]
    damping: np.ndarray  # worst damping per point
    decay: np.ndarray  # -max Re per point [1/s]
    gains: dict[str, np.ndarray]  # lambda1_ohm, lambda2_ohm per point
    noise: np.ndarray | None = None  # (N, n_out) RMS of the noise outputs (design/noise.py)

    def worst(self) -> int:
        """Index of the worst-damped point (NaN counts as worst)."""
        return int(np.argmin(np.where(np.isfinite(self.damping), self.damping, -np.inf)))

    def worst_damping(self) -> float:
        """Worst damping; -inf if any point has no equilibrium."""
        return float(np.min(self.damping)) if np.isfinite(self.damping).all() else -np.inf

    def worst_noise(self) -> np.ndarray | None:
        """(n_out,) worst RMS of each noise output over the grid."""
        if self.noise is None:
            return None
        return np.where(np.isnan(self.noise), np.inf, self.noise).max(axis=0)

    def per_speed(self) -> tuple[np.ndarray, np.ndarray]:
        """(speeds, worst damping over the torques at each speed)."""
        w = np.unique(self.w_m)
        z = np.array([np.min(np.where(np.isfinite(d := self.damping[self.w_m == v]), d, -np.inf)) for v in w])
        return w, z

    def decay_per_speed(self) -> np.ndarray:
        """Slowest decay over the torques at each speed (of ``per_speed``)."""
        w = np.unique(self.w_m)
        return np.array(
            [np.min(np.where(np.isfinite(d := self.decay[self.w_m == v]), d, -np.inf)) for v in w]
        )


@dataclass(frozen=True)
class TuneResult:
    """Everything ``sensorless tune`` reports."""

    family: str
    model: TuningModel
    theta: np.ndarray
    theta0: np.ndarray
    solution: nlp.Solution  # the best NLP result (its t is the NLP's, not the verified value)
    grid: Figures  # tuned gains on the optimization grid
    dense: Figures  # tuned gains on the re-verification grid
    dense_baseline: Figures  # the drive file's gains on the re-verification grid
    robust: list[dict[str, Any]]  # per error scenario: worst max Re on the dense grid
    table: GainTable
    seconds: float
    selection: dict[str, Any]  # which dense-verified candidate was kept and why
    floor: float = 0.0  # the decay floor the family was tuned under [1/s]
    bound: Bound | None = None  # the pointwise bound on the dense speeds
    seed: TuneResult | None = None  # the seed family's result (schedule: law16)
    ridge: dict[str, Any] | None = None  # the worst point, if no parameter of the family moves it
    pareto: list[dict[str, Any]] | None = None  # damping-versus-noise front
    global_phase: dict[str, Any] = dataclasses.field(default_factory=dict)

    def summary_lines(self, drive: Any) -> list[str]:
        """The terminal summary: parameters and worst damping before -> after, and where."""
        s = self.table.summary
        wb = drive.w_base
        env = self.table.envelope
        g = s.get("global_phase", {})
        nlp_from = (
            "the best is within the certificate of the bound: no NLP"
            if g.get("certified")
            else f"NLP from {g.get('starts', 1)} of them"
        )
        out = [
            f"global phase: {g.get('candidates', 0)} candidate gains, {g.get('feasible', 0)} meeting every "
            f"constraint; {nlp_from}",
            f"optimized over {env['optimization_points']} points in {s['exchange_rounds']} exchange rounds "
            f"({s['ipopt_iterations']} IPOPT iterations); re-verified on {env['dense_points']} points "
            f"({env['dense_factor']}x denser) in {self.seconds:.1f} s",
        ]
        seeded = self.seed is not None
        head = (
            f"{'':<22}{'drive file':>18}" + (f"{self.seed.family:>18}" if seeded else "") + f"{'tuned':>18}"
        )
        out.append(head)
        for n, u, v0, v in zip(self.model.names, self.model.units, self.theta0, self.theta, strict=True):
            if u == "rad/s":
                out.append(f"{n + ' [p.u.]':<22}{v0 / wb:>18.4g}{'':>{18 * seeded}}{v / wb:>18.4g}")
            elif self.model.n_theta <= 6:
                out.append(f"{n + ' [' + u + ']':<22}{v0:>18.4g}{'':>{18 * seeded}}{v:>18.4g}")

        def where(a: dict[str, Any]) -> str:
            return f"at {a['w_m_pu']:+.3f} p.u., {a['T_e_Nm']:+.3g} N m"

        sd = s.get("seed", {})
        mid = f"{sd['worst_damping']:>18.4f}" if seeded else ""
        out += [
            f"{'worst damping':<22}{s['baseline_worst_damping']:>18.4f}{mid}{s['worst_damping']:>18.4f}",
            f"{'  where':<22}{where(s['baseline_worst_damping_at']):>36}",
        ]
        if seeded:
            out.append(f"{'':<22}{where(sd['worst_damping_at']):>36} ({self.seed.family})")
        out.append(f"{'':<22}{where(s['worst_damping_at']):>36}")
        mid = f"{sd['min_decay_rate']:>18.4g}" if seeded else ""
        out.append(
            f"{'slowest decay [1/s]':<22}{s['baseline_min_decay_rate']:>18.4g}{mid}"
            f"{s['min_decay_rate']:>18.4g}"
        )
        nz = s.get("noise")
        if nz:
            for k, name in enumerate(nz["outputs"]):
                u = nz["units"][k]
                mid = f"{sd['worst_noise'][k]:>18.4g}" if seeded and sd.get("worst_noise") else ""
                out.append(
                    f"{'noise ' + name + ' [' + u + ']':<22}{nz['baseline'][k]:>18.4g}{mid}"
                    f"{nz['tuned'][k]:>18.4g}"
                )
            out.append(
                f"  (worst RMS over the dense grid for {nz['sigma_A']:.4g} A rms current noise per axis and "
                f"sample at T_s = {nz['T_s_s'] * 1e6:g} us)"
            )
        nlp_t = s["nlp_worst_damping"]
        out.append(
            f"worst damping on the optimization grid {s['optimization_grid_worst_damping']:.4f} "
            + (f"(NLP: {nlp_t:.4f})" if np.isfinite(nlp_t) else "(no NLP run)")
            + "; the table reports the dense re-verification"
        )
        if s.get("selection"):
            out.append(f"kept: {s['selection']['text']}")
        b = s.get("bound")
        if b:
            out.append(
                "bound (best worst-case damping of any gain at each speed, "
                f"decay >= {b['floor_1_s']:.4g} 1/s): "
                f"worst {b['worst_damping']:.4f} at {b['worst_at_w_m_pu']:+.3f} p.u.; tuned "
                f"{s['worst_damping']:.4f}, {b['gap']:.4f} below it"
                + (f"; {self.seed.family} {b['gap_seed']:.4f} below" if seeded and "gap_seed" in b else "")
            )
            if not b["feasible_everywhere"]:
                out.append(f"  no gain meets the floor at {b['infeasible_speeds']} dense speeds")
        r = s.get("ridge")
        if r:
            out.append(r["text"])
        for rb in s["robust"]:
            out.append(
                f"estimates {rb['scenario']}: max Re(p) = {rb['max_real_1_s']:.4g} 1/s at "
                f"{rb['at_w_m_pu']:+.3f} p.u., {rb['at_T_e_Nm']:+.3g} N m "
                f"({'stable' if rb['stable'] else 'UNSTABLE'})"
            )
        pf = s.get("pareto")
        if pf:
            out.append(
                f"damping-versus-noise front ({pf['output']}): {len(pf['points'])} points, noise "
                f"{pf['points'][-1]['noise']:.4g} .. {pf['points'][0]['noise']:.4g} {pf['unit']}, "
                "worst damping "
                f"{pf['points'][-1]['worst_damping']:.4f} .. {pf['points'][0]['worst_damping']:.4f}"
            )
        return out


def figures(
    model: TuningModel, theta: np.ndarray, w: np.ndarray, T: np.ndarray, est=None, noise: bool = False
) -> Figures:
    """Poles, damping, decay rate, gains (and noise) of ``theta`` at the points (w, T)."""
    est = model.nominal_estimate if est is None else est
    e = evaluate(model, theta, model.make_points(w, T, est), noise=noise and model.noise is not None)
    return Figures(w, T, e.poles, e.damping, e.decay, model.point_gains(theta, w), e.noise)


def error_scenarios(settings: TuningSettings, nominal: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Corners of the stated estimate-error box: every combination of +-error on each parameter
    with a nonzero error (2^m scenarios). Labelled like 'R_s+30%,L_q-10%'."""
    keys = [(k, e) for k, e in zip(range(4), settings.errors, strict=True) if e > 0]
    out = []
    for signs in itertools.product((1, -1), repeat=len(keys)):
        est = nominal.copy()
        parts = []
        for (k, e), s in zip(keys, signs, strict=True):
            est[k] = nominal[k] * (1 + s * e)
            parts.append(f"{ESTIMATE_KEYS[k]}{'+' if s > 0 else '-'}{100 * e:g}%")
        out.append((",".join(parts), est))
    return out if keys else []


def _label(w: float, T: float, w_base: float, extra: str = "") -> str:
    return f"w_m = {w / w_base:+.3f} p.u., T_e = {T:+.3g} N m{extra}"


def tune(
    drive: Any,
    family: str | None = None,
    settings: Any = None,
    progress: Callable[[str], None] | None = None,
) -> Any:
    """Tune the gain family ``family`` (None: the default of the drive's observer family) on ``drive``
    over the envelope of ``settings`` (default: the tunable's, e.g. the drive's ``[tuning]``). Returns a
    TuneResult (or the own tuner's result). Raises nlp.TuningError if the constraints cannot be met
    (with the evidence), CapabilityError if the family cannot be tuned."""
    tunable = tunable_for(drive, family)
    family = tunable.name
    settings = settings if settings is not None else tunable.settings(drive)
    if tunable.tuner is not None:  # e.g. the reduced-order observer's deangelo family
        return tunable.tuner(drive, settings, progress)
    t_start = time.perf_counter()
    say = progress or (lambda s: None)
    seed_res: TuneResult | None = None
    if tunable.seed is not None:
        seed_name = tunable.seed
        say(f"{family}: tuning its start, the {seed_name} family, first")
        seed_set = dataclasses.replace(settings, pareto=0)
        seed_res = tune(drive, seed_name, seed_set, progress=lambda m: say(f"  [{seed_name}] {m}"))
    model = tunable.build(drive, settings, None if seed_res is None else seed_res.theta)
    env = settings.envelope
    wb, T_N = drive.w_base, drive.T_N
    W, T = env.grid(wb, T_N)
    Wd, Td = env.grid(wb, T_N, env.dense_factor)
    theta0 = np.clip(model.theta0, model.lower, model.upper)
    start = None if model.start is None else np.clip(model.start, model.lower, model.upper)
    base = figures(model, theta0, W, T)
    if not np.isfinite(base.poles).all():
        raise nlp.TuningError("the drive file's gains have no closed-loop equilibrium on the envelope")
    scale = float(np.abs(base.poles).max())
    max_noise = settings.noise_limits(model.noise_outputs) if model.noise is not None else None
    if settings.max_noise and model.noise is None:
        raise nlp.TuningError(f"gain family {family} has no noise model: --max-noise does not apply")

    floor = settings.min_decay
    if start is not None:
        # a seeded family keeps at least its seed's decay rate on the grid (here, in the global
        # phase and in the bound: the floor of the whole tuning)
        start_decay = float(np.min(figures(model, start, W, T).decay))
        if start_decay > floor:
            say(f"keeping the start's decay rate: >= {start_decay:.4g} 1/s at every point")
            floor = start_decay
    settings = dataclasses.replace(settings, min_decay=floor)
    _check_error_equilibria(model, settings, start if start is not None else theta0, W, T, wb)
    cand = _candidates(model, settings, W, T, wb, scale, max_noise)
    say(
        f"{family}: {model.n_theta} parameters, {W.size} envelope points"
        f"{f', {cand.size - W.size} constraint points' if cand.size > W.size else ''}; "
        f"drive file's gains: worst damping {base.damping.min():.4f}"
    )
    # the pointwise bound first when it starts the family (the schedule), else after the NLP
    bound = None
    extra: list[np.ndarray] = []
    if seed_res is not None and model.pointwise is not None and model.from_pointwise is not None:
        bound = _bound(drive, model, settings, floor, scale, max_noise, [seed_res], say, seed_res.bound)
        extra.append(model.from_pointwise(bound.speeds, bound.theta))
    pb = _Problem(model, settings, W, T, Wd, Td, wb, scale, theta0, start, floor, say)
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
        raise nlp.TuningError(f"tuned gains: no closed-loop equilibrium at {_label(Wd[k], Td[k], wb)}")
    robust = _robust(model, settings, theta, Wd, Td, wb)
    if bound is None and settings.bound and model.pointwise is not None:
        # the same decay floor: the configured one, or else the tuned gains' own slowest decay
        fb = floor if floor > 0 else float(np.min(grid.decay))
        bound = _bound(drive, model, settings, fb, scale, max_noise, [], say, None, theta, theta0)
    ridge = _ridge(model, theta, dense, bound, wb, say)
    pareto = None
    if settings.pareto and model.noise is not None:
        pareto = _pareto(drive, pb, cand, theta, max_noise)
    seconds = time.perf_counter() - t_start
    result = TuneResult(
        family=family,
        model=model,
        theta=theta,
        theta0=theta0,
        solution=best_sol,
        grid=grid,
        dense=dense,
        dense_baseline=dense0,
        robust=robust,
        table=None,  # type: ignore[arg-type]  (filled below from the result itself)
        seconds=seconds,
        selection=note,
        floor=floor,
        bound=bound,
        seed=seed_res,
        ridge=ridge,
        pareto=pareto,
        global_phase={
            "candidates": int(ranked.evaluated),
            "feasible": int(ranked.feasible.sum()),
            "starts": len(starts),
            "certified": certified,
        },
    )
    table = _table(drive, settings, result, scale)
    return dataclasses.replace(result, table=table)


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


def _optimize(
    drive: Any,
    pb: _Problem,
    cand: nlp.Candidates,
    max_noise: np.ndarray | None,
    extra: list[np.ndarray],
    bound: Bound | None = None,
) -> _Optimum:
    """Steps 1-3 of the module docstring: global phase, NLP from its best starts, dense selection."""
    model, say = pb.model, pb.say
    ranked = search.global_phase(model, cand, pb.scale, max_noise, extra, say)
    if not ranked.feasible[0]:
        raise nlp.TuningError(_infeasible(drive, model, pb.settings, cand, ranked, pb.scale, max_noise, say))
    # a few parameters: several distinct starts (local optima are common); many: the best one (for
    # the schedule the better on the grid of its seed's gains and the pointwise optima)
    k = N_STARTS if model.n_theta <= search.MAX_PATTERN_PARAMETERS else 1
    starts = ranked.starts(k, model.typical)
    sols: list[nlp.Solution] = []
    certified = False
    if bound is not None and max_noise is None:
        # the certificate: no gain law exceeds the bound's worst on the dense grid; a start that is
        # already within CERTIFIED of it leaves the NLP nothing to gain
        f0 = figures(model, starts[0], pb.Wd, pb.Td)
        gap = float(np.min(bound.damping)) - f0.worst_damping()
        certified = gap <= CERTIFIED and float(np.min(f0.decay)) >= pb.floor * (1 - 1e-6) - 1e-9
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
        except nlp.TuningError as e:
            say(f"start {i + 1}: the NLP failed ({e}); its start stays a candidate")
    say(f"re-verifying on the {pb.settings.envelope.dense_factor}x denser grid")
    pool = [("drive file's gains", pb.theta0)]
    if pb.start is not None:
        pool.append((model.start_label or "start", pb.start))
    pool += [(f"global-phase start {i + 1}", th) for i, th in enumerate(starts)]
    theta, dense, note, best_sol = _select(model, sols, pool, pb.Wd, pb.Td, pb.floor, max_noise, say)
    if best_sol is None:  # a start was kept: report the best NLP run (if any) for its statistics
        best_sol = max(sols, key=lambda s: s.t) if sols else nlp.Solution(theta, float("nan"), (), 0, 0, ())
    return _Optimum(theta, dense, note, best_sol, ranked, starts, certified)


def _robust(model, settings, theta, Wd, Td, wb) -> list[dict[str, Any]]:
    robust = []
    for name, est in error_scenarios(settings, model.nominal_estimate):
        f = figures(model, theta, Wd, Td, est)
        mr = np.where(np.isfinite(f.decay), -f.decay, np.inf)
        k = int(np.argmax(mr))
        robust.append(
            {
                "scenario": name,
                "estimate": est,
                "max_real_1_s": float(mr[k]),
                "at_w_m_pu": float(Wd[k] / wb),
                "at_T_e_Nm": float(Td[k]),
                "stable": bool(mr[k] < 0),
            }
        )
    unstable = [r for r in robust if not r["stable"]]
    if unstable:
        r = unstable[0]
        raise nlp.TuningError(
            f"tuned gains are not stable under estimate errors {r['scenario']} at "
            f"w_m = {r['at_w_m_pu']:+.3f} p.u., T_e = {r['at_T_e_Nm']:+.3g} N m on the dense grid "
            f"(max Re = {r['max_real_1_s']:.3g} 1/s): use more --speeds"
        )
    return robust


def _bound(drive, model, settings, floor, scale, max_noise, others, say, reuse=None, *thetas) -> Bound:
    """The pointwise bound on the dense speeds x torques with decay floor ``floor``; the gains of
    ``thetas`` (this family's) and of the results ``others`` start it at every speed."""
    env = settings.envelope
    if reuse is not None and abs(reuse.floor - floor) <= 1e-9 * max(1.0, floor):
        say("pointwise bound: the seed's (same decay floor)")
        return reuse
    pw = model.pointwise()
    speeds = env.speed_grid(drive.w_base, env.dense_factor)
    torques = env.torque_grid(drive.T_N, env.dense_factor)
    extra = [model.pointwise_gains(th, speeds) for th in thetas]
    extra += [o.model.pointwise_gains(o.theta, speeds) for o in others]
    say(f"pointwise bound on {speeds.size} speeds x {torques.size} torques, decay >= {floor:.4g} 1/s")
    return pointwise_bound(
        pw,
        speeds,
        torques,
        floor,
        scale,
        max_noise,
        np.array(extra) if extra else None,
        coarse=env.dense_factor,
        progress=say,
    )


def _infeasible(drive, model, settings, cand, ranked, scale, max_noise, say) -> str:
    """The message of an infeasible envelope, with its evidence."""
    wb = drive.w_base
    env = settings.envelope
    worst = cand.labels[int(ranked.worst_point[0])]
    what = f"stable with decay >= {settings.min_decay:g} 1/s" if settings.min_decay > 0 else "stable"
    if max_noise is not None:
        what += " within the noise limits"
    if model.pointwise is None:
        return (
            f"no {model.family} gains found that are {what} at every envelope point: the best of "
            f"{ranked.evaluated} candidates fails at {worst} (margin {ranked.margin[0]:.3g})"
        )
    speeds = env.speed_grid(wb)
    torques = env.torque_grid(drive.T_N)
    say("no feasible candidate: is any gain at all feasible at each envelope speed?")
    b = pointwise_bound(model.pointwise(), speeds, torques, settings.min_decay, scale, max_noise, coarse=1)
    bad = np.flatnonzero(~b.feasible)
    if bad.size:
        pts = "; ".join(
            f"{speeds[j] / wb:+.3f} p.u. (best slowest decay {b.decay[j]:.4g} 1/s)" for j in bad[:6]
        )
        return (
            f"the envelope is infeasible: at {bad.size} of {speeds.size} envelope speeds no gain "
            f"({', '.join(b.names)} anywhere in the box) is {what} at every torque, so no gain law is: "
            f"{pts}{' and more' if bad.size > 6 else ''}"
        )
    return (
        f"no {model.family} gains found that are {what} at every envelope point (best of "
        f"{ranked.evaluated} candidates and a margin search: fails at {worst}, margin "
        f"{ranked.margin[0]:.3g}); at every envelope speed some gain ({', '.join(b.names)}) is, so the "
        f"limit is the {model.family} law's shape: try another family"
    )


def _select(
    model: TuningModel,
    sols: list[nlp.Solution],
    pool: list[tuple[str, np.ndarray]],
    Wd: np.ndarray,
    Td: np.ndarray,
    floor: float,
    max_noise: np.ndarray | None,
    say,
) -> tuple[np.ndarray, Figures, dict[str, Any], nlp.Solution | None]:
    """The best on the dense grid among the starts (``pool``: the drive file's gains, a seed's, the
    global phase's) and every round each NLP verified on its grid.

    The NLP only checks its grid; between those points a free schedule may be worse (even
    unstable), which only the dense grid shows. Admissible: decay >= the floor (with the NLP's
    tolerance) and noise within its limits on the dense grid; among those, the best worst damping.
    So the reported gains are never worse than the drive file's or a seed's when those are
    admissible."""
    use_noise = max_noise is not None
    cands: list[tuple[str, np.ndarray, Figures, nlp.Solution | None]] = []
    for name, th in pool:
        cands.append((name, th, figures(model, th, Wd, Td, noise=use_noise), None))
    for i, s in enumerate(sols):
        tag = f"start {i + 1}: " if len(sols) > 1 else ""
        for k, th in enumerate(s.verified):
            name = (
                "NLP solution" if k == len(s.verified) - 1 else f"exchange round {k + 1} of {len(s.verified)}"
            )
            cands.append((tag + name, th, figures(model, th, Wd, Td, noise=use_noise), s))

    def admissible(f: Figures) -> bool:
        ok = bool(np.min(f.decay) >= floor * (1 - 1e-6) - 1e-9) if floor > 0 else bool(np.min(f.decay) > 0)
        if ok and use_noise:
            ok = bool(np.all(f.worst_noise() <= max_noise * (1 + 1e-6)))
        return ok

    def rank(i: int) -> tuple[bool, float, int]:
        f = cands[i][2]
        return (admissible(f), f.worst_damping(), i)

    top = max(range(len(cands)), key=rank)
    # ties (within TIE in damping, e.g. along a ridge of law16): the faster slowest decay
    best = max(
        (i for i in range(len(cands)) if rank(i)[0] == rank(top)[0] and rank(i)[1] >= rank(top)[1] - TIE),
        key=lambda i: (float(np.min(cands[i][2].decay)), i),
    )
    name, theta, _, sol = cands[best]
    finals = {c[0]: c[2].worst_damping() for c in cands if c[0].endswith("NLP solution")}
    starts = {c[0]: c[2].worst_damping() for c in cands[: len(pool)]}
    bad = {c[0] for c in cands if not admissible(c[2])}
    parts = ", ".join(f"{k} {v:.4f}{'*' if k in bad else ''}" for k, v in {**starts, **finals}.items())
    text = f"{name} (dense worst damping: {parts}"
    text += "; *: slower than the decay floor or noisier than the limit on the dense grid)" if bad else ")"
    if not rank(best)[0]:
        text += "; no candidate meets the constraints on the dense grid: use more --speeds"
    say(f"kept: {text}")
    seed_start = [v for k, v in starts.items() if k != "drive file's gains"]
    return (
        theta,
        figures(model, theta, Wd, Td, noise=model.noise is not None),
        {
            "selected": name,
            "start": model.start_label,
            "start_worst_damping": seed_start[0] if model.start is not None else starts["drive file's gains"],
            "nlp_solution_worst_damping": max(finals.values()) if finals else float("nan"),
            "candidates": {k: v for k, v in {**starts, **finals}.items()},
            "text": text,
        },
        sol,
    )


def _ridge(model: TuningModel, theta: np.ndarray, dense: Figures, bound: Bound | None, wb: float, say):
    """The worst point, and whether any parameter of the family moves its damping: central
    differences of its worst damping in each parameter (scaled by its typical magnitude). If none
    exceeds RIDGE_TOL, the family cannot improve that point: its optimum is a ridge there."""
    k = dense.worst()
    if dense.damping[k] >= nlp.T_MAX:  # damping 1 everywhere: nothing to improve
        return None
    w, T = dense.w_m[k], dense.T_e[k]
    n = model.n_theta
    h = 1e-4 * model.typical
    th = np.repeat(theta[:, None], 2 * n, axis=1)
    for i in range(n):
        th[i, 2 * i] += h[i]
        th[i, 2 * i + 1] -= h[i]
    th = np.clip(th, model.lower[:, None], model.upper[:, None])
    P = model.make_points(np.full(2 * n, w), np.full(2 * n, T), model.nominal_estimate)
    z = evaluate(model, th, P).damping
    step = (th[np.arange(n), 2 * np.arange(n)] - th[np.arange(n), 2 * np.arange(n) + 1]) / model.typical
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(step > 0, (z[0::2] - z[1::2]) / step, 0.0)
    g = np.where(np.isfinite(g), g, np.inf)
    if not np.all(np.abs(g) < RIDGE_TOL):
        return None
    where = f"w_m = {w / wb:+.3f} p.u., T_e = {T:+.3g} N m"
    text = (
        f"ridge: the worst point ({where}, damping {dense.damping[k]:.4f}) does not move with any "
        f"{model.family} parameter (|d damping/d theta| <= {np.max(np.abs(g)):.1e} per typical magnitude): "
        f"the {model.family} family cannot improve it"
    )
    out: dict[str, Any] = {
        "w_m_pu": float(w / wb),
        "T_e_Nm": float(T),
        "damping": float(dense.damping[k]),
        "gradient": {nm: float(v) for nm, v in zip(model.names, g, strict=True)},
    }
    if bound is not None:
        j = int(np.argmin(np.abs(bound.speeds - w)))
        out["bound_there"] = float(bound.damping[j])
        if bound.damping[j] > dense.damping[k] + 1e-3:
            text += f"; other gains reach {bound.damping[j]:.4f} there (the pointwise bound)"
    out["text"] = text
    say(text)
    return out


def _pareto(drive, pb: _Problem, cand, theta_best, max_noise):
    """The damping-versus-noise front: the tuning (global phase, NLP, dense selection) repeated with the
    noise output limited to a sweep of values from the unconstrained optimum's noise down to the
    least noise of a feasible global candidate (half the optimum's for a family without a candidate
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
    pcand = _with_noise_points(cand)
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
    if n_lo >= n_hi * 0.999:  # no candidate grid (the schedule), or none quieter: down to half
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


def _with_noise_points(cand: nlp.Candidates) -> nlp.Candidates:
    """The candidates with a noise point at every envelope point (if not there yet)."""
    if (cand.kind == nlp.NOISE).any():
        return cand
    dmp = np.flatnonzero(cand.kind == nlp.DAMPING)
    return nlp.Candidates(
        np.hstack([cand.P, cand.P[:, dmp]]),
        np.concatenate([cand.kind, np.full(dmp.size, nlp.NOISE)]),
        np.concatenate([cand.sigma, np.zeros(dmp.size)]),
        (*cand.labels, *(cand.labels[j] + ", noise" for j in dmp)),
    )


def _check_error_equilibria(
    model: TuningModel, settings: TuningSettings, theta: np.ndarray, W: np.ndarray, T: np.ndarray, wb: float
) -> None:
    """Under estimate errors the equilibrium branch of exact estimates can end in a fold (the observer
    cannot hold the rotor position: at 0.05 p.u. and full torque already with R̂s 0.75 % off and the
    drive file's gains). Then "stable under these errors" has no meaning there: say so before the NLP."""
    for name, est in error_scenarios(settings, model.nominal_estimate):
        x0 = model.equilibrium(theta, model.make_points(W, T, est))
        bad = np.flatnonzero(~np.isfinite(x0).all(axis=0))
        if bad.size:
            where = "; ".join(_label(W[k], T[k], wb) for k in bad[:4])
            raise nlp.TuningError(
                f"the envelope is infeasible under estimate errors {name}: with the start gains the "
                f"observer has no equilibrium (it cannot hold the rotor position) at {where}"
                f"{' and more' if bad.size > 4 else ''}; use smaller --errors or a larger --speed-min"
            )


def _candidates(
    model: TuningModel,
    settings: TuningSettings,
    W: np.ndarray,
    T: np.ndarray,
    wb: float,
    scale: float,
    max_noise: np.ndarray | None = None,
) -> nlp.Candidates:
    """Damping points of the envelope, decay-rate points, noise points (with a limit), and stability
    points per error scenario."""
    P = [model.make_points(W, T, model.nominal_estimate)]
    kind = [np.ones(W.size)]
    sigma = [np.zeros(W.size)]
    labels = [_label(w, t, wb) for w, t in zip(W, T, strict=True)]
    if settings.min_decay > 0:
        P.append(P[0])
        kind.append(np.zeros(W.size))
        sigma.append(np.full(W.size, settings.min_decay))
        labels += [
            _label(w, t, wb, f", decay >= {settings.min_decay:g} 1/s") for w, t in zip(W, T, strict=True)
        ]
    if max_noise is not None:
        P.append(P[0])
        kind.append(np.full(W.size, nlp.NOISE))
        sigma.append(np.zeros(W.size))
        labels += [_label(w, t, wb, ", noise") for w, t in zip(W, T, strict=True)]
    for name, est in error_scenarios(settings, model.nominal_estimate):
        P.append(model.make_points(W, T, est))
        kind.append(np.zeros(W.size))
        sigma.append(np.full(W.size, max(settings.min_decay, ROBUST_MARGIN * scale)))
        labels += [_label(w, t, wb, f", estimates {name}") for w, t in zip(W, T, strict=True)]
    return nlp.Candidates(np.hstack(P), np.concatenate(kind), np.concatenate(sigma), tuple(labels))


def _where(f: Figures, k: int, wb: float) -> dict[str, float]:
    return {"w_m_pu": float(f.w_m[k] / wb), "w_m_rad_s": float(f.w_m[k]), "T_e_Nm": float(f.T_e[k])}


def _table(drive: Any, settings: TuningSettings, r: TuneResult, scale: float) -> GainTable:
    wb = drive.w_base
    env = settings.envelope
    d, d0 = r.dense, r.dense_baseline
    m = r.model
    b = r.bound
    sd = None
    if r.seed is not None:  # the seed family's gains on the same dense grid
        sd = figures(r.seed.model, r.seed.theta, d.w_m, d.T_e, noise=r.seed.model.noise is not None)
    bj = None if b is None else np.searchsorted(b.speeds, d.w_m)
    points = []
    for j in range(d.w_m.size):
        pt = {
            "w_m_rad_s": float(d.w_m[j]),
            "w_m_pu": float(d.w_m[j] / wb),
            "T_e_Nm": float(d.T_e[j]),
            "lambda1": float(d.gains["lambda1_ohm"][j]),
            "lambda2": float(d.gains["lambda2_ohm"][j]),
            "poles": [[float(p.real), float(p.imag)] for p in d.poles[j]],
            "damping": float(d.damping[j]),
            "decay_rate": float(d.decay[j]),
            "baseline": {
                "lambda1": float(d0.gains["lambda1_ohm"][j]),
                "lambda2": float(d0.gains["lambda2_ohm"][j]),
                "poles": [[float(p.real), float(p.imag)] for p in d0.poles[j]],
                "damping": float(d0.damping[j]),
                "decay_rate": float(d0.decay[j]),
            },
        }
        if d.noise is not None:
            pt["noise"] = {o: float(v) for o, v in zip(m.noise_outputs, d.noise[j], strict=True)}
            pt["baseline"]["noise"] = {o: float(v) for o, v in zip(m.noise_outputs, d0.noise[j], strict=True)}
        if sd is not None:
            pt["seed"] = {
                "family": r.seed.family,
                "lambda1": float(sd.gains["lambda1_ohm"][j]),
                "lambda2": float(sd.gains["lambda2_ohm"][j]),
                "damping": float(sd.damping[j]),
                "decay_rate": float(sd.decay[j]),
            }
        if b is not None:
            k = int(bj[j])
            pt["bound"] = {
                "damping": float(b.damping[k]),
                **{nm: float(v) for nm, v in zip(b.names, b.theta[k], strict=True)},
            }
        points.append(pt)
    k, k0, kg = d.worst(), d0.worst(), r.grid.worst()
    summary: dict[str, Any] = {
        "worst_damping": float(d.damping[k]),
        "worst_damping_at": _where(d, k, wb),
        "baseline_worst_damping": float(d0.damping[k0]),
        "baseline_worst_damping_at": _where(d0, k0, wb),
        "min_decay_rate": float(np.min(d.decay)),
        "baseline_min_decay_rate": float(np.min(d0.decay)),
        "decay_floor_1_s": float(r.floor),
        "optimization_grid_worst_damping": float(r.grid.damping[kg]),
        "nlp_worst_damping": float(r.solution.t),
        "ipopt_iterations": int(r.solution.iterations),
        "exchange_rounds": int(r.solution.rounds),
        "global_phase": r.global_phase,
        "robust": r.robust,
        "selection": r.selection,
        "parameters": {n: float(v) for n, v in zip(m.names, r.theta, strict=True)},
        "baseline_parameters": {n: float(v) for n, v in zip(m.names, r.theta0, strict=True)},
        "sector_scale_1_s": scale,
    }
    if d.noise is not None:
        summary["noise"] = {
            "outputs": list(m.noise_outputs),
            "units": list(m.noise_units),
            "sigma_A": m.noise_sigma,
            "T_s_s": m.T_s,
            "convention": "per-axis rms sigma in each sample at T_s: white density sigma^2 T_s; "
            "RMS = sqrt(C P C^T + sigma^2 D D^T)",
            "tuned": [float(v) for v in d.worst_noise()],
            "baseline": [float(v) for v in d0.worst_noise()],
        }
    if sd is not None:
        ks = sd.worst()
        summary["seed"] = {
            "family": r.seed.family,
            "parameters": {n: float(v) for n, v in zip(r.seed.model.names, r.seed.theta, strict=True)},
            "worst_damping": float(sd.damping[ks]),
            "worst_damping_at": _where(sd, ks, wb),
            "min_decay_rate": float(np.min(sd.decay)),
            "worst_noise": None if sd.noise is None else [float(v) for v in sd.worst_noise()],
        }
    if b is not None:
        kb = b.worst()
        summary["bound"] = {
            "floor_1_s": float(b.floor),
            "worst_damping": float(b.damping[kb]),
            "worst_at_w_m_pu": float(b.speeds[kb] / wb),
            "gains_there": {nm: float(v) for nm, v in zip(b.names, b.theta[kb], strict=True)},
            "gap": float(b.damping[kb] - d.damping[k]),
            "feasible_everywhere": bool(b.feasible.all()),
            "infeasible_speeds": int((~b.feasible).sum()),
            "evaluations": int(b.evaluations),
        }
        if sd is not None:
            summary["bound"]["gap_seed"] = float(b.damping[kb] - sd.damping[sd.worst()])
        # per speed: the bound beside this family, its seed and the drive file's gains
        ws, zt = d.per_speed()
        _, z0 = d0.per_speed()
        dz0 = d0.decay_per_speed()
        zs = sd.per_speed()[1] if sd is not None else None
        summary["speeds"] = [
            {
                "w_m_pu": float(ws[i] / wb),
                "bound": float(b.damping[np.searchsorted(b.speeds, ws[i])]),
                "tuned": float(zt[i]),
                "baseline": float(z0[i]),
                # the bound is for gains decaying at least at its floor: the drive file's may not
                "baseline_meets_floor": bool(dz0[i] >= b.floor * (1 - 1e-6)),
                **({"seed": float(zs[i])} if zs is not None else {}),
            }
            for i in range(ws.size)
        ]
    if r.ridge is not None:
        summary["ridge"] = r.ridge
    if r.pareto is not None:
        summary["pareto"] = r.pareto
    W, _ = env.grid(wb, drive.T_N)
    Wd, _ = env.grid(wb, drive.T_N, env.dense_factor)
    envelope = {
        "speed_base_rad_s": wb,
        "speed_min_pu": env.speed_min,
        "speed_max_pu": env.speed_max,
        "directions": env.directions,
        "speeds_rad_s": env.speed_grid(wb),
        "torques_Nm": env.torque_grid(drive.T_N),
        "optimization_points": int(W.size),
        "dense_factor": env.dense_factor,
        "dense_speeds_rad_s": env.speed_grid(wb, env.dense_factor),
        "dense_torques_Nm": env.torque_grid(drive.T_N, env.dense_factor),
        "dense_points": int(Wd.size),
        "constraints": {
            "min_decay_1_s": settings.min_decay,
            "lambda_max_ohm": settings.lambda_max,
            "estimate_errors": dict(zip(ESTIMATE_KEYS, settings.errors, strict=True)),
            "smoothing": settings.smoothing,
            "max_noise": dict(settings.max_noise),
        },
        "bounds": {n: [float(lo), float(hi)] for n, lo, hi in zip(m.names, m.lower, m.upper, strict=True)},
    }
    return GainTable(
        family=r.family,
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains=m.table_gains(r.theta),
        envelope=envelope,
        points=points,
        summary=summary,
    )
