"""Simulation set-up of a sensorless PMSM drive (symbolic/pmsm_drive.py) around any family's runtime observer.

Every family whose observer runs on a PMSM gives its drive the shared sections of
design/pmsm_schema.py (:class:`OnPmsm`: the true motor, the controllers' estimates, the control
settings) and gets the whole loop set-up for a scenario from :func:`loop_setup`: the loop Function
around its runtime step, the parameter vector, the state at rest at the scenario's initial operating
point (from the SX Functions of the loop and of the observer, nothing re-typed) and the per-sample
inputs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from sensorless.design.capabilities import Linearizable, OpenLoopStart, Scaled, require
from sensorless.design.family import CapabilityError, Drive, GainSet, Panel, TraceLine
from sensorless.design.memo import kept_function
from sensorless.design.motor_data import mtpa_torque_current
from sensorless.design.pmsm_schema import PmsmControl, PmsmEstimate, PmsmMotor
from sensorless.design.registry import family_of
from sensorless.design.runtime import RuntimeSetup, step_variant
from sensorless.design.scenario import Scenario, speed_filter_of
from sensorless.design.simulate import (
    LoopCoordinates,
    LoopSetup,
    StateFrames,
    noise,
    provenance,
    sample_times,
)
from sensorless.design.speed_ramp import drive_ramp
from sensorless.design.units import DriveFileError
from sensorless.symbolic.pmsm_drive import (
    INPUTS,
    LOOP_STATE,
    MEAS,
    PARAMS,
    RECORD,
    initial_loop_state_function,
    loop_function,
    observer_record,
)
from sensorless.symbolic.speed_ramp import W_RAMP
from sensorless.symbolic.startup import W_CMD

# the loop around an observer step, built once per step and kept for later processes (design/memo.py)
_loop_function = kept_function(loop_function)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.family import GainSet
    from sensorless.design.low_speed import LowSpeed, SpeedOptions
    from sensorless.symbolic.runtime import RuntimeObserver

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


class OnPmsm(Drive, Protocol):
    """What the loop reads of a drive whose observer runs on a PMSM (design/pmsm_schema.py)."""

    @property
    def file(self) -> str: ...

    @property
    def motor(self) -> PmsmMotor:
        """The true motor."""

    @property
    def estimate(self) -> PmsmEstimate:
        """The controllers' (and the observer's) model of it."""

    @property
    def control(self) -> PmsmControl:
        """Sampling, current and speed control, torque limit, DC link."""

    @property
    def T_N(self) -> float: ...

    @property
    def w_base(self) -> float: ...


def _params(
    drive: OnPmsm, sc: Scenario, carrier: tuple[float, float], notch: bool, speed_notch: bool = False
) -> np.ndarray:
    m, e, c = drive.motor, drive.estimate, drive.control
    k = {key: sc.estimate_scale.get(key, 1.0) for key in ESTIMATE_KEYS}
    w_c, band = carrier
    q = {
        "R_s": m.R_s,
        "L_d": m.L_d,
        "L_q": m.L_q,
        "psi_pm": m.psi_pm,
        "p": float(m.p),
        "J": m.J,
        "B": sc.viscous,
        "R_s_hat": e.R_s * k["R_s"],
        "L_d_hat": e.L_d * k["L_d"],
        "L_q_hat": e.L_q * k["L_q"],
        "psi_pm_hat": e.psi_pm * k["psi_pm"],
        "J_hat": m.J * k["J"],
        "alpha_c": sc.current_bandwidth or c.alpha_c,
        "alpha_s": c.alpha_s,
        "T_max": c.T_max,
        "u_max": c.u_dc / math.sqrt(3),
        "T_s": c.T_s,
        "sensor": 1.0 if sc.feedback == "sensor" else 0.0,
        "speed_mode": 1.0 if sc.mode == "speed" else 0.0,
        "stiff": 1.0 if sc.stiff_load else 0.0,
        "alpha_w": speed_filter_of(sc, c.alpha_s),
        "notch": 1.0 if notch and w_c > 0 else 0.0,
        "speed_notch": 1.0 if notch and speed_notch and w_c > 0 else 0.0,
        "w_n": w_c if w_c > 0 else math.pi / c.T_s / 2,  # unused without the notch
        "B_n": band if band > 0 else 1.0,
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


# startup_values per (drive object, gains): a command simulates several scenarios of one drive at one gain
# set (tune's proof: 4 checks x 2 gain sets; report: its checks), and each build of a run with the start
# asked for the same whole-drive w_min (design/low_speed.py) again, 0.3-0.6 s each. Keyed by the drive's
# identity (frozen; the entry holds it, so its id is not reused) and the gains' values; a few entries.
_STARTUP_CACHE: dict[tuple[int, str, tuple], tuple[OnPmsm, tuple[dict[str, float] | None, str, float]]] = {}
_STARTUP_CACHE_SIZE = 8


def _gains_key(gains: GainSet | None) -> tuple:
    """A hashable, exact key of a gain set's law and values (arrays by their bytes)."""
    if gains is None:
        return (None,)
    arrays = {k: np.asarray(v, float) for k, v in gains.values.items()}
    return (gains.law, tuple((k, a.shape, a.tobytes()) for k, a in sorted(arrays.items())))


