"""The gradient flux observer of Lee et al. (2010) with its firmware variants, a PI PLL, and the runtime step.

Surface PMSM in the stationary frame (amplitude-invariant Clarke, as the firmwares use), flux
``psi = L i + lambda c(theta)``, ``c = [cos, sin]``, ``y = u - R i`` so that ``d psi/dt = y``.
Lee, Hong, Nam, Ortega, Praly, Astolfi, IEEE TPEL 25(2) 2010, eqs. (4)-(8):

    eta(x) = x - L i                                                            (6)
    dx/dt  = y + (gamma/2) eta(x) (lambda^2 - |eta(x)|^2),   gamma > 0          (8)
    theta_obs = atan2(eta_2, eta_1)

written here with the observer gain ``k = gamma lambda^2`` [1/s] (ODrive's observer_gain; VESC's
run-time gain times lambda^2), so that the correction is ``(k/2) eta (1 - |eta|^2/lambda^2)``.

Firmware variants (runtime options, docs/families/pmsm_flux_observer.md):

- correction ``gradient`` (ODrive): (8) as written;
  ``clamped-gradient`` (VESC's original Ortega observer): the factor lambda^2 - |eta|^2 clamped to
  at most 0, so the correction acts only where |eta| > lambda;
  ``box-clamp`` (MXLEMMING: VESC's default, SimpleFOC): no gain, pure integration of y with each axis
  of eta clamped to +-lambda;
- inductance rule ``fixed`` (one L = (L_d + L_q)/2), ``q-axis`` (L = L_q: the "active flux" of
  Boldea, exact angle on a salient motor) or ``interpolated`` (VESC: L_d + (L_q - L_d) i_q^2/|i|^2, i_q in
  the frame of the observer's last angle, the direction of x - L_q i);
- online flux adaptation (optional): lambda_hat follows |eta| by the gradient of the same cost:
  ``d lambda_hat/dt = a (gamma/2) lambda_hat (|eta|^2 - lambda_hat^2)``, gamma = k/lambda^2, with
  a = 0.2 (gradient corrections) or 0.1 (box clamp), lambda_hat within 0.3 .. 2.5 lambda (the rates
  and limits VESC documents; its update itself is not reproduced);
- the gain: ``k = k_0 max(k_slow, |u| / u_ref)`` where ``scheduled`` is 1 (VESC's run-time schedule:
  4 foc_observer_gain max(foc_observer_gain_slow, |duty| V_bus / 40 V), with |duty| V_bus = sqrt(3) |u|),
  else k = k_0; k_0 is the scheduled gain ``lam`` (a constant or a table over the PLL speed).

PLL (a PI tracking loop on the observer angle, as all three firmwares' speed estimates)::

    e = wrap(theta_obs - theta_pll),  d theta_pll/dt = w_pll + k_p e,  d w_pll/dt = k_i e

Discretization (the firmwares'): forward Euler at the observer period T. At sample k the step has the
current i_k and the voltage u_{k-1} applied over the previous period (stored in the state: the loop
gives the voltage of the coming period); it predicts ``x' = x + T (u_{k-1} - R i_k)``, then corrects
``x_k = x' + T corr(eta(x'))`` (ODrive's order), and the PLL takes ``theta_obs`` of x_k as ODrive
does: ``th' = th + T w``, ``e = wrap(theta_obs - th')``, ``th_k = th' + T k_p e``, ``w_k = w + T k_i e``,
w_k clamped to its runtime bound +-min(w_max, pi/(2T)) (a sample that would carry it beyond is used,
the speed held at the bound, not rejected). The outputs are the raw observer angle (the firmwares
commutate on it) and the PLL speed w_k.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import Sym, rot, wrap_angle
from sensorless.symbolic.pmsm_drive import MEAS_FIELDS
from sensorless.symbolic.runtime import (
    REJECTS,
    RESET,
    VALID,
    Field,
    RuntimeObserver,
    bound_expression,
    core_function,
    guarded,
)

NAME = "pmsm_flux_observer"
DISCRETIZATIONS = ("euler",)
CORRECTIONS = ("gradient", "clamped-gradient", "box-clamp")
INDUCTANCES = ("fixed", "q-axis", "interpolated")
ADAPT_RATE = {"gradient": 0.2, "clamped-gradient": 0.2, "box-clamp": 0.1}  # x (k/2), VESC's rates
LAMBDA_RANGE = (0.3, 2.5)  # lambda_hat within these multiples of the nominal flux (VESC's limits)
CURRENT_EPS = 1e-9  # A^2 added to |i|^2 in the interpolated rule (no division by zero at no current)
# (V s A)^2 added to the share's divisor (a zero frame): relative 1e-30 / (lambda^2 CURRENT_EPS) < 1e-16
# on any motor with lambda > 1e-6 V s, so below double rounding wherever the frame is not zero
FRAME_EPS = 1e-30

_X_BOUND = "6 * psi_pm"  # flux state: |eta| ~ lambda plus L i (L i < 5 lambda on any SPM drive)
_W_BOUND = "min(w_max, pi / (2 * T_s))"
STATE = (
    Field("x_alpha", "V s", "stator flux estimate x, alpha axis, eq. (8)", bound=_X_BOUND),
    Field("x_beta", "V s", "stator flux estimate x, beta axis", bound=_X_BOUND),
    Field("lambda_hat", "V s", "PM flux the observer uses (adapted online or held)", bound="2.5 * psi_pm"),
    Field("u_prev_alpha", "V", "voltage applied over the previous period, alpha axis", bound="u_max"),
    Field("u_prev_beta", "V", "voltage applied over the previous period, beta axis", bound="u_max"),
    Field("theta_pll", "rad", "PLL angle, in (-pi, pi]", bound="pi"),
    Field("w_pll", "rad/s", "PLL speed (integrator), electrical", bound=_W_BOUND),
    REJECTS,
)
N_OBS = len(STATE) - 1
MEAS = MEAS_FIELDS

PARAMS = (
    Field("R_s", "ohm", "stator resistance estimate", "positive"),
    Field("L_d", "H", "d-axis inductance estimate", "positive"),
    Field("L_q", "H", "q-axis inductance estimate", "positive"),
    Field("psi_pm", "V s", "PM flux estimate lambda", "positive"),
    Field("k_slow", "1", "VESC's foc_observer_gain_slow: least gain factor of the schedule", "nonnegative"),
    Field("u_ref", "V", "voltage amplitude at which the schedule's factor is 1 (40 V/sqrt(3))", "positive"),
    Field("scheduled", "1", "1: k = k_0 max(k_slow, |u|/u_ref) (VESC); 0: k = k_0", "flag"),
    Field("adapt", "1", "1: adapt lambda_hat online; 0: hold it at psi_pm", "flag"),
    Field("k_p", "1/s", "PLL proportional gain", "positive"),
    Field("k_i", "1/s^2", "PLL integral gain", "positive"),
    Field("T_s", "s", "observer period T", "positive"),
    Field("w_max", "rad/s", "highest speed of the drive (electrical): the PLL speed's bound", "positive"),
    Field("u_max", "V", "largest voltage per axis the inverter applies (the DC-link voltage)", "positive"),
)
LAM = (Field("k_0", "1/s", "observer gain gamma lambda^2 before VESC's voltage factor"),)

OUTPUTS = (
    Field("w_hat", "rad/s", "PLL speed estimate (electrical)"),
    Field("theta_hat", "rad", "observer angle atan2(eta) at t_k (the firmwares commutate on it)"),
    Field("theta_pll_out", "rad", "PLL angle at t_k"),
    Field("eta_alpha", "V s", "PM flux estimate eta = x - L i, alpha axis, eq. (6)"),
    Field("eta_beta", "V s", "PM flux estimate eta, beta axis"),
    Field("k_obs", "1/s", "observer gain gamma lambda^2 in effect this period"),
    VALID,
    RESET,
)


class Params(NamedTuple):
    """The parameters (symbols or numbers), in the order of PARAMS."""

    R_s: Sym
    L_d: Sym
    L_q: Sym
    psi_pm: Sym
    k_slow: Sym
    u_ref: Sym
    scheduled: Sym
    adapt: Sym
    k_p: Sym
    k_i: Sym
    T_s: Sym
    w_max: Sym
    u_max: Sym

    @classmethod
    def of(cls, p: Sym) -> Params:
        return cls(*(p[k] for k in range(len(PARAMS))))


def inductance(rule: str, i: Sym, frame: Sym, p: Params) -> Sym:
    """The one inductance of (6) by the firmware's rule (module docstring); ``frame`` a vector (any
    length) along the angle the interpolated rule takes i_q in.

    With ``frame`` = r [cos theta, sin theta], i_q = -sin(theta) i_alpha + cos(theta) i_beta is
    (frame x i) / r, so the share i_q^2 / |i|^2 is (frame x i)^2 / (r^2 |i|^2): the same number
    with no angle, cosine or sine (a fixed-point step needs neither a CORDIC nor a polynomial for
    it). FRAME_EPS keeps the degenerate frame (r = 0, where atan2 gave angle 0) a finite share."""
    if rule == "fixed":
        return (p.L_d + p.L_q) / 2
    if rule == "q-axis":
        return p.L_q
    if rule == "interpolated":
        cross = frame[0] * i[1] - frame[1] * i[0]
        share = cross**2 / (ca.sumsqr(frame) * (ca.sumsqr(i) + CURRENT_EPS) + FRAME_EPS)
        return p.L_d + (p.L_q - p.L_d) * share
    raise ValueError(f"unknown inductance rule {rule!r} (known: {', '.join(INDUCTANCES)})")


def observer_gain(k_0: Sym, u: Sym, p: Params) -> Sym:
    """k = gamma lambda^2 [1/s]: k_0, times VESC's voltage factor where scheduled."""
    factor = ca.fmax(p.k_slow, ca.norm_2(u) / p.u_ref)
    return ca.if_else(p.scheduled > 0.5, k_0 * factor, k_0)


