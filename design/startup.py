"""The open-loop I-f start of a drive (symbolic/startup.py) with its numbers: rules and runtime set-up.

The rules (each with its reason; :func:`if_values`):

- current amplitude i_if = T_max / k_t (k_t: torque per ampere, peak): the torque limit's current, so
  that rated load is carried at a load angle acos(T_N/T_max) (48 deg at T_max = 1.5 T_N), well below
  the 90 deg at which the rotor falls out of step;
- acceleration a = ACC_SHARE p (T_max - T_N) / J: half what the torque margin over rated load gives
  the rotor, so that it follows the current vector with margin;
- handover speed w_on = ON_FACTOR (2) w_min, never above 1 p.u., and back to open loop below w_off =
  w_min (at most w_on / ON_FACTOR), w_min the minimum speed at rated load for the handover: the whole
  sampled drive's minimum sensorless speed (design/low_speed.py on design/drive_analysis.py) with, as a
  fifth criterion, its angle error under the largest speed change at each load T within the analysis'
  angle limit (30 deg): the bias at the fixed point plus the loop's steady lag to a speed ramp of slope
  p (T_max + |T|) / J, a linear property of the whole-drive linearization. That slope is the speed
  loop braking at the torque limit with the load helping (a speed step towards zero under a motoring
  load): the drop back to open loop is below w_min, so the observer must hold the rotor while the drive
  brakes down to it (the 2807 drone motor with its tuned gains, speed steps: judged at p (T_max - T_N) /
  J the drive dropped back at 0.087 p.u. and lost the rotor at 0.11 p.u., braking at 4.9 times that;
  judged at p (T_max + T_N) / J it drops back at 0.18 p.u. and holds 19 deg); a drive whose speed
  reference is rate-limited (``[control] speed_ramp``, design/speed_ramp.py) is asked for no more than
  its ramp, so the slope is the lower of the two (the gimbal motor of docs/examples/motors: w_min 1 ->
  0.184 p.u. at its start's 1375 rad/s^2, and every check passes). Below that speed the
  observer loses the rotor when the speed controller it takes over from the start accelerates or
  brakes at the torque limit; where the handover must be high (the acceleration limits it, or the
  rule's 2 w_min reaches 1 p.u. and is capped there) the start's line says why with the numbers
  (:func:`handover_reason`; the report quotes it); the band between w_off and w_on is the hysteresis;
- damping gain k_d = 2 ZETA w_n (ZETA = 0.5), w_n = sqrt(p T_max cos(delta_N) / J) the rotor's swing
  about the current vector at rated load (sin(delta_N) = T_N / T_max; symbolic/startup.py): a swing
  decays within about a period instead of lasting until the rotor slips;
- the swing's high-pass corner w_hp = HP_SHARE (1/4) w_n: well below the swing (whose phase it leaves
  within 15 deg), well above the slow change of the load angle along the ramp;
- current per acceleration k_a = J / (p k_t), the motor's (not a choice: never in the drive file),
  for the load angle of a drop back to open loop (symbolic/startup.py);
- dwell at the handover speed t_dwell = DWELL (1.5) / sigma, sigma the observer's decay at w_on under
  rated load (at least the required one) from the family's observer-only linearization: in the dwell
  the controllers run on the I-f frame, not on the estimate, which is that analysis' set-up (the whole
  drive's slowest mode need not be the observer's: on the 400-W servo, tuned, 233 1/s against the
  observer's 398 1/s, and a dwell that long leaves the speed steps in open loop at their end); three
  time constants of the observer's error, so that the observer has converged on the rotor when it
  takes over (it may have lost it while the ramp accelerated through low speeds, where the start does
  not need it; the start re-seeds it: symbolic/startup.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from sensorless.design.drive_file import Entry, load_section, q, table
from sensorless.design.low_speed import MAX_BIAS_DEG
from sensorless.design.runtime import RuntimeSetup
from sensorless.design.units import DriveFileError, check_magnitude, parse_quantity
from sensorless.symbolic.startup import with_startup

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.low_speed import LowSpeed

ACC_SHARE = 0.5
# how the start's line says that the observer cannot follow the drive's full acceleration (the failed
# checks of reports/time_domain.py quote it)
ACCELERATION_LIMIT = "the whole drive's angle error under the full acceleration exceeds its limit below"
# how the start's line says that the rule's handover (ON_FACTOR w_min) was capped at the rated speed where
# w_min itself is not limited by the acceleration (reports/low_speed.py quotes it, as the one above)
HANDOVER_CAPPED = "the handover is capped at the rated speed"
ON_FACTOR = 2.0
ZETA = 0.5
DWELL = 1.5
HP_SHARE = 0.25
# The ranges of the values a [startup] section may give (past them a value is a unit or typing error,
# not a start): the handover below the rated speed (1 p.u.; a multiple of w_min up to W_MIN_FACTOR_MAX),
# a dwell of at most DWELL_MAX (the rule gives 1.5 time constants of the observer's error), a current
# of at most CURRENT_SHARE_MAX times the torque limit's (design/pmsm_drive.py, which knows the motor)
SPEED_MAX_PU = 1.0
W_MIN_FACTOR_MAX = 20.0
DWELL_MAX = 10.0  # s
CURRENT_SHARE_MAX = 3.0


def swing_frequency(T_N: float, T_max: float, J: float, p: int) -> float:
    """w_n [rad/s]: the rotor's swing about the I-f current vector (k_t i_if = T_max) at rated load."""
    return math.sqrt(p * T_max * math.sqrt(max(0.0, 1 - (T_N / T_max) ** 2)) / J)


