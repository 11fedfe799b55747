"""Linearized motor + adaptive-observer closed loop by automatic Jacobians; poles, G_c(s) of eq. (15).

``casadi.jacobian`` of the coupled motor+observer system (symbolic/ipmsm_adaptive/closed_loop.py)
gives, at any operating point, the state-space model from the true speed w_m to the speed estimate
w_hat: the closed loop of Piippo, Hinkkanen, Luomi (2008) Fig. 2 whose transfer function is G_c(s),
eq. (15). Sweeps over speed x torque are one call of ``Function.map``; eigenvalues of the stacked
matrices come from one batched numpy call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.ipmsm_adaptive.operating_point import (
    loop_parameters,
    rotor_frame_loop,
)
from sensorless.design.linearization import Linearization
from sensorless.design.noise import noise_rms
from sensorless.design.poles import eigvals_batched, sort_poles
from sensorless.design.rotor_frame import disturbance_function, equilibrium_points, pmsm_steady_current
from sensorless.symbolic.ipmsm_adaptive.gains import GainLaw, get_law

if TYPE_CHECKING:  # python-control imports scipy.signal and matplotlib (~3 s): only where used
    import control
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

STATE_NAMES = ("psi_hat_d", "psi_hat_q", "theta_tilde", "w_i", "x_eps")


def gain_parameters(
    drive: IpmsmDrive, gain: str | tuple[str | GainLaw, Any] | None = None
) -> tuple[GainLaw, np.ndarray]:
    """Resolve a gain choice to (law, parameter vector of the law's width).

    ``gain`` is the name of an ``[observer.gains.*]`` table of the drive (default: ``[observer]
    gain``), or an explicit ``(law, params)`` pair, e.g. ``("speed", [7.18, 471.2])`` or
    ``(schedule_law(grid), [lambda1..., lambda2...])``.
    """
    if isinstance(gain, tuple):
        law = get_law(gain[0])
        vals = np.asarray(gain[1], float).ravel()
    else:
        g = drive.gain(gain)
        law = get_law(gain or drive.observer.gain)
        vals = np.array([getattr(g, n) for n in law.param_names], float)
    if vals.size != law.n_params:
        raise ValueError(f"gain law {law.name} takes {law.n_params} parameters, got {vals.size}")
    vec = np.zeros(law.width)
    vec[: vals.size] = vals
    return law, vec


def drive_arguments(drive: IpmsmDrive, gain: str | tuple | None) -> tuple[GainLaw, dict[str, np.ndarray]]:
    """The non-operating-point inputs of the analysis Functions for ``drive``."""
    law, gvec = gain_parameters(drive, gain)
    inj = drive.injection
    args = {
        "motor": np.array(drive.motor.vector()),
        "p": np.array(float(drive.motor.p)),
        "estimate": np.array(drive.estimate.vector()),
        "gain": gvec,
        "alpha_fo": np.array(drive.observer.alpha_fo),
        "inj": np.array([inj.w_c, inj.u_c, inj.alpha_i, inj.w_Delta]),
    }
    return law, args


@dataclass(frozen=True, kw_only=True)
class PoleSweep(Linearization):
    """Linearized closed loops at N operating points (w: true speed w_m, torque: T_e), with their
    state-space models from w_m to w_hat (arrays have leading dimension N)."""

    law: GainLaw
    injection: bool
    x0: np.ndarray  # equilibrium states (N, n)
    i_s0: np.ndarray  # MTPA current, rotor frame (N, 2) [A]
    A: np.ndarray  # (N, n, n)
    B: np.ndarray  # (N, n, 1)
    C: np.ndarray  # (N, 1, n)
    D: np.ndarray  # (N, 1, 1)
    noise_input: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (B_n, C_n, D_n), see noise_rms
    # the drive's current-sensor noise [A rms per axis and sample] and period [s] with noise_input
    noise_sigma: tuple[float, float] | None = None

    def point_columns(self) -> dict[str, np.ndarray]:
        """The operating point's MTPA current (rotor frame) [A]."""
        return {"i_d_A": self.i_s0[:, 0], "i_q_A": self.i_s0[:, 1]}

    def notes(self) -> tuple[str, ...]:
        """The gain law and the HF-injection switch of the sweep."""
        return (f"gain law: {self.law.name}", f"injection: {'on' if self.injection else 'off'}")

    def angle_bias(self) -> np.ndarray:
        """(N,) equilibrium position error theta_tilde [rad] under the estimates linearized with."""
        return self.x0[:, STATE_NAMES.index("theta_tilde")]

    def low_speed_decay(self) -> np.ndarray:
        """(N,) decay rate [1/s] of the slowest mode that moves the estimates: with injection, a mode
        living in the PI state x_eps alone (eigenvector over 99 % in it: the PI pole heading for the
        origin as the injection fades out towards w_Delta) is left out."""
        if not self.injection:
            return self.decay_rate
        out = self.decay_rate.copy()
        ok = np.isfinite(self.A).all(axis=(1, 2)) & ~np.all(self.A[:, 4, :] == 0, axis=1)
        if ok.any():
            lam, vec = np.linalg.eig(self.A[ok])
            share = np.abs(vec[:, 4, :]) / np.linalg.norm(vec, axis=1)
            re = np.where(share > 0.99, -np.inf, lam.real)
            out[ok] = -re.max(axis=1)
        return out

    def angle_noise(self) -> np.ndarray | None:
        """(N,) RMS position error [rad] from the drive's current-sensor noise (``noise=True``)."""
        if self.noise_sigma is None or self.noise_input is None:
            return None
        out = self.noise_rms(*self.noise_sigma)[:, 0]
        if self.injection:  # above w_Delta the PI state x_eps is frozen (zero row): its 4 poles
            frozen = np.isfinite(self.A).all(axis=(1, 2)) & np.all(self.A[:, 4, :] == 0, axis=1)
            if frozen.any():
                B, C, D = (a[frozen] for a in self.noise_input)
                A = self.A[frozen][:, :4, :4]
                out[frozen] = noise_rms(A, B[:, :4], C[:, :, :4], D, *self.noise_sigma)[:, 0]
        return out

    def noise_rms(self, sigma: float, T_s: float) -> np.ndarray:
        """(N, 2) RMS of the position error [rad] and the speed estimate [rad/s] for current-sensor
        noise of ``sigma`` A rms per axis and sample at ``T_s`` (design/noise.py); needs
        ``linearize(..., noise=True)``. inf where unstable."""
        if self.noise_input is None:
            raise ValueError("linearized without noise=True")
        B, C, D = self.noise_input
        n = B.shape[1]
        # the poles are A's eigenvalues (without injection: with it, a frozen point's PI pole is NaN):
        # where they clearly decide stability, LAPACK's eigenvalues are not computed again (the same
        # decision, design/noise.py; 2618 points of the report's envelope per gain set)
        poles = None if self.injection else self.poles
        return noise_rms(self.A[:, :n, :n], B, C, D, sigma, T_s, poles=poles)

    def statespace(self, k: int) -> control.StateSpace:
        """The closed loop at point k as a python-control StateSpace, input w_m, output w_hat."""
        import control

        n = self.A.shape[1]
        return control.ss(
            self.A[k],
            self.B[k],
            self.C[k],
            self.D[k],
            inputs=["w_m"],
            outputs=["w_hat"],
            states=list(STATE_NAMES[:n]),
        )

    def transfer_function(self, k: int) -> control.TransferFunction:
        """G_c(s) = w_hat(s)/w_m(s) at point k, eq. (15)."""
        import control

        return control.ss2tf(self.statespace(k))

    @property
    def acceleration_lag(self) -> np.ndarray:
        """(N,) steady position error per unit of speed ramp [rad per rad/s^2]: -[A^-2 B]_theta_tilde.

        Under w_m = a t the loop (of type 2: no steady error at constant speed) settles to
        theta_tilde = a * acceleration_lag. NaN where A is singular or undefined.
        """
        out = np.full(self.A.shape[0], np.nan)
        ok = np.isfinite(self.A).all(axis=(1, 2)) & (np.abs(np.linalg.det(self.A)) > 0)
        if ok.any():
            x = np.linalg.solve(self.A[ok], np.linalg.solve(self.A[ok], self.B[ok]))
            out[ok] = -x[:, STATE_NAMES.index("theta_tilde"), 0]
        return out


def operating_points(w_m: Any, T_e: Any, estimate: Any = None) -> tuple[np.ndarray, np.ndarray, Any]:
    """(w, T_e) broadcast and flattened (row-major), and the estimates (4, N) broadcast with them (None
    if ``estimate`` is None): the points of :func:`linearize`."""
    if estimate is None:
        w_b, T_b = np.broadcast_arrays(np.asarray(w_m, float), np.asarray(T_e, float))
        return w_b.ravel(), T_b.ravel(), None
    est = np.asarray(estimate, float)
    w_b, T_b, _ = np.broadcast_arrays(np.asarray(w_m, float), np.asarray(T_e, float), est[..., 0])
    return w_b.ravel(), T_b.ravel(), np.broadcast_to(est, (*w_b.shape, 4)).reshape(-1, 4).T


def linearize(
    drive: IpmsmDrive,
    w_m: Any,
    T_e: Any,
    gain: str | tuple | None = None,
    injection: bool = False,
    estimate: Any = None,
    noise: bool = False,
) -> PoleSweep:
    """Linearize the coupled system at the operating points (w_m [rad/s], T_e [N m]).

    ``w_m`` and ``T_e`` broadcast against each other; the result is flat over the broadcast shape
    (row-major). ``estimate`` optionally gives the observer's parameter estimates per point, an
    array (..., 4) of [R̂s, L̂d, L̂q, ψ̂pm] broadcasting with the operating points (default: the
    drive's ``[estimate]``), so robustness maps over parameter errors are one call. Points where no
    equilibrium exists (possible with estimation errors) get NaN. ``noise`` also evaluates the input
    from current-measurement noise (the loop's ``disturbance``, ``PoleSweep.noise_rms``). The discrete-time
    observer that runs is analysed beside this by one_step.py (its ``linearize`` takes a
    ``discretization``).
    """
    w_flat, T_flat, est = operating_points(w_m, T_e, estimate)
    n_pts = w_flat.size
    law, args = drive_arguments(drive, gain)
    if estimate is not None:
        args["estimate"] = np.ascontiguousarray(est)
    plant, p = loop_parameters(args, n_pts)
    # exact estimates: the closed form at every point, in one Function (rotor_frame start_function)
    eq = equilibrium_points(rotor_frame_loop(law, injection), w_flat, T_flat, plant, p)
    A, x0 = eq.A, eq.x
    poles = np.full(x0.shape, np.nan + 0j)
    frozen = np.zeros(n_pts, bool)
    if injection:
        # Above w_Delta the injection is off (fade = 0): the PI integrator x_eps has no input and
        # its row of A is zero. Its structural pole at the origin says nothing about stability;
        # report it as NaN and analyse the adaptive observer's four poles.
        frozen = eq.ok & np.all(A[:, 4, :] == 0, axis=1)
        if frozen.any():
            poles[frozen, :4] = sort_poles(eigvals_batched(A[frozen][:, :4, :4]))
    rest = eq.ok & ~frozen
    if rest.any():
        poles[rest] = sort_poles(eq.poles(rest)[rest])
    noise_input = None
    if noise:
        nf = disturbance_function(rotor_frame_loop(law, injection))
        xs = np.where(np.isfinite(x0), x0, 0.0).T
        B_n, C_n, D_n = evaluate_batch(nf, n_pts, [xs, w_flat[None, :], T_flat[None, :], plant, p])
        bad = ~np.isfinite(x0).all(axis=1)
        B_n[bad] = np.nan
        noise_input = (B_n, C_n, D_n)
    return PoleSweep(
        noise_input=noise_input,
        noise_sigma=(float(drive.control.i_noise), float(drive.control.T_s)) if noise else None,
        law=law,
        injection=injection,
        w=w_flat,
        torque=T_flat,
        x0=x0,
        i_s0=pmsm_steady_current(T_flat, plant),  # plant = [motor, p]: design/rotor_frame.py pmsm_plant
        A=A,
        B=eq.B,
        C=eq.C,
        D=eq.D,
        poles=poles,
    )


def refine_band_edges(
    f_unstable: Any, lo: np.ndarray, hi: np.ndarray, iters: int = 40, depth: int = 4
) -> np.ndarray:
    """Bisect each bracket [lo, hi] (stability differs at the ends) to the switching speed.

    ``depth`` bisection steps per call of ``f_unstable``: it is given every midpoint those steps could
    visit (the 2^depth - 1 nodes of each bracket's bisection tree, each computed as the bisection would
    compute it), and the bisection then follows its path through them: the same speeds, the same
    result, in a quarter of the calls (each a linearization whose fixed cost outweighs its few points:
    ~0.4 s CPU of a report's band edges). Fewer steps per call where the nodes would reach 64 points,
    the batch size from which the eigenvalues take another path (design/poles.py)."""
    s_lo = f_unstable(lo)
    done = 0
    while done < iters:
        k = min(depth, iters - done)
        while k > 1 and lo.size * (2**k - 1) >= 64:
            k -= 1
        n_nodes = 2**k - 1
        # node j's bracket; its children: 2j + 1 (the midpoint as stable as lo: lo moves), 2j + 2 (hi moves)
        t_lo = np.empty((n_nodes, lo.size))
        t_hi = np.empty((n_nodes, lo.size))
        t_lo[0], t_hi[0] = lo, hi
        mids = np.empty((n_nodes, lo.size))
        for j in range(n_nodes):
            mids[j] = 0.5 * (t_lo[j] + t_hi[j])
            if 2 * j + 2 < n_nodes:
                t_lo[2 * j + 1], t_hi[2 * j + 1] = mids[j], t_hi[j]
                t_lo[2 * j + 2], t_hi[2 * j + 2] = t_lo[j], mids[j]
        s_mid = np.asarray(f_unstable(mids.ravel())).reshape(n_nodes, lo.size)
        node = np.zeros(lo.size, int)
        cols = np.arange(lo.size)
        for _ in range(k):
            mid = mids[node, cols]
            same = s_mid[node, cols] == s_lo
            lo = np.where(same, mid, lo)
            hi = np.where(same, hi, mid)
            node = np.where(same, 2 * node + 1, 2 * node + 2)
        done += k
    return 0.5 * (lo + hi)


def unstable_speed_bands(
    drive: IpmsmDrive,
    w: np.ndarray,
    T_e: float,
    gain: str | tuple | None = None,
    injection: bool = False,
    sweep: PoleSweep | None = None,
) -> list[tuple[float, float]]:
    """Speed intervals [rad/s] with a right-half-plane pole at torque T_e, edges refined by bisection.

    ``w`` is the sorted speed grid that brackets the bands; ``sweep`` may pass its linearization.
    An edge at the end of the grid is reported as the grid end.
    """
    s = sweep if sweep is not None else linearize(drive, w, T_e, gain=gain, injection=injection)
    tol = 1e-9 * np.nanmax(np.abs(s.poles))

    def unstable(ws: np.ndarray) -> np.ndarray:
        return linearize(drive, ws, T_e, gain=gain, injection=injection).max_real > tol

    bands = [list(b) for b in unstable_bands(w, s.max_real, tol)]
    # every edge inside the grid, bisected together: one linearization per step for all of them
    where, lo, hi = [], [], []
    for k, (lo_w, hi_w) in enumerate(bands):
        i_lo, i_hi = int(np.searchsorted(w, lo_w)), int(np.searchsorted(w, hi_w))
        if i_lo > 0:
            where.append((k, 0))
            lo.append(w[i_lo - 1])
            hi.append(w[i_lo])
        if i_hi < w.size - 1:
            where.append((k, 1))
            lo.append(w[i_hi + 1])
            hi.append(w[i_hi])
    if where:
        for (k, side), x in zip(where, refine_band_edges(unstable, np.array(lo), np.array(hi)), strict=True):
            bands[k][side] = float(x)
    return [(a, b) for a, b in bands]


def unstable_bands(w: np.ndarray, max_real: np.ndarray, tol: float = 1e-9) -> list[tuple[float, float]]:
    """Contiguous speed intervals (on the sorted grid ``w``) where max Re(pole) > tol."""
    bad = max_real > tol
    bands = []
    i = 0
    while i < len(w):
        if bad[i]:
            j = i
            while j + 1 < len(w) and bad[j + 1]:
                j += 1
            bands.append((float(w[i]), float(w[j])))
            i = j + 1
        else:
            i += 1
    return bands
