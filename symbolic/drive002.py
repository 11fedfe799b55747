"""One sampling period of the sensorless drive of paper 002, Fig. 1, as a casadi.Function.

The blocks of Fig. 1, each from its own symbolic definition:

- motor: the PMAC model (2)-(5) with viscosity (symbolic/pmac.py), RK4 between samples
  (symbolic/plant.py);
- inverter: ideal, zero-order hold, one-sample computation delay (as for paper 000);
- observer: the reduced-order EMF/load-torque observer step (symbolic/reduced_order_step.py, the step
  that is also generated to C), contract ``step(x, i_ab, u_ab, params) -> (x_next, w_hat, theta_hat,
  T_L_hat, e_hat, phi_hat)``. The step integrates (16) over [t_(k-1), t_k] from the samples at both
  ends (Heun's stages), i.e. it takes the voltage as a sampled continuous signal. The inverter holds
  it piecewise constant instead, with a jump at every t_k; the step is given the mean of the voltages
  held before and after t_k (the midpoint of the jump), so that its two stages average to the voltage
  held over the interval. Either one-sided value puts the angle estimate off by half a sample
  (w T_s / 2 = 1.1 electrical degrees at 250 r/min, measured); with the mean the remaining bias is of
  second order in w T_s (0.06 r/min and -0.04 N m at 250 r/min, 180 us; a quarter of that at 90 us);
- speed control: the speed PI with the load-torque feedforward and the current references (25)
  (symbolic/pmac_control.py);
- current control: the paper's "fast current control loop" is not specified; here a PI in the frame of
  the controller's angle (symbolic/drive_control.py) with the model EMF phî(theta) w/p_r, harmonics
  included (eqs. (3)-(4) at the estimates), as feedforward.

``sensor`` = 1 closes the loops on the measured angle and speed (the paper's observer-only
simulations, Figs. 2-4); 0 on the estimates (Fig. 5). Loop state, inputs and recorded signals are
named below; the loop Function is ``loop(z, v, q, p_obs, gain) -> (z_next, rec)`` like paper 000's,
with ``p_obs`` the observer's params vector and ``gain`` the speed-controller params.
"""

from __future__ import annotations

import functools

import casadi as ca
from sensorless.symbolic.drive000 import Signal, wrap
from sensorless.symbolic.drive_control import delay_compensated_angle, low_pass_step, pi_current_control
from sensorless.symbolic.plant import rk4
from sensorless.symbolic.pmac import EmfSeries, PmacParams, flux_derivative, pmac_rhs, torque
from sensorless.symbolic.pmac_control import speed_controller
from sensorless.symbolic.pmsm import PmsmParams, rot

LOOP_STATE = (
    Signal("i_a", "A", "stator current, stationary frame"),
    Signal("i_b", "A", "stator current, stationary frame"),
    Signal("theta_m", "rad", "rotor angle (electrical), in (-pi, pi]"),
    Signal("w_m", "rad/s", "rotor speed (electrical)"),
    Signal("u_a", "V", "voltage applied over the current period, stationary frame"),
    Signal("u_b", "V", "voltage applied over the current period, stationary frame"),
    Signal("u_i_d", "V", "current-PI integral state, controller frame"),
    Signal("u_i_q", "V", "current-PI integral state, controller frame"),
    Signal("x_s", "N m", "speed-PI integral state"),
    Signal("w_f", "rad/s", "low-pass filtered speed estimate used by the controllers"),
    Signal("u_a_last", "V", "voltage applied over the previous period, stationary frame"),
    Signal("u_b_last", "V", "voltage applied over the previous period, stationary frame"),
)

INPUTS = (
    Signal("w_ref", "rad/s", "speed reference (electrical)"),
    Signal("T_L", "N m", "load torque (without the viscous part)"),
    Signal("n_i_a", "A", "current measurement noise, stationary frame"),
    Signal("n_i_b", "A", "current measurement noise, stationary frame"),
)

PARAMS = (
    Signal("R", "ohm", "motor: stator resistance"),
    Signal("L", "H", "motor: inductance"),
    Signal("J", "kg m^2", "motor: inertia (reading's units)"),
    Signal("B", "N m s", "motor: viscosity (reading's units)"),
    Signal("p_r", "1", "speed in eq. (2) per electrical speed (reading)"),
    Signal("R_hat", "ohm", "controller estimate"),
    Signal("L_hat", "H", "controller estimate"),
    Signal("alpha_c", "rad/s", "current-control bandwidth"),
    Signal("u_max", "V", "inverter voltage limit (peak phase)"),
    Signal("T_s", "s", "sampling period"),
    Signal("sensor", "1", "1: controllers use the measured angle and speed; 0: the estimates"),
    Signal("alpha_w", "rad/s", "bandwidth of the low-pass filter on the controllers' speed feedback"),
)