def handover_reason(ls: LowSpeed, given_on: float | None = None) -> str:
    """Why the handover is high, in one line with the numbers (a LowSpeed of design/low_speed.py with
    the acceleration criterion): what limits w_min at rated load, and that the handover stays at 1 p.u.
    at most: where the acceleration limits it, or where the rule's ON_FACTOR w_min reaches 1 p.u. (the
    handover capped there: a gimbal motor's drive file handed over at 1 p.u. without a word).
    ``given_on`` [rad/s]: the handover the drive file fixes (``[startup] w_on`` as a speed), which the
    start runs instead of the rule's: the line then says where it lies against w_min, never that the
    handover is at (or capped at) 1 p.u. (a gimbal's file with w_on = 0.3 p.u. was told "handover at
    1 p.u." in its failed checks)."""
    w = ls.w_min_rated / ls.w_base
    why = ls.rated_limited_by
    if given_on is not None:
        on = given_on / ls.w_base
        where = "below" if on < w * (1 - 1e-9) else "at or above"
        given = f" (the drive file's handover {on:.3g} p.u. is {where} it)"
        if why != "acceleration":  # no cap to explain: the file's handover runs, where w_min says
            return f"the whole drive's w_min at rated load is {w:.3g} p.u. (limited by {why}){given}"
    if why == "acceleration":
        braking = (
            f"along the speed reference's ramp ([control] speed_ramp = {ls.acceleration:.4g} rad/s^2)"
            if ls.ramped
            else f"braking at p (T_max + T_N) / J = {ls.acceleration:.4g} rad/s^2 at rated load"
        )
        head = (
            f"{ACCELERATION_LIMIT} {w:.3g} p.u. (angle error > {MAX_BIAS_DEG:g} deg {braking}, the whole "
            "drive's lag to a speed ramp)"
        )
    else:  # the rule's ON_FACTOR w_min reaches the rated speed: the handover is capped there
        return (
            f"{HANDOVER_CAPPED} (1 p.u.): the whole drive's w_min at rated load is {w:.3g} p.u. (limited by "
            f"{why}), {ON_FACTOR:g} w_min = {ON_FACTOR * w:.3g} p.u.: below w_min the observer does not meet "
            "its criteria (gains with a lower w_min: sensorless tune)"
        )
    cap = (
        given
        if given_on is not None
        else " (above 1 p.u.: handover at 1 p.u.)"
        if w >= 1 - 1e-9
        else f" ({ON_FACTOR:g} w_min = {ON_FACTOR * w:.3g} p.u., above 1 p.u.: handover at 1 p.u.)"
        if ON_FACTOR * w >= 1 - 1e-9
        else ""
    )
    return (
        f"{head}{cap}: a full-torque acceleration or braking below it may lose the rotor (limit the "
        "acceleration: ramp the speed reference or lower T_max; or raise the observer's gains)"
    )


def if_values(
    T_N: float,
    T_max: float,
    J: float,
    p: int,
    k_t: float,
    w_min: float,
    sigma: float,
    w_rated: float = math.inf,
) -> dict[str, float]:
    """The I-f start's parameters (module docstring); speeds electrical [rad/s], sigma the decay rate
    at the handover speed [1/s]; the handover never above ``w_rated``."""
    w_n = swing_frequency(T_N, T_max, J, p)
    w_on = min(ON_FACTOR * w_min, w_rated)
    return {
        "if_i": T_max / k_t,
        "if_acc": ACC_SHARE * p * (T_max - T_N) / J,
        "if_w_on": w_on,
        "if_w_off": min(w_min, w_on / ON_FACTOR),
        "if_k_d": 2 * ZETA * w_n,
        "if_w_hp": HP_SHARE * w_n,
        "if_t_dwell": DWELL / sigma,
        "if_k_a": J / (p * k_t),
    }


