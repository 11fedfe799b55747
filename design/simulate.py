"""Time-domain simulation of a whole sensorless drive: a compiled ``mapaccum`` over the loop step.

``simulate(drive, scenario)`` builds the drive's loop step (for paper 000 the Fig. 7 loop of
symbolic/drive000.py around the runtime observer step that is also generated to C), the parameter
vectors, the initial state and the per-sample inputs (references, load, noise), and runs the loop as
``Function.mapaccum`` over chunks of samples, compiled to native code (design/compiled.py). No Python
code runs per sample; Python only moves from one chunk to the next, which is where progress is
reported. Each drive kind registers its builder in ``BUILDERS``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.compiled import compiled
from sensorless.design.scenario import Scenario
from sensorless.design.units import DriveFileError
from sensorless.symbolic.drive000 import (
    INPUTS,
    LOOP_STATE,
    PARAMS,
    RECORD,
    Signal,
    loop_function,
    observer_record,
)
from sensorless.symbolic.drive_control import speed_gains
from sensorless.symbolic.pmsm import PmsmParams, flux_from_current
from sensorless.tuning.gain_table import GainTable

CHUNK = 2048  # samples per compiled call: progress granularity; the per-call cost is negligible


@dataclass(frozen=True)
class LoopSetup:
    """Everything the runner needs: the loop Function, its constant inputs, initial state and inputs."""

    loop: ca.Function  # (z, v, q, p_obs, gain) -> (z_next, rec)
    q: np.ndarray
    p_obs: np.ndarray
    gain: np.ndarray
    z0: np.ndarray
    inputs: np.ndarray  # (n_v, N): one column per sample
    record: tuple[Signal, ...]  # names and units of the rows of rec
    T_s: float
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Traces:
    """Simulated signals at the sampling instants: ``t`` [s] and one array per recorded signal (SI)."""

    t: np.ndarray
    data: dict[str, np.ndarray]
    units: dict[str, str]
    docs: dict[str, str]
    meta: dict[str, Any]
    wall_time: float = 0.0  # [s] spent in the compiled loop (not written: it differs between runs)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def window(self, t0: float, t1: float = math.inf) -> np.ndarray:
        """Boolean mask of the samples with t0 <= t < t1."""
        return (self.t >= t0) & (self.t < t1)


# --------------------------------------------------------------------------------------------------
# Paper 000: IPMSM, adaptive observer with HF injection (kind "ipmsm-adaptive")
# --------------------------------------------------------------------------------------------------
def scaled_setup(setup: Any, sc: Scenario) -> Any:
    """The runtime observer set-up with the scenario's injection switch and parameter errors."""
    params = dict(setup.params)
    params["injection"] = 1.0 if sc.injection else 0.0
    for k in ("R_s", "L_d", "L_q", "psi_pm"):
        params[k] = params[k] * sc.estimate_scale.get(k, 1.0)
    disc = sc.discretization or setup.discretization
    return dataclasses.replace(setup, params=params, discretization=disc)


