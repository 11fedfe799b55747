"""The adaptive observer's own causes of a failed time-domain check (reports/causes.py), and what its
verdict may say of the checks through zero speed.

- the HF injection's coupling band (Piippo et al. 2008, Section V; design/ipmsm_adaptive/carrier.py):
  regenerating below the injection's fade-out w_Delta and above the speed |w_1| below which the HF
  correction (20) holds the angle, the averaged loop with the injection has a real right-half-plane pole;
  a closed-loop failure there is "injection_coupling_band";
- an RHP band of the linearization with the injection the drive runs (the shared rule leaves a family
  that holds zero speed by injection to it): "rhp_band";
- the verdict's reason on the coupling band says that zero-speed crossings pass it in a transient only
  where every check through zero speed passed (:func:`crossings`): an explanation never contradicts a
  check.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.ipmsm_adaptive import FAMILY
from sensorless.design.ipmsm_adaptive.carrier import coupling_limit, coupling_torque
from sensorless.reports.causes import CLOSED_LOOP, Failure, Named, operating_torque_pu

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive


def crossings(td: Sequence[dict[str, Any]]) -> str:
    """What the time-domain checks through zero speed say of the injection's coupling band: pass it in a
    transient only where every one of them passed (an explanation never contradicts a check)."""
    crossing = [c for c in td if c.get("crosses_zero")]
    failed = [c for c in crossing if not c["passed"]]
    if failed:
        causes = sorted({x for c in failed for x in c.get("causes", [])})
        return (
            f"the time-domain checks through zero speed ({', '.join(c['name'] for c in failed)}) fail "
            f"(causes: {', '.join(causes) or 'see the checks'}): the crossings do not get through it here."
        )
    if crossing:
        return (
            f"zero-speed crossings pass it in a transient (the time-domain checks "
            f"{', '.join(c['name'] for c in crossing)}), but do not hold a regenerating speed in that band "
            "under load."
        )
    return (
        "no time-domain check crosses zero speed here: a regenerating speed in that band under load does "
        "not hold."
    )


def _coupling_fix(drive: IpmsmDrive, w: float, T: float) -> str:
    """The change for a failure in the coupling band at |w| [rad/s], |T| [N m]: the regenerating torque at
    which the correction holds there (carrier.py ``coupling_torque``), or a position sensor."""
    t_c = coupling_torque(drive.motor, w, T)
    return (
        f"keep the regenerating torque at this speed within {t_c:.4g} N m ({t_c / drive.T_N:.3g} T_N), where "
        "the HF correction holds, or run on a position sensor below the injection's fade-out"
    )


def _speed_loop_named(drive: IpmsmDrive, failure: Failure) -> Named:
    hz, a_s, a_i = 2 * math.pi, drive.control.alpha_s, drive.injection.alpha_i
    w_asked = failure.w_ref_pu if failure.w_ref_pu is not None else failure.w_pu
    return Named(
        "injection_speed_loop",
        f"asked for {w_asked:+.3g} p.u., inside the injection's fade-out "
        f"{drive.injection.w_Delta / drive.w_base:.3g} p.u., where the angle and speed estimates come "
        f"through the injection's PI (21)-(22) of alpha_i = {a_i / hz:.3g} Hz: the speed loop (alpha_s = "
        f"{a_s / hz:.3g} Hz) is faster than it (design/ipmsm_adaptive/derive.py)",
        f"a speed loop no faster than the injection's PI ([control] alpha_s <= {a_i / hz:.3g} Hz, the rule "
        "of sensorless init), or a faster PI ([injection] alpha_i)",
    )


def failure_cause(drive: IpmsmDrive, gains: GainSet, failure: Failure) -> Named | None:
    """The cause of a failed check in the adaptive observer's own analysis (reports/causes.py): a closed-loop
    failure regenerating where the HF injection runs, above the speed below which its correction (20) holds
    (design/ipmsm_adaptive/carrier.py ``coupling_limit``), is the injection's coupling band; one where the
    linearization with the injection the drive runs has a right-half-plane pole, an RHP band; None for
    anything else (the shared rules)."""
    torque = operating_torque_pu(failure)  # T_e where recorded: braking against the load regenerates
    if failure.kind not in CLOSED_LOOP or failure.open_loop or failure.w_pu is None or torque is None:
        return None
    wb, T_N = drive.w_base, drive.T_N
    w, T = failure.w_pu * wb, torque * T_N
    inj = bool(drive.injection.enabled)
    # asked to run where the injection runs (a loss there runs off at the torque limit before it is seen)
    w_ref = w if failure.w_ref_pu is None else failure.w_ref_pu * wb
    in_band = inj and min(abs(w), abs(w_ref)) < drive.injection.w_Delta
    if in_band and drive.control.alpha_s > drive.injection.alpha_i * (1 + 1e-6):
        return _speed_loop_named(drive, failure)
    if inj and abs(w) < drive.injection.w_Delta and w * T < 0:
        w1 = coupling_limit(drive.motor, T)
        if abs(w) > w1:
            return Named(
                "injection_coupling_band",
                f"regenerating at {failure.w_pu:+.3g} p.u., T_e = {torque:+.3g} T_N: above the HF "
                f"correction's coupling limit {w1 / wb:.3g} p.u. at this torque, below the injection's "
                f"fade-out {drive.injection.w_Delta / wb:.3g} p.u. (design/ipmsm_adaptive/carrier.py)",
                _coupling_fix(drive, abs(w), abs(T)),
            )
    s = FAMILY.linearize(drive, gains, np.array([w]), T, injection=inj)
    if np.nanmax(s.max_real) > 0:
        return Named(
            "rhp_band",
            f"at {failure.w_pu:+.3g} p.u., T_e = {torque:+.3g} T_N the linearized observer"
            f"{' with the injection' if inj else ''} has a pole at Re = {np.nanmax(s.max_real):+.3g} 1/s",
        )
    return None
