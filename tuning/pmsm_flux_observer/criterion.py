"""The flux family's own criterion for its gains: what it judges, how candidates rank, and what a set
of gains misses (the cause and the change that fixes it), shared by ``tune`` and the report.

The gradient observer's damping k/(2|w|) falls with speed by design while its decay k/2 does not (in
the stationary frame its error does not oscillate: the rotor frame's frequency w is the rotation), so
damping is not its figure. Per candidate, over the envelope x the estimate-error corners (assessment.py):

1. **holds**: a speed holds when at every torque, direction and corner the sampled observer is stable,
   its angle bias is within ``bias_max_deg`` and its angle noise within its limit (default a third of
   the bias limit); the *low-speed limit* is the lowest speed from which every higher one holds;
2. **decay and lag under acceleration**: the observer's own modes (nominal estimates, the PLL's left
   out) decay at least ``decay_share`` x alpha_s from the limit up (the observer settles as fast as
   the speed loop it feeds), and at least sqrt(a_max / 30 deg) (a_max = p (T_max - T_N) / J: its angle
   lags a ramp by about a / sigma^2; the I-f start's handover rule, design/startup.py);
3. **the PLL's lag**: the PLL's speed estimate (its integrator) settles with the slower root of
   s^2 + k_p s + k_i, at least PLL_SPEED_LOOP x alpha_s (the drive file's rule); behind the drive's full
   acceleration a = p T_max / J it lags a k_p / k_i;
4. optionally the worst damping (``--min-damping``).

Rank: the candidates that meet 2-4 first, then the lower low-speed limit (or the hold speed given),
then the faster worst decay from it up. The firmware defaults are candidates of their law (the ODrive
defaults in VESC's terms too), so the tuned gains rank no worse than either. Tuned gains that hold
nowhere, or only at the envelope's top speed, or miss 2-4, are shortfalls: ``tune`` exits 3 naming
each (cause and change).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer.gains import pll_gains
from sensorless.design.pmsm_flux_observer.schema import PLL_SPEED_LOOP
from sensorless.tuning.pmsm_flux_observer.assessment import Assessment, assess, figures, low_limit
from sensorless.tuning.pmsm_flux_observer.settings import FluxTuneSettings

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

LAG_LIMIT_DEG = 30.0  # deg electrical: the angle the observer may lag the full acceleration
TOL = 1e-9  # relative: a requirement met to rounding is met (a double root k_p/2 at exactly the floor)


def requirements(drive: FluxObserverDrive, settings: FluxTuneSettings) -> dict[str, float]:
    """The criterion's numbers on this drive: decay [1/s], PLL root [1/s], full acceleration [rad/s^2]."""
    a_s = float(drive.control.alpha_s)
    m, c = drive.motor, drive.control
    # what the full acceleration against rated load asks of the observer's decay: its angle lags a ramp
    # by about a / sigma^2, within LAG_LIMIT_DEG (the tuner's fast proxy; the whole drive's ramp lag,
    # design/drive_analysis.py, is what the handover and the report judge)
    a_max = m.p * (c.T_max - drive.T_N) / m.J
    follow = math.sqrt(max(a_max, 0.0) / math.radians(LAG_LIMIT_DEG))
    return {
        "decay": max(settings.decay_share * a_s, follow),
        "decay_speed_loop": settings.decay_share * a_s,
        "decay_acceleration": follow,
        "pll": PLL_SPEED_LOOP * a_s,
        "acceleration": m.p * c.T_max / m.J,
    }


def judged(drive: FluxObserverDrive, a: Assessment, c: int, settings: FluxTuneSettings) -> dict[str, Any]:
    """Candidate ``c``'s figures (assessment.figures from its own limit, or from the hold speed where
    one is given and lower) and which requirement it meets."""
    W, _ = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    lim = float(low_limit(a.holds[c : c + 1], speeds)[0])
    w_from = lim if settings.hold_speed is None else max(lim, settings.hold_speed)
    f = figures(drive, a, c, w_from if math.isfinite(w_from) else None)
    need = requirements(drive, settings)
    sel = np.abs(W) >= (w_from if math.isfinite(w_from) else 0.0)
    dec = a.decay[c, sel] if a.decay is not None else np.full(1, np.nan)
    worst_decay = float(np.min(dec)) if math.isfinite(lim) and np.isfinite(dec).all() else math.nan
    at = float(np.abs(W[sel])[int(np.argmin(dec))]) if math.isfinite(worst_decay) else math.nan
    pll = float(a.pll[c]) if a.pll is not None else math.nan
    ok = {
        "holds": math.isfinite(lim),
        "decay": math.isfinite(worst_decay) and worst_decay >= need["decay"] * (1 - TOL),
        "pll": pll >= need["pll"] * (1 - TOL),
        "damping": settings.min_damping <= 0 or f["worst_damping"] >= settings.min_damping * (1 - TOL),
    }
    return {
        **f,
        "worst_decay_1_s": worst_decay,
        "worst_decay_at_rad_s": at,
        "pll_root_1_s": pll,
        "hold_from_rad_s": w_from,
        "meets": ok,
        "requirements": need,
    }


def rank_key(j: dict[str, Any], c: int) -> tuple[Any, ...]:
    """Lower is better (module docstring)."""
    ok = j["meets"]
    met = ok["holds"] and ok["decay"] and ok["pll"] and ok["damping"]
    lim = j["hold_from_rad_s"] if math.isfinite(j["hold_from_rad_s"]) else math.inf
    dec = j["worst_decay_1_s"]
    return (0 if met else 1, lim, -(dec if math.isfinite(dec) else -math.inf), c)


