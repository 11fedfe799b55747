"""Equations of the back-EMF PLL observer for non-salient PMSMs, and its runtime step (symbolic layer).

The observer (a textbook structure: S.-K. Sul, *Control of Electric Machine Drive Systems*, Wiley-IEEE
Press 2011, chapter on sensorless control, back-EMF estimation with a PLL; the PLL-type position and
speed estimator of L. Harnefors and H.-P. Nee, "A general algorithm for speed and position estimation
of AC motors", IEEE Trans. Ind. Electron. 47(1):77-83, 2000), in the stationary frame, speeds
electrical:

- motor (non-salient, L_d = L_q = L):  L di/dt = u - R_s i - e,  e = w psi_pm J [cos theta, sin theta];
- back-EMF, by a reduced-order observer driven by the measured current and the applied voltage. The
  EMF turns at the speed, de/dt = w J e; with the observer gain g [1/s] and the state z = e_hat + g L i
  (no current derivative needed)::

      dz/dt = g (u - R_s i - e_hat) + w_hat J e_hat,      e_hat = z - g L i          (1)

  so that with exact parameters d(e_hat - e)/dt = (-g + w J)(e_hat - e) + (w_hat - w) J e_hat;
- angle, by a PI-type PLL on the direction of e_hat. In the estimated frame e_hat has the components
  e_d = -w psi sin(theta - theta_hat), e_q = w psi cos(theta - theta_hat); the PLL error is::

      eps = -sgn(w_i) e_d / sqrt(e_d^2 + e_q^2 + (w_0 psi_pm)^2)  ~  sin(theta - theta_hat)   (2)

  (normalized by the EMF magnitude, so the loop gain is speed-independent above w_0 and fades below
  it; sgn of the PLL's integrator w_i, taken as +1 at 0, removes the 180-degree ambiguity), and::

      w_hat = k_p eps + w_i,   dw_i/dt = k_i eps,   dtheta_hat/dt = w_hat            (3)

  with k_p = 2 w_pll, k_i = w_pll^2: the linearized PLL alone has a double pole at -w_pll. The PLL
  bandwidth w_pll is the family's one tunable parameter.

Runtime step (the contract of sensorless.symbolic.runtime): forward Euler of (1)-(3) over one sampling
period, ``meas`` = [i_alpha, i_beta] sampled at t_k and [u_alpha, u_beta] applied over [t_k, t_k + T_s]
(zero-order hold in the stationary frame); outputs the estimates at t_k. With the voltage held over the
period, (1) converges to the EMF of the middle of the period, half a period ahead of the current
sample: the PLL error (2) is taken at the angle theta_hat + w_i T_s / 2 so that theta_hat is the angle
at t_k (without it the angle would lag by w T_s / 2, 3.6 degrees at 0.8 p.u. of the test drive). A
sample whose result is not finite, or whose PLL integrator leaves +-w_max (the drive's highest speed,
a runtime parameter) or EMF state +-4 w_max psi_pm, is rejected (``valid`` = 0): the observer coasts,
its EMF state turning and its angle advancing at w_i; after the runtime contract's count of rejected
samples it resets itself (symbolic/runtime.py). At 0.5 p.u. and above the PLL pulls in by itself
from anywhere within the bounds, in a time that grows with the square of its speed error; at lower
speeds a wrong speed sign of w_i can hold it in a limit cycle (tests/common/test_third_family.py).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import J, Sym, rot, wrap_angle
from sensorless.symbolic.pmsm_drive import MEAS_FIELDS
from sensorless.symbolic.runtime import REJECTS, RESET, VALID, Field, RuntimeObserver, core_function, guarded

NAME = "pmsm_pll"
DISCRETIZATIONS = ("euler",)

# bounds (the runtime contract's guard): the angle wrapped, the PLL integrator within the drive's highest
# speed (and the sampling limit |w| T_s <= pi/2), the EMF state within 4 times the EMF at that speed
# (z = e_hat + g L i: room for g L i up to 3 times the EMF)
_W_BOUND = "min(w_max, pi / 2 / T_s)"
_Z_BOUND = "4 * w_max * psi_pm"
STATE = (
    Field("z_alpha", "V", "EMF observer state z = e_hat + g L i, alpha axis, eq. (1)", bound=_Z_BOUND),
    Field("z_beta", "V", "EMF observer state, beta axis", bound=_Z_BOUND),
    Field("theta", "rad", "angle estimate theta_hat (electrical), in (-pi, pi]", bound="pi"),
    Field("w_i", "rad/s", "PLL integrator: integral part of the speed estimate, eq. (3)", bound=_W_BOUND),
    REJECTS,  # the runtime contract's counter of rejected samples
)
N_OBS = len(STATE) - 1  # the observer's own states

MEAS = MEAS_FIELDS  # what the shared PMSM drive loop feeds the step (symbolic/pmsm_drive.py)

PARAMS = (
    Field("R_s", "ohm", "stator resistance estimate", "positive"),
    Field("L", "H", "stator inductance estimate (non-salient)", "positive"),
    Field("psi_pm", "V s", "PM flux estimate", "positive"),
    Field("g", "rad/s", "EMF observer bandwidth, eq. (1)", "positive"),
    Field("w_pll", "rad/s", "PLL bandwidth: k_p = 2 w_pll, k_i = w_pll^2, eq. (3)", "positive"),
    Field("w_0", "rad/s", "speed below which the PLL error (2) fades", "positive"),
    Field("T_s", "s", "sampling period", "positive"),
    Field(
        "w_max", "rad/s", "highest speed of the drive (electrical): the PLL integrator's bound", "positive"
    ),
)

OUTPUTS = (
    Field("w_hat", "rad/s", "speed estimate (3) over this period (electrical)"),
    Field("theta_hat", "rad", "angle estimate at t_k (electrical), in (-pi, pi]"),
    Field("e_alpha", "V", "back-EMF estimate e_hat at t_k, alpha axis, eq. (1)"),
    Field("e_beta", "V", "back-EMF estimate e_hat at t_k, beta axis"),
    Field("eps", "1", "PLL error (2), ~ sin(theta - theta_hat)"),
    VALID,
    RESET,
)


class Params(NamedTuple):
    """The observer's parameters (symbols or numbers), in the order of PARAMS."""

    R_s: Sym
    L: Sym
    psi_pm: Sym
    g: Sym
    w_pll: Sym
    w_0: Sym
    T_s: Sym
    w_max: Sym

    @classmethod
    def of(cls, p: Sym) -> Params:
        return cls(*(p[k] for k in range(len(PARAMS))))


