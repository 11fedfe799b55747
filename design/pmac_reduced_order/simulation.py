"""Simulation set-up of the reduced-order-observer drive: De Angelo et al. (2006) Fig. 1 for a scenario.

The drive loop of symbolic/pmac_reduced_order/drive_loop.py around this family's runtime step, with
the scenario's load-torque estimation switch (Gamma = 0 without it: the observer of their [11]),
feedforward, discretization and parameter errors.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.family import GainSet, Panel, TraceLine
from sensorless.design.pmac_reduced_order.runtime import drive_gains, runtime_setup
from sensorless.design.scenario import Scenario, speed_filter_of
from sensorless.design.simulate import LoopCoordinates, LoopSetup, noise, provenance, sample_times
from sensorless.design.units import DriveFileError
from sensorless.symbolic.pmac_reduced_order import drive_loop

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

PMAC_ALPHA_C = 2 * math.pi * 400  # [rad/s] the paper's "fast current control loop", not specified

# scenario keys this family adds (design/scenario.py): section -> key -> (dimension, default)
SCENARIO_OPTIONS = {
    "observer": {"load_torque_estimation": ("bool", True)},  # estimate T_L (Fig. 3) or not (Fig. 2)
    "control": {"feedforward": ("bool", False)},  # add T_L_hat to the torque reference (Fig. 5(b))
}

# [estimate_scale] keys: factors on the observer's estimates R, L (named L_d, as on a PMSM), J, Phi
SCENARIO_ESTIMATE_KEYS = ("R_s", "L_d", "J", "Phi")

# trace panels of its own (a scenario's figure list), De Angelo et al. (2006) Figs. 2-4
PANELS = (
    Panel(
        "load_torque",
        "N m",
        "load torque (dashed) and its estimate (solid) (De Angelo et al. 2006 Figs. 3-4)",
        r"$T_\mathrm{L}$ (N m)",
        (
            TraceLine(("T_L_total", "T_L"), "k--", r"$T_\mathrm{L}$"),
            TraceLine(("T_L_hat",), "k-", r"$\hat T_\mathrm{L}$"),
        ),
    ),
    Panel(
        "emf_error",
        "V",
        "norm of the EMF estimation error (De Angelo et al. 2006 Figs. 2-3)",
        r"$\|\varepsilon_e\|$ (V)",
        (TraceLine(("emf_err",), "k-", r"$\|\varepsilon_e\|$"),),
    ),
)


def build(drive: PmacDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """Loop set-up of ``sc`` on ``drive`` (Fig. 1); ``gains`` None: the drive's [observer]."""
    m, e, c = drive.motor, drive.estimate, drive.control
    if tuple(m.harmonics) != tuple(e.harmonics):
        raise DriveFileError(
            drive.file, "estimate.harmonics", "simulation needs the same harmonic orders as [motor]"
        )
    if sc.mode != "speed" or sc.stiff_load:
        raise DriveFileError(sc.file, "control.mode", "this drive's loop (Fig. 1) has speed control only")
    if sc.startup:  # De Angelo et al. (2006), Sec. V start and reverse open loop; this loop does not
        raise DriveFileError(
            sc.file, "control.startup", "this drive's loop (Fig. 1) has no open-loop start (I-f) modelled"
        )
    orders = tuple(int(n) for n in m.harmonics)
    gains = gains or drive_gains(drive)
    if not sc.options["load_torque_estimation"]:
        # the observer of [11]: no load-torque state (tau stays 0, so T_L_hat = 0)
        gains = dataclasses.replace(
            gains,
            values={**gains.values, "Gamma": 0.0},
            source=gains.source + " (load-torque estimation off)",
        )
    setup = runtime_setup(drive, gains, sc.discretization)
    k = sc.estimate_scale
    params = dict(setup.params)
    params.update(R=e.R * k["R_s"], L=e.L * k["L_d"], J=e.J * k["J"])
    Phi_hat = np.asarray(e.Phi, float) * k["Phi"]
    for f, v in zip(setup.observer.params[-len(orders) :], Phi_hat, strict=True):
        params[f.name] = float(v)
    setup.observer.check_params(params)
    setup = dataclasses.replace(setup, params=params)

    B = m.B + sc.viscous
    u_max = 2 * float(np.sum(np.abs(m.Phi))) * drive.w_base / m.p_r  # ideal inverter: twice the EMF at n_N
    qd = {
        "R": m.R,
        "L": m.L,
        "J": m.J,
        "B": B,
        "p_r": m.p_r,
        "R_hat": params["R"],
        "L_hat": params["L"],
        "alpha_c": sc.current_bandwidth or PMAC_ALPHA_C,
        "u_max": u_max,
        "T_s": c.T_s,
        "sensor": 1.0 if sc.feedback == "sensor" else 0.0,
        "alpha_w": speed_filter_of(sc, c.alpha_s),
        "J_hat": params["J"],
        "alpha_s": c.alpha_s,
        "T_max": c.T_max,
        "feedforward": 1.0 if sc.options["feedforward"] else 0.0,
    }
    q = np.array([*(qd[s.name] for s in drive_loop.PARAMS), *m.Phi, *Phi_hat])
    t = sample_times(sc, c.T_s)
    v = np.zeros((len(drive_loop.INPUTS), t.size))
    v[0] = sc.speed_reference.sample(t)
    v[1] = sc.load_torque.sample(t)
    v[2:4] = noise(sc, t.size)
    z0 = drive_loop.initial_state_function(orders)(q, setup.p, v[:, 0], sc.w_m0, sc.theta_m0, sc.theta_err0)
    obs = setup.observer
    loop = drive_loop.loop_function(setup.step_function(), tuple(f.name for f in obs.outputs), orders)
    g = setup.gains.values
    meta = {
        **provenance(drive, sc),
        "gain": f"{setup.gain_source}: g = {g['g']:g} 1/s, Gamma = {g['Gamma']:g}",
        "gain_law": setup.gains.law,
        "discretization": setup.discretization,
        "injection": False,
        "feedback": sc.feedback,
        "feedforward": bool(sc.options["feedforward"]),
        "T_s": c.T_s,
        "base_w": drive.w_base,
        "T_N": drive.T_N,
        "pole_pairs": m.p,
        "speed_unit": "r/min",
        "speed_scale": 30 / (math.pi * m.p),  # rad/s (electrical) -> r/min
    }
    return LoopSetup(
        loop=loop,
        q=q,
        p_obs=setup.p,
        gain=setup.gain,
        z0=np.asarray(z0).ravel(),
        inputs=v,
        record=drive_loop.RECORD,
        T_s=c.T_s,
        meta=meta,
        coordinates=_coordinates(orders, q, setup.p, len(obs.state)) if orders == (1,) else None,
    )


