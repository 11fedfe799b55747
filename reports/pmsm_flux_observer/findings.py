"""What the flux-observer report's verdict says of a figure that misses its limit: the cause in the
design's own numbers, and what to do.

- the PLL: its speed estimate is the integrator of a PI on the observer's angle, so it settles with the
  slower root of s^2 + k_p s + k_i at every speed (VESC's default k_p = 2000 1/s, k_i = 30000 1/s^2:
  -15.1 1/s); a time-domain check that ends soon after a speed ramp sees that lag as its final
  speed-estimation error, while the angle the drive commutates on (the observer's) is not delayed;
- the estimate errors: which one alone already loses the motor at every envelope speed (the gradient
  observer's angle error under a flux error grows with k/|w|, Lee et al. 2010's circle |eta| = lambda);
- a failed time-domain check whose final speed-estimation error is that lag: its cause "pll_root"
  (:func:`failure_cause`, the family's report hook; reports/causes.py);
- the damping: where it is worst (the gradient observer's k/(2|w|): low where k is small for the speed).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.pmsm_flux_observer.gains import SCALED_U_REF, base_gain, pll_gains
from sensorless.design.pmsm_flux_observer.schema import PLL_SPEED_LOOP
from sensorless.reports.causes import Failure, Named
from sensorless.reports.time_domain import Check
from sensorless.tuning.pmsm_flux_observer import Assessment, FluxTuneSettings, assess, low_limit

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


def pll_roots(gains: GainSet) -> tuple[complex, complex]:
    """The roots of the PLL's s^2 + k_p s + k_i [1/s], slower first, in closed form (a double root is
    -k_p/2 exactly: a polynomial solver's rounding would put it on either side of a limit)."""
    k_p, k_i = pll_gains(gains)
    disc = k_p**2 / 4 - k_i
    if disc > 0:
        r = math.sqrt(disc)
        return complex(-k_p / 2 + r), complex(-k_p / 2 - r)
    im = math.sqrt(-disc)
    return complex(-k_p / 2, im), complex(-k_p / 2, -im)


def pll_fixed(gains: GainSet, alpha_s: float) -> GainSet | None:
    """The gains with the PLL :func:`pll_finding` names (a double root at PLL_SPEED_LOOP x ``alpha_s``
    or faster, in the values written: VESC's k_i = k_p^2/4 to 6 digits, ODrive's bandwidth); None where
    the PLL already settles fast enough."""
    min_decay = PLL_SPEED_LOOP * alpha_s
    if -pll_roots(gains)[0].real >= min_decay * (1 - 1e-9):
        return None
    if gains.law == "voltage-scaled":
        kp = float(f"{max(pll_gains(gains)[0], 2 * min_decay):.6g}")
        new = {"foc_pll_kp": kp, "foc_pll_ki": float(f"{kp**2 / 4:.6g}")}
    else:
        new = {"pll_bandwidth": float(f"{min_decay:.6g}")}
    return dataclasses.replace(gains, values={**gains.values, **new}, source=f"{gains.source}, the PLL's fix")


