"""HF-injection carrier of a derived drive file from the motor: amplitude and frequency, each with its reason.

Piippo et al. (2008) Section V inject a pulsating carrier u_c cos(w_c t) on the estimated d axis; the
q-axis current it leaves at an angle error theta_tilde is, for w_c far above the rotor speed and R_s/L
(the inductances dominate at the carrier frequency),

    i_qc = (u_c / w_c) (L_q - L_d) / (2 L_d L_q) sin(2 theta_tilde),

and the error signal (19) is that current demodulated and averaged by the injection PI (21)-(22) of
bandwidth alpha_i. The rules (constants below) of :func:`carrier`:

- frequency: w_c = 2 pi f_s/6: six samples per carrier period (the current sensor samples it without
  aliasing and the band-stop of the current control can remove it), twice the current control's
  f_s/12.5, so the current loop neither follows nor cancels it (the paper: 833 Hz at 5 kHz);
- amplitude: the smallest u_c at which an angle error of THETA_RES (5 deg electrical) shows in the
  averaged error signal SNR (3) times above the current sensor's noise, sigma_eff = sqrt(i_noise^2 +
  q^2/12) per axis and sample (q: the resolution, one step of the sensor's converter), whose variance
  the demodulation (x 2) and the PI's averaging (equivalent bandwidth alpha_i/2 of a sample of T_s)
  reduce by alpha_i T_s:
      u_c = SNR sigma_eff sqrt(alpha_i T_s) w_c 2 L_d L_q / (|L_q - L_d| sin(2 THETA_RES));
  on the paper's motor (i_noise 0.3 % of base i) this gives 32 V against its 40 V;
- limits: u_c at most VOLTAGE_SHARE (half) of the voltage the inverter has left at the fade-out speed
  w_Delta under rated load (u_dc/sqrt(3) less the steady voltage there), and the carrier's d-axis
  current u_c/(w_c L_d) at most CURRENT_SHARE (10 %) of the base current (torque ripple and losses).
  Where the amplitude needed exceeds a limit, the motor's saliency is too small for the sensor to see:
  injection off, with a warning that says by how much and what would help.

The carrier's error signal corrects the observer through the rotation omega_eps of its flux estimate
(20). How the adaptive observer answers that rotation sets the sign of the correction's integral
loop (21): at equilibrium (exact estimates, i_tilde_q = 0 by the adaptation (9)) a rotation shifts the
angle by -N / (w_m D) with N = (R_s + lambda1) psi_d + (w_m L_d + lambda2) L_q i_q, psi_d = psi_pm
+ L_d i_d. Regenerating (w_m i_q < 0), N changes sign at the speed of :func:`coupling_limit`,

    |w_1| = (R_s + lambda1) psi_d / ((L_d + lambda2/w_m) L_q |i_q|),

and between |w_1| and w_Delta the averaged loop with the injection has a real pole in the right half
plane (the linearization's crossing equals w_1: tests/ipmsm_adaptive/test_carrier.py). The paper's
motor has |w_1| = 0.38 p.u. at T_N, beyond its w_Delta = 0.13 p.u.; a motor of small R_s and strong
reluctance torque (small psi_d under load, large L_d L_q i_q) has it far below: zero-speed crossings
pass the band in a transient, but holding a regenerating speed inside it under load loses the rotor.
|w_1| falls as the regenerating torque grows (|i_q| up, psi_d down), so :func:`coupling_torque` gives the
largest regenerating torque at which the correction still holds up to a speed (w_Delta: the band closes):
what a drive may regenerate there (the Prius-class traction motor of docs/examples/motors: 73 N m, 0.24
T_N, against its rated 300 N m).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from sensorless.design.motor_data import mtpa_torque_current, steady_voltage
from sensorless.design.pmsm_schema import PmsmMotor

CARRIER_FS = 1 / 6  # w_c = 2 pi f_s / 6
THETA_RES = math.radians(5.0)  # the angle error the error signal must show
SNR = 3.0  # ... this many times above its noise
VOLTAGE_SHARE = 0.5  # of the inverter's voltage left at w_Delta under rated load
CURRENT_SHARE = 0.1  # carrier d-axis current, of the base current


@dataclass(frozen=True)
class Carrier:
    """The derived carrier: frequency [Hz], amplitude [V] (0: off) and the reasons."""

    f_c: float
    u_c: float
    needed: float  # the amplitude the sensor needs [V]
    limit: float  # the smaller limit [V]
    rule_f: str
    rule_u: str
    warning: str = ""


def carrier(
    m: PmsmMotor,
    f_s: float,
    u_dc: float,
    T_N: float,
    w_delta: float,
    alpha_i: float,
    i_noise: float,
    i_resolution: float,
    i_base: float,
    f_c: float | None = None,
) -> Carrier:
    """The carrier of a motor ``m`` sampled at ``f_s`` [Hz] (module docstring); speeds in rad/s;
    ``f_c`` [Hz]: the drive file's carrier frequency where it gives one."""
    f_c = CARRIER_FS * f_s if f_c is None else f_c
    w_c = 2 * math.pi * f_c
    T_s = 1 / f_s
    dL = abs(m.L_q - m.L_d)
    sigma = math.hypot(i_noise, i_resolution / math.sqrt(12))
    needed = SNR * sigma * math.sqrt(alpha_i * T_s) * w_c * 2 * m.L_d * m.L_q / (dL * math.sin(2 * THETA_RES))
    i_d, i_q = mtpa_torque_current(T_N, m)
    left = max(u_dc / math.sqrt(3) - steady_voltage(m, w_delta, i_d, i_q), 0.0)
    by_voltage = VOLTAGE_SHARE * left
    by_current = CURRENT_SHARE * i_base * w_c * m.L_d
    limit = min(by_voltage, by_current)
    rule_f = (
        "carrier f_s/6: six samples a period, twice the current control's f_s/12.5 (Piippo et al.: 833 Hz)"
    )
    sens = (
        f"sensor noise sqrt(i_noise^2 + q^2/12) = {sigma:.3g} A, averaged by the PI at alpha_i = "
        f"{alpha_i / (2 * math.pi):.3g} Hz"
    )
    lim_text = (
        f"limits: {VOLTAGE_SHARE:g} x the {left:.4g} V the inverter has left at w_Delta under T_N "
        f"({by_voltage:.4g} V), carrier d current <= {CURRENT_SHARE:g} base i ({by_current:.4g} V)"
    )
    if needed > limit:
        warning = (
            f"HF injection off: the saliency |L_q - L_d| = {dL:.3g} H is too small for the current sensor "
            f"to see a {math.degrees(THETA_RES):g}-deg angle error: the carrier would need {needed:.4g} V "
            f"({sens}), above the {limit:.4g} V limit; a less noisy or finer current sensor, or a lower "
            "carrier frequency, would help; below the minimum sensorless speed the drive needs the "
            "open-loop start"
        )
        return Carrier(f_c, 0.0, needed, limit, rule_f, f"off: {needed:.4g} V needed > {lim_text}", warning)
    rule_u = (
        f"smallest u_c showing a {math.degrees(THETA_RES):g}-deg angle error {SNR:g}x above the {sens} "
        f"(i_qc = u_c/w_c (L_q - L_d)/(2 L_d L_q) sin 2 theta); {lim_text}"
    )
    return Carrier(f_c, needed, needed, limit, rule_f, rule_u)