def startup_values(drive: OnPmsm, gains: GainSet) -> tuple[dict[str, float] | None, str, float]:
    """:func:`compute_startup_values`, remembered per drive object and gains (see _STARTUP_CACHE)."""
    try:
        key = (id(drive), type(drive).__name__, _gains_key(gains))
    except (TypeError, ValueError, AttributeError):  # gains of another shape: no cache
        return compute_startup_values(drive, gains)
    hit = _STARTUP_CACHE.get(key)
    if hit is not None and hit[0] is drive:
        values, line, w_min = hit[1]
        return (None if values is None else dict(values)), line, w_min
    out = compute_startup_values(drive, gains)
    if len(_STARTUP_CACHE) >= _STARTUP_CACHE_SIZE:
        _STARTUP_CACHE.pop(next(iter(_STARTUP_CACHE)))
    _STARTUP_CACHE[key] = (drive, (None if out[0] is None else dict(out[0]), out[1], out[2]))
    return out


def compute_startup_values(drive: OnPmsm, gains: GainSet) -> tuple[dict[str, float] | None, str, float]:
    """The I-f start's parameters of ``drive`` (design/startup.py): its ``[startup]`` section where the
    file gives one, else the rules from the minimum sensorless speed at rated load (design/low_speed.py,
    at ``gains``); None where the observer holds zero speed. With one line saying which, and w_min
    [rad/s] (0 where not analysed). CapabilityError for a drive without a PMSM's data."""
    from sensorless.design.low_speed import QUICK, minimum_speed, required_decay
    from sensorless.design.poles import MIN_DAMPING
    from sensorless.design.startup import CURRENT_SHARE_MAX, ON_FACTOR, handover_reason, if_values

    fam = family_of(drive)
    if fam.holds_zero_speed(drive):
        return None, "no I-f start: the observer holds zero speed (its family: HF injection)", 0.0
    startup = fam.startup(drive) if isinstance(fam, OpenLoopStart) else None
    given = startup.values() if startup is not None else {}
    values, w_min, warn = given, 0.0, ""
    try:
        m, c = drive.motor, drive.control
        inertia, pole_pairs, T_max, _ = m.J, m.p, c.T_max, m.psi_pm  # another motor model: no I-f rules
        i_d, i_q = mtpa_torque_current(T_max, m)
        k_t = T_max / math.hypot(i_d, i_q)  # torque per ampere (peak) at the torque limit, MTPA
    except AttributeError:
        raise CapabilityError(
            f"observer family {fam.name!r}: the I-f start needs a PMSM drive (psi_pm, J, T_max); this "
            "drive's motor model has none (--startup: not for this drive)"
        ) from None
    i_max = CURRENT_SHARE_MAX * math.hypot(i_d, i_q)
    if given.get("if_i", 0.0) > i_max:  # the range of a given current: the motor's own
        raise DriveFileError(
            drive.file,
            "startup.current",
            f"{given['if_i']:.6g} A: at most {CURRENT_SHARE_MAX:g} times the torque limit's current "
            f"T_max/k_t = {math.hypot(i_d, i_q):.4g} A, i.e. {i_max:.4g} A (peak)",
        )
    values = {**given, "if_k_a": inertia / (pole_pairs * k_t)}  # the motor's (design/startup.py)
    if startup is None or not startup.complete:  # a key the file does not give keeps its rule
        # the handover's w_min: the whole drive's criteria with its angle error under the full
        # acceleration a_max against rated load (design/low_speed.py); the handover never above 1 p.u.
        try:
            # the analysis behind the start's values is the design's (double) step, whatever step the
            # run itself is given (design/runtime.py step_variant: e.g. the fixed-point step)
            with step_variant(None):
                opts: SpeedOptions = {**QUICK, "acceleration": True}
                ls = minimum_speed(handover_drive(drive), gains, min_damping=MIN_DAMPING, **opts)
        except CapabilityError:  # no analysis (e.g. no linearization): the speeds must be given
            if startup is None or startup.needs_w_min:
                raise
            require(fam, Scaled)
            sigma = required_decay(drive)
            rules = if_values(drive.T_N, T_max, inertia, pole_pairs, k_t, 0.0, sigma, drive.w_base)
            return (*_startup_line({**rules, **given}, given, drive.w_base, ""), 0.0)
        with step_variant(None):
            sigma = _handover_decay(drive, gains, ls)
        # the rule's handover (ON_FACTOR w_min) capped at 1 p.u. where the file gives no w_on: said why
        capped = ON_FACTOR * ls.w_min_rated >= drive.w_base * (1 - 1e-9) and (
            startup is None or startup.w_on is None
        )
        if capped or ls.w_min_rated >= drive.w_base * (1 - 1e-9) or ls.rated_limited_by == "acceleration":
            warn = "; " + handover_reason(ls, None if startup is None else startup.w_on)
        w_min = ls.w_min_rated
        if w_min <= 0:
            return None, "no I-f start: the design holds zero speed", 0.0
        given = startup.values(w_min) if startup is not None else {}
        values = {
            **if_values(drive.T_N, T_max, inertia, pole_pairs, k_t, w_min, sigma, drive.w_base),
            **given,
        }
        if values["if_w_on"] > drive.w_base and (startup is None or startup.w_on is None):
            # a handover given in w_min never above 1 p.u. (the rules' cap)
            values["if_w_on"] = drive.w_base
            values["if_w_off"] = min(values["if_w_off"], drive.w_base / ON_FACTOR)
        if values["if_w_off"] >= values["if_w_on"]:
            if "if_w_off" in given:
                raise DriveFileError(
                    drive.file, "startup.w_off", "not below startup.w_on (by the keys given and the rules)"
                )
            # a handover given below w_min (e.g. a firmware's open-loop ERPM): kept, as the file says,
            # with the rules' hysteresis ratio below it, and said
            values["if_w_off"] = values["if_w_on"] / ON_FACTOR
            warn += (
                f"; the handover given is below w_min = {w_min / drive.w_base:.3g} p.u.: the observer takes "
                f"over where its criteria do not hold (raise startup.w_on to {ON_FACTOR:g} w_min)"
            )
    return (*_startup_line(values, given, drive.w_base, warn), w_min)


