"""The speed reference's rate limiter, as a wrapper around any family's runtime observer.

A drive turns a step of its speed command into a ramp before its speed controller (ODrive's velocity-
ramp input mode, ``controller.config.vel_ramp_rate``; VESC's ramping of the speed command): a step
asks the speed controller for the torque limit, and the drive brakes or accelerates at p (T_max +
|T_L|) / J, which a sensorless observer at low speed may not follow (docs/simulation.md, the gimbal
motor). :func:`with_speed_ramp` composes the limiter (symbolic/controllers.py ``ramp_step``: one place
for its equation) with a :class:`~sensorless.symbolic.runtime.RuntimeObserver` into another one, so
that the simulated drive loop (symbolic/pmsm_drive.py, whose speed controller takes the output
``w_ref_r``) and the generated C run the same expression through the runtime contract, as the I-f
start does (symbolic/startup.py).

Per sampling period: w_ramp moves towards the speed command ``w_cmd`` (a measurement: what the drive is
asked for) by at most ``ramp_acc`` T_s (0: the command passes); a command that is not finite holds
it. The output ``w_ref_r`` is the limited reference of this period (what the speed controller tracks);
an observer that takes the speed command itself (the I-f start) is given it, so that its open-loop ramp
aims where the speed controller does. The ramp is no estimate: it runs whether the wrapped step
accepts its sample or not, and a reset of the observer keeps it (the wrapped observer's guard and
counter stay the contract's).

Parameter (appended to the observer's): ``ramp_acc`` [rad/s^2]; state (before the counter):
``w_ramp`` [rad/s]; measurement (appended, unless the observer takes it already): ``w_cmd``.
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.controllers import ramp_step
from sensorless.symbolic.runtime import X_MAX, Field, RuntimeObserver, core_function
from sensorless.symbolic.startup import W_CMD

RAMP_ACC = Field(
    "ramp_acc", "rad/s^2", "speed reference's rate limit (electrical); 0: the command passes", "nonnegative"
)
W_RAMP = Field("w_ramp", "rad/s", "speed reference after the rate limiter (electrical)")
W_REF_R = Field("w_ref_r", "rad/s", "rate-limited speed reference: what the speed controller tracks")


@functools.cache
def with_speed_ramp(obs: RuntimeObserver) -> RuntimeObserver:
    """The observer ``obs`` with the speed reference's rate limiter (module docstring)."""
    n_x, n_p, n_m = len(obs.state), len(obs.params), len(obs.meas)
    takes_cmd = obs.meas[-1].name == W_CMD.name
    meas = obs.meas if takes_cmd else (*obs.meas, W_CMD)
    state = (*obs.state[:-1], W_RAMP, obs.state[-1])
    params = (*obs.params, RAMP_ACC)
    outputs = (*obs.outputs[:-2], W_REF_R, *obs.outputs[-2:])
    i_ts = [f.name for f in obs.params].index("T_s")

    def make(disc: str) -> ca.Function:
        inner = obs.core(disc)

        def step(x, m, p, lam=None):
            w_r = x[n_x - 1]
            w_cmd = m[len(meas) - 1]
            finite = ca.fabs(w_cmd) <= X_MAX  # NaN compares false: a command that is not finite holds it
            w_next = ca.if_else(finite, ramp_step(w_r, w_cmd, p[n_p], p[i_ts]), w_r)
            m_in = ca.vertcat(m[: n_m - 1], w_next) if takes_cmd else m[:n_m]
            x_in = ca.vertcat(x[: n_x - 1], x[n_x])
            x_in_next, y_in = inner(x_in, m_in, p[:n_p], lam if lam is not None else ca.SX(0, 1))
            n_y = len(obs.outputs)
            x_next = ca.vertcat(x_in_next[: n_x - 1], w_next, x_in_next[n_x - 1])
            y = ca.vertcat(y_in[: n_y - 2], w_next, y_in[n_y - 2 :])
            return x_next, y

        return core_function(f"{obs.name}_ramp_{disc}", step, state, meas, params, obs.lam)

    def initial() -> ca.Function:
        p = ca.SX.sym("p", len(params))
        x0 = obs.initial_state()(p[:n_p])
        return ca.Function(
            f"{obs.name}_ramp_init", [p], [ca.vertcat(x0[: n_x - 1], 0, x0[n_x - 1])], ["p"], ["x0"]
        )

    steady = None
    if obs.steady_state is not None:
        inner_steady = obs.steady_state

        def steady_fn() -> ca.Function:
            p, op = ca.SX.sym("p", len(params)), ca.SX.sym("op", 4)
            x_in = inner_steady()(p[:n_p], op)
            # at a steady operating point the reference has reached the speed (op[1])
            return ca.Function(
                f"{obs.name}_ramp_steady", [p, op], [ca.vertcat(x_in[: n_x - 1], op[1], x_in[n_x - 1])]
            )

        steady = steady_fn
    return RuntimeObserver(
        name=f"{obs.name}_ramp",
        title=f"{obs.title}, with the speed reference's rate limiter",
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
        doc_init=f"{obs.doc_init}; the speed reference at rest (0)",
        doc_in=obs.doc_in if takes_cmd else f"{obs.doc_in}; the speed command",
        doc_out=f"{obs.doc_out}; the rate-limited speed reference",
    )
