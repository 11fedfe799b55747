"""The drive file of the flux-observer family: a minimal file completed by rules, then loaded strictly.

The format (agreed with the firmware import/export, docs/families/pmsm_flux_observer.md "Drive files"):
``[drive]``; ``[motor]`` in the shared datasheet terms (design/motor_data.py ``read_motor``; J may be
left out); ``[rating]`` n_N and T_N or I_N (optional); ``[inverter]`` u_dc and f_s; ``[observer]``
firmware, correction, inductance, lambda_adaptation, T_obs; ``[estimate]`` (optional, the shared keys
R_s, L_d, L_q, psi_pm: what the firmware was given; default the motor's); ``[gains]`` (the law and its
gains, in the firmware's terms; default the firmware's defaults); ``[control]`` and ``[envelope]``
(optional: the shared drive loop's controllers, the analysed speeds and torques). :func:`document`
derives every missing value with its rule; :func:`load` reads the complete document.

Rules (the constants below; reasons in the family doc):
- J = TAU_M p T_N / w_N: a mechanical time constant of TAU_M (firmware configurations carry no inertia);
- n_N = N_SPEED x the no-load speed u_dc / (sqrt(3) psi_pm p) (the voltage the inverter has);
- I_N = I_DROP u_dc / R_s (the current whose resistive drop is I_DROP of the DC link), T_N its MTPA torque;
- T_obs = 1/f_s; control: alpha_c = ALPHA_C/T_obs, alpha_s = min(alpha_c/ALPHA_S_DIV, the PLL's slowest
  pole its speed estimate shows / 4) (the speed loop closes on the PLL's speed), T_max = 2 T_N;
- envelope: |speed| ENV_SPEEDS p.u. of n_N, torques 0 and T_N.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sensorless.design.drive_file import (
    DriveDocument,
    Entry,
    check_keys,
    derived_document,
    g6,
    load_section,
    positive,
    q,
    quantities,
    table,
)
from sensorless.design.envelope import Envelope, SpeedRule
from sensorless.design.motor_data import mtpa_torque, read_motor
from sensorless.design.plausibility import plausibility, warning_lines
from sensorless.design.pmsm_flux_observer.laws import LAW_KEYS, law_now, parse_law, section_gains
from sensorless.design.pmsm_schema import (
    PmsmControl,
    PmsmDriveProperties,
    PmsmEstimate,
    PmsmMotor,
    PmsmRating,
    speed_ramp,
)
from sensorless.design.units import DriveFileError
from sensorless.symbolic.pmsm_flux_observer.observer import CORRECTIONS, INDUCTANCES

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.startup import StartupSettings

PAGE = "docs/families/pmsm_flux_observer.md"
SECTIONS = ("drive", "motor", "rating", "inverter", "observer", "estimate", "gains", "control", "envelope")
FIRMWARES = ("odrive", "vesc", "simplefoc", "generic")
# each firmware's observer: (correction, inductance rule, lambda adaptation, law). VESC: ORTEGA_ORIGINAL
# (foc_observer_type 0), the observer whose gain its law sets and the analysis judges; its newer default
# MXLEMMING_LAMBDA_COMP is the box clamp (no gain, no linearization): correction = "box-clamp" and
# lambda_adaptation = true in the file for it
FIRMWARE_DEFAULTS = {
    "odrive": ("gradient", "fixed", False, "constant"),
    "vesc": ("clamped-gradient", "interpolated", False, "voltage-scaled"),
    "simplefoc": ("box-clamp", "q-axis", False, "constant"),
    "generic": ("gradient", "fixed", False, "constant"),
}
TAU_M = 0.1  # [s] mechanical time constant of the J rule
N_SPEED = 0.8  # rated speed / no-load speed at the DC link
I_DROP = 0.05  # R_s I_N / u_dc
ALPHA_C = 0.2  # alpha_c T_obs
ALPHA_S_DIV = 16.0
PLL_SPEED_LOOP = 4.0  # the PLL's slowest root at least this multiple of the speed loop's bandwidth
PLL_CANCELLED = 0.1  # weight of the PLL's slow root in its speed estimate below which it is ignored
T_MAX_TN = 2.0
ENV_SPEEDS = (0.05, 1.0, 12)  # speed_min, speed_max [p.u.], speeds per direction


@dataclass(frozen=True)
class ObserverSettings:
    """[observer]: whose variant, and its period."""

    firmware: str = q("choice", doc="odrive | vesc | simplefoc | generic")
    correction: str = q("choice", doc="gradient | clamped-gradient | box-clamp")
    # the [observer] key ``inductance`` (the shared word "inductance" is a dimension's name)
    inductance_rule: str = q("choice", doc="fixed | q-axis | interpolated")
    T_obs: float = q("time", doc="observer and PLL period [s]")
    lambda_adaptation: bool = field(default=False, metadata={"dim": "bool"})


@dataclass(frozen=True)
class EnvelopeKeys:
    """[envelope] as the file gives it (speeds in both directions), made the drive's
    :class:`~sensorless.design.envelope.Envelope` at load."""

    speed_min: float = q("angular", doc="smallest |speed| [rad/s]")
    speed_max: float = q("angular", doc="largest |speed| [rad/s]")
    speeds: int = q("integer", doc="speeds per direction")
    torques: tuple[float, ...] = field(default=(), metadata={"dim": "torque"})


@dataclass(frozen=True)
class FluxObserverDrive(PmsmDriveProperties):
    """A drive of the flux-observer family (SI; speeds electrical); its ``Drive`` properties are the shared
    PMSM drive's (design/pmsm_schema.py)."""

    name: str
    kind: str
    source: str
    file: str
    rating: PmsmRating
    motor: PmsmMotor
    estimate: PmsmEstimate
    control: PmsmControl
    observer: ObserverSettings
    gains_table: Mapping[str, Any]  # the [gains] section as written (read by gains.py)
    envelope: Envelope  # [envelope], SI (design/envelope.py)
    digest: str = ""
    warnings: tuple[str, ...] = ()
    i_noise: float = 0.0  # [control] i_noise, the current-sensor noise [A rms per axis]; 0: the default
    startup: StartupSettings | None = None  # [startup] of the file (design/startup.py) or None: the rules


