"""The open-loop I-f start's settings judged against the motor, like gains: what each must be, and why.

A drive's ``[startup]`` (typed by its user, or imported from a firmware's ramp: design/pmsm_flux_observer
/firmware/) is judged at the gains under review, key by key, against the physics of the start
(symbolic/startup.py: the rotor follows the current vector i_if at a load angle delta, the torque being
k_t i_if sin(delta)):

- **current**: it carries the rated load and the ramp's acceleration at a load angle of at most
  LOAD_ANGLE_MAX (symbolic/startup.py DROP_MAX, 60 deg: 30 deg from the 90 deg at which the rotor falls
  out of step, room for the swing about the current vector): k_t i_if sin(LOAD_ANGLE_MAX) >= T_N +
  J a / p. Less is the cause ``if_current_below_load``. It is at most the torque limit's current
  T_max / k_t (an imported firmware's motor current limit is that limit): more is ``torque_limit``;
- **acceleration**: at most what the current can give at that load angle, p (k_t i_if
  sin(LOAD_ANGLE_MAX) - T_N) / J (where the limit's current cannot carry it: ``torque_limit``); at least
  the speed reference of the drive's own start (0.5 p.u. in t_seg: design/scenario.py generic_times,
  the time its torque limit needs), else the open loop lags the drive's speed command
  (``ramp_slower_than_reference``); a slow ramp is replaced by the rule's (design/startup.py);
- **handover w_on**: at least w_min, the minimum speed for the handover at the gains under review
  (design/pmsm_drive.py startup_values: the observer follows the drive's full acceleration there); below
  it the observer never agrees with the open loop and the drive never hands over
  (``observer_lag_acceleration``); at most the rated speed and below the no-load speed u_dc /
  (sqrt(3) psi_pm) at the DC link (``speed_unreachable``: the open loop never gets there). The rule's
  ON_FACTOR w_min is proposed, at most the rated speed;
- **w_off** (back to open loop below it): at least w_min, below w_on.

Keys the drive file does not give keep their rules and are judged too (a rule can land beyond rated
speed where w_min is high). :func:`judge_startup` returns the values with every shortfall's fix applied
(the start ``tune`` proposes and ``export`` writes, the user's values kept where they hold) and the
shortfalls, each with the value that fixes it and why; a family names the firmware's own fields.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

from sensorless.design.capabilities import OpenLoopStart
from sensorless.design.family import DriveScales, GainSet
from sensorless.design.motor_data import mtpa_torque_current
from sensorless.design.registry import family_of
from sensorless.design.scenario import generic_times
from sensorless.symbolic.startup import DROP_MAX

if TYPE_CHECKING:  # pmsm_drive imports this module's rules
    from sensorless.design.pmsm_drive import OnPmsm

LOAD_ANGLE_MAX = DROP_MAX  # the largest steady load angle a start may need (symbolic/startup.py)
REFERENCE_PU = 0.5  # the drive's own start: 0.5 p.u. in t_seg (design/scenario.py generic_scenarios)
SWING_ALLOWANCE = 2.0  # faster_start: the ramp's cut, over the shortfall it must make up
KEYS = {"current": "if_i", "acceleration": "if_acc", "w_on": "if_w_on", "w_off": "if_w_off"}


@dataclasses.dataclass(frozen=True)
class Shortfall:
    """One ``[startup]`` key that does not hold: its value, the value that fixes it, the cause (an id of
    the verdicts' cause catalogue) and why, in one clause."""

    key: str  # current | acceleration | w_on | w_off
    value: float  # SI (A, rad/s^2, rad/s electrical)
    needed: float  # SI; nan where no start-up value fixes it
    cause: str
    why: str
    given: bool  # the drive file gave the value (else it is a rule's)


@dataclasses.dataclass(frozen=True)
class StartJudgement:
    """The start judged: ``values`` (design/startup.py if_values names) with every fix applied,
    ``shortfalls``, and w_min [rad/s], the minimum speed for the handover at the gains."""

    values: dict[str, float]
    given: frozenset[str]  # the [startup] keys the drive file gave
    shortfalls: tuple[Shortfall, ...]
    w_min: float

    @property
    def fixable(self) -> bool:
        """Whether start-up values fix every shortfall."""
        return all(math.isfinite(s.needed) for s in self.shortfalls)


def _up(x: float) -> float:
    """``x`` rounded up to 3 significant digits (a lower bound written as a setting)."""
    if not (math.isfinite(x) and x > 0):
        return x
    e = 10 ** (math.floor(math.log10(x)) - 2)
    return math.ceil(x / e - 1e-9) * e


def _down(x: float) -> float:
    """``x`` rounded down to 3 significant digits (an upper bound written as a setting)."""
    if not (math.isfinite(x) and x > 0):
        return x
    e = 10 ** (math.floor(math.log10(x)) - 2)
    return math.floor(x / e + 1e-9) * e


def judge_startup(drive: OnPmsm, gains: GainSet) -> StartJudgement | None:
    """The drive's I-f start judged at ``gains`` (module docstring); None where it needs no start.
    CapabilityError where the start has no rules (no PMSM data, no minimum-speed analysis)."""
    from sensorless.design.pmsm_drive import startup_values
    from sensorless.design.startup import ON_FACTOR

    fam = family_of(drive)
    if not isinstance(fam, OpenLoopStart):
        return None
    start = fam.startup(drive)
    rules, _, w_min = startup_values(fam.with_startup(drive, None), gains)
    if rules is None or w_min <= 0:
        return None
    given = start.values(w_min) if start is not None else {}
    v = {**rules, **given}
    # the rules' values as settings: 3 digits, each rounded to the side its bound allows (the current and
    # the acceleration down, within the torque limit; the speeds up, above w_min)
    for key, name in KEYS.items():
        if name not in given:
            v[name] = (_down if key in ("current", "acceleration") else _up)(v[name])
    m, c = drive.motor, drive.control
    i_d, i_q = mtpa_torque_current(c.T_max, m)
    k_t = c.T_max / math.hypot(i_d, i_q)  # torque per ampere (peak) at the torque limit, MTPA
    s_max = math.sin(LOAD_ANGLE_MAX)
    i_lim, T_N, J, p = c.T_max / k_t, drive.T_N, m.J, m.p
    scales = DriveScales(T_N, c.T_max, J, p, drive.w_base, c.alpha_s, speed_ramp=c.speed_ramp)
    a_ref = REFERENCE_PU * drive.w_base / generic_times(scales)["t_seg"]
    out: list[Shortfall] = []

    def fall(key: str, needed: float, cause: str, why: str) -> None:
        out.append(Shortfall(key, v[KEYS[key]], needed, cause, why, KEYS[key] in given))
        v[KEYS[key]] = needed

    def i_need(a: float) -> float:
        return (T_N + J * a / p) / (k_t * s_max)

    if v["if_acc"] < a_ref * (1 - 1e-9):
        fall(
            "acceleration",
            max(_up(rules["if_acc"]), _up(a_ref)),
            "ramp_slower_than_reference",
            f"slower than the {a_ref:.4g} rad/s^2 the drive's speed command asks ({REFERENCE_PU:g} p.u. in "
            "the time its torque limit needs): the open loop lags the command",
        )
    if v["if_i"] > i_lim * (1 + 1e-9):
        fall(
            "current",
            _down(i_lim),
            "torque_limit",
            f"above the torque limit's current T_max/k_t = {i_lim:.4g} A",
        )
    if v["if_i"] < i_need(v["if_acc"]) * (1 - 1e-9):
        need = _up(i_need(v["if_acc"]))
        load = (
            f"rated load {T_N:.4g} N m and the ramp's {v['if_acc']:.4g} rad/s^2 "
            f"(J a/p = {J * v['if_acc'] / p:.3g} N m)"
        )
        if need <= i_lim * (1 + 1e-9):
            fall(
                "current",
                need,
                "if_current_below_load",
                f"cannot carry {load} at a load angle of at most {math.degrees(LOAD_ANGLE_MAX):g} deg "
                f"(k_t = {k_t:.4g} N m/A): the rotor falls out of step",
            )
        else:
            if v["if_i"] < i_lim * (1 - 1e-9):
                fall(
                    "current",
                    _down(i_lim),
                    "if_current_below_load",
                    f"cannot carry {load}; at most the limit's",
                )
            a_fit = p * (k_t * v["if_i"] * s_max - T_N) / J
            ok = a_fit >= a_ref
            fall(
                "acceleration",
                _down(a_fit) if ok else math.nan,
                "torque_limit",
                f"more than the torque limit's current {i_lim:.4g} A gives against rated load at "
                f"{math.degrees(LOAD_ANGLE_MAX):g} deg"
                + (
                    "" if ok else ": no ramp fits; raise the torque limit ([control] T_max) or lower the load"
                ),
            )
    w_noload = c.u_dc / (math.sqrt(3) * m.psi_pm)
    w_up = min(drive.w_base, w_noload)
    proposal = min(_up(ON_FACTOR * w_min), _down(w_up))
    pu = drive.w_base
    if w_min >= w_up * (1 - 1e-9):
        fall(
            "w_on",
            math.nan,
            "speed_unreachable",
            f"the observer's minimum speed for the handover, {w_min / pu:.3g} p.u., is at or above the "
            f"{'rated' if w_up == drive.w_base else 'no-load'} speed: no handover below it; the gains, not "
            "the start, must change (sensorless tune)",
        )
    elif v["if_w_on"] < w_min:
        fall(
            "w_on",
            proposal,
            "observer_lag_acceleration",
            f"below the observer's minimum speed for the handover, w_min = {w_min:.4g} rad/s "
            f"({w_min / pu:.3g} p.u.) at the gains under review: the observer never agrees with the open "
            "loop there and the drive never hands over",
        )
    elif v["if_w_on"] > w_up * (1 + 1e-9):
        fall(
            "w_on",
            proposal,
            "speed_unreachable",
            f"above the {'rated' if w_up == drive.w_base else 'no-load'} speed {w_up:.4g} rad/s "
            f"({w_up / pu:.3g} p.u.; no-load at the DC link {w_noload / pu:.3g} p.u.): the open loop never "
            "gets there",
        )
    if math.isfinite(v["if_w_on"]):
        if v["if_w_off"] < w_min * (1 - 1e-9) or v["if_w_off"] >= v["if_w_on"]:
            off = w_min if w_min < v["if_w_on"] else v["if_w_on"] / ON_FACTOR
            fall(
                "w_off",
                _up(off) if _up(off) < v["if_w_on"] else off,
                "observer_lag_acceleration",
                f"the drive must fall back to open loop at w_min = {w_min:.4g} rad/s, below w_on",
            )
    return StartJudgement(v, frozenset(k for k, n in KEYS.items() if n in given), tuple(out), w_min)


def largest_acceleration(drive: OnPmsm, current: float) -> float:
    """The largest I-f acceleration [rad/s^2] ``current`` [A, peak] gives against rated load at the load
    angle LOAD_ANGLE_MAX: p (k_t i_if sin(LOAD_ANGLE_MAX) - T_N) / J (the bound the acceleration is
    judged against above); at most 0 where the current cannot carry the rated load."""
    m, c = drive.motor, drive.control
    k_t = c.T_max / math.hypot(*mtpa_torque_current(c.T_max, m))
    return m.p * (k_t * current * math.sin(LOAD_ANGLE_MAX) - drive.T_N) / m.J


def faster_start(
    drive: OnPmsm, judged: StartJudgement, open_s: float, avail_s: float, need_s: float
) -> float:
    """The ``[startup] acceleration`` [rad/s^2] with which a check's end that the I-f start's time made
    miss (reports/causes.py ``ramp_slower_than_reference``: the start had the loop ``open_s`` of the
    ``avail_s`` after the reference's last step; the rest of the step needs ``need_s`` at the torque
    limit) fits: the start's ramp (its time less the dwell at w_on, which the acceleration does not
    shorten) scales as 1/a, the speed it covers is the same, and it must shrink by SWING_ALLOWANCE times
    the shortfall (the swing at a faster ramp's end lengthens the wait for the handover). The largest
    the I-f current carries (:func:`largest_acceleration`, 3 digits down) where that fits; nan where
    even it does not (no start-up acceleration fixes it: the handover, i.e. the gains' w_min, must)."""
    a = judged.values["if_acc"]
    a_max = _down(largest_acceleration(drive, judged.values["if_i"]))
    ramp = open_s - judged.values.get("if_t_dwell", 0.0)
    # the ramp's time that fits, cutting twice the shortfall: a faster ramp ends in a larger swing about
    # the current vector, which the handover waits out (the hub motor of tests/pmsm_flux_observer/drives:
    # 4390 -> 6430 rad/s^2 cut the ramp by 26 ms and the swing took 40 ms more: within the allowance, no
    # value is named there; a heuristic, not a simulation of the start)
    room = ramp - SWING_ALLOWANCE * (open_s + need_s - avail_s)
    if ramp <= 0 or room <= 0 or a_max <= a or a * ramp / room > a_max:
        return math.nan
    return a_max
