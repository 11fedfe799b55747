"""The open-loop start judged (design/startup_check.py) in each firmware's own fields: what to write,
and the one line per change that says why.

VESC (vesc.py): ``foc_openloop_rpm`` [ERPM] = w_on, ``foc_sl_openloop_time`` [s] = w_on / acceleration,
``foc_sl_openloop_hyst`` [s] = (w_on - w_off) / acceleration; its open-loop current is set by its own
fields (not written: the start's current is judged as [startup] current). ODrive (odrive.py):
``axis0.config.sensorless_ramp.current`` [A], ``.accel`` [rad/s^2], ``.vel`` [rad/s] = w_on; no w_off.
Any other firmware (generic, SimpleFOC): the drive file's ``[startup]`` keys.
"""

from __future__ import annotations

from collections.abc import Mapping

from sensorless.design.pmsm_flux_observer.firmware import erpm, stored
from sensorless.design.pmsm_flux_observer.firmware.odrive import RAMP
from sensorless.design.startup_check import KEYS, StartJudgement

UNITS = {"current": "A", "acceleration": "rad/s^2", "w_on": "rad/s", "w_off": "rad/s"}


def fields(firmware: str, values: Mapping[str, float]) -> dict[str, tuple[float, str]]:
    """The firmware's start-up fields of the start ``values`` (design/startup.py names, SI): field ->
    (value in the firmware's unit, unit)."""
    on, off, acc = values["if_w_on"], values["if_w_off"], values["if_acc"]
    if firmware == "vesc":  # whole ERPM as VESC Tool shows them, times to 4 digits
        rpm = float(round(erpm(on)))
        return {
            "foc_openloop_rpm": (rpm, "ERPM"),
            "foc_sl_openloop_time": (float(f"{on / acc:.4g}"), "s"),
            "foc_sl_openloop_hyst": (float(f"{(on - off) / acc:.4g}"), "s"),
        }
    if firmware == "odrive":
        return {
            RAMP + "current": (values["if_i"], "A"),
            RAMP + "accel": (acc, "rad/s^2"),
            RAMP + "vel": (on, "rad/s"),
        }
    return {f"[startup] {k}": (values[n], UNITS[k]) for k, n in KEYS.items()}


def change_lines(firmware: str, judged: StartJudgement, w_base: float) -> list[str]:
    """One line per start-up value that does not hold (its key, the value now, the value that fixes it,
    why, the cause's id), then the firmware's fields to write (those that change, from what); empty
    where every value holds."""
    if not judged.shortfalls:
        return []
    before = dict(judged.values)
    lines = []
    for s in reversed(judged.shortfalls):
        before[KEYS[s.key]] = s.value
    for s in judged.shortfalls:
        unit = UNITS[s.key]
        pu = f" ({s.value / w_base:.3g} p.u.)" if unit == "rad/s" else ""
        src = "the drive file's" if s.given else "the rule's"
        fix = (
            f"needs {stored(s.needed)} {unit}" + (f" ({s.needed / w_base:.3g} p.u.)" if pu else "")
            if s.needed == s.needed
            else "no start-up value fixes it"
        )
        now = f"[startup] {s.key} = {stored(s.value)} {unit}{pu} ({src})"
        lines.append(f"start-up: {now} {fix}: {s.why} (cause: {s.cause})")
    if judged.fixable:
        old, new = fields(firmware, before), fields(firmware, judged.values)
        changed = [
            f"{k} = {stored(v)} {u}" + (f" (was {stored(old[k][0])})" if old[k][0] > 0 else "")
            for k, (v, u) in new.items()
            if stored(v) != stored(old[k][0])
        ]
        if changed:
            lines.append("start-up: write " + ", ".join(changed))
    return lines