def correction(kind: str, eta: Sym, lam: Sym, k: Sym, psi: Sym) -> Sym:
    """The gradient term of (8) per unit time, (gamma/2) eta (lambda_hat^2 - |eta|^2) with gamma =
    k / psi_pm^2 (the firmware's gain on its configured flux), or its clamped form."""
    err = lam**2 - ca.sumsqr(eta)
    if kind == "clamped-gradient":
        err = ca.fmin(err, 0)
    elif kind != "gradient":
        raise ValueError(f"correction {kind!r} has no gradient term")
    return (k / 2) * eta * err / psi**2


def flux_rate(kind: str, lam: Sym, eta: Sym, k: Sym, p: Params) -> Sym:
    """d lambda_hat/dt of the online adaptation (module docstring), 0 where it is off."""
    return p.adapt * ADAPT_RATE[kind] * (k / 2) * lam * (ca.sumsqr(eta) - lam**2) / p.psi_pm**2


def pll_rates(theta_obs: Sym, theta_pll: Sym, w_pll: Sym, p: Params) -> tuple[Sym, Sym]:
    """(d theta_pll/dt, d w_pll/dt) of the PI PLL."""
    e = wrap_angle(theta_obs - theta_pll)
    return w_pll + p.k_p * e, p.k_i * e


