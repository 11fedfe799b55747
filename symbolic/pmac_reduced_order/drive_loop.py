"""One sampling period of the sensorless drive of De Angelo et al. (2006), Fig. 1, as a casadi.Function.

The blocks of Fig. 1, each from its own symbolic definition:

- motor: the PMAC model (2)-(5) with viscosity (symbolic/pmac.py), RK4 between samples
  (symbolic/integrators.py);
- inverter: ideal, zero-order hold, one-sample computation delay (as in symbolic/pmsm_drive.py);
- observer: the runtime step of the reduced-order EMF/load-torque observer (step.py, the contract of
  symbolic/runtime.py, the step that is also generated to C). The step integrates (16) over
  [t_(k-1), t_k] from the samples at both ends (Heun's stages), i.e. it takes the voltage as a sampled
  continuous signal. The inverter holds it piecewise constant instead, with a jump at every t_k; the
  step is given the mean of the voltages held before and after t_k (the midpoint of the jump), so that
  its two stages average to the voltage held over the interval. Either one-sided value puts the angle
  estimate off by half a sample (w T_s / 2 = 1.1 electrical degrees at 250 r/min, measured); with the
  mean the remaining bias is of second order in w T_s (0.06 r/min and -0.04 N m at 250 r/min, 180 us;
  a quarter of that at 90 us);
- speed control: the speed PI with the load-torque feedforward and the current references (25)
  (control.py);
- current control: the paper's "fast current control loop" is not specified; here a PI in the frame of
  the controller's angle (symbolic/controllers.py) with the model EMF phî(theta) w/p_r, harmonics
  included (eqs. (3)-(4) at the estimates), as feedforward.

``sensor`` = 1 closes the loops on the measured angle and speed (the paper's observer-only
simulations, Figs. 2-4); 0 on the estimates (Fig. 5). Loop state, inputs, parameters and recorded
signals are named below; the loop Function is ``loop(z, v, q, p_obs, gain) -> (z_next, rec)`` like
every drive loop, with ``p_obs`` the observer's params vector and ``gain`` its (empty) scheduled gains.
The drive at rest at an operating point is :func:`initial_state_function`.
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.controllers import delay_compensated_angle, low_pass_step, pi_current_control
from sensorless.symbolic.frames import rot, wrap_angle
from sensorless.symbolic.integrators import rk4
from sensorless.symbolic.pmac import (
    EmfSeries,
    PmacParams,
    emf,
    flux_derivative,
    pmac_rhs,
    ripple_free_current,
    torque,
    viscous_torque,
)
from sensorless.symbolic.pmac_reduced_order.control import speed_controller, speed_pi_gains
from sensorless.symbolic.pmac_reduced_order.observer import zeta_tau
from sensorless.symbolic.pmac_reduced_order.step import STATE, param_names, split_params
from sensorless.symbolic.pmsm import PmsmParams
from sensorless.symbolic.runtime import Field

LOOP_STATE = (
    Field("i_a", "A", "stator current, stationary frame"),
    Field("i_b", "A", "stator current, stationary frame"),
    Field("theta_m", "rad", "rotor angle (electrical), in (-pi, pi]"),
    Field("w_m", "rad/s", "rotor speed (electrical)"),
    Field("u_a", "V", "voltage applied over the current period, stationary frame"),
    Field("u_b", "V", "voltage applied over the current period, stationary frame"),
    Field("u_i_d", "V", "current-PI integral state, controller frame"),
    Field("u_i_q", "V", "current-PI integral state, controller frame"),
    Field("x_s", "N m", "speed-PI integral state"),
    Field("w_f", "rad/s", "low-pass filtered speed estimate used by the controllers"),
    Field("u_a_last", "V", "voltage applied over the previous period, stationary frame"),
    Field("u_b_last", "V", "voltage applied over the previous period, stationary frame"),
)

INPUTS = (
    Field("w_ref", "rad/s", "speed reference (electrical)"),
    Field("T_L", "N m", "load torque (without the viscous part)"),
    Field("n_i_a", "A", "current measurement noise, stationary frame"),
    Field("n_i_b", "A", "current measurement noise, stationary frame"),
)

PARAMS = (
    Field("R", "ohm", "motor: stator resistance"),
    Field("L", "H", "motor: inductance"),
    Field("J", "kg m^2", "motor: inertia (reading's units)"),
    Field("B", "N m s", "motor: viscosity (reading's units)"),
    Field("p_r", "1", "speed in eq. (2) per electrical speed (reading)"),
    Field("R_hat", "ohm", "controller estimate"),
    Field("L_hat", "H", "controller estimate"),
    Field("alpha_c", "rad/s", "current-control bandwidth"),
    Field("u_max", "V", "inverter voltage limit (peak phase)"),
    Field("T_s", "s", "sampling period"),
    Field("sensor", "1", "1: controllers use the measured angle and speed; 0: the estimates"),
    Field("alpha_w", "rad/s", "bandwidth of the low-pass filter on the controllers' speed feedback"),
    Field("J_hat", "kg m^2", "controller estimate of the inertia (reading's units)"),
    Field("alpha_s", "rad/s", "speed-loop bandwidth (places both PI poles there)"),
    Field("T_max", "N m", "torque reference limit"),
    Field("feedforward", "1", "1: add the load-torque estimate to the torque reference (Fig. 5(b))"),
)

RECORD = (
    Field("w_ref", "rad/s", "speed reference (electrical)"),
    Field("w_m", "rad/s", "rotor speed (electrical)"),
    Field("w_hat", "rad/s", "speed estimate (electrical), eqs. (13)-(14)"),
    Field("theta_m", "rad", "rotor angle (electrical)"),
    Field("theta_hat", "rad", "position estimate (electrical), eq. (18)"),
    Field("theta_err", "rad", "position estimation error theta_m - theta_hat, wrapped"),
    Field("T_L", "N m", "load torque input"),
    Field("T_L_total", "N m", "load the observer should see: T_L + B omega (Section II)"),
    Field("T_L_hat", "N m", "load-torque estimate, eq. (17)"),
    Field("T_ref", "N m", "torque reference incl. the feedforward, limited (Fig. 1)"),
    Field("T_e", "N m", "electromagnetic torque, eq. (5)"),
    Field("emf_err", "V", "norm of the EMF estimation error |e - e_hat|"),
    Field("i_a", "A", "stator current, stationary frame"),
    Field("i_b", "A", "stator current, stationary frame"),
    Field("i_a_ref", "A", "current reference (25), stationary frame"),
    Field("i_b_ref", "A", "current reference (25), stationary frame"),
)


def _unpack(q: ca.SX, orders: tuple[int, ...]) -> tuple[dict, PmacParams, EmfSeries, EmfSeries]:
    """Named parameters, the true motor and the true and estimated EMF series from ``q``."""
    Q = {s.name: q[k] for k, s in enumerate(PARAMS)}
    n_q, n_phi = len(PARAMS), len(orders)
    emf_true = EmfSeries(orders, q[n_q : n_q + n_phi])
    emf_hat = EmfSeries(orders, q[n_q + n_phi : n_q + 2 * n_phi])
    return Q, PmacParams(Q["R"], Q["L"], Q["J"], Q["B"], Q["p_r"]), emf_true, emf_hat


def n_params(orders: tuple[int, ...]) -> int:
    """Length of ``q``: PARAMS, then Phi_n of the motor, then Phi_n of the controller's estimates."""
    return len(PARAMS) + 2 * len(orders)


