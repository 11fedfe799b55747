"""An independent numpy/scipy model of the PM AC motor of De Angelo et al. (2006), for tests only.

The motor (2)-(5) with a stiff sensored speed PI and ideal current control: the current is the
ripple-free (25) of the PI's torque at the true position, so the voltage is v = R i + L di/dt + e.
Viscosity B omega loads the shaft. Integrated with scipy's DOP853 to 1e-11 and sampled every T_s.
:class:`ProfilePlant` follows a piecewise-linear speed reference instead of a constant one;
:func:`codegen_trajectory` is the recorded trajectory that the generated C is checked (tests) and timed
(benchmarks) on.
"""

import numpy as np


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
        return self.current_voltage(th, w, T_e, dT, T_L)

    def current_voltage(self, th, w, T_e, dT, T_L):
        """(i, v, T_L + B omega) of the ripple-free current (25) for torque T_e changing at dT."""
        phi, dphi = self.phi(th)
        n2 = (phi * phi).sum(0)
        i = T_e * phi / n2
        di = dT * phi / n2 + T_e * w * (dphi * n2 - 2 * phi * (phi * dphi).sum(0)) / n2**2
        v = self.R * i + self.L * di + phi * w / self.p_r
        return i, v, T_L + self.B * w / self.p_r

    def run(self, T_s, t_end, steps):
        """Samples at k T_s, k = 0..N, with T_L piecewise constant: steps = [(t_start, T_L), ...]."""
        from scipy.integrate import solve_ivp  # here: scipy.integrate is ~0.45 s of a worker's collection

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


class ProfilePlant(Plant):
    """The plant with a piecewise-linear speed reference and piecewise-constant load.

    ``segments`` = [(duration [s], w_ref from, w_ref to [electrical rad/s], T_L [N m]), ...]; the speed
    PI's torque T_e = k_p (w_ref - w) + x_i then changes at dT_e = k_p (dw_ref/dt - dw/dt) + k_i (w_ref - w).
    Each segment is integrated on its own (the reference's slope and the load jump at the joins).
    """

    def __init__(self, R, L, J, B, p_r, orders, Phi, segments, alpha=2 * np.pi * 5):
        super().__init__(R, L, J, B, p_r, orders, Phi, segments[0][1], alpha)
        self.segments = tuple(segments)

    def run_profile(self, T_s):
        """Samples at k T_s, k = 0..N (N T_s the total duration): t, Y (theta, w, x_i), i, v, T_L + B w."""
        from scipy.integrate import solve_ivp  # as in run

        N = round(sum(s[0] for s in self.segments) / T_s)
        t = np.arange(N + 1) * T_s
        Y, ref, slope, TL = np.empty((3, N + 1)), np.empty(N + 1), np.empty(N + 1), np.empty(N + 1)
        w0, T0 = self.segments[0][1], self.segments[0][3]
        y0 = np.array([0.3, w0, T0 + self.B * w0 / self.p_r])
        start = 0.0
        for n, (dur, wa, wb, T) in enumerate(self.segments):
            end = start + dur
            k = (wb - wa) / dur
            last = n == len(self.segments) - 1
            sel = (t >= start - 1e-12) & ((t < end - 1e-12) | last)

            def rhs(tt, y, wa=wa, k=k, start=start, T=T):
                _, w, x_i = y
                e = wa + k * (tt - start) - w
                dw = self.p_r * (self.k_p * e + x_i - T - self.B * w / self.p_r) / self.J
                return [w, dw, self.k_i * e]

            t_eval = np.r_[t[sel][t[sel] < end], end]
            sol = solve_ivp(rhs, (start, end), y0, method="DOP853", rtol=1e-11, atol=1e-11, t_eval=t_eval)
            Y[:, sel] = sol.y[:, : sel.sum()]
            ref[sel], slope[sel], TL[sel] = wa + k * (t[sel] - start), k, T
            y0, start = sol.y[:, -1], end
        th, w, x_i = Y
        e = ref - w
        T_e = self.k_p * e + x_i
        dw = self.p_r * (T_e - TL - self.B * w / self.p_r) / self.J
        dT = self.k_p * (slope - dw) + self.k_i * e
        i, v, T_obs = self.current_voltage(th, w, T_e, dT, TL)
        return t, Y, i, v, T_obs


# The trajectory that the generated C of the reduced-order observer is checked (tests) and timed
# (benchmarks) on: load steps both ways, speed ramps up and through zero to the other direction.
# Rows: (duration [s], speed reference from, to [r/min, mechanical], load T_L [N m]).
CODEGEN_SEGMENTS = (
    (0.25, 250, 250, 0.0),
    (0.3, 250, 250, 20.0),
    (0.3, 250, 400, 20.0),
    (0.3, 400, 400, -10.0),
    (0.6, 400, -300, -10.0),
    (0.3, -300, -300, 15.0),
    (0.3, -300, -300, -15.0),
    (0.25, -300, -100, 0.0),
)


def codegen_trajectory(drive, segments=CODEGEN_SEGMENTS):
    """The true motor of ``drive`` on ``segments``: dict with ``meas`` (N x 4: i_alpha, i_beta, u_alpha,
    u_beta at t_1..t_N, what the observer samples), ``w`` and ``theta`` (electrical) and ``T_L``
    (load plus viscosity) at the same instants."""
    m = drive.motor
    rows = [(d, float(drive.rpm_to_w(a)), float(drive.rpm_to_w(b)), T) for d, a, b, T in segments]
    plant = ProfilePlant(m.R, m.L, m.J, m.B, m.p_r, m.harmonics, m.Phi, rows)
    _, Y, i, v, T_obs = plant.run_profile(drive.control.T_s)
    return {
        "meas": np.ascontiguousarray(np.vstack([i, v])[:, 1:].T),
        "w": Y[1, 1:],
        "theta": Y[0, 1:],
        "T_L": T_obs[1:],
    }