SECTION = "startup"
SPEEDS = ("w_on", "w_off")  # in rad/s, Hz, p.u. or as multiples of w_min ("2 w_min")


@dataclasses.dataclass(frozen=True)
class StartupSettings:
    """The ``[startup]`` section of a drive file: the I-f start's parameters (SI, speeds electrical);
    every key optional (a missing one keeps its rule); a speed given in w_min (``w_on = "2 w_min"``) is
    that multiple of the minimum sensorless speed at the gains under review."""

    current: float | None = q("current", doc="I-f current amplitude (peak)", default=None)
    acceleration: float | None = q("rate_squared", doc="I-f acceleration, electrical", default=None)
    w_on: float | None = q("angular", doc="handover speed to the observer, electrical", default=None)
    w_off: float | None = q("angular", doc="back to open loop below it, electrical", default=None)
    damping: float | None = q("rate", "nonnegative", doc="damping gain of the swing", default=None)
    w_hp: float | None = q("angular", doc="high-pass corner of the swing, electrical", default=None)
    dwell: float | None = q("time", "nonnegative", doc="time at w_on before the handover", default=None)
    w_on_per_w_min: float | None = None  # w_on given as this multiple of w_min
    w_off_per_w_min: float | None = None

    @property
    def needs_w_min(self) -> bool:
        """Whether a value is to come from w_min: a speed not given, or given as a multiple of it (the
        other keys' rules need no w_min: the dwell's decay is the required decay then)."""
        return any(getattr(self, k) is None for k in SPEEDS)

    @property
    def complete(self) -> bool:
        """Whether every key is given (no rule needed at all)."""
        keys = ("current", "acceleration", "damping", "w_hp", "dwell", *SPEEDS)
        return all(getattr(self, k) is not None for k in keys)

    def values(self, w_min: float | None = None) -> dict[str, float]:
        """The keys given, as :func:`if_values` names them, speeds in w_min resolved at ``w_min`` (left
        out without it)."""
        k = (self.w_on_per_w_min, self.w_off_per_w_min)
        on = self.w_on if k[0] is None else (None if w_min is None else k[0] * w_min)
        off = self.w_off if k[1] is None else (None if w_min is None else k[1] * w_min)
        given = {
            "if_i": self.current,
            "if_acc": self.acceleration,
            "if_w_on": on,
            "if_w_off": off,
            "if_k_d": self.damping,
            "if_w_hp": self.w_hp,
            "if_t_dwell": self.dwell,
        }
        return {k: v for k, v in given.items() if v is not None}


def load_startup(data: Mapping[str, Any], file: str, w_base: float) -> StartupSettings:
    """The ``[startup]`` section of a drive file's data, strictly (speeds in rad/s, Hz, p.u. of
    ``w_base`` or w_min; each key optional, a missing one keeps its rule); DriveFileError naming the
    key."""
    t = table(data, SECTION, file)
    keys = ("current", "acceleration", *SPEEDS, "damping", "w_hp", "dwell")
    s = load_section(
        StartupSettings, t, file, SECTION, skip=(*SPEEDS, "w_on_per_w_min", "w_off_per_w_min"), optional=keys
    )
    for k in ("w_on_per_w_min", "w_off_per_w_min"):
        if k in t:
            raise DriveFileError(file, f"{SECTION}.{k}", f"unknown key (allowed: {', '.join(keys)})")
    speeds: dict[str, Any] = {}
    for k in SPEEDS:
        if k not in t:
            continue
        x, rel = parse_quantity(t[k], "angular", file=file, key=f"{SECTION}.{k}")
        if not x > 0:
            raise DriveFileError(file, f"{SECTION}.{k}", f"non-physical value {t[k]!r}: must be > 0")
        if rel == "w_min":
            if x > W_MIN_FACTOR_MAX:
                raise DriveFileError(
                    file, f"{SECTION}.{k}", f"{t[k]!r}: at most {W_MIN_FACTOR_MAX:g} w_min (the handover)"
                )
            speeds[f"{k}_per_w_min"] = x
        else:
            speeds[k] = (
                check_magnitude(x * w_base, t[k], file=file, key=f"{SECTION}.{k}") if rel == "pu" else x
            )
            if speeds[k] > SPEED_MAX_PU * w_base * (1 + 1e-12):
                raise DriveFileError(
                    file,
                    f"{SECTION}.{k}",
                    f"{t[k]!r} = {speeds[k] / w_base:.4g} p.u.: the open loop hands over below the rated "
                    f"speed (at most {SPEED_MAX_PU:g} p.u. = {SPEED_MAX_PU * w_base:.6g} rad/s, electrical)",
                )
    if s.dwell is not None and s.dwell > DWELL_MAX:
        raise DriveFileError(
            file,
            f"{SECTION}.dwell",
            f"{t['dwell']!r}: at most {DWELL_MAX:g} s (the time at w_on before handover)",
        )
    s = dataclasses.replace(s, **speeds)
    on, off = (s.w_on, s.w_off) if s.w_on_per_w_min is None else (s.w_on_per_w_min, s.w_off_per_w_min)
    if (s.w_on is None) == (s.w_off is None) and on is not None and off is not None and off >= on:
        raise DriveFileError(
            file, f"{SECTION}.w_off", f"must be below {SECTION}.w_on (the hysteresis band lies between)"
        )
    return s


