"""Which verified candidate the tuner keeps, and what the result says about the law: selection among
the dense-verified candidates, ridges (a worst point no parameter of the law moves), and the
evidence of an infeasible envelope."""

from __future__ import annotations

from typing import Any

import numpy as np
from sensorless.tuning import nlp
from sensorless.tuning.bound import Bound, pointwise_bound
from sensorless.tuning.candidates import BOUNDED_SLACK, meets_floor
from sensorless.tuning.model import TuningModel, evaluate
from sensorless.tuning.result import Figures, figures
from sensorless.tuning.slots import T_MAX

# The worst point is a ridge when no parameter moves its damping: |d damping / d theta_i| * typical_i
# below this for every i, i.e. a 10 % change of any parameter moves the damping by less than 1e-3.
RIDGE_TOL = 1e-2
# Candidates within this of the best worst damping tie (the faster slowest decay wins; the tie-break of
# tuning/tiebreak.py uses the same tolerance): below what the tuner resolves and below anything a time
# response shows (the overshoot moves by < 0.13 percentage points at any damping >= 0.1; docs/tuning.md).
TIE = 5e-4
DRIVE_FILE = "drive file's gains"  # the label of the drive file's gains among the starts


ENVELOPE_INFEASIBLE = "the envelope is infeasible"  # no gain at all at some speed


def infeasible(
    drive, model, settings, cand, ranked, scale, max_noise, say, known: Bound | None = None
) -> str:
    """The message of an infeasible envelope, with its evidence. ``known``: a pointwise bound this tuning
    computed already with the same decay floor, pole scale and noise limits (a seeded law's, on the dense
    grid): where its speeds and torques hold the envelope's and it found gains meeting the constraints
    at every speed, those gains are the evidence at every envelope speed, and no search is run again
    (the README servo's handover floor: 0.3-0.5 s of a 9 s tune)."""
    wb = drive.w_base
    env = settings.envelope
    worst = cand.labels[int(ranked.worst_point[0])]
    what = f"stable with decay >= {settings.min_decay:g} 1/s" if settings.min_decay > 0 else "stable"
    if max_noise is not None:
        what += " within the noise limits"
    if model.pointwise is None:
        return (
            f"no {model.law} gains found that are {what} at every envelope point: the best of "
            f"{ranked.evaluated} candidates fails at {worst} (margin {ranked.margin[0]:.3g})"
        )
    speeds = env.speed_grid()
    torques = env.torque_grid()
    say("no feasible candidate: is any gain at all feasible at each envelope speed?")
    if _covers(known, speeds, torques, settings.min_decay):
        names = known.names  # type: ignore[union-attr]
        say(
            f"  yes: the pointwise bound's gains (decay >= {settings.min_decay:.4g} 1/s, "
            "on a grid holding the envelope's)"
        )
        return _shape_limit(model, what, ranked, worst, names)
    b = pointwise_bound(model.pointwise(), speeds, torques, settings.min_decay, scale, max_noise, coarse=1)
    bad = np.flatnonzero(~b.feasible)
    if bad.size:
        pts = "; ".join(
            f"{speeds[j] / wb:+.3f} p.u. (best slowest decay {b.decay[j]:.4g} 1/s)" for j in bad[:6]
        )
        todo = ""
        if settings.min_decay > 0:
            best = float(np.min(b.decay[bad]))
            todo = f": lower --min-decay to at most {best:.4g} 1/s, or narrow the envelope"
        return (
            f"{ENVELOPE_INFEASIBLE}: at {bad.size} of {speeds.size} envelope speeds no gain "
            f"({', '.join(b.names)} anywhere in the box) is {what} at every torque, so no gain law is: "
            f"{pts}{' and more' if bad.size > 6 else ''}{todo}"
        )
    return _shape_limit(model, what, ranked, worst, b.names)