def handover_drive(drive: OnPmsm) -> OnPmsm:
    """``drive`` as the handover's w_min analyses it: without its ``[startup]`` section and its text's
    digest. The analysis runs no I-f start (design/drive_analysis.py ``analysis_scenario``) and the
    section is what its w_min places, so neither changes the result (tests/common/test_startup.py);
    keyed without them (design/memo.py), the analysis ``init`` makes before it writes the section is the
    one ``tune`` proves the drive file's gains with (0.1-0.2 s CPU of the README servo's tune)."""
    fam = family_of(drive)
    bare = fam.with_startup(drive, None) if isinstance(fam, OpenLoopStart) else drive
    # (every family's drive is a frozen dataclass, read here through the Drive Protocol)
    return dataclasses.replace(bare, digest="")  # type: ignore[type-var]


def _handover_decay(drive: OnPmsm, gains: GainSet, ls: LowSpeed) -> float:
    """sigma [1/s]: the decay of the observer's error during the dwell at the handover (2 w_min, at most
    1 p.u., +-T_N), at least the required one. In the dwell the controllers run on the I-f frame, not on
    the estimate, so the observer's error decays as the family's observer-only linearization says (the
    whole drive's slowest mode need not be the observer's); the required decay where it gives none."""
    from sensorless.design.startup import ON_FACTOR

    fam = family_of(drive)
    w_on = min(ON_FACTOR * ls.w_min_rated, drive.w_base)
    if not isinstance(fam, Linearizable):
        return ls.min_decay
    try:  # a drive its family does not linearize (e.g. a firmware variant) refuses it: CapabilityError
        T = np.array([-1.0, 1.0]) * drive.T_N
        lin = fam.linearize(drive, gains, np.full(2, w_on), T, **fam.low_speed_options(drive))
        decay = np.asarray(lin.low_speed_decay(), float)
    except CapabilityError:
        return ls.min_decay
    return float(max(ls.min_decay, np.nanmin(decay))) if np.isfinite(decay).any() else ls.min_decay


