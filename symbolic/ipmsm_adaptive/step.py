"""Runtime step of the speed-adaptive observer: what simulation runs and ``codegen`` emits as C.

One sampling period of the speed-adaptive flux observer of Piippo, Hinkkanen, Luomi (2008), eqs.
(4)-(10), with the HF-injection correction (17)-(22), built in SX from the continuous-time definitions
in observer.py, gains.py and injection.py (nothing re-typed here). The interface, every timing
convention and the discretizations are in docs/families/ipmsm_adaptive.md; in short, at sample k
(time t_k):

- ``meas`` = [i_alpha, i_beta] sampled at t_k and [u_alpha, u_beta], the stator voltage applied during
  [t_k, t_k + T_s] (with a one-sample computation delay: the reference computed at step k-1, carrier
  included), all in the stationary frame. The step transforms them with its own angle estimate.
- outputs: the estimates at t_k (w_hat, theta_hat, psi_hat), the carrier voltage to add on the
  estimated d axis of the next voltage reference, the error signal eps (18), omega_eps (21), the gains.
- the state advances to t_k + T_s. The gain (7) is scheduled at the previous sample's speed estimate
  (state ``w_hat``) and held over the period, like the inputs; the HF chain and the integral of (21)
  are sampled-data by nature (forward Euler for the integral).

Discretizations (``DISCRETIZATIONS``, the first is the default), compared by the discrete-time analysis
of design/ipmsm_adaptive/one_step.py:

- ``zoh``: every input held over the period as the drive holds it. The voltage is constant in the
  stationary frame (the inverter's zero-order hold) and is integrated exactly there; the rotation of
  the estimated frame is exact; the current error of t_k is held (the current of t_k+1 is not known
  yet); the resistive drop and the corrections of (20) by the trapezoidal rule. No voltage
  feedthrough to w_hat, no steady angle lag.
- ``heun``: Heun's method (explicit trapezoidal RK2) in the estimated frame, the measured current of t_k
  held in both stages. Its second stage compares the flux predicted at t_k+1 with the current of t_k,
  so a voltage step moves w_hat by k_p T_s / 2 per volt before the current has answered.
- ``euler``: forward Euler with every input at t_k; the voltage is taken at the angle of t_k, which
  lags the period's mean by w T_s / 2: a steady angle error of about that much.
- ``heun-model``: Heun with the current at t_k+1 predicted by the observer's model from the measured
  one: no feedthrough, but the rotating frame's trapezoidal rule leaves a steady angle error growing
  as (w T_s)^2.
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.frames import Sym, rot, wrap_angle
from sensorless.symbolic.ipmsm_adaptive.gains import LAWS, GainLaw, get_law
from sensorless.symbolic.ipmsm_adaptive.injection import (
    fade,
    faded_pi_gains,
    hf_chain_step,
    injection_gain,
    injection_pi,
)
from sensorless.symbolic.ipmsm_adaptive.observer import ObserverRates, observer_rates, speed_adaptation
from sensorless.symbolic.pmsm import PmsmParams, current_from_flux, flux_from_current
from sensorless.symbolic.pmsm_drive import MEAS_FIELDS
from sensorless.symbolic.runtime import REJECTS, RESET, VALID, Field, RuntimeObserver, core_function, guarded

NAME = "ipmsm_adaptive"
DISCRETIZATIONS = ("zoh", "heun", "euler", "heun-model")  # the first is the default (module docstring)

# bounds (docs/families/ipmsm_adaptive.md, "Bounds and recovery"): the flux within 4 psi_pm (the PM
# flux plus a current of 3 psi_pm / L), the speeds within twice the drive's highest speed and within the
# sampling limit |w| T_s <= pi/2, the angles wrapped; the filter states only finite
_W_BOUND = "min(2 * w_max, pi / (2 * T_s))"
STATE = (
    Field("psi_d", "V s", "stator-flux estimate psi_hat, estimated d axis, eq. (4)/(20)", bound="4 * psi_pm"),
    Field("psi_q", "V s", "stator-flux estimate psi_hat, estimated q axis", bound="4 * psi_pm"),
    Field("w_i", "rad/s", "integral part of the speed adaptation (9)", bound=_W_BOUND),
    Field("theta", "rad", "rotor-position estimate theta_hat (electrical), in (-pi, pi]", bound="pi"),
    Field("w_hat", "rad/s", "latest speed estimate (output w_hat): schedules the gain (7)", bound=_W_BOUND),
    Field("phi_c", "rad", "carrier phase w_c t, in (-pi, pi]", bound="pi"),
    Field("bp_z1", "A", "band-pass filter state (transposed direct form II)"),
    Field("bp_z2", "A", "band-pass filter state"),
    Field("lp_z1", "A", "low-pass filter state (transposed direct form II)"),
    Field("lp_z2", "A", "low-pass filter state"),
    Field("x_eps", "rad/s", "integral part of the PI (21), bounded to +-x_eps_max", bound="x_eps_max"),
    REJECTS,
)

MEAS = MEAS_FIELDS  # what the shared PMSM drive loop feeds the step (symbolic/pmsm_drive.py)

PARAMS = (
    Field("R_s", "ohm", "stator resistance estimate", "positive"),
    Field("L_d", "H", "d-axis inductance estimate", "positive"),
    Field("L_q", "H", "q-axis inductance estimate", "positive"),
    Field("psi_pm", "V s", "PM flux estimate", "positive"),
    Field("alpha_fo", "rad/s", "speed-adaptation bandwidth, eq. (10)", "positive"),
    Field("T_s", "s", "sampling period", "positive"),
    Field("injection", "1", "HF injection on (1) or off (0)", "flag"),
    Field("w_c", "rad/s", "carrier angular frequency, eq. (17)", "positive"),
    Field("u_c", "V", "carrier amplitude at zero speed, eq. (17) (0 with injection off)", "nonnegative"),
    Field("alpha_i", "rad/s", "PI (21) bandwidth at zero speed, eq. (22)", "positive"),
    Field("w_Delta", "rad/s", "speed where the injection has faded to zero (Section V)", "positive"),
    Field("x_eps_max", "rad/s", "bound on the integral part of (21)", "nonnegative"),
    Field("w_bp", "rad/s", "band-pass -3 dB bandwidth (centre w_c)", "positive"),
    Field("w_lp", "rad/s", "low-pass (Butterworth) cut-off", "positive"),
    Field("carrier_delay", "samples", "delay from carrier command to applied voltage", "nonnegative"),
    Field("w_max", "rad/s", "highest speed of the drive (electrical): the speed states' bounds", "positive"),
)

OUTPUTS = (
    Field("w_hat", "rad/s", "speed estimate (9): the rate theta_hat advances at over this period"),
    Field("theta_hat", "rad", "position estimate at t_k (electrical), in (-pi, pi]"),
    Field("psi_hat_d", "V s", "stator-flux estimate at t_k, estimated d axis"),
    Field("psi_hat_q", "V s", "stator-flux estimate at t_k, estimated q axis"),
    Field("u_c_d", "V", "carrier voltage to add to the estimated-d-axis voltage reference, eq. (17)"),
    Field("eps", "A", "demodulated error signal, eq. (18) (0 where the injection is off)"),
    Field("w_eps", "rad/s", "correction speed omega_eps of (20), (21)"),
    Field("lambda1", "ohm", "observer gain lambda1 applied this period, eq. (7)"),
    Field("lambda2", "ohm", "observer gain lambda2 applied this period, eq. (7)"),
    Field("fade", "1", "injection fade factor (1 at zero speed, 0 beyond w_Delta)"),
    VALID,
    RESET,
)

LAM = (
    Field("lambda1", "ohm", "gain lambda1 of eq. (7), scheduled at state w_hat"),
    Field("lambda2", "ohm", "gain lambda2 of eq. (7), scheduled at state w_hat"),
)

_IX = {f.name: k for k, f in enumerate(STATE)}
_HELD = LAWS["constant"]  # lambda1, lambda2 given as numbers: the scheduled gains, held over a period


def _step(discretization: str, x: Sym, meas: Sym, p: Sym, lam: Sym) -> tuple[Sym, Sym]:
    """(x_next, y) of one sampling period; see the module docstring."""
    P = {f.name: p[k] for k, f in enumerate(PARAMS)}
    X = {f.name: x[k] for k, f in enumerate(STATE)}
    est = PmsmParams(P["R_s"], P["L_d"], P["L_q"], P["psi_pm"])
    T_s = P["T_s"]
    psi, theta = x[0:2], X["theta"]
    i_ab, u_ab = meas[0:2], meas[2:4]

    T = rot(theta)
    i_s = T.T @ i_ab  # measured current in the estimated rotor frame, eq. (24) with theta_hat
    u_s = T.T @ u_ab
    w_hat = speed_adaptation(psi, X["w_i"], i_s, est, P["alpha_fo"]).w_hat  # eq. (9)

    # HF injection, Section V: carrier (17), error signal (18), PI (21)-(22), fading to w_Delta
    f = P["injection"] * fade(w_hat, P["w_Delta"])
    hf = hf_chain_step(
        i_s[1],
        X["phi_c"],
        x[6:8],
        x[8:10],
        f * P["u_c"],
        P["w_c"],
        T_s,
        P["w_bp"],
        P["w_lp"],
        P["carrier_delay"],
    )
    K_eps_hat = injection_gain(P["u_c"], P["w_c"], est)  # eq. (19) from the estimates
    # off: any finite K keeps the (unused) gains finite, also for a non-salient motor
    K_eps_hat = ca.if_else(P["injection"] > 0, K_eps_hat, 1)
    gamma_p, gamma_i = faded_pi_gains(f, P["alpha_i"], K_eps_hat)  # eq. (22)
    eps = ca.if_else(f > 0, hf.eps, 0)  # no carrier, no signal: leakage must not steer the observer
    pi = injection_pi(eps, X["x_eps"], gamma_p, gamma_i)  # eq. (21)
    x_eps_next = ca.fmin(ca.fmax(X["x_eps"] + T_s * pi.dx_eps, -P["x_eps_max"]), P["x_eps_max"])

    def rates(psi_: Sym, w_i_: Sym, u_: Sym, i_: Sym = i_s, w_hat_: Sym | None = None) -> ObserverRates:
        # (4) with the correction of (20)
        return observer_rates(psi_, w_i_, u_, i_, est, P["alpha_fo"], _HELD, lam, pi.w_eps, w_hat_)

    if discretization == "zoh":
        # Each input is held over the period as the drive holds it: the voltage in the stationary frame
        # (the inverter), the current error of t_k in the estimated frame (the next current is not
        # known yet, so nothing of the voltage applied now reaches w_hat now).
        a = speed_adaptation(psi, X["w_i"], i_s, est, P["alpha_fo"])  # (5), (6), (8), (9) at t_k
        w_i_next = X["w_i"] + T_s * a.dw_i  # integral of (9) with F_eps held: exact
        w_step = a.w_hat + T_s / 2 * a.dw_i  # mean of (9) over the period: theta_hat advances exactly
        back = rot(T_s * w_step).T  # the estimated frame of t_k seen from that of t_k+1

        def g(psi_: Sym) -> Sym:
            """(20) without the voltage and without the frame's rotation: -R_s i_hat + lambda i_tilde
            + w_eps J psi_hat, the current error held. (w_hat imposed 0: the rotation is exact, below.)"""
            i_ = current_from_flux(psi_, est) + a.i_tilde
            return rates(psi_, X["w_i"], ca.DM.zeros(2), i_, 0).dpsi_hat

        # (20) in the stationary frame is d psi/dt = u + T(theta_hat) g: the held voltage integrates
        # exactly, the rotation of the estimated frame is exact, g by the trapezoidal rule (Heun)
        g0 = g(psi)
        psi_p = back @ (psi + T_s * (u_s + g0))  # predictor, in the frame of t_k+1
        psi_next = back @ (psi + T_s * (u_s + g0 / 2)) + T_s / 2 * g(psi_p)
    elif discretization == "euler":
        r0 = rates(psi, X["w_i"], u_s)
        psi_next = psi + T_s * r0.dpsi_hat
        w_i_next = X["w_i"] + T_s * r0.dw_i
        w_step = r0.w_hat
    elif discretization in ("heun", "heun-model"):
        r0 = rates(psi, X["w_i"], u_s)
        # predictor; the voltage is held in the stationary frame (as the inverter holds it)
        theta_p = theta + T_s * r0.w_hat
        if discretization == "heun":
            i_p = i_s  # the current of t_k held in the estimated frame: against the predicted flux,
            # the voltage applied now reaches w_hat now (k_p T_s / 2 per volt)
        else:
            # the current at t_k+1 predicted by the observer model (2), (4) from the measured one:
            # the voltage enters it as it enters the predicted flux, and cancels in the current error
            psi_m = flux_from_current(i_s, est)
            i_p = current_from_flux(psi_m + T_s * rates(psi_m, X["w_i"], u_s, i_s, r0.w_hat).dpsi_hat, est)
        r1 = rates(psi + T_s * r0.dpsi_hat, X["w_i"] + T_s * r0.dw_i, rot(theta_p).T @ u_ab, i_p)
        psi_next = psi + T_s / 2 * (r0.dpsi_hat + r1.dpsi_hat)
        w_i_next = X["w_i"] + T_s / 2 * (r0.dw_i + r1.dw_i)
        w_step = (r0.w_hat + r1.w_hat) / 2
    else:
        raise ValueError(f"unknown discretization {discretization!r} (known: {', '.join(DISCRETIZATIONS)})")

    x_cand = ca.vertcat(
        psi_next,
        w_i_next,
        wrap_angle(theta + T_s * w_step),  # theta_hat integrates w_hat (Section III)
        w_step,
        wrap_angle(X["phi_c"] + P["w_c"] * T_s),
        hf.z_bp_next,
        hf.z_lp_next,
        x_eps_next,
    )
    y_cand = ca.vertcat(w_step, theta, psi, hf.u_c_d, eps, pi.w_eps, lam[0], lam[1], f)
    # invalid sample: coast. The angle and the carrier phase advance at the latest speed estimate, the
    # rest is held (the flux in the estimated frame is constant in steady state); no carrier.
    x_coast = ca.vertcat(
        x[0:3],
        wrap_angle(theta + T_s * X["w_hat"]),
        x[4],
        wrap_angle(X["phi_c"] + P["w_c"] * T_s),
        x[6:11],
    )
    y_coast = ca.vertcat(X["w_hat"], theta, psi, 0, 0, X["x_eps"], lam[0], lam[1], 0)
    # rejected (not finite, beyond the bounds): coast; too many rejected (REJECTS): start afresh
    cand, coast, x0 = (x_cand, y_cand), (x_coast, y_coast), initial_state_function()(p)
    return guarded(x, p, STATE, PARAMS, cand=cand, coast=coast, reset=x0)


def _symbols() -> dict[str, ca.SX]:
    return {
        "x": ca.SX.sym("x", len(STATE)),
        "meas": ca.SX.sym("meas", len(MEAS)),
        "p": ca.SX.sym("p", len(PARAMS)),
    }


@functools.cache
def observer_step_core(discretization: str = DISCRETIZATIONS[0]) -> ca.Function:
    """Step with the scheduled gains as an input: (x, meas, p, lam) -> (x_next, y).

    This is what the C generator emits; the gain schedule becomes a C function of its own that the
    generated ``*_step`` calls with the state ``w_hat``.
    """
    step = functools.partial(_step, discretization)
    return core_function(f"{NAME}_core_{discretization.replace('-', '_')}", step, STATE, MEAS, PARAMS, LAM)


@functools.cache
def observer_step_function(
    discretization: str = DISCRETIZATIONS[0], law: str | GainLaw = "speed"
) -> ca.Function:
    """One sampling period of the adaptive observer: (x, meas, p, gain) -> (x_next, y).

    ``law`` is a gain law of gains.py (``zero``, ``constant``, ``speed`` = eq. (16), or a
    ``schedule_law(grid)``); ``gain`` its parameter vector (``law.param_names``). Vector layouts are
    ``STATE``, ``MEAS``, ``PARAMS``, ``OUTPUTS`` of this module.
    Suited to ``mapaccum`` (the state is the first input and the first output).
    """
    law = get_law(law)
    s = _symbols()
    gain = ca.SX.sym("gain", law.n_params)
    lam = ca.vertcat(*law.expr(s["x"][_IX["w_hat"]], gain))  # eq. (7)/(16) at the stored estimate
    x_next, y = observer_step_core(discretization)(s["x"], s["meas"], s["p"], lam)
    return ca.Function(
        f"{NAME}_step_{discretization.replace('-', '_')}_{law.name}",
        [s["x"], s["meas"], s["p"], gain],
        [x_next, y],
        ["x", "meas", "p", "gain"],
        ["x_next", "y"],
    )


@functools.cache
def initial_state_function() -> ca.Function:
    """x0(p): the observer at rest at theta_hat = 0: psi_hat = [psi_pm_hat, 0], everything else 0."""
    p = ca.SX.sym("p", len(PARAMS))
    x0 = ca.SX.zeros(len(STATE))
    x0[_IX["psi_d"]] = p[[f.name for f in PARAMS].index("psi_pm")]
    return ca.Function(f"{NAME}_init", [p], [x0], ["p"], ["x0"])


@functools.cache
def steady_state_function() -> ca.Function:
    """x(p, op): converged at the operating point op = [theta_hat, w, i_d, i_q] of a PMSM drive loop.

    The flux estimate is the estimated-parameter flux (2) of the current, the adaptation's integral and
    the stored speed estimate are the speed, the injection chain is at rest.
    """
    p = ca.SX.sym("p", len(PARAMS))
    op = ca.SX.sym("op", 4)
    P = {f.name: p[k] for k, f in enumerate(PARAMS)}
    x = initial_state_function()(p)
    est = PmsmParams(P["R_s"], P["L_d"], P["L_q"], P["psi_pm"])
    psi = flux_from_current(op[2:4], est)  # eq. (2) with the estimates
    x[_IX["psi_d"]], x[_IX["psi_q"]] = psi[0], psi[1]
    x[_IX["w_i"]], x[_IX["w_hat"]] = op[1], op[1]
    x[_IX["theta"]] = wrap_angle(op[0])
    return ca.Function(f"{NAME}_steady_state", [p, op], [x], ["p", "op"], ["x"])


OBSERVER = RuntimeObserver(
    name=NAME,
    title="speed-adaptive stator-flux observer with HF injection (Piippo, Hinkkanen, Luomi 2008)",
    state=STATE,
    meas=MEAS,
    params=PARAMS,
    outputs=OUTPUTS,
    lam=LAM,
    schedule_state="w_hat",
    core=observer_step_core,
    initial_state=initial_state_function,
    discretizations=DISCRETIZATIONS,
    steady_state=steady_state_function,
    doc_init="theta_hat = 0, psi_hat = [psi_pm, 0], everything else 0",
    doc_in="current sampled now, voltage applied over the coming period (stationary frame)",
    doc_out="speed and angle estimates now, the carrier voltage for the next reference",
)