def _coordinates(orders: tuple[int, ...], q: np.ndarray, p_obs: np.ndarray, n_obs: int) -> LoopCoordinates:
    """The rotor coordinates of Fig. 1's loop with a sinusoidal EMF (with harmonics it is periodic in
    the angle, no fixed point): the currents, voltages and the observer's EMF and stored samples are
    stationary-frame vectors, its angle estimate an angle; the runtime contract's counter held at 0."""
    n = len(drive_loop.LOOP_STATE)
    init = drive_loop.initial_state_function(orders)

    def start(v0: np.ndarray, w0: np.ndarray) -> np.ndarray:
        return np.asarray(init.map(w0.size)(q, p_obs, v0, w0.reshape(1, -1), 0.0, 0.0))

    return LoopCoordinates(
        theta=2,
        speed=3,
        w_ref=0,
        load=1,
        angles=(n + 3,),
        vectors=((0, 1), (4, 5), (10, 11), (n, n + 1), (n + 5, n + 6), (n + 7, n + 8)),
        held=(n + n_obs - 1,),
        start=start,
    )


def analysed_loop(drive: PmacDrive, sc: Scenario, gains: GainSet | None) -> LoopSetup:
    """The loop the whole-drive linearization analyses: with EMF harmonics, the drive with its
    fundamental only (the sinusoidal case: the loop with harmonics runs on a periodic orbit, which the
    observer-only Floquet analysis covers), and said in ``meta['drive_note']``."""
    m, e = drive.motor, drive.estimate
    if tuple(m.harmonics) == (1,) and tuple(e.harmonics) == (1,):
        return build(drive, sc, gains)
    sine = dataclasses.replace(
        drive,
        motor=dataclasses.replace(m, harmonics=(1,), Phi=(m.Phi[m.harmonics.index(1)],)),
        estimate=dataclasses.replace(e, harmonics=(1,), Phi=(e.Phi[e.harmonics.index(1)],)),
    )
    setup = build(sine, sc, gains)
    note = (
        f"EMF harmonics {', '.join(str(h) for h in m.harmonics if h != 1)} left out: the drive with its "
        "fundamental EMF is linearized (with harmonics the loop runs on a periodic orbit; the observer-only "
        "analysis covers it by Floquet multipliers)"
    )
    return dataclasses.replace(setup, meta={**setup.meta, "drive_note": note})