def _choice(t: Mapping[str, Any], k: str, allowed: tuple[str, ...], default: str, file: str) -> str:
    v = t.get(k, default)
    if not isinstance(v, str) or v not in allowed:
        raise DriveFileError(file, f"observer.{k}", f"{v!r} is not one of: {', '.join(allowed)}")
    return v


def _keep(sec: dict[str, Entry], given: Mapping[str, Any], derived: Mapping[str, tuple[Any, str]]) -> None:
    for k, (v, rule) in derived.items():
        sec[k] = Entry(given[k], given=True) if k in given else Entry(v, rule)
    for k, v in given.items():
        if k not in sec:
            sec[k] = Entry(v, given=True)


def document(data: Mapping[str, Any], file: str) -> DriveDocument:
    """The complete drive document of a (minimal) drive file (module docstring)."""
    check_keys(data, SECTIONS, file, "")
    doc = derived_document(data, file, PAGE)
    motor_t = dict(table(data, "motor", file))
    inv_t = table(data, "inverter", file) if "inverter" in data else {}
    check_keys(inv_t, ("u_dc", "f_s"), file, "inverter.")
    for k, ex in (("u_dc", "24 V"), ("f_s", "8 kHz")):
        if k not in inv_t:
            raise DriveFileError(file, f"inverter.{k}", f"missing key (e.g. '{ex}')")
    u_dc = positive(inv_t, "u_dc", "voltage", file, "inverter")
    f_s = positive(inv_t, "f_s", "frequency", file, "inverter")
    # the motor without its inertia first (the J rule needs the rating)
    m = read_motor({**motor_t, "J": motor_t.get("J", "1 kgm2")}, file)

    rating_t = table(data, "rating", file) if "rating" in data else {}
    check_keys(rating_t, ("n_N", "T_N", "I_N"), file, "rating.")
    w0 = u_dc / (math.sqrt(3) * m.psi_pm * m.p)  # no-load mechanical speed [rad/s]
    n_N = (
        positive(rating_t, "n_N", "mech_speed", file, "rating")
        if "n_N" in rating_t
        else N_SPEED * w0 * 30 / math.pi
    )
    if "T_N" in rating_t:
        T_N, t_rule = positive(rating_t, "T_N", "torque", file, "rating"), ""
    else:
        I_N = (
            positive(rating_t, "I_N", "current", file, "rating")
            if "I_N" in rating_t
            else I_DROP * u_dc / m.R_s
        )
        T_N = mtpa_torque(math.sqrt(2) * I_N, m)
        t_rule = f"MTPA torque at I_N = {g6(I_N)} A rms" + (
            "" if "I_N" in rating_t else f" = {I_DROP:g} u_dc / R_s (rule)"
        )
    sec = doc.section("rating", "rated values; 1 p.u. speed = n_N")
    _keep(
        sec,
        rating_t,
        {
            "n_N": (f"{g6(n_N)} rpm", f"{N_SPEED:g} x the no-load speed u_dc/(sqrt(3) psi_pm p)"),
            "T_N": (f"{g6(T_N)} Nm", t_rule),
        },
    )
    w_N = n_N * math.pi / 30
    sec = doc.section("motor", "the true motor (shared PMSM datasheet keys, docs/motor_data.md)")
    _keep(sec, motor_t, {})
    if "J" not in motor_t:
        J = TAU_M * T_N / w_N
        sec["J"] = Entry(f"{g6(J)} kgm2", f"tau_m T_N / w_N with tau_m = {TAU_M:g} s (no inertia given)")

    doc.section("inverter", "DC link and the firmware's control sampling frequency").update(
        {k: Entry(v, given=True) for k, v in inv_t.items()}
    )

    obs_t = table(data, "observer", file) if "observer" in data else {}
    check_keys(
        obs_t, ("firmware", "correction", "inductance", "lambda_adaptation", "T_obs"), file, "observer."
    )
    fw = _choice(obs_t, "firmware", FIRMWARES, "generic", file)
    corr, rule, adapt, law = FIRMWARE_DEFAULTS[fw]
    sec = doc.section("observer", "the firmware's observer variant (docs/families/pmsm_flux_observer.md)")
    _keep(
        sec,
        obs_t,
        {
            "firmware": (
                "generic",
                "no firmware given (sensorless init --firmware vesc|odrive|simplefoc, or this key): "
                "the gradient observer of Lee et al. (2010) with ODrive's gains",
            ),
            "correction": (corr, f"{fw}'s observer"),
            "inductance": (rule, f"{fw}'s inductance rule"),
            "lambda_adaptation": (adapt, f"{fw}'s default"),
            "T_obs": (f"{g6(1e6 / f_s)} us", "1/f_s"),
        },
    )
    T_obs = positive(obs_t, "T_obs", "time", file, "observer") if "T_obs" in obs_t else 1 / f_s

    est_t = table(data, "estimate", file) if "estimate" in data else {}
    check_keys(est_t, ("R_s", "L_d", "L_q", "psi_pm"), file, "estimate.")
    sec = doc.section("estimate", "what the firmware was given (the observer's model)")
    _keep(
        sec,
        est_t,
        {
            # SI numbers in full precision: exact estimates are the motor's values to the last bit
            "R_s": (m.R_s, "= motor [ohm]"),
            "L_d": (m.L_d, "= motor [H]"),
            "L_q": (m.L_q, "= motor [H]"),
            "psi_pm": (m.psi_pm, "= motor [V s]"),
        },
    )
    psi_hat = positive(est_t, "psi_pm", "flux", file, "estimate") if "psi_pm" in est_t else m.psi_pm

    gains_t = dict(table(data, "gains", file)) if "gains" in data else {}
    laws = " | ".join(LAW_KEYS)
    sec = doc.section("gains", f"the observer's gains in the firmware's terms ({laws})")
    if "law" in gains_t:
        gains_t["law"] = law_now(gains_t["law"], file)  # a former name written as the name now
        _keep(sec, gains_t, {})
    else:
        if gains_t:
            raise DriveFileError(file, "gains.law", f"missing key ({laws})")
        for k, (v, r) in default_gains(law, psi_hat).items():
            sec[k] = Entry(v, r)

    ctl_t = table(data, "control", file) if "control" in data else {}
    check_keys(ctl_t, ("alpha_c", "alpha_s", "T_max", "i_noise", "speed_ramp"), file, "control.")
    alpha_c = (
        positive(ctl_t, "alpha_c", "angular", file, "control") if "alpha_c" in ctl_t else ALPHA_C / T_obs
    )
    pll_slow = slowest_pll_pole(doc.sections["gains"], file)
    sec = doc.section("control", "the shared drive loop's controllers (simulation only)")
    _keep(
        sec,
        ctl_t,
        {
            "alpha_c": (f"{g6(ALPHA_C / T_obs)} rad/s", f"{ALPHA_C:g}/T_obs"),
            "alpha_s": (
                f"{g6(min(alpha_c / ALPHA_S_DIV, pll_slow / PLL_SPEED_LOOP))} rad/s",
                f"min(alpha_c/{ALPHA_S_DIV:g}, the PLL's pole {g6(pll_slow)} 1/s / {PLL_SPEED_LOOP:g}): the "
                "speed loop closes on the PLL's speed (voltage-scaled: the fast root where the PI's "
                "zero nearly cancels the slow one in the angle; the report names the slow root's lag in the "
                "speed)",
            ),
            "T_max": (f"{g6(T_MAX_TN * T_N)} Nm", f"{T_MAX_TN:g} T_N"),
        },
    )
    env_t = table(data, "envelope", file) if "envelope" in data else {}
    check_keys(env_t, ("speed_min", "speed_max", "speeds", "torques"), file, "envelope.")
    sec = doc.section("envelope", "operating points of analysis and tuning (both directions)")
    _keep(
        sec,
        env_t,
        {
            "speed_min": (f"{ENV_SPEEDS[0]:g} pu", "rule"),
            "speed_max": (f"{ENV_SPEEDS[1]:g} pu", "rule"),
            "speeds": (ENV_SPEEDS[2], "rule"),
            "torques": (["0 Nm", f"{g6(T_N)} Nm"], "0 and T_N"),
        },
    )
    return doc


