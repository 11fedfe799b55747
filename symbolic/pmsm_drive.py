"""One sampling period of a sensorless PMSM drive around any runtime observer, as a casadi.Function.

The structure of Piippo, Hinkkanen, Luomi (2008) Fig. 7, shared by every observer family that runs on
a PMSM (salient or not); each block from its own symbolic definition:

- motor: continuous plant (1)-(3) with mechanics, RK4 between samples (symbolic/pmsm.py);
- inverter: ideal, zero-order hold, one-sample computation delay: the voltage computed at t_k is
  applied over [t_k + T_s, t_k + 2 T_s] (it is carried in the loop state until then);
- observer: the family's runtime step, the one that is also generated to C (symbolic/runtime.py,
  contract ``step(x, meas, p, gain) -> (x_next, y)``); its outputs ``w_hat`` and ``theta_hat`` close
  the loops, and an output ``u_c_d`` (a carrier voltage for HF injection), if it has one, is added on
  the estimated d axis of the voltage reference;
- speed control: IP with the torque limit and MTPA current references (symbolic/controllers.py,
  symbolic/pmsm.py), on the observer's rate-limited speed reference ``w_ref_r`` where the runtime
  observer carries the limiter (symbolic/speed_ramp.py; it is the drive's, generated to C with it);
- current control: PI in the estimated rotor frame, decoupled, rotated to the stationary frame at the
  delay-compensated angle; a band-stop keeps a carrier out of its feedback.

Timing at sample k (time t_k): the plant shows its current i_s(t_k); the observer takes that current
and the voltage applied over [t_k, t_k + T_s] (computed at k-1) and gives the estimates at t_k; the
controllers compute the next voltage; the plant integrates over [t_k, t_k + T_s]. The recorded
signals are those at t_k. With ``sensor`` = 1 the controllers use the measured angle and speed
instead of the estimates (the observer still runs and is recorded).

The loop is one Function ``loop(z, v, q, p_obs, gain) -> (z_next, rec)``: z the loop state, v the
per-sample inputs (references, load, noise), q the drive parameters, p_obs and gain the observer's
parameter and gain vectors. ``Function.mapaccum`` turns it into a whole simulation. The drive at rest
at an operating point (the start of a simulation) is :func:`initial_loop_state_function`.
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.controllers import (
    delay_compensated_angle,
    low_pass_step,
    pi_current_control,
    speed_control,
    speed_gains,
)
from sensorless.symbolic.filters import band_pass, biquad_step
from sensorless.symbolic.frames import J, rot, wrap_angle
from sensorless.symbolic.pmsm import (
    Mechanics,
    PmsmParams,
    flux_from_current,
    mtpa_current,
    plant_outputs,
    plant_period,
    stator_voltage,
    torque,
)
from sensorless.symbolic.runtime import Field

# loop state, without the observer state that follows it
LOOP_STATE = (
    Field("psi_d", "V s", "stator flux, true rotor frame"),
    Field("psi_q", "V s", "stator flux, true rotor frame"),
    Field("theta_m", "rad", "rotor angle (electrical), in (-pi, pi]"),
    Field("w_m", "rad/s", "rotor speed (electrical)"),
    Field("u_a", "V", "voltage applied over the current period, stationary frame"),
    Field("u_b", "V", "voltage applied over the current period, stationary frame"),
    Field("u_i_d", "V", "current-PI integral state, controller frame"),
    Field("u_i_q", "V", "current-PI integral state, controller frame"),
    Field("x_s", "N m", "speed-controller integral state"),
    Field("w_f", "rad/s", "low-pass filtered speed estimate used by the controllers"),
    Field("nf_d1", "A", "carrier notch filter state, controller-frame d current"),
    Field("nf_d2", "A", "carrier notch filter state, controller-frame d current"),
    Field("nf_q1", "A", "carrier notch filter state, controller-frame q current"),
    Field("nf_q2", "A", "carrier notch filter state, controller-frame q current"),
    Field("nf_w1", "rad/s", "carrier notch filter state, speed feedback"),
    Field("nf_w2", "rad/s", "carrier notch filter state, speed feedback"),
)

# per-sample inputs
INPUTS = (
    Field("w_ref", "rad/s", "speed reference (speed control) or prescribed speed (stiff load)"),
    Field("T_L", "N m", "load torque"),
    Field("T_ext", "N m", "torque reference in torque-control mode"),
    Field("n_i_a", "A", "current measurement noise, stationary frame"),
    Field("n_i_b", "A", "current measurement noise, stationary frame"),
)

# drive parameters
PARAMS = (
    Field("R_s", "ohm", "motor: stator resistance"),
    Field("L_d", "H", "motor: d-axis inductance"),
    Field("L_q", "H", "motor: q-axis inductance"),
    Field("psi_pm", "V s", "motor: PM flux"),
    Field("p", "1", "pole pairs"),
    Field("J", "kg m^2", "total inertia"),
    Field("B", "N m s/rad", "viscous friction (mechanical speed)"),
    Field("R_s_hat", "ohm", "controller estimate"),
    Field("L_d_hat", "H", "controller estimate"),
    Field("L_q_hat", "H", "controller estimate"),
    Field("psi_pm_hat", "V s", "controller estimate"),
    Field("J_hat", "kg m^2", "controller estimate of the inertia"),
    Field("alpha_c", "rad/s", "current-control bandwidth"),
    Field("alpha_s", "rad/s", "speed-control bandwidth"),
    Field("T_max", "N m", "torque limit"),
    Field("u_max", "V", "inverter voltage limit (peak phase, linear range u_dc/sqrt(3))"),
    Field("T_s", "s", "sampling period"),
    Field("sensor", "1", "1: controllers use the measured angle and speed; 0: the estimates"),
    Field("speed_mode", "1", "1: speed control; 0: torque control (T_ext)"),
    Field("stiff", "1", "1: speed prescribed by a stiff load machine (w_ref); 0: inertia"),
    Field("alpha_w", "rad/s", "bandwidth of the low-pass filter on the controllers' speed feedback"),
    Field("notch", "1", "1: remove the carrier from the current-controller feedback (band-stop)"),
    Field("speed_notch", "1", "1: remove the carrier from the speed feedback too (band-stop)"),
    Field("w_n", "rad/s", "band-stop centre (the carrier frequency w_c)"),
    Field("B_n", "rad/s", "band-stop -3 dB bandwidth"),
)

# recorded signals (at t_k); the observer's own outputs follow these
RECORD = (
    Field("w_ref", "rad/s", "speed reference"),
    Field("w_m", "rad/s", "rotor speed (electrical)"),
    Field("w_hat", "rad/s", "speed estimate (electrical)"),
    Field("theta_m", "rad", "rotor angle (electrical)"),
    Field("theta_hat", "rad", "rotor-angle estimate (electrical)"),
    Field("theta_err", "rad", "position estimation error theta_m - theta_hat, wrapped"),
    Field("T_L", "N m", "load torque"),
    Field("T_ref", "N m", "torque reference (limited)"),
    Field("T_e", "N m", "electromagnetic torque, eq. (3)"),
    Field("T_e_hat", "N m", "estimated torque (3) from measured current and estimates"),
    Field("i_d", "A", "stator current, true rotor frame"),
    Field("i_q", "A", "stator current, true rotor frame"),
    Field("i_d_ref", "A", "current reference (MTPA), controller frame"),
    Field("i_q_ref", "A", "current reference (MTPA), controller frame"),
    Field("u_d_ref", "V", "voltage reference incl. carrier, controller frame"),
    Field("u_q_ref", "V", "voltage reference, controller frame"),
)


_RECORDED = frozenset(s.name for s in RECORD)


def observer_record(outputs: tuple) -> tuple:
    """The observer's outputs that the loop records after RECORD (those not already in it)."""
    return tuple(f for f in outputs if f.name not in _RECORDED)


