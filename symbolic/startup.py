"""Open-loop start-up (I-f) and handover, as a wrapper around any family's runtime observer.

Below its minimum sensorless speed an observer cannot be trusted (design/low_speed.py), so drives start
and reverse with a current vector of set amplitude turned at a set acceleration (I-f start: the rotor
follows the rotating current vector like a synchronous motor's rotor follows its field; the current
carries the load torque at a load angle below 90 deg) and hand over to the observer above a speed
where it is reliable, with hysteresis. :func:`with_startup` composes this with any
:class:`~sensorless.symbolic.runtime.RuntimeObserver` into another one, so that simulation and the
generated C get it through the runtime contract (its parameters in the parameter vector, its mode an
output). Per sampling period T_s:

- the wrapped observer always runs (its estimates converge during the start);
- open loop (``startup_mode`` = 1): w_ol moves towards the speed command ``w_cmd`` (a measurement the
  start adds: what the drive is asked for), limited to +-w_on, by at most a T_s a period; theta_ol +=
  w_ol T_s (the angle advances with the speed of the period's start); the outputs ``theta_hat`` and
  ``w_hat`` are theta_ol and w_ol, ``i_f`` = sign(w_cmd) i_if is the current command (q axis of the
  open-loop frame); handover (mode 0 from the next period) once |w_ol| has reached w_on (the I-f
  current vector drives an undamped pendulum, the rotor swinging about it: a handover waiting for the
  observer's speed to settle near w_ol waited until the rotor slipped, on three example motors);
- closed loop (mode 0): the observer's estimates pass through, ``i_f`` = 0; back to open loop when
  |w_hat| < w_off (< w_on: the hysteresis), starting from the observer's angle and speed.

Parameters (appended to the observer's): ``if_i`` [A], ``if_acc`` [rad/s^2], ``if_w_on`` and
``if_w_off`` [rad/s]; measurement (appended): ``w_cmd`` [rad/s].
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.frames import wrap_angle
from sensorless.symbolic.runtime import REJECTS, RESET, VALID, Field, RuntimeObserver, core_function, guarded

PARAMS = (
    Field("if_i", "A", "I-f start: current amplitude (peak)", "nonnegative"),
    Field("if_acc", "rad/s^2", "I-f start: acceleration of the current vector (electrical)", "positive"),
    Field("if_w_on", "rad/s", "I-f start: handover speed to the observer (electrical)", "positive"),
    Field("if_w_off", "rad/s", "back to the I-f start below this estimated speed (< if_w_on)", "nonnegative"),
)
# the measurement the start adds to the observer's: the speed command (what the drive is asked for)
W_CMD = Field("w_cmd", "rad/s", "speed command (electrical): the I-f start ramps towards it")
STATE = (
    Field("if_theta", "rad", "I-f start: angle of the current vector (electrical)", bound="pi"),
    Field("if_w", "rad/s", "I-f start: speed of the current vector (electrical)", bound="pi / T_s"),
    Field("startup_mode_x", "1", "1: open-loop I-f start; 0: observer", bound="1"),
)
OUTPUTS = (
    Field(
        "startup_mode", "1", "1: open-loop I-f start (theta_hat, w_hat are the current vector's); 0: observer"
    ),
    Field("i_f", "A", "I-f start: q-axis current command in the open-loop frame (0 with the observer)"),
)
INNER_REJECTS = "obs_rejects"  # the wrapped observer's own counter, renamed (one 'rejects' per struct)


@functools.cache
def with_startup(obs: RuntimeObserver) -> RuntimeObserver:
    """The observer ``obs`` wrapped with the I-f start and handover (module docstring)."""
    n_x, n_p = len(obs.state), len(obs.params)
    outs = obs.outputs[:-2]  # without valid, reset
    names = [f.name for f in outs]
    k_th, k_w = names.index("theta_hat"), names.index("w_hat")
    inner_state = (*obs.state[:-1], obs.state[-1]._replace(name=INNER_REJECTS))
    state = (*inner_state, *STATE, REJECTS)
    params = (*obs.params, *PARAMS)
    meas = (*obs.meas, W_CMD)
    outputs = (*outs, *OUTPUTS, VALID, RESET)

    def make(disc: str) -> ca.Function:
        inner = obs.core(disc)

        def step(x, meas, p, lam=None):
            P = {f.name: p[n_p + k] for k, f in enumerate(PARAMS)}
            T_s = p[[f.name for f in obs.params].index("T_s")]
            lam_in = lam if lam is not None else ca.SX(0, 1)
            x_in_next, y_in = inner(x[:n_x], meas[: len(obs.meas)], p[:n_p], lam_in)
            w_cmd = meas[len(obs.meas)]
            th, w, mode = x[n_x], x[n_x + 1], x[n_x + 2]
            theta_obs, w_obs = y_in[k_th], y_in[k_w]
            # open loop: ramp towards the command (within +-w_on), angle with the period's speed; hand
            # over once the speed has reached w_on
            target = ca.fmin(ca.fmax(w_cmd, -P["if_w_on"]), P["if_w_on"])
            dw = P["if_acc"] * T_s
            w_ramp = w + ca.fmin(ca.fmax(target - w, -dw), dw)
            th_ramp = wrap_angle(th + w * T_s)
            # ... and the observer's angle within 90 deg of the current vector's, where an I-f start that
            # holds the rotor keeps it (an observer off by half a turn is not handed the drive)
            agree = ca.fabs(wrap_angle(theta_obs - th)) < ca.pi / 2
            handover = ca.logic_and(ca.fabs(w) >= P["if_w_on"] * (1 - 1e-9), agree)
            # closed loop: back to open loop below w_off, from the observer's angle and speed
            drop = ca.fabs(w_obs) < P["if_w_off"]
            open_now = mode > 0.5
            mode_next = ca.if_else(open_now, ca.if_else(handover, 0, 1), ca.if_else(drop, 1, 0))
            th_next = ca.if_else(open_now, th_ramp, theta_obs)
            w_next = ca.if_else(open_now, w_ramp, w_obs)
            y_out = [y_in[k] for k in range(len(outs))]
            y_out[k_th] = ca.if_else(open_now, th, theta_obs)
            y_out[k_w] = ca.if_else(open_now, w, w_obs)
            # the current vector leads in the direction of the command (of the ramp at zero command)
            sign = ca.if_else(w_cmd != 0, ca.sign(w_cmd), ca.if_else(w != 0, ca.sign(w), 1))
            i_f = ca.if_else(open_now, sign * P["if_i"], 0)
            cand = (ca.vertcat(x_in_next, th_next, w_next, mode_next), ca.vertcat(*y_out, open_now, i_f))
            coast = (ca.vertcat(x[:n_x], th_ramp, w, mode), ca.vertcat(*y_out, open_now, i_f))
            reset = ca.vertcat(obs.initial_state()(p[:n_p]), 0, 0, 1, 0)
            # the wrapped step's own verdict counts: its sample rejected, the wrapper coasts too
            ok = y_in[len(obs.outputs) - 2] > 0.5
            return guarded(x, p, state, params, cand=cand, coast=coast, reset=reset, ok=ok)

        return core_function(f"{obs.name}_if_{disc}", step, state, meas, params, obs.lam)

    def initial() -> ca.Function:
        p = ca.SX.sym("p", len(params))
        x0 = ca.vertcat(obs.initial_state()(p[:n_p]), 0, 0, 1, 0)  # at rest, open loop
        return ca.Function(f"{obs.name}_if_init", [p], [x0], ["p"], ["x0"])

    steady = None
    if obs.steady_state is not None:

        def steady_fn() -> ca.Function:
            p, op = ca.SX.sym("p", len(params)), ca.SX.sym("op", 4)
            x_in = obs.steady_state()(p[:n_p], op)
            w_on = p[n_p + 2]
            mode = ca.if_else(ca.fabs(op[1]) >= w_on, 0, 1)  # running above w_on: the observer
            w0 = ca.if_else(mode > 0.5, 0 * op[1], op[1])
            return ca.Function(
                f"{obs.name}_if_steady", [p, op], [ca.vertcat(x_in[:-1], x_in[-1], op[0], w0, mode, 0)]
            )

        steady = steady_fn
    return RuntimeObserver(
        name=f"{obs.name}_if",
        title=f"{obs.title}, with the open-loop I-f start and handover",
        state=state,
        meas=meas,
        params=params,
        outputs=outputs,
        lam=obs.lam,
        schedule_state=obs.schedule_state,
        core=make,
        initial_state=initial,
        discretizations=obs.discretizations,
        steady_state=steady,
        doc_init=f"{obs.doc_init}; the I-f start in open loop at rest",
        doc_in=f"{obs.doc_in}; the speed command",
        doc_out=f"{obs.doc_out}; the start-up mode and its current command",
    )