@functools.cache
def loop_function(step: ca.Function, y_names: tuple[str, ...], orders: tuple[int, ...], n_sub: int = 4):
    """The loop step of Fig. 1 around the runtime ``step`` (outputs ``y_names``) for harmonic ``orders``."""
    n_x = step.size1_in(0)
    z = ca.SX.sym("z", len(LOOP_STATE) + n_x)
    v = ca.SX.sym("v", len(INPUTS))
    q = ca.SX.sym("q", n_params(orders))
    p_obs = ca.SX.sym("p_obs", step.size1_in(2))
    gain = ca.SX.sym("gain", step.size1_in(3))
    Z = {s.name: z[k] for k, s in enumerate(LOOP_STATE)}
    V = {s.name: v[k] for k, s in enumerate(INPUTS)}
    Q, motor, emf_true, emf_hat = _unpack(q, orders)
    T_s, p_r = Q["T_s"], Q["p_r"]
    i_s, theta_m, w_m = z[0:2], Z["theta_m"], Z["w_m"]
    u_now = z[4:6]
    x_obs = z[len(LOOP_STATE) :]

    # measurement at t_k and the observer's estimates there
    i_meas = i_s + v[2:4]
    # the voltage "sampled" at t_k: the mean of the held voltages before and after t_k (module docstring)
    u_obs = (z[10:12] + u_now) / 2
    x_obs_next, y = step(x_obs, ca.vertcat(i_meas, u_obs), p_obs, gain)
    Y = {name: y[k] for k, name in enumerate(y_names)}
    w_hat, theta_hat, T_L_hat = Y["w_hat"], Y["theta_hat"], Y["T_L_hat"]
    e_hat = ca.vertcat(Y["e_alpha"], Y["e_beta"])

    sensor = Q["sensor"]
    theta_c = sensor * theta_m + (1 - sensor) * theta_hat
    w_f_next = low_pass_step(Z["w_f"], w_hat, Q["alpha_w"], T_s)
    w_c = sensor * w_m + (1 - sensor) * w_f_next

    # speed PI with the load feedforward and the references (25) along phî at the controller's angle
    phi_c = flux_derivative(theta_c, emf_hat)  # eq. (23)
    k_p, k_i = speed_pi_gains(Q["alpha_s"], Q["J_hat"], p_r)
    sc = speed_controller(V["w_ref"], w_c, Z["x_s"], T_L_hat, phi_c, k_p, k_i, Q["T_max"], Q["feedforward"])
    x_s_next = Z["x_s"] + T_s * sc.dx_i

    # current control in the controller frame with the model EMF as feedforward
    Tc = rot(theta_c)
    est = PmsmParams(Q["R_hat"], Q["L_hat"], Q["L_hat"], 0)  # decoupling w J L i; the EMF is u_ff
    e_ff = Tc.T @ (phi_c * (w_c / p_r))  # eq. (3) at the estimates
    cc = pi_current_control(
        Tc.T @ sc.i_ref, Tc.T @ i_meas, z[6:8], w_c, est, Q["alpha_c"], T_s, Q["u_max"], e_ff
    )
    u_next = rot(delay_compensated_angle(theta_c, w_c, T_s)) @ cc.u_ref

    # motor over [t_k, t_k + T_s], voltage held
    def f(x: ca.SX) -> ca.SX:
        return pmac_rhs(x[0:2], x[2], x[3], u_now, V["T_L"], motor, emf_true)

    x_pl = rk4(f, ca.vertcat(i_s, theta_m, w_m), T_s, n_sub)
    x_pl = ca.vertcat(x_pl[0:2], wrap_angle(x_pl[2]), x_pl[3])

    z_next = ca.vertcat(x_pl, u_next, cc.u_i_next, x_s_next, w_f_next, u_now, x_obs_next)
    phi = flux_derivative(theta_m, emf_true)
    e_true = phi * (w_m / p_r)  # eq. (3)
    rec = ca.vertcat(
        V["w_ref"],
        w_m,
        w_hat,
        theta_m,
        theta_hat,
        wrap_angle(theta_m - theta_hat),
        V["T_L"],
        V["T_L"] + Q["B"] * w_m / p_r,
        T_L_hat,
        sc.T_ref,
        torque(phi, i_s),
        ca.norm_2(e_true - e_hat),
        i_s,
        sc.i_ref,
    )
    return ca.Function(
        f"pmac_drive_loop_{step.name()}_{n_sub}",
        [z, v, q, p_obs, gain],
        [ca.cse(z_next), ca.cse(rec)],
        ["z", "v", "q", "p_obs", "gain"],
        ["z_next", "rec"],
    )