def _ipmsm_initial(
    drive: Any, sc: Scenario, est: PmsmParams, obs: Any, p_obs: np.ndarray, q: dict
) -> np.ndarray:
    """Loop state at t = 0: the drive in steady state at (w_m0, T_L(0)), controllers settled.

    The observer starts at its rest state with the flux, speed and angle of that steady state (angle
    offset by the scenario's initial estimation error).
    """
    from sensorless.design.operating_point import mtpa_function

    m = drive.motor
    motor = PmsmParams(*m.vector())
    w0, th0 = sc.w_m0, sc.theta_m0
    B = q["B"]
    T0 = float(sc.load_torque.sample(np.array([0.0]))[0]) + B * w0 / m.p
    if sc.mode == "torque":
        T0 = float(sc.torque_reference.sample(np.array([0.0]))[0])
    i0 = np.asarray(mtpa_function()(T0, m.vector(), m.p)).ravel()
    psi0 = np.asarray(flux_from_current(ca.DM(i0), motor)).ravel()
    Jm = np.array([[0.0, -1.0], [1.0, 0.0]])
    u_r = m.R_s * i0 + w0 * Jm @ psi0  # eq. (1) at rest in the rotor frame, (29)
    c, s = math.cos(th0), math.sin(th0)
    Rot = np.array([[c, -s], [s, c]])
    psi_hat_c = np.array([est.L_d * i0[0] + est.psi_pm, est.L_q * i0[1]])
    u_i0 = u_r - w0 * Jm @ psi_hat_c  # PI at rest: its output minus the decoupling term
    k_p, _ = speed_gains(q["alpha_s"], q["J_hat"], m.p)
    x_s0 = T0 + float(k_p) * w0 if sc.mode == "speed" else 0.0
    z = {s_.name: 0.0 for s_ in LOOP_STATE}
    z.update(psi_d=psi0[0], psi_q=psi0[1], theta_m=th0, w_m=w0, x_s=x_s0, w_f=w0)
    z["u_a"], z["u_b"] = Rot @ u_r
    z["u_i_d"], z["u_i_q"] = u_i0
    x_obs = np.asarray(obs.initial_state()(p_obs)).ravel()
    P = {f.name: p_obs[k] for k, f in enumerate(obs.params)}
    psi_hat = np.array([P["L_d"] * i0[0] + P["psi_pm"], P["L_q"] * i0[1]])
    for name, val in (
        ("psi_d", psi_hat[0]),
        ("psi_q", psi_hat[1]),
        ("w_i", w0),
        ("w_hat", w0),
        ("theta", math.remainder(th0 - sc.theta_err0, 2 * math.pi)),
    ):
        x_obs[obs.index("state", name)] = val
    return np.concatenate([[z[s_.name] for s_ in LOOP_STATE], x_obs])


def _sample_inputs(sc: Scenario, n: int, T_s: float) -> np.ndarray:
    t = np.arange(n) * T_s
    v = np.zeros((len(INPUTS), n))
    v[0] = sc.speed_reference.sample(t)
    v[1] = sc.load_torque.sample(t)
    v[2] = sc.torque_reference.sample(t)
    if sc.i_noise > 0:
        rng = np.random.default_rng(sc.seed)
        v[3:5] = sc.i_noise * rng.standard_normal((2, n))
    return v


def _provenance(drive: Any, sc: Scenario) -> dict[str, Any]:
    """What a run describes: the drive (and its TOML hash) and the scenario; shared by every kind."""
    return {
        "drive": drive.name,
        "drive_file": drive.file,
        "drive_sha256": drive.digest,
        "kind": drive.kind,
        "scenario": sc.name,
        "scenario_title": sc.title,
        "scenario_source": sc.source,
    }