def _speed_keys(data: Mapping[str, Any], m: Any) -> str:
    """The keys the user wrote that set the highest speed and the observer's period (a derived
    value's error names them, not ``envelope.speed_max`` of a file that does not give it)."""
    env, rating = (data.get(s, {}) for s in ("envelope", "rating"))
    speed = ["envelope.speed_max"] if isinstance(env, Mapping) and "speed_max" in env else []
    if isinstance(rating, Mapping) and "n_N" in rating:
        speed.append("rating.n_N")
    else:  # n_N from the no-load speed u_dc/(sqrt(3) psi_pm p)
        speed += ["inverter.u_dc", m.source.get("psi_pm", "motor.psi_pm")]
    speed.append(m.source.get("p", "motor.p"))
    return ", ".join(dict.fromkeys([*speed, _period_key(data)]))


def _period_key(data: Mapping[str, Any]) -> str:
    """The key the user wrote that sets the observer's period."""
    obs = data.get("observer", {})
    return "observer.T_obs" if isinstance(obs, Mapping) and "T_obs" in obs else "inverter.f_s"


def _too_fast(w_max: float, T_obs: float) -> str:
    return (
        f"the highest speed {w_max:.4g} rad/s (electrical) leaves fewer than 4 observer periods "
        f"(T_obs = {T_obs:.4g} s) per electrical period (w_max T_obs = {w_max * T_obs:.3g} >= pi/2): "
        "check these values and their units, or lower envelope.speed_max"
    )