@functools.cache
def initial_state_function(orders: tuple[int, ...]) -> ca.Function:
    """(q, p_obs, v0, w0, theta0, theta_err0) -> z0: the drive at rest, the observer converged.

    The motor turns at w0 carrying the ripple-free current (25) of the load of ``v0`` plus viscosity,
    with the voltage (2) that holds it; the controllers' integrators hold what they would at rest; the
    observer's states are those of exact estimates at the angle estimate theta0 - theta_err0 (wrapped),
    with the load estimate only where load-torque estimation is on (Gamma > 0).
    """
    q = ca.SX.sym("q", n_params(orders))
    n_p = len(param_names(orders))
    p_obs = ca.SX.sym("p_obs", n_p)
    v0 = ca.SX.sym("v0", len(INPUTS))
    w0, th0, err0 = ca.SX.sym("w0"), ca.SX.sym("theta0"), ca.SX.sym("theta_err0")
    Q, motor, emf_true, emf_hat = _unpack(q, orders)
    V = {s.name: v0[k] for k, s in enumerate(INPUTS)}
    op, _, _ = split_params(p_obs, orders)
    p_r = Q["p_r"]
    T0 = V["T_L"] + viscous_torque(w0, Q["B"], p_r)
    phi0 = flux_derivative(th0, emf_true)  # eq. (4)
    i0 = ripple_free_current(T0, phi0)  # eq. (25) with the true phi
    u0 = motor.R * i0 + emf(th0, w0, emf_true, p_r)  # eq. (2) at rest in the current
    th_hat0 = wrap_angle(th0 - err0)
    phi_hat0 = flux_derivative(th_hat0, emf_hat)
    T_L_hat0 = ca.if_else(op.Gamma > 0, T0, 0)
    zeta0, tau0 = zeta_tau(phi_hat0 * (w0 / p_r), T_L_hat0, phi_hat0, i0, op)  # eq. (15)
    x_obs0 = ca.vertcat(zeta0, tau0, th_hat0, w0, i0, u0, 0)  # and the runtime contract's counter
    u_i0 = rot(th0).T @ (Q["R_hat"] * i0)
    Z = {s.name: ca.SX(0) for s in LOOP_STATE}
    Z.update(
        i_a=i0[0],
        i_b=i0[1],
        theta_m=wrap_angle(th0),
        w_m=w0,
        u_a=u0[0],
        u_b=u0[1],
        u_i_d=u_i0[0],
        u_i_q=u_i0[1],
        x_s=T0 - Q["feedforward"] * T_L_hat0,
        w_f=w0,
        u_a_last=u0[0],
        u_b_last=u0[1],
    )
    z0 = ca.vertcat(*[Z[s.name] for s in LOOP_STATE], x_obs0)
    assert x_obs0.size1() == len(STATE)
    names = ["q", "p_obs", "v0", "w0", "theta0", "theta_err0"]
    return ca.Function("pmac_drive_initial", [q, p_obs, v0, w0, th0, err0], [z0], names, ["z0"])