@functools.cache
def loop_function(
    step: ca.Function | None,
    y_names: tuple[str, ...] = (),
    n_sub: int = 4,
) -> ca.Function:
    """The loop step of Fig. 7 around the observer ``step`` (None: no observer, sensor feedback only).

    ``y_names`` names the observer's outputs (``w_hat`` and ``theta_hat`` are used, and ``u_c_d``
    where the observer has it);
    ``n_sub`` RK4 substeps per sampling period integrate the plant.
    """
    n_x = step.size1_in(0) if step is not None else 0
    n_p = step.size1_in(2) if step is not None else 0
    n_g = step.size1_in(3) if step is not None else 0
    z = ca.SX.sym("z", len(LOOP_STATE) + n_x)
    v = ca.SX.sym("v", len(INPUTS))
    q = ca.SX.sym("q", len(PARAMS))
    p_obs = ca.SX.sym("p_obs", n_p)
    gain = ca.SX.sym("gain", n_g)
    Z = {s.name: z[k] for k, s in enumerate(LOOP_STATE)}
    V = {s.name: v[k] for k, s in enumerate(INPUTS)}
    Q = {s.name: q[k] for k, s in enumerate(PARAMS)}
    motor = PmsmParams(Q["R_s"], Q["L_d"], Q["L_q"], Q["psi_pm"])
    est = PmsmParams(Q["R_s_hat"], Q["L_d_hat"], Q["L_q_hat"], Q["psi_pm_hat"])
    mech = Mechanics(Q["J"], Q["B"], Q["p"])
    T_s = Q["T_s"]
    x_plant = z[0:4]
    u_now = z[4:6]
    u_i = z[6:8]
    nf_d, nf_q, nf_w = z[10:12], z[12:14], z[14:16]
    x_obs = z[len(LOOP_STATE) :]

    # motor at t_k: current measured (with noise), torque
    out = plant_outputs(x_plant, motor, mech.pole_pairs)
    i_meas = out.i_ab + v[3:5]

    # observer (runtime step): estimates at t_k
    if step is not None:
        # an observer with the I-f start (symbolic/startup.py) also takes the speed command
        cmd = [V["w_ref"]] if step.size1_in(1) > len(MEAS_FIELDS) else []
        x_obs_next, y = step(x_obs, ca.vertcat(i_meas, u_now, *cmd), p_obs, gain)
        Y = {name: y[k] for k, name in enumerate(y_names)}
        w_hat, theta_hat, u_c_d = Y["w_hat"], Y["theta_hat"], Y.get("u_c_d", 0)
        # an observer wrapped in the speed reference's rate limiter (symbolic/speed_ramp.py): the speed
        # controller tracks its limited reference
        w_ref = Y.get("w_ref_r", V["w_ref"])
        # an observer wrapped in the open-loop I-f start (symbolic/startup.py): its mode and currents
        m_if, i_f, i_f_q = Y.get("startup_mode", 0), Y.get("i_f", 0), Y.get("i_f_q", 0)
    else:
        x_obs_next, y = ca.SX(0, 1), ca.SX(0, 1)
        w_hat, theta_hat, u_c_d = Z["w_m"], Z["theta_m"], 0
        w_ref = V["w_ref"]
        m_if, i_f, i_f_q = 0, 0, 0

    sensor = Q["sensor"]
    theta_c = sensor * Z["theta_m"] + (1 - sensor) * theta_hat  # controller frame angle
    # the carrier's speed-estimate ripple is the observer's signal too: the speed loop would feed it back
    # as a carrier current against the injection's error signal (docs/simulation.md, "Speed control")
    bp = band_pass(Q["w_n"], Q["B_n"], T_s)
    hf_w = biquad_step(bp, nf_w, w_hat)
    w_f_next = low_pass_step(Z["w_f"], w_hat - Q["speed_notch"] * hf_w.y, Q["alpha_w"], T_s)
    w_c = sensor * Z["w_m"] + (1 - sensor) * w_f_next

    # speed control (IP) or torque control, torque limit, MTPA references [12]
    sc = speed_control(w_ref, w_c, Z["x_s"], Q["alpha_s"], Q["J_hat"], Q["p"], T_s, Q["T_max"])
    T_ext = ca.fmin(ca.fmax(V["T_ext"], -Q["T_max"]), Q["T_max"])
    speed_mode = Q["speed_mode"]
    T_ref = speed_mode * sc.T_ref + (1 - speed_mode) * T_ext
    x_s_next = speed_mode * sc.x_next + (1 - speed_mode) * Z["x_s"]
    i_ref = mtpa_current(T_ref, est, Q["p"])
    # I-f start: the current vector i_f on the d axis of the open-loop frame (theta_hat is its angle);
    # the speed controller held where it hands over the torque the I-f current carries by the observer
    # (i_f_q, its component on the observer's q axis: symbolic/startup.py), without a torque step
    if not isinstance(m_if, int):
        T_if = 1.5 * Q["p"] * Q["psi_pm_hat"] * i_f_q
        k_p_s, _ = speed_gains(Q["alpha_s"], Q["J_hat"], Q["p"])
        x_s_next = ca.if_else(m_if > 0.5, speed_mode * (T_if + k_p_s * w_c), x_s_next)
        i_ref = ca.if_else(m_if > 0.5, ca.vertcat(i_f, 0), i_ref)
        T_ref = ca.if_else(m_if > 0.5, T_if, T_ref)

    # current control in the controller frame; carrier (17) on its d axis; delay-compensated output
    i_c = rot(theta_c).T @ i_meas
    # the carrier response is the observer's signal, not a current error: band-stop it (d and q)
    hf_d, hf_q = biquad_step(bp, nf_d, i_c[0]), biquad_step(bp, nf_q, i_c[1])
    i_fb = i_c - Q["notch"] * ca.vertcat(hf_d.y, hf_q.y)
    cc = pi_current_control(i_ref, i_fb, u_i, w_c, est, Q["alpha_c"], T_s, Q["u_max"])
    u_ref = cc.u_ref + ca.vertcat(u_c_d, 0)
    u_next = rot(delay_compensated_angle(theta_c, w_c, T_s)) @ u_ref

    # motor over [t_k, t_k + T_s] with the voltage computed one period earlier
    w_presc = Q["stiff"] * V["w_ref"] + (1 - Q["stiff"]) * Z["w_m"]
    x_in = ca.vertcat(x_plant[0:3], w_presc)
    x_plant_next = plant_period(x_in, u_now, V["T_L"], motor, mech, Q["stiff"], T_s, n_sub)

    z_next = ca.vertcat(
        x_plant_next,
        u_next,
        cc.u_i_next,
        x_s_next,
        w_f_next,
        hf_d.z_next,
        hf_q.z_next,
        hf_w.z_next,
        x_obs_next,
    )
    T_e_hat = torque(flux_from_current(i_c, est), i_c, Q["p"])
    rec = ca.vertcat(
        V["w_ref"],
        w_presc,
        w_hat,
        Z["theta_m"],
        theta_hat,
        wrap_angle(Z["theta_m"] - theta_hat),
        V["T_L"],
        T_ref,
        out.T_e,
        T_e_hat,
        out.i_r,
        i_ref,
        u_ref,
        *[y[k] for k, n in enumerate(y_names) if n not in _RECORDED],  # the observer's other outputs
    )
    name = f"pmsm_drive_loop_{step.name() if step is not None else 'sensor'}_{n_sub}"
    return ca.Function(
        name,
        [z, v, q, p_obs, gain],
        [ca.cse(z_next), ca.cse(rec)],
        ["z", "v", "q", "p_obs", "gain"],
        ["z_next", "rec"],
    )


