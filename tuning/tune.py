"""Gain tuning end to end: envelope -> NLP -> dense re-verification -> gain table.

``tune(drive, name)`` tunes the tunable gain family ``name`` of the drive's observer family (tuning/
family.py): with its own tuner if it has one, else by the shared pipeline below on the TuningModel it
builds. The numbers a user sees (terminal summary, CSV, JSON) are all from the *re-verification*: the
eigenvalues of the linearized closed loop on a grid ``dense_factor`` (>= 4) times denser in speed and
in torque than the grid the NLP optimized over, for the tuned gains and for the drive file's gains
(the baseline).
The NLP's own value of the worst damping is kept in the summary only for comparison.
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
from sensorless.design.poles import max_real, worst_damping
from sensorless.tuning import nlp
from sensorless.tuning.family import tunable_for
from sensorless.tuning.model import TuningModel, poles

ROBUST_MARGIN = 1e-3  # under estimate errors require max Re(p) <= -ROBUST_MARGIN * scale (strictly stable)


@dataclass(frozen=True)
class Figures:
    """Closed-loop figures of one gain set on a grid."""

    w_m: np.ndarray  # [rad/s]
    T_e: np.ndarray  # [N m]
    poles: np.ndarray  # (N, n) [1/s]
    damping: np.ndarray  # worst damping per point
    decay: np.ndarray  # -max Re per point [1/s]
    gains: dict[str, np.ndarray]  # lambda1_ohm, lambda2_ohm per point

    def worst(self) -> int:
        """Index of the worst-damped point (NaN counts as worst)."""
        return int(np.argmin(np.where(np.isfinite(self.damping), self.damping, -np.inf)))


@dataclass(frozen=True)
class TuneResult:
    """Everything ``sensorless tune`` reports."""

    family: str
    model: TuningModel
    theta: np.ndarray
    theta0: np.ndarray
    solution: nlp.Solution  # the exchange method's result (its t is the NLP's, not the verified value)
    grid: Figures  # tuned gains on the optimization grid
    dense: Figures  # tuned gains on the re-verification grid
    dense_baseline: Figures  # the drive file's gains on the re-verification grid
    robust: list[dict[str, Any]]  # per error scenario: worst max Re on the dense grid
    table: GainTable
    seconds: float
    selection: dict[str, Any]  # which dense-verified candidate was kept and why ({}: the NLP's)

    def summary_lines(self, drive: Any) -> list[str]:
        """The terminal summary: parameters and worst damping before -> after, and where."""
        s = self.table.summary
        wb = drive.w_base
        env = self.table.envelope
        out = [
            f"optimized over {env['optimization_points']} points in {s['exchange_rounds']} exchange rounds "
            f"({s['ipopt_iterations']} IPOPT iterations); re-verified on {env['dense_points']} points "
            f"({env['dense_factor']}x denser) in {self.seconds:.1f} s",
            f"{'':<22}{'drive file':>18}{'tuned':>18}",
        ]
        for n, u, v0, v in zip(self.model.names, self.model.units, self.theta0, self.theta, strict=True):
            if u == "rad/s":
                out.append(f"{n + ' [p.u.]':<22}{v0 / wb:>18.4g}{v / wb:>18.4g}")
            elif self.model.n_theta <= 6:
                out.append(f"{n + ' [' + u + ']':<22}{v0:>18.4g}{v:>18.4g}")

        def where(key: str) -> str:
            a = s[key]
            return f"at {a['w_m_pu']:+.3f} p.u., {a['T_e_Nm']:+.3g} N m"

        out += [
            f"{'worst damping':<22}{s['baseline_worst_damping']:>18.4f}{s['worst_damping']:>18.4f}",
            f"{'  where':<22}{where('baseline_worst_damping_at'):>36}",
            f"{'':<22}{where('worst_damping_at'):>36}",
            f"{'slowest decay [1/s]':<22}{s['baseline_min_decay_rate']:>18.4g}{s['min_decay_rate']:>18.4g}",
            f"worst damping on the optimization grid {s['optimization_grid_worst_damping']:.4f} "
            f"(NLP: {s['nlp_worst_damping']:.4f}); the table reports the dense re-verification",
        ]
        if s.get("selection"):
            out.append(f"kept: {s['selection']['text']}")
        for rb in s["robust"]:
            out.append(
                f"estimates {rb['scenario']}: max Re(p) = {rb['max_real_1_s']:.4g} 1/s at "
                f"{rb['at_w_m_pu']:+.3f} p.u., {rb['at_T_e_Nm']:+.3g} N m "
                f"({'stable' if rb['stable'] else 'UNSTABLE'})"
            )
        return out


def figures(model: TuningModel, theta: np.ndarray, w: np.ndarray, T: np.ndarray, est=None) -> Figures:
    """Poles, damping, decay rate and gains of ``theta`` at the points (w, T)."""
    est = model.nominal_estimate if est is None else est
    p, _ = poles(model, theta, model.make_points(w, T, est))
    return Figures(w, T, p, worst_damping(p), -max_real(p), model.point_gains(theta, w))


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
    TuneResult (or the own tuner's result). Raises nlp.TuningError if IPOPT fails or the constraints
    cannot be met, CapabilityError if the family cannot be tuned."""
    tunable = tunable_for(drive, family)
    family = tunable.name
    settings = settings if settings is not None else tunable.settings(drive)
    if tunable.tuner is not None:  # e.g. the reduced-order observer's deangelo family
        return tunable.tuner(drive, settings, progress)
    t_start = time.perf_counter()
    say = progress or (lambda s: None)
    seed_theta = None
    if tunable.seed is not None:
        seed_name = tunable.seed
        say(f"{family}: tuning its start, the {seed_name} family, first")
        seed_res = tune(drive, seed_name, settings, progress=lambda m: say(f"  [{seed_name}] {m}"))
        seed_theta = seed_res.theta
    model = tunable.build(drive, settings, seed_theta)
    env = settings.envelope
    wb, T_N = drive.w_base, drive.T_N
    W, T = env.grid(wb, T_N)
    theta0 = np.clip(model.theta0, model.lower, model.upper)
    start = theta0 if model.start is None else np.clip(model.start, model.lower, model.upper)
    base = figures(model, theta0, W, T)
    if not np.isfinite(base.poles).all():
        raise nlp.TuningError("the drive file's gains have no closed-loop equilibrium on the envelope")
    scale = float(np.abs(base.poles).max())

    if model.start is not None:
        # Damping alone would trade decay for damping (a pole creeping to the origin has damping 1):
        # a started family must keep at least the start's decay rate on the grid.
        start_decay = float(np.min(figures(model, start, W, T).decay))
        if start_decay > settings.min_decay:
            say(f"keeping the start's decay rate: >= {start_decay:.4g} 1/s at every point")
            settings = dataclasses.replace(settings, min_decay=start_decay)
    _check_error_equilibria(model, settings, start, W, T, wb)
    cand = _candidates(model, settings, W, T, wb, scale)
    say(
        f"{family}: {model.n_theta} parameters, {W.size} envelope points"
        f"{f', {cand.size - W.size} constraint points' if cand.size > W.size else ''}; "
        f"drive file's gains: worst damping {base.damping.min():.4f}"
    )
    say(
        "maximize the worst damping (IPOPT, sector conditions)"
        + (f", starting from the {model.start_label}" if model.start is not None else "")
    )
    Wd, Td = env.grid(wb, T_N, env.dense_factor)
    try:
        s1 = nlp.solve(model, cand, start, scale, smoothing=settings.smoothing, progress=say)
    except nlp.TuningError as e:
        if model.start is None:
            raise
        # the start is a verified solution of its own family: report it rather than fail
        say(f"the NLP failed ({e}); keeping the {model.start_label}")
        s1 = nlp.Solution(start, float("nan"), (), 0, 0, ())
    say(f"re-verifying on the {env.dense_factor}x denser grid")
    theta, dense, note = _select(model, s1, start, Wd, Td, say)
    dense0 = figures(model, theta0, Wd, Td)
    grid = figures(model, theta, W, T)
    if not np.isfinite(dense.damping).all():
        k = int(np.flatnonzero(~np.isfinite(dense.damping))[0])
        raise nlp.TuningError(f"tuned gains: no closed-loop equilibrium at {_label(Wd[k], Td[k], wb)}")
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
    seconds = time.perf_counter() - t_start
    result = TuneResult(
        family=family,
        model=model,
        theta=theta,
        theta0=theta0,
        solution=s1,
        grid=grid,
        dense=dense,
        dense_baseline=dense0,
        robust=robust,
        table=None,  # type: ignore[arg-type]  (filled below from the result itself)
        seconds=seconds,
        selection=note,
    )
    table = _table(drive, settings, result, scale)
    return dataclasses.replace(result, table=table)


