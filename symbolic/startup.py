"""Open-loop start-up (I-f) and handover, as a wrapper around any family's runtime observer.

Below its minimum sensorless speed an observer cannot be trusted (design/low_speed.py), so drives start
and reverse with a current vector of set amplitude turned at a set speed (I-f start: the rotor follows
the rotating current vector like a synchronous motor's rotor follows its field) and hand over to the
observer above a speed where it is reliable, with hysteresis. :func:`with_startup` composes this with
any :class:`~sensorless.symbolic.runtime.RuntimeObserver` into another one, so that simulation and the
generated C get it through the runtime contract (its parameters in the parameter vector, its mode and
current command outputs).

Convention (the usual one of I-f starts, e.g. Fatu, Teodorescu, Boldea, Andreescu, Blaabjerg, PESC
2008): the current vector i_if lies on the **d axis of the open-loop frame** (angle theta_ol); the rotor
(its d axis, the magnet) lags it by the load angle delta = theta_ol - theta_m, the torque being
k_t i_if sin(delta) (non-salient; k_t = 1.5 p psi_pm), so that the rotor carries the load torque T at
sin(delta) = T / (k_t i_if) and falls out of step beyond delta = 90 deg. At rest and unloaded the
rotor sits on the current vector: the start begins after an alignment (parking) of the rotor on the
frame's angle (a drive parks it with the same current on a fixed angle; simulations start with the
rotor parked: the open-loop frame starts at the rotor's angle).

The I-f current drives an undamped pendulum (J/p delta'' = T - k_t i_if sin(delta)): each change of
acceleration or load leaves the rotor swinging about the current vector. A damping loop turns the
frame's speed against the load angle's swing: w_ol = w_ramp - k_d f delta_hp, where delta_hp is the
load angle delta_obs = theta_ol - theta_obs, seen by the wrapped observer (which always runs), high-
passed (first order, corner ``if_w_hp``: the steady load angle is no swing; the high-pass acts on the
load's share asin(sin(delta_obs) - k_a a_r / i_if) and the frame's own acceleration a_r adds its share
back each period, so that the ramp's end, a step of the steady angle, 56 to 42 deg at the rules'
acceleration and rated load, is no swing: read as one, it held the handover 36 ms past the dwell on
the e-bike hub of docs/examples/motors), limited to +-``SWING_MAX``
and left out where delta_obs is 90 deg or more (an observer that lost the rotor), and f = min(1,
|w_r| / w_off) fades it in with speed (the observer's angle means nothing at standstill). Linearized about a
steady load angle, delta_hp ~ delta - delta_0, and with delta' = w_ol - w_m, J/p w_m' = k_t i_if cos
(delta_0) (delta - delta_0): s^2 + k_d s + w_n^2 = 0, w_n^2 = p k_t i_if cos(delta_0) / J, so that
k_d = 2 zeta w_n gives the damping zeta (the power-based stabilizer of Fatu et al. 2008 damps the same
swing through the active power, which has no damping term at standstill or when regenerating).

Per sampling period T_s:

- the wrapped observer always runs (its estimates converge during the start);
- open loop (``startup_mode`` = 1): the ramp speed w_r moves towards the speed command ``w_cmd`` (a
  measurement the start adds: what the drive is asked for), limited to +-w_on, by at most a T_s a
  period; the frame's speed is w_ol = w_r - k_d f delta_hp, theta_ol += w_ol T_s; the outputs
  ``theta_hat`` and ``w_hat`` are theta_ol and w_ol, ``i_f`` = i_if the d-axis current command of the
  open-loop frame, ``i_f_q`` = i_if sin(delta_obs) its component on the observer's q axis (the torque-
  producing current by the observer: a speed controller taking over starts from it, without a torque
  step);
- handover (mode 0 from the next period) once, for ``if_t_dwell`` without a break, |w_r| has been at
  w_on, the observer's angle within 90 deg of the frame's (an observer off by half a turn is not handed
  the drive) and the swing settled (|delta_hp| below ``SETTLED``): the observer, which may have lost
  the rotor while the ramp accelerated through low speeds, has converged and stays;
- the wrapped observer re-seeded (its steady state at the frame's angle and speed, the current on
  the frame's d axis: an angle error of the load angle, below 90 deg) while the ramp is at w_on and its
  angle more than ``LOST`` (120 deg) off the frame's, where a rotor that follows the frame cannot be:
  at low speed, under acceleration, it may have lost the rotor or settled on a wrong solution, and need
  not find it back by itself (a seed on every arrival at w_on put it 90 deg off a rotor swinging at
  the edge, in simulation);
- closed loop (mode 0): the observer's estimates pass through, ``i_f`` = ``i_f_q`` = 0; back to open
  loop when |w_hat + w_lag| < w_off (< w_on: the hysteresis), at that speed (w_lag: the observer's
  angle rate less its speed estimate, low-passed: the lag of a PLL's speed, a k_p / k_i under an
  acceleration a, which its angle's rate has not), the frame placed ahead
  of the observer's angle by the load angle that carries the current the open loop needs: delta =
  asin(i_n / i_if), i_n = i_q - k_a (dw - a_f), i_q the measured current on the observer's q axis,
  dw the observer's acceleration (low-passed), a_f = +-a the frame's towards the command and k_a =
  J / (p k_t) the current per acceleration: the load's current and the frame's acceleration's (a
  drive braking at its torque limit with the load's help decelerates ten times faster than the start's
  ramp on the drone of docs/examples/motors: placed for the braking current, the rotor slipped), at
  most ``DROP_MAX`` (60 deg, 30 deg from the edge). dw and w_lag are low-passed at w_c = DROP_SETTLE
  (3) (i_if / k_a) / (w_on - w_off), at least ``if_w_hp``, at most 1 / (2 T_s): three time constants
  within the time the drive takes to brake from w_on to w_off at the I-f current's acceleration i_if /
  k_a = p k_t i_if / J (the torque limit's, p T_max / J, by the rules), so that both have settled at
  the drop-back. At the swing's corner ``if_w_hp`` alone (19.6 rad/s, 51 ms) the 7.5-ohm gimbal motor
  of docs/examples/motors, braking from 1 to 0.5 p.u. in 8.4 ms at p (T_max + T_N) / J, dropped back
  with 15 % of its deceleration and lag read: the frame 0.12 p.u. above the rotor and placed for the
  braking current (-60 deg), the rotor braked on through zero and slipped half a turn.

Parameters (appended to the observer's): ``if_i`` [A], ``if_acc`` [rad/s^2], ``if_w_on`` and
``if_w_off`` [rad/s], ``if_k_d`` [1/s], ``if_w_hp`` [rad/s], ``if_t_dwell`` [s], ``if_k_a`` [A s^2/rad];
measurement
(appended): ``w_cmd`` [rad/s].
"""