def slowest_pll_pole(gains: Mapping[str, Entry], file: str) -> float:
    """-(the PLL's slowest pole seen in its speed estimate) [1/s] of a [gains] section: bw (constant,
    schedule) or the slow root of s^2 + k_p s + k_i (voltage-scaled; k_p/2 where the roots are complex).

    d theta_pll/dt follows the speed by (k_p s + k_i)/((s + p_1)(s + p_2)): in its step response the
    slow root p_1 has the weight p_1/(p_2 - p_1) (the PI's zero k_i/k_p nearly cancels it). Below
    PLL_CANCELLED (VESC's defaults 2000/30000: 0.8 %) the rule takes the fast root p_2. The runtime's
    speed output is the integrator w_pll, k_i/((s + p_1)(s + p_2)), which shows p_1 in full: the report
    says so where p_1 is below a tenth of alpha_s (reports/pmsm_flux_observer/findings.py)."""
    t = {k: e.value for k, e in gains.items()}
    law = law_now(t.get("law"), file)
    if not isinstance(law, str):
        raise DriveFileError(file, "gains.law", f"missing key or not a string ({' | '.join(LAW_KEYS)})")
    v = parse_law(law, t, file, "gains")
    if law != "voltage-scaled":
        return float(v["pll_bandwidth"])
    kp, ki = v["foc_pll_kp"], v["foc_pll_ki"]
    disc = kp**2 - 4 * ki
    if disc <= 0:
        return kp / 2
    p1, p2 = (kp - math.sqrt(disc)) / 2, (kp + math.sqrt(disc)) / 2
    return p2 if p1 / (p2 - p1) < PLL_CANCELLED else p1


def default_gains(law: str, psi: float) -> dict[str, tuple[Any, str]]:
    """The firmware's default gains of ``law`` (their sources: docs/families/pmsm_flux_observer.md)."""
    if law == "voltage-scaled":
        return {
            "law": ("voltage-scaled", "VESC Tool's detection"),
            "foc_observer_gain": (float(g6(1e3 / psi**2)), "detection: 1e-3/lambda^2, stored x1e6"),
            "foc_observer_gain_slow": (0.05, "VESC default"),
            "foc_pll_kp": ("2000 1/s", "VESC default"),
            "foc_pll_ki": ("30000 1/s2", "VESC default"),
        }
    return {
        "law": ("constant", "ODrive's defaults"),
        "observer_gain": ("1000 1/s", "ODrive default (gamma lambda^2)"),
        "pll_bandwidth": ("1000 rad/s", "ODrive default"),
    }


