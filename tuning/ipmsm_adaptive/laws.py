"""Tunable gain laws of the adaptive observer: the speed-dependent gain (16) and the free speed schedule.

Both are gain laws of symbolic/ipmsm_adaptive/gains.py, each a TuningModel of
tuning/ipmsm_adaptive/model.py (the analysis closed loop with the law plugged in): here are their
parameters, boxes, starts and regularizers. theta is the law's parameter vector, plus alpha_fo (10)
when ``tune_alpha_fo`` is set.

- speed-dependent: theta = [lambda' (ohm), omega_lambda (rad/s)], eq. (16) of Piippo, Hinkkanen, Luomi (2008).
  Baseline: the drive's ``[observer.gains.speed]`` (the paper's Fig. 4(c): lambda' = 2 R̂s,
  omega_lambda = 1 p.u.).
- schedule: theta = [lambda1 at each breakpoint..., lambda2 at each breakpoint...] (ohm), linear in
  the speed estimate between breakpoints, held beyond the ends (``schedule_law``). Breakpoints: zero,
  ``breakpoints`` speeds per direction from speed_min to speed_max, and the kinks +-omega_lambda of
  the drive file's law (16) and of the tuned speed-dependent law (its seed) inside the envelope.
  Eq. (16) is piecewise linear with kinks only at 0 and +-omega_lambda, so on these breakpoints the
  schedule reproduces both laws *exactly* over the envelope: its baseline is the drive file's gains
  sampled at the breakpoints, its NLP start the tuned speed-dependent law sampled there, and the
  tuner can only improve on it.
  Where the drive injects (``[injection] u_c > 0``), the breakpoints inside the injection band
  (|w_hat| <= w_Delta) keep the seed's gains (law (16), else the drive file's): their box is that
  one value (``pinned_in_band``). There the HF correction (20) and the observer gains act together,
  and the linear analysis of the averaged loop does not capture the large-signal transient: on the
  traction example (docs/examples/motors/prius.toml) the linear optimum in the band lost the rotor in
  the time-domain checks speed_steps and start; law (16) is what Piippo et al. (2008) validated with
  the injection (docs/families/ipmsm_adaptive.md, "Tuning").
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from sensorless.design.envelope import TuningSettings
from sensorless.design.ipmsm_adaptive.law_settings import law_settings
from sensorless.design.units import MAGNITUDE
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, get_law, schedule_law
from sensorless.tuning.ipmsm_adaptive.model import alpha_fo_cap, law_model, law_values, settled
from sensorless.tuning.model import TuningModel

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

GAIN_BOX = 20.0  # default search box |lambda| <= 20 R̂s when no lambda_max is given
LAMBDA1_MIN = -0.9  # lambda1 > -R̂s (Section IV-B): the box keeps lambda1 >= -0.9 R̂s


def _model(drive: IpmsmDrive, gain_law: GainLaw, settings: TuningSettings, **kw: Any) -> TuningModel:
    """The law's TuningModel, whose pointwise model (of the bound, tuning/bound.py) is build_pointwise."""
    return law_model(drive, gain_law, settings, pointwise=lambda: build_pointwise(drive, settings), **kw)


def _lambda_max(settings: TuningSettings, R: float) -> float:
    """The bound on |lambda1|, |lambda2| [ohm]: the configured one, else GAIN_BOX R̂s."""
    lam = law_settings(settings).lambda_max
    return lam if lam is not None else GAIN_BOX * R


def _grid_starts(a: np.ndarray, b: np.ndarray, settings: TuningSettings, drive: IpmsmDrive) -> np.ndarray:
    """The global phase's starts: every pair of a value of ``a`` and one of ``b`` (rows: [a, b]), with
    the alpha_fo starts when it is tuned too."""
    A, B = np.meshgrid(a, b)
    return with_alpha_fo_starts(np.column_stack([A.ravel(), B.ravel()]), settings, drive)


def _alpha_reg(th: ca.SX, law: GainLaw, settings: TuningSettings, a0: float) -> ca.SX:
    """Keep a tuned alpha_fo near the drive's value unless damping needs otherwise."""
    return (th[law.n_params] / a0 - 1) ** 2 if law_settings(settings).tune_alpha_fo else 0


