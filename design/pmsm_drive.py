"""Simulation set-up of a sensorless PMSM drive (symbolic/pmsm_drive.py) around any family's runtime observer.

Every family whose observer runs on a PMSM describes its drive in the numbers of :class:`PmsmDrive`
(true motor, the controllers' estimates, control settings) and gets the whole loop set-up for a
scenario from :func:`loop_setup`: the loop Function around its runtime step, the parameter vector,
the state at rest at the scenario's initial operating point (from the SX Functions of the loop and of
the observer, nothing re-typed) and the per-sample inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensorless.design.family import CapabilityError, Drive, Panel, TraceLine
from sensorless.design.registry import family_of
from sensorless.design.runtime import RuntimeSetup
from sensorless.design.scenario import Scenario, speed_filter_of
from sensorless.design.simulate import LoopSetup, noise, provenance, sample_times
from sensorless.symbolic.pmsm_drive import (
    INPUTS,
    MEAS,
    PARAMS,
    RECORD,
    initial_loop_state_function,
    loop_function,
    observer_record,
)

# the parameter-error factors of a scenario's [estimate_scale] that the loop applies to the
# controllers' estimates (a family on this loop declares them in ObserverFamily.estimate_keys, with
# the observer's own, which it applies itself); a factor not declared is 1
ESTIMATE_KEYS = ("R_s", "L_d", "L_q", "psi_pm", "J")

# the trace panel of this loop's stator currents (symbolic/pmsm_drive.py records i_d, i_q), for the
# families on this loop to list among their panels (ObserverFamily.panels)
CURRENT_PANEL = Panel(
    "current",
    "A",
    "stator current components in the true rotor frame",
    "current (A)",
    (TraceLine(("i_d",), "k-", r"$i_d$"), TraceLine(("i_q",), "k--", r"$i_q$")),
)


@dataclass(frozen=True)
class PmsmDrive:
    """The numbers of a PMSM drive loop (SI; speeds electrical)."""

    R_s: float  # true motor [ohm]
    L_d: float  # [H]
    L_q: float  # [H]
    psi_pm: float  # [V s]
    p: int  # pole pairs
    J: float  # total inertia [kg m^2]
    R_s_hat: float  # the controllers' estimates
    L_d_hat: float
    L_q_hat: float
    psi_pm_hat: float
    alpha_c: float  # current-control bandwidth [rad/s]
    alpha_s: float  # speed-control bandwidth [rad/s]
    T_max: float  # torque limit [N m]
    u_dc: float  # DC-link voltage [V]
    T_s: float  # sampling period [s]
    carrier: float = 0.0  # carrier frequency to keep out of the current feedback [rad/s]; 0: none
    carrier_band: float = 0.0  # its band-stop bandwidth [rad/s]


def from_sections(motor: Any, estimate: Any, control: Any, **carrier: float) -> PmsmDrive:
    """The numbers of the loop from a drive's sections: ``motor`` (R_s, L_d, L_q, psi_pm, p, J),
    ``estimate`` (R_s, L_d, L_q, psi_pm) and ``control`` (design/pmsm_schema.py's PmsmControl);
    ``carrier``: the ``carrier`` and ``carrier_band`` of an observer that injects one."""
    return PmsmDrive(
        R_s=motor.R_s,
        L_d=motor.L_d,
        L_q=motor.L_q,
        psi_pm=motor.psi_pm,
        p=motor.p,
        J=motor.J,
        R_s_hat=estimate.R_s,
        L_d_hat=estimate.L_d,
        L_q_hat=estimate.L_q,
        psi_pm_hat=estimate.psi_pm,
        alpha_c=control.alpha_c,
        alpha_s=control.alpha_s,
        T_max=control.T_max,
        u_dc=control.u_dc,
        T_s=control.T_s,
        **carrier,
    )


def _params(d: PmsmDrive, sc: Scenario, carrier: bool) -> np.ndarray:
    k = {key: sc.estimate_scale.get(key, 1.0) for key in ESTIMATE_KEYS}
    q = {
        "R_s": d.R_s,
        "L_d": d.L_d,
        "L_q": d.L_q,
        "psi_pm": d.psi_pm,
        "p": float(d.p),
        "J": d.J,
        "B": sc.viscous,
        "R_s_hat": d.R_s_hat * k["R_s"],
        "L_d_hat": d.L_d_hat * k["L_d"],
        "L_q_hat": d.L_q_hat * k["L_q"],
        "psi_pm_hat": d.psi_pm_hat * k["psi_pm"],
        "J_hat": d.J * k["J"],
        "alpha_c": sc.current_bandwidth or d.alpha_c,
        "alpha_s": d.alpha_s,
        "T_max": d.T_max,
        "u_max": d.u_dc / math.sqrt(3),
        "T_s": d.T_s,
        "sensor": 1.0 if sc.feedback == "sensor" else 0.0,
        "speed_mode": 1.0 if sc.mode == "speed" else 0.0,
        "stiff": 1.0 if sc.stiff_load else 0.0,
        "alpha_w": speed_filter_of(sc, d.alpha_s),
        "notch": 1.0 if carrier and d.carrier > 0 else 0.0,
        "w_n": d.carrier if d.carrier > 0 else math.pi / d.T_s / 2,  # unused without the notch
        "B_n": d.carrier_band if d.carrier_band > 0 else 1.0,
    }
    return np.array([q[s.name] for s in PARAMS])


def inputs(sc: Scenario, T_s: float) -> np.ndarray:
    """(len(INPUTS), N) per-sample inputs: references, load, noise."""
    t = sample_times(sc, T_s)
    v = np.zeros((len(INPUTS), t.size))
    v[0] = sc.speed_reference.sample(t)
    v[1] = sc.load_torque.sample(t)
    v[2] = sc.torque_reference.sample(t)
    v[3:5] = noise(sc, t.size)
    return v


def loop_setup(
    drive: Drive, data: PmsmDrive, sc: Scenario, setup: RuntimeSetup, carrier: bool, meta: dict[str, Any]
) -> LoopSetup:
    """The loop set-up of ``sc`` on a PMSM drive with the runtime observer ``setup``.

    ``carrier``: the observer injects a carrier (its output ``u_c_d``) that the current control must
    not see. ``meta`` adds the family's own entries (its gains, its switches) to the provenance.
    """
    obs = setup.observer
    meas = tuple(f.name for f in obs.meas)
    if meas != MEAS:
        raise CapabilityError(
            f"{obs.name}: the PMSM drive loop feeds the measurements {', '.join(MEAS)}, "
            f"the observer takes {', '.join(meas)}"
        )
    if obs.steady_state is None:  # a capability the family lacks: one line from every command
        raise CapabilityError(
            f"observer family {family_of(drive).name!r}: its runtime observer {obs.name} has no steady "
            "state (RuntimeObserver.steady_state) to start a simulation from"
        )
    step = setup.step_function()
    loop = loop_function(step, tuple(f.name for f in obs.outputs))
    q = _params(data, sc, carrier)
    v = inputs(sc, data.T_s)
    z_loop, op = initial_loop_state_function()(q, v[:, 0], sc.w_m0, sc.theta_m0)
    op = np.asarray(op).ravel()
    op[0] -= sc.theta_err0  # the estimate starts off by the scenario's angle error
    x_obs = np.asarray(obs.steady_state()(setup.p, op)).ravel()
    return LoopSetup(
        loop=loop,
        q=q,
        p_obs=setup.p,
        gain=setup.gain,
        z0=np.concatenate([np.asarray(z_loop).ravel(), x_obs]),
        inputs=v,
        record=RECORD + observer_record(obs.outputs),
        T_s=data.T_s,
        meta={
            **provenance(drive, sc),
            "gain": setup.gain_source,
            "gain_law": setup.gains.family,
            "discretization": setup.discretization,
            "feedback": sc.feedback,
            "T_s": data.T_s,
            "base_w": drive.w_base,
            "T_N": drive.T_N,
            "pole_pairs": data.p,
            "speed_unit": "p.u.",
            "speed_scale": 1 / drive.w_base,  # rad/s (electrical) -> speed_unit
            **meta,
        },
    )