def load(data: Mapping[str, Any], file: str, digest: str, kind: str) -> FluxObserverDrive:
    """The drive of a (minimal or complete) drive file: completed by :func:`document`, read strictly."""
    d = document(data, file).data()
    head = d["drive"]
    m = read_motor(d["motor"], file)  # datasheet terms; the drive keeps the shared record
    motor = PmsmMotor(m.p, m.R_s, m.L_d, m.L_q, m.psi_pm, m.J)
    rating = load_section(PmsmRating, d["rating"], file, "rating", skip=("I_N",))
    obs_t = d["observer"]
    adapt = obs_t["lambda_adaptation"]
    if not isinstance(adapt, bool):
        raise DriveFileError(file, "observer.lambda_adaptation", f"expected true or false, got {adapt!r}")
    observer = ObserverSettings(
        firmware=_choice(obs_t, "firmware", FIRMWARES, "generic", file),
        correction=_choice(obs_t, "correction", CORRECTIONS, "", file),
        inductance_rule=_choice(obs_t, "inductance", INDUCTANCES, "", file),
        lambda_adaptation=adapt,
        T_obs=positive(obs_t, "T_obs", "time", file, "observer"),
    )
    estimate = load_section(PmsmEstimate, d["estimate"], file, "estimate")
    ctl = d["control"]
    w_base = rating.n_N * math.pi / 30 * motor.p
    control = PmsmControl(
        T_s=observer.T_obs,
        alpha_c=positive(ctl, "alpha_c", "angular", file, "control"),
        alpha_s=positive(ctl, "alpha_s", "angular", file, "control"),
        T_max=positive(ctl, "T_max", "torque", file, "control"),
        u_dc=positive(d["inverter"], "u_dc", "voltage", file, "inverter"),
        speed_ramp=speed_ramp(ctl, file, w_base),
    )
    env_t = d["envelope"]
    keys = load_section(EnvelopeKeys, env_t, file, "envelope", {"pu": w_base}, skip=("torques",))
    torques = quantities(env_t, "torques", "torque", file, "envelope")
    if keys.speeds < 2 or not keys.speed_min < keys.speed_max:
        raise DriveFileError(file, "envelope", "need speeds >= 2 and 0 < speed_min < speed_max")
    if keys.speed_max * observer.T_obs >= math.pi / 2:
        raise DriveFileError(file, _speed_keys(data, m), _too_fast(keys.speed_max, observer.T_obs))
    # speeds evenly spaced in rad/s from speed_min to speed_max, both directions
    given = dataclasses.replace(keys, torques=tuple(torques))
    env = Envelope(
        SpeedRule(keys.speed_min, keys.speed_max, keys.speeds), given.torques, w_base, rating.T_N, given=given
    )
    drive = FluxObserverDrive(
        name=head["name"],
        kind=kind,
        source=head.get("source", ""),
        file=file,
        rating=rating,
        motor=motor,
        estimate=estimate,
        control=control,
        observer=observer,
        gains_table=dict(d["gains"]),
        envelope=env,
        digest=digest,
        i_noise=positive(ctl, "i_noise", "current", file, "control") if "i_noise" in ctl else 0.0,
    )
    # the [gains] section checked at load time, its observer gain against the period
    section_gains(drive.gains_table, file, observer.T_obs, _period_key(data))
    r_t = table(data, "rating", file) if "rating" in data else {}
    keys = {
        "n_N": "rating.n_N" if "n_N" in r_t else "inverter.u_dc",
        "T_N": "rating.T_N" if "T_N" in r_t else ("rating.I_N" if "I_N" in r_t else "motor.R_s"),
        "I_N": "rating.I_N",
        "f_N": "rating.f_N",
        "u_dc": "inverter.u_dc",
        "T_s": "observer.T_obs" if "T_obs" in d["observer"] and "observer" in data else "inverter.f_s",
        "w_max": "envelope.speed_max",
    }
    I_N = positive(r_t, "I_N", "current", file, "rating") if "I_N" in r_t and "T_N" in r_t else None
    findings = plausibility(
        m,
        n_N=rating.n_N,
        T_N=rating.T_N,
        I_N=I_N,
        f_N=None,
        u_dc=control.u_dc,
        T_s=observer.T_obs,
        w_max=env.speed_max,
        keys=keys,
    )
    warnings = warning_lines(findings, file)
    return dataclasses.replace(drive, warnings=tuple(warnings)) if warnings else drive