def build_speed_dependent(
    drive: IpmsmDrive, settings: TuningSettings, seed: np.ndarray | None = None
) -> TuningModel:
    """Law speed-dependent: eq. (16) with lambda' and omega_lambda free."""
    settings = settled(drive, settings)
    law = get_law("speed")
    R = drive.estimate.R_s
    wb = drive.base.w
    g = drive.gain("speed")
    lam_max = _lambda_max(settings, R)
    a0 = drive.observer.alpha_fo

    def table_gains(theta: np.ndarray) -> dict[str, Any]:
        return {
            "lambda_p": float(theta[0]),
            "w_lambda": float(theta[1]),
            "alpha_fo": float(theta[2] if law_settings(settings).tune_alpha_fo else a0),
        }

    def starts() -> np.ndarray:
        """Global phase: a log grid of lambda' (0.25 R̂s .. the bound) x omega_lambda (0.02 .. 5 p.u.)."""
        lp = np.geomspace(0.25 * R, lam_max, 10)
        wl = np.geomspace(0.02 * wb, 5.0 * wb, 10)
        return _grid_starts(lp, wl, settings, drive)

    return _model(
        drive,
        law,
        settings,
        theta0=[g.lambda_p, g.w_lambda],
        lower=[0.0, 0.01 * wb],
        upper=[lam_max, 10.0 * wb],
        typical=[R, wb],
        law="speed-dependent",
        # no regularizer: the optimum is a ridge (lambda' |w|/omega_lambda fixed at the binding
        # speed) and any point on it is as good; the NLP is deterministic for given inputs
        regularizer=None,
        table_gains=table_gains,
        # exact Hessian: with the equilibria as data (exact estimates) the slots' second derivatives
        # are cheap, and IPOPT needs fewer iterations than with L-BFGS (benchmarks/bench_tune.py);
        # 8 points in the first round: the binding ones of the default envelope in one round
        hessian="exact",
        n_initial_active=8,
        starts=starts,
        smooth_box=_speed_kinks,
    )


