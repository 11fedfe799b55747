"""Simulation set-up of the adaptive-observer drive: Piippo, Hinkkanen, Luomi (2008) Fig. 7 for a scenario.

The shared PMSM drive loop (design/pmsm_drive.py) around this family's runtime step, with the
scenario's gain choice, HF injection switch, discretization and parameter errors applied to the
observer's parameters.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from sensorless.design.family import GainSet, Panel, TraceLine
from sensorless.design.ipmsm_adaptive.carrier import FEEDBACK_MAX, SpeedLoopPath, speed_loop_feedback
from sensorless.design.ipmsm_adaptive.runtime import drive_gains, runtime_setup
from sensorless.design.pmsm_drive import CURRENT_PANEL, ESTIMATE_KEYS, loop_setup
from sensorless.design.pmsm_schema import saliency
from sensorless.design.runtime import RuntimeSetup
from sensorless.design.scenario import Scenario, speed_filter_of
from sensorless.design.simulate import LoopSetup, SimulationError, StateFrames

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

# scenario keys this family adds (design/scenario.py): section -> key -> (dimension, default)
SCENARIO_OPTIONS = {
    "observer": {
        "gain": ("str", None),  # [observer.gains.*] name; None: the drive's default
        "injection": ("bool", None),  # HF injection (Section V); None: the drive's ([injection] u_c > 0)
    }
}

# [estimate_scale] keys: the shared loop's (the controllers' estimates); R_s, L_d, L_q, psi_pm also
# scale the observer's (scaled_setup)
SCENARIO_ESTIMATE_KEYS = ESTIMATE_KEYS

# trace panels of its own (a scenario's figure list): the loop's currents and the HF-injection signal
PANELS = (
    CURRENT_PANEL,
    Panel(
        "w_eps",
        "rad/s",
        "HF-injection correction omega_eps (21)",
        r"$\omega_\varepsilon$ (rad/s)",
        (TraceLine(("w_eps",), "k-", r"$\omega_\varepsilon$"),),
    ),
)


def scaled_setup(setup: RuntimeSetup, sc: Scenario) -> RuntimeSetup:
    """The runtime set-up with the scenario's injection switch and parameter errors."""
    params = dict(setup.params)
    params["injection"] = 1.0 if sc.options["injection"] else 0.0
    for k in ("R_s", "L_d", "L_q", "psi_pm"):
        params[k] = params[k] * sc.estimate_scale.get(k, 1.0)
    setup.observer.check_params(params)
    return dataclasses.replace(setup, params=params)


def injection_off(drive: IpmsmDrive) -> str:
    """Why the drive has no HF injection to analyse or simulate (one line)."""
    xi = saliency(drive.estimate.L_d, drive.estimate.L_q)
    return (
        f"{drive.file}: the drive's HF injection is off ([injection] u_c = 0 V; saliency "
        f"2|L_q - L_d|/(L_q + L_d) = {xi:.3g}{': L_d = L_q gives no error signal (19)' if xi == 0 else ''})"
    )


def with_injection(drive: IpmsmDrive, sc: Scenario) -> Scenario:
    """The scenario with its injection switch resolved: not given, the drive's; on for a drive whose
    injection is off, SimulationError naming the key (a non-salient motor gives no error signal)."""
    inj = sc.options.get("injection")
    if inj is None:
        inj = drive.injection.enabled
    elif inj and not drive.injection.enabled:
        raise SimulationError(
            f"{sc.file}: key 'observer.injection': true, but {injection_off(drive)}; "
            "run it with the injection off (sensorless simulate --injection off)"
        )
    return dataclasses.replace(sc, options={**sc.options, "injection": bool(inj)})


def build(drive: IpmsmDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """Loop set-up of ``sc`` on ``drive``; ``gains`` None: the scenario's [observer] gain choice."""
    sc = with_injection(drive, sc)
    gains = gains or drive_gains(drive, sc.options.get("gain"))
    setup = scaled_setup(runtime_setup(drive, gains, sc.discretization), sc)
    inj = bool(sc.options["injection"])
    share = speed_loop_share(drive, speed_filter_of(sc, drive.control.alpha_s))
    notch_w = inj and share > FEEDBACK_MAX
    return loop_setup(
        drive,
        sc,
        setup,
        meta={"injection": inj, "speed_notch": f"{share:.3g}" if notch_w else ""},
        carrier=(drive.injection.w_c, drive.run.w_bp),
        notch=inj,
        frames=FRAMES,
        speed_notch=notch_w,
    )


def speed_loop_share(drive: IpmsmDrive, w_f: float, alpha_s: float | None = None) -> float:
    """G: the share of the HF error signal (19) the drive's speed loop (``alpha_s``, default the drive's)
    with the speed filter ``w_f`` [rad/s] feeds back against it (carrier.py ``speed_loop_feedback``).
    Where it is above FEEDBACK_MAX the drive band-stops its speed feedback at the carrier, as its current
    feedback (G then 0: the band-stop's zero at w_c); the paper's drive (G = 0.24) runs as published."""
    c = drive.control
    return speed_loop_feedback(speed_loop_path(drive), c.alpha_s if alpha_s is None else alpha_s, w_f)


def speed_loop_path(drive: IpmsmDrive) -> SpeedLoopPath:
    """The drive's path of the speed loop's carrier feedback (carrier.py ``speed_loop_feedback``)."""
    c, e = drive.control, drive.estimate
    return SpeedLoopPath(
        drive.observer.alpha_fo,
        e.L_q,
        e.psi_pm,
        drive.motor.J,
        drive.motor.p,
        c.alpha_c,
        drive.injection.w_c,
        c.T_s,
    )


# how the observer's state turns with the rotor (the whole-drive linearization, design/drive_analysis.py):
# the angle estimate; the flux estimate is in the estimated rotor frame; the HF chain at rest (off)
FRAMES = StateFrames(angles=("theta",), held=("phi_c", "bp_z1", "bp_z2", "lp_z1", "lp_z2", "x_eps"))


def analysed_loop(drive: IpmsmDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """The loop the whole-drive linearization analyses: the HF injection off (its carrier has no fixed
    point; with injection the observer-only analysis holds, design/low_speed.py)."""
    setup = build(drive, dataclasses.replace(sc, options={**sc.options, "injection": False}), gains)
    if not drive.injection.enabled:
        return setup
    note = (
        "HF injection off: its carrier has no fixed point; the observer-only analysis with the injection "
        "averaged (analyze --injection) and the minimum sensorless speed cover it"
    )
    return dataclasses.replace(setup, meta={**setup.meta, "drive_note": note})
