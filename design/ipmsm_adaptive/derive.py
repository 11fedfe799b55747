"""The complete drive file of the speed-adaptive observer from a minimal one, each value with its rule.

A minimal drive file gives ``[drive]`` (name, kind), ``[motor]`` in datasheet terms
(design/motor_data.py), ``[rating]`` n_N and T_N or I_N, and ``[inverter]`` u_dc and f_s (the sampling
frequency). :func:`document` fills in every other key of the schema (schema.py) by the rules below,
scaled by the motor and the sampling rate, and keeps every key the file does give (a full drive file
passes through unchanged). The loader (:func:`load`) reads the document's data, so a minimal file and
the complete file ``sensorless init`` writes from it load to the same drive. The rules and their reasons:
docs/families/ipmsm_adaptive.md ("Derived drive files").

- ``[rating]``: f_N = n_N p / 60; I_N from T_N by MTPA (or T_N from I_N); U_N = the line-to-line rms
  voltage of the rated point (MTPA current for T_N at n_N, steady state); P_N = T_N 2 pi n_N / 60.
- ``[base]``: w = 2 pi f_N, u = sqrt(2/3) U_N, i = sqrt(2) I_N (peak-value scaling, as the paper).
- ``[estimate]``: the motor's values (exact estimates).
- ``[control]``: T_s = 1/f_s; bandwidths as fractions of the sampling rate, those of Piippo et al.
  (2008) Table II at 5 kHz: alpha_c = f_s/12.5 (400 Hz); speed control
  alpha_s = min(5/tau_m, alpha_fo/5), tau_m = J w_N / (p T_N) the mechanical time constant (the
  paper: 5 Hz at tau_m = 0.168 s, 5.3/tau_m), slower than the speed estimate, and with HF injection at
  most alpha_i (the injection's PI gives the estimate at low speed: the paper's 5 Hz = alpha_i); where
  that speed loop feeds back more than half of the injection's error signal (carrier.py
  ``speed_loop_feedback``), the drive band-stops its speed feedback at the carrier (simulation.py) and
  the file says so in a comment of ``[injection]``;
  T_max = 1.5 T_N (the paper 1.57 T_N).
- ``[observer]``: alpha_fo = max(f_s/100, 50/tau_m), at most f_s/20: the paper's 50 Hz at 5 kHz
  (= 53/tau_m), and fast enough for a light rotor, whose speed changes by 2.5/tau_m p.u./s at the torque
  limit against rated load: the speed estimate lags by about that over alpha_fo. The gains of the
  paper's Fig. 4 (zero, constant lambda1 = -0.5 R_s_hat, speed-dependent (16) lambda' = 2 R_s_hat,
  omega_lambda = 1 p.u.) are the baseline that ``sensorless tune`` starts from.
- ``[injection]``: on only where the saliency gives a usable error signal (19): 2 |L_q - L_d| /
  (L_q + L_d) >= SALIENCY_MIN and the current sensor sees it; carrier f_s/6 (833 Hz at 5 kHz) and u_c
  from the saliency, the sensor's noise and resolution, the inverter's voltage margin and the sampling
  rate (carrier.py: 32 V on the paper's motor, which uses 40 V), alpha_i = f_s/1000 (5 Hz), w_Delta
  1.3 x the speed up to which the observer alone (the file's gains) is unstable motoring at +-T_max
  (``_fade_out``; the paper's 0.13 p.u. where it is stable throughout); off (u_c = 0 V, with a warning
  where the sensor is the reason) otherwise.
- ``[tuning]``: torques -T_max, -T_N, 0, T_N, T_max (the torques the drive applies: gains tuned at
  +-T_N only were unstable just beyond it); the rest the documented defaults (design/envelope.py).
- ``[runtime]``: the documented defaults (schema.RUNTIME_DEFAULTS).
- ``w_Delta``'s rule names the HF correction's coupling limit where it lies inside the band
  (carrier.py ``coupling_limit``).
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Mapping
from typing import Any

from sensorless.design.drive_file import (
    DriveDocument,
    Entry,
    check_keys,
    derived_document,
    g6,
    positive,
    sampling_frequency,
    table,
    toml_value,
)
from sensorless.design.ipmsm_adaptive.carrier import (
    CARRIER_FS,
    FEEDBACK_MAX,
    SpeedLoopPath,
    carrier,
    coupling_limit,
    speed_loop_feedback,
    speed_loop_limit,
)
from sensorless.design.ipmsm_adaptive.schema import (
    I_NOISE_DEFAULT,
    RUNTIME_DEFAULTS,
    RUNTIME_RULES,
    SALIENCY_MIN,
    SECTIONS,
    IpmsmDrive,
    check_plausibility,
    load_complete,
)
from sensorless.design.motor_data import mtpa_torque, mtpa_torque_current, read_motor, steady_voltage
from sensorless.design.pmsm_schema import saliency
from sensorless.design.scenario import default_speed_filter
from sensorless.design.units import DriveFileError, parse_quantity

# the rules (module docstring); fractions of the sampling frequency f_s
ALPHA_C_FS = 1 / 12.5
ALPHA_S_TAU = 5.0  # speed-loop bandwidth x mechanical time constant (Piippo et al.: 5 Hz x 0.168 s = 5.3)
ALPHA_FO_S = 5.0  # the speed estimate (adaptation bandwidth alpha_fo) at least this much faster
ALPHA_FO_TAU = 50.0  # alpha_fo x tau_m at least (Piippo et al.: 2 pi 50 Hz x 0.168 s = 53)
ALPHA_FO_MAX_FS = 1 / 20  # alpha_fo at most f_s/20
ALPHA_FO_FS = 1 / 100
W_DELTA_PU = 0.13  # injection fade-out speed (Piippo et al.), where the observer alone holds at +-T_max
W_DELTA_EDGE = 1.3  # otherwise this much above the observer-alone stability edge at T_max (_fade_out)
W_DELTA_MAX_PU = 0.5
FADE_RULE = (
    "1.3 x {:.3g} p.u., where the observer alone (the file's gains) turns stable motoring at T_max "
    "(design/ipmsm_adaptive/derive.py _fade_out; Piippo et al.: 0.13 p.u.): the HF correction's angle "
    "error grows with speed under load, so it fades out as soon as the observer holds ({:.3g} p.u.)"
)
ALPHA_I_FO = 1 / 10
T_MAX_TN = 1.5
W_MAX_PU, W_MAX_MIN_PU = 2.0, 1.2  # the runtime top speed [p.u.]: default, and least where the voltage limits

RATING = {
    "P_N": "power",
    "U_N": "voltage",
    "I_N": "current",
    "f_N": "frequency",
    "n_N": "mech_speed",
    "T_N": "torque",
}
INVERTER = {"u_dc": "voltage", "f_s": "frequency"}
MOTOR_ORDER = ("p", "R_s", "L_d", "L_q", "psi_pm", "J")
TUNING_DEFAULTS: dict[str, Any] = {
    "speed_min": "0.05 pu",
    "speed_max": "1 pu",
    "speeds": 20,
    "directions": "both",
    "torques": ["-1 T_N", "0 T_N", "1 T_N"],  # widened to +-T_max by tuning_torques()
    "dense_factor": 4,
    "min_decay": "0 1/s",
    "breakpoints": 11,
}


class _Reader:
    """Values of the given tables, parsed with their keys named in errors."""

    def __init__(self, data: Mapping[str, Any], file: str) -> None:
        self.data, self.file = data, file

    def table(self, name: str) -> Mapping[str, Any] | None:
        if name not in self.data:
            return None
        return table(self.data, name, self.file)

    def value(self, section: str, key: str, dim: str) -> float:
        return positive(self.data[section], key, dim, self.file, section)


def document(data: Mapping[str, Any], file: str, w_delta_pu: float | None = None) -> DriveDocument:
    """The complete drive document of ``data`` (module docstring); DriveFileError naming the key for
    what is missing or wrong. Each key given is kept as written; each derived one carries its rule.
    ``w_delta_pu``: the injection's fade-out speed [p.u.] the second pass places (:func:`_fade_out`)."""
    check_keys(data, SECTIONS, file, "")
    doc = derived_document(data, file, "docs/families/ipmsm_adaptive.md")
    r = _Reader(data, file)

    # ------------------------------------------------------------------ motor (datasheet terms)
    motor_t = table(data, "motor", file)
    m = read_motor(motor_t, file)
    sec = doc.section("motor", "the true motor, per phase of the equivalent wye (docs/motor_data.md)")
    if any(k not in MOTOR_ORDER for k in motor_t):
        given = "given as: " + ", ".join(f"{k} = {toml_value(v)}" for k, v in motor_t.items())
        doc.notes["motor"] += textwrap.wrap(given, 100)
    units = {"R_s": "ohm", "L_d": "H", "L_q": "H", "psi_pm": "Vs", "J": "kgm2"}
    for k in MOTOR_ORDER:
        if k in motor_t:
            sec[k] = Entry(motor_t[k], given=True)
        elif k == "p":
            sec[k] = Entry(m.p, m.rules.get("p", ""))
        else:
            sec[k] = Entry(f"{g6(getattr(m, k))} {units[k]}", m.rules.get(k, f"from {m.source[k]}"))

    # ------------------------------------------------------------------ rating
    rating_t = table(data, "rating", file)
    check_keys(rating_t, tuple(RATING), file, "rating.")
    if "n_N" not in rating_t:
        raise DriveFileError(file, "rating.n_N", "missing key (rated mechanical speed, e.g. '3000 rpm')")
    if "T_N" not in rating_t and "I_N" not in rating_t:
        raise DriveFileError(
            file, "rating.T_N", "missing key (rated torque T_N, or the rated current I_N in A rms)"
        )
    n_N = r.value("rating", "n_N", "mech_speed")
    f_N = n_N * m.p / 60
    if "T_N" in rating_t:
        T_N = r.value("rating", "T_N", "torque")
        rule_T = ""
    else:
        I_given = r.value("rating", "I_N", "current")
        T_N = float(g6(mtpa_torque(math.sqrt(2) * I_given, m)))
        rule_T = "MTPA torque at sqrt(2) I_N"
    i_d, i_q = mtpa_torque_current(T_N, m)
    w_N = 2 * math.pi * f_N
    U_N = math.sqrt(1.5) * steady_voltage(m, w_N, i_d, i_q)
    derived_rating = {
        "P_N": (f"{g6(T_N * 2 * math.pi * n_N / 60)} W", "T_N 2 pi n_N / 60"),
        "U_N": (
            f"{g6(U_N)} V",
            "line-to-line rms voltage at T_N (MTPA) and n_N in steady state",
        ),
        "I_N": (f"{g6(math.hypot(i_d, i_q) / math.sqrt(2))} A", "rms of the MTPA current for T_N"),
        "f_N": (f"{g6(f_N)} Hz", "n_N p / 60"),
        "T_N": (f"{g6(T_N)} Nm", rule_T),
    }
    sec = doc.section("rating", "rated values; 1 p.u. speed = the rated speed")
    for k in RATING:
        if k in rating_t:
            sec[k] = Entry(rating_t[k], given=True)
        else:
            sec[k] = Entry(*derived_rating[k])

    def rated(k: str, dim: str) -> float:
        if k in rating_t:
            return r.value("rating", k, dim)
        x, _ = parse_quantity(sec[k].value, dim, file=file, key=f"rating.{k}")
        return x

    U_N, I_N, f_N_used = rated("U_N", "voltage"), rated("I_N", "current"), rated("f_N", "frequency")

    # ------------------------------------------------------------------ inverter and control
    inv_t = r.table("inverter")
    ctl_t = r.table("control") or {}
    if inv_t is not None:
        check_keys(inv_t, tuple(INVERTER), file, "inverter.")
    f_s = sampling_frequency(inv_t or {}, ctl_t, file)[0]
    u_dc_raw, u_dc_rule = _dc_link(r, inv_t, ctl_t, file)
    u_dc_key = "inverter.u_dc" if inv_t is not None and "u_dc" in inv_t else "control.u_dc"
    u_dc = parse_quantity(u_dc_raw, "voltage", file=file, key=u_dc_key)[0]

    # ------------------------------------------------------------------ base
    base_t = r.table("base") or {}
    sec = doc.section("base", "per-unit bases, peak-value scaling")
    derived_base = {
        "w": (f"{g6(f_N_used)} Hz", "2 pi f_N: 1 p.u. speed"),
        "u": (f"{g6(math.sqrt(2 / 3) * U_N)} V", "sqrt(2/3) U_N, peak phase voltage"),
        "i": (f"{g6(math.sqrt(2) * I_N)} A", "sqrt(2) I_N, peak current"),
    }
    for k, (v, rule) in derived_base.items():
        sec[k] = Entry(base_t[k], given=True) if k in base_t else Entry(v, rule)
    _extra(sec, base_t, derived_base)
    i_base = math.sqrt(2) * I_N if "i" not in base_t else r.value("base", "i", "current")

    # ------------------------------------------------------------------ estimate
    est_t = r.table("estimate") or {}
    sec = doc.section("estimate", "the observer's parameter estimates (kept apart from the motor)")
    for k in ("R_s", "L_d", "L_q", "psi_pm"):
        sec[k] = (
            Entry(est_t[k], given=True) if k in est_t else Entry(doc.sections["motor"][k].value, "= [motor]")
        )
    _extra(sec, est_t, ("R_s", "L_d", "L_q", "psi_pm"))

    # ------------------------------------------------------------------ injection: on or off (the speed
    # loop's rule below depends on it; its section is written after the observer's)
    inj_t = r.table("injection") or {}
    xi = saliency(m.L_d, m.L_q)
    usable = xi >= SALIENCY_MIN
    cw = None
    if usable and "u_c" not in inj_t:  # a drive file that gives u_c keeps it (a preset is complete)

        def rate(section: str, key: str, default: float, t: Mapping[str, Any]) -> float:
            raw = t.get(key)
            if isinstance(raw, str) and raw.strip().endswith("pu"):  # per unit of the rated speed
                return (
                    parse_quantity(raw.strip()[:-2], "dimensionless", file=file, key=f"{section}.{key}")[0]
                    * w_N
                )
            return r.value(section, key, "angular") if key in t else default

        alpha_i = rate("injection", "alpha_i", 2 * math.pi * ALPHA_I_FO * ALPHA_FO_FS * f_s, inj_t)
        w_delta = rate("injection", "w_Delta", (w_delta_pu or W_DELTA_PU) * w_N, inj_t)
        w_c = rate("injection", "w_c", 2 * math.pi * CARRIER_FS * f_s, inj_t)
        i_noise = r.value("control", "i_noise", "current") if "i_noise" in ctl_t else I_NOISE_DEFAULT * i_base
        i_res = r.value("control", "i_resolution", "current") if "i_resolution" in ctl_t else 0.0
        cw = carrier(m, f_s, u_dc, T_N, w_delta, alpha_i, i_noise, i_res, i_base, w_c / (2 * math.pi))
    if cw is not None and cw.warning:
        doc.context["carrier_warning"] = f"{file}: injection.u_c: {cw.warning}"
    on = cw.u_c > 0 if cw is not None else usable
    # ------------------------------------------------------------------ control
    tau_m = m.J * w_N / m.p / T_N  # rated speed at rated torque: the mechanical time constant
    alpha_fo = min(
        max(2 * math.pi * ALPHA_FO_FS * f_s, ALPHA_FO_TAU / tau_m), 2 * math.pi * ALPHA_FO_MAX_FS * f_s
    )
    alpha_s = min(ALPHA_S_TAU / tau_m, alpha_fo / ALPHA_FO_S)
    alpha_s_rule = (
        f"speed control min({ALPHA_S_TAU:g}/tau_m, alpha_fo/{ALPHA_FO_S:g}), tau_m = J w_N/(p T_N) = "
        f"{g6(tau_m)} s (Piippo et al.: 5 Hz, tau_m 0.17 s)"
    )
    if on and cw is not None and alpha_i < alpha_s:
        # inside the injection's band the angle and speed come through its PI (21)-(22): a speed loop
        # faster than it loses the rotor (docs/families/ipmsm_adaptive.md, "The speed loop against ...")
        alpha_s_rule = (
            f"speed control min({ALPHA_S_TAU:g}/tau_m, alpha_fo/{ALPHA_FO_S:g}, alpha_i): no faster than the "
            "injection's PI (21)-(22), which gives the estimate at low speed (Piippo et al.: 5 Hz = "
            f"alpha_i); tau_m = J w_N/(p T_N) = {g6(tau_m)} s; the first two: "
            f"{g6(alpha_s / (2 * math.pi))} Hz"
        )
        alpha_s = alpha_i
    alpha_c = (
        r.value("control", "alpha_c", "angular") if "alpha_c" in ctl_t else 2 * math.pi * ALPHA_C_FS * f_s
    )
    speed_notch = ""
    if on and cw is not None:
        # the speed loop feeds the carrier back into the error signal (19): carrier.py speed_loop_feedback
        obs_given = r.table("observer") or {}
        a_fo = r.value("observer", "alpha_fo", "angular") if "alpha_fo" in obs_given else alpha_fo
        a_s = r.value("control", "alpha_s", "angular") if "alpha_s" in ctl_t else alpha_s
        loop = SpeedLoopPath(a_fo, m.L_q, m.psi_pm, m.J, m.p, alpha_c, 2 * math.pi * cw.f_c, 1 / f_s)
        share = speed_loop_feedback(loop, a_s, default_speed_filter(a_s))
        if share > FEEDBACK_MAX:
            speed_notch = (
                f"the drive band-stops its speed feedback at w_c (as its current feedback): else its "
                f"speed loop ({g6(a_s / (2 * math.pi))} Hz, filter max(50 Hz, 10 alpha_s)) feeds back "
                f"G = {share:.3g} "
                f"of the error signal (19) against it (carrier.py speed_loop_feedback; above 1 the injection "
                f"pushes the angle away); without one, alpha_s <= "
                f"{g6(speed_loop_limit(loop, default_speed_filter) / (2 * math.pi))} Hz keeps G <= "
                f"{FEEDBACK_MAX:g}"
            )
    sec = doc.section("control", "control system; bandwidths as fractions of the sampling rate f_s")
    derived_ctl = {
        "T_s": (f"{g6(1e6 / f_s)} us", f"1/f_s, f_s = {g6(f_s / 1e3)} kHz"),
        "alpha_c": (
            f"{g6(ALPHA_C_FS * f_s)} Hz",
            "current control f_s/12.5 (Piippo et al.: 400 Hz at 5 kHz)",
        ),
        "alpha_s": (f"{g6(alpha_s / (2 * math.pi))} Hz", alpha_s_rule),
        "T_max": (f"{g6(T_MAX_TN * T_N)} Nm", "1.5 T_N (Piippo et al.: 1.57 T_N)"),
        "u_dc": (u_dc_raw, u_dc_rule),
    }
    for k, (v, rule) in derived_ctl.items():
        sec[k] = Entry(ctl_t[k], given=True) if k in ctl_t else Entry(v, rule)
    if "i_noise" in ctl_t:
        sec["i_noise"] = Entry(ctl_t["i_noise"], given=True)
    else:
        doc.optional.setdefault("control", []).append(
            f'i_noise = "{g6(I_NOISE_DEFAULT * i_base)} A"  # optional: current-sensor noise, rms per axis '
            "and sample (default 0.3 % of base i)"
        )
    if "i_resolution" in ctl_t:
        sec["i_resolution"] = Entry(ctl_t["i_resolution"], given=True)
    else:
        doc.optional.setdefault("control", []).append(
            'i_resolution = "..."  # optional: current-sensor resolution, A per converter step (sizes the '
            "HF carrier with i_noise)"
        )
    _extra(sec, ctl_t, (*derived_ctl, "i_noise", "i_resolution"))

    # ------------------------------------------------------------------ observer and gains
    obs_t = r.table("observer") or {}
    sec = doc.section("observer", "speed-adaptive observer, eqs. (4)-(10)")
    alpha_fo_hz = alpha_fo / (2 * math.pi)
    derived_obs = {
        "alpha_fo": (
            f"{g6(alpha_fo_hz)} Hz",
            f"max(f_s/100, {ALPHA_FO_TAU:g}/tau_m), at most f_s/20 (Piippo et al.: 50 Hz at 5 kHz), eq. (10)",
        ),
        "gain": ("speed", "the speed-dependent gain (16)"),
    }
    for k, (v, rule) in derived_obs.items():
        sec[k] = Entry(obs_t[k], given=True) if k in obs_t else Entry(v, rule)
    _extra(sec, obs_t, (*derived_obs, "gains"))
    if "gains" in obs_t:
        gains_t = table(obs_t, "gains", file, "observer.")
        for name, g in gains_t.items():
            sec = doc.section(f"observer.gains.{name}")
            if isinstance(g, dict):
                sec.update({k: Entry(v, given=True) for k, v in g.items()})
            else:
                raise DriveFileError(file, f"observer.gains.{name}", "expected a table")
    else:
        doc.section("observer.gains.zero", "baseline gains: Piippo et al. (2008) Fig. 4; `sensorless tune`")
        doc.section("observer.gains.constant").update(
            lambda1=Entry("-0.5 R_s_hat", "Fig. 4(b)"), lambda2=Entry("0 ohm", "Fig. 4(b)")
        )
        doc.section("observer.gains.speed").update(
            lambda_p=Entry("2 R_s_hat", "Fig. 4(c), eq. (16)"), w_lambda=Entry("1 pu", "Fig. 4(c)")
        )

    # ------------------------------------------------------------------ injection (section below)
    note = f"HF injection, Section V: saliency 2|L_q - L_d|/(L_q + L_d) = {xi:.3g} " + (
        f">= {SALIENCY_MIN:g}: " + ("on" if on else "but too small for the current sensor: off")
        if usable
        else f"< {SALIENCY_MIN:g}: no usable error signal (19), off"
    )
    sec = doc.section("injection", note)
    f_c = cw.f_c if cw is not None else CARRIER_FS * f_s
    derived_inj = {
        "w_c": (f"{g6(f_c)} Hz", cw.rule_f if cw is not None else "carrier f_s/6 (Piippo et al.: 833 Hz)"),
        "u_c": (
            (f"{g6(cw.u_c)} V", cw.rule_u)
            if cw is not None
            else ("0 V", "off: the motor's saliency is too small (u_c > 0 turns it on)")
        ),  # (u_c given: kept below)
        "alpha_i": (
            f"{g6(ALPHA_I_FO * ALPHA_FO_FS * f_s)} Hz",
            "f_s/1000 (Piippo et al.: 5 Hz at 5 kHz), eq. (22)",
        ),
        "w_Delta": (
            f"{g6(w_delta_pu or W_DELTA_PU)} pu",
            (
                FADE_RULE.format(w_delta_pu / W_DELTA_EDGE, w_delta_pu)
                if w_delta_pu
                else "Piippo et al.: fades out at 0.13 p.u."
            )
            + _coupling(m, T_N, w_N, on, w_delta_pu or W_DELTA_PU),
        ),
    }
    for k, (v, rule) in derived_inj.items():
        sec[k] = Entry(inj_t[k], given=True) if k in inj_t else Entry(v, rule)
    _extra(sec, inj_t, derived_inj)
    if speed_notch:
        doc.optional.setdefault("injection", []).append(speed_notch)

    # ------------------------------------------------------------------ runtime, tuning
    rt_t = r.table("runtime") or {}
    sec = doc.section("runtime", "the discrete-time observer that runs (docs/families/ipmsm_adaptive.md)")
    # the top speed: 2 p.u., but not beyond what the inverter's voltage can reach (1.1 x the no-load
    # speed u_dc/(sqrt(3) psi_pm)), and at least 1.2 p.u.
    w_top = 1.1 * u_dc / math.sqrt(3) / m.psi_pm / w_N
    w_max_pu = min(W_MAX_PU, max(W_MAX_MIN_PU, w_top))
    derived_rt = dict(RUNTIME_DEFAULTS)
    rules_rt = dict(RUNTIME_RULES)
    if w_max_pu < W_MAX_PU:
        derived_rt["w_max"] = f"{g6(w_max_pu)} pu"
        rules_rt["w_max"] = (
            f"top speed: 1.1 u_dc/(sqrt(3) psi_pm), the no-load speed the DC link reaches, in p.u. (at "
            f"most {W_MAX_PU:g}, at least {W_MAX_MIN_PU:g} p.u.); the runtime state's speed bounds"
        )
    for k, v in derived_rt.items():
        sec[k] = Entry(rt_t[k], given=True) if k in rt_t else Entry(v, rules_rt[k])
    _extra(sec, rt_t, RUNTIME_DEFAULTS)
    tu_t = r.table("tuning")
    sec = doc.section("tuning", "envelope and constraints of `sensorless tune` (design/envelope.py)")
    if tu_t is None:
        T_max = r.value("control", "T_max", "torque") if "T_max" in ctl_t else T_MAX_TN * T_N
        for k, v in TUNING_DEFAULTS.items():
            sec[k] = Entry(v, "default")
        sec["torques"] = Entry(tuning_torques(T_max / T_N), TORQUES_RULE)
    else:
        sec.update({k: Entry(v, given=True) for k, v in tu_t.items()})
    doc.context["motor"] = m
    doc.context["keys"] = {
        "n_N": "rating.n_N",
        "T_N": "rating.T_N" if "T_N" in rating_t else "rating.I_N",
        "I_N": "rating.I_N",
        "f_N": "rating.f_N",
        "u_dc": "inverter.u_dc" if inv_t is not None and "u_dc" in inv_t else "control.u_dc",
        "T_s": "inverter.f_s" if inv_t is not None and "f_s" in inv_t else "control.T_s",
        "w_max": "runtime.w_max",
    }
    doc.context["given"] = {"I_N": "I_N" in rating_t and "T_N" in rating_t, "f_N": "f_N" in rating_t}
    if cw is not None and cw.u_c > 0 and "w_Delta" not in inj_t and w_delta_pu is None:
        T_max = r.value("control", "T_max", "torque") if "T_max" in ctl_t else T_MAX_TN * T_N
        edge = _fade_out(doc, file, T_max, w_N)
        if edge > 0:
            return document(data, file, w_delta_pu=min(W_DELTA_MAX_PU, W_DELTA_EDGE * edge))
    return doc