def observer_rhs(kind: str, rule: str, x: Sym, i: Sym, u: Sym, p: Params, k_0: Sym) -> Sym:
    """Continuous-time observer (8) with the PLL: x = [x (2), lambda_hat, theta_pll, w_pll] -> dx/dt.
    (The box clamp is a discrete map with no continuous form: ValueError.)"""
    lam = x[2]
    L = inductance(rule, i, x[0:2] - p.L_q * i, p)
    eta = x[0:2] - L * i
    k = observer_gain(k_0, u, p)
    dx = u - p.R_s * i + correction(kind, eta, lam, k, p.psi_pm)
    dth, dw = pll_rates(ca.atan2(eta[1], eta[0]), x[3], x[4], p)
    return ca.vertcat(dx, flux_rate(kind, lam, eta, k, p), dth, dw)


@functools.cache
def rhs_function(kind: str, rule: str) -> ca.Function:
    """(x[5], i, u, p, k_0) -> dx/dt of the continuous observer with its PLL."""
    x, i, u = ca.SX.sym("x", 5), ca.SX.sym("i", 2), ca.SX.sym("u", 2)
    p, k_0 = ca.SX.sym("p", len(PARAMS)), ca.SX.sym("k_0")
    return ca.Function(
        f"{NAME}_rhs_{_tag(kind, rule)}",
        [x, i, u, p, k_0],
        [observer_rhs(kind, rule, x, i, u, Params.of(p), k_0)],
        ["x", "i", "u", "p", "k_0"],
        ["dx"],
    )