# what the loop feeds the observer's step as ``meas``, in this order: the runtime contract's MEAS fields
# of every observer that runs in it (the current sampled at t_k, the voltage held over the period)
MEAS_FIELDS = (
    Field("i_alpha", "A", "stator current at t_k, stationary frame"),
    Field("i_beta", "A", "stator current at t_k, stationary frame"),
    Field("u_alpha", "V", "stator voltage applied over [t_k, t_k + T_s], stationary frame"),
    Field("u_beta", "V", "stator voltage applied over [t_k, t_k + T_s], stationary frame"),
)
MEAS = tuple(f.name for f in MEAS_FIELDS)

# the operating point a PMSM observer's ``steady_state`` Function takes (RuntimeObserver.steady_state)
OPERATING_POINT = (
    Field("theta_hat", "rad", "angle estimate (electrical)"),
    Field("w", "rad/s", "rotor speed (electrical)"),
    Field("i_d", "A", "stator current, rotor frame"),
    Field("i_q", "A", "stator current, rotor frame"),
)


@functools.cache
def initial_loop_state_function() -> ca.Function:
    """(q, v0, w0, theta0) -> (z0, op): the drive at rest at speed w0 and angle theta0.

    The load (or, in torque mode, the torque reference) of the first inputs ``v0`` plus the viscous
    torque is carried by the MTPA current of the true motor; its voltage is the steady-state voltage
    (29); the controllers' integrators hold what they would at rest (the current PI its output minus the
    decoupling term, the speed controller the torque). ``op`` = [theta0, w0, i_d, i_q] is the operating
    point for the observer's ``steady_state`` (:data:`OPERATING_POINT`), before its angle error.
    """
    q = ca.SX.sym("q", len(PARAMS))
    v0 = ca.SX.sym("v0", len(INPUTS))
    w0, th0 = ca.SX.sym("w0"), ca.SX.sym("theta0")
    Q = {s.name: q[k] for k, s in enumerate(PARAMS)}
    V = {s.name: v0[k] for k, s in enumerate(INPUTS)}
    motor = PmsmParams(Q["R_s"], Q["L_d"], Q["L_q"], Q["psi_pm"])
    est = PmsmParams(Q["R_s_hat"], Q["L_d_hat"], Q["L_q_hat"], Q["psi_pm_hat"])
    speed_mode = Q["speed_mode"]
    T0 = speed_mode * (V["T_L"] + Q["B"] * w0 / Q["p"]) + (1 - speed_mode) * V["T_ext"]
    i0 = mtpa_current(T0, motor, Q["p"])
    psi0 = flux_from_current(i0, motor)  # eq. (2)
    u_r = stator_voltage(i0, 0, psi0, w0, motor.R_s)  # eq. (29)
    u_i0 = u_r - w0 * (J @ flux_from_current(i0, est))  # the current PI at rest, minus its decoupling
    k_p, _ = speed_gains(Q["alpha_s"], Q["J_hat"], Q["p"])
    bp = band_pass(Q["w_n"], Q["B_n"], Q["T_s"])
    Z = {s.name: ca.SX(0) for s in LOOP_STATE}
    u_ab = rot(th0) @ u_r
    Z.update(
        psi_d=psi0[0],
        psi_q=psi0[1],
        theta_m=wrap_angle(th0),
        w_m=w0,
        u_a=u_ab[0],
        u_b=u_ab[1],
        u_i_d=u_i0[0],
        u_i_q=u_i0[1],
        x_s=speed_mode * (T0 + k_p * w0),
        w_f=w0,
        # the speed notch's band-pass at rest on the constant w0 (its output 0: zero gain at DC)
        nf_w1=-bp.b0 * w0,
        nf_w2=bp.b2 * w0,
    )
    z0 = ca.vertcat(*[Z[s.name] for s in LOOP_STATE])
    op = ca.vertcat(th0, w0, i0)
    return ca.Function(
        "pmsm_drive_initial", [q, v0, w0, th0], [z0, op], ["q", "v0", "w0", "theta0"], ["z0", "op"]
    )