def _fade_out(doc: DriveDocument, file: str, T_max: float, w_N: float) -> float:
    """The speed [p.u.] below which the observer alone, with the drive file's gains, has a right-half-
    plane pole motoring at T_max (0 if none up to W_DELTA_MAX_PU): the injection must carry it there.

    Why (measured on the start check, 0 to 0.5 p.u. against T_N accelerating at ~T_max): the
    HF correction's angle error grows with speed under that load (the observer's answer to it goes with
    psi_d, near 0 at T_max on a strongly salient motor), so fading out later hands the observer a
    larger error (prius of docs/examples/motors: w_Delta 0.13 p.u. lost the rotor, 0.06-0.09 p.u.
    held it within 2.6 deg); fading out before this edge hands it over where it is unstable (the test
    traction motor: edge 0.12 p.u., lost at 0.13 p.u.)."""
    import numpy as np
    from sensorless.design.ipmsm_adaptive.linearize import linearize, unstable_bands

    data = doc.data()
    drive = load_complete(data, file, "", str(data["drive"]["kind"]))
    w = np.linspace(0.0, W_DELTA_MAX_PU * w_N, 201)  # 0.0025 p.u. steps: the rule needs no finer edge
    # motoring both ways: (w, +T_max) and (-w, -T_max), one linearization
    s = linearize(drive, np.concatenate([w, -w]), np.repeat([T_max, -T_max], w.size))
    edge = 0.0
    for half in (s.max_real[: w.size], s.max_real[w.size :]):
        tol = 1e-9 * float(np.nanmax(np.abs(s.poles)))
        for _lo, hi in unstable_bands(w, half, tol):
            edge = max(edge, hi / w_N)
    return edge