def best(drive: FluxObserverDrive, a: Assessment, settings: FluxTuneSettings) -> int:
    """The index of the best candidate by the criterion."""
    return min(rank_key(judged(drive, a, c, settings), c) for c in range(a.holds.shape[0]))[-1]


def shortfalls(
    drive: FluxObserverDrive, gains: GainSet, j: dict[str, Any], settings: FluxTuneSettings, pll: bool = True
) -> list[str]:
    """What ``gains`` (judged ``j``) miss of the criterion, one line each with the cause and the change
    that fixes it; empty where they meet it. ``pll`` False: leave the PLL's lag out (the report says
    it in its own finding)."""
    W, _ = drive.envelope.grid()
    top = float(np.max(np.abs(W)))
    wb = drive.w_base
    ok, need = j["meets"], j["requirements"]
    out = []
    errs = ", ".join(f"{k} +-{100 * v:g} %" for k, v in settings.errors.items())
    if not ok["holds"] or j["low_speed_limit_rad_s"] >= top * (1 - TOL):
        where = (
            "at no envelope speed"
            if not ok["holds"]
            else f"only at the envelope's top speed {top / wb:.3g} p.u."
        )
        below = top if not ok["holds"] else float(np.max(np.abs(W)[np.abs(W) < top * (1 - TOL)]))
        out.append(
            f"the tuned gains hold {where}: {lost_cause(drive, gains, settings, below)}; change: estimates "
            f"closer than the errors assumed ({errs}: state yours with --r-error, --flux-error, --l-error), "
            f"a larger --bias-max than {settings.bias_max_deg:g} deg, or an envelope whose speeds the motor "
            "runs sensorless ([envelope] speed_min, speed_max), with the open-loop start below"
        )
    if ok["holds"] and not ok["decay"]:
        dec = j["worst_decay_1_s"]
        if need["decay_speed_loop"] >= need["decay_acceleration"]:
            why = (
                f"the {need['decay']:.4g} 1/s the speed loop needs ({settings.decay_share:g} x alpha_s: the "
                "observer settles at least as fast as the speed loop it feeds)"
            )
            fix = f"a slower speed loop ([control] alpha_s at most {dec / settings.decay_share:.4g} rad/s)"
        else:
            why = (
                f"the {need['decay']:.4g} 1/s the full acceleration against rated load asks (sqrt(a_max / 30 "
                "deg): its angle lag a / sigma^2 within 30 deg; design/startup.py)"
            )
            fix = "a lower torque limit ([control] T_max)"
        out.append(
            f"the observer decays at {dec:.4g} 1/s at {j['worst_decay_at_rad_s'] / wb:.3g} p.u., below "
            f"{why}; change: {fix}, or a higher hold speed (--hold-speed)"
        )
    if pll and not ok["pll"]:
        k_p, k_i = pll_gains(gains)
        lag = need["acceleration"] * k_p / k_i
        out.append(
            f"the PLL's speed estimate settles at {j['pll_root_1_s']:.4g} 1/s, below {need['pll']:.4g} 1/s "
            f"({PLL_SPEED_LOOP:g} x alpha_s): it lags {lag:.4g} rad/s ({lag / wb:.3g} p.u.) behind the full "
            f"acceleration {need['acceleration']:.4g} rad/s^2 (k_p/k_i = {k_p / k_i:.3g} s); change: "
            f"a faster PLL (a double root at {need['pll']:.4g} 1/s or beyond: "
            f"k_p = {2 * need['pll']:.6g} 1/s, "
            f"k_i = k_p^2/4) or a slower speed loop ([control] alpha_s at most "
            f"{j['pll_root_1_s'] / PLL_SPEED_LOOP:.4g} rad/s)"
        )
    if not ok["damping"]:
        out.append(
            f"the worst damping {j['worst_damping']:.3g} is below --min-damping {settings.min_damping:g} "
            "(the gradient observer's k/(2|w|) falls with speed); change: a lower --min-damping, or a "
            "lower top speed ([envelope] speed_max)"
        )
    return out


def lost_cause(drive: FluxObserverDrive, gains: GainSet, settings: FluxTuneSettings, speed: float) -> str:
    """Why ``gains`` do not hold at ``speed`` [rad/s]: each estimate error alone, judged as the criterion
    judges it (stable, bias, noise), named where it alone loses the speed."""
    W, _ = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    j = int(np.argmin(np.abs(speeds - speed)))
    alone = []
    for key, rel in settings.errors.items():
        if rel <= 0:
            continue
        one = dataclasses.replace(
            settings, errors={k: (v if k == key else 0.0) for k, v in settings.errors.items()}
        )
        a = assess(drive, [gains], one)
        if not a.holds[0, j]:
            f = figures(drive, a, 0, speeds[j])
            alone.append(f"{key} +-{100 * rel:g} % alone (angle bias {f['worst_bias_deg']:.3g} deg)")
    at = f"at {speeds[j] / drive.w_base:.3g} p.u."
    if alone:
        return (
            f"{at} "
            + " and ".join(alone)
            + f" breaks the {settings.bias_max_deg:g} deg angle-bias limit or stability"
        )
    lim = settings.bias_max_deg
    return f"{at} the estimate errors together break the {lim:g} deg angle-bias limit or stability"