from __future__ import annotations

import functools
import math

import casadi as ca
from sensorless.symbolic.frames import Sym, wrap_angle
from sensorless.symbolic.observer_wrapper import InnerStep, wrap_observer
from sensorless.symbolic.runtime import REJECTS, RESET, VALID, Field, RuntimeObserver, guarded

PARAMS = (
    Field("if_i", "A", "I-f start: current amplitude (peak), d axis of the open-loop frame", "nonnegative"),
    Field("if_acc", "rad/s^2", "I-f start: acceleration of the current vector (electrical)", "positive"),
    Field("if_w_on", "rad/s", "I-f start: handover speed to the observer (electrical)", "positive"),
    Field("if_w_off", "rad/s", "back to the I-f start below this estimated speed (< if_w_on)", "nonnegative"),
    Field("if_k_d", "1/s", "I-f start: damping gain, frame speed per rad of load-angle swing", "nonnegative"),
    Field("if_w_hp", "rad/s", "I-f start: corner of the load angle's high-pass (the swing)", "positive"),
    Field("if_t_dwell", "s", "I-f start: time at the handover speed before the handover", "nonnegative"),
    Field(
        "if_k_a",
        "A s^2/rad",
        "I-f start: current per acceleration J / (p k_t) (rotor, electrical)",
        "nonnegative",
    ),
)
# the measurement the start adds to the observer's: the speed command (what the drive is asked for)
W_CMD = Field("w_cmd", "rad/s", "speed command (electrical): the I-f start ramps towards it")
STATE = (
    Field("if_theta", "rad", "I-f start: angle of the current vector (electrical)", bound="pi"),
    Field("if_w", "rad/s", "I-f start: ramp speed of the current vector (electrical)", bound="pi / T_s"),
    Field("if_delta_lp", "rad", "I-f start: the load's share of the load angle, low-passed", bound="pi"),
    Field("if_t", "s", "I-f start: time at the handover speed with the observer agreeing (to if_t_dwell)"),
    Field("if_w_obs", "rad/s", "I-f start: the observer's speed estimate of the previous period"),
    Field("if_dw", "rad/s^2", "I-f start: the observer's acceleration, low-passed (the drop-back's corner)"),
    Field("if_th_obs", "rad", "I-f start: the observer's angle of the previous period", bound="pi"),
    Field("if_w_lag", "rad/s", "I-f start: the observer's angle rate less its speed estimate, low-passed"),
    Field("startup_mode_x", "1", "1: open-loop I-f start; 0: observer", bound="1"),
)
OUTPUTS = (
    Field(
        "startup_mode", "1", "1: open-loop I-f start (theta_hat, w_hat are the current vector's); 0: observer"
    ),
    Field("i_f", "A", "I-f start: d-axis current command in the open-loop frame (0 with the observer)"),
    Field("i_f_q", "A", "I-f start: its current on the observer's q axis (a speed control starts from it)"),
)
INNER_REJECTS = "obs_rejects"  # the wrapped observer's own counter, renamed (one 'rejects' per struct)
SETTLED = math.pi / 18  # handover once the load angle's swing (high-passed) is within 10 deg
SWING_MAX = math.pi / 12  # the damping acts on swings up to 15 deg (beyond: saturated)
LOST = 2 * math.pi / 3  # an observer further off the frame than a rotor can lag: re-seeded
DROP_MAX = math.pi / 3  # back to open loop at most 60 deg ahead of the rotor (30 deg from the edge)
# the drop-back's estimates of the rotor's acceleration and of the speed estimate's lag settle within
# the band w_on - w_off crossed at the start current's acceleration (module docstring): this many time
# constants of their low-pass (at least the swing's high-pass corner; at most 1 / (2 T_s), so that
# the first-order update's factor w_c T_s stays within 1/2)
DROP_SETTLE = 3.0