def pll_finding(gains: GainSet, alpha_s: float, td: Sequence[Check]) -> str:
    """Empty where the PLL's speed estimate settles at PLL_SPEED_LOOP x the speed loop's bandwidth
    ``alpha_s`` [rad/s] or faster; else why, and what to do."""
    min_decay = PLL_SPEED_LOOP * alpha_s
    slow, fast = pll_roots(gains)
    sigma = -slow.real
    if sigma >= min_decay * (1 - 1e-9):  # met to rounding is met
        return ""
    k_p, k_i = pll_gains(gains)
    if gains.law == "voltage-scaled":
        names = f"foc_pll_kp = {k_p:.6g} 1/s, foc_pll_ki = {k_i:.6g} 1/s^2"
        fixed = pll_fixed(gains, alpha_s)
        assert fixed is not None
        kp, ki = fixed.values["foc_pll_kp"], fixed.values["foc_pll_ki"]  # a double root at -kp/2
        todo = (
            f"foc_pll_kp = {kp:.6g} 1/s, foc_pll_ki = foc_pll_kp^2/4 = {ki:.6g} 1/s^2 (a double root "
            f"at {-kp / 2:.4g} 1/s), a slower speed loop ([control] alpha_s at most "
            f"{sigma / PLL_SPEED_LOOP:.4g} rad/s), or sensorless tune --law voltage-scaled"
        )
    else:
        names = f"pll_bandwidth = {k_p / 2:.6g} rad/s"
        todo = (
            f"pll_bandwidth of at least {min_decay:.4g} rad/s, a slower speed loop ([control] alpha_s at "
            f"most {sigma / PLL_SPEED_LOOP:.4g} rad/s), or sensorless tune"
        )
    checks = [c["name"] for c in td if any("speed-estimation" in x for x in c["failed"])]
    seen = f"; the final speed-estimation error of {', '.join(checks)} is that lag" if checks else ""
    return (
        f"the PLL's speed estimate (its integrator) settles at {sigma:.3g} 1/s at every speed ({names}: "
        f"roots {slow.real:.4g} and {fast.real:.4g} 1/s of s^2 + k_p s + k_i), slower than the "
        f"{min_decay:.4g} 1/s the speed loop closing on it asks ({PLL_SPEED_LOOP:g} x its bandwidth, the "
        "rule of [control] alpha_s); a speed ramp of a rad/s^2 leaves "
        f"it {k_p / k_i * 1e3:.3g} ms x a behind, caught up {3 / sigma * 1e3:.3g} ms (3 time constants) "
        f"after the ramp{seen}; the angle the drive commutates on is the "
        f"observer's, not delayed by it; to do: {todo}"
    )


def failure_cause(drive: FluxObserverDrive, gains: GainSet, failure: Failure) -> Named | None:
    """The cause of a failed time-domain check in the flux observer's own analysis (reports/causes.py):
    a final speed-estimation error where the PLL's slower root is slower than the speed loop needs
    (:func:`pll_finding`) is the PLL's lag ("pll_root"); a run's end that the I-f start's time made miss
    names the start-up acceleration that fits it (:func:`start_too_slow`); None for anything else (the
    shared rules)."""
    if failure.kind == "tracking":
        return start_too_slow(drive, gains, failure)
    if failure.kind != "speed_estimate":
        return None
    why = pll_finding(gains, drive.control.alpha_s, [])
    return Named("pll_root", why) if why else None