def _shape_limit(model, what: str, ranked, worst: str, names: tuple[str, ...]) -> str:
    """The message of an envelope where some gain meets the constraints at every speed, but no gain of
    the law found does at every point."""
    return (
        f"no {model.law} gains found that are {what} at every envelope point (best of "
        f"{ranked.evaluated} candidates and a margin search: fails at {worst}, margin "
        f"{ranked.margin[0]:.3g}); at every envelope speed some gain ({', '.join(names)}) is, so the "
        f"limit is the {model.law} law's shape: try another law"
    )


def _covers(known: Bound | None, speeds: np.ndarray, torques: np.ndarray, floor: float) -> bool:
    """Whether ``known`` shows gains meeting the constraints at each of ``speeds`` at every one of
    ``torques``: its floor is ``floor``, its grid holds both exactly, and it is feasible at every
    speed of its own (so at theirs, over its torques, which hold theirs)."""
    return (
        known is not None
        and known.floor == floor
        and bool(np.all(known.feasible))
        and bool(np.all(np.isin(speeds, known.speeds)))
        and bool(np.all(np.isin(torques, known.torques)))
    )


def select(
    model: TuningModel,
    sols: list[nlp.Solution],
    pool: list[tuple[str, np.ndarray]],
    Wd: np.ndarray,
    Td: np.ndarray,
    floor: float,
    max_noise: np.ndarray | None,
    say,
    scale: float,
) -> tuple[np.ndarray, Figures, dict[str, Any], nlp.Solution | None]:
    """The best on the dense grid among the starts (``pool``: the drive file's gains, a seed's, the
    global phase's) and every round each NLP verified on its grid.

    The NLP only checks its grid; between those points a law of many parameters may be worse (even
    unstable), which only the dense grid shows. Admissible: decay >= the floor (with the NLP's
    tolerance) and noise within its limits on the dense grid; among those, the best worst damping.
    So the reported gains are never worse than the drive file's or a seed's when those are
    admissible. The floor is met as in every other step (``candidates.meets_floor``, with the pole
    scale ``scale``)."""
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
        ok = bool(np.all(meets_floor(f.decay, floor, scale)))
        if ok and f.bounded is not None:  # the family's bounded figures (tuning/model.py)
            ok = bool(np.all(f.bounded >= -BOUNDED_SLACK))
        if ok and use_noise:
            ok = bool(np.all(f.worst_noise() <= max_noise * (1 + 1e-6)))
        return ok

    def rank(i: int) -> tuple[bool, float, int]:
        f = cands[i][2]
        return (admissible(f), f.worst_damping(), i)

    top = max(range(len(cands)), key=rank)
    # ties (within TIE in damping, e.g. along a ridge): the faster slowest decay; laws
    # with a gain size then go through the tie-break of tuning/tiebreak.py (the smallest gains win)
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
    drive_file = [k for k in starts if k.startswith(DRIVE_FILE)]  # (in the law's box, if it holds some)
    seed_start = [v for k, v in starts.items() if k not in drive_file]
    return (
        theta,
        figures(model, theta, Wd, Td, noise=model.noise is not None),
        {
            "selected": name,
            "start": model.start_label,
            "start_worst_damping": seed_start[0] if model.start is not None else starts[drive_file[0]],
            "nlp_solution_worst_damping": max(finals.values()) if finals else float("nan"),
            "best_worst_damping": rank(top)[1],
            "admissible": rank(best)[0],
            "candidates": {k: v for k, v in {**starts, **finals}.items()},
            "text": text,
        },
        sol,
    )


def ridge_of(model: TuningModel, theta: np.ndarray, dense: Figures, bound: Bound | None, wb: float, say):
    """The worst point, and whether any parameter of the law moves its damping: central
    differences of its worst damping in each parameter (scaled by its typical magnitude). If none
    exceeds RIDGE_TOL, the law cannot improve that point: its optimum is a ridge there."""
    k = dense.worst()
    if dense.damping[k] >= T_MAX:  # damping 1 everywhere: nothing to improve
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
        f"{model.law} parameter (|d damping/d theta| <= {np.max(np.abs(g)):.1e} per typical magnitude): "
        f"the {model.law} law cannot improve it"
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