def _startup_line(
    values: dict[str, float], given: Mapping[str, float], w_base: float, warn: str
) -> tuple[dict[str, float], str]:
    """(values, the one line that says the start's numbers)."""
    line = (
        f"I-f start{' ([startup] of the drive file)' if given else ''}: "
        f"{values['if_i']:.4g} A, {values['if_acc']:.4g} rad/s^2, handover at "
        f"{values['if_w_on'] / w_base:.3g} p.u., back below "
        f"{values['if_w_off'] / w_base:.3g} p.u.{warn}"
    )
    return values, line


def startup_setup(drive: OnPmsm, setup: RuntimeSetup) -> tuple[RuntimeSetup, str]:
    """``setup`` wrapped in the I-f start (design/startup.py; :func:`startup_values` at the gains of
    ``setup``), and one line saying so; unchanged where the observer holds zero speed."""
    from sensorless.design.startup import with_if_start

    values, line, _ = startup_values(drive, setup.gains)
    return (setup, line) if values is None else (with_if_start(setup, values), line)


def loop_setup(
    drive: OnPmsm,
    sc: Scenario,
    setup: RuntimeSetup,
    meta: dict[str, Any],
    carrier: tuple[float, float] = (0.0, 0.0),
    notch: bool = False,
    frames: StateFrames | None = None,
    speed_notch: bool = False,
) -> LoopSetup:
    """The loop set-up of ``sc`` on a PMSM drive with the runtime observer ``setup``.

    ``carrier``: (frequency, band-stop bandwidth) [rad/s] of the carrier an observer injects (its
    output ``u_c_d``; 0: none); ``notch``: it injects in this run, so the current control must not see
    the carrier; ``speed_notch``: nor the speed loop (a band-stop on its speed feedback too). ``meta``
    adds the family's own lines (gains, injection, ...) to the provenance.
    ``frames``: how the observer's state turns with the rotor (its family's declaration), which gives
    the set-up its rotor coordinates (the whole-drive linearization) where it runs without injection
    and without the I-f start.
    """
    if sc.startup:
        setup, line = startup_setup(drive, setup)
        meta = {**meta, "startup": line}
    ramped = drive_ramp(drive, setup)  # outside the start: the start ramps towards the limited reference
    if ramped is not setup:
        meta = {**meta, "speed_ramp": ramped.notes[-1]}
    setup = ramped
    obs = setup.observer
    meas = tuple(f.name for f in obs.meas)
    if meas not in (MEAS, (*MEAS, W_CMD.name)):
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
    loop = _loop_function(step, tuple(f.name for f in obs.outputs))
    T_s = drive.control.T_s
    q = _params(drive, sc, carrier, notch, speed_notch)
    v = inputs(sc, T_s)
    z_loop, op = initial_loop_state_function()(q, v[:, 0], sc.w_m0, sc.theta_m0)
    op = np.asarray(op).ravel()
    op[0] -= sc.theta_err0  # the estimate starts off by the scenario's angle error
    x_obs = np.asarray(obs.steady_state()(setup.p, op)).ravel()
    coords = None
    if frames is not None and not sc.startup and not notch:
        coords = _coordinates(frames, obs, q, setup.p)
    return LoopSetup(
        loop=loop,
        q=q,
        p_obs=setup.p,
        gain=setup.gain,
        z0=np.concatenate([np.asarray(z_loop).ravel(), x_obs]),
        inputs=v,
        record=RECORD + observer_record(obs.outputs),
        T_s=T_s,
        meta={
            **provenance(drive, sc),
            "gain": setup.gain_source,
            "gain_law": setup.gains.law,
            "discretization": setup.discretization,
            "feedback": sc.feedback,
            "T_s": T_s,
            "base_w": drive.w_base,
            "T_N": drive.T_N,
            "pole_pairs": drive.motor.p,
            "speed_unit": "p.u.",
            "speed_scale": 1 / drive.w_base,  # rad/s (electrical) -> speed_unit
            **meta,
        },
        coordinates=coords,
    )