def build_ipmsm(drive: Any, sc: Scenario, table: GainTable | None, table_file: str) -> LoopSetup:
    """Loop set-up of the paper-000 drive (Fig. 7) for scenario ``sc``."""
    from sensorless.design.runtime import runtime_setup

    setup = runtime_setup(drive, gain=sc.gain, table=table, table_file=table_file)
    setup = scaled_setup(setup, sc)
    setup.observer.check_params(setup.params)
    obs = setup.observer
    step = setup.step_function()
    loop = loop_function(step, tuple(f.name for f in obs.outputs))
    m, e, c = drive.motor, drive.estimate, drive.control
    k = sc.estimate_scale
    est = PmsmParams(e.R_s * k["R_s"], e.L_d * k["L_d"], e.L_q * k["L_q"], e.psi_pm * k["psi_pm"])
    q = {
        "R_s": m.R_s,
        "L_d": m.L_d,
        "L_q": m.L_q,
        "psi_pm": m.psi_pm,
        "p": float(m.p),
        "J": m.J,
        "B": sc.viscous,
        "R_s_hat": est.R_s,
        "L_d_hat": est.L_d,
        "L_q_hat": est.L_q,
        "psi_pm_hat": est.psi_pm,
        "J_hat": m.J * k["J"],
        "alpha_c": sc.current_bandwidth or c.alpha_c,
        "alpha_s": c.alpha_s,
        "T_max": c.T_max,
        "u_max": c.u_dc / math.sqrt(3),
        "T_s": c.T_s,
        "sensor": 1.0 if sc.feedback == "sensor" else 0.0,
        "speed_mode": 1.0 if sc.mode == "speed" else 0.0,
        "stiff": 1.0 if sc.stiff_load else 0.0,
        "alpha_w": sc.speed_filter,
        "notch": 1.0 if sc.injection else 0.0,
        "w_n": drive.injection.w_c,
        "B_n": drive.runtime.w_bp,
    }
    qv = np.array([q[s.name] for s in PARAMS])
    p_obs = setup.p
    n = round(sc.duration / c.T_s) + 1
    obs_record = tuple(Signal(f.name, f.unit, f.doc) for f in observer_record(obs.outputs))
    meta = {
        **_provenance(drive, sc),
        "gain": setup.gain_source,
        "gain_law": setup.law.name,
        "discretization": setup.discretization,
        "injection": sc.injection,
        "feedback": sc.feedback,
        "T_s": c.T_s,
        "base_w": drive.base.w,
        "T_N": drive.T_N,
        "pole_pairs": m.p,
        "speed_unit": "p.u.",
        "speed_scale": 1 / drive.base.w,  # rad/s (electrical) -> speed_unit
    }
    return LoopSetup(
        loop=loop,
        q=qv,
        p_obs=p_obs,
        gain=np.asarray(setup.gain, float),
        z0=_ipmsm_initial(drive, sc, est, obs, p_obs, q),
        inputs=_sample_inputs(sc, n, c.T_s),
        record=RECORD + obs_record,
        T_s=c.T_s,
        meta=meta,
    )


# --------------------------------------------------------------------------------------------------
# Paper 002: PMAC motor, reduced-order EMF/load-torque observer (kind "pmac-reduced-order")
# --------------------------------------------------------------------------------------------------
PMAC_ALPHA_C = 2 * math.pi * 400  # [rad/s] the paper's "fast current control loop", not specified


def _pmac_gains(drive: Any, table: GainTable | None, table_file: str) -> tuple[float, float, str]:
    """(g, Gamma, source) from a 'deangelo' gain table or the drive's [observer]."""
    from sensorless.tuning.gain_table import GainTableError

    if table is None:
        return drive.observer.g, drive.observer.Gamma, f"{drive.file} [observer]"
    if table.family != "deangelo":
        raise GainTableError(
            f"{table_file}: key 'family': {table.family!r} gains are not for the paper-002 observer "
            "(use a deangelo table)"
        )
    try:
        g, Gamma = float(table.gains["g"]), float(table.gains["Gamma"])
    except (TypeError, ValueError) as e:
        raise GainTableError(f"{table_file}: key 'gains': {e}") from None
    if not (g > 0 and Gamma >= 0):
        raise GainTableError(f"{table_file}: key 'gains': need g > 0 and Gamma >= 0")
    return g, Gamma, f"deangelo table {table_file} (tuned for {table.drive.get('name')})"