def _tag(kind: str, rule: str) -> str:
    return f"{kind}_{rule}".replace("-", "_")


def _step(kind: str, rule: str, x: Sym, meas: Sym, p_vec: Sym, lam_in: Sym) -> tuple[Sym, Sym]:
    """(x_next, y) of one guarded observer period (module docstring)."""
    p = Params.of(p_vec)
    T = p.T_s
    i, u = meas[0:2], meas[2:4]
    lam, u_prev, th, w = x[2], x[3:5], x[5], x[6]
    k = observer_gain(lam_in[0], u_prev, p)
    # the inductance of the interpolated rule in the frame of the last angle estimate
    L = inductance(rule, i, x[0:2] - p.L_q * i, p)
    x_pred = x[0:2] + T * (u_prev - p.R_s * i)  # prediction with the previous period's voltage
    eta_pred = x_pred - L * i
    if kind == "box-clamp":
        eta = ca.fmin(ca.fmax(eta_pred, -lam), lam)  # each axis within +-lambda_hat
        x_new = eta + L * i
    else:
        x_new = x_pred + T * correction(kind, eta_pred, lam, k, p.psi_pm)
        eta = x_new - L * i
    # the box clamp corrects with no gain; its flux adaptation (if on) runs at the rate of k
    lam_new = lam + T * flux_rate(kind, lam, eta_pred, k, p)
    lam_new = ca.fmin(ca.fmax(lam_new, LAMBDA_RANGE[0] * p.psi_pm), LAMBDA_RANGE[1] * p.psi_pm)
    theta_obs = ca.atan2(eta[1], eta[0])
    # the PLL as ODrive steps it: its angle predicted with its speed, then corrected by the error to
    # the observer's angle (at t_k), and its speed integrated
    th_pred = th + T * w
    e = wrap_angle(theta_obs - th_pred)
    # the PLL speed is clamped to its bound (an integrator held at its limit), not rejected: neither
    # firmware bounds it and both keep every sample (docs/families/pmsm_flux_observer.md, "C code,
    # bounds and recovery"). By comparisons, not fmin/fmax: a NaN stays NaN for the guard to reject,
    # and the C calls no libm function for it
    w_bound = bound_expression(_W_BOUND, PARAMS, p_vec)
    th_new, w_raw = wrap_angle(th_pred + T * p.k_p * e), w + T * p.k_i * e
    w_new = ca.if_else(w_raw > w_bound, w_bound, ca.if_else(w_raw < -w_bound, -w_bound, w_raw))
    x_cand = ca.vertcat(x_new, lam_new, u, th_new, w_new)
    y_cand = ca.vertcat(w_new, theta_obs, th_new, eta, k)
    # coasting (nothing of the rejected sample used): the flux state turns at the PLL speed, the PLL
    # runs on, the voltage is held; the flux output is the turned state (no current to subtract)
    x_c = rot(w * T) @ x[0:2]
    th_c = wrap_angle(th + T * w)
    x_coast = ca.vertcat(x_c, lam, u_prev, th_c, w)
    y_coast = ca.vertcat(w, th_c, th_c, x_c, k)
    x0 = initial_state_function()(p_vec)
    return guarded(x, p_vec, STATE, PARAMS, cand=(x_cand, y_cand), coast=(x_coast, y_coast), reset=x0)