class Rates(NamedTuple):
    """Right-hand side of (1)-(3) and the signals it computes on the way."""

    dx: Sym  # d/dt [z (2), theta_hat, w_i]
    w_hat: Sym
    e_hat: Sym
    eps: Sym


def emf_estimate(z: Sym, i: Sym, p: Params) -> Sym:
    """e_hat = z - g L i, eq. (1)."""
    return z - p.g * p.L * i


def pll_gains(w_pll: Sym) -> tuple[Sym, Sym]:
    """(k_p, k_i) of the PI (3): a critically damped double pole at -w_pll."""
    return 2 * w_pll, w_pll**2


def pll_error(e_hat: Sym, theta_hat: Sym, w_i: Sym, p: Params) -> Sym:
    """eps of eq. (2): the EMF direction's error, normalized, sign of the speed from w_i."""
    e = rot(theta_hat).T @ e_hat  # in the estimated rotor frame
    sgn = ca.if_else(w_i >= 0, 1, -1)
    return -sgn * e[0] / ca.sqrt(e[0] ** 2 + e[1] ** 2 + (p.w_0 * p.psi_pm) ** 2)


def observer_rhs(x: Sym, i: Sym, u: Sym, p: Params, lead: Sym = 0) -> Rates:
    """Continuous-time observer (1)-(3): x = [z_alpha, z_beta, theta_hat, w_i], stationary frame.

    ``lead``: the angle by which e_hat leads theta_hat's instant (0 in continuous time; the sampled
    step's half period, see the module docstring)."""
    z, theta_hat, w_i = x[0:2], x[2], x[3]
    e_hat = emf_estimate(z, i, p)
    eps = pll_error(e_hat, theta_hat + lead, w_i, p)
    k_p, k_i = pll_gains(p.w_pll)
    w_hat = k_p * eps + w_i
    dz = p.g * (u - p.R_s * i - e_hat) + w_hat * (J @ e_hat)
    return Rates(ca.vertcat(dz, w_hat, k_i * eps), w_hat, e_hat, eps)


