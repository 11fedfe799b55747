"""The tuner's result: figures of gains on a grid, the result of a tuning run, and its gain table.

What ``sensorless tune`` prints (``TuneResult.summary_lines``) and writes (the gain table of
design/gain_table.py, with the dense re-verification, the baseline, the bound, noise and the front) is
assembled here from the pipeline's numbers (tuning/tune.py).
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from sensorless.design.envelope import ESTIMATE_KEYS, TuningSettings, tuning_keys
from sensorless.design.family import Drive
from sensorless.design.gain_table import GainTable
from sensorless.design.memo import OwnedMemo
from sensorless.tuning import nlp
from sensorless.tuning.bound import Bound
from sensorless.tuning.model import TuningModel, evaluate


@dataclass(frozen=True)
class Figures:
    """Closed-loop figures of one gain set on a grid."""

    w_m: np.ndarray  # [rad/s]
    T_e: np.ndarray  # [N m]
    poles: np.ndarray  # (N, n) [1/s]
    damping: np.ndarray  # worst damping per point
    decay: np.ndarray  # -max Re per point [1/s]
    gains: dict[str, np.ndarray]  # the law's gains per point, keyed as in the gain table's points
    noise: np.ndarray | None = None  # (N, n_out) RMS of the noise outputs (design/noise.py)
    # (N,) the model's bounded figures' margin (tuning/model.py Evaluation.bounded); None: none bounded
    bounded: np.ndarray | None = None

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


class RobustCase(TypedDict):
    """The tuned gains under one corner of the estimate-error box (tuning/conditions.py ``robust``)."""

    scenario: str  # e.g. "R_s+30%,psi_pm-10%"
    estimate: np.ndarray  # the law's estimates there
    max_real_1_s: float  # the worst max Re of the poles on the dense grid
    at_w_m_pu: float
    at_T_e_Nm: float
    stable: bool


@dataclass(frozen=True)
class TuneResult:
    """Everything ``sensorless tune`` reports."""

    law: str
    model: TuningModel
    theta: np.ndarray
    theta0: np.ndarray
    solution: nlp.Solution  # the best NLP result (its t is the NLP's, not the verified value)
    grid: Figures  # tuned gains on the optimization grid
    dense: Figures  # tuned gains on the re-verification grid
    dense_baseline: Figures  # the drive file's gains on the re-verification grid
    robust: list[RobustCase]  # per error scenario: worst max Re on the dense grid
    table: GainTable  # (None in a seed law's result: tuning/tune.py tabulates only the law it returns)
    seconds: float
    selection: dict[str, Any]  # which dense-verified candidate was kept and why
    floor: float = 0.0  # the decay floor the law was tuned under [1/s]
    bound: Bound | None = None  # the pointwise bound on the dense speeds
    seed: TuneResult | None = None  # the seed law's result (Tunable.seed)
    ridge: dict[str, Any] | None = None  # the worst point, if no parameter of the law moves it
    pareto: list[dict[str, Any]] | None = None  # damping-versus-noise front
    global_phase: dict[str, Any] = dataclasses.field(default_factory=dict)
    # IPOPT runs that failed within an NLP run and were retried with half the trust region (said in the
    # summary: a feasible start that ends Infeasible_Problem_Detected is not left unreported)
    nlp_retried: tuple[str, ...] = ()

    def summary_lines(self, drive: Drive) -> list[str]:
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
        failed = g.get("nlp_failed") or []
        if failed:  # said here too: --quiet hides the progress line that said it first
            nlp_from += f"; the NLP failed from {len(failed)} of them ({failed[0]}): the best start is kept"
        out = [
            f"global phase: {g.get('candidates', 0)} candidate gains, {g.get('feasible', 0)} meeting every "
            f"constraint; {nlp_from}",
            f"optimized over {env['optimization_points']} points in {s['exchange_rounds']} exchange rounds "
            f"({s['ipopt_iterations']} IPOPT iterations); re-verified on {env['dense_points']} points "
            f"({env['dense_factor']}x denser) in {self.seconds:.1f} s",
        ]
        seeded = self.seed is not None
        head = f"{'':<22}{'drive file':>18}" + (f"{self.seed.law:>18}" if seeded else "") + f"{'tuned':>18}"
        out.append(head)
        for n, u, v0, v in zip(self.model.names, self.model.units, self.theta0, self.theta, strict=True):
            if u == "rad/s":
                out.append(f"{n + ' [p.u.]':<22}{v0 / wb:>18.4g}{'':>{18 * seeded}}{v / wb:>18.4g}")
            elif self.model.n_theta <= 6:
                out.append(f"{n + ' [' + u + ']':<22}{v0:>18.4g}{'':>{18 * seeded}}{v:>18.4g}")

        def where(a: Mapping[str, float]) -> str:
            return f"at {a['w_m_pu']:+.3f} p.u., {a['T_e_Nm']:+.3g} N m"

        sd = s.get("seed", {})
        mid = f"{sd['worst_damping']:>18.4f}" if seeded else ""
        out += [
            f"{'worst damping':<22}{s['baseline_worst_damping']:>18.4f}{mid}{s['worst_damping']:>18.4f}",
            f"{'  where':<22}{where(s['baseline_worst_damping_at']):>36}",
        ]
        if seeded:
            out.append(f"{'':<22}{where(sd['worst_damping_at']):>36} ({self.seed.law})")
        out.append(f"{'':<22}{where(s['worst_damping_at']):>36}")
        mid = f"{sd['min_decay_rate']:>18.4g}" if seeded else ""
        out.append(
            f"{'slowest decay [1/s]':<22}{s['baseline_min_decay_rate']:>18.4g}{mid}"
            f"{s['min_decay_rate']:>18.4g}"
        )
        gs = s.get("gain_size")
        if gs:
            mid = f"{'':>18}" if seeded else ""
            head = f"gain size [{self.model.gain_size_unit}]"
            out.append(f"{head:<22}{gs['baseline']:>18.4g}{mid}{gs['tuned']:>18.4g}")
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
            + (
                f"(NLP: {nlp_t:.4f})"
                if np.isfinite(nlp_t)
                else "(the NLP failed, above)"
                if failed
                else "(no NLP run)"
            )
            + "; the table reports the dense re-verification"
        )
        for res, whose in ((self.seed, f" ({self.seed.law}, the start)" if self.seed else ""), (self, "")):
            if res is not None and res.nlp_retried:
                out.append(
                    f"IPOPT failed and was retried with half the trust region{whose}: "
                    + "; ".join(
                        note if n == 1 else f"{note} ({n} times, one per halving)"
                        for note, n in collections.Counter(res.nlp_retried).items()
                    )
                )
        if s.get("selection"):
            out.append(f"kept: {s['selection']['text']}")
            if s["selection"].get("tie_break"):
                out.append(s["selection"]["tie_break"]["text"])
        b = s.get("bound")
        if b:
            out.append(
                "bound (best worst-case damping of any gain at each speed, "
                f"decay >= {b['floor_1_s']:.4g} 1/s): "
                f"worst {b['worst_damping']:.4f} at {b['worst_at_w_m_pu']:+.3f} p.u.; tuned "
                f"{s['worst_damping']:.4f}, {b['gap']:.4f} below it"
                + (f"; {self.seed.law} {b['gap_seed']:.4f} below" if seeded and "gap_seed" in b else "")
            )
            if not b["feasible_everywhere"]:
                out.append(f"  no gain meets the floor at {b['infeasible_speeds']} dense speeds")
        r = s.get("ridge")
        if r:
            out.append(r["text"])
        if s.get("law_note"):
            out.append(s["law_note"])
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


# figures' memo: a tune asks for the same gains on the same grid again and again (the drive file's gains
# on the dense grid in every selection and as the table's baseline, the kept gains in the tie-break and
# the table, a seed's gains in its law's table: 7 of 23 calls, 0.26 s CPU on the README servo)
_FIGURES: OwnedMemo[Figures] = OwnedMemo(32)


def figures(
    model: TuningModel, theta: np.ndarray, w: np.ndarray, T: np.ndarray, est=None, noise: bool = False
) -> Figures:
    """Poles, damping, decay rate, gains (and noise) of ``theta`` at the points (w, T). The same
    arguments give the same (read-only) Figures object: the evaluation is deterministic, computed once."""
    est = model.nominal_estimate if est is None else est
    noise = noise and model.noise is not None
    parts = [np.asarray(a, float) for a in (theta, w, T, est)]
    key = repr([(a.shape, noise) for a in parts]).encode() + b"".join(a.tobytes() for a in parts)
    hit = _FIGURES.get(model, key)
    if hit is not None:
        return hit
    e = evaluate(model, theta, model.make_points(w, T, est), noise=noise)
    f = Figures(w, T, e.poles, e.damping, e.decay, model.point_gains(theta, w), e.noise, e.bounded)
    for a in (f.poles, f.damping, f.decay, f.noise, f.bounded, *f.gains.values()):  # (w, T: the caller's)
        if isinstance(a, np.ndarray):
            a.flags.writeable = False
    return _FIGURES.put(model, key, f)


def where(f: Figures, k: int, wb: float) -> dict[str, float]:
    return {"w_m_pu": float(f.w_m[k] / wb), "w_m_rad_s": float(f.w_m[k]), "T_e_Nm": float(f.T_e[k])}


def gain_table(drive: Drive, settings: TuningSettings, r: TuneResult, scale: float) -> GainTable:
    wb = drive.w_base
    env = settings.envelope
    d, d0 = r.dense, r.dense_baseline
    m = r.model
    b = r.bound
    sd = None
    if r.seed is not None:  # the seed law's gains on the same dense grid
        sd = figures(r.seed.model, r.seed.theta, d.w_m, d.T_e, noise=r.seed.model.noise is not None)
    bj = None if b is None else np.searchsorted(b.speeds, d.w_m)

    def col(v: np.ndarray) -> list:
        """The values as Python floats, one per point (``tolist``: each float(v[j]), in one call)."""
        return np.asarray(v, float).tolist()

    def poles(p: np.ndarray) -> list:
        """Per point, its poles as [re, im] pairs of Python floats."""
        pairs = zip(col(p.real), col(p.imag), strict=True)
        return [[list(ri) for ri in zip(re, im, strict=True)] for re, im in pairs]

    wm, tq, wpu = col(d.w_m), col(d.T_e), col(d.w_m / wb)
    g1, g0 = {k: col(v) for k, v in d.gains.items()}, {k: col(v) for k, v in d0.gains.items()}
    p1, p0 = poles(d.poles), poles(d0.poles)
    z1, z0, r1, r0 = col(d.damping), col(d0.damping), col(d.decay), col(d0.decay)
    n1 = None if d.noise is None else col(d.noise)
    n0 = None if d.noise is None else col(d0.noise)
    if sd is not None:
        gs, zs, rs = {k: col(v) for k, v in sd.gains.items()}, col(sd.damping), col(sd.decay)
    if b is not None:
        bz, bt = col(b.damping), col(b.theta)
    points = []
    for j in range(d.w_m.size):
        pt = {
            "w_m_rad_s": wm[j],
            "w_m_pu": wpu[j],
            "T_e_Nm": tq[j],
            **{k: v[j] for k, v in g1.items()},
            "poles": p1[j],
            "damping": z1[j],
            "decay_rate": r1[j],
            "baseline": {
                **{k: v[j] for k, v in g0.items()},
                "poles": p0[j],
                "damping": z0[j],
                "decay_rate": r0[j],
            },
        }
        if n1 is not None and n0 is not None:
            pt["noise"] = dict(zip(m.noise_outputs, n1[j], strict=True))
            pt["baseline"]["noise"] = dict(zip(m.noise_outputs, n0[j], strict=True))
        if sd is not None:
            pt["seed"] = {
                "law": r.seed.law,
                **{k: v[j] for k, v in gs.items()},
                "damping": zs[j],
                "decay_rate": rs[j],
            }
        if b is not None:
            k = int(bj[j])
            pt["bound"] = {
                "damping": bz[k],
                **dict(zip(b.names, bt[k], strict=True)),
            }
        points.append(pt)
    k, k0, kg = d.worst(), d0.worst(), r.grid.worst()
    summary: dict[str, Any] = {
        "worst_damping": float(d.damping[k]),
        "worst_damping_at": where(d, k, wb),
        "baseline_worst_damping": float(d0.damping[k0]),
        "baseline_worst_damping_at": where(d0, k0, wb),
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
    if m.gain_size is not None:  # tuning/tiebreak.py: smaller wins among equally damped gains
        g0, g1 = m.gain_size(np.vstack([r.theta0, r.theta]))
        summary["gain_size"] = {"baseline": float(g0), "tuned": float(g1)}
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
            "law": r.seed.law,
            "parameters": {n: float(v) for n, v in zip(r.seed.model.names, r.seed.theta, strict=True)},
            "worst_damping": float(sd.damping[ks]),
            "worst_damping_at": where(sd, ks, wb),
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
        # per speed: the bound beside this law, its seed and the drive file's gains
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
    if m.note:
        summary["law_note"] = m.note
    if r.pareto is not None:
        summary["pareto"] = r.pareto
    W, _ = env.grid()
    Wd, _ = env.grid(env.dense_factor, env.dense_factor)
    keys = tuning_keys(env)
    envelope = {
        "speed_base_rad_s": wb,
        "speed_min_pu": keys["speed_min"],
        "speed_max_pu": keys["speed_max"],
        "directions": keys["directions"],
        "speeds_rad_s": env.speed_grid(),
        "torques_Nm": env.torque_grid(),
        "optimization_points": int(W.size),
        "dense_factor": env.dense_factor,
        "dense_speeds_rad_s": env.speed_grid(env.dense_factor),
        "dense_torques_Nm": env.torque_grid(env.dense_factor),
        "dense_points": int(Wd.size),
        "constraints": {
            "min_decay_1_s": settings.min_decay,
            "estimate_errors": dict(zip(ESTIMATE_KEYS, settings.errors, strict=True)),
            "smoothing": settings.smoothing,
            "max_noise": dict(settings.max_noise),
            **settings.law.constraints(),
        },
        "bounds": {n: [float(lo), float(hi)] for n, lo, hi in zip(m.names, m.lower, m.upper, strict=True)},
    }
    return GainTable(
        law=r.law,
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains=m.table_gains(r.theta),
        envelope=envelope,
        points=points,
        summary=summary,
    )
