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
from sensorless.symbolic.frames import Sym
from sensorless.symbolic.observer_wrapper import InnerStep, wrap_observer
from sensorless.symbolic.runtime import X_MAX, Field, RuntimeObserver
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
    i_ts = [f.name for f in obs.params].index("T_s")
    n_y = len(obs.outputs)

    def step(inner: InnerStep, x: Sym, m: Sym, p: Sym) -> tuple[Sym, Sym]:
        w_r = x[n_x - 1]
        w_cmd = m[len(meas) - 1]
        finite = ca.fabs(w_cmd) <= X_MAX  # NaN compares false: a command that is not finite holds it
        w_next = ca.if_else(finite, ramp_step(w_r, w_cmd, p[n_p], p[i_ts]), w_r)
        m_in = ca.vertcat(m[: n_m - 1], w_next) if takes_cmd else m[:n_m]
        x_in_next, y_in = inner(ca.vertcat(x[: n_x - 1], x[n_x]), m_in)
        x_next = ca.vertcat(x_in_next[: n_x - 1], w_next, x_in_next[n_x - 1])
        y = ca.vertcat(y_in[: n_y - 2], w_next, y_in[n_y - 2 :])
        return x_next, y

    def steady(x_in: Sym, p: Sym, op: Sym) -> Sym:
        # at a steady operating point the reference has reached the speed (op[1])
        return ca.vertcat(x_in[: n_x - 1], op[1], x_in[n_x - 1])

    return wrap_observer(
        obs,
        suffix="ramp",
        title="with the speed reference's rate limiter",
        state=(*obs.state[:-1], W_RAMP, obs.state[-1]),
        meas=meas,
        params=(*obs.params, RAMP_ACC),
        outputs=(*obs.outputs[:-2], W_REF_R, *obs.outputs[-2:]),
        step=step,
        initial=lambda x0: ca.vertcat(x0[: n_x - 1], 0, x0[n_x - 1]),
        steady=steady,
        doc_init="the speed reference at rest (0)",
        doc_in=None if takes_cmd else "the speed command",
        doc_out="the rate-limited speed reference",
    )