def _worst(f: Figures) -> float:
    """Worst damping of a grid; -inf if any point has no equilibrium."""
    return float(np.min(f.damping)) if np.isfinite(f.damping).all() else -np.inf


def _select(
    model: TuningModel, s1: nlp.Solution, start: np.ndarray, Wd: np.ndarray, Td: np.ndarray, say
) -> tuple[np.ndarray, Figures, dict[str, Any]]:
    """The NLP's final gains, or, for a family with a start of its own (``model.start``), the best
    on the dense grid among the start and every round the exchange method verified on its grid.

    A free schedule is only checked at the grid speeds by the NLP; between them it may be worse
    (even unstable), which only the dense grid shows. Re-verifying each candidate densely and
    keeping the best means the reported gains are never worse than the start (for the schedule:
    the tuned law16, which it reproduces exactly)."""
    final = figures(model, s1.theta, Wd, Td)
    if model.start is None:
        return s1.theta, final, {}
    cands = [("start", start, figures(model, start, Wd, Td))]
    for k, th in enumerate(s1.verified[:-1]):
        cands.append(
            (f"exchange round {k + 1} of {len(s1.verified)} verified", th, figures(model, th, Wd, Td))
        )
    if s1.verified:
        cands.append(("NLP solution", s1.theta, final))
    decay0 = float(np.min(cands[0][2].decay))

    def rank(i: int) -> tuple[bool, float, int]:
        # never slower than the start: admissible first, then the worst damping; ties: the later
        f = cands[i][2]
        return (bool(np.min(f.decay) >= decay0 * (1 - 1e-6)), _worst(f), i)

    best = max(range(len(cands)), key=rank)
    name, theta, dense = cands[best]
    w_start, w_final = _worst(cands[0][2]), _worst(final) if s1.verified else float("nan")
    if name == "start":
        text = (
            f"kept the start ({model.start_label}): on the dense grid the NLP's gains reach a worst "
            f"damping of {w_final:.4f} (start {w_start:.4f}) and a slowest decay of "
            f"{np.min(final.decay):.4g} 1/s (start {decay0:.4g} 1/s): worse between the optimization "
            "grid points"
        )
    elif name == "NLP solution":
        text = f"NLP solution; the start ({model.start_label}) had {w_start:.4f} on the dense grid"
    else:
        text = (
            f"{name} (the final NLP solution has {w_final:.4f} on the dense grid, the start "
            f"({model.start_label}) {w_start:.4f})"
        )
    say(text)
    return (
        theta,
        dense,
        {
            "selected": name,
            "start": model.start_label,
            "start_worst_damping": w_start,
            "nlp_solution_worst_damping": w_final,
            "text": text,
        },
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
    model: TuningModel, settings: TuningSettings, W: np.ndarray, T: np.ndarray, wb: float, scale: float
) -> nlp.Candidates:
    """Damping points of the envelope, decay-rate points, and stability points per error scenario."""
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
    points = []
    for j in range(d.w_m.size):
        points.append(
            {
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
        )
    k, k0, kg = d.worst(), d0.worst(), r.grid.worst()
    m = r.model
    summary = {
        "worst_damping": float(d.damping[k]),
        "worst_damping_at": _where(d, k, wb),
        "baseline_worst_damping": float(d0.damping[k0]),
        "baseline_worst_damping_at": _where(d0, k0, wb),
        "min_decay_rate": float(np.min(d.decay)),
        "baseline_min_decay_rate": float(np.min(d0.decay)),
        "optimization_grid_worst_damping": float(r.grid.damping[kg]),
        "nlp_worst_damping": float(r.solution.t),
        "ipopt_iterations": int(r.solution.iterations),
        "exchange_rounds": int(r.solution.rounds),
        "robust": r.robust,
        "selection": r.selection,
        "parameters": {n: float(v) for n, v in zip(m.names, r.theta, strict=True)},
        "baseline_parameters": {n: float(v) for n, v in zip(m.names, r.theta0, strict=True)},
        "sector_scale_1_s": scale,
    }
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