def coupling_limit(m: PmsmMotor, T: float, lambda1: float = 0.0, lambda2_per_w: float = 0.0) -> float:
    """|w_1| [rad/s, electrical]: regenerating at the torque ``T`` [N m] (MTPA current), the HF correction
    (20)-(21) holds the angle only below this speed (module docstring); ``lambda1`` [ohm] and
    ``lambda2_per_w`` = lambda2/w_m [H] are the observer gain (7) near zero speed (law (16): both 0 at
    zero speed). ``inf`` where N keeps its sign at every speed, 0 where it is wrong from zero speed on."""
    i_d, i_q = mtpa_torque_current(T, m)
    rho_psi = (m.R_s + lambda1) * (m.psi_pm + m.L_d * i_d)
    den = (m.L_d + lambda2_per_w) * m.L_q * abs(i_q)
    if den <= 0:
        return math.inf if rho_psi > 0 else 0.0
    return max(rho_psi / den, 0.0)


def coupling_torque(m: PmsmMotor, w: float, T_max: float, bisections: int = 60) -> float:
    """The largest |T| <= ``T_max`` [N m] at which the HF correction still holds regenerating up to the speed
    ``w`` [rad/s, electrical] with zero gain (:func:`coupling_limit` >= |w|; it falls as |T| grows): the
    regenerating torque a drive may hold below w_Delta where :func:`coupling_limit` lies inside its band;
    ``T_max`` where it holds up to there, 0 where at no torque."""
    if coupling_limit(m, T_max) >= abs(w):
        return T_max
    lo, hi = 0.0, T_max
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if coupling_limit(m, mid) >= abs(w) else (lo, mid)
    return lo