def start_too_slow(drive: FluxObserverDrive, gains: GainSet, failure: Failure) -> Named | None:
    """A run's end the I-f start's time made miss (reports/causes.py ``ramp_slower_than_reference``) with
    the change that fits it: the ``[startup] acceleration`` and the firmware's fields at it
    (design/startup_check.py ``faster_start``), or, where no acceleration the current carries fits, one
    line saying so and naming the gains' tune (a lower w_min, an earlier handover), as where the gains
    hold at no envelope speed under the estimate errors (the review's verdict fails then whatever the
    start: :func:`holds_nowhere_finding`). None: not this case."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.pmsm_flux_observer.firmware import stored
    from sensorless.design.pmsm_flux_observer.firmware.startup import fields
    from sensorless.design.startup_check import faster_start, judge_startup, largest_acceleration
    from sensorless.reports.causes import shared_cause

    if not failure.open_loop_took_it:
        return None
    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:
        return None
    if judged is None or judged.shortfalls:
        return None  # the start's own shortfalls come first (the start-up findings name their values)
    named = shared_cause(failure)
    if (
        drive.observer.correction != "box-clamp"
        and not assess(drive, [gains], FluxTuneSettings()).holds.any()
    ):
        return Named(
            named.cause,
            named.detail,
            "no start-up value fixes it: the gains under review hold at no envelope speed under the "
            "estimate errors (their finding above), so the verdict fails whatever the start; the gains "
            f"must change: sensorless tune --law {gains.law}",
        )
    assert failure.open_s is not None and failure.avail_s is not None and failure.need_s is not None
    a = faster_start(drive, judged, failure.open_s, failure.avail_s, failure.need_s)  # open_loop_took_it
    if math.isnan(a):
        top = largest_acceleration(drive, judged.values["if_i"])
        return Named(
            named.cause,
            named.detail,
            "no start-up value fixes it: even the largest acceleration the I-f current carries against "
            f"rated load ({stored(top)} rad/s^2) leaves the start too long; an earlier handover needs gains "
            f"with a lower w_min than these {judged.w_min:.4g} rad/s: sensorless tune --law {gains.law}",
        )
    fw = drive.observer.firmware
    old, new = fields(fw, judged.values), fields(fw, {**judged.values, "if_acc": a})
    write = ", ".join(f"{k} = {stored(v)} {u}" for k, (v, u) in new.items() if stored(v) != stored(old[k][0]))
    return Named(
        named.cause,
        named.detail,
        f"[startup] acceleration = {stored(a)} rad/s^2 (was "
        f"{stored(judged.values['if_acc'])}; the largest the I-f current carries against rated load at "
        f"the start-up check's load angle)" + (f", i.e. write {write}" if write else ""),
    )


def holds_nowhere_finding(drive: FluxObserverDrive, gains: GainSet, settings: FluxTuneSettings) -> str:
    """Why the gains hold at no envelope speed under the estimate errors: which error alone already
    loses the motor, the gain's ratio to the speed at the top, and what to do."""
    errors = settings.errors
    lost = []
    for key in (k for k, v in errors.items() if v > 0):
        alone = {k: (v if k == key else 0.0) for k, v in errors.items()}
        if not assess(drive, [gains], dataclasses.replace(settings, errors=alone)).holds.any():
            lost.append(f"{key} +-{100 * errors[key]:g} %")
    w_top = float(drive.envelope.speed_max)
    k = base_gain(gains, drive.estimate.psi_pm)
    if gains.law == "voltage-scaled":
        k *= max(float(gains.values["foc_observer_gain_slow"]), drive.motor.psi_pm * w_top / SCALED_U_REF)
    which = (
        f"{' and '.join(lost)} alone already lose{'s' if len(lost) == 1 else ''} it"
        if lost
        else "only the errors together lose it"
    )
    vesc = ", VESC's k grows with the voltage" if gains.law == "voltage-scaled" else ""
    adapt = (
        ""
        if drive.observer.lambda_adaptation
        else (", run the flux adaptation ([observer] lambda_adaptation = true, VESC's *_LAMBDA_COMP)")
    )
    return (
        f"the gains under review hold at no envelope speed under the estimate errors: {which} (no "
        f"equilibrium near the rotor angle, or an angle bias over {settings.bias_max_deg:g} deg); the "
        "flux observer's angle error under an estimate error grows with its gain k (a flux error's with "
        f"k/|w|, a resistance error's as k dR i_q/(lambda w^2)): k/|w| = {k / w_top:.3g} at the top speed "
        f"({w_top / drive.w_base:.3g} p.u.{vesc}); to do: measure R_s and psi_pm closer and state their "
        f"errors (sensorless tune --r-error, --flux-error){adapt}, or sensorless tune --law {gains.law}"
    )


def damping_finding(drive: FluxObserverDrive, a: Assessment, c: int, min_damping: float, law: str) -> str:
    """Where candidate ``c``'s worst damping over the speeds it holds is, and why it is low there."""
    W, T = drive.envelope.grid()
    speeds = np.unique(np.abs(W))
    lim = low_limit(a.holds[c : c + 1], speeds)[0]
    sel = np.abs(W) >= lim if math.isfinite(lim) else np.ones(W.size, bool)
    z = np.where(sel, a.damping[c], np.inf)
    j = int(np.argmin(z))
    if a.damping[c, j] <= -1.0:
        return (
            f"worst damping: no equilibrium under an estimate error at {W[j] / drive.w_base:+.3g} p.u., "
            f"T_e = {T[j]:.4g} N m (counted as -1 < required {min_damping:g})"
        )
    return (
        f"worst damping {a.damping[c, j]:.4g} < required {min_damping:g} at {W[j] / drive.w_base:+.3g} p.u., "
        f"T_e = {T[j]:.4g} N m (under the estimate errors): the flux observer's damping is k/(2|w|), low "
        "where the gain is small for the speed (at the top speed with a constant gain); a larger gain there "
        "raises it, and the angle bias under a resistance error with it "
        f"(sensorless tune --law {law} trades them; --min-damping states what the drive needs)"
    )