def document_entries(values: Mapping[str, float], w_base: float, w_min: float) -> dict[str, Entry]:
    """The ``[startup]`` entries of ``sensorless init`` for the values of :func:`if_values`, each with its
    rule as the comment (module docstring); the speeds as multiples of w_min, so that they follow the
    gains under review (a tuned gain table moves w_min)."""
    return {
        "current": Entry(f"{values['if_i']:.6g} A", "T_max / k_t: the torque limit's current (MTPA, peak)"),
        "acceleration": Entry(
            f"{values['if_acc']:.6g} rad/s2",
            f"{ACC_SHARE:g} p (T_max - T_N) / J: that share of the torque margin over rated load",
        ),
        "w_on": Entry(f"{ON_FACTOR:g} w_min", "the handover, with margin (rad/s or p.u. to fix it)"),
        "w_off": Entry(
            "1 w_min",
            f"w_min at rated load for the handover, the gains under review (design/low_speed.py on the whole "
            "sampled drive, with its angle error under the full acceleration, design/startup.py): "
            f"{w_min / w_base:.4g} p.u. at this file's own gains",
        ),
        "damping": Entry(
            f"{values['if_k_d']:.6g} 1/s",
            f"2 zeta w_n, zeta = {ZETA:g}: damps the rotor's swing about the current vector, w_n = sqrt(p "
            "T_max cos(delta_N) / J), sin(delta_N) = T_N / T_max (0: undamped)",
        ),
        "w_hp": Entry(
            f"{values['if_w_hp']:.6g} rad/s",
            f"{HP_SHARE:g} w_n: the swing's high-pass, below it, above the load angle's slow change",
        ),
    }


# The drive-file keys each derived [startup] value follows from (by the rules of document_entries):
# an error in a derived value names them, the keys the user wrote
DERIVED_FROM = {
    "current": "control.T_max, motor.psi_pm",
    "acceleration": "motor.J, motor.p, control.T_max",
    "damping": "motor.J, motor.p, control.T_max",
    "w_hp": "motor.J, motor.p, control.T_max",
    "dwell": "motor.J, motor.p, control.T_max",
}


def optional_lines(values: Mapping[str, float]) -> list[str]:
    """The ``[startup]`` keys ``sensorless init`` writes commented out: the dwell, whose rule follows the
    gains under review (as w_min does; a number in the file would keep the value of the file's own)."""
    return [
        f'dwell = "{values["if_t_dwell"]:.6g} s"  # optional: {DWELL:g} / sigma, sigma the decay at w_min at '
        "the gains under review (this value at the file's): the observer converges at w_on before handover"
    ]


def with_if_start(setup: RuntimeSetup, values: dict[str, float]) -> RuntimeSetup:
    """``setup`` with its observer wrapped in the I-f start (symbolic/startup.py) and its parameters."""
    obs = with_startup(setup.observer)
    params: dict[str, Any] = {**setup.params, **values}
    obs.check_params(params)
    notes = (
        *setup.notes,
        f"I-f start: handover at {values['if_w_on']:.4g} rad/s, back below {values['if_w_off']:.4g} rad/s",
    )
    return dataclasses.replace(setup, observer=obs, params=params, notes=notes)
