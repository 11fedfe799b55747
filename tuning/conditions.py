"""The conditions the shared pipeline tunes under: estimate-error scenarios, the points of the NLP and
the global phase (damping, decay floor, noise, stability under errors), and the checks that the tuned
gains hold under the stated estimate errors (tuning/tune.py)."""

from __future__ import annotations

import itertools

import numpy as np
from sensorless.design.envelope import ESTIMATE_KEYS, TuningSettings
from sensorless.tuning import nlp
from sensorless.tuning.candidates import NOISE, Candidates
from sensorless.tuning.model import TuningModel
from sensorless.tuning.result import RobustCase, figures

# Under estimate errors the gains must be strictly stable: max Re(p) <= -ROBUST_MARGIN * scale (the pole
# scale), a margin far above the NLP's tolerance (search.FEASIBILITY_TOL = 1e-7) so that "stable" is not
# met by rounding; the tie-break checks its candidates with the same margin (tuning/tiebreak.py).
ROBUST_MARGIN = 1e-3


def error_scenarios(settings: TuningSettings, model: TuningModel) -> list[tuple[str, np.ndarray]]:
    """Corners of the stated estimate-error box: every combination of +-error on each estimate with a
    nonzero error (2^m scenarios), on the law's nominal estimates (``TuningModel.estimate_names``).
    Labelled like '<name>+30%,<name>-10%'. TuningError if the law's points carry no such estimate."""
    nominal = model.nominal_estimate
    keys = []
    for name, e in zip(ESTIMATE_KEYS, settings.errors, strict=True):
        if e > 0:
            if name not in model.estimate_names:
                raise nlp.TuningError(
                    f"gain law {model.law} has no estimate {name}: an error of it does not apply"
                )
            keys.append((model.estimate_names.index(name), name, e))
    out = []
    for signs in itertools.product((1, -1), repeat=len(keys)):
        est = nominal.copy()
        parts = []
        for (k, name, e), s in zip(keys, signs, strict=True):
            est[k] = nominal[k] * (1 + s * e)
            parts.append(f"{name}{'+' if s > 0 else '-'}{100 * e:g}%")
        out.append((",".join(parts), est))
    return out if keys else []


def label(w: float, T: float, w_base: float, extra: str = "") -> str:
    return f"w_m = {w / w_base:+.3f} p.u., T_e = {T:+.3g} N m{extra}"


def robust(model, settings, theta, Wd, Td, wb) -> list[RobustCase]:
    """Per estimate-error scenario the worst max Re of the poles on the dense grid, and where; raises
    TuningError if the gains are unstable under one."""
    out: list[RobustCase] = []
    for name, est in error_scenarios(settings, model):
        f = figures(model, theta, Wd, Td, est)
        mr = np.where(np.isfinite(f.decay), -f.decay, np.inf)
        k = int(np.argmax(mr))
        out.append(
            {
                "scenario": name,
                "estimate": est,
                "max_real_1_s": float(mr[k]),
                "at_w_m_pu": float(Wd[k] / wb),
                "at_T_e_Nm": float(Td[k]),
                "stable": bool(mr[k] < 0),
            }
        )
    unstable = [r for r in out if not r["stable"]]
    if unstable:
        r = unstable[0]
        raise nlp.TuningError(
            f"tuned gains are not stable under estimate errors {r['scenario']} at "
            f"w_m = {r['at_w_m_pu']:+.3f} p.u., T_e = {r['at_T_e_Nm']:+.3g} N m on the dense grid "
            f"(max Re = {r['max_real_1_s']:.3g} 1/s): use more --speeds"
        )
    return out


def check_error_equilibria(
    model: TuningModel, settings: TuningSettings, theta: np.ndarray, W: np.ndarray, T: np.ndarray, wb: float
) -> None:
    """Under estimate errors the equilibrium branch of exact estimates can end in a fold (the observer
    cannot hold the rotor position: seen at 0.05 p.u. and full torque with one estimate 0.75 % off
    and a drive file's gains). Then "stable under these errors" has no meaning there: say so before
    the NLP."""
    for name, est in error_scenarios(settings, model):
        x0 = model.equilibrium(theta, model.make_points(W, T, est))
        bad = np.flatnonzero(~np.isfinite(x0).all(axis=0))
        if bad.size:
            where = "; ".join(label(W[k], T[k], wb) for k in bad[:4])
            raise nlp.TuningError(
                f"the envelope is infeasible under estimate errors {name}: with the start gains the "
                f"observer has no equilibrium (it cannot hold the rotor position) at {where}"
                f"{' and more' if bad.size > 4 else ''}; use smaller --errors or a larger --speed-min"
            )


def candidates(
    model: TuningModel,
    settings: TuningSettings,
    W: np.ndarray,
    T: np.ndarray,
    wb: float,
    scale: float,
    max_noise: np.ndarray | None = None,
) -> Candidates:
    """Damping points of the envelope, decay-rate points, noise points (with a limit), and stability
    points per error scenario."""
    P = [model.make_points(W, T, model.nominal_estimate)]
    condition = [np.ones(W.size)]
    sigma = [np.zeros(W.size)]
    labels = [label(w, t, wb) for w, t in zip(W, T, strict=True)]
    if settings.min_decay > 0:
        P.append(P[0])
        condition.append(np.zeros(W.size))
        sigma.append(np.full(W.size, settings.min_decay))
        labels += [
            label(w, t, wb, f", decay >= {settings.min_decay:g} 1/s") for w, t in zip(W, T, strict=True)
        ]
    if max_noise is not None:
        P.append(P[0])
        condition.append(np.full(W.size, NOISE))
        sigma.append(np.zeros(W.size))
        labels += [label(w, t, wb, ", noise") for w, t in zip(W, T, strict=True)]
    for name, est in error_scenarios(settings, model):
        P.append(model.make_points(W, T, est))
        condition.append(np.zeros(W.size))
        sigma.append(np.full(W.size, max(settings.min_decay, ROBUST_MARGIN * scale)))
        labels += [label(w, t, wb, f", estimates {name}") for w, t in zip(W, T, strict=True)]
    return Candidates(np.hstack(P), np.concatenate(condition), np.concatenate(sigma), tuple(labels))