_Z = {f.name: k for k, f in enumerate(LOOP_STATE)}
_V = {f.name: k for k, f in enumerate(INPUTS)}


def _coordinates(
    frames: StateFrames, obs: RuntimeObserver, q: np.ndarray, p_obs: np.ndarray
) -> LoopCoordinates:
    """The rotor coordinates of this loop (symbolic/pmsm_drive.py: the flux in the true rotor frame, the
    current PI and the notch filters in the controller frame, the applied voltage in the stationary
    frame) with the observer's ``frames`` after it; the notch filters are held (nothing reads them
    without injection)."""
    steady_state = obs.steady_state
    assert steady_state is not None  # loop_setup refuses an observer without one
    n = len(LOOP_STATE)
    names = [f.name for f in obs.state]
    ix = lambda name: n + names.index(name)  # noqa: E731

    def start(v0: np.ndarray, w0: np.ndarray) -> np.ndarray:
        N = w0.size
        z_loop, op = initial_loop_state_function().map(N)(q, v0, w0.reshape(1, -1), 0.0)
        x_obs = steady_state().map(N)(p_obs, op)
        return np.vstack([np.asarray(z_loop), np.asarray(x_obs)])

    return LoopCoordinates(
        theta=_Z["theta_m"],
        speed=_Z["w_m"],
        w_ref=_V["w_ref"],
        load=_V["T_L"],
        angles=tuple(ix(a) for a in frames.angles),
        vectors=((_Z["u_a"], _Z["u_b"]), *((ix(a), ix(b)) for a, b in frames.vectors)),
        held=(
            *(_Z[k] for k in ("nf_d1", "nf_d2", "nf_q1", "nf_q2", "nf_w1", "nf_w2")),
            *(ix(h) for h in frames.held),
            # the speed reference's limiter: at a fixed point it has reached the reference (inside its
            # limit w_ramp_next = w_ref, no dynamics: symbolic/controllers.py ramp_step)
            *(ix(h) for h in (W_RAMP.name,) if h in names),
            n + len(names) - 1,  # the runtime contract's counter: 0 in steady state
        ),
        start=start,
    )