def _coupling(m: Any, T_N: float, w_N: float, on: bool, w_delta_pu: float = W_DELTA_PU) -> str:
    """The w_Delta rule's note where the HF correction turns sign regenerating at T_N inside the band
    (carrier.py ``coupling_limit``)."""
    w1 = coupling_limit(m, T_N) / w_N
    if not on or w1 >= w_delta_pu:
        return ""
    return (
        f"; regenerating at T_N the HF correction (20) holds only below (R_s psi_d)/(L_d L_q i_q) = "
        f"{w1:.3g} p.u. (carrier.py coupling_limit): crossing zero passes {w1:.3g}-{w_delta_pu:.3g} p.u. "
        "in a transient, but a regenerating speed held there under load drifts off (its growth rate: "
        "`sensorless report`)"
    )


TORQUES_RULE = (
    "the torques the drive applies: +-T_max (the speed loop's limit, reached in every acceleration) and "
    "+-T_N, as the report judges +-1.5 T_N; gains tuned at +-T_N only were unstable just beyond it (a "
    "traction IPMSM lost the rotor at 1 p.u. after an acceleration at T_max)"
)


def tuning_torques(k_max: float) -> list[str]:
    """The tuning envelope's torques: +-k_max T_N (the torque limit T_max in T_N), +-T_N where it lies
    within, and zero (TORQUES_RULE)."""
    ks = sorted({0.0, k_max, -k_max, *((1.0, -1.0) if k_max > 1 else ())})
    return [f"{g6(k)} T_N" for k in ks]


