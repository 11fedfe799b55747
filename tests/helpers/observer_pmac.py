"""The reduced-order observer's runtime step fed by an independent plant (helpers/plant_pmac.py).

De Angelo et al. (2006) Figs. 2-4 in a short simulation: the plant's samples drive the same step that
runs and is generated to C.
"""

import casadi as ca
import numpy as np
from sensorless.symbolic.pmac_reduced_order.step import runtime_observer

from helpers.plant_pmac import Plant

T_STEP, T_END = 0.5, 1.5  # load step at 0.5 s; 8 time constants of the slow pole (-10.7 1/s) after it
WINDOW = 0.1  # averaging window at the end of each phase [s]


def simulate(drive, rpm, T_L, Gamma=None, method=None):
    """Observer fed by the plant's samples; returns (t, w, theta, T_L + B omega, w_hat, theta_hat,
    T_L_hat). The observer starts at the true EMF and speed with T_L_hat = 0."""
    m, T_s = drive.motor, drive.control.T_s
    w_ref = float(drive.rpm_to_w(rpm))
    plant = Plant(m.R, m.L, m.J, m.B, m.p_r, m.harmonics, m.Phi, w_ref)
    t, Y, i, v, T_obs = plant.run(T_s, T_END, [(0.0, 0.0), (T_STEP, T_L)])
    params = drive.observer_params(Gamma=Gamma)
    g, L, J, Gam = params[4], params[1], params[2], params[5]
    phi0, _ = plant.phi(Y[0, 0])
    e0 = phi0[:, 0] * Y[1, 0] / m.p_r
    zeta0 = e0 + g * L * i[:, 0]  # eq. (15) with the true EMF
    tau0 = 0.0 - Gam * L / J * phi0[:, 0] @ i[:, 0]  # eq. (15) with T_L_hat = 0
    x0 = np.r_[zeta0, tau0, Y[0, 0], Y[1, 0], i[:, 0], v[:, 0], 0]  # 0: no rejected sample
    F = runtime_observer(tuple(m.harmonics)).core(method or drive.control.discretization)
    x, u = ca.MX.sym("x", x0.size), ca.MX.sym("u", 4)
    x_next, y = F(x, u, params, ca.DM(0, 1))
    step = ca.Function("s", [x, u], [x_next, y[0:3]])  # w_hat, theta_hat, T_L_hat
    _, est = step.mapaccum(t.size - 1)(x0, np.vstack([i[:, 1:], v[:, 1:]]))
    est = np.asarray(est)
    return t[1:], Y[1, 1:], Y[0, 1:], T_obs[1:], est[0], est[1], est[2]


def window_mean(t, x, t_end):
    sel = (t > t_end - WINDOW) & (t <= t_end)
    return x[sel].mean()
