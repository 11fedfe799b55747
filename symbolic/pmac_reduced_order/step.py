"""Runtime step of the reduced-order EMF + load-torque observer: what simulation runs and codegen emits as C.

The step integrates the observer ODE (16) over the sampling interval [t_(k-1), t_k] and returns the
estimates at t_k, after the current i_k and voltage u_k have been sampled (both measured, as in the
paper). It keeps the previous samples in its state so every scheme can use both ends of the interval:

    x = [zeta_a, zeta_b, tau, theta_hat, w_hat, i_a_prev, i_b_prev, u_a_prev, u_b_prev]

``theta_hat``/``w_hat`` are the previous estimates, needed by the harmonic removal (19)-(21) and the
speed sign (14). The right-hand side is evaluated by
:func:`~sensorless.symbolic.pmac_reduced_order.observer.observer_rhs` only; the schemes differ in
where they evaluate it (docs/families/pmac_reduced_order.md, "Discretization"):

- ``euler``: forward Euler at the start of the interval (t_(k-1), i_(k-1), u_(k-1)).
- ``rk2-hold``: Heun's RK2 with the inputs held at the interval's first samples (what integrating
  forward from the newest sample gives: the input at the end of the step is not yet measured).
- ``rk2``: Heun's RK2 as in the textbook, each stage with the samples at its own time (t_(k-1), t_k):
  the paper's "second-order Runge-Kutta method" taken literally.
- ``midpoint``: the midpoint RK2, the middle stage with the mean of the two samples.
- ``rk2-rotating``: ``rk2`` in a frame that rotates at the previous speed estimate. The EMF state
  rotates at the electrical speed; a polynomial scheme in the stationary frame makes a small error per
  step that the load-torque integrator (and the speed (13)) turn into a steady bias. In the rotating
  frame a sinusoidal steady state is constant and the scheme is exact there.
- ``rk2-model`` (default): ``rk2-rotating`` around the observer model's own steady motion: the EMF the
  model predicts from the previous estimates, (w_hat/p_r) phi(theta_hat + w_hat t) by (3)-(4), harmonics
  included, is propagated exactly and Heun integrates only the (small, slow) remainder. Exact in the
  steady state of a sinusoidal motor, and far more accurate than the others with EMF harmonics.

Measured steady-state errors of each scheme are in docs/families/pmac_reduced_order.md.

The state's zeta/tau are the paper's (15); the position is the electrical angle in (-pi, pi].

As a runtime observer (:func:`runtime_observer`, the contract of symbolic/runtime.py) the step takes
``meas`` = [i_alpha, i_beta, u_alpha, u_beta] sampled at t_k and every parameter, the gains g and Gamma
and the EMF series Phi_n included, in ``p``: firmware can retune them without regenerating code. The
harmonic *orders* shape the expression and are fixed per generated observer. A sample whose result is
not finite, or whose speed estimate leaves the range the step is valid in (|w_hat| T_s <= pi/2, where
the speed sign (14) reads the angle step modulo pi), is rejected (output ``valid`` = 0): the observer
coasts, its EMF state turning at the speed estimate and its angle advancing by w_hat T_s, and keeps the
newest finite samples for the next period. Both matter after an absurd but finite sample (an ADC
glitch of 1e5 A): accepting a speed beyond the range, or keeping a glitch that an accepted period
stored, would make every later period diverge and be rejected, for good. When the counter of rejected
samples (up per rejected, down per accepted sample) reaches RESET_AFTER, the step starts afresh from the
initial state (output ``reset``; the contract's recovery, symbolic/runtime.py).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import J, Sym, rot, wrap_angle
from sensorless.symbolic.pmac import EmfSeries, flux_derivative, flux_derivative_slope
from sensorless.symbolic.pmac import emf as emf_of
from sensorless.symbolic.pmac_reduced_order.observer import (
    Estimates,
    ObserverParams,
    emf_from_zeta,
    emf_fundamental,
    estimates,
    load_torque_from_tau,
    observer_rhs,
    speed_sign,
)
from sensorless.symbolic.runtime import (
    REJECTS,
    RESET,
    VALID,
    Field,
    RuntimeObserver,
    all_within,
    core_function,
    guarded,
)

DISCRETIZATIONS: dict[str, str] = {
    "euler": "forward Euler at the interval start",
    "rk2-hold": "Heun RK2, inputs held at the interval start",
    "rk2": "Heun RK2, samples at both interval ends (textbook, literal)",
    "midpoint": "midpoint RK2, mean of the two samples at mid-interval",
    "rk2-rotating": "Heun RK2 in the frame rotating at the speed estimate",
    "rk2-model": "Heun RK2 around the model's exactly propagated EMF, rotating frame (default)",
}
DEFAULT_DISCRETIZATION = "rk2-model"

N_STATE = 9  # of step(): [zeta_a, zeta_b, tau, theta_hat, w_hat, i_a_prev, i_b_prev, u_a_prev, u_b_prev]


def param_names(orders: tuple[int, ...]) -> tuple[str, ...]:
    """Names of the ``params`` entries: R, L, J, p_r, g, Gamma, T_s, T_max, then Phi_n of each order."""
    return tuple(f.name for f in params_fields(tuple(orders)))


def split_params(params: Sym, orders: tuple[int, ...]) -> tuple[ObserverParams, EmfSeries, Sym]:
    """(observer parameters, EMF series, T_s) from the ``params`` vector."""
    p = ObserverParams(params[0], params[1], params[2], params[3], params[4], params[5])
    n = len(_BASE_PARAMS)
    return p, EmfSeries(tuple(orders), params[n : n + len(orders)]), params[6]


class Step(NamedTuple):
    """The states at t_k and the estimates there."""

    x_next: Sym
    est: Estimates


def integrate(
    x: Sym, i: Sym, u: Sym, p: ObserverParams, emf: EmfSeries, T_s: Sym, method: str
) -> tuple[Sym, Sym]:
    """(zeta_k, tau_k) from the states at t_(k-1) with the chosen scheme (module docstring)."""
    zeta0, tau0, th0, w0 = x[0:2], x[2], x[3], x[4]
    i0, u0 = x[5:7], x[7:9]
    sigma0 = ca.if_else(w0 >= 0, 1, -1)  # speed sign during the step: the previous one, eq. (14)

    def f(zeta: Sym, tau: Sym, i_s: Sym, u_s: Sym, dt: Sym) -> tuple[Sym, Sym]:
        # stage at t_(k-1) + dt: harmonics predicted at theta_hat_(k-1) + w_hat_(k-1) dt, eqs. (20)-(21)
        dz, dtau, _ = observer_rhs(zeta, tau, i_s, u_s, th0 + w0 * dt, w0, sigma0, p, emf)
        return dz, dtau

    k1z, k1t = f(zeta0, tau0, i0, u0, 0)
    if method == "euler":
        return zeta0 + T_s * k1z, tau0 + T_s * k1t
    if method in ("rk2", "rk2-hold"):
        i1, u1 = (i, u) if method == "rk2" else (i0, u0)
        k2z, k2t = f(zeta0 + T_s * k1z, tau0 + T_s * k1t, i1, u1, T_s)
        return zeta0 + T_s / 2 * (k1z + k2z), tau0 + T_s / 2 * (k1t + k2t)
    if method == "midpoint":
        kmz, kmt = f(zeta0 + T_s / 2 * k1z, tau0 + T_s / 2 * k1t, (i0 + i) / 2, (u0 + u) / 2, T_s / 2)
        return zeta0 + T_s * kmz, tau0 + T_s * kmt
    if method in ("rk2-rotating", "rk2-model"):
        # zeta = E(dt) + R(w0 dt) z. "rk2-rotating": E = 0, z is zeta in the frame rotating at w0.
        # "rk2-model": E(dt) = (w0/p_r) phi(th0 + w0 dt) is the observer model's own steady EMF
        # (eqs. (3), (4) at the estimates), propagated exactly; Heun integrates only the remainder z.
        if method == "rk2-model":

            def E(dt: Sym) -> Sym:
                return emf_of(th0 + w0 * dt, w0, emf, p.p_r)  # eq. (3) at the estimates

            def dE(dt: Sym) -> Sym:
                return flux_derivative_slope(th0 + w0 * dt, emf) * (w0 * w0 / p.p_r)
        else:

            def E(dt: Sym) -> Sym:
                return ca.DM.zeros(2)

            dE = E
        R1 = rot(w0 * T_s)
        z0 = zeta0 - E(0)
        # dz/dt = R(-w0 dt) (dzeta/dt - dE/dt) - w0 J z
        s1 = k1z - dE(0) - w0 * (J @ z0)
        z_pred = z0 + T_s * s1
        k2z, k2t = f(E(T_s) + R1 @ z_pred, tau0 + T_s * k1t, i, u, T_s)
        s2 = R1.T @ (k2z - dE(T_s)) - w0 * (J @ z_pred)
        return E(T_s) + R1 @ (z0 + T_s / 2 * (s1 + s2)), tau0 + T_s / 2 * (k1t + k2t)
    raise ValueError(f"unknown discretization {method!r} (known: {', '.join(DISCRETIZATIONS)})")


def step(x: Sym, i: Sym, u: Sym, params: Sym, orders: tuple[int, ...], method: str) -> Step:
    """One sampling period: integrate (16) over [t_(k-1), t_k], then the estimates at t_k."""
    p, emf, T_s = split_params(params, orders)
    zeta, tau = integrate(x, i, u, p, emf, T_s, method)
    th0, w0 = x[3], x[4]
    theta_pred = th0 + w0 * T_s  # eq. (21)
    e1 = emf_fundamental(emf_from_zeta(zeta, i, p), theta_pred, w0, p.p_r, emf)  # eqs. (17), (19)-(22)
    sigma = speed_sign(ca.atan2(-e1[0], e1[1]), th0)  # eq. (14)
    est = estimates(zeta, tau, i, theta_pred, w0, sigma, p, emf)
    x_next = ca.vertcat(zeta, tau, est.theta_hat, est.w_hat, i, u)
    return Step(x_next, est)


# --------------------------------------------------------------------------------------------------
# As a runtime observer (symbolic/runtime.py)
# --------------------------------------------------------------------------------------------------
# the runtime state: step()'s, then the contract's counter. Bounds: the angle wrapped, the speed within
# the range the step is valid in (|w_hat| T_s <= pi/2, where the speed sign (14) reads the angle step
# modulo pi), the load state within twice what the torque limit gives it (|T_L_hat| <= T_max and
# |phi_hat . i| <= T_max in (15)); the EMF state and the stored samples only finite
_TAU_BOUND = "2 * (1 + Gamma * L / J) * T_max"
STATE = (
    Field("zeta_a", "V", "EMF state zeta = e_hat + g L i, eq. (15), alpha axis"),
    Field("zeta_b", "V", "EMF state, beta axis"),
    Field("tau", "N m", "load state tau = T_L_hat - (Gamma L / J) phi_hat . i, eq. (15)", bound=_TAU_BOUND),
    Field("theta", "rad", "position estimate theta_hat (electrical), in (-pi, pi], eq. (18)", bound="pi"),
    Field("w_hat", "rad/s", "speed estimate (electrical), eqs. (13)-(14)", bound="pi / 2 / T_s"),
    Field("i_a_prev", "A", "current sample of the previous period, alpha axis"),
    Field("i_b_prev", "A", "current sample of the previous period, beta axis"),
    Field("u_a_prev", "V", "voltage sample of the previous period, alpha axis"),
    Field("u_b_prev", "V", "voltage sample of the previous period, beta axis"),
    REJECTS,
)

MEAS = (
    Field("i_alpha", "A", "stator current at t_k, stationary frame"),
    Field("i_beta", "A", "stator current at t_k, stationary frame"),
    Field("u_alpha", "V", "stator voltage at t_k, stationary frame"),
    Field("u_beta", "V", "stator voltage at t_k, stationary frame"),
)

_BASE_PARAMS = (
    Field("R", "ohm", "stator resistance estimate", "positive"),
    Field("L", "H", "inductance estimate", "positive"),
    Field("J", "kg m^2", "inertia estimate (units of the reading of eq. (2))", "positive"),
    Field("p_r", "1", "speed in eq. (2) per electrical speed (pole pairs, or 1)", "positive"),
    Field("g", "1/s", "EMF observer gain, eq. (9)", "positive"),
    Field("Gamma", "A^2 s^2", "load-torque adaptation gain, eq. (10) (0: no load estimation)", "nonnegative"),
    Field("T_s", "s", "sampling period", "positive"),
    Field("T_max", "N m", "torque limit of the drive: the load state's bound", "positive"),
)

OUTPUTS = (
    Field("w_hat", "rad/s", "speed estimate at t_k (electrical), eqs. (13)-(14)"),
    Field("theta_hat", "rad", "position estimate at t_k (electrical), in (-pi, pi], eq. (18)"),
    Field("T_L_hat", "N m", "load-torque estimate (viscosity included), eq. (17)"),
    Field("e_alpha", "V", "EMF estimate, alpha axis, eq. (17)"),
    Field("e_beta", "V", "EMF estimate, beta axis"),
    Field("phi_alpha", "V s", "flux derivative phi(theta_hat), eq. (23): direction of the references (25)"),
    Field("phi_beta", "V s", "flux derivative phi(theta_hat), beta axis"),
    VALID,
    RESET,
)


def params_fields(orders: tuple[int, ...]) -> tuple[Field, ...]:
    """The ``p`` fields: R, L, J, p_r, g, Gamma, T_s, T_max, then Phi_n of each harmonic order."""
    phi = tuple(
        Field(
            f"Phi_{n}" if n > 0 else f"Phi_m{-n}",
            "V s",
            f"EMF harmonic amplitude of order {n}, eq. (4)" + (" (the fundamental)" if n == 1 else ""),
            "positive" if n == 1 else "any",
        )
        for n in orders
    )
    return _BASE_PARAMS + phi


def _runtime_step(method: str, orders: tuple[int, ...], x: Sym, meas: Sym, p: Sym) -> tuple[Sym, Sym]:
    """(x_next, y) of one guarded period: :func:`step`, or coasting on a rejected sample."""
    i, u = meas[0:2], meas[2:4]
    s = step(x, i, u, p, orders, method)
    e = s.est
    y = ca.vertcat(e.w_hat, e.theta_hat, e.T_L_hat, e.e_hat, e.phi_hat)
    # coasting: the EMF (and zeta with it) turns at the speed estimate, the angle advances by w T_s;
    # the stored samples become this period's if they are finite (else stay those of the last period
    # that had finite ones): a glitch stored by an accepted period must not poison every later one
    par, emf, T_s = split_params(p, orders)
    w0 = x[4]
    R = rot(w0 * T_s)
    theta_c = wrap_angle(x[3] + w0 * T_s)
    zeta_c = R @ x[0:2]
    x_coast = ca.vertcat(zeta_c, x[2], theta_c, w0, ca.if_else(all_within(meas), meas, x[5:9]))
    phi_c = flux_derivative(theta_c, emf)
    y_coast = ca.vertcat(
        w0,
        theta_c,
        load_torque_from_tau(x[2], phi_c, x[5:7], par),
        emf_from_zeta(zeta_c, R @ x[5:7], par),
        phi_c,
    )
    # accepted: finite, and the speed within the step's range |w_hat| T_s <= pi/2 (the bound of w_hat:
    # beyond it the discrete observer diverges, so a state accepted there could never be left again)
    cand, coast = (s.x_next, y), (x_coast, y_coast)
    return guarded(x, p, STATE, params_fields(orders), cand=cand, coast=coast, reset=ca.DM.zeros(len(STATE)))


@functools.cache
def runtime_observer(orders: tuple[int, ...] = (1,)) -> RuntimeObserver:
    """The observer for an EMF series of harmonic ``orders`` as a runtime observer (one per series)."""
    orders = tuple(int(n) for n in orders)
    fields = params_fields(orders)
    tag = "_".join(str(n) if n > 0 else f"m{-n}" for n in orders)

    @functools.cache
    def core(discretization: str = DEFAULT_DISCRETIZATION) -> ca.Function:
        if discretization not in DISCRETIZATIONS:
            known = ", ".join(DISCRETIZATIONS)
            raise ValueError(f"unknown discretization {discretization!r} (known: {known})")
        step = functools.partial(_runtime_step, discretization, orders)
        name = f"pmac_reduced_order_{tag}_core_{discretization.replace('-', '_')}"
        return core_function(name, step, STATE, MEAS, fields)

    @functools.cache
    def initial_state() -> ca.Function:
        # at rest at theta_hat = 0 with w_hat = 0: the EMF states zero, no load estimate
        p = ca.SX.sym("p", len(fields))
        return ca.Function(f"pmac_reduced_order_{tag}_init", [p], [ca.DM.zeros(len(STATE))], ["p"], ["x0"])

    return RuntimeObserver(
        name=f"pmac_reduced_order_{tag}",
        title="extended reduced-order EMF and load-torque observer (De Angelo et al. 2006)",
        state=STATE,
        meas=MEAS,
        params=fields,
        outputs=OUTPUTS,
        lam=(),
        schedule_state=None,
        core=core,
        initial_state=initial_state,
        discretizations=tuple(sorted(DISCRETIZATIONS, key=lambda m: m != DEFAULT_DISCRETIZATION)),
        doc_init="every state 0: theta_hat = 0, w_hat = 0, no EMF and no load estimate",
        doc_in="current and voltage sampled now (stationary frame)",
        doc_out="speed, angle, load-torque and EMF estimates now, phi_hat for the references (25)",
    )