@functools.cache
def with_startup(obs: RuntimeObserver) -> RuntimeObserver:
    """The observer ``obs`` wrapped with the I-f start and handover (module docstring)."""
    n_x, n_p = len(obs.state), len(obs.params)
    outs = obs.outputs[:-2]  # without valid, reset
    names = [f.name for f in outs]
    k_th, k_w = names.index("theta_hat"), names.index("w_hat")
    meas_names = [f.name for f in obs.meas]
    k_i = [meas_names.index(n) for n in ("i_alpha", "i_beta")] if "i_alpha" in meas_names else None
    inner_state = (*obs.state[:-1], obs.state[-1]._replace(name=INNER_REJECTS))
    state = (*inner_state, *STATE, REJECTS)
    params = (*obs.params, *PARAMS)
    meas = (*obs.meas, W_CMD)
    outputs = (*outs, *OUTPUTS, VALID, RESET)
    i_ts = [f.name for f in obs.params].index("T_s")

    def step(inner: InnerStep, x: Sym, meas: Sym, p: Sym) -> tuple[Sym, Sym]:
        P = {f.name: p[n_p + k] for k, f in enumerate(PARAMS)}
        T_s = p[i_ts]
        x_in_next, y_in = inner(x[:n_x], meas[: len(obs.meas)])
        w_cmd = meas[len(obs.meas)]
        th, w_r, d_lp, t_on, w_prev, dw, th_prev, w_lag, mode = (x[n_x + k] for k in range(9))
        theta_obs, w_obs = y_in[k_th], y_in[k_w]
        # the load angle by the observer and its swing: about the steady load angle, the low-passed
        # load's share (d_lp) plus the frame's own acceleration's (k_a a_r / i_if in sine), so that
        # the ramp's end (a step of the steady angle, 15 deg at the rules' acceleration) is no swing
        delta = wrap_angle(th - theta_obs)
        target = ca.fmin(ca.fmax(w_cmd, -P["if_w_on"]), P["if_w_on"])
        step_r = P["if_acc"] * T_s
        w_r_next = w_r + ca.fmin(ca.fmax(target - w_r, -step_r), step_r)
        i_if = ca.fmax(P["if_i"], 1e-12)
        s_acc = P["if_k_a"] * (w_r_next - w_r) / T_s / i_if
        delta_load = ca.asin(ca.fmin(ca.fmax(ca.sin(delta) - s_acc, -1), 1))
        steady = ca.asin(ca.fmin(ca.fmax(ca.sin(d_lp) + s_acc, -1), 1))
        swing = wrap_angle(delta - steady)
        # the damping's swing: within +-SWING_MAX, and none from an observer off by 90 deg or more
        # (lost while the ramp accelerated through low speeds: the start then holds the rotor alone)
        agree_90 = ca.fabs(delta) < ca.pi / 2
        swing_d = ca.if_else(agree_90, ca.fmin(ca.fmax(swing, -SWING_MAX), SWING_MAX), 0)
        d_lp_next = wrap_angle(d_lp + P["if_w_hp"] * T_s * wrap_angle(delta_load - d_lp))
        # open loop: the ramp towards the command (within +-w_on, above); the frame's speed damped
        # against the swing, faded in with speed (module docstring); the angle with the period's speed
        fade = ca.fmin(1, ca.fabs(w_r) / ca.fmax(P["if_w_off"], 1e-9))
        w_ol = w_r - P["if_k_d"] * fade * swing_d
        th_ol = wrap_angle(th + w_ol * T_s)
        # handover at w_on, the observer's angle within 90 deg of the frame's (where an I-f start
        # that holds the rotor keeps it; an observer off by half a turn is not handed the drive),
        # the swing settled
        agree = ca.logic_and(agree_90, ca.fabs(swing) < SETTLED)
        at_on = ca.logic_and(ca.fabs(w_r) >= P["if_w_on"] * (1 - 1e-9), agree)
        t_next = ca.if_else(at_on, ca.fmin(t_on + T_s, P["if_t_dwell"]), 0)
        handover = ca.logic_and(at_on, t_on >= P["if_t_dwell"] * (1 - 1e-9))
        # closed loop: back to open loop below w_off, at the observer's speed, the frame ahead of its
        # angle by the load angle that carries the measured q-axis current
        if k_i is None:
            i_q = 0
        else:
            i_a, i_b = meas[k_i[0]], meas[k_i[1]]
            i_q = -ca.sin(theta_obs) * i_a + ca.cos(theta_obs) * i_b
        s_max = math.sin(DROP_MAX)
        # the current the open loop needs: the load's (the closed loop's current less what its
        # acceleration takes) and what the frame's acceleration towards the command takes
        # low-passed at w_c: settled when the drive, braking at the I-f current's acceleration
        # i_if / k_a = p k_t i_if / J (p T_max / J by the rules), has crossed the band from w_on to
        # w_off (module docstring)
        a_if = P["if_i"] / ca.fmax(P["if_k_a"], 1e-12)
        w_c = DROP_SETTLE * a_if / ca.fmax(P["if_w_on"] - P["if_w_off"], 1e-9)
        w_c = ca.fmin(ca.fmax(P["if_w_hp"], w_c), 0.5 / T_s)
        dw_next = dw + w_c * T_s * ((w_obs - w_prev) / T_s - dw)
        # the speed estimate's lag behind the rotor: its angle's rate less the estimate (a PLL's speed
        # lags by a k_p / k_i under acceleration a while its angle's rate does not: braking at the
        # torque limit through zero, VESC's PLL read +0.035 p.u. with the rotor at -0.062 p.u. on the
        # 2017 VESC motor, and the frame started there slipped), low-passed: constant under a
        # constant acceleration, so the low-pass adds no lag of its own; each sample within +-w_on
        # (the first period after a reset has no previous angle)
        lag_k = wrap_angle(theta_obs - th_prev) / T_s - w_obs
        lag_k = ca.fmin(ca.fmax(lag_k, -P["if_w_on"]), P["if_w_on"])
        w_lag_next = w_lag + w_c * T_s * (lag_k - w_lag)
        w_fb = w_obs + w_lag  # the rotor's speed by the observer's angle: the fall-back's
        a_f = P["if_acc"] * ca.sign(target - w_fb)
        i_need = i_q - P["if_k_a"] * (dw - a_f)
        d_drop = ca.asin(ca.fmin(ca.fmax(i_need / i_if, -s_max), s_max))
        # the steady load angle's load share there (the frame's acceleration's is added per period)
        d_load = ca.asin(ca.fmin(ca.fmax(ca.sin(d_drop) - P["if_k_a"] * a_f / i_if, -1), 1))
        drop = ca.fabs(w_fb) < P["if_w_off"]
        open_now = mode > 0.5
        mode_next = ca.if_else(open_now, ca.if_else(handover, 0, 1), ca.if_else(drop, 1, 0))
        th_next = ca.if_else(open_now, th_ol, wrap_angle(theta_obs + d_drop))
        w_next = ca.if_else(open_now, w_r_next, w_fb)
        d_next = ca.if_else(open_now, d_lp_next, d_load)
        y_out = [y_in[k] for k in range(len(outs))]
        y_out[k_th] = ca.if_else(open_now, th, theta_obs)
        y_out[k_w] = ca.if_else(open_now, w_ol, w_obs)
        i_f = ca.if_else(open_now, P["if_i"], 0)
        i_f_q = ca.if_else(open_now, P["if_i"] * ca.sin(delta), 0)
        y_if = (open_now, i_f, i_f_q)
        t_next = ca.if_else(open_now, t_next, 0)
        if obs.steady_state is not None:
            # re-seeded on the frame at w_on while off by more than LOST (module docstring): steady
            # at the frame's angle and speed, the current on its d axis
            at_w_on = ca.fabs(w_r_next) >= P["if_w_on"] * (1 - 1e-9)
            reseed = ca.logic_and(open_now, ca.logic_and(at_w_on, ca.fabs(delta) > LOST))
            seed = obs.steady_state()(p[:n_p], ca.vertcat(th_ol, w_r_next, P["if_i"], 0))
            x_in_next = ca.if_else(reseed, seed, x_in_next)
        x_if = ca.vertcat(th_next, w_next, d_next, t_next, w_obs, dw_next, theta_obs, w_lag_next, mode_next)
        cand = (ca.vertcat(x_in_next, x_if), ca.vertcat(*y_out, *y_if))
        x_coast = ca.vertcat(
            x[:n_x], wrap_angle(th + w_r * T_s), w_r, d_lp, t_on, w_prev, dw, th_prev, w_lag, mode
        )
        coast = (x_coast, ca.vertcat(*y_out, *y_if))
        reset = ca.vertcat(obs.initial_state()(p[:n_p]), 0, 0, 0, 0, 0, 0, 0, 0, 1, 0)
        # the wrapped step's own verdict counts: its sample rejected, the wrapper coasts too
        ok = y_in[len(obs.outputs) - 2] > 0.5
        return guarded(x, p, state, params, cand=cand, coast=coast, reset=reset, ok=ok)

    def steady_state(x_in: Sym, p: Sym, op: Sym) -> Sym:
        w_on = p[n_p + 2]
        mode = ca.if_else(ca.fabs(op[1]) >= w_on, 0, 1)  # running above w_on: the observer
        w0 = op[1]  # in open loop below w_on: the frame turning with the rotor, parked on it
        prev = wrap_angle(op[0] - op[1] * p[i_ts])
        # the previous angle one period back at the speed: no lag in the steady state
        return ca.vertcat(x_in[:-1], x_in[-1], op[0], w0, 0, 0, op[1], 0, prev, 0, mode, 0)

    return wrap_observer(
        obs,
        suffix="if",
        title="with the open-loop I-f start and handover",
        state=state,
        meas=meas,
        params=params,
        outputs=outputs,
        step=step,
        initial=lambda x0: ca.vertcat(x0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0),  # at rest, open loop
        steady=steady_state,
        doc_init="the I-f start in open loop at rest",
        doc_in="the speed command",
        doc_out="the start-up mode and its current command",
    )