def build_pmac(drive: Any, sc: Scenario, table: GainTable | None, table_file: str) -> LoopSetup:
    """Loop set-up of the paper-002 drive (Fig. 1) for scenario ``sc``."""
    from sensorless.symbolic import drive002
    from sensorless.symbolic.pmac import EmfSeries, flux_derivative, ripple_free_current
    from sensorless.symbolic.reduced_order_observer import ObserverParams, zeta_tau
    from sensorless.symbolic.reduced_order_step import observer_step_function

    m, e, c = drive.motor, drive.estimate, drive.control
    if tuple(m.harmonics) != tuple(e.harmonics):
        raise DriveFileError(
            drive.file, "estimate.harmonics", "simulation needs the same harmonic orders as [motor]"
        )
    orders = tuple(int(n) for n in m.harmonics)
    disc = sc.discretization or c.discretization
    step = observer_step_function(disc, orders)
    loop = drive002.loop_function(step, orders)
    k = sc.estimate_scale
    g, Gamma, source = _pmac_gains(drive, table, table_file)
    if not sc.load_torque_estimation:
        Gamma = 0.0  # the observer of [11]: no load-torque state (tau stays 0, so T_L_hat = 0)
    R_hat, L_hat, J_hat = e.R * k["R_s"], e.L * k["L_d"], e.J * k["J"]
    Phi_hat = np.asarray(e.Phi, float) * k["Phi"]
    p_obs = np.array([R_hat, L_hat, J_hat, m.p_r, g, Gamma, c.T_s, *Phi_hat])
    gain = np.asarray(drive.speed_params(feedforward=sc.feedforward), float)
    B = m.B + sc.viscous
    w_max = drive.w_base
    u_max = 2 * float(np.sum(np.abs(m.Phi))) * w_max / m.p_r  # ideal inverter: twice the EMF at n_N
    qd = {
        "R": m.R,
        "L": m.L,
        "J": m.J,
        "B": B,
        "p_r": m.p_r,
        "R_hat": R_hat,
        "L_hat": L_hat,
        "alpha_c": sc.current_bandwidth or PMAC_ALPHA_C,
        "u_max": u_max,
        "T_s": c.T_s,
        "sensor": 1.0 if sc.feedback == "sensor" else 0.0,
        "alpha_w": sc.speed_filter,
    }
    q = np.array([*(qd[s.name] for s in drive002.PARAMS), *m.Phi, *Phi_hat])

    # initial state: steady state at (w_m0, T_L(0)), observer converged
    w0, th0 = sc.w_m0, sc.theta_m0
    T_L0 = float(sc.load_torque.sample(np.array([0.0]))[0])
    T0 = T_L0 + B * w0 / m.p_r
    emf_t = EmfSeries(orders, ca.DM(m.Phi))
    emf_h = EmfSeries(orders, ca.DM(Phi_hat))
    phi0 = flux_derivative(th0, emf_t)
    i0 = np.asarray(ripple_free_current(T0, phi0)).ravel()
    e0 = np.asarray(phi0 * (w0 / m.p_r)).ravel()
    u0 = m.R * i0 + e0
    th_hat0 = math.remainder(th0 - sc.theta_err0, 2 * math.pi)
    phi_hat0 = flux_derivative(th_hat0, emf_h)
    T_L_hat0 = T0 if Gamma > 0 else 0.0
    op = ObserverParams(R_hat, L_hat, J_hat, m.p_r, g, Gamma)
    zeta0, tau0 = zeta_tau(phi_hat0 * (w0 / m.p_r), T_L_hat0, phi_hat0, ca.DM(i0), op)
    x_obs0 = np.array([*np.asarray(zeta0).ravel(), float(tau0), th_hat0, w0, *i0, *u0])
    Rc = np.array([[math.cos(th0), math.sin(th0)], [-math.sin(th0), math.cos(th0)]])
    z0 = {
        "i_a": i0[0],
        "i_b": i0[1],
        "theta_m": th0,
        "w_m": w0,
        "u_a": u0[0],
        "u_b": u0[1],
        "x_s": T0 - (T_L_hat0 if sc.feedforward else 0.0),
        "w_f": w0,
        "u_a_last": u0[0],
        "u_b_last": u0[1],
    }
    z0["u_i_d"], z0["u_i_q"] = Rc @ (R_hat * i0)
    z = np.array([*(z0.get(s.name, 0.0) for s in drive002.LOOP_STATE), *x_obs0])

    n = round(sc.duration / c.T_s) + 1
    t = np.arange(n) * c.T_s
    v = np.zeros((len(drive002.INPUTS), n))
    v[0] = sc.speed_reference.sample(t)
    v[1] = sc.load_torque.sample(t)
    if sc.i_noise > 0:
        v[2:4] = sc.i_noise * np.random.default_rng(sc.seed).standard_normal((2, n))
    rpm = np.pi / 30 * m.p  # electrical rad/s per r/min
    meta = {
        **_provenance(drive, sc),
        "gain": f"{source}: g = {g:g} 1/s, Gamma = {Gamma:g}"
        + ("" if sc.load_torque_estimation else " (load-torque estimation off)"),
        "gain_law": "deangelo",
        "discretization": disc,
        "injection": False,
        "feedback": sc.feedback,
        "feedforward": sc.feedforward,
        "T_s": c.T_s,
        "base_w": drive.w_base,
        "T_N": drive.T_N,
        "pole_pairs": m.p,
        "speed_unit": "r/min",
        "speed_scale": 1 / rpm,
    }
    return LoopSetup(
        loop=loop,
        q=q,
        p_obs=p_obs,
        gain=gain,
        z0=z,
        inputs=v,
        record=drive002.RECORD,
        T_s=c.T_s,
        meta=meta,
    )