@functools.cache
def rhs_function() -> ca.Function:
    """(x, i, u, p) -> dx/dt of (1)-(3) as a Function (what the continuous linearization takes)."""
    x, i, u = ca.SX.sym("x", N_OBS), ca.SX.sym("i", 2), ca.SX.sym("u", 2)
    p = ca.SX.sym("p", len(PARAMS))
    return ca.Function(f"{NAME}_rhs", [x, i, u, p], [observer_rhs(x, i, u, Params.of(p)).dx])


def _step(discretization: str, x: Sym, meas: Sym, p_vec: Sym) -> tuple[Sym, Sym]:
    """(x_next, y) of one guarded sampling period (module docstring)."""
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"unknown discretization {discretization!r} (known: {', '.join(DISCRETIZATIONS)})")
    p = Params.of(p_vec)
    i, u = meas[0:2], meas[2:4]
    r = observer_rhs(x, i, u, p, lead=x[3] * p.T_s / 2)
    x_cand = ca.vertcat(
        x[0:2] + p.T_s * r.dx[0:2], wrap_angle(x[2] + p.T_s * r.dx[2]), x[3] + p.T_s * r.dx[3]
    )
    y_cand = ca.vertcat(r.w_hat, x[2], r.e_hat, r.eps)
    w_i = x[3]
    x_coast = ca.vertcat(rot(w_i * p.T_s) @ x[0:2], wrap_angle(x[2] + p.T_s * w_i), w_i)
    y_coast = ca.vertcat(w_i, x[2], 0, 0, 0)
    x0 = initial_state_function()(p_vec)
    return guarded(x, p_vec, STATE, PARAMS, cand=(x_cand, y_cand), coast=(x_coast, y_coast), reset=x0)


@functools.cache
def observer_step_core(discretization: str = "euler") -> ca.Function:
    """(x, meas, p, lam) -> (x_next, y); nothing is scheduled (lam is empty)."""
    step = functools.partial(_step, discretization)
    return core_function(f"{NAME}_core_{discretization}", step, STATE, MEAS, PARAMS)


@functools.cache
def initial_state_function() -> ca.Function:
    """x0(p): everything zero (no EMF estimate, theta_hat = 0, w_i = 0)."""
    p = ca.SX.sym("p", len(PARAMS))
    return ca.Function(f"{NAME}_init", [p], [ca.DM.zeros(len(STATE))], ["p"], ["x0"])


@functools.cache
def steady_state_function() -> ca.Function:
    """x(p, op): converged at op = [theta_hat, w, i_d, i_q] of a PMSM drive loop.

    The EMF estimate is the estimated-parameter EMF at the observer's own angle, w psi_pm J
    [cos theta_hat, sin theta_hat]; z = e_hat + g L i with the current at that angle; w_i = w.
    """
    p_vec = ca.SX.sym("p", len(PARAMS))
    op = ca.SX.sym("op", 4)
    p = Params.of(p_vec)
    theta_hat, w = op[0], op[1]
    T = rot(theta_hat)
    e_hat = w * p.psi_pm * (T @ ca.vertcat(0, 1))
    z = e_hat + p.g * p.L * (T @ op[2:4])
    x = ca.vertcat(z, wrap_angle(theta_hat), w, 0)
    return ca.Function(f"{NAME}_steady_state", [p_vec, op], [x], ["p", "op"], ["x"])


OBSERVER = RuntimeObserver(
    name=NAME,
    title="back-EMF observer with PLL, for non-salient PMSMs (Sul 2011; Harnefors and Nee 2000)",
    state=STATE,
    meas=MEAS,
    params=PARAMS,
    outputs=OUTPUTS,
    lam=(),
    schedule_state=None,
    core=observer_step_core,
    initial_state=initial_state_function,
    discretizations=DISCRETIZATIONS,
    steady_state=steady_state_function,
    doc_init="every state 0: no EMF estimate, theta_hat = 0, w_i = 0",
    doc_in="current sampled now, voltage applied over the coming period (stationary frame)",
    doc_out="speed and angle estimates now, the back-EMF estimate and the PLL error",
)
