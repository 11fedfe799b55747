"""Plausibility checks of a drive's motor data against its rating and inverter: warnings and errors.

:func:`plausibility` checks a drive's data against each other (back-EMF at rated speed against the
inverter's voltage, rated torque against current and flux, samples per electrical period, L/R against
the sampling period, f_N against n_N and p) and returns findings, each naming its keys: warnings, and
errors for what cannot be right (docs/motor_data.md, "Plausibility checks"). Any PMSM family calls it
on the motor it read with design/motor_data.py ``read_motor``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from sensorless.design.motor_data import MotorData, mtpa_torque, mtpa_torque_current, steady_voltage
from sensorless.design.units import DriveFileError

# the thresholds of :func:`plausibility` (docs/motor_data.md, "Plausibility checks")
EMF_ERROR = 1.05  # no-load back-EMF at n_N beyond this times the available voltage: error
TORQUE_WARN, TORQUE_ERROR = 0.10, 0.30  # |T_N / T(I_N) - 1| beyond: warning, error
SAMPLES_WARN, SAMPLES_ERROR = 10.0, 4.0  # samples per electrical period at the top speed
LR_WARN, LR_ERROR = 5.0, 1.0  # electrical time constant L/R in sampling periods
# electrical time constant L/R [s] beyond: warning, error. PM motors span ~0.1 ms (a drone motor) to
# ~50 ms (large machines); a resistance in ohm for mohm is 1000x, 1e-11 ohm makes the analyses overflow
LR_MAX_WARN, LR_MAX_ERROR = 1.0, 100.0
F_N_TOLERANCE = 0.01  # f_N against n_N p / 60
# w_N L_q |i_q| at the rated point beyond this times the available voltage: error. Field weakening
# (i_d) cannot lower the q-axis inductive drop, and 3x leaves room for a salient motor's smaller i_q
# there; an inductance in H instead of mH (a bare number is SI) is 1000x
U_L_ERROR = 3.0
# the available voltage u_dc/sqrt(3) beyond these multiples of the rated point's voltage: warning, error.
# Drives leave 1.1-3x of headroom; a DC link in V for mV, kV for V, or of another drive is 1000x
UDC_WARN, UDC_ERROR = 10.0, 100.0
# the mechanical time constant J w_N / (p T_N) (1 p.u. of speed at rated torque) outside this range
# [s]: warning. Measured motors span ~10 ms (a drone motor, a small servo) to ~5 s (the 30-kW
# axial-flux preset); kg cm2 read as kg m2 is 10^4 x, g cm2 as kg cm2 10^3 x
TAU_M_RANGE = (1e-3, 60.0)


@dataclass(frozen=True)
class Finding:
    """One plausibility finding: ``level`` "warning" or "error", the keys it concerns, the text."""

    level: str
    keys: tuple[str, ...]
    text: str

    def line(self, file: str) -> str:
        return f"{file}: {', '.join(self.keys)}: {self.text}"


def plausibility(
    motor: MotorData,
    *,
    n_N: float,
    T_N: float,
    I_N: float | None,
    f_N: float | None,
    u_dc: float,
    T_s: float,
    w_max: float,
    keys: Mapping[str, str],
) -> list[Finding]:
    """The plausibility findings of a drive's data (module docstring; thresholds above, documented in
    docs/motor_data.md). ``n_N`` [r/min], ``T_N`` [N m], ``I_N`` [A rms] (None: not given), ``f_N``
    [Hz] (None: not given), ``u_dc`` [V], ``T_s`` [s], ``w_max`` [electrical rad/s, top speed];
    ``keys`` names the keys: n_N, T_N, I_N, f_N, u_dc, T_s, w_max (the motor's come from its source)."""
    out: list[Finding] = []
    src = motor.source
    w_N = 2 * math.pi * n_N / 60 * motor.p
    u_avail = u_dc / math.sqrt(3)  # peak phase voltage in the linear range of space-vector modulation
    # n_N against f_N and p
    if f_N is not None:
        f_exp = n_N * motor.p / 60
        if abs(f_N / f_exp - 1) > F_N_TOLERANCE:
            out.append(
                Finding(
                    "error",
                    (keys["f_N"], keys["n_N"], src["p"]),
                    f"f_N = {f_N:g} Hz, but n_N p / 60 = {n_N:g} x {motor.p} / 60 = {f_exp:.5g} Hz "
                    f"(tolerance {100 * F_N_TOLERANCE:g} %): check n_N (mechanical r/min) and the pole "
                    "pairs (p = poles/2)",
                )
            )
    # back-EMF at rated speed against the available voltage
    emf = w_N * motor.psi_pm
    if emf > EMF_ERROR * u_avail:
        out.append(
            Finding(
                "error",
                (src["psi_pm"], keys["n_N"], keys["u_dc"]),
                f"the no-load back-EMF at n_N = {n_N:g} r/min is {emf:.4g} V (peak phase), more than the "
                f"{u_avail:.4g} V the inverter can apply (u_dc/sqrt(3)): the flux or its convention "
                "(line-line or phase, rms or peak), the pole pairs, or n_N (the rated speed without "
                "field weakening) is wrong",
            )
        )
    # rated torque against current and flux
    i_d, i_q = mtpa_torque_current(T_N, motor)
    if I_N is not None:
        T_I = mtpa_torque(math.sqrt(2) * I_N, motor)
        dev = T_N / T_I - 1
        if abs(dev) > TORQUE_WARN:
            level = "error" if abs(dev) > TORQUE_ERROR else "warning"
            # a salient motor's MTPA torque has a reluctance part (L_d - L_q) i_d i_q: its inductances
            # set T(I_N) as much as the flux does
            salient = motor.L_d != motor.L_q
            L_keys = tuple(dict.fromkeys((src["L_d"], src["L_q"]))) if salient else ()
            out.append(
                Finding(
                    level,
                    (keys["T_N"], keys["I_N"], src["psi_pm"], *L_keys),
                    f"T_N = {T_N:.4g} N m, but I_N = {I_N:.4g} A rms gives {T_I:.4g} N m with this flux"
                    + (f" and L_d = {motor.L_d:.4g} H, L_q = {motor.L_q:.4g} H" if salient else "")
                    + f" (MTPA, {100 * dev:+.0f} %; warning beyond {100 * TORQUE_WARN:g} %, error beyond "
                    f"{100 * TORQUE_ERROR:g} %): check that I_N is rms and the flux's convention"
                    + (", and the inductances' unit (a bare number is in henries)" if salient else ""),
                )
            )
    # the q-axis inductive voltage of the rated point, which no field weakening removes
    u_L = w_N * motor.L_q * abs(i_q)
    if u_L > U_L_ERROR * u_avail:
        out.append(
            Finding(
                "error",
                (src["L_q"], keys["T_N"], keys["n_N"], keys["u_dc"]),
                f"rated torque at rated speed needs w L_q i_q = {u_L:.4g} V (peak phase) across the "
                f"inductance alone, {u_L / u_avail:.3g} times the {u_avail:.4g} V available (error beyond "
                f"{U_L_ERROR:g}x; field weakening cannot lower it): check the inductance's unit (a bare "
                "number is in henries), that L is per phase (= line-to-line/2), and T_N and n_N",
            )
        )
        return out  # the rated point is not reachable: the remaining voltage findings would only repeat it
    # the voltage the rated point needs
    u_N = steady_voltage(motor, w_N, i_d, i_q)
    if emf <= EMF_ERROR * u_avail and u_N > u_avail:
        out.append(
            Finding(
                "warning",
                (keys["T_N"], keys["n_N"], keys["u_dc"]),
                f"rated torque at rated speed needs {u_N:.4g} V (peak phase, MTPA), more than the "
                f"{u_avail:.4g} V available (u_dc/sqrt(3)): the drive needs field weakening there, which "
                "the analysis (MTPA, no voltage limit) does not model",
            )
        )
    # the DC link far above what the rated point needs: a unit or another drive's inverter
    if u_N > 0 and math.isfinite(u_avail) and u_avail > UDC_WARN * u_N:  # inf: no DC link given
        out.append(
            Finding(
                "error" if u_avail > UDC_ERROR * u_N else "warning",
                (keys["u_dc"], keys["T_N"], keys["n_N"]),
                f"the inverter can apply {u_avail:.4g} V (peak phase, u_dc/sqrt(3)), {u_avail / u_N:.3g} "
                f"times the {u_N:.4g} V the rated point needs (warning beyond {UDC_WARN:g}x, error beyond "
                f"{UDC_ERROR:g}x): check u_dc's unit and that it is this drive's DC link",
            )
        )
    # mechanical time constant: an inertia off by a unit
    tau_m = motor.J * w_N / motor.p / T_N
    if not TAU_M_RANGE[0] <= tau_m <= TAU_M_RANGE[1]:
        out.append(
            Finding(
                "warning",
                (src["J"], keys["T_N"], keys["n_N"]),
                f"the mechanical time constant J w_N / (p T_N) = {tau_m:.3g} s (rated torque takes the rotor "
                f"to n_N in that time) is outside {TAU_M_RANGE[0]:g}-{TAU_M_RANGE[1]:g} s: check J's unit "
                "(kg m2, kg cm2 = 1e-4 kg m2, g cm2 = 1e-7 kg m2; a bare number is kg m2)",
            )
        )
    # samples per electrical period at the top speed
    spp = 2 * math.pi / (w_max * T_s)
    if spp < SAMPLES_WARN:
        level = "error" if spp < SAMPLES_ERROR else "warning"
        out.append(
            Finding(
                level,
                (keys["T_s"], keys["w_max"]),
                f"{spp:.3g} samples per electrical period at the top speed {w_max / (2 * math.pi):.4g} Hz "
                f"(warning below {SAMPLES_WARN:g}, error below {SAMPLES_ERROR:g}: a quarter turn per "
                "sample is the runtime observer's limit): sample faster or lower the top speed, or check "
                "the pole pairs (p = poles/2)",
            )
        )
    # electrical time constant against the sampling period
    tau = min(motor.L_d, motor.L_q) / motor.R_s
    if tau > LR_MAX_WARN:
        out.append(
            Finding(
                "error" if tau > LR_MAX_ERROR else "warning",
                (src["R_s"], src["L_d"]),
                f"L/R = {tau:.3g} s (warning beyond {LR_MAX_WARN:g} s, error beyond {LR_MAX_ERROR:g} s; PM "
                "motors have milliseconds): check R's unit (ohm, mohm) and L's (H, mH, uH)",
            )
        )
    if tau < LR_WARN * T_s:
        level = "error" if tau < LR_ERROR * T_s else "warning"
        out.append(
            Finding(
                level,
                (src["L_d"], src["R_s"], keys["T_s"]),
                f"L/R = {tau * 1e6:.4g} us is {tau / T_s:.3g} sampling periods (warning below "
                f"{LR_WARN:g}, error below {LR_ERROR:g}): the current changes too much within a sample; "
                "check R and L (per phase = line-to-line/2; mH or uH)",
            )
        )
    return out


def warning_lines(findings: list[Finding], file: str) -> list[str]:
    """The warning lines of ``findings`` (``file: keys: text``); DriveFileError for the first error."""
    for fd in findings:
        if fd.level == "error":
            raise DriveFileError(file, ", ".join(fd.keys), fd.text)
    return [fd.line(file) for fd in findings]