# kind -> builder(drive, scenario, gain table or None, table file name) -> LoopSetup
BUILDERS: dict[str, Callable[[Any, Scenario, GainTable | None, str], LoopSetup]] = {
    "ipmsm-adaptive": build_ipmsm,
    "pmac-reduced-order": build_pmac,
}


# --------------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------------
@functools.cache
def chunk_function(loop: ca.Function, n: int) -> ca.Function:
    """``n`` loop steps as one Function (z, V, q, p_obs, gain) -> (z after n steps, rec (n_rec, n))."""
    F = loop.mapaccum(n)
    args = [ca.MX.sym(loop.name_in(k), loop.sparsity_in(k)) for k in range(loop.n_in())]
    V = ca.MX.sym("V", loop.size1_in(1), n)
    zs, rec = F(args[0], V, *args[2:])  # constant inputs broadcast over the n steps
    return ca.Function(
        f"{loop.name()}_x{n}",
        [args[0], V, *args[2:]],
        [zs[:, n - 1], rec],
        ["z", "V", "q", "p_obs", "gain"],
        ["z_end", "rec"],
    )


@functools.cache
def compiled_chunk(loop: ca.Function, n: int) -> ca.Function:
    """:func:`chunk_function`, compiled to native code (cached on disk)."""
    return compiled(chunk_function(loop, n))


def run_loop(
    setup: LoopSetup,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = CHUNK,
    compile: bool = True,
) -> np.ndarray:
    """Run the loop over all input columns; returns rec as (n_rec, N). ``progress(done, total)``."""
    n = setup.inputs.shape[1]
    fn = compiled_chunk(setup.loop, chunk) if compile else chunk_function(setup.loop, chunk)
    n_rec = setup.loop.size1_out(1)
    out = np.empty((n_rec, n))
    z = np.asarray(setup.z0, float)
    const = [setup.q, setup.p_obs, setup.gain]
    for k0 in range(0, n, chunk):
        k1 = min(k0 + chunk, n)
        V = setup.inputs[:, k0:k1]
        if k1 - k0 < chunk:  # pad the last chunk by holding its last inputs; the excess is dropped
            V = np.hstack([V, np.repeat(V[:, -1:], chunk - (k1 - k0), axis=1)])
        z_end, rec = fn(z, V, *const)
        out[:, k0:k1] = np.asarray(rec)[:, : k1 - k0]
        z = np.asarray(z_end).ravel()
        if progress is not None:
            progress(k1, n)
    return out


def simulate(
    drive: Any,
    scenario: Scenario,
    table: GainTable | None = None,
    table_file: str = "gain table",
    progress: Callable[[int, int], None] | None = None,
    compile: bool = True,
) -> Traces:
    """Simulate ``scenario`` on ``drive`` (gains from ``table`` if given); returns the traces."""
    if drive.kind not in BUILDERS:
        raise ValueError(
            f"{drive.file}: no simulation for drive kind {drive.kind!r} (have: {', '.join(BUILDERS)})"
        )
    setup = BUILDERS[drive.kind](drive, scenario, table, table_file)
    if compile:
        compiled_chunk(setup.loop, CHUNK)  # build and compile (or load from the cache) outside the timing
    t0 = time.perf_counter()
    rec = run_loop(setup, progress, compile=compile)
    wall = time.perf_counter() - t0
    t = np.arange(rec.shape[1]) * setup.T_s
    data = {s.name: rec[k] for k, s in enumerate(setup.record)}
    return Traces(
        t=t,
        data=data,
        units={s.name: s.unit for s in setup.record},
        docs={s.name: s.doc for s in setup.record},
        meta={**setup.meta, "samples": rec.shape[1]},
        wall_time=wall,
    )
