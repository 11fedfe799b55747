"""An independent numpy/scipy model of the paper-002 motor for tests (not the package's symbolic one).

The motor (2)-(5) with a stiff sensored speed PI and ideal current control: the current is the
ripple-free (25) of the PI's torque at the true position, so the voltage is v = R i + L di/dt + e.
Viscosity B omega loads the shaft. Integrated with scipy's DOP853 to 1e-11 and sampled every T_s.
"""

import numpy as np
from scipy.integrate import solve_ivp


class Plant:
    def __init__(self, R, L, J, B, p_r, orders, Phi, w_ref, alpha=2 * np.pi * 5):
        self.R, self.L, self.J, self.B, self.p_r = R, L, J, B, p_r
        self.n = np.asarray(orders, float)[:, None]
        self.Phi = np.asarray(Phi, float)[:, None]
        self.w_ref = w_ref
        # PI on the electrical speed with a double pole at -alpha for dw/dt = p_r (T - T_L) / J
        self.k_p, self.k_i = 2 * alpha * J / p_r, alpha**2 * J / p_r

    def phi(self, th):
        th = np.atleast_1d(th)[None, :]
        s, c = np.sin(self.n * th), np.cos(self.n * th)
        phi = np.vstack([-(self.Phi * s).sum(0), (self.Phi * c).sum(0)])
        dphi = np.vstack([-(self.n * self.Phi * c).sum(0), -(self.n * self.Phi * s).sum(0)])
        return phi, dphi

    def torque(self, w, x_i):
        return self.k_p * (self.w_ref - w) + x_i

    def rhs(self, t, y, T_L):
        _, w, x_i = y
        T_e = self.torque(w, x_i)
        dw = self.p_r * (T_e - T_L - self.B * w / self.p_r) / self.J
        return [w, dw, self.k_i * (self.w_ref - w)]

    def signals(self, y, T_L):
        """Current, voltage and the load the observer should see, at states y (3 x N)."""
        th, w, x_i = y
        T_e = self.torque(w, x_i)
        dw = self.p_r * (T_e - T_L - self.B * w / self.p_r) / self.J
        dT = -self.k_p * dw + self.k_i * (self.w_ref - w)
        phi, dphi = self.phi(th)
        n2 = (phi * phi).sum(0)
        i = T_e * phi / n2
        di = dT * phi / n2 + T_e * w * (dphi * n2 - 2 * phi * (phi * dphi).sum(0)) / n2**2
        v = self.R * i + self.L * di + phi * w / self.p_r
        return i, v, T_L + self.B * w / self.p_r

    def run(self, T_s, t_end, steps):
        """Samples at k T_s, k = 0..N, with T_L piecewise constant: steps = [(t_start, T_L), ...]."""
        N = round(t_end / T_s)
        t = np.arange(N + 1) * T_s
        y0 = [0.3, self.w_ref, steps[0][1] + self.B * self.w_ref / self.p_r]
        Y = np.empty((3, N + 1))
        TL = np.empty(N + 1)
        bounds = [s[0] for s in steps[1:]] + [t[-1] + T_s]
        start = 0.0
        for (t0, T), t1 in zip(steps, bounds, strict=True):
            sel = (t >= t0 - 1e-12) & (t < t1 - 1e-12)
            sol = solve_ivp(
                self.rhs,
                (start, t[sel][-1]),
                y0,
                args=(T,),
                method="DOP853",
                rtol=1e-11,
                atol=1e-11,
                t_eval=t[sel],
                dense_output=False,
            )
            Y[:, sel], TL[sel] = sol.y, T
            y0, start = sol.y[:, -1], t[sel][-1]
        i, v, T_obs = self.signals(Y, TL)
        return t, Y, i, v, T_obs