@functools.cache
def observer_step_core(kind: str, rule: str, discretization: str = "euler") -> ca.Function:
    """(x, meas, p, lam) -> (x_next, y) of the variant (kind, rule); lam = [k_0]."""
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"unknown discretization {discretization!r} (known: {', '.join(DISCRETIZATIONS)})")
    if kind not in CORRECTIONS:
        raise ValueError(f"unknown correction {kind!r} (known: {', '.join(CORRECTIONS)})")
    step = functools.partial(_step, kind, rule)
    return core_function(f"{NAME}_{_tag(kind, rule)}_{discretization}", step, STATE, MEAS, PARAMS, LAM)


@functools.cache
def initial_state_function() -> ca.Function:
    """x0(p): eta = [lambda, 0] at no current (angle 0), lambda_hat = lambda, no voltage, PLL at rest."""
    p = ca.SX.sym("p", len(PARAMS))
    psi = p[3]
    x0 = ca.vertcat(psi, 0, psi, 0, 0, 0, 0, 0)
    return ca.Function(f"{NAME}_init", [p], [x0], ["p"], ["x0"])


@functools.cache
def steady_state_function(rule: str) -> ca.Function:
    """x(p, op): converged at op = [theta_hat, w, i_d, i_q] of a PMSM loop: eta = lambda c(theta_hat),
    x = eta + L i at that angle, the previous period's steady voltage of the estimated model, the PLL
    on the angle at speed w."""
    p_vec, op = ca.SX.sym("p", len(PARAMS)), ca.SX.sym("op", 4)
    p = Params.of(p_vec)
    th, w, i_r = op[0], op[1], op[2:4]
    i = rot(th) @ i_r
    L = inductance(rule, i, ca.vertcat(ca.cos(th), ca.sin(th)), p)
    eta = p.psi_pm * ca.vertcat(ca.cos(th), ca.sin(th))
    psi_r = ca.vertcat(p.L_d * i_r[0] + p.psi_pm, p.L_q * i_r[1])
    u_r = p.R_s * i_r + w * ca.vertcat(-psi_r[1], psi_r[0])
    u_prev = rot(th - w * p.T_s / 2) @ u_r  # the steady voltage at the middle of the previous period
    x = ca.vertcat(eta + L * i, p.psi_pm, u_prev, wrap_angle(th), w, 0)
    return ca.Function(f"{NAME}_steady_state_{_tag('x', rule)}", [p_vec, op], [x], ["p", "op"], ["x"])


@functools.cache
def runtime_observer(kind: str, rule: str) -> RuntimeObserver:
    """The runtime observer of one variant (its C names carry the variant)."""
    if kind not in CORRECTIONS or rule not in INDUCTANCES:
        raise ValueError(f"unknown variant {kind!r}, {rule!r}")
    return RuntimeObserver(
        name=f"{NAME}_{_tag(kind, rule)}",
        title=f"flux observer ({kind}, {rule} inductance) with PI PLL (Lee et al. 2010)",
        state=STATE,
        meas=MEAS,
        params=PARAMS,
        outputs=OUTPUTS,
        lam=LAM,
        schedule_state="w_pll",
        core=functools.partial(observer_step_core, kind, rule),
        initial_state=initial_state_function,
        discretizations=DISCRETIZATIONS,
        steady_state=functools.partial(steady_state_function, rule),
        doc_init="eta = [psi_pm, 0], lambda_hat = psi_pm, no previous voltage, PLL at rest",
        doc_in="current sampled now, voltage applied over the coming period (stationary frame)",
        doc_out="PLL speed, observer angle, PLL angle, PM flux estimate, observer gain",
    )


ODRIVE_FLUX_CONSTANT = 60 / (2 * math.pi * math.sqrt(3))  # 5.51328895422: psi = this / (p KV[rpm/V])