def _extra(sec: dict[str, Entry], given: Mapping[str, Any], known: Any) -> None:
    """Keys given beyond the known ones, kept (the strict loader names them as unknown)."""
    for k, v in given.items():
        if k not in known and k not in sec:
            sec[k] = Entry(v, given=True)


def _dc_link(r: _Reader, inv: Mapping[str, Any] | None, ctl: Mapping[str, Any], file: str) -> tuple[Any, str]:
    """The DC-link voltage as written and its rule: [inverter] u_dc or [control] u_dc."""
    if inv is not None and "u_dc" in inv:
        v = r.value("inverter", "u_dc", "voltage")
        if "u_dc" in ctl and abs(r.value("control", "u_dc", "voltage") / v - 1) > 1e-9:
            raise DriveFileError(file, "inverter.u_dc", "differs from control.u_dc: give one of them")
        return inv["u_dc"], "from [inverter] u_dc"
    if "u_dc" in ctl:
        return ctl["u_dc"], ""
    raise DriveFileError(file, "inverter.u_dc", "missing key (DC-link voltage, e.g. '310 V')")


def load(data: Mapping[str, Any], file: str, digest: str, kind: str) -> IpmsmDrive:
    """Validate a parsed drive TOML of this family: a minimal one is completed first (derive.py), then
    the complete data is loaded strictly and checked for plausibility (design/plausibility.py)."""
    doc = document(data, file)
    with doc.blaming_given_keys(data, file):
        drive = load_complete(doc.data(), file, digest, kind)
    warnings = check_plausibility(drive, doc.context)
    if "carrier_warning" in doc.context:
        warnings = [*warnings, doc.context["carrier_warning"]]
    return dataclasses.replace(drive, warnings=tuple(warnings)) if warnings else drive