RECORD = (
    Signal("w_ref", "rad/s", "speed reference (electrical)"),
    Signal("w_m", "rad/s", "rotor speed (electrical)"),
    Signal("w_hat", "rad/s", "speed estimate (electrical), eqs. (13)-(14)"),
    Signal("theta_m", "rad", "rotor angle (electrical)"),
    Signal("theta_hat", "rad", "position estimate (electrical), eq. (18)"),
    Signal("theta_err", "rad", "position estimation error theta_m - theta_hat, wrapped"),
    Signal("T_L", "N m", "load torque input"),
    Signal("T_L_total", "N m", "load the observer should see: T_L + B omega (Section II)"),
    Signal("T_L_hat", "N m", "load-torque estimate, eq. (17)"),
    Signal("T_ref", "N m", "torque reference incl. the feedforward, limited (Fig. 1)"),
    Signal("T_e", "N m", "electromagnetic torque, eq. (5)"),
    Signal("emf_err", "V", "norm of the EMF estimation error |e - e_hat|"),
    Signal("i_a", "A", "stator current, stationary frame"),
    Signal("i_b", "A", "stator current, stationary frame"),
    Signal("i_a_ref", "A", "current reference (25), stationary frame"),
    Signal("i_b_ref", "A", "current reference (25), stationary frame"),
)


@functools.cache
def loop_function(step: ca.Function, orders: tuple[int, ...], n_sub: int = 4) -> ca.Function:
    """The loop step of Fig. 1 around the observer ``step`` for an EMF series of harmonic ``orders``."""
    n_x = step.size1_in(0)
    n_phi = len(orders)
    z = ca.SX.sym("z", len(LOOP_STATE) + n_x)
    v = ca.SX.sym("v", len(INPUTS))
    q = ca.SX.sym("q", len(PARAMS) + 2 * n_phi)  # then Phi of the motor, Phi of the estimates
    p_obs = ca.SX.sym("p_obs", step.size1_in(3))
    gain = ca.SX.sym("gain", 5)  # speed controller: k_p, k_i, T_max, T_s, feedforward
    Z = {s.name: z[k] for k, s in enumerate(LOOP_STATE)}
    V = {s.name: v[k] for k, s in enumerate(INPUTS)}
    Q = {s.name: q[k] for k, s in enumerate(PARAMS)}
    n_q = len(PARAMS)
    emf_true = EmfSeries(orders, q[n_q : n_q + n_phi])
    emf_hat = EmfSeries(orders, q[n_q + n_phi : n_q + 2 * n_phi])
    motor = PmacParams(Q["R"], Q["L"], Q["J"], Q["B"], Q["p_r"])
    T_s, p_r = Q["T_s"], Q["p_r"]
    i_s, theta_m, w_m = z[0:2], Z["theta_m"], Z["w_m"]
    u_now = z[4:6]
    x_obs = z[len(LOOP_STATE) :]

    # measurement at t_k and the observer's estimates there
    i_meas = i_s + v[2:4]
    # the voltage "sampled" at t_k: the mean of the held voltages before and after t_k (module docstring)
    u_obs = (z[10:12] + u_now) / 2
    x_obs_next, w_hat, theta_hat, T_L_hat, e_hat, _phi_hat = step(x_obs, i_meas, u_obs, p_obs)

    sensor = Q["sensor"]
    theta_c = sensor * theta_m + (1 - sensor) * theta_hat
    w_f_next = low_pass_step(Z["w_f"], w_hat, Q["alpha_w"], T_s)
    w_c = sensor * w_m + (1 - sensor) * w_f_next

    # speed PI with the load feedforward and the references (25) along phî at the controller's angle
    phi_c = flux_derivative(theta_c, emf_hat)  # eq. (23)
    sc = speed_controller(V["w_ref"], w_c, Z["x_s"], T_L_hat, phi_c, gain[0], gain[1], gain[2], gain[4])
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
    x_pl = ca.vertcat(x_pl[0:2], wrap(x_pl[2]), x_pl[3])

    z_next = ca.vertcat(x_pl, u_next, cc.u_i_next, x_s_next, w_f_next, u_now, x_obs_next)
    phi = flux_derivative(theta_m, emf_true)
    e_true = phi * (w_m / p_r)  # eq. (3)
    rec = ca.vertcat(
        V["w_ref"],
        w_m,
        w_hat,
        theta_m,
        theta_hat,
        wrap(theta_m - theta_hat),
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
        f"drive002_loop_{step.name()}_{n_sub}",
        [z, v, q, p_obs, gain],
        [ca.cse(z_next), ca.cse(rec)],
        ["z", "v", "q", "p_obs", "gain"],
        ["z_next", "rec"],
    )