def _speed_kinks(theta: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (16) is smooth in omega_lambda between the speeds |w_hat| = |w_m| of the points P (at an
    equilibrium w_hat = w_m; row 0 of a point): the box of omega_lambda between the nearest kinks below
    and above it (at a kink, the two pieces that meet there); lambda' and alpha_fo are free."""
    w = float(theta[1])
    speeds = np.abs(np.asarray(P[0], float))
    below = speeds[speeds < w * (1 - 1e-9)]
    above = speeds[speeds > w * (1 + 1e-9)]
    lo, hi = np.full(theta.size, -np.inf), np.full(theta.size, np.inf)
    lo[1] = below.max() if below.size else -np.inf
    hi[1] = above.min() if above.size else np.inf
    return lo, hi


def _ohm(v: float) -> float:
    """A tuned gain for the table: a rounding residue below the tables' smallest magnitude (1e-12 ohm,
    design/units.py) is zero, as the optimizer meant (lambda2 at zero speed came out -4e-14 ohm, which
    the table's reader refuses); every other value is kept as it is."""
    return 0.0 if abs(v) < MAGNITUDE[0] else float(v)


def schedule_breakpoints(
    drive: IpmsmDrive, settings: TuningSettings, kinks: tuple[float, ...] = ()
) -> tuple[float, ...]:
    """Breakpoints [rad/s]: zero, ``breakpoints`` speeds per direction over the envelope, and +-each
    of ``kinks`` [rad/s] that lies inside the envelope and not within 1e-3 p.u. of another."""
    e = settings.resolved
    wb = drive.base.w
    lo, hi = e.rule.lo, e.rule.hi  # [p.u.], the [tuning] keys
    mag = list(np.linspace(lo, hi, law_settings(settings).breakpoints) * wb)
    for k in kinks:
        k = abs(float(k))
        if lo * wb < k < hi * wb and min(abs(k - m) for m in mag) > 1e-3 * wb:
            mag.append(k)
    ordered = np.sort(mag)
    return tuple(float(v) for v in np.concatenate([-ordered[::-1], [0.0], ordered]))


def _speed_dependent_at(grid: tuple[float, ...], params: np.ndarray) -> np.ndarray:
    """eq. (16) with params [lambda', omega_lambda] sampled at the breakpoints: [lambda1..., lambda2...]."""
    l1, l2 = law_values(get_law("speed")).map(len(grid))(np.array(grid)[None, :], params[:2])
    return np.concatenate([np.asarray(l1).ravel(), np.asarray(l2).ravel()])


def pinned_in_band(drive: IpmsmDrive, grid: tuple[float, ...]) -> np.ndarray:
    """(K,) bool: the breakpoints [rad/s] of ``grid`` inside the injection band (|w_hat| <= w_Delta)
    where the drive injects; none without injection."""
    inj = drive.injection
    if not inj.enabled:
        return np.zeros(len(grid), bool)
    return np.abs(np.array(grid)) <= inj.w_Delta * (1 + 1e-9)


def build_schedule(
    drive: IpmsmDrive, settings: TuningSettings, seed: np.ndarray | None = None
) -> TuningModel:
    """Family schedule: free (lambda1, lambda2) at each breakpoint, linear in between; started from
    ``seed``, the tuned speed-dependent parameters (lambda', omega_lambda[, alpha_fo]), when given.
    In the injection band the breakpoints keep the seed's gains (the drive file's without a seed):
    the module docstring."""
    settings = settled(drive, settings)
    g = drive.gain("speed")
    baseline = np.array([g.lambda_p, g.w_lambda])
    grid = schedule_breakpoints(drive, settings, (g.w_lambda, *(() if seed is None else (seed[1],))))
    law = schedule_law(grid)
    K = len(grid)
    R = drive.estimate.R_s
    a0 = drive.observer.alpha_fo
    lam_max = _lambda_max(settings, R)
    theta0 = _speed_dependent_at(grid, baseline)
    lower = np.concatenate([np.full(K, max(LAMBDA1_MIN * R, -lam_max)), np.full(K, -lam_max)])
    upper = np.full(2 * K, lam_max)
    start = None
    if seed is not None:
        start = _speed_dependent_at(grid, np.asarray(seed, float))
    pin = np.tile(pinned_in_band(drive, grid), 2)
    kept = np.clip(theta0 if start is None else start, lower, upper)
    lower[pin] = upper[pin] = kept[pin]
    note = ""
    if pin.any():
        at = ", ".join(f"{v / drive.base.w:+.3g}" for v in np.array(grid)[pin[:K]])
        note = (
            f"held: lambda1, lambda2 at the breakpoints inside the injection band |w_hat| <= w_Delta = "
            f"{drive.injection.w_Delta / drive.base.w:.3g} p.u. ({at} p.u.) keep "
            + ("the speed-dependent optimum's" if start is not None else "the drive file's")
            + " gains (16): there the HF correction (20) and the observer gains act together, and the "
            "linear analysis of the averaged loop does not capture the large-signal transient; law (16) "
            "is what Piippo et al. (2008) validated with the injection"
        )
    w = np.array(grid)
    h = np.diff(w)
    h_mean = float(h.mean())

    def regularizer(th: ca.SX) -> ca.SX:
        # roughness: squared change of slope between neighbouring intervals (zero for a straight
        # line, as (16) is below omega_lambda), plus a small pull towards small gains
        total = 0
        for part in (th[:K], th[K : 2 * K]):
            slope = [(part[k + 1] - part[k]) / h[k] for k in range(K - 1)]
            total += sum(((slope[k + 1] - slope[k]) * h_mean / R) ** 2 for k in range(K - 2))
            total += 0.01 * sum((part[k] / R) ** 2 for k in range(K)) / K
        return total + _alpha_reg(th, law, settings, a0)

    def table_gains(theta: np.ndarray) -> dict[str, Any]:
        return {
            "w_hat": list(grid),
            "lambda1": [_ohm(v) for v in theta[:K]],
            "lambda2": [_ohm(v) for v in theta[K : 2 * K]],
            "alpha_fo": float(theta[2 * K] if law_settings(settings).tune_alpha_fo else a0),
        }

    if start is not None and law_settings(settings).tune_alpha_fo:
        assert seed is not None  # start is the seed's
        start = np.append(start, seed[2])

    def from_pointwise(speeds: np.ndarray, optima: np.ndarray) -> np.ndarray:
        """The pointwise optima (per speed: lambda1, lambda2[, alpha_fo]) sampled at the breakpoints
        (linear between speeds, held beyond; zero speed: the mean of the two directions' nearest)."""
        out = [_sample(speeds, optima[:, c], w) for c in range(2)]
        th = np.concatenate(out)
        if law_settings(settings).tune_alpha_fo:
            th = np.append(th, float(np.median(optima[:, 2])) if optima.shape[1] > 2 else a0)
        return th

    return _model(
        drive,
        law,
        settings,
        theta0=theta0,
        lower=lower,
        upper=upper,
        typical=np.full(2 * K, R),
        law="schedule",
        regularizer=regularizer,
        table_gains=table_gains,
        start=start,
        start_label="speed-dependent optimum" if seed is not None else "",
        from_pointwise=from_pointwise,
        n_initial_active=16,
        # the interval between breakpoints: its points share the pair of free gains at its ends
        point_group=lambda P: np.searchsorted(w, P[0]),
        note=note,
    )


def _sample(speeds: np.ndarray, v: np.ndarray, at: np.ndarray) -> np.ndarray:
    """v(speeds) at the breakpoints ``at``: linear within each direction, held beyond its ends; at zero
    (between the directions) the mean of the nearest values of both."""
    out = np.empty(at.size)
    neg, pos = speeds < 0, speeds > 0
    for i, x in enumerate(at):
        if x < 0 and neg.any():
            out[i] = np.interp(x, speeds[neg], v[neg])
        elif x > 0 and pos.any():
            out[i] = np.interp(x, speeds[pos], v[pos])
        else:
            near = [v[m][np.argmin(np.abs(speeds[m]))] for m in (neg, pos) if m.any()]
            out[i] = float(np.mean(near))
    return out


def with_alpha_fo_starts(starts: np.ndarray, settings: Any, drive: IpmsmDrive) -> np.ndarray:
    """The global phase's starts, each at 1, 2 and 4 x the drive's alpha_fo, within its box (the
    values that the cap makes equal, once: prius's cap 1.48x made its 2x and 4x starts the same, a third
    of its global phase's and pointwise bound's candidates), when it is tuned too."""
    if not law_settings(settings).tune_alpha_fo:
        return starts
    a0 = drive.observer.alpha_fo
    alphas = np.unique(np.clip(np.array([1.0, 2.0, 4.0]) * a0, a0, alpha_fo_cap(drive)))
    return np.vstack([np.column_stack([starts, np.full(len(starts), a)]) for a in alphas])


def _signed_log(lo: float, hi: float, R: float, n: int) -> np.ndarray:
    """Gains from lo to hi [ohm]: zero, and geometric from 0.1 R̂s to the bound on each side."""
    out = [0.0]
    if hi > 0.1 * R:
        out += list(np.geomspace(0.1 * R, hi, n))
    if lo < -0.1 * R:
        out += list(-np.geomspace(0.1 * R, -lo, n))
    return np.unique(np.clip(out, lo, hi))


def build_pointwise(
    drive: IpmsmDrive, settings: TuningSettings, seed: np.ndarray | None = None
) -> TuningModel:
    """The free gains at one operating point: theta = [lambda1, lambda2] (constant law, eq. (7)), in the
    box of the schedule; the model of the pointwise bound (tuning/bound.py). The bound is of the damping
    alone, without the laws' bound on the angle lag (``hold_lag``): still an upper bound of what they
    reach, and evaluating the lag there cost the README servo's bound 3x its time for figures it never
    reads."""
    settings = settled(drive, settings)
    settings = dataclasses.replace(settings, law=dataclasses.replace(law_settings(settings), hold_lag=False))
    law = get_law("constant")
    R = drive.estimate.R_s
    lam_max = _lambda_max(settings, R)
    g = drive.gain("speed")

    def starts() -> np.ndarray:
        l1 = _signed_log(max(LAMBDA1_MIN * R, -lam_max), lam_max, R, 9)
        l2 = _signed_log(-lam_max, lam_max, R, 8)
        return _grid_starts(l1, l2, settings, drive)

    return _model(
        drive,
        law,
        settings,
        theta0=[g.lambda_p, g.lambda_p],
        lower=[max(LAMBDA1_MIN * R, -lam_max), -lam_max],
        upper=[lam_max, lam_max],
        typical=[R, R],
        law="pointwise",
        regularizer=None,
        table_gains=lambda theta: {"lambda1": float(theta[0]), "lambda2": float(theta[1])},
        starts=starts,
    )


def with_estimate(drive: IpmsmDrive, estimate: np.ndarray) -> Any:
    """The drive with other parameter estimates (for analysis of the error scenarios)."""
    e = dataclasses.replace(
        drive.estimate, R_s=estimate[0], L_d=estimate[1], L_q=estimate[2], psi_pm=estimate[3]
    )
    return dataclasses.replace(drive, estimate=e)