# the speed loop's carrier feedback (speed_loop_feedback): at most this share of the error signal (19)
# may the speed loop cancel (the injection PI (21)-(22) then runs at >= half its alpha_i, damping >= 0.61)
FEEDBACK_MAX = 0.5


@dataclass(frozen=True)
class SpeedLoopPath:
    """The path the speed loop feeds the carrier back through (:func:`speed_loop_feedback`): the
    adaptation's alpha_fo [rad/s] and the estimates L̂_q [H], ψ̂_pm [V s], Ĵ [kg m^2], the pole pairs,
    the current loop's alpha_c [rad/s], the carrier w_c [rad/s] and the sampling period T_s [s]."""

    alpha_fo: float
    L_q_hat: float
    psi_pm_hat: float
    J_hat: float
    p: int
    alpha_c: float
    w_c: float
    T_s: float


def speed_loop_feedback(path: SpeedLoopPath, alpha_s: float, w_f: float) -> float:
    """G: the carrier current the speed loop feeds back, over the saliency's own i_qc (at zero torque).

    At an angle error the carrier leaves i_qc (module docstring) in the measured q current; the observer's
    model (aligned with its own frame) does not predict it, so it is a current error, and the adaptation
    (9)-(10) turns it into a speed-estimate ripple k_p L̂_q i_qc at w_c. Through the speed feedback's
    low-pass F (design/pmsm_drive.py, sampled exactly), the speed PI's k_p = 2 alpha_s Ĵ/p, the MTPA
    reference (di_q/dT = 1/(1.5 p ψ̂_pm) at T = 0) and the current PI (k_p = alpha_c L̂_q; its feedback is
    band-stopped at the carrier, so the reference passes) it returns as a q voltage at w_c, whose current
    (u / (w_c L_q), times the sampled response's Delta / (2 sin(Delta/2)), Delta = w_c T_s) the
    demodulation (18) reads beside i_qc, nearly in antiphase (the 1.5-sample delay the carrier's own
    response is demodulated with acts on the fed-back path twice). So the error signal (19) is scaled by
    about 1 - G:

        G = (2 alpha_fo L̂_q / ψ̂_pm) |F(e^{j w_c T_s})| (2 alpha_s Ĵ / p) / (1.5 p ψ̂_pm)
            (alpha_c / w_c) Delta / (2 sin(Delta / 2)),
        |F| = (1 - a) / |1 - a e^{-j w_c T_s}|,   a = e^{-w_f T_s}.

    G > 1 reverses its sign and the injection pushes the angle away: the traction IPMSM of
    docs/examples/motors (prius) had G = 32 with its 33.8-Hz speed loop and lost the rotor held at
    -0.04 p.u. unloaded. Where G > FEEDBACK_MAX the drive band-stops its speed feedback at w_c, which takes
    G to 0 (simulation.py). Simulated error-signal gains against 1 - G: tests/ipmsm_adaptive/test_carrier.py.
    """
    q = path
    k_p_obs = 2 * q.alpha_fo / q.psi_pm_hat  # eq. (10)
    a = math.exp(-w_f * q.T_s)
    delta = q.w_c * q.T_s
    filt = (1 - a) / abs(1 - a * complex(math.cos(delta), -math.sin(delta)))
    k_p_speed = 2 * alpha_s * q.J_hat / q.p  # design/pmsm_drive.py speed PI, electrical speed
    di_dT = 1 / (1.5 * q.p * q.psi_pm_hat)
    plant = q.alpha_c / q.w_c * delta / (2 * math.sin(delta / 2))
    return k_p_obs * q.L_q_hat * filt * k_p_speed * di_dT * plant


def speed_loop_limit(
    path: SpeedLoopPath, speed_filter: Callable[[float], float], bisections: int = 60
) -> float:
    """The fastest speed loop alpha_s [rad/s] whose carrier feedback :func:`speed_loop_feedback` is at most
    FEEDBACK_MAX, with the speed filter ``speed_filter(alpha_s)`` [rad/s] the drive runs (G grows with
    both)."""

    def g(alpha_s: float) -> float:
        return speed_loop_feedback(path, alpha_s, speed_filter(alpha_s))

    hi = 1.0
    while g(hi) < FEEDBACK_MAX:
        hi *= 2
    lo = 0.0
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) <= FEEDBACK_MAX else (lo, mid)
    return lo
